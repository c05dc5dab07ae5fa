"""The swarm reconnaissance environment: its batched core, the PettingZoo ``ParallelEnv`` view and the SB3 vec envs;
and the adapter that makes any PettingZoo ``ParallelEnv`` a vec env ``LatentSwarmPPO`` trains on."""

from sb3_latentswarm.envs import swarm_recon_v0
from sb3_latentswarm.envs.adapted_env import AdaptedEnv
from sb3_latentswarm.envs.batched_core import SwarmBatch
from sb3_latentswarm.envs.parallel_adapter import AdaptedVecEnv, LinkSpec, make_adapted_vec_env
from sb3_latentswarm.envs.swarm_recon import ACTOR_OBS_KEYS, OBS_KEYS, STATE_OBS_KEYS, SwarmReconEnv, parallel_env
from sb3_latentswarm.envs.vec_env import BatchedSwarmVecEnv, SwarmVecEnv, make_vec_env
from sb3_latentswarm.utils.threads import apply_default_torch_threads_once

apply_default_torch_threads_once()

__all__ = [
    "ACTOR_OBS_KEYS",
    "AdaptedEnv",
    "AdaptedVecEnv",
    "LinkSpec",
    "BatchedSwarmVecEnv",
    "OBS_KEYS",
    "STATE_OBS_KEYS",
    "SwarmBatch",
    "SwarmReconEnv",
    "SwarmVecEnv",
    "make_adapted_vec_env",
    "make_vec_env",
    "parallel_env",
    "swarm_recon_v0",
]
