"""The batched core of Sec. II: B swarms stepped at once, every state array with a leading swarm dimension.

:class:`SwarmBatch` holds the state of ``B`` independent swarms of ``N`` UAVs and implements the whole model once, for
the batch: the transition T, the noisy sensing P_o, the map estimate M_hat and the coverage set C, the rewards of
Sec. II-B, the link draws of Eq. (1), the observations, termination and the episode statistics. The PettingZoo
:class:`~sb3_latentswarm.envs.swarm_recon.SwarmReconEnv` is its ``B = 1`` view and the ``"batched"`` backend of
:func:`~sb3_latentswarm.envs.vec_env.make_vec_env` its SB3 ``VecEnv`` view; there is no second implementation
(the model and the spaces are documented in :mod:`sb3_latentswarm.envs.swarm_recon`).

Random streams: swarm ``b`` owns one ``numpy.random.Generator`` (``gymnasium.utils.seeding.np_random(seed)``) and
draws from it, in this order, exactly what a lone swarm draws, so a swarm's episode does not depend on ``B`` or on
its slot in the batch:

* at reset: the obstacle cells (``rng.choice(H*W, num_obstacles, replace=False)``), the start ``(x, y)``
  (:func:`~sb3_latentswarm.envs.start_positions.sample_start_positions`: ``rng.random((1, N, 2))``), the headings
  (``rng.uniform(-pi, pi, N)``), then the sensing and link draws below;
* at each step: the actuation noise (``rng.standard_normal((N, 3))``, if ``actuation_noise_std > 0``), then
* sensing: the reading flips (``rng.random((N, F*F))``, if ``sensor_flip_prob > 0``), then
* links: what the link model draws (:mod:`sb3_latentswarm.links`; the default A2A channel of Eq. (1):
  ``rng.standard_normal((N, N, 2))`` and ``rng.random((N, N + 1))``, :meth:`~sb3_latentswarm.channel.A2AChannel.sample`'s
  order; ``link_mode`` ``"full"``, ``"none"``, ``"full_in_range"``: nothing), then its delays (``rng.random((N, N))``,
  only with drawn delays).

These per-swarm draws are the only loops over swarms; everything else is one array operation for the batch.

State layout (VMAS style: born in ``__init__``, reset in place by :meth:`SwarmBatch.reset` for any subset of swarms):
the grid of every swarm is stored flat with a border of ``r`` cells ("padded"), so every footprint index is valid;
border cells read -1 (outside) in the truth and in M_hat and count as covered (never new). All swarms' padded grids
are rows of one ``(B, pad_size)`` array, so one fancy index reaches every swarm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from sb3_latentswarm.channel import squared_distances
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.observations import (
    ACTOR_OBS_KEYS,
    LINK_AGE_KEY,
    OBS_KEYS,
    PROPRIO_DIM,
    PROPRIO_ENERGY,
    PROPRIO_HEADING,
    PROPRIO_POSITION,
    PROPRIO_VELOCITY,
    STATE_OBS_KEYS,
    obs_keys,
    proprio_normalization,
)
from sb3_latentswarm.envs.start_positions import sample_start_positions
from sb3_latentswarm.links import ALL, Swarms, make_link_model
from sb3_latentswarm.utils.checks import check_int

__all__ = [
    "check_actions",
    "ACTOR_OBS_KEYS",
    "LINK_AGE_KEY",
    "OBS_KEYS",
    "PROPRIO_DIM",
    "STATE_OBS_KEYS",
    "SWARM_ATTRIBUTES",
    "SWARM_METHODS",
    "SwarmBatch",
    "agent_action_space",
    "agent_observation_space",
]

#: Actions may exceed [-1, 1] by this much (float32 rounding) before they are rejected; they are clipped.
ACTION_TOLERANCE = 1e-6
#: Relative tolerance of the energy-depletion test ``b_t <= eps * b_0``.
ENERGY_EPS = 1e-9
#: Coverage share that defines ``steps_to_90``.
COVERAGE_MILESTONE = 0.9
#: Per-swarm state that the views read (each a property of :class:`SwarmBatch` with a leading swarm dimension).
SWARM_ATTRIBUTES = ("coverage", "energy", "positions", "links", "ground_truth", "global_map", "reward_terms")
#: Per-swarm methods of :class:`SwarmBatch` (swarm index first) that the views expose.
SWARM_METHODS = ("swarm_summary", "set_positions")


def agent_observation_space(config: SwarmConfig) -> spaces.Dict:
    """The observation space of one agent (see :mod:`sb3_latentswarm.envs.swarm_recon` for the content of each key)."""
    fw, n = config.footprint_width, config.n_agents
    boxes: dict[str, spaces.Space] = {
        "local_obs": spaces.Box(-1, 1, (fw * fw,), np.int8),
        "proprio": spaces.Box(-np.inf, np.inf, (PROPRIO_DIM,), np.float32),
        "link_row": spaces.Box(0.0, 1.0, (n,), np.float32),
        LINK_AGE_KEY: spaces.Box(0.0, float(config.message_expiry), (n,), np.float32),  # only with delay (opt-in)
        "swarm_proprio": spaces.Box(-np.inf, np.inf, (n, PROPRIO_DIM), np.float32),
        "global_map": spaces.Box(-1, 1, (config.grid_height, config.grid_width), np.int8),
    }
    return spaces.Dict([(key, boxes[key]) for key in obs_keys(config)])  # a sequence keeps this order


def check_actions(actions: Any, shape: tuple[int, ...], layout: str, n_agents: int) -> np.ndarray:
    """The one action check of the three front ends (the batched vec env, the SuperSuit vec env, the PettingZoo env).

    Return ``actions`` as a float64 array of ``shape`` clipped to [-1, 1]. Actions may exceed [-1, 1] by
    :data:`ACTION_TOLERANCE` (float32 rounding); beyond that, or not finite, the error names the agent (``uav_i``, and
    the swarm when there are several).

    :param shape: the expected shape, whose last axis is the 4 action components
    :param layout: what the axes are, for the message (``"one row per slot"``)
    :param n_agents: N, to name the agent and swarm of a flat row (rows are swarm-major, agent-minor)
    :raise TypeError: for actions that are not real numbers (strings, complex numbers, objects)
    :raise ValueError: for another shape, or an action that is not finite or outside [-1, 1]
    """
    array = np.asarray(actions)
    if array.dtype.kind not in "iuf":
        raise TypeError(
            f"actions must be real numbers (a float or int array), got dtype {array.dtype}; complex numbers, strings "
            f"and objects are refused"
        )
    if array.shape != shape:
        raise ValueError(f"actions must have shape {shape} ({layout}), got shape {array.shape}")
    command = np.array(array, dtype=np.float64)
    high, low = command.max(), command.min()  # NaN propagates and fails the test below
    if not (-1.0 - ACTION_TOLERANCE <= low and high <= 1.0 + ACTION_TOLERANCE):
        rows = command.reshape(-1, 4)
        n_swarms = rows.shape[0] // n_agents

        def name(row: int) -> str:
            swarm, agent = divmod(int(row), n_agents)
            return f"agent uav_{agent}" if n_swarms == 1 else f"agent uav_{agent} of swarm {swarm}"

        finite = np.isfinite(rows).all(axis=1)
        if not finite.all():
            row = int(np.flatnonzero(~finite)[0])
            raise ValueError(f"Action of {name(row)} is not finite: {rows[row].tolist()}")
        magnitude = np.abs(rows).max(axis=1)
        row = int(np.argmax(magnitude))
        raise ValueError(
            f"Action of {name(row)} is outside [-1, 1]: {rows[row].tolist()} (max |a| = {magnitude[row]}); actions are "
            f"normalized velocity and yaw-rate commands"
        )
    if high > 1.0 or low < -1.0:
        np.clip(command, -1.0, 1.0, out=command)
    return command


def agent_action_space() -> spaces.Box:
    """The action space of one agent: ``[vx, vy, vz, yaw_rate]`` normalized to [-1, 1]."""
    return spaces.Box(-1.0, 1.0, (4,), np.float32)


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class SwarmBatch:
    """B independent swarms of the reconnaissance task, stepped together (Sec. II for the batch).

    After :meth:`reset` or :meth:`step` the observations of every agent are in :attr:`local_obs` (B, N, F*F) int8,
    :attr:`proprio` (B, N, 8) float32 (``swarm_proprio`` of swarm ``b`` is ``proprio[b]``), :attr:`link_rows`
    (B, N, N) float32 and :attr:`global_map` (B, H, W) int8 (M_hat_t, which changes only when the swarm senses):
    fresh read-only arrays, never modified afterwards, so the views can hand out views of them.

    :param config: the configuration shared by the swarms.
    :param n_swarms: B, the number of swarms.
    """

    def __init__(self, config: SwarmConfig, n_swarms: int) -> None:
        if not isinstance(config, SwarmConfig):
            raise TypeError(f"config must be a SwarmConfig, got {type(config).__name__} ({config!r})")
        check_int("n_swarms", n_swarms, low=1)
        self.config = config
        self.n_swarms = b = int(n_swarms)
        self.n_agents = n = config.n_agents
        width, height, r = config.grid_width, config.grid_height, config.sensor_range
        fw = config.footprint_width
        self.link_model = make_link_model(config, b)

        # Constants of the hot path.
        x_max, y_max = config.arena_size
        self._pos_low = np.array([0.0, 0.0, config.min_altitude])
        self._pos_high = np.array([x_max, y_max, config.max_altitude])
        self._vel_scale = np.array([config.v_max, config.v_max, config.vz_max])
        self._proprio_offset, self._proprio_scale = proprio_normalization(config)  # e_t = (state - offset) * scale
        self._noise_std = config.actuation_noise_std * self._vel_scale
        self._yaw_scale = config.yaw_rate_max * config.dt
        self._body_frame = config.action_frame == "body"
        self._energy_eps = ENERGY_EPS * config.initial_energy
        self._inv_peers = 1.0 / (n - 1) if n > 1 else 0.0
        self._d_safe2 = config.d_safe**2
        self._pairs = np.triu(np.ones((n, n), dtype=bool), 1)  # i < j
        self._milestone = COVERAGE_MILESTONE * config.n_cells
        self._max_cell = np.array([width - 1, height - 1], dtype=np.intp)
        self._inv_cell_size = 1.0 / config.cell_size
        self._flip_prob = config.sensor_flip_prob
        self._n_cells = config.n_cells
        self._footprint_size = fw * fw
        self._pad_width = width + 2 * r
        self._pad_height = height + 2 * r
        self._pad_size = self._pad_width * self._pad_height
        dy, dx = np.divmod(np.arange(fw * fw), fw)
        # Footprint entry (dy, dx), dy, dx in [0, 2r], of the cell (ix, iy) has the padded index
        # (iy + r + dy - r) * W_pad + (ix + r + dx - r) = iy * W_pad + ix + dy * W_pad + dx.
        self._footprint_offsets = dy * self._pad_width + dx  # (F*F,), row-major patch: y outer, x inner
        self._cell_stride = np.array([1, self._pad_width], dtype=np.intp)  # (ix, iy) -> iy * W_pad + ix
        inside = np.zeros((self._pad_height, self._pad_width), dtype=bool)
        inside[r : r + height, r : r + width] = True
        self._inside_flat = np.flatnonzero(inside.ravel())  # padded index of the cell iy * W + ix, (H*W,)
        self._interior = (slice(None), slice(r, r + height), slice(r, r + width))
        self._swarm_offset = np.arange(b, dtype=np.intp) * self._pad_size  # row b of the flat (B * pad_size) grids
        self._every_swarm = list(range(b))
        self._empty_truth = np.where(inside.ravel(), 0, -1).astype(np.int8)  # padded M without obstacles
        self._uncovered = ~inside.ravel()  # padded C at reset (only the border counts as covered)

        # Episode state, (B, ...), allocated once and reset in place.
        self._truth = np.full((b, self._pad_size), -1, dtype=np.int8)  # ground truth M, padded
        self._map = np.full((b, self._pad_size), -1, dtype=np.int8)  # M_hat, padded
        self._covered = np.ones((b, self._pad_size), dtype=bool)  # C, padded (border True)
        # Kinematic state [p (3), v (3), chi, b] of every UAV, so e_t is one affine map of it.
        self.kinematics = np.zeros((b, n, PROPRIO_DIM))  # (B, N, 8)
        self._links = np.zeros((b, n, n), dtype=bool)  # [b, i, j]: receiver i got sender j
        self._link_ages = np.zeros((b, n, n), dtype=np.int16) if self.link_model.has_delay else None  # steps late
        self.footprint = np.zeros((b, n, fw * fw), dtype=np.intp)  # padded index of every sensed cell
        self.t = np.zeros(b, dtype=np.int64)
        self.n_covered = np.zeros(b, dtype=np.int64)
        self.collisions = np.zeros(b, dtype=np.int64)
        self.episode_return = np.zeros(b)
        self.steps_to_90 = np.full(b, -1, dtype=np.int64)  # -1: not reached yet
        self._in_link_sum = np.zeros((b, n), dtype=np.int64)  # live in-links per agent, summed over the link draws
        self._n_dropouts = np.zeros((b, n), dtype=np.int64)  # link draws without a live in-link, per agent
        self._n_link_draws = np.zeros(b, dtype=np.int64)
        self._reward_terms = np.zeros((b, 3))  # unweighted (r_cov, r_red, r_coll) of the last step
        self.dropout = np.zeros((b, n), dtype=bool)  # N_t^i empty at the last link draw
        self.rngs: list[np.random.Generator | None] = [None] * b
        self.seeds: list[int | None] = [None] * b
        self.local_obs = _read_only(np.full((b, n, fw * fw), -1, dtype=np.int8))
        self.proprio = _read_only(np.zeros((b, n, PROPRIO_DIM), dtype=np.float32))
        self.link_rows = _read_only(np.zeros((b, n, n), dtype=np.float32))
        self.link_ages = _read_only(np.zeros((b, n, n), dtype=np.float32)) if self.link_model.has_delay else None
        self.global_map = _read_only(np.full((b, height, width), -1, dtype=np.int8))

    # ------------------------------------------------------------------ per-swarm state (copies)
    @property
    def coverage(self) -> np.ndarray:
        """``|C_t| / |X|`` of every swarm, (B,)."""
        return self.n_covered / self._n_cells

    @property
    def energy(self) -> np.ndarray:
        """b_t = b_0 - kappa t of every swarm (the same for all its UAVs), clamped at 0, (B,)."""
        return np.maximum(self.config.initial_energy - self.config.energy_decay * self.t, 0.0)

    @property
    def positions(self) -> np.ndarray:
        """UAV positions in metres, (B, N, 3) (a copy)."""
        return self.kinematics[:, :, PROPRIO_POSITION].copy()

    @property
    def links(self) -> np.ndarray:
        """The current link matrices, (B, N, N) bool, ``[b, i, j]`` = receiver i got sender j (a copy)."""
        return self._links.copy()

    @property
    def ground_truth(self) -> np.ndarray:
        """The ground-truth occupancy maps M, (B, H, W) indexed [b, iy, ix], 1 = occupied (a copy)."""
        return self._truth.reshape(self.n_swarms, self._pad_height, self._pad_width)[self._interior].copy()

    @property
    def reward_terms(self) -> np.ndarray:
        """Unweighted ``(r_cov, r_red, r_coll)`` of the last step of every swarm, (B, 3) (0 after reset; a copy)."""
        return self._reward_terms.copy()

    def swarm_summary(self, swarm: int) -> dict[str, Any]:
        """Episode statistics of swarm ``swarm`` so far (see :meth:`SwarmReconEnv.swarm_summary`)."""
        draws = max(int(self._n_link_draws[swarm]), 1)
        steps_to_90 = int(self.steps_to_90[swarm])
        return {
            "coverage": float(self.n_covered[swarm] / self._n_cells),
            "collisions": int(self.collisions[swarm]),
            "steps_to_90": None if steps_to_90 < 0 else steps_to_90,
            "length": int(self.t[swarm]),
            "episode_return": float(self.episode_return[swarm]),
            "link_up_rate": float(self._in_link_sum[swarm].mean() * self._inv_peers / draws),
            "dropout_rate": float(self._n_dropouts[swarm].sum() / (draws * self.n_agents)),
        }

    def step_infos(self, terminated: np.ndarray, truncated: np.ndarray) -> list[list[dict[str, Any]]]:
        """The info of every agent of every swarm after :meth:`step` (the one place the views' infos are built).

        :param terminated: (B,) bool, as returned by :meth:`step`.
        :param truncated: (B,) bool, as returned by :meth:`step`.
        :return: ``infos[b][i]`` for agent ``i`` of swarm ``b``: ``coverage`` (``|C| / |X|``), ``collisions`` (so far),
            ``link_up_rate`` (the agent's mean share of live in-links so far), ``dropout`` (N_t^i empty at the last
            link draw); in a finished swarm also ``swarm_summary`` (:meth:`swarm_summary` plus ``truncated``), one
            copy per agent.
        """
        n = self.n_agents
        coverage, collisions = self.coverage.tolist(), self.collisions.tolist()
        rates, dropped = self.link_up_rates().tolist(), self.dropout.tolist()
        infos = [
            [
                {"coverage": coverage[b], "collisions": collisions[b], "link_up_rate": rates[b][i], "dropout": dropped[b][i]}
                for i in range(n)
            ]
            for b in range(self.n_swarms)
        ]
        for swarm in np.flatnonzero(np.asarray(terminated) | np.asarray(truncated)).tolist():
            summary = self.swarm_summary(swarm)
            summary["truncated"] = bool(truncated[swarm])
            for info in infos[swarm]:
                info["swarm_summary"] = dict(summary)
        return infos

    def link_up_rates(self) -> np.ndarray:
        """Mean share of live in-links of every agent over the episode's link draws so far, (B, N)."""
        return self._in_link_sum * (self._inv_peers / np.maximum(self._n_link_draws, 1))[:, None]

    # ------------------------------------------------------------------ reset and step
    def reset(
        self,
        swarms: Sequence[int] | np.ndarray | None = None,
        seeds: Sequence[int | None] | None = None,
        positions: np.ndarray | None = None,
    ) -> None:
        """Start a new episode (Sec. IV) in the given swarms; the others are untouched.

        Obstacles, positions and headings at random, altitude ``initial_altitude``, then the first sensing and link
        draw. A swarm whose RNG does not exist yet, or whose seed is given, gets a fresh
        ``gymnasium.utils.seeding.np_random(seed)``; otherwise its RNG continues.

        :param swarms: indices of the swarms to reset (``None``: all).
        :param seeds: one seed (int or ``None``) per reset swarm, or ``None``.
        :param positions: start positions in metres, (len(swarms), N, 3), instead of random ones (the random ones
            are still drawn, so the RNG advances the same way).
        """
        idx = ALL if swarms is None else np.asarray(swarms, dtype=np.intp).reshape(-1)
        listed = self._listed(idx)
        if seeds is not None and len(seeds) != len(listed):
            raise ValueError(f"seeds must give one seed per reset swarm ({len(listed)}), got {len(seeds)}")
        if positions is not None:
            positions = self.check_positions(positions, len(listed))
        cfg = self.config
        n = self.n_agents
        start = np.empty((len(listed), n, 3))
        heading = np.empty((len(listed), n))
        self._truth[idx] = self._empty_truth
        for k, swarm in enumerate(listed):
            seed = None if seeds is None else seeds[k]
            if seed is not None or self.rngs[swarm] is None:
                self.rngs[swarm], self.seeds[swarm] = seeding.np_random(seed)
            rng = self._rng(swarm)
            obstacles = rng.choice(self._n_cells, size=cfg.num_obstacles, replace=False)
            self._truth[swarm, self._inside_flat[obstacles]] = 1
            start[k] = sample_start_positions(cfg, rng)[0]  # SwarmConfig.start_region
            heading[k] = rng.uniform(-math.pi, math.pi, n)
        self._map[idx] = -1
        self._covered[idx] = self._uncovered
        kinematics = np.zeros((len(listed), n, PROPRIO_DIM))
        kinematics[:, :, PROPRIO_POSITION] = start if positions is None else positions
        kinematics[:, :, PROPRIO_HEADING] = heading
        kinematics[:, :, PROPRIO_ENERGY] = cfg.initial_energy
        self.kinematics[idx] = kinematics

        self.t[idx] = 0
        self.collisions[idx] = 0
        self.episode_return[idx] = 0.0
        self._in_link_sum[idx] = 0
        self._n_dropouts[idx] = 0
        self._n_link_draws[idx] = 0
        self._reward_terms[idx] = 0.0
        self.link_model.reset(idx)  # e.g. the outage chains restart from their stationary distribution

        readings, n_new, _ = self._sense(idx)
        self.n_covered[idx] = n_new
        self.steps_to_90[idx] = np.where(n_new >= self._milestone, 0, -1)
        self._draw_links(idx)
        self._observe(idx, readings)

    def step(self, command: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Apply the joint actions of every swarm, sense, draw the links, and compute the rewards of Sec. II-B.

        :param command: (B, N, 4) float64 actions in [-1, 1] (see :meth:`check_actions`).
        :return: the shared reward (B,) float64, terminated (B,) bool and truncated (B,) bool of every swarm.
        """
        cfg = self.config
        self.t += 1
        kinematics = self.kinematics

        # Transition T: v = command * (v_max, v_max, vz_max) + noise, p += v dt (clipped), chi += yaw dt (wrapped)
        vel = command[:, :, :3] * self._vel_scale  # (B, N, 3)
        if self._body_frame:
            heading = kinematics[:, :, PROPRIO_HEADING]
            cos, sin = np.cos(heading), np.sin(heading)
            forward, lateral = vel[:, :, 0].copy(), vel[:, :, 1].copy()
            vel[:, :, 0] = forward * cos - lateral * sin
            vel[:, :, 1] = forward * sin + lateral * cos
        if cfg.actuation_noise_std > 0.0:
            noise = np.empty(vel.shape)
            for swarm in range(len(self.rngs)):
                self._rng(swarm).standard_normal(out=noise[swarm])
            vel += self._noise_std * noise
        kinematics[:, :, PROPRIO_VELOCITY] = vel
        pos = kinematics[:, :, PROPRIO_POSITION]  # views: updated in place
        pos += vel * cfg.dt
        np.maximum(pos, self._pos_low, out=pos)  # ufuncs: np.clip costs more per call on small arrays
        np.minimum(pos, self._pos_high, out=pos)
        heading = kinematics[:, :, PROPRIO_HEADING]
        heading += command[:, :, 3] * self._yaw_scale
        heading += math.pi  # wrap to [-pi, pi)
        np.remainder(heading, 2.0 * math.pi, out=heading)
        heading -= math.pi
        energy = cfg.initial_energy - cfg.energy_decay * self.t  # b_t = b_0 - kappa t, from t (no accumulated rounding)
        kinematics[:, :, PROPRIO_ENERGY] = np.maximum(energy, 0.0)[:, None]

        readings, n_new, n_redundant = self._sense(ALL)
        # Eq. r_cov: r_cov = |C(M_hat_t)| - |C(M_hat_{t-1})| - c
        r_cov = n_new - cfg.stall_penalty
        self.n_covered += n_new
        # Eq. r_red: r_red = -sum_{i<j} |C_t^i ∩ C_t^j|, C_t^i = cells of UAV i's footprint not in C(M_hat_{t-1})
        r_red = -n_redundant
        # Eq. r_coll: r_coll = -sum_{i<j} 1[||p_t^i - p_t^j|| < d_safe]   (3D distance)
        distances2 = squared_distances(pos)  # (B, N, N), also the channel's d^2
        n_close = ((distances2 < self._d_safe2) & self._pairs).sum(axis=(1, 2))
        r_coll = -n_close.astype(np.float64)
        # Sec. II-B: r_t = w_cov r_cov + w_red r_red + w_coll r_coll, shared by all UAVs of a swarm
        reward = cfg.w_cov * r_cov + cfg.w_red * r_red + cfg.w_coll * r_coll
        self._reward_terms[:, 0] = r_cov
        self._reward_terms[:, 1] = r_red
        self._reward_terms[:, 2] = r_coll
        self.collisions += n_close
        self.episode_return += reward
        reached = (self.n_covered >= self._milestone) & (self.steps_to_90 < 0)
        np.copyto(self.steps_to_90, self.t, where=reached)

        self._draw_links(ALL, distances2)
        self._observe(ALL, readings)

        terminated = (energy <= self._energy_eps) | (self.n_covered == self._n_cells)  # depleted or all covered
        truncated = ~terminated & (self.t >= cfg.max_steps)
        return reward, terminated, truncated

    def set_positions(self, swarm: int, positions: np.ndarray) -> None:
        """Teleport the UAVs of swarm ``swarm`` (scenario and test hook). Its next step moves from there, then senses.

        Nothing is sensed and no link is drawn here; the observations are not updated.

        :param positions: shape (N, 3), metres, inside the arena and the altitude bounds.
        """
        self.kinematics[swarm, :, PROPRIO_POSITION] = self.check_positions(positions)

    # ------------------------------------------------------------------ input checks
    def check_positions(self, positions: Any, n_swarms: int | None = None) -> np.ndarray:
        """Return ``positions`` as float64 (N, 3), or (n_swarms, N, 3) when ``n_swarms`` is given, or raise."""
        pos = np.asarray(positions, dtype=np.float64)
        shape = (self.n_agents, 3) if n_swarms is None else (n_swarms, self.n_agents, 3)
        if pos.shape != shape:
            raise ValueError(f"positions must have shape {shape} (metres), got shape {pos.shape}")
        if not np.isfinite(pos).all():
            raise ValueError(f"positions must be finite, got {pos.tolist()}")
        if (pos < self._pos_low).any() or (pos > self._pos_high).any():
            raise ValueError(
                f"positions must lie in [{self._pos_low.tolist()}, {self._pos_high.tolist()}] (x, y, z in metres), "
                f"got {pos.tolist()}"
            )
        return pos

    def check_actions(self, actions: Any) -> np.ndarray:
        """Return the joint actions as a (B, N, 4) float64 array clipped to [-1, 1], or raise (see :func:`check_actions`)."""
        return check_actions(actions, (self.n_swarms, self.n_agents, 4), "swarms, agents, 4", self.n_agents)

    # ------------------------------------------------------------------ internals
    def _rng(self, swarm: int) -> np.random.Generator:
        """Swarm ``swarm``'s generator (made at its first reset)."""
        rng = self.rngs[swarm]
        if rng is None:
            raise RuntimeError(f"swarm {swarm} has not been reset: call reset before stepping")
        return rng

    def _listed(self, idx: Swarms) -> list[int]:
        return self._every_swarm if isinstance(idx, slice) else idx.tolist()

    def _sense(self, idx: Swarms) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sense at the current positions of swarms ``idx`` and update their M_hat and C.

        :return: the readings (K, N, F*F) int8, the number of newly covered cells (K,) and
            sum_{i<j} |C^i ∩ C^j| over them (K,), K = the number of swarms in ``idx``.
        """
        cell = (self.kinematics[idx, :, :2] * self._inv_cell_size).astype(np.intp)  # floor: positions are >= 0
        np.minimum(cell, self._max_cell, out=cell)
        center = cell @ self._cell_stride  # iy * W_pad + ix, (K, N)
        footprint = center[:, :, None] + self._footprint_offsets  # (K, N, F*F) padded indices
        self.footprint[idx] = footprint
        flat = footprint + self._swarm_offset[idx][:, None, None]  # indices into the flat (B * pad_size) grids
        readings = self._truth.reshape(-1)[flat]  # -1 outside the arena
        if self._flip_prob > 0.0:
            # Noisy P_o: each reading inside the arena is flipped with probability sensor_flip_prob
            draws = np.empty(readings.shape)
            for k, swarm in enumerate(self._listed(idx)):
                self._rng(swarm).random(out=draws[k])
            readings ^= draws < self._flip_prob
            np.maximum(readings, -1, out=readings)  # a flipped outside reading (-1 ^ 1 = -2) stays -1
        covered = self._covered.reshape(-1)
        fresh = flat[~covered[flat]]  # one entry per (new cell, observer)
        self._map.reshape(-1)[flat] = readings  # latest reading wins (the higher agent index)
        n_swarms = self.n_swarms
        if fresh.size == 0:
            zeros = np.zeros(len(readings), dtype=np.int64)
            return readings, zeros, zeros.astype(np.float64)
        fresh.sort()
        # rank of each entry among the observers of its cell: 0, 1, ..., k - 1 (they sum to k (k - 1) / 2 pairs)
        rank = np.arange(fresh.size) - np.searchsorted(fresh, fresh)
        new_cells = fresh[rank == 0]
        covered[new_cells] = True
        n_new = np.bincount(new_cells // self._pad_size, minlength=n_swarms)[idx]
        n_redundant = np.bincount(fresh // self._pad_size, weights=rank, minlength=n_swarms)[idx]
        return readings, n_new, n_redundant

    def _draw_links(self, idx: Swarms, distances2: np.ndarray | None = None) -> None:
        """Draw the link matrices of swarms ``idx`` at their current positions and update the link statistics.

        :param distances2: their squared pairwise distances, if computed already.
        """
        pos = self.kinematics[idx, :, PROPRIO_POSITION]
        rngs = [self._rng(swarm) for swarm in self._listed(idx)]
        links, ages = self.link_model.step(idx, rngs, pos, distances2)
        self._links[idx] = links
        if self._link_ages is not None and ages is not None:
            self._link_ages[idx] = ages
        n_in = links.sum(axis=2)  # live in-links per receiver, |N_t^i|
        dropout = n_in == 0  # N_t^i empty
        self.dropout[idx] = dropout
        self._in_link_sum[idx] += n_in
        self._n_link_draws[idx] += 1
        self._n_dropouts[idx] += dropout

    def _observe(self, idx: Swarms, readings: np.ndarray) -> None:
        """Write the observations of swarms ``idx`` into fresh arrays (earlier ones stay as they were handed out)."""
        # e_t = [x/X, y/Y, (z - z_min)/(z_max - z_min), vx/v_max, vy/v_max, vz/vz_max, chi/pi, b/b_0]
        kinematics = self.kinematics[idx]
        proprio = np.empty(kinematics.shape, dtype=np.float32)
        np.multiply(kinematics - self._proprio_offset, self._proprio_scale, out=proprio)
        link_rows = self._links[idx].astype(np.float32)
        global_map = self._map.reshape(self.n_swarms, self._pad_height, self._pad_width)[idx][self._interior]
        fresh = {"local_obs": readings, "proprio": proprio, "link_rows": link_rows, "global_map": global_map}
        if self._link_ages is not None:
            fresh["link_ages"] = self._link_ages[idx].astype(np.float32)
        for name, rows in fresh.items():
            if isinstance(idx, slice):  # every swarm: the new arrays replace the old ones
                array = np.ascontiguousarray(rows)  # copies the (strided) map interior only
            else:  # some swarms: a copy of the old array with their rows replaced
                array = getattr(self, name).copy()
                array[idx] = rows
            setattr(self, name, _read_only(array))
