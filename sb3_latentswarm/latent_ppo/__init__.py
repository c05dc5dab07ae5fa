"""LatentSwarmPPO and its policy.

The names load on first use (PEP 562), so that a torch-free module of this package (``latent_ppo.schedules``) imports
without torch; the torch thread default is applied when the policy module loads.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sb3_latentswarm._lazy import lazy_exports

_EXPORTS = {  # the module that defines them -> public names
    "sb3_latentswarm.latent_ppo.latent_ppo": ("LatentSwarmPPO", "NonFiniteLossError", "validate_algorithm_kwargs"),
    "sb3_latentswarm.latent_ppo.policies": ("LatentSwarmPolicy",),
}

if TYPE_CHECKING:
    from sb3_latentswarm.latent_ppo.latent_ppo import LatentSwarmPPO, NonFiniteLossError, validate_algorithm_kwargs
    from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["LatentSwarmPPO", "LatentSwarmPolicy", "NonFiniteLossError", "validate_algorithm_kwargs"]
