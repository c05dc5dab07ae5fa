"""sb3-latentswarm: latent semantic state estimation for UAV swarms under intermittent connectivity.

A Stable-Baselines3 extension implementing Karakasis and Saad, "Latent Semantic State Estimation for Reliable Swarming
of UAVs under Intermittent Connectivity": a PettingZoo swarm-reconnaissance env with the paper's air-to-air channel,
and ``LatentSwarmPPO``, a subclass of sb3-contrib's ``RecurrentPPO``.
"""

from sb3_latentswarm.channel import A2AChannel, link_probability
from sb3_latentswarm.common.schedules import StepSchedule, paper_learning_rate
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.latent_ppo import LatentSwarmPolicy, LatentSwarmPPO
from sb3_latentswarm.version import __version__

__all__ = [
    "A2AChannel",
    "LatentSwarmPPO",
    "LatentSwarmPolicy",
    "StepSchedule",
    "SwarmConfig",
    "__version__",
    "link_probability",
    "paper_learning_rate",
]


def __getattr__(name: str):
    # the env stack (PettingZoo, SuperSuit) is imported on first use, so `import sb3_latentswarm` stays light
    if name in ("make_vec_env", "SwarmReconEnv", "parallel_env"):
        from sb3_latentswarm import envs

        return getattr(envs, name)
    if name in ("evaluate", "summarize"):
        from sb3_latentswarm import evaluation

        return getattr(evaluation, name)
    raise AttributeError(f"module 'sb3_latentswarm' has no attribute {name!r}")
