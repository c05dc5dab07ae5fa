"""sb3-latentswarm: latent semantic state estimation for UAV swarms under intermittent connectivity.

A Stable-Baselines3 extension implementing Karakasis and Saad, "Latent Semantic State Estimation for Reliable Swarming
of UAVs under Intermittent Connectivity": a PettingZoo swarm-reconnaissance env with the paper's air-to-air channel,
and ``LatentSwarmPPO``, a subclass of sb3-contrib's ``RecurrentPPO``.

Importing the package sets torch to one CPU thread (unless ``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` is set): see
:mod:`sb3_latentswarm.common.threads` for the measurement behind it.
"""

from sb3_latentswarm.channel import A2AChannel, link_probability
from sb3_latentswarm.common.schedules import StepSchedule, paper_learning_rate
from sb3_latentswarm.common.threads import apply_default_torch_threads
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env, parallel_env
from sb3_latentswarm.evaluation import evaluate, summarize
from sb3_latentswarm.latent_ppo import LatentSwarmPolicy, LatentSwarmPPO
from sb3_latentswarm.version import __version__

apply_default_torch_threads()

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

