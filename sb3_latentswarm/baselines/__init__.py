"""Baselines to compare the learned swarm with, usable wherever a model is (``evaluate``, ``predict``): non-learned
planners and independent recurrent PPO without messages."""

from sb3_latentswarm.baselines.independent import IndependentRecurrentPPO, OwnObservationVecEnv, train_independent_ppo
from sb3_latentswarm.baselines.planners import (
    FrontierPlanner,
    FrontierState,
    LawnmowerPlanner,
    LawnmowerState,
    RandomPlanner,
    RandomState,
)

__all__ = [
    "FrontierPlanner",
    "FrontierState",
    "IndependentRecurrentPPO",
    "LawnmowerPlanner",
    "LawnmowerState",
    "OwnObservationVecEnv",
    "RandomPlanner",
    "RandomState",
    "train_independent_ppo",
]
