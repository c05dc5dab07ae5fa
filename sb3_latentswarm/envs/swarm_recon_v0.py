"""PettingZoo-style versioned entry point: ``from sb3_latentswarm.envs import swarm_recon_v0``.

``swarm_recon_v0.parallel_env(**kwargs)`` builds a :class:`~sb3_latentswarm.envs.swarm_recon.SwarmReconEnv`
(``ParallelEnv``); ``swarm_recon_v0.env(**kwargs)`` wraps it as an AEC env (``pettingzoo.utils.parallel_to_aec``).
Keyword arguments: ``config``, ``render_mode`` and any ``SwarmConfig`` field.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec

from sb3_latentswarm.envs.swarm_recon import SwarmReconEnv, parallel_env

__all__ = ["SwarmReconEnv", "env", "parallel_env", "raw_env"]

raw_env = SwarmReconEnv


def env(**kwargs: Any):
    """The swarm environment as a PettingZoo AEC env (agents act in turn; the step happens after the last one)."""
    return parallel_to_aec(parallel_env(**kwargs))
