"""What one UAV's step reads, checked before any state changes; numpy only (no torch), shared by
:class:`~sb3_latentswarm.agent.LatentSwarmAgent` and :class:`~sb3_latentswarm.agent.OnnxSwarmAgent`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

__all__ = ["AgentSpec", "AgentStepInfo", "StepArrays", "check_step", "pooled_message_age"]


@dataclass(frozen=True)
class AgentSpec:
    """The sizes a per-UAV step works with (read from the policy, or from an exported file's metadata)."""

    local_obs_shape: tuple[int, ...]
    """Shape of one UAV's ``local_obs`` o_t (flattened to o_dim floats inside the step)."""
    proprio_dim: int
    """e_dim, the size of ``proprio`` e_t (on the swarm env its first three entries are the normalized position p_t;
    0 on an adapted env without an own-state function)."""
    message_dim: int
    """d = d_mu + d_tau, the floats of one message z = [mu; tau] (Sec. III-B)."""
    action_dim: int
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    position_key: str | None = "proprio"
    """Where the map update's p_t comes from (the policy's ``layout.position_key``): ``"proprio"`` (the swarm env),
    ``"position"`` (an adapted env with a position function: the observation's ``position`` key), ``None`` (none)."""
    position_dims: int = 3
    """The size of p_t (2 or 3; 0 without positions)."""


class AgentStepInfo(NamedTuple):
    """What one step computed besides the action (numpy, float32)."""

    message: np.ndarray
    """z_t = [mu_t; tau_t], the message this UAV broadcasts for step t + 1 (what :meth:`LatentSwarmAgent.message`
    returns next), (d,)."""
    received_message: np.ndarray
    """m_t, the mean of the messages received this step (zero when none), (d,)."""
    has_message: bool
    """Whether any message arrived (N_t^i not empty)."""
    predicted_message: np.ndarray
    """mhat_t = P_zeta(rho_t, o_t, e_t) (Sec. III-C), computed at every step, (d,)."""
    best_message: np.ndarray
    """mbar_t: m_t if a message arrived, else the policy's ``message_substitute``, (d,)."""


@dataclass(frozen=True)
class StepArrays:
    """One step's checked inputs, float32."""

    local_obs: np.ndarray
    """o_t, flattened, (o_dim,)."""
    proprio: np.ndarray
    """e_t, (e_dim,)."""
    message_mean: np.ndarray
    """m_t, the mean of the received messages (zero when none), (d,)."""
    message_count: int
    """|N_t^i|, how many messages arrived."""
    noise: np.ndarray | None
    """eps ~ N(0, I) for a sampled action, (action_dim,); ``None`` for the mean action."""
    position: np.ndarray | None = None
    """p_t, (position_dims,), where the spec reads it from the ``position`` key (an adapted env); else ``None``."""


def check_step(spec: AgentSpec, observation: Any, received_messages: Any, deterministic: bool, noise: Any,
               rng: Any, own_rng: np.random.Generator) -> StepArrays:
    """Check one step's inputs and turn them into float32 arrays.

    :param observation: a mapping with ``local_obs`` (``spec.local_obs_shape``), ``proprio`` (``(e_dim,)``) and, for
        a policy trained on an adapted env with positions, ``position`` (``(position_dims,)``); other keys
        (``link_row``, the critic's keys) are ignored, so a per-agent observation of the vec env fits as is
    :param received_messages: the messages z_{t-1}^j that arrived this step, (k, d) for any k >= 0 (an empty
        sequence is k = 0)
    :param deterministic: the mean action (then ``noise`` and ``rng`` must be None)
    :param noise: eps ~ N(0, I), (action_dim,), or None
    :param rng: a ``numpy.random.Generator`` to draw eps from, or None
    :param own_rng: drawn from when the action is sampled and neither ``noise`` nor ``rng`` is given
    :raise TypeError: for an observation that is not a mapping, non-numeric arrays, ``rng`` not a Generator
    :raise ValueError: for a missing key, a wrong shape, a non-finite value, noise with a deterministic step
    """
    if not isinstance(observation, Mapping):
        raise TypeError(f"observation must be a mapping with keys 'local_obs' and 'proprio', got {type(observation).__name__}")
    keys = ("local_obs", "proprio", "position") if spec.position_key == "position" else ("local_obs", "proprio")
    missing = [key for key in keys if key not in observation]
    if missing:
        raise ValueError(f"observation lacks the key(s) {missing} (has {list(observation)})")
    local_obs = _numeric("observation['local_obs']", observation["local_obs"])
    if local_obs.shape != spec.local_obs_shape:
        raise ValueError(f"observation['local_obs'] must have shape {spec.local_obs_shape}, got {local_obs.shape}")
    proprio = _numeric("observation['proprio']", observation["proprio"])
    if proprio.shape != (spec.proprio_dim,):
        raise ValueError(f"observation['proprio'] must have shape ({spec.proprio_dim},), got {proprio.shape}")
    position = None
    if spec.position_key == "position":
        position = _numeric("observation['position']", observation["position"])
        if position.shape != (spec.position_dims,):
            pad = " (2-D positions are padded with z = 0, as the adapter does)" if position.shape == (2,) else ""
            raise ValueError(f"observation['position'] must have shape ({spec.position_dims},), got {position.shape}{pad}")
    if not all(np.isfinite(x).all() for x in (local_obs, proprio, *(() if position is None else (position,)))):
        raise ValueError("observation holds a non-finite value (NaN or inf)")

    messages = _numeric("received_messages", received_messages)
    if messages.size == 0 and messages.ndim <= 2 and (messages.ndim < 2 or messages.shape[-1] in (0, spec.message_dim)):
        messages = messages.reshape(0, spec.message_dim)
    if messages.ndim != 2 or messages.shape[1] != spec.message_dim:
        raise ValueError(
            f"received_messages must have shape (k, {spec.message_dim}) (k messages of d = d_mu + d_tau floats), "
            f"got {messages.shape}"
        )
    if not np.isfinite(messages).all():
        bad = sorted({int(i) for i in np.flatnonzero(~np.isfinite(messages).all(axis=1))})
        raise ValueError(f"received_messages rows {bad} hold a non-finite value (NaN or inf)")
    count = messages.shape[0]
    mean = messages.mean(axis=0, dtype=np.float32) if count else np.zeros(spec.message_dim, dtype=np.float32)

    if not isinstance(deterministic, (bool, np.bool_)):
        raise TypeError(f"deterministic must be a bool, got {deterministic!r}")
    if noise is not None and rng is not None:
        raise ValueError("give noise or rng, not both")
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    eps = None
    if deterministic:
        if noise is not None or rng is not None:
            raise ValueError("a deterministic step takes the mean action: noise and rng must be None")
    elif noise is not None:
        eps = _numeric("noise", noise)
        if eps.shape != (spec.action_dim,):
            raise ValueError(f"noise must have shape ({spec.action_dim},), got {eps.shape}")
        if not np.isfinite(eps).all():
            raise ValueError("noise holds a non-finite value (NaN or inf)")
    else:
        eps = (own_rng if rng is None else rng).standard_normal(spec.action_dim).astype(np.float32)
    return StepArrays(local_obs.reshape(-1), proprio, mean.astype(np.float32), count, eps, position)


def pooled_message_age(message_ages: Any, count: int, expiry: int, delay_aware: bool) -> float | None:
    """alpha_t = mean_{j in N_t^i} a_ij / max(E, 1), the age input of a delay-aware policy (``docs/concepts.md``,
    "Delayed messages"; 0 when nothing arrived or no ages are given: all on time); ``None`` for a policy that does not
    read ages.

    :param message_ages: how many steps late each received message is, (count,) in [0, E], or ``None``
    :param count: how many messages arrived this step
    :param expiry: E, the largest delay the policy was trained with (steps)
    :param delay_aware: whether the policy reads ages
    :raise ValueError: ages given to a policy that does not read them; ages of the wrong shape, non-finite or outside
        [0, E]
    """
    if not delay_aware:
        if message_ages is not None:
            raise ValueError("message_ages given, but this policy does not read message ages (delay_aware=False): "
                             "pass the messages as sent without their ages, or train with policy_kwargs "
                             "delay_aware=True")
        return None
    if message_ages is None:
        return 0.0
    ages = np.asarray(message_ages, dtype=np.float64).reshape(-1) if np.ndim(message_ages) else np.array([np.nan])
    if ages.shape != (count,) or not (np.isfinite(ages).all() and (ages >= 0).all() and (ages <= expiry).all()):
        raise ValueError(f"message_ages must hold one age in [0, {expiry}] (steps) per received message ({count}), "
                         f"got {message_ages!r}")
    return float(ages.mean() / max(expiry, 1)) if count else 0.0


def _numeric(name: str, value: Any) -> np.ndarray:
    """``value`` as a new float32 array; ``TypeError`` unless it holds numbers (bool, int or float)."""
    array = np.asarray(value)
    if array.dtype.kind not in "biuf":
        raise TypeError(f"{name} must hold numbers, got an array of dtype {array.dtype}")
    return np.array(array, dtype=np.float32)  # a writable copy (torch warns on read-only arrays)
