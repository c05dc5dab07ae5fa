"""The observation contract between the env and everything that acts on it (the latent policy, the planners, the
independent baseline), named once: the observation keys, the layout of the proprioceptive vector e_t, and reading a
vec-env or PettingZoo observation.

Two layouts share the actor's keys and differ in the global state (:func:`observation_layout` tells them apart):

==========  ======================================================  ===================================================
            swarm env (:data:`SWARM_LAYOUT`)                          any ``ParallelEnv`` through the adapter
==========  ======================================================  ===================================================
actor       ``local_obs`` o_t, ``proprio`` e_t, ``link_row``          the same; ``proprio`` may be 0-dim; ``position``
                                                                     (3,) only where the user gave positions
p_t         the first 3 entries of ``proprio``                        ``position``, or nothing (0 columns)
critic      ``swarm_proprio`` (N, 8), ``global_map`` (H, W)           ``global_state`` (S,) float
referent    ``global_map``, the occupancy estimate M_hat_t            ``referent`` (R,) float, or ``global_state``
==========  ======================================================  ===================================================

The map decoder D_eta reconstructs the referent with the same loss in both (Eq. (3), a mean squared error).

The batched core (:class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`) produces the observations with these
names; the policy and the planners read them with the same names. NumPy only, so the env does not import torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from sb3_latentswarm.config import SwarmConfig

#: Observation keys, in the order of the env's ``Dict`` space.
OBS_KEYS = ("local_obs", "proprio", "link_row", "swarm_proprio", "global_map")
#: Keys an actor may use at execution time (decentralized): its sensor patch o_t, its own state e_t, which links arrived.
ACTOR_OBS_KEYS = ("local_obs", "proprio", "link_row")
#: Keys that form the global state s_t (the centralized critic and the map loss only, during training).
STATE_OBS_KEYS = ("swarm_proprio", "global_map")
#: Opt-in key (``SwarmConfig.message_delay > 0`` only), after ``link_row``: ``link_age[j]`` = how many steps late the
#: message of peer ``j`` that arrived at this step is (0 = on time, and 0 where ``link_row[j] = 0``: nothing arrived).
LINK_AGE_KEY = "link_age"


#: Adapted envs: the agent's position p_t in the units of the user's link model (only when a position function is given).
POSITION_KEY = "position"
#: Adapted envs: the global state s_t the centralized critic reads (default ``env.state()``), flattened, float32.
GLOBAL_STATE_KEY = "global_state"
#: Adapted envs: the semantic referent D_eta reconstructs, when it is not the global state itself, flattened, float32.
REFERENT_KEY = "referent"


class ObservationLayout(NamedTuple):
    """Which keys of a ``Dict`` observation space play which role (:func:`observation_layout`)."""

    actor_keys: tuple[str, ...]
    """What an agent reads at execution time (the latent step)."""
    state_keys: tuple[str, ...]
    """The global state, equal for every agent of a swarm (stored once per swarm); the critic and the map loss."""
    critic_keys: tuple[str, ...]
    """What the centralized critic reads, a subset of ``state_keys``."""
    referent_key: str
    """What the map decoder D_eta reconstructs (the target of L_map), one of ``state_keys``."""
    position_key: str | None
    """Where p_t comes from: ``"proprio"`` (its first :data:`POSITION_DIMS` entries), :data:`POSITION_KEY`, or ``None``
    (the map update gets no position)."""

    @property
    def position_dims(self) -> int:
        """Columns of p_t in the map update: :data:`POSITION_DIMS`, or 0 without a position."""
        return 0 if self.position_key is None else POSITION_DIMS


def observation_layout(observation_space: Any) -> ObservationLayout:
    """The layout of a ``Dict`` observation space: :data:`SWARM_LAYOUT` when it holds ``global_map``, else the adapted
    layout (``global_state``, optional ``referent`` and ``position``).

    :raises TypeError: not a ``Dict`` space
    :raises ValueError: a required key is missing, with what the space has
    """
    keys = getattr(observation_space, "spaces", None)
    if not isinstance(keys, dict):
        raise TypeError(
            f"LatentSwarmPolicy needs a Dict observation space (sb3_latentswarm.make_vec_env for the swarm env, "
            "sb3_latentswarm.envs.make_adapted_vec_env for any PettingZoo ParallelEnv), got "
            f"{type(observation_space).__name__}"
        )
    if "global_map" in keys:
        layout = SWARM_LAYOUT
    else:
        referent = REFERENT_KEY if REFERENT_KEY in keys else GLOBAL_STATE_KEY
        state_keys = (GLOBAL_STATE_KEY,) if referent == GLOBAL_STATE_KEY else (GLOBAL_STATE_KEY, REFERENT_KEY)
        position = POSITION_KEY if POSITION_KEY in keys else None
        layout = ObservationLayout(ACTOR_OBS_KEYS + ((POSITION_KEY,) if position else ()), state_keys,
                                   (GLOBAL_STATE_KEY,), referent, position)
    missing = [key for key in layout.actor_keys + layout.state_keys if key not in keys]
    if missing:
        raise ValueError(
            f"The observation space lacks the key(s) {missing} needed by LatentSwarmPolicy (has {list(keys)}); use "
            "sb3_latentswarm.make_vec_env (swarm env) or sb3_latentswarm.envs.make_adapted_vec_env (any ParallelEnv)"
        )
    return layout


def obs_keys(config: SwarmConfig) -> tuple[str, ...]:
    """The observation keys of ``config``'s env, in the order of its ``Dict`` space: :data:`OBS_KEYS`, plus
    :data:`LINK_AGE_KEY` after ``link_row`` when messages can be delayed."""
    if config.message_delay == 0:
        return OBS_KEYS
    return OBS_KEYS[:3] + (LINK_AGE_KEY,) + OBS_KEYS[3:]

#: Length of the proprioceptive vector e_t (``proprio``; ``swarm_proprio`` is (N, 8)).
PROPRIO_DIM = 8
# Layout of e_t and of the core's kinematic state (B, N, 8), of which e_t is the normalized copy (proprio_normalization):
POSITION_DIMS = 3
PROPRIO_POSITION = slice(0, POSITION_DIMS)
"""x, y, z in metres; in e_t: x / x_max, y / y_max, (z - z_min) / (z_max - z_min)."""
PROPRIO_VELOCITY = slice(3, 6)
"""vx, vy, vz in m/s; in e_t: divided by (v_max, v_max, vz_max)."""
PROPRIO_HEADING = 6
"""Heading chi in radians, in [-pi, pi); in e_t: chi / pi."""
PROPRIO_ENERGY = 7
"""Energy b_t; in e_t: b_t / b_0."""

#: The swarm env's layout: p_t from e_t, the critic on ({e_t^j}, M_hat_t), D_eta reconstructs M_hat_t.
SWARM_LAYOUT = ObservationLayout(ACTOR_OBS_KEYS, STATE_OBS_KEYS, STATE_OBS_KEYS, "global_map", "proprio")


def proprio_normalization(config: SwarmConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(offset, scale)`` of shape (8,) with ``e_t = (kinematic state - offset) * scale`` (Sec. II-A's e_t).

    A field whose range is 0 (``max_altitude == min_altitude``, ``vz_max == 0``) gets scale 0: it reads 0 in e_t.
    """
    x_max, y_max = config.arena_size
    ranges = np.zeros(PROPRIO_DIM)
    ranges[PROPRIO_POSITION] = (x_max, y_max, config.max_altitude - config.min_altitude)
    ranges[PROPRIO_VELOCITY] = (config.v_max, config.v_max, config.vz_max)
    ranges[PROPRIO_HEADING] = math.pi
    ranges[PROPRIO_ENERGY] = config.initial_energy
    scale = np.divide(1.0, ranges, out=np.zeros(PROPRIO_DIM), where=ranges > 0)
    offset = np.zeros(PROPRIO_DIM)
    offset[2] = config.min_altitude  # z
    return offset, scale


