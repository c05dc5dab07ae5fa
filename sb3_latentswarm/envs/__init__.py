"""The swarm reconnaissance environment (PettingZoo ``ParallelEnv``) and its SB3 vectorization (SuperSuit)."""

from sb3_latentswarm.envs import swarm_recon_v0
from sb3_latentswarm.envs.swarm_recon import ACTOR_OBS_KEYS, OBS_KEYS, STATE_OBS_KEYS, SwarmReconEnv, parallel_env
from sb3_latentswarm.envs.vec_env import SwarmVecEnv, make_vec_env

__all__ = [
    "ACTOR_OBS_KEYS",
    "OBS_KEYS",
    "STATE_OBS_KEYS",
    "SwarmReconEnv",
    "SwarmVecEnv",
    "make_vec_env",
    "parallel_env",
    "swarm_recon_v0",
]
