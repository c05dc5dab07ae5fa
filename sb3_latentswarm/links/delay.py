"""Delayed messages (*extension, opt-in*): a message that gets through may arrive ``d`` steps late, or be lost.

At step ``t`` the base model says which transmissions ``j -> i`` get through. Each gets a delay ``d`` (fixed, or drawn
per directed link and step) and arrives at ``t + d`` if ``d <= expiry``; a message with ``d > expiry`` is lost.
Several messages of one sender can arrive at the same step (one sent at ``t - 2`` with ``d = 2`` and one sent at
``t - 1`` with ``d = 1``): the freshest (smallest age) is kept and the older ones are dropped, since a newer message of
the same sender supersedes them. So at every step each directed link delivers at most one message, and

* ``mask[s, i, j]`` = a message of ``j`` arrived at ``i`` at this step (the ``link_row`` convention),
* ``age[s, i, j]`` = its delay ``d`` in steps (0 = on time; 0 where nothing arrived).

A message that arrives at ``t`` with age ``a`` carries what ``j`` sent ``a`` steps before the on-time message: the
pooled message of Sec. III-B under delay is the mean over the arrivals of each sender's ``z`` of the step it was sent
(the policy's :func:`sb3_latentswarm.latent_ppo.recurrence.pool_delayed_messages`). Delay draws come after the base
model's draws, from the same per-swarm stream; with ``message_delay = 0`` this module is not used and nothing changes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sb3_latentswarm.config import DELAY_MODELS
from sb3_latentswarm.links.base import LinkModel, LinkStep, Swarms

__all__ = ["DELAY_MODELS", "DelayedLinks", "draw_delays"]

#: Marks an empty slot of the in-flight buffer.
_EMPTY = -1


def draw_delays(model: str, mean_delay: int, uniforms: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """Delays in steps (int64, ``shape``) of messages sent at one step, mean ``mean_delay`` = D in every model.

    * ``"fixed"``: ``d = D`` (no random draw, ``uniforms`` unused);
    * ``"uniform"``: ``d = floor(u (2D + 1))``, uniform on ``{0, ..., 2D}``;
    * ``"geometric"``: ``P(d >= k) = q^k`` with ``q = D / (1 + D)``, ``d = floor(log(1 - u) / log(q))``.

    :param uniforms: U(0, 1) variates of ``shape`` (one per directed link), unless the model is ``"fixed"``.
    """
    if model == "fixed" or mean_delay == 0:
        return np.full(shape, mean_delay, dtype=np.int64)
    if uniforms is None:
        raise ValueError(f"delay model {model!r} draws its delays: pass uniforms of shape {shape}")
    if model == "uniform":
        return np.floor(uniforms * (2 * mean_delay + 1)).astype(np.int64)
    if model == "geometric":
        log_q = math.log(mean_delay / (1.0 + mean_delay))
        with np.errstate(divide="ignore"):
            steps = np.floor(np.log1p(-uniforms) / log_q)
        return np.minimum(steps, np.iinfo(np.int32).max).astype(np.int64)
    raise ValueError(f"delay model must be one of {DELAY_MODELS}, got {model!r}")


class DelayedLinks(LinkModel):
    """Wraps a link model: what gets through at step t arrives ``d`` steps later, or is lost when ``d > expiry``.

    State: the in-flight buffer ``in_flight[s, i, j, k]``, the age of the message of ``j`` that arrives at ``i`` in
    ``k`` steps (``-1``: none), ``k = 0 .. expiry``, plus the base model's state.

    :param base: the model that says which transmissions get through.
    :param mean_delay: D, the delay in steps (``"fixed"``) or its mean.
    :param delay_model: one of :data:`DELAY_MODELS`.
    :param expiry: E, the largest delay at which a message is still delivered.
    """

    has_delay = True

    def __init__(self, base: LinkModel, mean_delay: int, delay_model: str, expiry: int) -> None:
        super().__init__(base.n_swarms, base.n_agents)
        if delay_model not in DELAY_MODELS:
            raise ValueError(f"delay_model must be one of {DELAY_MODELS}, got {delay_model!r}")
        self.base = base
        self.needs_positions = base.needs_positions
        self.mean_delay = int(mean_delay)
        self.delay_model = delay_model
        self.expiry = int(expiry)
        n = self.n_agents
        self.in_flight = np.full((self.n_swarms, n, n, self.expiry + 1), _EMPTY, dtype=np.int16)

    def reset(self, swarms: Swarms) -> None:
        self.base.reset(swarms)
        self.in_flight[swarms] = _EMPTY  # messages of the last episode never arrive

    def step(
        self,
        swarms: Swarms,
        rngs: Sequence[np.random.Generator],
        positions: np.ndarray | None,
        distances2: np.ndarray | None = None,
    ) -> LinkStep:
        sent = self.base.step(swarms, rngs, positions, distances2).mask  # (K, N, N): what gets through this step
        shape = sent.shape
        uniforms = None
        if self.delay_model != "fixed" and self.mean_delay > 0:
            uniforms = np.empty(shape)
            for k, rng in enumerate(rngs):
                rng.random(out=uniforms[k])
        delays = draw_delays(self.delay_model, self.mean_delay, uniforms, shape)
        in_flight = self.in_flight[swarms]  # (K, N, N, E + 1)
        in_flight[..., :-1] = in_flight[..., 1:]  # one step closer; slot 0 of the last step was delivered then
        in_flight[..., -1] = _EMPTY
        s, i, j = np.nonzero(sent & (delays <= self.expiry))
        d = delays[s, i, j]
        # a message placed now at slot d has age d; whatever sits there was sent earlier (older): the freshest wins
        in_flight[s, i, j, d] = d
        self.in_flight[swarms] = in_flight
        arrived = in_flight[..., 0]
        mask = arrived != _EMPTY
        return LinkStep(mask, np.maximum(arrived, 0))

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return {"in_flight": self.in_flight, **{f"base.{k}": v for k, v in self.base._state_arrays().items()}}
