"""Start positions of the swarm at reset (``SwarmConfig.start_region``), for one swarm or a batch of swarms.

``"uniform"`` (the paper's random placement) draws every UAV uniformly over the arena ``[0, X] x [0, Y]``; ``"corner"``
(extension) draws every UAV uniformly in the common launch square ``[0, s] x [0, s]``, ``s = start_region_size``, so
the start positions neither split the map nor tell the agents apart. All UAVs start at ``initial_altitude``.
"""

from __future__ import annotations

import numpy as np

from sb3_latentswarm.config import SwarmConfig

__all__ = ["sample_start_positions"]


def sample_start_positions(config: SwarmConfig, rng: np.random.Generator, n_swarms: int = 1) -> np.ndarray:
    """Draw the start positions of ``n_swarms`` swarms of ``config.n_agents`` UAVs.

    Consumes exactly one ``rng.random((n_swarms, N, 2))`` call in both regions (the draw order of the env's reset;
    with ``n_swarms=1`` it gives the same positions as the paper-default env always did for the same seed).

    :param config: the swarm configuration (``start_region``, ``start_region_size``, arena, ``initial_altitude``).
    :param rng: numpy random generator.
    :param n_swarms: number of swarms B drawn from ``rng`` in one call.
    :return: positions in metres, float64 array of shape (B, N, 3).
    """
    if config.start_region == "corner":
        extent = (config.start_region_size, config.start_region_size)
    else:
        extent = config.arena_size
    positions = np.empty((n_swarms, config.n_agents, 3))
    positions[..., :2] = rng.random((n_swarms, config.n_agents, 2)) * extent
    positions[..., 2] = config.initial_altitude
    return positions
