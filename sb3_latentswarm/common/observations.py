"""Observation handling shared by everything that acts (the latent policy, the planners, the independent baseline)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

ACTOR_KEYS = ("local_obs", "proprio", "link_row")
"""What a UAV may act on under decentralized execution: its sensor patch, its own state and which links arrived."""


def as_vec_observation(
    observation: dict[str, Any], keys: Sequence[str] = ACTOR_KEYS, owner: str = "the policy"
) -> tuple[dict[str, np.ndarray], list[str] | None]:
    """Accept a vec-env observation or a PettingZoo one and return the ``keys`` as slot-major arrays.

    :param observation: a vec-env observation (dict of arrays with a leading slot dimension) or a PettingZoo
        observation ``{agent: {key: array}}`` of one swarm
    :param keys: the keys to keep
    :param owner: named in the error message
    :return: (dict of arrays, the agent names in slot order when the input was PettingZoo-style, else ``None``)
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
