"""Baselines to compare the learned swarm with, usable wherever a model is (``evaluate``, ``predict``): non-learned
planners and independent recurrent PPO without messages."""

from sb3_latentswarm.baselines.independent import IndependentRecurrentPPO, OwnObservationVecEnv, train_independent_ppo
from sb3_latentswarm.baselines.planners import (
    COORDINATED_PLANNERS,
    MESSAGE_FREE_PLANNERS,
    FrontierPlanner,
    FrontierState,
    LawnmowerPlanner,
    RandomPlanner,
    RandomState,
    RandomStripPlanner,
    SpiralPlanner,
    SweepPlanner,
    WaypointState,
)
from sb3_latentswarm.utils.threads import apply_default_torch_threads_once

apply_default_torch_threads_once()

__all__ = [
    "COORDINATED_PLANNERS",
    "MESSAGE_FREE_PLANNERS",
    "FrontierPlanner",
    "FrontierState",
    "IndependentRecurrentPPO",
    "LawnmowerPlanner",
    "OwnObservationVecEnv",
    "RandomPlanner",
    "RandomState",
    "RandomStripPlanner",
    "SpiralPlanner",
    "SweepPlanner",
    "WaypointState",
    "train_independent_ppo",
]
