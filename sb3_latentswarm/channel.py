"""Air-to-air (A2A) channel of Sec. II-A, Eq. (1): which directed links are up at one environment step.

The SINR at receiver ``i`` of the transmission of sender ``j`` is

    Gamma_{j->i} = P / (sigma^2 + I_i) * |h_{j->i}|^2 * d_{ij}^-alpha * L_atm * xi_{j->i}        (Eq. (1))

and the directed link ``j -> i`` is active iff ``Gamma_{j->i} >= beta_th``.

Units and conventions
---------------------
* ``P`` is the transmit power in mW, converted from ``SwarmConfig.tx_power_dbm`` (20 dBm = 100 mW).
  ``sigma^2`` (``noise_power``) and ``I`` (``interference_max``) are in mW, so the SINR is dimensionless.
* ``d_ij`` is the 3D Euclidean distance in metres between the positions ``(x, y, z)`` (already in metres, not cells).
  Distances below ``SwarmConfig.min_link_distance`` are raised to it, so co-located UAVs give a finite SINR.
* ``|h|^2`` is Rician with factor ``K`` and ``E|h|^2 = 1``: ``h = sqrt(K/(K+1)) + sqrt(1/(K+1)) * CN(0, 1)``, drawn
  independently per directed link and step (so ``h_{j->i}`` and ``h_{i->j}`` are independent draws).
  Equivalently ``2 (K+1) |h|^2`` is noncentral chi-square with 2 degrees of freedom and noncentrality ``2K``.
* Optional (off by default, ``rician_k_altitude_slope = 0``): the K-factor grows with the pair's mean altitude,
  ``K_ij = max(0, K + slope * (0.5 (z_i + z_j) - min_altitude))``.
* ``I_i ~ U(0, I_max)`` is drawn once per receiver ``i`` and step (shared by all links into ``i``).
* ``xi_{j->i} ~ Bernoulli(1 - p_f)`` is drawn per directed link and step (``outage_model="bernoulli"``, the paper's).
* Extension, ``outage_model="gilbert_elliott"``: ``xi_{j->i}`` is a two-state Markov chain per directed link (bursty
  outages). An up link fails with probability ``f`` per step and a failed link recovers with probability ``r = 1 / L``
  (``L = mean_outage_steps``, the mean failure run); ``f = p_f r / (1 - p_f)`` makes ``p_f`` the stationary failure
  probability, so :func:`link_probability` holds at every step once the chain starts stationary (it does: the first
  draw of an episode is Bernoulli). ``L = 1 / (1 - p_f)`` gives back independent draws; ``p_f = 1`` keeps every link
  down. The caller keeps the chain state (:data:`XI_UNSET` at reset) and passes it to :meth:`A2AChannel.sample`.
* A link is active iff ``xi_{j->i} = 1`` and ``Gamma_{j->i} >= beta_th``. For ``beta_th > 0`` this is exactly
  ``Gamma >= beta_th`` (a failed link has ``Gamma = 0``); for ``beta_th = 0`` it keeps failed links down.

Link-matrix convention: ``L[..., i, j] = True`` iff the message of sender ``j`` reached receiver ``i``
(row = receiver, column = sender), i.e. ``(j, i)`` is an edge of the paper's graph ``G_t`` and ``j`` is in
``N_t^i``. The diagonal is always ``False`` (a UAV does not "receive" its own message).

``SwarmConfig.link_mode`` selects the ablations: ``"channel"`` draws links from Eq. (1), ``"full"`` sets every
off-diagonal link up (Full comm), ``"none"`` sets every link down (No comm); ``"full_in_range"`` (extension) sets up
exactly the links no longer than :func:`usable_link_range`. The last three make no random draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_latentswarm.config import SwarmConfig

__all__ = [
    "XI_UNSET",
    "A2AChannel",
    "ChannelDraws",
    "link_probability",
    "outage_thresholds",
    "outage_transition_probabilities",
    "sample_rician_power",
    "squared_distances",
    "step_link_outages",
    "usable_link_range",
]

#: Gauss-Legendre nodes used by :func:`link_probability` to average over ``I ~ U(0, I_max)``.
N_QUADRATURE = 64
#: Value of a link's outage state before its first draw of an episode (the states are int8: 1 up, 0 failed).
XI_UNSET = -1
#: Distances in metres beyond which :func:`usable_link_range` calls a link always usable (e.g. ``alpha = 0``).
MAX_LINK_RANGE = 1e9


def outage_transition_probabilities(p_fail: float, mean_outage_steps: float) -> tuple[float, float]:
    """Gilbert-Elliott transition probabilities ``(f, r)`` per step: up -> failed ``f``, failed -> up ``r``.

    ``r = 1 / L`` and ``f = p_f r / (1 - p_f)``, so the stationary failure probability ``f / (f + r)`` is ``p_f`` and a
    failure run lasts ``L`` steps on average (geometric). ``p_f = 1`` gives ``(1, 0)``: every link stays down.

    :param p_fail: stationary failure probability p_f in [0, 1].
    :param mean_outage_steps: L >= 1 / (1 - p_f), the mean failure run in steps.
    """
    if p_fail >= 1.0:
        return 1.0, 0.0
    recover = 1.0 / mean_outage_steps
    return min(p_fail * recover / (1.0 - p_fail), 1.0), recover


def outage_thresholds(config: SwarmConfig) -> np.ndarray:
    """Thresholds of the xi draw, indexed by the previous outage state + 1: xi_t = (u >= thresholds[state + 1]).

    Entries ``[p_f, 1 - r, f]`` for the states ``(XI_UNSET, failed, up)``: an unset link is drawn from the stationary
    Bernoulli(1 - p_f), a failed link recovers with probability ``r``, an up link fails with probability ``f`` (see
    :func:`outage_transition_probabilities`). ``outage_model="bernoulli"`` gives ``[p_f, p_f, p_f]``, Eq. (1)'s xi.

    :return: float64 array of shape (3,).
    """
    if config.outage_model == "bernoulli":
        return np.full(3, float(config.p_fail))
    fail, recover = outage_transition_probabilities(config.p_fail, config.mean_outage_steps)
    return np.array([config.p_fail, 1.0 - recover, fail])


def step_link_outages(xi_state: np.ndarray, uniforms: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Advance the outage chain of every directed link by one step (vectorized over any leading shape).

    :param xi_state: int8 outage state of the previous step, shape (..., N, N): 1 up, 0 failed, :data:`XI_UNSET`
        before the first draw of an episode.
    :param uniforms: U(0, 1) draws of the same shape, one per link.
    :param thresholds: :func:`outage_thresholds` of the config.
    :return: xi of this step, bool, same shape (True = no abrupt failure).
    """
    # Gilbert-Elliott: P(xi_t = 1 | xi_{t-1}) = 1 - f (was up), r (was failed), 1 - p_f (unset: stationary)
    return uniforms >= thresholds[xi_state + 1]