def proprio_position(proprio: np.ndarray, config: SwarmConfig) -> np.ndarray:
    """Positions (..., 3) in metres from e_t of shape (..., 8): the inverse of :func:`proprio_normalization`."""
    x_max, y_max = config.arena_size
    extent = np.array([x_max, y_max, config.max_altitude - config.min_altitude])
    return proprio[..., PROPRIO_POSITION] * extent + (0.0, 0.0, config.min_altitude)


def proprio_heading(proprio: np.ndarray) -> np.ndarray:
    """Headings chi (...) in radians from e_t of shape (..., 8)."""
    return proprio[..., PROPRIO_HEADING] * np.pi


def as_vec_observation(
    observation: dict[str, Any], keys: Sequence[str] = ACTOR_OBS_KEYS, owner: str = "the policy"
) -> tuple[dict[str, np.ndarray], list[str] | None]:
    """Accept a vec-env observation or a PettingZoo one and return the ``keys`` as slot-major arrays.

    :param observation: a vec-env observation (dict of arrays with a leading slot dimension) or a PettingZoo
        observation ``{agent: {key: array}}`` of one swarm
    :param keys: the keys to keep
    :param owner: named in the error message
    :return: (dict of arrays, the agent names in slot order when the input was PettingZoo-style, else ``None``)
    :raises ValueError: when a key is missing
    """
    agent_names = None
    if observation and all(isinstance(value, dict) for value in observation.values()):
        agent_names = list(observation.keys())
        observation = {
            key: np.stack([observation[agent][key] for agent in agent_names])
            for key in keys
            if key in observation[agent_names[0]]
        }
    missing = [key for key in keys if key not in observation]
    if missing:
        raise ValueError(f"observation lacks the key(s) {missing}; {owner} acts on {list(keys)}")
    return {key: np.asarray(observation[key]) for key in keys}, agent_names
