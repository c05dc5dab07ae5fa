"""Non-learned planners for :class:`~sb3_latentswarm.envs.SwarmReconEnv`, with the recurrent ``predict`` of a model.

* :class:`RandomPlanner`: uniformly random horizontal velocity commands, the floor every planner must beat.

Coordinated planners (the UAVs split the work):

* :class:`LawnmowerPlanner`: a boustrophedon sweep, one vertical strip of the arena per UAV, assigned by agent index
  (coordination agreed in advance; no messages).
* :class:`FrontierPlanner`: greedy frontier exploration on per-UAV maps shared explicitly over the live links,
  the explicit-communication mapping approach the paper names as future work (Sec. V, refs. [mahdoui2020,
  westheider2023]): when the link j -> i is up at step t, UAV i merges UAV j's map, position and target of step t-1.

Message-free heuristics (every UAV plans from its own position only, without messages or agent-based partition; they
measure how much a scenario rewards coordination):

* :class:`SweepPlanner`: a boustrophedon sweep of the whole arena.
* :class:`SpiralPlanner`: an inward rectangular spiral of the whole arena.
* :class:`RandomStripPlanner`: the lawnmower's strips, the first one picked at random, then the others in turn.

All act only on the decentralized observation keys (``local_obs``, ``proprio``, ``link_row``), are vectorized over
all slots of all swarms (slots env-major, agent-minor; N is read from the length of ``link_row``, so one planner
serves any swarm size), hold the altitude at ``initial_altitude``, command no yaw, and respect the config's
``action_frame``. Their state is explicit, as for
:meth:`LatentSwarmPolicy.predict`: ``predict`` returns it and takes it back at the next step; a NamedTuple of arrays
whose leading dimension is the slot, reset where ``episode_start`` is 1.

Positions and headings are read from ``proprio`` (e_t) with :func:`~sb3_latentswarm.envs.observations.proprio_position`
and :func:`~sb3_latentswarm.envs.observations.proprio_heading`, the inverse of the env's normalization, and the
UAV's cell is ``floor(x / cell_size)`` as in the env.
"""

from __future__ import annotations

import abc
from typing import Any, NamedTuple

import numpy as np

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.observations import ACTOR_OBS_KEYS, as_vec_observation, proprio_heading, proprio_position
from sb3_latentswarm.utils.checks import check_int

__all__ = [
    "COORDINATED_PLANNERS",
    "MESSAGE_FREE_PLANNERS",
    "FrontierPlanner",
    "FrontierState",
    "LawnmowerPlanner",
    "RandomPlanner",
    "RandomState",
    "RandomStripPlanner",
    "SpiralPlanner",
    "SweepPlanner",
    "WaypointState",
]



