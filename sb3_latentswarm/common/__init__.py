"""Shared building blocks of the latent-swarm algorithm: latent-state types, the swarm rollout buffer, schedules."""

from sb3_latentswarm.common.buffers import SwarmRolloutBuffer
from sb3_latentswarm.common.schedules import StepSchedule, paper_learning_rate
from sb3_latentswarm.common.type_aliases import LatentState, SwarmRolloutBufferSamples

__all__ = ["LatentState", "StepSchedule", "SwarmRolloutBuffer", "SwarmRolloutBufferSamples", "paper_learning_rate"]