def usable_link_range(config: SwarmConfig) -> float:
    """The channel's usable range in metres: the 3D distance at which a link without abrupt failures (p_f = 0) is up
    with probability ``config.link_range_probability`` under Eq. (1) (:func:`link_probability`, solved by bisection).

    With ``rician_k_altitude_slope != 0`` the K-factor is taken at ``initial_altitude``. Used by
    ``link_mode="full_in_range"``; 0 when even ``min_link_distance`` falls short of the probability.
    """
    from scipy import optimize  # lazy: only the "full_in_range" mode needs it

    channel_only = config.replace(p_fail=0.0, link_mode="channel")
    target = config.link_range_probability

    def excess(distance: float) -> float:
        return float(link_probability(distance, channel_only, altitude=config.initial_altitude)) - target

    low = config.min_link_distance
    if excess(low) < 0.0:
        return 0.0
    high = 2.0 * low
    while excess(high) >= 0.0:  # the probability falls to 0 as the distance grows, unless alpha = 0
        if high > MAX_LINK_RANGE:
            return math.inf
        high *= 2.0
    return float(optimize.brentq(excess, low, high, xtol=1e-6))


def _check_positions(positions: Any) -> np.ndarray:
    """Return ``positions`` as a float64 array of shape (N, 3) or (B, N, 3), or raise ``ValueError``."""
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim not in (2, 3) or pos.shape[-1] != 3:
        raise ValueError(f"positions must have shape (N, 3) or (B, N, 3) in metres, got shape {pos.shape}")
    if not np.isfinite(pos).all():
        raise ValueError(f"positions must be finite, got non-finite values in an array of shape {pos.shape}")
    return pos