class _Planner(abc.ABC):
    """Shared parts: observation handling, positions, and the velocity command towards a waypoint."""

    def __init__(self, config: SwarmConfig | None = None) -> None:
        if config is None:
            config = SwarmConfig()
        elif not isinstance(config, SwarmConfig):
            raise TypeError(f"config must be a SwarmConfig or None, got {type(config).__name__} ({config!r})")
        self.config = config
        self._step_length = config.v_max * config.dt  # metres per step at a full command
        # cell centres in metres, along x (W,) and y (H,)
        self._centres_x = (np.arange(config.grid_width) + 0.5) * config.cell_size
        self._centres_y = (np.arange(config.grid_height) + 0.5) * config.cell_size

    # ------------------------------------------------------------------ interface of a model
    @abc.abstractmethod
    def initial_state(self, n_slots: int, n_agents: int) -> Any:
        """The state before the first step of an episode, for ``n_slots`` UAVs in swarms of ``n_agents``."""

    def predict(
        self,
        observation: dict[str, np.ndarray] | dict[str, dict[str, np.ndarray]],
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray | dict[str, np.ndarray], Any]:
        """Actions of every slot, as a recurrent SB3 model's ``predict``.

        :param observation: a vec-env observation (dict of arrays with a leading slot dimension, whole swarms,
            env-major) or a PettingZoo observation ``{agent: {key: array}}`` of one swarm (actions come back as
            ``{agent: action}``); only ``local_obs``, ``proprio`` and ``link_row`` are read
        :param state: the state returned by the previous call (``None``: a fresh episode)
        :param episode_start: (n_slots,) 1 where an episode starts: that slot's state is reset
        :param deterministic: ignored (every planner's action is a deterministic function of its inputs)
        :return: actions in [-1, 1] of shape (n_slots, 4) and the new state
        """
        observation, agent_names = as_vec_observation(observation, ACTOR_OBS_KEYS, type(self).__name__)
        local_obs = np.asarray(observation["local_obs"])
        proprio = np.asarray(observation["proprio"], dtype=np.float64)
        link_row = np.asarray(observation["link_row"])
        fw = self.config.footprint_width
        if local_obs.ndim != 2 or local_obs.shape[1] != fw * fw:
            raise ValueError(
                f"local_obs must have shape (n_slots, {fw * fw}) for sensor_range={self.config.sensor_range}, "
                f"got {local_obs.shape}"
            )
        n_slots, n_agents = link_row.shape
        if n_slots % n_agents != 0:
            raise ValueError(f"The batch of {n_slots} slots is not a whole number of swarms of {n_agents} agents")
        if state is None:
            state = self.initial_state(n_slots, n_agents)
        elif len(state[0]) != n_slots:
            raise ValueError(f"state has {len(state[0])} slots but the observation has {n_slots}")
        starts = np.zeros(n_slots, dtype=bool) if episode_start is None else np.asarray(episode_start).astype(bool)
        actions, state = self._act(local_obs, proprio, link_row, state, starts)
        if agent_names is not None:
            return dict(zip(agent_names, actions)), state
        return actions, state

    @abc.abstractmethod
    def _act(self, local_obs: np.ndarray, proprio: np.ndarray, link_row: np.ndarray, state: Any, starts: np.ndarray):
        """Actions in [-1, 1] for every slot and the new state (``starts``: slots whose episode begins)."""

    # ------------------------------------------------------------------ helpers
    def _positions(self, proprio: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal positions (n, 2) in metres and cells (n, 2) as (ix, iy), from e_t = [x/X, y/Y, ...]."""
        cfg = self.config
        xy = proprio_position(proprio, cfg)[:, :2]
        cells = np.floor(xy / cfg.cell_size).astype(np.intp)
        np.clip(cells, 0, (cfg.grid_width - 1, cfg.grid_height - 1), out=cells)
        return xy, cells

    def _command(self, proprio: np.ndarray, xy: np.ndarray, target: np.ndarray, max_step: float) -> np.ndarray:
        """[vx, vy, vz, yaw] in [-1, 1]: reach ``target`` (n, 2 metres) in as few steps as the speed allows, moving
        at most ``max_step`` metres per axis and step; hold ``initial_altitude``; no yaw."""
        cfg = self.config
        actions = np.zeros((len(xy), 4))
        step = min(self._step_length, max_step)
        actions[:, :2] = np.clip(target - xy, -step, step) / self._step_length
        if cfg.action_frame == "body":
            # the env rotates (forward, lateral) by the heading chi before the move: apply the inverse rotation,
            # scaled back into the box so that the direction is kept
            chi = proprio_heading(proprio)
            cos, sin = np.cos(chi), np.sin(chi)
            vx, vy = actions[:, 0].copy(), actions[:, 1].copy()
            actions[:, 0], actions[:, 1] = vx * cos + vy * sin, -vx * sin + vy * cos
            actions[:, :2] /= np.maximum(np.abs(actions[:, :2]).max(-1, keepdims=True), 1.0)
        if cfg.vz_max > 0.0:
            z = proprio_position(proprio, cfg)[:, 2]
            actions[:, 2] = np.clip((cfg.initial_altitude - z) / (cfg.vz_max * cfg.dt), -1.0, 1.0)
        return actions


# ---------------------------------------------------------------------------------------------- random
def _splitmix64(x: np.ndarray) -> np.ndarray:
    """The splitmix64 finalizer, elementwise on uint64 (wrapping arithmetic): a fast, well-mixed integer hash."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _proprio_hash(seed: int, agent: np.ndarray, proprio: np.ndarray, *columns: np.ndarray) -> np.ndarray:
    """A uint64 hash per slot of (``seed``, agent index, further integer ``columns``, the float32 bits of ``proprio``)."""
    words = np.ascontiguousarray(proprio, dtype=np.float32).view(np.uint32).astype(np.uint64)  # (n, 8)
    key = np.full(len(proprio), seed, dtype=np.uint64)
    for column in (agent, *columns, *words.T):
        key = _splitmix64(key ^ np.asarray(column).astype(np.uint64))
    return key


def _check_seed(seed: int) -> int:
    return check_int("seed", seed, low=0)


class RandomState(NamedTuple):
    """Per-slot step counter (mixed into the hash, so a repeated observation still gets a fresh action)."""

    step: np.ndarray
    """(n_slots,) int: steps since the episode start."""


class RandomPlanner(_Planner):
    """Uniformly random horizontal velocity commands in [-1, 1]^2, altitude held, no yaw.

    The action of a slot is a hash of (``seed``, its agent index, its step count, the bits of its ``proprio``),
    so it is a pure function of the episode: an episode is reproducible from its env seed alone, whatever the
    number of env copies run in lockstep, and two UAVs never share a random stream.

    :param config: the env configuration
    :param seed: seed of the hash
    """

    def __init__(self, config: SwarmConfig | None = None, seed: int = 0) -> None:
        super().__init__(config)
        self.seed = _check_seed(seed)

    def initial_state(self, n_slots: int, n_agents: int = 1) -> RandomState:
        return RandomState(np.zeros(n_slots, dtype=np.int64))

    def _act(self, local_obs, proprio, link_row, state: RandomState, starts: np.ndarray):
        n_slots, n_agents = link_row.shape
        step = np.where(starts, 0, state.step)
        key = _proprio_hash(self.seed, np.arange(n_slots) % n_agents, proprio, step)
        draws = np.stack([_splitmix64(key ^ np.uint64(axis)) for axis in (1, 2)], axis=-1)  # (n, 2)
        uniform = (draws >> np.uint64(11)).astype(np.float64) * 2.0**-53  # [0, 1), 53 random bits
        xy, _ = self._positions(proprio)
        actions = self._command(proprio, xy, xy, np.inf)  # altitude hold and no yaw, no horizontal part
        actions[:, :2] = 2.0 * uniform - 1.0
        return actions, RandomState(step + 1)


# ---------------------------------------------------------------------------------------------- waypoint routes
class WaypointState(NamedTuple):
    """Per-slot progress along a route of waypoints."""

    route: np.ndarray
    """(n_slots,) int: which of the agent's route variants the UAV follows; -1 before its first step."""
    waypoint: np.ndarray
    """(n_slots,) int: index of the waypoint the UAV heads to."""


def _strip_orders(x0: int, x1: int, config: SwarmConfig) -> list[list[tuple[int, int]]]:
    """The four boustrophedon orders (left or right lane first, bottom or top first) of the columns [x0, x1).

    The ``ceil((x1 - x0) / (2r + 1))`` vertical lanes are spread evenly from ``x0 + r`` to ``x1 - 1 - r`` (so they cover
    the strip, at most 2r + 1 cells apart); each runs from row ``r`` to row ``H - 1 - r`` (the footprint covers rows
    0 to H - 1). Waypoints are cells (ix, iy).
    """
    r, fw, width, height = config.sensor_range, config.footprint_width, config.grid_width, config.grid_height
    y_low, y_high = r, height - 1 - r  # the grid is at least one footprint tall (SwarmConfig checks it)
    strip = x1 - x0
    n_lanes = -(-strip // fw)
    if n_lanes == 1:
        lanes = np.array([(x0 + x1 - 1) // 2])
    else:  # integer steps of floor((strip - fw) / (L - 1)) or one more: at most fw apart
        lanes = x0 + r + (np.arange(n_lanes) * (strip - fw)) // (n_lanes - 1)
    lanes = np.clip(lanes, r, width - 1 - r) if width > 2 * r else lanes
    orders = []
    for reverse in (False, True):
        for top_first in (False, True):
            points = []
            for k, x in enumerate(lanes[::-1] if reverse else lanes):
                up = (k % 2 == 0) != top_first
                points += [(int(x), y_low), (int(x), y_high)] if up else [(int(x), y_high), (int(x), y_low)]
            orders.append(points)
    return orders


def _route_table(routes: list[list[list[tuple[int, int]]]]) -> tuple[np.ndarray, np.ndarray]:
    """Pack ``routes[agent][variant]`` (lists of cells) into a table (N, V, L_max, 2) padded with the last waypoint,
    and the lengths (N, V). Consecutive duplicate waypoints are merged (they would need two arrivals in one step)."""
    routes = [[[p for j, p in enumerate(order) if j == 0 or p != order[j - 1]] for order in orders] for orders in routes]
    max_len = max(len(order) for orders in routes for order in orders)
    n_variants = len(routes[0])
    table = np.zeros((len(routes), n_variants, max_len, 2), dtype=np.intp)
    lengths = np.zeros((len(routes), n_variants), dtype=np.intp)
    for i, orders in enumerate(routes):
        for v, order in enumerate(orders):
            lengths[i, v] = len(order)
            table[i, v, : len(order)] = order
            table[i, v, len(order) :] = order[-1]
    return table, lengths


class _WaypointPlanner(_Planner):
    """Follows a fixed route of waypoint cells; subclasses define the routes (:meth:`_build_routes`).

    Each agent has V route variants. At its first step a UAV picks one (by default the variant whose first waypoint
    is nearest, in Chebyshev cells since diagonal moves are free); a waypoint is reached when the UAV is in its cell.
    The UAV moves at most 2r + 1 cells per step along each axis, so a lane leaves no gap; after the last waypoint it
    hovers.
    """

    def __init__(self, config: SwarmConfig | None = None) -> None:
        super().__init__(config)
        self._routes: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def initial_state(self, n_slots: int, n_agents: int = 1) -> WaypointState:
        return WaypointState(np.full(n_slots, -1, dtype=np.int64), np.zeros(n_slots, dtype=np.int64))

    def routes(self, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
        """Waypoint cells of every agent and variant, (N, V, L_max, 2) as (ix, iy), padded with the last one;
        lengths (N, V)."""
        if n_agents not in self._routes:
            self._routes[n_agents] = self._build_routes(n_agents)
        return self._routes[n_agents]

    @abc.abstractmethod
    def _build_routes(self, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
        """The route table of swarms of ``n_agents`` (see :meth:`routes`)."""

    def _choose_routes(self, first: np.ndarray, cells: np.ndarray, agent: np.ndarray, proprio: np.ndarray) -> np.ndarray:
        """Route variant of each starting UAV: the nearest first waypoint ``first`` (k, V, 2) from ``cells`` (k, 2)."""
        return np.abs(first - cells[:, None, :]).max(-1).argmin(-1)

    def _act(self, local_obs, proprio, link_row, state: WaypointState, starts: np.ndarray):
        n_slots, n_agents = link_row.shape
        table, lengths = self.routes(n_agents)
        agent = np.arange(n_slots) % n_agents
        xy, cells = self._positions(proprio)
        route, waypoint = state.route.copy(), state.waypoint.copy()

        choose = starts | (route < 0)
        if choose.any():
            route[choose] = self._choose_routes(table[agent[choose], :, 0], cells[choose], agent[choose], proprio[choose])
            waypoint[choose] = 0
        target = table[agent, route, waypoint]  # (n, 2) cells
        arrived = (target == cells).all(-1) & (waypoint < lengths[agent, route] - 1)
        waypoint[arrived] += 1
        target = table[agent, route, waypoint]
        target_xy = np.stack([self._centres_x[target[:, 0]], self._centres_y[target[:, 1]]], axis=-1)
        actions = self._command(proprio, xy, target_xy, self.config.footprint_width * self.config.cell_size)
        return actions, WaypointState(route, waypoint)


# ---------------------------------------------------------------------------------------------- coordinated by id
class LawnmowerPlanner(_WaypointPlanner):
    """Boustrophedon coverage: UAV i sweeps the i-th of N vertical strips in lanes spaced by the footprint width.

    Strip i spans cells ``[floor(i W / N), floor((i + 1) W / N))``. No messages, but the partition is coordination
    agreed in advance through the agent index. Its four route variants are the four sweep orders of the strip (left
    or right lane first, starting at the bottom or the top); see :class:`_WaypointPlanner` for how they are followed.

    :param config: the env configuration (grid, sensor range, speeds)
    """

    def _build_routes(self, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
        width = self.config.grid_width
        routes = []
        for i in range(n_agents):
            x0, x1 = (i * width) // n_agents, ((i + 1) * width) // n_agents
            if x1 == x0:  # more UAVs than columns: this UAV sweeps the column it shares with its left neighbour
                x0, x1 = max(x0 - 1, 0), max(x0, 1)
            routes.append(_strip_orders(x0, x1, self.config))
        return _route_table(routes)


# ---------------------------------------------------------------------------------------------- message-free
class SweepPlanner(_WaypointPlanner):
    """Message-free whole-map sweep: every UAV sweeps the whole arena in vertical boustrophedon lanes, from the sweep
    order whose first lane end is nearest, ignoring the other UAVs (no messages, no agent index).

    UAVs that start close together sweep the same lanes: the coverage of a swarm is then that of one UAV.

    :param config: the env configuration
    """

    def _build_routes(self, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
        return _route_table([_strip_orders(0, self.config.grid_width, self.config)] * n_agents)


def _inward_spiral(width: int, height: int, config: SwarmConfig) -> list[tuple[int, int]]:
    """Corner cells of an inward rectangular spiral on a ``width x height`` grid, from the corner (0, 0) east first.

    The uncovered band shrinks by one footprint (2r + 1 cells) per leg: each leg runs along the band's edge with the
    footprint just inside it (centred on the band's middle once the band is a footprint or less wide), so the
    footprints tile the grid; the spiral ends when the band is empty.
    """
    r, fw = config.sensor_range, config.footprint_width

    def lane_low(low: int, high: int) -> int:  # lane centre along the low edge of the band [low, high]
        return low + r if high - low + 1 > fw else (low + high) // 2

    def lane_high(low: int, high: int) -> int:
        return high - r if high - low + 1 > fw else (low + high) // 2

    x_low, x_high, y_low, y_high = 0, width - 1, 0, height - 1  # the uncovered band, in cells
    x, y = lane_low(x_low, x_high), lane_low(y_low, y_high)
    points = [(x, y)]
    while True:
        x = lane_high(x_low, x_high)  # east along the bottom
        points.append((x, y))
        y_low = y + r + 1
        if y_low > y_high:
            break
        y = lane_high(y_low, y_high)  # north along the right
        points.append((x, y))
        x_high = x - r - 1
        if x_low > x_high:
            break
        x = lane_low(x_low, x_high)  # west along the top
        points.append((x, y))
        y_high = y - r - 1
        if y_low > y_high:
            break
        y = lane_low(y_low, y_high)  # south along the left
        points.append((x, y))
        x_low = x + r + 1
        if x_low > x_high:
            break
    return points


class SpiralPlanner(_WaypointPlanner):
    """Message-free inward spiral: every UAV flies a rectangular spiral of the whole arena, lanes one footprint apart,
    from the nearest corner, ignoring the other UAVs (no messages, no agent index).

    The eight route variants are the four corners times the two turning senses.

    :param config: the env configuration
    """

    def _build_routes(self, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        width, height = cfg.grid_width, cfg.grid_height
        east_first = _inward_spiral(width, height, cfg)
        north_first = [(x, y) for y, x in _inward_spiral(height, width, cfg)]  # the other turning sense
        orders = []
        for spiral in (east_first, north_first):
            for mirror_x in (False, True):
                for mirror_y in (False, True):
                    orders.append(
                        [(width - 1 - x if mirror_x else x, height - 1 - y if mirror_y else y) for x, y in spiral]
                    )
        return _route_table([orders] * n_agents)


class RandomStripPlanner(_WaypointPlanner):
    """Message-free random strips: each UAV picks one of the N vertical strips of :class:`LawnmowerPlanner` at random,
    sweeps it, then sweeps the next strips in cyclic order; no messages and no agent-based partition.

    The choice is a hash of (``seed``, the UAV's ``proprio`` at its first step, its slot's agent index), as in
    :class:`RandomPlanner`: a pure function of the episode, independent between UAVs, so two UAVs pick the same
    strip with probability 1/N. With distinct strips it matches the lawnmower; with shared ones it sweeps twice.

    :param config: the env configuration
    :param seed: seed of the hash
    """

    def __init__(self, config: SwarmConfig | None = None, seed: int = 0) -> None:
        super().__init__(config)
        self.seed = _check_seed(seed)

    def _build_routes(self, n_agents: int) -> tuple[np.ndarray, np.ndarray]:
        strips = LawnmowerPlanner(self.config).routes(n_agents)
        strip_orders: list[list[list[list[int]]]] = [
            [strips[0][i, v, : strips[1][i, v]].tolist() for v in range(4)] for i in range(n_agents)
        ]
        # variant 4 k + v: strip k in order v, then strips k + 1, ... each entered at its nearest end
        variants: list[list[tuple[int, int]]] = []
        for k in range(n_agents):
            for v in range(4):
                route = list(strip_orders[k][v])
                for step in range(1, n_agents):
                    following = strip_orders[(k + step) % n_agents]
                    last = np.array(route[-1])
                    nearest = min(following, key=lambda order: np.abs(np.array(order[0]) - last).max())
                    route += nearest
                variants.append([(x, y) for x, y in route])
        return _route_table([variants] * n_agents)

    def _choose_routes(self, first: np.ndarray, cells: np.ndarray, agent: np.ndarray, proprio: np.ndarray) -> np.ndarray:
        n_strips = first.shape[1] // 4
        strip = (_proprio_hash(self.seed, agent, proprio) % np.uint64(n_strips)).astype(np.intp)  # (k,)
        own = first.reshape(len(first), n_strips, 4, 2)[np.arange(len(first)), strip]  # (k, 4, 2) first waypoints
        return 4 * strip + super()._choose_routes(own, cells, agent, proprio)


# ---------------------------------------------------------------------------------------------- frontier
class FrontierState(NamedTuple):
    """Per-slot onboard state of the frontier explorer; the first three fields are what the UAV broadcasts."""

    known: np.ndarray
    """(n_slots, H, W) bool: cells this UAV has sensed or received in a peer's map."""
    cell: np.ndarray
    """(n_slots, 2) float (ix, iy): the UAV's cell at its last step; NaN before the first step."""
    target: np.ndarray
    """(n_slots,) int: flat cell index ``iy * W + ix`` of the frontier cell the UAV heads to; -1 for none."""
    peer_cell: np.ndarray
    """(n_slots, N, 2) float: last received cell of each peer; NaN if never received (and for the UAV itself)."""
    peer_target: np.ndarray
    """(n_slots, N, 2) float: last received target cell of each peer (a claimed frontier); NaN if none."""


class FrontierPlanner(_Planner):
    """Greedy frontier exploration with explicit sharing of maps, positions and claimed frontiers over the live links.

    Each step, UAV i

    1. merges the map, cell and target of step t-1 of every peer j whose message reached it (``link_row[i, j] = 1``);
    2. marks the cells of its own ``local_obs`` patch as known;
    3. replans if its target is known, if it has none, or if a lower-indexed peer has claimed a target within
       ``spread_radius`` of it (this breaks the tie of two UAVs chasing one frontier side by side): it picks the
       unknown cell of its own map with the least cost

           cost(c) = max(0, d(c, p_i) - r) + spread_weight * max(0, spread_radius - min_j min(d(c, p_j), d(c, g_j))),

       d the Chebyshev distance in cells (the steps needed under per-axis speed limits), p_j and g_j the last
       received cell and target of peer j: the first term is the travel until c enters the footprint, the second
       keeps the UAVs apart (a tiny Euclidean term breaks ties towards the nearest cell);
    4. flies towards its target at full speed, or hovers when its map has no unknown cell left.

    Without links (``no_comm``) every UAV explores the whole arena alone; with links the shared maps and claims
    remove most of the redundant sweeps.

    :param config: the env configuration
    :param spread_radius: cells; frontiers closer than this to a peer or to its target are penalized
        (default: 4 (2r + 1), four footprints)
    :param spread_weight: cost per cell of intrusion into a peer's radius
    """

    def __init__(self, config: SwarmConfig | None = None, spread_radius: float | None = None, spread_weight: float = 2.0):
        super().__init__(config)
        cfg = self.config
        self.spread_radius = 4.0 * cfg.footprint_width if spread_radius is None else float(spread_radius)
        self.spread_weight = float(spread_weight)
        if self.spread_radius < 0 or self.spread_weight < 0:
            raise ValueError(f"spread_radius and spread_weight must be >= 0, got {self.spread_radius}, {self.spread_weight}")
        r, fw = cfg.sensor_range, cfg.footprint_width
        dy, dx = np.divmod(np.arange(fw * fw), fw)  # the patch is row-major: rows are y, ascending
        self._patch_dx, self._patch_dy = dx - r, dy - r
        iy, ix = np.divmod(np.arange(cfg.n_cells), cfg.grid_width)
        self._cell_x, self._cell_y = ix, iy  # (H*W,) coordinates of the flat cells
        self._cell_xy = np.stack([ix, iy], axis=-1)

    def initial_state(self, n_slots: int, n_agents: int = 1) -> FrontierState:
        cfg = self.config
        return FrontierState(
            known=np.zeros((n_slots, cfg.grid_height, cfg.grid_width), dtype=bool),
            cell=np.full((n_slots, 2), np.nan),
            target=np.full(n_slots, -1, dtype=np.int64),
            peer_cell=np.full((n_slots, n_agents, 2), np.nan),
            peer_target=np.full((n_slots, n_agents, 2), np.nan),
        )

    def _act(self, local_obs, proprio, link_row, state: FrontierState, starts: np.ndarray):
        cfg = self.config
        n_slots, n_agents = link_row.shape
        n_swarms = n_slots // n_agents
        if state.peer_cell.shape[1] != n_agents:
            raise ValueError(f"state is for swarms of {state.peer_cell.shape[1]} agents, link_row for {n_agents}")
        known = state.known.reshape(n_slots, -1).copy()
        target = state.target.copy()
        peer_cell, peer_target = state.peer_cell.copy(), state.peer_target.copy()
        sent_cell = state.cell.copy()
        known[starts] = False
        target[starts] = -1
        sent_cell[starts] = np.nan
        peer_cell[starts] = np.nan
        peer_target[starts] = np.nan
        sent_target = np.where(target[:, None] >= 0, self._cell_xy[np.maximum(target, 0)], np.nan)  # (n, 2)

        # (1) explicit sharing: i merges j's map, cell and target of step t-1 when j -> i is up at step t
        links = link_row.reshape(n_swarms, n_agents, n_agents) > 0.5  # [s, i, j]
        sent_maps = known.reshape(n_swarms, n_agents, -1).astype(np.float32)
        known |= (np.matmul(links.astype(np.float32), sent_maps) > 0.0).reshape(n_slots, -1)
        received = links[..., None]  # (S, N, N, 1)
        peer_cell = np.where(
            received, sent_cell.reshape(n_swarms, 1, n_agents, 2), peer_cell.reshape(received.shape[:3] + (2,))
        )
        peer_target = np.where(
            received, sent_target.reshape(n_swarms, 1, n_agents, 2), peer_target.reshape(received.shape[:3] + (2,))
        )
        peer_cell, peer_target = peer_cell.reshape(n_slots, n_agents, 2), peer_target.reshape(n_slots, n_agents, 2)

        # (2) own sensing: the patch is centred on the UAV's cell; -1 marks cells outside the arena
        xy, cells = self._positions(proprio)
        px = cells[:, :1] + self._patch_dx  # (n, F*F)
        py = cells[:, 1:] + self._patch_dy
        inside = (local_obs >= 0) & (px >= 0) & (px < cfg.grid_width) & (py >= 0) & (py < cfg.grid_height)
        rows = np.broadcast_to(np.arange(n_slots)[:, None], px.shape)
        known[rows[inside], (py * cfg.grid_width + px)[inside]] = True

        # (3) replan where the target is sensed, missing, or claimed nearby by a lower-indexed peer
        slots = np.arange(n_slots)
        replan = (target < 0) | known[slots, np.maximum(target, 0)]
        lower = np.arange(n_agents)[None, :] < (slots % n_agents)[:, None]  # (n, N): peer j has a lower index
        claim_gap = np.abs(peer_target - self._cell_xy[np.maximum(target, 0)][:, None, :]).max(-1)  # NaN if no claim
        replan |= (target >= 0) & (lower & (claim_gap < self.spread_radius)).any(-1)
        if replan.any():
            target[replan] = self._choose_targets(known[replan], cells[replan], peer_cell[replan], peer_target[replan])

        # (4) fly to the target cell's centre, or hover
        target_xy = xy.copy()
        has_target = target >= 0
        target_xy[has_target] = (self._cell_xy[target[has_target]] + 0.5) * cfg.cell_size
        actions = self._command(proprio, xy, target_xy, np.inf)
        new_state = FrontierState(known.reshape(state.known.shape), cells.astype(np.float64), target, peer_cell, peer_target)
        return actions, new_state

    def _choose_targets(
        self, known: np.ndarray, cells: np.ndarray, peer_cell: np.ndarray, peer_target: np.ndarray
    ) -> np.ndarray:
        """Least-cost unknown cell of each map (k, H*W) for UAVs at ``cells`` (k, 2); -1 where all is known."""
        dx = np.abs(self._cell_x - cells[:, :1])  # (k, H*W)
        dy = np.abs(self._cell_y - cells[:, 1:])
        cost = np.maximum(np.maximum(dx, dy) - self.config.sensor_range, 0).astype(np.float64)
        cost += 1e-3 * np.sqrt(dx * dx + dy * dy)
        if self.spread_weight > 0.0 and self.spread_radius > 0.0:
            nearest = np.full(cost.shape, np.inf)
            for anchors in (peer_cell, peer_target):  # (k, N, 2), NaN where unknown
                for j in range(anchors.shape[1]):
                    known_anchor = ~np.isnan(anchors[:, j, 0])
                    if known_anchor.any():
                        ax, ay = anchors[known_anchor, j, :1], anchors[known_anchor, j, 1:]
                        distance = np.maximum(np.abs(self._cell_x - ax), np.abs(self._cell_y - ay))
                        nearest[known_anchor] = np.minimum(nearest[known_anchor], distance)
            cost += self.spread_weight * np.maximum(self.spread_radius - nearest, 0.0)
        cost[known] = np.inf
        best = cost.argmin(axis=1)
        return np.where(np.isinf(cost[np.arange(len(best)), best]), -1, best)


COORDINATED_PLANNERS = {"lawnmower": LawnmowerPlanner, "frontier": FrontierPlanner}
"""Planners whose UAVs split the work: by agent index (lawnmower) or over the live links (frontier)."""
MESSAGE_FREE_PLANNERS = {"sweep": SweepPlanner, "spiral": SpiralPlanner, "random_strip": RandomStripPlanner}
"""Planners whose UAVs plan alone: no messages, no agent index in the plan."""
