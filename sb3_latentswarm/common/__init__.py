"""Shared building blocks of the latent-swarm algorithm: latent state, swarm rollout buffer, schedules, ValueNorm.

The names are loaded on first use (PEP 562), so that importing a torch-free module of this package
(``common.schedules``, ``common.checks``) does not import torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sb3_latentswarm._lazy import lazy_exports

_EXPORTS = {  # the module that defines them -> public names
    "sb3_latentswarm.common.buffers": ("SwarmRolloutBuffer",),
    "sb3_latentswarm.common.schedules": ("StepSchedule", "paper_learning_rate"),
    "sb3_latentswarm.common.type_aliases": ("LatentState", "SwarmRolloutBufferSamples"),
    "sb3_latentswarm.common.value_norm": ("ValueNorm",),
}

if TYPE_CHECKING:
    from sb3_latentswarm.common.buffers import SwarmRolloutBuffer
    from sb3_latentswarm.common.schedules import StepSchedule, paper_learning_rate
    from sb3_latentswarm.common.type_aliases import LatentState, SwarmRolloutBufferSamples
    from sb3_latentswarm.common.value_norm import ValueNorm


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


__all__ = [
    "LatentState",
    "StepSchedule",
    "SwarmRolloutBuffer",
    "SwarmRolloutBufferSamples",
    "ValueNorm",
    "paper_learning_rate",
]
