"""Cooperative UAV reconnaissance under intermittent A2A links: the Dec-POMDP of Sec. II as a PettingZoo ``ParallelEnv``.

====================  =====================================================================================================
Import                ``from sb3_latentswarm.envs import swarm_recon_v0`` (``swarm_recon_v0.parallel_env(...)``)
Agents                ``possible_agents = ["uav_0", ..., "uav_{N-1}"]`` (N = ``SwarmConfig.n_agents``, paper: 3)
Parallel API          yes; all agents start, terminate and truncate together (no agent is removed alone)
Action space          ``Box(-1, 1, (4,), float32)``: ``[vx, vy, vz, yaw_rate]`` scaled by ``(v_max, v_max, vz_max,
                      yaw_rate_max)``; with ``action_frame="body"`` ``(vx, vy)`` are (forward, lateral), rotated by chi
Observation space     ``Dict`` of what the agent may see at execution time: ``local_obs``, ``proprio``, ``link_row``
                      (and ``link_age`` with delay); see below (F = 2 * sensor_range + 1)
State space           ``state_space = Box(-inf, inf, (N * 8 + H * W,), float32)``, :meth:`SwarmReconEnv.state`: the global
                      state for a centralized critic (H x W = grid_height x grid_width)
Reward                shared by all agents, Sec. II-B: ``r = w_cov r_cov + w_red r_red + w_coll r_coll``
Termination           all agents, when the energy ``b_t = b_0 - kappa t`` is depleted or every cell has been observed
Truncation            all agents, at ``t >= max_steps`` without termination
Info keys             after each step: ``coverage``, ``collisions``, ``link_up_rate``, ``dropout``; ``swarm_summary``
                      at the last step (see :meth:`SwarmReconEnv.swarm_summary`); empty at reset
Implementation        the one-swarm (B = 1) view of :class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`, which holds
                      the model below once for any number of swarms (``make_vec_env``'s batched backend is another view)
====================  =====================================================================================================

Observation of agent ``i`` (a ``gymnasium.spaces.Dict``), PettingZoo's convention: what the agent may see when it acts
(its sensor patch, its own state, its link row, and ``link_age`` with delay); the global state comes from
:meth:`SwarmReconEnv.state`. The last two rows, the critic's keys, are in the observation only with
``SwarmReconEnv(..., critic_keys=True)``, the view the SB3 vec env of ``make_vec_env(backend="supersuit")`` steps:
its centralized critic reads them from every slot (not for decentralized execution).

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
:meth:`SwarmReconEnv.state` returns it as one flat float32 vector (``swarm_proprio`` flattened, then ``global_map``).
Up to 0.2.0 every agent's observation held them: a MARL library that hands each actor its observation handed it the
global state (CHANGELOG, Unreleased).

Model (units: metres, seconds of ``dt``; the arena is ``[0, X] x [0, Y]`` with ``X = grid_width * cell_size``):

* Transition T (stochastic): ``v = command + N(0, (actuation_noise_std * (v_max, v_max, vz_max))^2)``,
  ``p += v dt`` with ``(x, y)`` clipped to the arena and ``z`` to ``[min_altitude, max_altitude]``;
  ``chi += yaw_command dt`` wrapped to ``[-pi, pi)``; the body-frame rotation uses the heading before the update.
  ``proprio`` reports this actuated velocity ``v`` (also while a clipped axis does not move).
* Sensing P_o: each UAV reads the ``(2r+1) x (2r+1)`` cells around its cell ``(floor(x / cell_size),
  floor(y / cell_size))``; each reading is flipped with probability ``sensor_flip_prob``. ``M_hat`` keeps the latest
  reading of every sensed cell (two UAVs reading one cell at one step: the higher agent index wins); the coverage set
  C is the set of cells observed at least once. Sensing happens at reset and after every move.
* Links: drawn by the link model of the config (:func:`~sb3_latentswarm.links.make_link_model`; by default the A2A
  channel of Eq. (1), :class:`~sb3_latentswarm.channel.A2AChannel`) at the reset positions and after every move; the
  model keeps its state (a Gilbert-Elliott chain per link, messages in flight), restarted at every reset. With
  ``message_delay > 0`` each agent's observation also has ``link_age`` (N,): how many steps late each arrival is.
* Step counting: ``reset`` is t = 0, the k-th ``step`` is t = k. An episode already fully covered at reset ends
  (``terminated``) at its first step.

Start positions: drawn by :func:`~sb3_latentswarm.envs.start_positions.sample_start_positions` from
``SwarmConfig.start_region`` (uniform over the arena, the default, or a common corner launch area). Scenario hooks
(documented for tests and examples): ``reset(options={"positions": p})`` starts the UAVs at ``p``
(shape (N, 3), metres) instead of random positions; :meth:`SwarmReconEnv.set_positions` teleports them
mid-episode (the next ``step`` moves from there and senses); :attr:`SwarmReconEnv.reward_terms` holds the
unweighted ``(r_cov, r_red, r_coll)`` of the last step. Other ``options`` keys are ignored.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sb3_latentswarm.config import SwarmConfig, resolve_config
from sb3_latentswarm.envs.batched_core import (
    ACTOR_OBS_KEYS,
    LINK_AGE_KEY,
    OBS_KEYS,
    PROPRIO_DIM,
    STATE_OBS_KEYS,
    SwarmBatch,
    agent_action_space,
    agent_observation_space,
)

__all__ = ["SwarmReconEnv", "parallel_env", "render_frame", "OBS_KEYS", "ACTOR_OBS_KEYS", "STATE_OBS_KEYS", "PROPRIO_DIM"]


class SwarmReconEnv(ParallelEnv):
    """N UAVs map a ``grid_width x grid_height`` grid with noisy local sensors and intermittent links (Sec. II, IV).

    See the module docstring for the spaces, the reward and the dynamics. The model itself lives in
    :class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`; this env is its one-swarm (B = 1) view.

    :param config: the configuration; ``SwarmConfig()`` (the paper's settings) if ``None``.
    :param render_mode: ``None``, ``"rgb_array"`` (``render()`` returns an ``(H, W, 3)`` uint8 image) or ``"human"``
        (matplotlib window).
    :param critic_keys: also put the global keys ``swarm_proprio`` and ``global_map`` into every agent's observation
        (the SB3 vec env's view for a centralized critic, :func:`~sb3_latentswarm.envs.make_vec_env`); default
        ``False``: PettingZoo's convention, the global state comes from :meth:`state`.
    :param overrides: ``SwarmConfig`` fields replacing those of ``config``, e.g. ``SwarmReconEnv(n_agents=5)``;
        unknown names raise ``TypeError``.
    """

    metadata: dict[str, Any] = {
        "name": "swarm_recon_v0", "render_modes": ["human", "rgb_array"], "render_fps": 10, "is_parallelizable": True
    }

    def __init__(
        self, config: SwarmConfig | None = None, render_mode: str | None = None, *, critic_keys: bool = False,
        **overrides: Any
    ) -> None:
        config = resolve_config(config, **overrides)
        if not isinstance(critic_keys, bool):
            raise TypeError(f"critic_keys must be a bool, got {critic_keys!r}")
        self.critic_keys = critic_keys
        self.check_render_mode(render_mode)
        self.config = config
        self.render_mode = render_mode
        self.n_agents = n = config.n_agents
        self.possible_agents = [f"uav_{i}" for i in range(n)]
        self.agents: list[str] = []
        self.arena_size = config.arena_size
        self.action_spaces = {a: agent_action_space() for a in self.possible_agents}
        full = agent_observation_space(config)
        keys = [key for key in full.spaces if critic_keys or key not in STATE_OBS_KEYS]
        self.observation_spaces = {a: spaces.Dict([(key, full[key]) for key in keys]) for a in self.possible_agents}
        self.state_space = spaces.Box(-np.inf, np.inf, (n * PROPRIO_DIM + config.n_cells,), np.float32)
        self._core = SwarmBatch(config, n_swarms=1)
        self._last_obs: dict[str, dict[str, np.ndarray]] = {}
        self._figure: Any = None
        self._image: Any = None

    @classmethod
    def check_render_mode(cls, render_mode: str | None) -> None:
        """Raise ``ValueError`` unless ``render_mode`` is ``None`` or one of ``metadata["render_modes"]``."""
        if render_mode is not None and render_mode not in cls.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {cls.metadata['render_modes']}, got {render_mode!r}")

    # ------------------------------------------------------------------ PettingZoo API
    def observation_space(self, agent: str) -> spaces.Dict:
        """The (cached) observation space of ``agent``."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        """The (cached) action space of ``agent``."""
        return self.action_spaces[agent]

    @property
    def np_random(self) -> np.random.Generator | None:
        """The episode RNG (``None`` before the first reset)."""
        return self._core.rngs[0]

    @property
    def np_random_seed(self) -> int | None:
        """The seed of :attr:`np_random` (``None`` if it was seeded randomly or not yet created)."""
        return self._core.seeds[0]

    @property
    def coverage(self) -> float:
        """``|C_t| / |X|``, the share of cells observed at least once."""
        return float(self._core.coverage[0])

    @property
    def energy(self) -> float:
        """b_t = b_0 - kappa t (the same for every UAV), clamped at 0."""
        return float(self._core.energy[0])

    @property
    def positions(self) -> np.ndarray:
        """A copy of the UAV positions in metres, shape (N, 3)."""
        return self._core.positions[0]

    @property
    def links(self) -> np.ndarray:
        """A copy of the current link matrix, shape (N, N), ``[i, j]`` = receiver i got sender j."""
        return self._core.links[0]

    @property
    def ground_truth(self) -> np.ndarray:
        """A copy of the ground-truth occupancy map M, shape (H, W) indexed [iy, ix], 1 = occupied."""
        return self._core.ground_truth[0]

    @property
    def global_map(self) -> np.ndarray:
        """A copy of M_hat_t, shape (H, W) indexed [iy, ix]: -1 unknown, 0 free, 1 occupied."""
        return self._core.global_map[0].copy()

    @property
    def reward_terms(self) -> tuple[float, float, float]:
        """Unweighted ``(r_cov, r_red, r_coll)`` of the last step (0 after reset)."""
        r_cov, r_red, r_coll = self._core.reward_terms[0].tolist()
        return r_cov, r_red, r_coll

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
        positions = None if options is None else options.get("positions")
        if positions is not None:
            positions = self._core.check_positions(positions)[None]
        self._core.reset(seeds=[seed], positions=positions)
        self.agents = list(self.possible_agents)
        # Empty reset infos: SuperSuit merges the reset infos of the next episode into the last step's infos, which
        # would overwrite the final coverage / collisions / link statistics of the finished episode.
        return self._observations(), {agent: {} for agent in self.agents}

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
        core = self._core
        rewards, terminateds, truncateds = core.step(core.check_actions(self._stack_actions(actions)[None]))
        infos = dict(zip(self.possible_agents, core.step_infos(terminateds, truncateds)[0]))
        reward, terminated, truncated = float(rewards[0]), bool(terminateds[0]), bool(truncateds[0])
        obs = self._observations()
        if terminated or truncated:
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
        core = self._core
        return np.concatenate([core.proprio[0].ravel(), core.global_map[0].ravel()]).astype(np.float32)

    def swarm_summary(self) -> dict[str, Any]:
        """Episode statistics so far (the ``swarm_summary`` info of the last step, which adds ``truncated``).

        Keys: ``coverage`` (``|C| / |X|``), ``collisions`` (pairs closer than ``d_safe``, summed over the steps),
        ``steps_to_90`` (first step t with coverage >= 0.9, ``None`` if never), ``length`` (steps), ``episode_return``
        (sum of the shared reward), ``link_up_rate`` (mean over agents and link draws of the share of live in-links),
        ``dropout_rate`` (share of agent-draws with no live in-link). The link statistics count every link draw of
        the episode: the one at reset and one per step.
        """
        return self._core.swarm_summary(0)

    def set_positions(self, positions: np.ndarray) -> None:
        """Teleport the UAVs (scenario and test hook). The next ``step`` moves from there, then senses.

        Nothing is sensed and no link is drawn here; the observation of the last step is not updated.

        :param positions: shape (N, 3), metres, inside the arena and the altitude bounds.
        """
        if not self.agents:
            raise RuntimeError("set_positions() needs a running episode: call reset() first")
        self._core.set_positions(0, positions)

    # ------------------------------------------------------------------ internals
    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_figure"] = state["_image"] = None  # a matplotlib window does not travel
        return state

    def _stack_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """Stack the joint action into an (N, 4) float64 array, or raise ``ValueError`` naming the agent."""
        agents = self.agents
        if not isinstance(actions, Mapping):
            raise TypeError(
                f"actions must be a dict {{agent: action}} (PettingZoo's parallel API) for the agents {agents}, got "
                f"{type(actions).__name__}; for an array of shape (N, 4), pass dict(zip(env.agents, actions))"
            )
        try:
            command = np.array([np.asarray(actions[agent]) for agent in agents])
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
        return command

    def _observations(self) -> dict[str, dict[str, np.ndarray]]:
        # The core's arrays are fresh and read-only after every step; agents share views of them.
        core = self._core
        local_obs, proprio, link_rows, global_map = core.local_obs[0], core.proprio[0], core.link_rows[0], core.global_map[0]
        obs = {
            agent: {
                "local_obs": local_obs[i],
                "proprio": proprio[i],
                "link_row": link_rows[i],
            }
            for i, agent in enumerate(self.possible_agents)
        }
        for i, agent in enumerate(self.possible_agents):  # in the order of the observation space
            if core.link_ages is not None:
                obs[agent][LINK_AGE_KEY] = core.link_ages[0, i]
            if self.critic_keys:
                obs[agent]["swarm_proprio"] = proprio
                obs[agent]["global_map"] = global_map
        self._last_obs = obs
        return obs

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
        frame = render_frame(self._core, 0)
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
        self._figure.axes[0].set_title(f"t = {int(self._core.t[0])}, coverage = {self.coverage:.1%}")
        plt.pause(1.0 / self.metadata["render_fps"])
        return None

    def close(self) -> None:
        """Close the matplotlib window of ``render_mode="human"``, if any."""
        if self._figure is not None:
            import matplotlib.pyplot as plt

            plt.close(self._figure)
            self._figure = None


def parallel_env(**kwargs: Any) -> SwarmReconEnv:
    """PettingZoo-style constructor: ``parallel_env(config=..., render_mode=..., **SwarmConfig overrides)``."""
    return SwarmReconEnv(**kwargs)


#: Colours of the UAVs in :func:`render_frame` (RGB), cycled when N is larger.
#: The colour (RGB 0-255) of UAV ``i``, ``AGENT_COLOURS[i % 7]``: its square, footprint tint, trail and trajectory
#: (``sb3_latentswarm.rendering``), one palette for every picture of a swarm (matplotlib's tab10 order).
AGENT_COLOURS = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189], [140, 86, 75], [227, 119, 194]],
    dtype=np.float64,
)
#: The other colours (RGB 0-255) of :func:`render_frame`, named once for the picture and its legend
#: (``sb3_latentswarm.rendering``): the map estimate's cells, the obstacles no UAV has seen yet (ground truth, shown to
#: the viewer only), the links drawn between UAVs and the coverage bar above the map.
RENDER_COLOURS = {
    "unseen": (128, 128, 128),
    "free": (245, 245, 245),
    "obstacle": (20, 20, 20),
    "obstacle_unseen": (110, 40, 40),
    "link_both_ways": (0, 200, 0),
    "link_one_way": (230, 200, 0),
    "bar": (60, 60, 60),
    "coverage": (0, 150, 220),
}
#: How much of its colour a UAV's sensor footprint mixes into the cells under it: 0.65 cell + 0.35 UAV.
FOOTPRINT_TINT = 0.35


def render_frame(core: SwarmBatch, swarm: int) -> np.ndarray:
    """The picture of swarm ``swarm`` of ``core`` as an (H, W, 3) uint8 image (see :meth:`SwarmReconEnv.render`)."""
    config = core.config
    width, height = config.grid_width, config.grid_height
    px = max(1, 480 // max(width, height))  # pixels per cell
    estimate = core.global_map[swarm]
    truth = core.ground_truth[swarm]
    colours = np.empty((height, width, 3))
    colours[:] = RENDER_COLOURS["unseen"]
    colours[estimate == 0] = RENDER_COLOURS["free"]
    colours[estimate == 1] = RENDER_COLOURS["obstacle"]
    colours[(estimate == -1) & (truth == 1)] = RENDER_COLOURS["obstacle_unseen"]
    agent_colours = AGENT_COLOURS[np.arange(core.n_agents) % len(AGENT_COLOURS)]
    r = config.sensor_range
    rows_padded, cols_padded = np.divmod(core.footprint[swarm], width + 2 * r)  # padded (row, col) per entry
    for i in range(core.n_agents):
        iy, ix = rows_padded[i] - r, cols_padded[i] - r
        keep = (iy >= 0) & (iy < height) & (ix >= 0) & (ix < width)
        mask = np.zeros((height, width), dtype=bool)
        mask[iy[keep], ix[keep]] = True
        colours[mask] = (1 - FOOTPRINT_TINT) * colours[mask] + FOOTPRINT_TINT * agent_colours[i]
    image = np.repeat(np.repeat(colours[::-1], px, axis=0), px, axis=1)  # y axis up
    img_h, img_w = image.shape[:2]
    x_max, y_max = config.arena_size
    positions = core.kinematics[swarm, :, :3]
    cols = np.clip((positions[:, 0] / x_max * img_w).astype(int), 0, img_w - 1)
    rows = np.clip(((1.0 - positions[:, 1] / y_max) * img_h).astype(int), 0, img_h - 1)
    links = core.links[swarm]
    for a, b in zip(*np.triu_indices(core.n_agents, 1)):
        if links[a, b] or links[b, a]:
            steps = max(abs(cols[a] - cols[b]), abs(rows[a] - rows[b])) + 1
            line_r = np.linspace(rows[a], rows[b], steps).round().astype(int)
            line_c = np.linspace(cols[a], cols[b], steps).round().astype(int)
            both_ways = links[a, b] and links[b, a]
            image[line_r, line_c] = RENDER_COLOURS["link_both_ways"] if both_ways else RENDER_COLOURS["link_one_way"]
    half = max(1, px // 2 + 1)
    for i in range(core.n_agents):
        image[max(rows[i] - half, 0) : rows[i] + half + 1, max(cols[i] - half, 0) : cols[i] + half + 1] = agent_colours[i]
    bar = np.full((max(4, px), img_w, 3), RENDER_COLOURS["bar"], dtype=np.float64)
    bar[:, : int(round(core.n_covered[swarm] / config.n_cells * img_w))] = RENDER_COLOURS["coverage"]
    return np.concatenate([bar, image]).astype(np.uint8)
