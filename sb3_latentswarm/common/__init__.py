"""Shared building blocks of the latent-swarm algorithm: latent state, swarm rollout buffer, schedules, ValueNorm."""

from sb3_latentswarm.common.buffers import SwarmRolloutBuffer
from sb3_latentswarm.common.schedules import StepSchedule, paper_learning_rate
from sb3_latentswarm.common.type_aliases import LatentState, SwarmRolloutBufferSamples
from sb3_latentswarm.common.value_norm import ValueNorm

__all__ = [
    "LatentState",
    "StepSchedule",
    "SwarmRolloutBuffer",
    "SwarmRolloutBufferSamples",
    "ValueNorm",
    "paper_learning_rate",
]
