"""Multi-seed experiments: training seeds x variants x grid points on Ray Tune, with across-seed intervals.

``run_sweep(SweepSpec.create(...))`` (and ``sb3-latentswarm sweep``) trains every (variant, training seed, grid point)
as one Ray Tune trial, evaluates each trained model on held-out seeds under the evaluation cells, and writes the
per-run scores and their IQM and mean with stratified-bootstrap confidence intervals. Ray is needed only to run trials
(extra ``sweep``); the spec (:mod:`.spec`), the aggregation (:mod:`.aggregate`) and the report (:mod:`.report`) need
NumPy, SciPy, pandas and matplotlib.
"""

from sb3_latentswarm.experiments.aggregate import (
    aggregate_scores,
    interquartile_mean,
    interval_estimates,
    mean,
    stratified_bootstrap_ci,
)
from sb3_latentswarm.experiments.report import finished_trials, write_report
from sb3_latentswarm.experiments.spec import SweepSpec, trial_id
from sb3_latentswarm.experiments.sweep import check_cluster, check_storage, plan_trials, run_sweep
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
    "SweepSpec",
    "aggregate_scores",
    "check_cluster",
    "check_storage",
    "default_eval_sets",
    "finished_trials",
    "interquartile_mean",
    "interval_estimates",
    "mean",
    "plan_trials",
    "run_sweep",
    "stratified_bootstrap_ci",
    "train_and_evaluate",
    "trial_id",
    "write_report",
]
