"""Shared building blocks of the latent-swarm algorithm: latent state, swarm rollout buffer, schedules, ValueNorm.

The names are loaded on first use (PEP 562), so that importing a torch-free module of this package
(``common.schedules``, ``common.checks``) does not import torch.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "SwarmRolloutBuffer": "sb3_latentswarm.common.buffers",
    "StepSchedule": "sb3_latentswarm.common.schedules",
    "paper_learning_rate": "sb3_latentswarm.common.schedules",
    "LatentState": "sb3_latentswarm.common.type_aliases",
    "SwarmRolloutBufferSamples": "sb3_latentswarm.common.type_aliases",
    "ValueNorm": "sb3_latentswarm.common.value_norm",
}

if TYPE_CHECKING:
    from sb3_latentswarm.common.buffers import SwarmRolloutBuffer
    from sb3_latentswarm.common.schedules import StepSchedule, paper_learning_rate
    from sb3_latentswarm.common.type_aliases import LatentState, SwarmRolloutBufferSamples
    from sb3_latentswarm.common.value_norm import ValueNorm


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'sb3_latentswarm.common' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = [
    "LatentState",
    "StepSchedule",
    "SwarmRolloutBuffer",
    "SwarmRolloutBufferSamples",
    "ValueNorm",
    "paper_learning_rate",
]
