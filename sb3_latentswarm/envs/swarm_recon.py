"""Cooperative UAV reconnaissance under intermittent A2A links: the Dec-POMDP of Sec. II as a PettingZoo ``ParallelEnv``.

====================  =====================================================================================================
Import                ``from sb3_latentswarm.envs import swarm_recon_v0`` (``swarm_recon_v0.parallel_env(...)``)
Agents                ``possible_agents = ["uav_0", ..., "uav_{N-1}"]`` (N = ``SwarmConfig.n_agents``, paper: 3)
Parallel API          yes; all agents start, terminate and truncate together (no agent is removed alone)
Action space          ``Box(-1, 1, (4,), float32)``: ``[vx, vy, vz, yaw_rate]`` scaled by ``(v_max, v_max, vz_max,
                      yaw_rate_max)``; with ``action_frame="body"`` ``(vx, vy)`` are (forward, lateral), rotated by chi
Observation space     ``Dict`` with the keys below (F = 2 * sensor_range + 1, H x W = grid_height x grid_width)
Reward                shared by all agents, Sec. II-B: ``r = w_cov r_cov + w_red r_red + w_coll r_coll``
Termination           all agents, when the energy ``b_t = b_0 - kappa t`` is depleted or every cell has been observed
Truncation            all agents, at ``t >= max_steps`` without termination
Info keys             after each step: ``coverage``, ``collisions``, ``link_up_rate``, ``dropout``; ``swarm_summary``
                      at the last step (see :meth:`SwarmReconEnv.swarm_summary`); empty at reset
====================  =====================================================================================================

Observation of agent ``i`` (a ``gymnasium.spaces.Dict``; the actor uses the first three keys only):

=================  ================================  ================================================================
key                space                             content
=================  ================================  ================================================================
``local_obs``      ``Box(-1, 1, (F*F,), int8)``      o_t^i: the sensed F x F patch around the UAV's cell, row-major
                                                     (rows = y, ascending), noisy readings as sensed: 1 occupied,
                                                     0 free, -1 outside the arena
``proprio``        ``Box(-inf, inf, (8,), f32)``     e_t^i = [x/X, y/Y, (z - z_min)/(z_max - z_min), vx/v_max,
                                                     vy/v_max, vz/vz_max, chi/pi, b/b_0] (X, Y = arena size in
                                                     metres; a term whose scale is 0 is 0)
``link_row``       ``Box(0, 1, (N,), f32)``          row i of the link matrix: 1.0 where the message of UAV j
                                                     reached UAV i at this step (j in N_t^i); own entry 0
``swarm_proprio``  ``Box(-inf, inf, (N, 8), f32)``   {e_t^j}: every agent's proprio, in agent order (global state)
``global_map``     ``Box(-1, 1, (H, W), int8)``      M_hat_t indexed [iy, ix]: -1 unknown, 0 free, 1 occupied
                                                     (global state; target of the map-reconstruction loss)
=================  ================================  ================================================================

The last two keys are the global state ``s_t = ({e_t^i}, M_hat_t)`` of Sec. II, for the centralized critic only;
:meth:`SwarmReconEnv.state` returns it as one flat float32 vector.

Model (units: metres, seconds of ``dt``; the arena is ``[0, X] x [0, Y]`` with ``X = grid_width * cell_size``):

* Transition T (stochastic): ``v = command + N(0, (actuation_noise_std * (v_max, v_max, vz_max))^2)``,
  ``p += v dt`` with ``(x, y)`` clipped to the arena and ``z`` to ``[min_altitude, max_altitude]``;
  ``chi += yaw_command dt`` wrapped to ``[-pi, pi)``; the body-frame rotation uses the heading before the update.
  ``proprio`` reports this actuated velocity ``v`` (also while a clipped axis does not move).
* Sensing P_o: each UAV reads the ``(2r+1) x (2r+1)`` cells around its cell ``(floor(x / cell_size),
  floor(y / cell_size))``; each reading is flipped with probability ``sensor_flip_prob``. ``M_hat`` keeps the latest
  reading of every sensed cell (two UAVs reading one cell at one step: the higher agent index wins); the coverage set
  C is the set of cells observed at least once. Sensing happens at reset and after every move.
* Links: drawn from :class:`~sb3_latentswarm.channel.A2AChannel` at the reset positions and after every move.
* Step counting: ``reset`` is t = 0, the k-th ``step`` is t = k. An episode already fully covered at reset ends
  (``terminated``) at its first step.

Scenario hooks (documented for tests and examples): ``reset(options={"positions": p})`` starts the UAVs at ``p``
(shape (N, 3), metres) instead of random positions; :meth:`SwarmReconEnv.set_positions` teleports them
mid-episode (the next ``step`` moves from there and senses); :attr:`SwarmReconEnv.reward_terms` holds the
unweighted ``(r_cov, r_red, r_coll)`` of the last step. Other ``options`` keys are ignored.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from sb3_latentswarm.channel import A2AChannel
from sb3_latentswarm.config import SwarmConfig

__all__ = ["SwarmReconEnv", "parallel_env", "OBS_KEYS", "ACTOR_OBS_KEYS", "STATE_OBS_KEYS", "PROPRIO_DIM"]

#: Observation keys, in the order of the ``Dict`` space.
OBS_KEYS = ("local_obs", "proprio", "link_row", "swarm_proprio", "global_map")
#: Keys an actor may use at execution time (decentralized).
ACTOR_OBS_KEYS = ("local_obs", "proprio", "link_row")
#: Keys that form the global state s_t (centralized critic and map loss only).
STATE_OBS_KEYS = ("swarm_proprio", "global_map")
#: Length of the proprioceptive vector e_t.
PROPRIO_DIM = 8
#: Actions may exceed [-1, 1] by this much (float32 rounding) before they are rejected; they are clipped.
ACTION_TOLERANCE = 1e-6
#: Relative tolerance of the energy-depletion test ``b_t <= eps * b_0``.
ENERGY_EPS = 1e-9
#: Coverage share that defines ``steps_to_90``.
COVERAGE_MILESTONE = 0.9


class SwarmReconEnv(ParallelEnv):
    """N UAVs map a ``grid_width x grid_height`` grid with noisy local sensors and intermittent links (Sec. II, IV).

    See the module docstring for the spaces, the reward and the dynamics.

    :param config: the configuration; ``SwarmConfig()`` (the paper's settings) if ``None``.
    :param render_mode: ``None``, ``"rgb_array"`` (``render()`` returns an ``(H, W, 3)`` uint8 image) or ``"human"``
        (matplotlib window).
    :param overrides: ``SwarmConfig`` fields replacing those of ``config``, e.g. ``SwarmReconEnv(n_agents=5)``;
        unknown names raise ``TypeError``.
    """

    metadata = {"name": "swarm_recon_v0", "render_modes": ["human", "rgb_array"], "render_fps": 10, "is_parallelizable": True}

    def __init__(self, config: SwarmConfig | None = None, render_mode: str | None = None, **overrides: Any) -> None:
        if config is None:
            config = SwarmConfig()
        elif not isinstance(config, SwarmConfig):
            raise TypeError(f"config must be a SwarmConfig or None, got {type(config).__name__} ({config!r})")
        if overrides:
            config = config.replace(**overrides)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.config = config
        self.render_mode = render_mode
        self.n_agents = n = config.n_agents
        self.possible_agents = [f"uav_{i}" for i in range(n)]
        self.agents: list[str] = []

        width, height, r = config.grid_width, config.grid_height, config.sensor_range
        fw = config.footprint_width
        self.arena_size = config.arena_size
        self.action_spaces = {a: spaces.Box(-1.0, 1.0, (4,), np.float32) for a in self.possible_agents}
        self.observation_spaces = {
            a: spaces.Dict(  # a sequence keeps the keys in OBS_KEYS order (a plain dict would be sorted)
                [
                    ("local_obs", spaces.Box(-1, 1, (fw * fw,), np.int8)),
                    ("proprio", spaces.Box(-np.inf, np.inf, (PROPRIO_DIM,), np.float32)),
                    ("link_row", spaces.Box(0.0, 1.0, (n,), np.float32)),
                    ("swarm_proprio", spaces.Box(-np.inf, np.inf, (n, PROPRIO_DIM), np.float32)),
                    ("global_map", spaces.Box(-1, 1, (height, width), np.int8)),
                ]
            )
            for a in self.possible_agents
        }
        self.state_space = spaces.Box(-np.inf, np.inf, (n * PROPRIO_DIM + height * width,), np.float32)
        self._channel = A2AChannel(config)

        # Constants of the hot path.
        x_max, y_max = self.arena_size
        self._pos_low = np.array([0.0, 0.0, config.min_altitude])
        self._pos_high = np.array([x_max, y_max, config.max_altitude])
        self._vel_scale = np.array([config.v_max, config.v_max, config.vz_max])
        # e_t = (kinematic state - offset) * scale, with scale 0 where the range is 0 (z_max = z_min, vz_max = 0)
        ranges = np.concatenate([self._pos_high - self._pos_low, self._vel_scale, [math.pi, config.initial_energy]])
        self._proprio_scale = np.divide(1.0, ranges, out=np.zeros(PROPRIO_DIM), where=ranges > 0)
        self._proprio_offset = np.zeros(PROPRIO_DIM)
        self._proprio_offset[2] = config.min_altitude
        self._noise_std = config.actuation_noise_std * self._vel_scale
        self._yaw_scale = config.yaw_rate_max * config.dt
        self._body_frame = config.action_frame == "body"
        self._energy_eps = ENERGY_EPS * config.initial_energy
        self._inv_peers = 1.0 / (n - 1) if n > 1 else 0.0
        self._d_safe2 = config.d_safe**2
        self._pair_i, self._pair_j = np.triu_indices(n, 1)
        self._max_cell = np.array([width - 1, height - 1], dtype=np.intp)
        self._inv_cell_size = 1.0 / config.cell_size
        self._flip_prob = config.sensor_flip_prob
        self._entry_index = np.arange(n * fw * fw)
        self._n_cells = config.n_cells
        # The grid is stored flat with a border of r cells ("padded"), so every footprint index is valid:
        # border cells read -1 (outside) in the truth and in M_hat, and count as covered (never new).
        self._pad_width = width + 2 * r
        pad_height = height + 2 * r
        self._pad_size = self._pad_width * pad_height
        dy, dx = np.divmod(np.arange(fw * fw), fw)
        # Footprint entry (dy, dx), dy, dx in [0, 2r], of the cell (ix, iy) has the padded index
        # (iy + r + dy - r) * W_pad + (ix + r + dx - r) = iy * W_pad + ix + dy * W_pad + dx.
        self._footprint_offsets = dy * self._pad_width + dx  # (F*F,), row-major patch: y outer, x inner
        self._cell_stride = np.array([1, self._pad_width], dtype=np.intp)  # (ix, iy) -> iy * W_pad + ix
        inside = np.zeros((pad_height, self._pad_width), dtype=bool)
        inside[r : r + height, r : r + width] = True
        self._inside_flat = np.flatnonzero(inside.ravel())  # padded index of the cell iy * W + ix, (H*W,)
        self._interior = (slice(r, r + height), slice(r, r + width))

        # Episode state (allocated once, filled by reset).
        self._truth = np.full(self._pad_size, -1, dtype=np.int8)  # ground truth M, padded
        self._map = np.full(self._pad_size, -1, dtype=np.int8)  # M_hat, padded
        self._covered = np.ones(self._pad_size, dtype=bool)  # C, padded (border True)
        # Kinematic state [p (3), v (3), chi, b] of every UAV in one (N, 8) array, so e_t is one affine map of it.
        self._kinematics = np.zeros((n, PROPRIO_DIM))
        self._bind_views()  # views into the arrays above (rebound after unpickling)
        self._links = np.zeros((n, n), dtype=bool)
        self._footprint = np.zeros((n, fw * fw), dtype=np.intp)
        self._t = 0
        self._n_covered = 0
        self._collisions = 0
        self._episode_return = 0.0
        self._steps_to_90: int | None = None
        self._in_link_sum = np.zeros(n, dtype=np.int64)  # live in-links per agent, summed over the link draws
        self._n_dropouts = np.zeros(n, dtype=np.int64)  # link draws without a live in-link, per agent
        self._n_link_draws = 0
        self._last_obs: dict[str, dict[str, np.ndarray]] = {}
        self.reward_terms: tuple[float, float, float] = (0.0, 0.0, 0.0)
        """Unweighted ``(r_cov, r_red, r_coll)`` of the last step (0 after reset)."""
        self.np_random: np.random.Generator | None = None
        self.np_random_seed: int | None = None
        self._figure: Any = None
        self._image: Any = None

    # ------------------------------------------------------------------ PettingZoo API
    def observation_space(self, agent: str) -> spaces.Dict:
        """The (cached) observation space of ``agent``."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        """The (cached) action space of ``agent``."""
        return self.action_spaces[agent]

    @property
    def coverage(self) -> float:
        """``|C_t| / |X|``, the share of cells observed at least once."""
        return self._n_covered / self._n_cells

    @property
    def energy(self) -> float:
        """b_t = b_0 - kappa t (the same for every UAV), clamped at 0."""
        return max(self.config.initial_energy - self.config.energy_decay * self._t, 0.0)

    @property
    def positions(self) -> np.ndarray:
        """A copy of the UAV positions in metres, shape (N, 3)."""
        return self._pos.copy()

    @property
    def links(self) -> np.ndarray:
        """A copy of the current link matrix, shape (N, N), ``[i, j]`` = receiver i got sender j."""
        return self._links.copy()

    @property
    def ground_truth(self) -> np.ndarray:
        """A copy of the ground-truth occupancy map M, shape (H, W) indexed [iy, ix], 1 = occupied."""
        return self._truth_view.copy()

    @property
    def global_map(self) -> np.ndarray:
        """A copy of M_hat_t, shape (H, W) indexed [iy, ix]: -1 unknown, 0 free, 1 occupied."""
        return self._map_view.copy()

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, dict[str, Any]]]:
        """Start an episode (Sec. IV): obstacles, positions and headings at random, altitude ``initial_altitude``.

        :param seed: seeds the episode RNG (``gymnasium.utils.seeding.np_random``); ``None`` keeps the current RNG
            (a fresh random one at the first reset).
        :param options: ``{"positions": array (N, 3) in metres}`` fixes the start positions; other keys are ignored.
        :return: observations and infos per agent (the infos are empty dicts at reset; the current coverage is
            :attr:`coverage`).
        """
        if seed is not None or self.np_random is None:
            self.np_random, self.np_random_seed = seeding.np_random(seed)
        rng = self.np_random
        cfg = self.config
        n = self.n_agents

        self._truth[self._inside_flat] = 0
        obstacles = rng.choice(self._n_cells, size=cfg.num_obstacles, replace=False)
        self._truth[self._inside_flat[obstacles]] = 1
        self._map.fill(-1)
        self._covered.fill(True)
        self._covered[self._inside_flat] = False

        x_max, y_max = self.arena_size
        xy = rng.random((n, 2)) * (x_max, y_max)
        heading = rng.uniform(-math.pi, math.pi, n)
        positions = None if options is None else options.get("positions")
        if positions is None:
            self._pos[:, :2] = xy
            self._pos[:, 2] = cfg.initial_altitude
        else:
            self._pos[:] = self._check_positions(positions)
        self._vel.fill(0.0)
        self._heading[:] = heading
        self._energy[:] = cfg.initial_energy

        self.agents = list(self.possible_agents)
        self._t = 0
        self._n_covered = 0
        self._collisions = 0
        self._episode_return = 0.0
        self._steps_to_90 = None
        self._in_link_sum.fill(0)
        self._n_link_draws = 0
        self._n_dropouts.fill(0)
        self.reward_terms = (0.0, 0.0, 0.0)

        readings, new_cells, _ = self._sense()
        self._n_covered = new_cells.size
        if self._n_covered >= COVERAGE_MILESTONE * self._n_cells:
            self._steps_to_90 = 0
        link_rows, _ = self._draw_links()
        obs = self._observations(readings, link_rows)
        # Empty reset infos: SuperSuit merges the reset infos of the next episode into the last step's infos, which
        # would overwrite the final coverage / collisions / link statistics of the finished episode.
        return obs, {agent: {} for agent in self.agents}

    def step(
        self, actions: dict[str, np.ndarray]
    ) -> tuple[
        dict[str, dict[str, np.ndarray]],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """Apply the joint action, sense, draw the links, and return the shared reward of Sec. II-B.

        :param actions: one action per live agent, each of shape (4,) in [-1, 1].
        :return: observations, rewards, terminations, truncations, infos (PettingZoo parallel API).
        """
        agents = self.agents
        if not agents:
            raise RuntimeError("step() called without a running episode: call reset() first (the episode has ended)")
        command = self._check_actions(actions)
        cfg = self.config
        rng = self.np_random
        self._t += 1

        # Transition T: v = command * (v_max, v_max, vz_max) + noise, p += v dt (clipped), chi += yaw dt (wrapped)
        vel = self._vel
        np.multiply(command[:, :3], self._vel_scale, out=vel)
        if self._body_frame:
            cos, sin = np.cos(self._heading), np.sin(self._heading)
            forward, lateral = vel[:, 0].copy(), vel[:, 1].copy()
            vel[:, 0] = forward * cos - lateral * sin
            vel[:, 1] = forward * sin + lateral * cos
        if cfg.actuation_noise_std > 0.0:
            vel += self._noise_std * rng.standard_normal((self.n_agents, 3))
        pos = self._pos
        pos += vel * cfg.dt
        np.maximum(pos, self._pos_low, out=pos)  # ufuncs: np.clip costs 5x more per call on tiny arrays
        np.minimum(pos, self._pos_high, out=pos)
        heading = self._heading
        heading += command[:, 3] * self._yaw_scale
        heading += math.pi  # wrap to [-pi, pi)
        np.remainder(heading, 2.0 * math.pi, out=heading)
        heading -= math.pi
        self._energy.fill(self.energy)  # b_t = b_0 - kappa t, from t (no accumulated rounding)

        readings, new_cells, n_redundant = self._sense()
        # Eq. r_cov: r_cov = |C(M_hat_t)| - |C(M_hat_{t-1})| - c
        r_cov = new_cells.size - cfg.stall_penalty
        self._n_covered += new_cells.size
        # Eq. r_red: r_red = -sum_{i<j} |C_t^i ∩ C_t^j|, C_t^i = cells of UAV i's footprint not in C(M_hat_{t-1})
        r_red = -float(n_redundant)
        # Eq. r_coll: r_coll = -sum_{i<j} 1[||p_t^i - p_t^j|| < d_safe]   (3D distance)
        diff = pos[self._pair_i] - pos[self._pair_j]
        n_close = int(np.count_nonzero(np.einsum("ij,ij->i", diff, diff) < self._d_safe2))
        r_coll = -float(n_close)
        # Sec. II-B: r_t = w_cov r_cov + w_red r_red + w_coll r_coll, shared by all UAVs
        reward = cfg.w_cov * r_cov + cfg.w_red * r_red + cfg.w_coll * r_coll
        self.reward_terms = (float(r_cov), r_red, r_coll)
        self._collisions += n_close
        self._episode_return += reward
        if self._steps_to_90 is None and self._n_covered >= COVERAGE_MILESTONE * self._n_cells:
            self._steps_to_90 = self._t

        link_rows, dropout = self._draw_links()
        obs = self._observations(readings, link_rows)
        infos = self._infos(dropout)

        depleted = cfg.initial_energy - cfg.energy_decay * self._t <= self._energy_eps
        terminated = depleted or self._n_covered == self._n_cells
        truncated = not terminated and self._t >= cfg.max_steps
        if terminated or truncated:
            summary = self.swarm_summary()
            summary["truncated"] = truncated
            for info in infos.values():
                info["swarm_summary"] = dict(summary)
            self.agents = []
        return (
            obs,
            dict.fromkeys(agents, reward),
            dict.fromkeys(agents, terminated),
            dict.fromkeys(agents, truncated),
            infos,
        )

    def state(self) -> np.ndarray:
        """The global state s_t = ({e_t^i}, M_hat_t) as one float32 vector of length N * 8 + H * W."""
        if not self._last_obs:
            raise RuntimeError("state() called before reset()")
        first = self._last_obs[self.possible_agents[0]]
        return np.concatenate([first["swarm_proprio"].ravel(), first["global_map"].ravel()]).astype(np.float32)

    def swarm_summary(self) -> dict[str, Any]:
        """Episode statistics so far (the ``swarm_summary`` info of the last step, which adds ``truncated``).

        Keys: ``coverage`` (``|C| / |X|``), ``collisions`` (pairs closer than ``d_safe``, summed over the steps),
        ``steps_to_90`` (first step t with coverage >= 0.9, ``None`` if never), ``length`` (steps), ``episode_return``
        (sum of the shared reward), ``link_up_rate`` (mean over agents and link draws of the share of live in-links),
        ``dropout_rate`` (share of agent-draws with no live in-link). The link statistics count every link draw of
        the episode: the one at reset and one per step.
        """
        draws = max(self._n_link_draws, 1)
        return {
            "coverage": self.coverage,
            "collisions": self._collisions,
            "steps_to_90": self._steps_to_90,
            "length": self._t,
            "episode_return": self._episode_return,
            "link_up_rate": float(self._in_link_sum.mean() * self._inv_peers / draws),
            "dropout_rate": float(self._n_dropouts.sum() / (draws * self.n_agents)),
        }

    def set_positions(self, positions: np.ndarray) -> None:
        """Teleport the UAVs (scenario and test hook). The next ``step`` moves from there, then senses.

        Nothing is sensed and no link is drawn here; the observation of the last step is not updated.

        :param positions: shape (N, 3), metres, inside the arena and the altitude bounds.
        """
        if not self.agents:
            raise RuntimeError("set_positions() needs a running episode: call reset() first")
        self._pos[:] = self._check_positions(positions)

    # ------------------------------------------------------------------ internals
    _VIEWS = ("_pos", "_vel", "_heading", "_energy", "_map_view", "_truth_view")

    def _bind_views(self) -> None:
        self._pos = self._kinematics[:, 0:3]  # (N, 3) metres
        self._vel = self._kinematics[:, 3:6]  # (N, 3) m/s
        self._heading = self._kinematics[:, 6]  # (N,) rad
        self._energy = self._kinematics[:, 7]  # (N,)
        self._map_view = self._map.reshape(-1, self._pad_width)[self._interior]  # M_hat, (H, W) [iy, ix]
        self._truth_view = self._truth.reshape(-1, self._pad_width)[self._interior]  # M, (H, W) [iy, ix]

    def __getstate__(self) -> dict[str, Any]:
        # Pickling (SuperSuit copies the env with cloudpickle) would turn the views into independent arrays.
        state = {k: v for k, v in self.__dict__.items() if k not in self._VIEWS}
        state["_figure"] = state["_image"] = None  # a matplotlib window does not travel
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._bind_views()

    def _check_positions(self, positions: Any) -> np.ndarray:
        pos = np.asarray(positions, dtype=np.float64)
        if pos.shape != (self.n_agents, 3):
            raise ValueError(f"positions must have shape ({self.n_agents}, 3) (metres), got shape {pos.shape}")
        if not np.isfinite(pos).all():
            raise ValueError(f"positions must be finite, got {pos.tolist()}")
        if (pos < self._pos_low).any() or (pos > self._pos_high).any():
            raise ValueError(
                f"positions must lie in [{self._pos_low.tolist()}, {self._pos_high.tolist()}] (x, y, z in metres), "
                f"got {pos.tolist()}"
            )
        return pos

    def _check_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """Stack the joint action into an (N, 4) float64 array, or raise ``ValueError`` naming the agent."""
        agents = self.agents
        if not isinstance(actions, Mapping):
            raise TypeError(
                f"actions must be a dict {{agent: action}} (PettingZoo's parallel API) for the agents {agents}, got "
                f"{type(actions).__name__}; for an array of shape (N, 4), pass dict(zip(env.agents, actions))"
            )
        try:
            command = np.array([actions[agent] for agent in agents], dtype=np.float64)
        except KeyError:
            missing = [agent for agent in agents if agent not in actions]
            raise ValueError(f"Missing actions for agent(s) {missing}; every live agent needs one: {agents}") from None
        except (TypeError, ValueError) as error:
            shapes = {agent: np.shape(actions[agent]) for agent in agents}
            raise ValueError(f"Every action must be a sequence of 4 numbers, got shapes {shapes}") from error
        if len(actions) != len(agents):
            unknown = sorted(set(actions) - set(agents))
            raise ValueError(f"Actions given for unknown or finished agent(s) {unknown}; live agents: {agents}")
        if command.shape != (len(agents), 4):
            shapes = {agent: np.shape(actions[agent]) for agent in agents}
            raise ValueError(f"Every action must have shape (4,), got shapes {shapes}")
        high, low = command.max(), command.min()  # NaN propagates and fails the test below
        if not (-1.0 - ACTION_TOLERANCE <= low and high <= 1.0 + ACTION_TOLERANCE):
            finite = np.isfinite(command).all(axis=1)
            if not finite.all():
                i = int(np.argmin(finite))
                raise ValueError(f"Action of agent {agents[i]} is not finite: {command[i].tolist()}")
            i = int(np.argmax(np.abs(command).max(axis=1)))
            raise ValueError(
                f"Action of agent {agents[i]} is outside [-1, 1]: {command[i].tolist()} "
                f"(max |a| = {np.abs(command[i]).max()}); actions are normalized velocity and yaw-rate commands"
            )
        if high > 1.0 or low < -1.0:
            np.maximum(command, -1.0, out=command)
            np.minimum(command, 1.0, out=command)
        return command

    def _sense(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Sense at the current positions and update M_hat and C.

        :return: the readings (N, F*F) int8 (read-only), the padded indices of the newly covered cells, and
            sum_{i<j} |C^i ∩ C^j| over them.
        """
        cell = (self._pos[:, :2] * self._inv_cell_size).astype(np.intp)  # floor: positions are >= 0
        np.minimum(cell, self._max_cell, out=cell)
        center = cell @ self._cell_stride  # iy * W_pad + ix
        footprint = np.add(center[:, None], self._footprint_offsets, out=self._footprint)  # (N, F*F) padded indices
        readings = self._truth[footprint]  # -1 outside the arena
        if self._flip_prob > 0.0:
            # Noisy P_o: each reading inside the arena is flipped with probability sensor_flip_prob
            readings ^= self.np_random.random(readings.shape) < self._flip_prob
            np.maximum(readings, -1, out=readings)  # a flipped outside reading (-1 ^ 1 = -2) stays -1
        fresh = footprint[~self._covered[footprint]]  # one entry per (new cell, observer)
        self._map[footprint] = readings  # latest reading wins
        if fresh.size == 0:
            new_cells = fresh
            n_redundant = 0
        else:
            fresh.sort()
            # rank of each entry among the observers of its cell: 0, 1, ..., k - 1 (they sum to k (k - 1) / 2 pairs)
            rank = self._entry_index[: fresh.size] - np.searchsorted(fresh, fresh)
            new_cells = fresh[rank == 0]
            n_redundant = int(rank.sum())
            self._covered[new_cells] = True
        readings.flags.writeable = False
        return readings, new_cells, n_redundant

    def _draw_links(self) -> tuple[np.ndarray, np.ndarray]:
        """Draw the link matrix at the current positions and update the link statistics.

        :return: the link matrix as float32 (N, N), read-only, and the dropout flags (N,) bool.
        """
        links = self._channel.sample(self._pos, self.np_random)
        self._links = links
        n_in = links.sum(axis=1)  # live in-links per receiver, |N_t^i|
        dropout = n_in == 0  # N_t^i empty
        self._in_link_sum += n_in
        self._n_link_draws += 1
        self._n_dropouts += dropout
        link_rows = links.astype(np.float32)
        link_rows.flags.writeable = False
        return link_rows, dropout

    def _proprio(self) -> np.ndarray:
        """e_t of every agent, (N, 8) float32, read-only."""
        e = np.empty((self.n_agents, PROPRIO_DIM), dtype=np.float32)
        # e_t = [x/X, y/Y, (z - z_min)/(z_max - z_min), vx/v_max, vy/v_max, vz/vz_max, chi/pi, b/b_0]
        np.multiply(self._kinematics - self._proprio_offset, self._proprio_scale, out=e)
        e.flags.writeable = False
        return e

    def _observations(self, readings: np.ndarray, link_rows: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
        # Fresh read-only arrays each step; agents share views of them, nothing handed out is mutated later.
        e = self._proprio()
        global_map = self._map_view.copy()
        global_map.flags.writeable = False
        obs = {
            agent: {
                "local_obs": readings[i],
                "proprio": e[i],
                "link_row": link_rows[i],
                "swarm_proprio": e,
                "global_map": global_map,
            }
            for i, agent in enumerate(self.possible_agents)
        }
        self._last_obs = obs
        return obs

    def _infos(self, dropout: np.ndarray) -> dict[str, dict[str, Any]]:
        coverage = self.coverage
        collisions = self._collisions
        rates = (self._in_link_sum * (self._inv_peers / self._n_link_draws)).tolist()  # mean share of up in-links
        dropped = dropout.tolist()
        return {
            agent: {"coverage": coverage, "collisions": collisions, "link_up_rate": rates[i], "dropout": dropped[i]}
            for i, agent in enumerate(self.possible_agents)
        }

    # ------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        """Render the swarm: ``"rgb_array"`` returns an (H, W, 3) uint8 image, ``"human"`` draws it with matplotlib.

        Colours: unknown cells grey, free cells white, occupied cells black, true obstacles not yet found dark red,
        the current footprints tinted in the UAV's colour; UAVs as squares; live links as lines (green both ways,
        yellow one way); the bar on top shows the coverage.
        """
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if not self._last_obs:
            raise RuntimeError("render() called before reset()")
        frame = self._render_frame()
        if self.render_mode == "rgb_array":
            return frame
        import matplotlib.pyplot as plt  # lazy: matplotlib is only needed to display

        if self._figure is None:
            plt.ion()
            self._figure, axes = plt.subplots()
            self._image = axes.imshow(frame)
            axes.set_axis_off()
        else:
            self._image.set_data(frame)
        self._figure.axes[0].set_title(f"t = {self._t}, coverage = {self.coverage:.1%}")
        plt.pause(1.0 / self.metadata["render_fps"])
        return None

    _AGENT_COLOURS = np.array(
        [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189], [140, 86, 75], [227, 119, 194]],
        dtype=np.float64,
    )

    def _render_frame(self) -> np.ndarray:
        width, height = self.config.grid_width, self.config.grid_height
        px = max(1, 480 // max(width, height))  # pixels per cell
        estimate = self.global_map
        truth = self.ground_truth
        colours = np.empty((height, width, 3))
        colours[:] = (128, 128, 128)  # unknown
        colours[estimate == 0] = (245, 245, 245)
        colours[estimate == 1] = (20, 20, 20)
        colours[(estimate == -1) & (truth == 1)] = (110, 40, 40)
        agent_colours = self._AGENT_COLOURS[np.arange(self.n_agents) % len(self._AGENT_COLOURS)]
        inside = np.zeros(self._pad_size, dtype=bool)
        for i in range(self.n_agents):
            inside.fill(False)
            inside[self._footprint[i]] = True
            mask = inside.reshape(-1, self._pad_width)[self._interior]
            colours[mask] = 0.65 * colours[mask] + 0.35 * agent_colours[i]
        image = np.repeat(np.repeat(colours[::-1], px, axis=0), px, axis=1)  # y axis up
        img_h, img_w = image.shape[:2]
        x_max, y_max = self.arena_size
        cols = np.clip((self._pos[:, 0] / x_max * img_w).astype(int), 0, img_w - 1)
        rows = np.clip(((1.0 - self._pos[:, 1] / y_max) * img_h).astype(int), 0, img_h - 1)
        links = self._links
        for i, j in zip(*np.triu_indices(self.n_agents, 1)):
            if links[i, j] or links[j, i]:
                steps = max(abs(cols[i] - cols[j]), abs(rows[i] - rows[j])) + 1
                line_r = np.linspace(rows[i], rows[j], steps).round().astype(int)
                line_c = np.linspace(cols[i], cols[j], steps).round().astype(int)
                image[line_r, line_c] = (0, 200, 0) if links[i, j] and links[j, i] else (230, 200, 0)
        half = max(1, px // 2 + 1)
        for i in range(self.n_agents):
            image[max(rows[i] - half, 0) : rows[i] + half + 1, max(cols[i] - half, 0) : cols[i] + half + 1] = agent_colours[i]
        bar = np.full((max(4, px), img_w, 3), 60.0)
        bar[:, : int(round(self.coverage * img_w))] = (0, 150, 220)
        return np.concatenate([bar, image]).astype(np.uint8)

    def close(self) -> None:
        """Close the matplotlib window of ``render_mode="human"``, if any."""
        if self._figure is not None:
            import matplotlib.pyplot as plt

            plt.close(self._figure)
            self._figure = None


def parallel_env(**kwargs: Any) -> SwarmReconEnv:
    """PettingZoo-style constructor: ``parallel_env(config=..., render_mode=..., **SwarmConfig overrides)``."""
    return SwarmReconEnv(**kwargs)
