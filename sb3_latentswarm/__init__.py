"""sb3-latentswarm: latent semantic state estimation for UAV swarms under intermittent connectivity.

A Stable-Baselines3 extension implementing Karakasis and Saad, "Latent Semantic State Estimation for Reliable Swarming
of UAVs under Intermittent Connectivity": a PettingZoo swarm-reconnaissance env with the paper's air-to-air channel,
and ``LatentSwarmPPO``, a subclass of sb3-contrib's ``RecurrentPPO``.

The public names below are loaded on first use (PEP 562), so that ``import sb3_latentswarm`` and
``sb3-latentswarm --help`` do not pay for importing torch and Stable-Baselines3. The package sets torch to one CPU
thread (unless ``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` is set) once, when it first loads torch-using code, or at
import if torch is already loaded: see :mod:`sb3_latentswarm.utils.threads` for the measurement behind it.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from sb3_latentswarm._lazy import lazy_exports
from sb3_latentswarm.version import __version__

# the module that defines them -> public names (the same lines as the TYPE_CHECKING block below)
_EXPORTS = {
    "sb3_latentswarm.channel": ("A2AChannel", "link_probability"),
    "sb3_latentswarm.latent_ppo.schedules": ("StepSchedule", "paper_learning_rate"),
    "sb3_latentswarm.utils.threads": ("apply_default_torch_threads",),
    "sb3_latentswarm.config": ("SwarmConfig",),
    "sb3_latentswarm.envs": ("SwarmReconEnv", "make_vec_env", "parallel_env"),
    "sb3_latentswarm.evaluation": ("evaluate", "summarize"),
    "sb3_latentswarm.latent_ppo": ("LatentSwarmPolicy", "LatentSwarmPPO"),
}

if TYPE_CHECKING:
    from sb3_latentswarm.channel import A2AChannel, link_probability
    from sb3_latentswarm.config import SwarmConfig
    from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env, parallel_env
    from sb3_latentswarm.evaluation import evaluate, summarize
    from sb3_latentswarm.latent_ppo import LatentSwarmPolicy, LatentSwarmPPO
    from sb3_latentswarm.latent_ppo.schedules import StepSchedule, paper_learning_rate


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


if "torch" in sys.modules:
    from sb3_latentswarm.utils.threads import apply_default_torch_threads_once

    apply_default_torch_threads_once()

__all__ = [
    "A2AChannel",
    "LatentSwarmPPO",
    "LatentSwarmPolicy",
    "StepSchedule",
    "SwarmConfig",
    "SwarmReconEnv",
    "__version__",
    "evaluate",
    "link_probability",
    "make_vec_env",
    "paper_learning_rate",
    "parallel_env",
    "summarize",
]
