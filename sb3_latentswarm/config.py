"""``SwarmConfig``: every constant of the paper, and every constant the paper leaves open, in one validated dataclass.

Defaults are the paper's (Sec. II and Sec. IV, "Simulation Results"). Fields marked *open* are not fixed by the paper;
our choice and the reason are in ``docs/concepts.md`` (the paper-to-code table).

Units: lengths in metres, one grid cell is ``cell_size`` metres wide, time in environment steps of ``dt`` seconds,
power in mW (``tx_power_dbm`` is converted with :func:`dbm_to_mw`), energy in the paper's abstract units.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from sb3_latentswarm.utils import checks

LINK_MODES = ("channel", "full", "full_in_range", "none")
ACTION_FRAMES = ("world", "body")
START_REGIONS = ("uniform", "corner", "random_corner")
OUTAGE_MODELS = ("bernoulli", "gilbert_elliott")
LINK_MODELS = ("a2a", "outage", "distance")
DELAY_MODELS = ("fixed", "uniform", "geometric")


INT_BOUNDS: dict[str, tuple[int, int]] = {
    "n_agents": (1, 256),
    "sensor_range": (0, 50),
    "grid_width": (1, 1000),
    "grid_height": (1, 1000),
    "max_steps": (1, 1_000_000),
    "num_obstacles": (0, 1_000_000),
    "message_delay": (0, 1000),
    "message_expiry": (0, 1000),
}
"""Allowed ranges (inclusive) of the integer fields (``docs/concepts.md``, "Bounds of SwarmConfig")."""

FLOAT_BOUNDS: dict[str, tuple[float, float, bool]] = {
    # name: (low, high, low exclusive); chosen so that every accepted config gives finite rewards and SINRs
    "initial_energy": (0.0, 1e6, True),
    "energy_decay": (0.0, 1e6, False),
    "min_altitude": (0.0, 1e4, False),
    "max_altitude": (0.0, 1e4, False),
    "w_cov": (0.0, 1e3, False),
    "w_red": (0.0, 1e3, False),
    "w_coll": (0.0, 1e3, False),
    "stall_penalty": (0.0, 1e3, False),
    "d_safe": (0.0, 1e4, False),
    "cell_size": (0.0, 1e3, True),
    "dt": (0.0, 1e3, True),
    "v_max": (0.0, 1e3, True),
    "vz_max": (0.0, 1e3, False),
    "yaw_rate_max": (0.0, 100.0, False),
    "actuation_noise_std": (0.0, 10.0, False),
    "sensor_flip_prob": (0.0, 0.5, False),
    "p_fail": (0.0, 1.0, False),
    "rician_k": (0.0, 1e3, False),
    "rician_k_altitude_slope": (0.0, 100.0, False),
    "atmospheric_loss": (0.0, 1.0, True),
    "tx_power_dbm": (-50.0, 60.0, False),
    "path_loss_exponent": (0.0, 6.0, False),
    "sinr_threshold": (0.0, 1e9, True),
    "noise_power": (1e-9, 1e6, False),
    "interference_max": (0.0, 1e6, False),
    "min_link_distance": (1e-3, 1e3, False),
    "link_range": (0.0, 1e6, True),
}
"""Allowed ranges of the real fields: ``(low, high, low_exclusive)``, ``high`` inclusive (``docs/concepts.md``).

With these bounds the SINR of Eq. (1) is at most 1e6 mW * |h|^2 * (1e-3 m)^-6 / 1e-9 mW, finite for every finite
fading draw, and one step's reward is at most ``1e3 * 1e6`` cells in magnitude."""


def dbm_to_mw(power_dbm: float) -> float:
    """Convert a power in dBm to mW (20 dBm = 100 mW)."""
    return 10.0 ** (power_dbm / 10.0)


