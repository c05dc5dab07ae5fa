"""LatentSwarmPPO and its policy.

The names load on first use (PEP 562): the package's light modules, such as the learning-rate schedules the presets
name, import without torch, so that ``sb3-latentswarm --help`` stays fast. Loading the algorithm loads the envs,
which apply the package's torch thread default (:mod:`sb3_latentswarm.utils.threads`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sb3_latentswarm._lazy import lazy_exports

_EXPORTS = {
    "sb3_latentswarm.latent_ppo.latent_ppo": ("LatentSwarmPPO", "validate_algorithm_kwargs"),
    "sb3_latentswarm.latent_ppo.policies": ("LatentSwarmPolicy",),
    "sb3_latentswarm.latent_ppo.update": ("NonFiniteLossError",),
}

if TYPE_CHECKING:
    from sb3_latentswarm.latent_ppo.latent_ppo import LatentSwarmPPO, validate_algorithm_kwargs
    from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
    from sb3_latentswarm.latent_ppo.update import NonFiniteLossError

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["LatentSwarmPPO", "LatentSwarmPolicy", "NonFiniteLossError", "validate_algorithm_kwargs"]
