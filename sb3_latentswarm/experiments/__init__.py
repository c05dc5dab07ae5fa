"""Multi-seed experiments: training seeds x variants x grid points on Ray Tune, with across-seed intervals.

``run_sweep`` (and ``sb3-latentswarm sweep``) trains every (variant, training seed, grid point) as one Ray Tune trial,
evaluates each trained model on held-out seeds under the evaluation cells, and writes the per-run scores and their
IQM and mean with stratified-bootstrap confidence intervals. Ray is needed only to run trials (extra ``sweep``); the
aggregation (:mod:`.aggregate`) and the report (:mod:`.report`) need NumPy, SciPy, pandas and matplotlib.
"""

from sb3_latentswarm.experiments.aggregate import (
    aggregate_scores,
    interquartile_mean,
    interval_estimates,
    mean,
    stratified_bootstrap_ci,
)
from sb3_latentswarm.experiments.report import write_report
from sb3_latentswarm.experiments.sweep import check_address, make_spec, plan_trials, run_sweep
from sb3_latentswarm.experiments.trial import (
    EVAL_SEED_BASE,
    SCORE_METRICS,
    VARIANTS,
    EvalSet,
    default_eval_sets,
    train_and_evaluate,
)

__all__ = [
    "EVAL_SEED_BASE",
    "SCORE_METRICS",
    "VARIANTS",
    "EvalSet",
    "aggregate_scores",
    "check_address",
    "default_eval_sets",
    "interquartile_mean",
    "interval_estimates",
    "make_spec",
    "mean",
    "plan_trials",
    "run_sweep",
    "stratified_bootstrap_ci",
    "train_and_evaluate",
    "write_report",
]