def squared_distances(positions: np.ndarray) -> np.ndarray:
    """Squared 3D distances ``d_ij^2`` in m^2 between all UAV pairs, (..., N, N), from positions (..., N, 3)."""
    diff = positions[..., :, None, :] - positions[..., None, :, :]
    return (diff * diff).sum(axis=-1)


def _rician_k(config: SwarmConfig, mean_altitude: np.ndarray | float | None) -> np.ndarray | float:
    """K-factor of a pair at mean altitude ``mean_altitude`` (metres); ``config.rician_k`` when the slope is 0."""
    if config.rician_k_altitude_slope == 0.0 or mean_altitude is None:
        return float(config.rician_k)
    # K grows with altitude: K_ij = max(0, K + slope * (z_bar_ij - z_min))
    k = config.rician_k + config.rician_k_altitude_slope * (np.asarray(mean_altitude, dtype=np.float64) - config.min_altitude)
    return np.maximum(k, 0.0)


def sample_rician_power(k_factor: float | np.ndarray, size: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """Draw the Rician fading power ``|h|^2`` with factor ``K`` and ``E|h|^2 = 1``.

    ``h = sqrt(K/(K+1)) + sqrt(1/(K+1)) * CN(0, 1)`` with ``CN(0, 1) = (x + i y) / sqrt(2)``, ``x, y ~ N(0, 1)``.
    Consumes exactly one ``rng.standard_normal(size + (2,))`` call (the channel relies on this draw order).

    :param k_factor: Rician factor ``K >= 0`` (dimensionless), a scalar or an array broadcastable to ``size``.
    :param size: shape of the output.
    :param rng: numpy random generator.
    :return: array of shape ``size`` with the (dimensionless) fading powers ``|h|^2``.
    """
    k = np.asarray(k_factor, dtype=np.float64)
    if np.any(k < 0) or not np.all(np.isfinite(k)):
        raise ValueError(f"k_factor must be finite and >= 0, got {k_factor!r}")
    z = rng.standard_normal(tuple(size) + (2,))
    # Rician power: 2 (K+1) |h|^2 = (x + sqrt(2K))^2 + y^2 ~ ncx2(df=2, nc=2K)
    return ((z[..., 0] + np.sqrt(2.0 * k)) ** 2 + z[..., 1] ** 2) / (2.0 * (k + 1.0))


@dataclass(frozen=True)
class ChannelDraws:
    """The random quantities of Eq. (1) for one step (or a batch of steps) of ``N`` UAVs.

    :param h_power: Rician fading powers ``|h_{j->i}|^2``, shape (..., N, N), row = receiver ``i``.
    :param interference: interference ``I_i`` in mW per receiver, shape (..., N).
    :param xi: link-failure indicators ``xi_{j->i}`` (``True`` = no abrupt failure), shape (..., N, N), bool.
    """

    h_power: np.ndarray
    interference: np.ndarray
    xi: np.ndarray


class A2AChannel:
    """Samples the directed link matrix of Eq. (1) for the positions of the swarm.

    The link matrix ``L[..., i, j]`` is ``True`` iff receiver ``i`` got the message of sender ``j``
    (row = receiver); its diagonal is always ``False``. See the module docstring for units.

    :param config: the swarm configuration (channel constants, ``link_mode``).
    """

    def __init__(self, config: SwarmConfig) -> None:
        self.config = config
        self.link_mode = config.link_mode
        self.p_fail = float(config.p_fail)
        self.beta_th = float(config.sinr_threshold)
        self.noise_power = float(config.noise_power)
        self.interference_max = float(config.interference_max)
        self.tx_power_mw = float(config.tx_power_mw)
        self.path_loss_exponent = float(config.path_loss_exponent)
        self.atmospheric_loss = float(config.atmospheric_loss)
        self.k_factor = float(config.rician_k)
        self.k_slope = float(config.rician_k_altitude_slope)
        self._min_d2 = float(config.min_link_distance) ** 2
        self._half_alpha = 0.5 * self.path_loss_exponent
        # Eq. (1) rearranged (no division at sample time): link iff xi and
        #   (x + sqrt(2K))^2 + y^2 >= 2 (K+1) * beta_th (sigma2 + I) / (P L_atm) * d^alpha
        gain = self.tx_power_mw * self.atmospheric_loss  # P * L_atm in mW
        self._c_noise = self.beta_th * self.noise_power / gain
        self._c_interf = self.beta_th * self.interference_max / gain
        self._m = math.sqrt(2.0 * self.k_factor)  # sqrt of the noncentrality 2K
        self._scale = 2.0 * (self.k_factor + 1.0)  # 2 (K+1)
        self._offdiag: dict[int, np.ndarray] = {}
        self._offdiag_mask(config.n_agents)
        self.stateful_outages = config.outage_model == "gilbert_elliott"
        self._xi_thresholds = outage_thresholds(config)
        self.link_range = usable_link_range(config) if self.link_mode == "full_in_range" else None
        """Usable range in metres of ``link_mode="full_in_range"`` (``None`` in the other modes)."""

    def _offdiag_mask(self, n: int) -> np.ndarray:
        """Cached boolean (n, n) mask, ``True`` off the diagonal."""
        mask = self._offdiag.get(n)
        if mask is None:
            mask = ~np.eye(n, dtype=bool)
            mask.setflags(write=False)
            self._offdiag[n] = mask
        return mask

    # ------------------------------------------------------------------ hot path
    def sample(
        self, positions: np.ndarray, rng: np.random.Generator | None, xi_state: np.ndarray | None = None
    ) -> np.ndarray:
        """Draw the directed link matrix for one step.

        Draw order (shared with :meth:`draw`): ``rng.standard_normal(batch + (N, N, 2))`` for the fading, then
        ``rng.random(batch + (N, N + 1))`` whose first ``N`` columns give ``xi`` and last column gives ``I``.
        No draws are made (``rng`` may be ``None``) when ``link_mode`` is ``"full"``, ``"full_in_range"`` or ``"none"``.

        :param positions: UAV positions in metres, shape (N, 3) or a batch (B, N, 3).
        :param rng: numpy random generator.
        :param xi_state: the outage state of every directed link, int8 of shape (N, N) or (B, N, N) (1 up, 0 failed,
            :data:`XI_UNSET` at the start of an episode); advanced in place to this step's xi. Required by
            ``outage_model="gilbert_elliott"``; ignored (left as it is) by ``"bernoulli"``, which has no memory.
        :return: boolean link matrix of shape (N, N) or (B, N, N); ``L[..., i, j]`` = receiver ``i`` got sender ``j``.
        """
        pos = _check_positions(positions)
        n = pos.shape[-2]
        if self.link_mode != "channel":
            if self.link_mode == "full":
                return np.broadcast_to(self._offdiag_mask(n), pos.shape[:-1] + (n,)).copy()
            if self.link_mode == "full_in_range":
                assert self.link_range is not None  # set in __init__ for this link mode
                return (squared_distances(pos) <= self.link_range**2) & self._offdiag_mask(n)
            return np.zeros(pos.shape[:-1] + (n,), dtype=bool)
        if rng is None:
            raise ValueError(f"link_mode {self.link_mode!r} draws the channel: rng must be a numpy Generator, got None")
        normals = rng.standard_normal(pos.shape[:-1] + (n, 2))
        uniforms = rng.random(pos.shape[:-1] + (n + 1,))
        return self.links_from_variates(pos, normals, uniforms, xi_state)

    def links_from_variates(
        self,
        positions: np.ndarray,
        normals: np.ndarray,
        uniforms: np.ndarray,
        xi_state: np.ndarray | None = None,
        distances2: np.ndarray | None = None,
    ) -> np.ndarray:
        """The link matrix of Eq. (1) (``link_mode="channel"``) from the standard variates that :meth:`sample` draws.

        Callers with one random stream per swarm (the batched env) draw the variates swarm by swarm and evaluate the
        whole batch here.

        :param positions: UAV positions in metres, (..., N, 3), already checked.
        :param normals: standard normals, (..., N, N, 2): the fading of every directed link.
        :param uniforms: U(0, 1) variates, (..., N, N + 1): ``xi`` from the first ``N`` columns, ``I`` from the last.
        :param xi_state: the outage state (..., N, N), advanced in place (see :meth:`sample`).
        :param distances2: :func:`squared_distances` of ``positions`` if the caller has them already.
        :return: boolean link matrix (..., N, N).
        """
        pos = positions
        n = pos.shape[-2]
        if distances2 is None:
            distances2 = squared_distances(pos)
        d2 = np.maximum(distances2, self._min_d2)  # squared 3D distance, clamped at d_min^2
        d_alpha = d2 if self._half_alpha == 1.0 else d2**self._half_alpha  # path loss d^alpha
        z, u = normals, uniforms
        # Eq. (1): Gamma >= beta_th  <=>  2(K+1)|h|^2 >= 2(K+1) beta_th (sigma2 + I_i) d^alpha / (P L_atm)
        rhs = (self._c_noise + self._c_interf * u[..., n : n + 1]) * d_alpha  # I_i = I_max * u, one per receiver row
        if self.k_slope == 0.0:
            lhs = (z[..., 0] + self._m) ** 2 + z[..., 1] ** 2  # 2(K+1)|h|^2 ~ ncx2(2, 2K)
            rhs *= self._scale
        else:
            alt = pos[..., 2]
            k = _rician_k(self.config, 0.5 * (alt[..., :, None] + alt[..., None, :]))  # K_ij at mean pair altitude
            lhs = (z[..., 0] + np.sqrt(2.0 * k)) ** 2 + z[..., 1] ** 2
            rhs *= 2.0 * (k + 1.0)
        return (lhs >= rhs) & self._xi(u[..., :n], xi_state) & self._offdiag_mask(n)

    def _xi(self, uniforms: np.ndarray, xi_state: np.ndarray | None) -> np.ndarray:
        """xi of this step from its uniforms (..., N, N); advances ``xi_state`` in place for the Markov chain."""
        if not self.stateful_outages:
            # xi ~ Bernoulli(1 - p_f): the link survives iff u >= p_f (nothing to remember)
            return uniforms >= self.p_fail
        if xi_state is None:
            raise ValueError(
                "outage_model='gilbert_elliott' keeps a Markov state per link: pass xi_state, an int8 array of "
                f"shape {uniforms.shape} filled with XI_UNSET at the start of the episode"
            )
        if xi_state.shape != uniforms.shape or xi_state.dtype != np.int8:
            raise ValueError(
                f"xi_state must be an int8 array of shape {uniforms.shape}, got {xi_state.dtype} {xi_state.shape}"
            )
        xi = step_link_outages(xi_state, uniforms, self._xi_thresholds)
        xi_state[...] = xi
        return xi

    # ------------------------------------------------------------------ helpers (tests, diagnostics)
    def draw(self, positions: np.ndarray, rng: np.random.Generator, xi_state: np.ndarray | None = None) -> ChannelDraws:
        """Draw ``|h|^2``, ``I`` and ``xi`` with the same rng consumption as :meth:`sample` in ``"channel"`` mode.

        :param positions: UAV positions in metres, shape (N, 3) or (B, N, 3) (the altitude sets K if the slope is on).
        :param rng: numpy random generator.
        :param xi_state: the outage state, as in :meth:`sample` (advanced in place).
        :return: the draws, see :class:`ChannelDraws`.
        """
        pos = _check_positions(positions)
        n = pos.shape[-2]
        alt = pos[..., 2]
        k = _rician_k(self.config, 0.5 * (alt[..., :, None] + alt[..., None, :]))
        h_power = sample_rician_power(k, pos.shape[:-1] + (n,), rng)
        u = rng.random(pos.shape[:-1] + (n + 1,))
        interference = self.interference_max * u[..., n]  # I_i ~ U(0, I_max), per receiver
        xi = self._xi(u[..., :n], xi_state)
        return ChannelDraws(h_power=h_power, interference=interference, xi=xi)

    def sinr_from_draws(self, positions: np.ndarray, draws: ChannelDraws) -> np.ndarray:
        """Evaluate Eq. (1) for given draws. Independent of ``link_mode`` (it is the channel's physics).

        :param positions: UAV positions in metres, shape (N, 3) or (B, N, 3).
        :param draws: ``|h|^2``, ``I`` (mW) and ``xi`` as returned by :meth:`draw`.
        :return: SINR matrix (dimensionless, linear), shape (N, N) or (B, N, N), ``[..., i, j]`` = ``Gamma_{j->i}``;
            the diagonal is 0.
        """
        pos = _check_positions(positions)
        n = pos.shape[-2]
        d = np.sqrt(np.maximum(squared_distances(pos), self._min_d2))  # 3D distance in metres, >= d_min
        interference = np.asarray(draws.interference, dtype=np.float64)[..., :, None]
        # Eq. (1): SINR = P / (sigma2 + I) * |h|^2 * d^-alpha * L_atm * xi
        gamma = (
            self.tx_power_mw
            / (self.noise_power + interference)
            * draws.h_power
            * d ** (-self.path_loss_exponent)
            * self.atmospheric_loss
            * draws.xi
        )
        return np.where(self._offdiag_mask(n), gamma, 0.0)

    def sinr(self, positions: np.ndarray, rng: np.random.Generator, xi_state: np.ndarray | None = None) -> np.ndarray:
        """Draw the channel and return the SINR matrix of Eq. (1) (diagonal 0).

        With the same rng state, ``sample`` in ``"channel"`` mode returns ``(sinr >= beta_th) & xi`` off the diagonal.

        :param positions: UAV positions in metres, shape (N, 3) or (B, N, 3).
        :param rng: numpy random generator.
        :param xi_state: the outage state, as in :meth:`sample` (advanced in place).
        :return: SINR matrix, shape (N, N) or (B, N, N), ``[..., i, j]`` = ``Gamma_{j->i}``.
        """
        return self.sinr_from_draws(positions, self.draw(positions, rng, xi_state))


def link_probability(
    distance: float | np.ndarray, config: SwarmConfig, altitude: float | np.ndarray | None = None
) -> np.ndarray:
    """Closed-form probability that a directed link at 3D distance ``distance`` is active at one step.

    ``P = (1 - p_f) * E_I[ P(|h|^2 >= beta_th (sigma^2 + I) d^alpha / (P L_atm)) ]`` with
    ``P(|h|^2 >= x) = ncx2.sf(2 (K+1) x, df=2, nc=2K)`` (``exp(-x)`` for ``K = 0``) and ``I ~ U(0, I_max)``
    averaged by Gauss-Legendre quadrature with :data:`N_QUADRATURE` nodes (no averaging if ``I_max = 0``).
    Distances below ``min_link_distance`` are raised to it, as in :class:`A2AChannel`.
    ``link_mode="full"`` gives 1, ``"none"`` gives 0 and ``"full_in_range"`` gives 1 up to :func:`usable_link_range`,
    0 beyond. With ``outage_model="gilbert_elliott"`` it is the probability at every step of an episode (the outage
    chain starts and stays in its stationary distribution, whose failure probability is p_f).

    :param distance: 3D distance(s) in metres, scalar or array, ``>= 0`` (``inf`` gives probability 0).
    :param config: the swarm configuration.
    :param altitude: mean altitude of the pair in metres (broadcast with ``distance``); required only when
        ``config.rician_k_altitude_slope != 0``, ignored otherwise.
    :return: probabilities in [0, 1], array of the broadcast shape of ``distance`` and ``altitude`` (0-d for scalars).
    """
    d = np.asarray(distance, dtype=np.float64)
    if np.isnan(d).any() or (d < 0).any():
        raise ValueError(f"distance must be >= 0 metres (not NaN), got {distance!r}")
    if config.rician_k_altitude_slope != 0.0:
        if altitude is None:
            raise ValueError("altitude (mean pair altitude in metres) is required when rician_k_altitude_slope != 0")
        alt = np.asarray(altitude, dtype=np.float64)
        if not np.isfinite(alt).all():
            raise ValueError(f"altitude must be finite, got {altitude!r}")
        d, alt = np.broadcast_arrays(d, alt)
        k = np.asarray(_rician_k(config, alt))
    else:
        k = np.full(d.shape, float(config.rician_k))
    if config.link_mode == "full":
        return np.ones(d.shape)
    if config.link_mode == "none":
        return np.zeros(d.shape)
    if config.link_mode == "full_in_range":
        return (d <= usable_link_range(config)).astype(np.float64)

    from scipy import stats  # lazy: scipy is not needed on the hot path

    d = np.maximum(d, config.min_link_distance)
    with np.errstate(over="ignore"):
        d_alpha = d**config.path_loss_exponent
    if config.interference_max > 0.0:
        nodes, weights = np.polynomial.legendre.leggauss(N_QUADRATURE)
        interference = 0.5 * config.interference_max * (nodes + 1.0)  # nodes mapped from [-1, 1] to [0, I_max]
        weights = 0.5 * weights  # mean over U(0, I_max) = (1/I_max) * integral, weights sum to 1
    else:
        interference = np.zeros(1)
        weights = np.ones(1)
    # Eq. (1) solved for |h|^2: Gamma >= beta_th  <=>  |h|^2 >= x = beta_th (sigma2 + I) d^alpha / (P L_atm)
    x = (
        config.sinr_threshold
        * (config.noise_power + interference)
        / (config.tx_power_mw * config.atmospheric_loss)
        * d_alpha[..., None]
    )
    kq = k[..., None]
    with np.errstate(invalid="ignore", over="ignore"):
        # Rician tail: P(|h|^2 >= x) = ncx2.sf(2(K+1)x, 2, 2K); Rayleigh (K = 0): exp(-x)
        tail = np.where(
            kq > 0.0,
            stats.ncx2.sf(2.0 * (kq + 1.0) * x, 2, 2.0 * np.maximum(kq, 1e-300)),
            np.exp(-x),
        )
    tail = np.where(np.isinf(x), 0.0, tail)
    # xi ~ Bernoulli(1 - p_f) is independent of the fading and interference
    return np.clip((1.0 - config.p_fail) * (tail @ weights), 0.0, 1.0)