@dataclass(frozen=True)
class SwarmConfig:
    """Configuration of the swarm reconnaissance environment and of its air-to-air channel.

    Paper constants (Sec. IV) keep the paper's value as default; *open* constants are our documented choices.
    """

    # --- Swarm and task (Sec. II, Sec. IV) ---
    n_agents: int = 3
    """N, the number of UAVs in the swarm."""
    grid_width: int = 50
    """Cells along x of the discretized grid X (paper: 50)."""
    grid_height: int = 50
    """Cells along y of the discretized grid X (paper: 50)."""
    sensor_range: int = 2
    """Sensor range in cells (paper: 2). The footprint is the (2r+1) x (2r+1) square of cells around the UAV's cell."""
    max_steps: int = 1000
    """T, the episode horizon in steps (paper: 1000)."""
    initial_energy: float = 100.0
    """b_0, the initial energy budget of every UAV (paper: 100)."""
    energy_decay: float = 0.1
    """kappa, the energy spent per step (paper: 0.1)."""
    min_altitude: float = 5.0
    """Lower altitude bound in metres (paper: 5 m)."""
    max_altitude: float = 20.0
    """Upper altitude bound in metres (paper: 20 m)."""
    initial_altitude: float = 10.0
    """Altitude at reset in metres (paper: 10 m)."""
    start_region: str = "uniform"
    """*Extension, opt-in.* Where the UAVs start (see :func:`~sb3_latentswarm.envs.start_positions.sample_start_positions`).
    ``"uniform"`` (default, as the paper's random placement): independently and uniformly over the arena.
    ``"corner"``: uniformly in the ``start_region_size x start_region_size`` square at the arena's corner (0, 0), a
    common launch area, so start positions cannot act as implicit agent ids or split the map. ``"random_corner"``:
    the same square at one of the four corners, drawn per episode (no convention learnt from one corner applies)."""
    start_region_size: float = 5.0
    """*Extension.* Side in metres of the launch square of ``start_region="corner"`` (at most the arena's shorter side);
    unused by ``"uniform"``."""
    num_obstacles: int = 30
    """Occupied cells of the ground truth M, placed uniformly at random each episode (paper: 30)."""

    # --- Reward (Sec. II-B) ---
    w_cov: float = 0.4
    """Weight of the coverage reward r_cov (paper: 0.4)."""
    w_red: float = 0.02
    """Weight of the redundancy penalty r_red (paper: 0.02)."""
    w_coll: float = 0.8
    """Weight of the proximity penalty r_coll (paper: 0.8)."""
    stall_penalty: float = 0.5
    """*Open.* c > 0, subtracted from the coverage gain every step to discourage stalling (cells per step)."""
    d_safe: float = 2.0
    """*Open.* Safety distance in metres; pairs closer than this count as a collision (3D distance)."""

    # --- Dynamics (open in the paper) ---
    cell_size: float = 1.0
    """*Open.* Width of one grid cell in metres."""
    dt: float = 1.0
    """*Open.* Duration of one step in seconds."""
    v_max: float = 0.3
    """*Open.* Maximum horizontal speed per axis in m/s. Calibrated so that the horizon binds as in the paper: an ideal
    3-UAV sweep of the 50x50 map (footprint width 5) needs 2500 / (3 * 5 * 0.3) = 556 of the T = 1000 steps."""
    vz_max: float = 0.5
    """*Open.* Maximum vertical speed in m/s."""
    yaw_rate_max: float = math.pi / 4
    """*Open.* Maximum heading rate in rad/s."""
    action_frame: str = "world"
    """*Open.* ``"world"``: the horizontal velocity command is in the arena frame and the heading is commanded
    separately; ``"body"``: the horizontal command is rotated by the heading chi (forward, lateral)."""
    actuation_noise_std: float = 0.05
    """*Open.* Std of the Gaussian actuation noise, as a fraction of the maximum speed of each axis (stochastic T)."""
    sensor_flip_prob: float = 0.02
    """*Open.* Probability that one sensed cell is read with the wrong occupancy (the noisy P_o)."""

    # --- A2A channel, Eq. (1) (Sec. II-A, Sec. IV) ---
    link_mode: str = "channel"
    """``"channel"``: links drawn from Eq. (1); ``"full"``: every directed link up (Full comm); ``"none"``: every link
    down (No comm); ``"full_in_range"`` (*extension*): a link is up iff its 3D length is at most the channel's usable
    range (:func:`~sb3_latentswarm.channel.usable_link_range`), so only links that Eq. (1) can deliver are forced up."""
    p_fail: float = 0.3
    """p_f, probability of an abrupt link failure, xi ~ Bernoulli(1 - p_f) per directed link and step (paper: 0.3).
    With ``outage_model="gilbert_elliott"`` it is the stationary failure probability of the Markov chain."""
    outage_model: str = "bernoulli"
    """How xi evolves. ``"bernoulli"`` (default, Eq. (1)): independent draws every step, so a failure lasts
    1 / (1 - p_f) steps on average. ``"gilbert_elliott"`` (*extension, opt-in*): each directed link's xi is a two-state
    Markov chain with stationary failure probability ``p_fail`` and mean failure run ``mean_outage_steps`` (bursty
    outages); its initial state is drawn from the stationary distribution at reset."""
    mean_outage_steps: float = 10.0
    """*Extension.* L, the mean length in steps of a failure run under ``outage_model="gilbert_elliott"``: a failed
    link recovers with probability 1 / L per step. Must be >= 1 / (1 - p_fail) (the Bernoulli run length; equality
    gives back Bernoulli draws); unused by ``"bernoulli"``."""
    rician_k: float = 5.0
    """K, the Rician factor of ``|h|^2`` with ``E|h|^2 = 1`` (paper: 5)."""
    rician_k_altitude_slope: float = 0.0
    """*Open, off by default.* K grows with the pair's mean altitude z: K(z) = max(0, K + slope * (z - min_altitude))."""
    atmospheric_loss: float = 0.9
    """L_atm in (0, 1], the atmospheric attenuation factor (paper: 0.9)."""
    tx_power_dbm: float = 20.0
    """P^j, transmit power in dBm (paper: 20 dBm = 100 mW)."""
    path_loss_exponent: float = 2.0
    """alpha, the path loss exponent (paper: 2)."""
    sinr_threshold: float = 0.05
    """beta_th > 0, the SINR detection threshold, linear (paper: 0.05)."""
    noise_power: float = 1.0
    """sigma^2, the noise power in mW (paper: 1; the unit is our choice)."""
    interference_max: float = 0.5
    """I_max: the interference I ~ U(0, I_max) in mW, drawn per receiver and step (paper: 0.5)."""
    min_link_distance: float = 0.1
    """*Open.* Distances below this (metres) are raised to it in d^-alpha, so co-located UAVs give a finite SINR."""
    link_range_probability: float = 0.5
    """*Extension.* Defines the channel's usable range for ``link_mode="full_in_range"``: the distance at which a link
    without abrupt failures (p_f = 0) is up with this probability under Eq. (1) (0.5: the median range, 36.4 m with
    the paper's constants)."""

    # --- Link models and delay (extensions, opt-in; see sb3_latentswarm.links) ---
    link_model: str = "a2a"
    """*Extension.* Which links deliver (:func:`~sb3_latentswarm.links.make_link_model`). ``"a2a"`` (default): the
    channel of Eq. (1). ``"outage"``: only the abrupt failures xi (Bernoulli(1 - p_f), or the Gilbert-Elliott chain
    with ``outage_model="gilbert_elliott"``), whatever the distance. ``"distance"``: a link within ``link_range``
    metres (3D) delivers unless xi fails it, one beyond never."""
    link_range: float = 30.0
    """*Extension.* The range in metres of ``link_model="distance"`` (and its ``link_mode="full_in_range"``)."""
    message_delay: int = 0
    """*Extension, opt-in.* D >= 0, the delay in steps of a message that gets through (``"fixed"``) or its mean
    (``"uniform"``, ``"geometric"``). 0 (default, the paper's): every message arrives at the step it is sent, and the
    observation has no ``link_age`` key. See ``docs/concepts.md``, "Delayed messages"."""
    message_delay_model: str = "fixed"
    """*Extension.* How the delay of each message (per directed link and step) is chosen: ``"fixed"`` (d = D),
    ``"uniform"`` (d uniform on {0, ..., 2D}) or ``"geometric"`` (P(d >= k) = q^k, q = D / (1 + D))."""
    message_expiry: int = 10
    """*Extension.* E, the largest delay in steps at which a message still arrives; later ones are lost. With
    ``"fixed"`` delays it must be >= ``message_delay``; unused when ``message_delay = 0``."""

    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    """Free-form metadata carried with the config (ignored by the env)."""

    def __post_init__(self) -> None:
        self._validate()

    # ------------------------------------------------------------------ derived quantities
    @property
    def tx_power_mw(self) -> float:
        """Transmit power P in mW."""
        return dbm_to_mw(self.tx_power_dbm)

    @property
    def footprint_width(self) -> int:
        """Width in cells of the square sensor footprint, 2r + 1."""
        return 2 * self.sensor_range + 1

    @property
    def n_cells(self) -> int:
        """Number of cells ``|X|`` of the grid."""
        return self.grid_width * self.grid_height

    @property
    def arena_size(self) -> tuple[float, float]:
        """Horizontal size of the arena (x, y) in metres."""
        return self.grid_width * self.cell_size, self.grid_height * self.cell_size

    def replace(self, **changes: Any) -> SwarmConfig:
        """Return a copy with ``changes`` applied (validated again)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise TypeError(f"Unknown SwarmConfig field(s): {sorted(unknown)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """All fields as a plain dict (for logging and saving)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "extra"}

    # ------------------------------------------------------------------ validation
    def _validate(self) -> None:
        def check_int(name: str, low: int, high: int) -> None:
            # NumPy integers (np.int64(3)) are accepted as the Python ints they equal
            object.__setattr__(self, name, checks.check_int(f"SwarmConfig.{name}", getattr(self, name), low, high))

        def check_float(name: str, low: float, high: float, low_open: bool = False, high_open: bool = False) -> None:
            value = checks.check_float(f"SwarmConfig.{name}", getattr(self, name), low, high, low_open, high_open)
            object.__setattr__(self, name, value)

        for name, (low, high) in INT_BOUNDS.items():
            check_int(name, low, high)
        fw = 2 * self.sensor_range + 1
        if self.grid_width < fw or self.grid_height < fw:
            raise ValueError(
                f"SwarmConfig grid ({self.grid_width}x{self.grid_height}) must be at least the sensor footprint "
                f"({fw}x{fw} for sensor_range={self.sensor_range})"
            )
        if self.num_obstacles > self.grid_width * self.grid_height:
            raise ValueError(
                f"SwarmConfig.num_obstacles must be in [0, {self.grid_width * self.grid_height}] (the number of cells), "
                f"got {self.num_obstacles}"
            )
        for name, (float_low, float_high, low_open) in FLOAT_BOUNDS.items():
            check_float(name, float_low, float_high, low_open=low_open)
        check_float("max_altitude", self.min_altitude, FLOAT_BOUNDS["max_altitude"][1])
        check_float("initial_altitude", self.min_altitude, self.max_altitude)
        check_float("link_range_probability", 0.0, 1.0, low_open=True, high_open=True)
        if self.action_frame not in ACTION_FRAMES:
            raise ValueError(f"SwarmConfig.action_frame must be one of {ACTION_FRAMES}, got {self.action_frame!r}")
        if self.link_mode not in LINK_MODES:
            raise ValueError(f"SwarmConfig.link_mode must be one of {LINK_MODES}, got {self.link_mode!r}")
        if self.start_region not in START_REGIONS:
            raise ValueError(f"SwarmConfig.start_region must be one of {START_REGIONS}, got {self.start_region!r}")
        check_float("start_region_size", 0.0, math.inf, low_open=True)
        shorter_side = min(self.grid_width, self.grid_height) * self.cell_size
        if self.start_region in ("corner", "random_corner") and self.start_region_size > shorter_side:
            raise ValueError(
                f"SwarmConfig.start_region_size must be in (0, {shorter_side}] (the arena's shorter side in metres) for "
                f"start_region={self.start_region!r}, got {self.start_region_size}"
            )
        if self.link_model not in LINK_MODELS:
            raise ValueError(f"SwarmConfig.link_model must be one of {LINK_MODELS}, got {self.link_model!r}")
        if self.message_delay_model not in DELAY_MODELS:
            raise ValueError(
                f"SwarmConfig.message_delay_model must be one of {DELAY_MODELS}, got {self.message_delay_model!r}"
            )
        if self.message_delay_model == "fixed" and self.message_expiry < self.message_delay:
            raise ValueError(
                f"SwarmConfig.message_expiry must be an int in [{self.message_delay}, {INT_BOUNDS['message_expiry'][1]}] "
                f"(at least message_delay={self.message_delay}, or every message is lost) with "
                f"message_delay_model='fixed', got {self.message_expiry}"
            )
        if self.outage_model not in OUTAGE_MODELS:
            raise ValueError(f"SwarmConfig.outage_model must be one of {OUTAGE_MODELS}, got {self.outage_model!r}")
        check_float("mean_outage_steps", 1.0, 1e6)
        if self.outage_model == "gilbert_elliott" and self.p_fail < 1.0:
            bernoulli_run = 1.0 / (1.0 - self.p_fail)
            if self.mean_outage_steps < bernoulli_run * (1.0 - 1e-12):
                raise ValueError(
                    f"SwarmConfig.mean_outage_steps must be >= 1 / (1 - p_fail) = {bernoulli_run:.6g} steps (the "
                    f"Bernoulli run length) for outage_model='gilbert_elliott' with p_fail={self.p_fail}, got "
                    f"{self.mean_outage_steps}; lower p_fail or raise mean_outage_steps"
                )


def resolve_config(config: SwarmConfig | None = None, **overrides: Any) -> SwarmConfig:
    """``config`` (``SwarmConfig()`` if ``None``) with ``overrides`` applied: the env constructors' convention.

    :raises TypeError: ``config`` is not a ``SwarmConfig``, or an override is not a field.
    """
    if config is None:
        config = SwarmConfig()
    elif not isinstance(config, SwarmConfig):
        raise TypeError(f"config must be a SwarmConfig or None, got {type(config).__name__} ({config!r})")
    return config.replace(**overrides) if overrides else config
