"""The observation contract between the env and everything that acts on it (the latent policy, the planners, the
independent baseline), named once: the observation keys, the layout of the proprioceptive vector e_t, and reading a
vec-env or PettingZoo observation.

The batched core (:class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`) produces the observations with these
names; the policy and the planners read them with the same names. NumPy only, so the env does not import torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

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
