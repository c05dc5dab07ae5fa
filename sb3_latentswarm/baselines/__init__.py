"""Non-learned planners to compare the learned policy with, usable wherever a model is (``evaluate``, ``predict``)."""

from sb3_latentswarm.baselines.planners import (
    FrontierPlanner,
    FrontierState,
    LawnmowerPlanner,
    LawnmowerState,
    RandomPlanner,
    RandomState,
)

__all__ = ["FrontierPlanner", "FrontierState", "LawnmowerPlanner", "LawnmowerState", "RandomPlanner", "RandomState"]
