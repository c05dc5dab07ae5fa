"""Start positions of the swarm at reset (``SwarmConfig.start_region``), for one swarm or a batch of swarms.

``"uniform"`` (the paper's random placement) draws every UAV uniformly over the arena ``[0, X] x [0, Y]``; ``"corner"``
(extension) draws every UAV uniformly in the common launch square ``[0, s] x [0, s]``, ``s = start_region_size``, so
the start positions neither split the map nor tell the agents apart; ``"random_corner"`` (extension) draws the same
launch square at one of the arena's four corners, the corner drawn per episode, so that no fixed convention learnt from
one corner splits the work. All UAVs start at ``initial_altitude``.
"""

from __future__ import annotations

import numpy as np

from sb3_latentswarm.config import SwarmConfig

__all__ = ["sample_start_positions"]


def sample_start_positions(config: SwarmConfig, rng: np.random.Generator, n_swarms: int = 1) -> np.ndarray:
    """Draw the start positions of ``n_swarms`` swarms of ``config.n_agents`` UAVs.

    Consumes exactly one ``rng.random((n_swarms, N, 2))`` call in ``"uniform"`` and ``"corner"`` (the draw order of the
    env's reset; with ``n_swarms=1`` it gives the same positions as the paper-default env always did for the same
    seed); ``"random_corner"`` then draws each swarm's corner with one ``rng.integers(4, size=n_swarms)``.

    :param config: the swarm configuration (``start_region``, ``start_region_size``, arena, ``initial_altitude``).
    :param rng: numpy random generator.
    :param n_swarms: number of swarms B drawn from ``rng`` in one call.
    :return: positions in metres, float64 array of shape (B, N, 3).
    """
    if config.start_region in ("corner", "random_corner"):
        extent = (config.start_region_size, config.start_region_size)
    else:
        extent = config.arena_size
    positions = np.empty((n_swarms, config.n_agents, 3))
    positions[..., :2] = rng.random((n_swarms, config.n_agents, 2)) * extent
    if config.start_region == "random_corner":
        # corner k: bit 0 mirrors x (x -> X - x), bit 1 mirrors y; k = 0 is the (0, 0) corner of "corner"
        corner = rng.integers(4, size=n_swarms)
        arena = np.asarray(config.arena_size, dtype=np.float64)
        mirror = np.stack([corner & 1, corner >> 1], axis=-1).astype(bool)[:, None, :]  # (B, 1, 2)
        positions[..., :2] = np.where(mirror, arena - positions[..., :2], positions[..., :2])
    positions[..., 2] = config.initial_altitude
    return positions
