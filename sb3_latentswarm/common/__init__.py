"""Deprecated alias of 0.1's ``sb3_latentswarm.common`` (removed in 0.3).

Its parts moved in 0.2: the algorithm's building blocks (``LatentState``, ``SwarmRolloutBuffer``, ``ValueNorm``,
``StepSchedule``, ``paper_learning_rate``) to :mod:`sb3_latentswarm.latent_ppo`, plumbing to
:mod:`sb3_latentswarm.utils`. The names still load from here, on first use (PEP 562), with a ``DeprecationWarning``.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

from sb3_latentswarm._lazy import lazy_exports

_EXPORTS = {  # the module that defines them -> public names
    "sb3_latentswarm.latent_ppo.buffers": ("SwarmRolloutBuffer",),
    "sb3_latentswarm.latent_ppo.schedules": ("StepSchedule", "paper_learning_rate"),
    "sb3_latentswarm.latent_ppo.type_aliases": ("LatentState", "SwarmRolloutBufferSamples"),
    "sb3_latentswarm.latent_ppo.value_norm": ("ValueNorm",),
}

if TYPE_CHECKING:
    from sb3_latentswarm.latent_ppo.buffers import SwarmRolloutBuffer
    from sb3_latentswarm.latent_ppo.schedules import StepSchedule, paper_learning_rate
    from sb3_latentswarm.latent_ppo.type_aliases import LatentState, SwarmRolloutBufferSamples
    from sb3_latentswarm.latent_ppo.value_norm import ValueNorm


_lazy_getattr, __dir__ = lazy_exports(__name__, _EXPORTS)


def __getattr__(name: str) -> Any:
    value = _lazy_getattr(name)
    warnings.warn(
        f"sb3_latentswarm.common.{name} moved to {value.__module__}; the old path will be removed in 0.3",
        DeprecationWarning,
        stacklevel=2,
    )
    return value


__all__ = [
    "LatentState",
    "StepSchedule",
    "SwarmRolloutBuffer",
    "SwarmRolloutBufferSamples",
    "ValueNorm",
    "paper_learning_rate",
]
