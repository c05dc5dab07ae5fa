"""LatentSwarmPPO and its policy."""

from sb3_latentswarm.latent_ppo.latent_ppo import LatentSwarmPPO, NonFiniteLossError, validate_algorithm_kwargs
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
from sb3_latentswarm.utils.threads import apply_default_torch_threads_once

apply_default_torch_threads_once()

__all__ = ["LatentSwarmPPO", "LatentSwarmPolicy", "NonFiniteLossError", "validate_algorithm_kwargs"]
