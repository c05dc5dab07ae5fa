"""The link models without delay: fixed (Full comm, No comm), outages only (Bernoulli, Gilbert-Elliott), distance,
and the paper's A2A channel of Eq. (1) (:class:`~sb3_latentswarm.channel.A2AChannel`, its closed form and sampler).

Every model with abrupt failures draws them through :class:`Outages`: ``xi ~ Bernoulli(1 - p_f)`` per directed link
and step (``outage_model="bernoulli"``, Eq. (1)'s xi) or a Gilbert-Elliott chain per directed link
(``outage_model="gilbert_elliott"``, see :func:`~sb3_latentswarm.channel.outage_transition_probabilities`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sb3_latentswarm.channel import XI_UNSET, A2AChannel, outage_thresholds, squared_distances, step_link_outages
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.links.base import LinkModel, LinkStep, Swarms

__all__ = ["A2ALinks", "DistanceLinks", "FixedLinks", "OutageLinks", "Outages"]


class Outages:
    """The abrupt failures xi of every directed link of ``n_swarms`` swarms (1 = no failure).

    :param config: ``outage_model``, ``p_fail`` and ``mean_outage_steps`` are read.
    """

    def __init__(self, config: SwarmConfig, n_swarms: int) -> None:
        n = config.n_agents
        self.p_fail = float(config.p_fail)
        self.stateful = config.outage_model == "gilbert_elliott"
        self.thresholds = outage_thresholds(config)
        # outage state of every directed link: 1 up, 0 failed, XI_UNSET before its first draw of an episode
        self.xi_state = np.full((n_swarms, n, n), XI_UNSET, dtype=np.int8) if self.stateful else None

    def reset(self, swarms: Swarms) -> None:
        if self.xi_state is not None:
            self.xi_state[swarms] = XI_UNSET  # the chains restart from their stationary distribution

    def xi(self, swarms: Swarms, uniforms: np.ndarray) -> np.ndarray:
        """xi of this step (K, N, N) bool from one U(0, 1) variate per directed link; advances the chains."""
        if self.xi_state is None:
            return uniforms >= self.p_fail  # xi ~ Bernoulli(1 - p_f)
        xi_state = self.xi_state[swarms]
        xi = step_link_outages(xi_state, uniforms, self.thresholds)
        self.xi_state[swarms] = xi
        return xi

    def state_arrays(self) -> dict[str, np.ndarray]:
        return {} if self.xi_state is None else {"xi_state": self.xi_state}


def _uniforms(rngs: Sequence[np.random.Generator], shape: tuple[int, ...]) -> np.ndarray:
    """One ``rng.random(shape)`` per swarm, stacked: (K, *shape)."""
    out = np.empty((len(rngs),) + shape)
    for k, rng in enumerate(rngs):
        rng.random(out=out[k])
    return out


class FixedLinks(LinkModel):
    """Every directed link up (``up=True``, Full comm) or down (No comm); no random draws."""

    def __init__(self, n_swarms: int, n_agents: int, up: bool) -> None:
        super().__init__(n_swarms, n_agents)
        self.up = bool(up)

    def step(
        self,
        swarms: Swarms,
        rngs: Sequence[np.random.Generator],
        positions: np.ndarray | None,
        distances2: np.ndarray | None = None,
    ) -> LinkStep:
        n = self.n_agents
        if self.up:
            return LinkStep(np.broadcast_to(self._offdiagonal, (len(rngs), n, n)).copy(), None)
        return LinkStep(np.zeros((len(rngs), n, n), dtype=bool), None)


class OutageLinks(LinkModel):
    """Links fail only by abrupt failures: ``j -> i`` delivers iff ``xi_{j->i} = 1`` (no geometry).

    With ``outage_model="bernoulli"`` this is the Bernoulli model (delivery rate ``1 - p_f``, independent draws), with
    ``"gilbert_elliott"`` the Gilbert-Elliott model (stationary rate ``1 - p_f``, mean failure run
    ``mean_outage_steps``). Draws ``rng.random((N, N))`` per swarm and step.
    """

    def __init__(self, config: SwarmConfig, n_swarms: int) -> None:
        super().__init__(n_swarms, config.n_agents)
        self.outages = Outages(config, n_swarms)

    def reset(self, swarms: Swarms) -> None:
        self.outages.reset(swarms)

    def step(
        self,
        swarms: Swarms,
        rngs: Sequence[np.random.Generator],
        positions: np.ndarray | None,
        distances2: np.ndarray | None = None,
    ) -> LinkStep:
        n = self.n_agents
        return LinkStep(self.outages.xi(swarms, _uniforms(rngs, (n, n))) & self._offdiagonal, None)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return self.outages.state_arrays()


class DistanceLinks(OutageLinks):
    """Disk model: ``j -> i`` delivers iff ``||p_i - p_j|| <= link_range`` (3D, metres) and ``xi_{j->i} = 1``.

    With ``outages=False`` no failures are drawn (and no random numbers): exactly the links within range.
    """

    needs_positions = True

    def __init__(self, config: SwarmConfig, n_swarms: int, link_range: float, outages: bool = True) -> None:
        super().__init__(config, n_swarms)
        self.link_range = float(link_range)
        self._range2 = self.link_range**2
        self.draws_outages = bool(outages)

    def reset(self, swarms: Swarms) -> None:
        if self.draws_outages:
            super().reset(swarms)

    def step(
        self,
        swarms: Swarms,
        rngs: Sequence[np.random.Generator],
        positions: np.ndarray | None,
        distances2: np.ndarray | None = None,
    ) -> LinkStep:
        if distances2 is None:
            if positions is None:
                raise ValueError(f"{type(self).__name__} needs the positions (K, N, 3) in metres, got None")
            distances2 = squared_distances(positions)
        in_range = (distances2 <= self._range2) & self._offdiagonal
        if not self.draws_outages:
            return LinkStep(in_range, None)
        return LinkStep(in_range & super().step(swarms, rngs, positions).mask, None)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return super()._state_arrays() if self.draws_outages else {}


class A2ALinks(LinkModel):
    """The paper's A2A channel, Eq. (1): ``j -> i`` delivers iff ``Gamma_{j->i} >= beta_th`` and ``xi_{j->i} = 1``.

    Draws per swarm and step ``rng.standard_normal((N, N, 2))`` (the Rician fading) then ``rng.random((N, N + 1))``
    (xi from the first N columns, the interference I from the last), the order of
    :meth:`A2AChannel.sample <sb3_latentswarm.channel.A2AChannel.sample>`; the closed-form rate is
    :func:`~sb3_latentswarm.channel.link_probability`.
    """

    needs_positions = True

    def __init__(self, config: SwarmConfig, n_swarms: int) -> None:
        super().__init__(n_swarms, config.n_agents)
        self.channel = A2AChannel(config.replace(link_mode="channel"))
        self.outages = Outages(config, n_swarms)  # holds the Gilbert-Elliott state the channel advances

    def reset(self, swarms: Swarms) -> None:
        self.outages.reset(swarms)

    def step(
        self,
        swarms: Swarms,
        rngs: Sequence[np.random.Generator],
        positions: np.ndarray | None,
        distances2: np.ndarray | None = None,
    ) -> LinkStep:
        if positions is None:
            raise ValueError(f"{type(self).__name__} needs the positions (K, N, 3) in metres, got None")
        n = self.n_agents
        normals = np.empty((len(rngs), n, n, 2))
        uniforms = np.empty((len(rngs), n, n + 1))
        for k, rng in enumerate(rngs):
            rng.standard_normal(out=normals[k])
            rng.random(out=uniforms[k])
        chains = self.outages.xi_state
        if chains is None:
            return LinkStep(self.channel.links_from_variates(positions, normals, uniforms, None, distances2), None)
        xi_state = chains[swarms]
        links = self.channel.links_from_variates(positions, normals, uniforms, xi_state, distances2)
        chains[swarms] = xi_state  # advanced in place (on a copy when swarms gathers)
        return LinkStep(links, None)

    def _state_arrays(self) -> dict[str, np.ndarray]:
        return self.outages.state_arrays()
