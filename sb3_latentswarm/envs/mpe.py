"""What the adapter needs from MPE2 (``mpe2``, the maintained Multi-Agent Particle Environments) that the env does not
say by itself: the agents' positions (for distance links and the map update) and ``simple_spread``'s own metrics.

The functions read the world of an MPE2 ``parallel_env`` (``env.unwrapped.world``); this module does not import
``mpe2`` (install it with ``pip install sb3-latentswarm[mpe]``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["COVER_DISTANCE", "mpe_positions", "simple_spread_metrics"]

COVER_DISTANCE = 0.1
"""A landmark is covered when an agent is closer than this (MPE2's ``benchmark_data`` threshold)."""


def mpe_positions(env: Any) -> np.ndarray:
    """The agents' positions (N, 2) in MPE's world units (the arena spans about [-1, 1]^2)."""
    return np.array([agent.state.p_pos for agent in env.unwrapped.world.agents])


def simple_spread_metrics(env: Any) -> dict[str, float]:
    """``simple_spread``'s metrics at this step: the share of landmarks with an agent closer than
    :data:`COVER_DISTANCE` (``landmarks_covered``) and the number of colliding agent pairs (``collisions``; two agents
    collide when their distance is below the sum of their sizes, as MPE2's ``is_collision``).

    Through the adapter's ``metrics_fn``: ``final_landmarks_covered`` is the share covered at the end of an episode,
    ``sum_collisions`` the colliding pairs summed over its steps.
    """
    world = env.unwrapped.world
    agents = np.array([agent.state.p_pos for agent in world.agents])  # (N, 2)
    landmarks = np.array([landmark.state.p_pos for landmark in world.landmarks])  # (L, 2)
    nearest = np.linalg.norm(landmarks[:, None] - agents[None], axis=-1).min(axis=1)  # (L,)
    sizes = np.array([agent.size for agent in world.agents])
    distance = np.linalg.norm(agents[:, None] - agents[None], axis=-1)
    colliding = np.triu(distance < sizes[:, None] + sizes[None], k=1)
    return {"landmarks_covered": float((nearest < COVER_DISTANCE).mean()), "collisions": float(colliding.sum())}
