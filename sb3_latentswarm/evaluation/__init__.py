"""Evaluation harness: the test-time conditions of Sec. IV, the metrics of Table I, and the paper's numbers.

One module per job:

=====================================================  ========================================================
:mod:`~sb3_latentswarm.evaluation.conditions`          the conditions as a public table (:data:`CONDITION_TABLE`):
                                                       link mode and policy switches of each
:mod:`~sb3_latentswarm.evaluation.runner`              :func:`evaluate` and friends: episodes on the batched core
                                                       (:class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`)
:mod:`~sb3_latentswarm.evaluation.actors`              the policy (with diagnostics) or any recurrent ``predict``
:mod:`~sb3_latentswarm.evaluation.diagnostics`         per-episode map and message errors, dropout statistics
:mod:`~sb3_latentswarm.evaluation.tables`              Table I's format (:func:`summarize`) and markdown tables
:mod:`~sb3_latentswarm.evaluation.paper`               the paper's Table I and :func:`side_by_side`
:mod:`~sb3_latentswarm.evaluation.adapted`             episodes on an adapted env in its own metrics
                                                       (:func:`~sb3_latentswarm.evaluation.adapted.evaluate_adapted`)
=====================================================  ========================================================
"""

from sb3_latentswarm.evaluation.conditions import (
    CONDITION_LABELS,
    CONDITION_TABLE,
    CONDITIONS,
    EXTRA_CONDITIONS,
    Condition,
    check_condition,
    condition_config,
    policy_switches,
)
from sb3_latentswarm.evaluation.diagnostics import DEPTH_BINS, DEPTH_COLUMNS, DIAGNOSTIC_COLUMNS
from sb3_latentswarm.evaluation.paper import PAPER_P_FAILS, PAPER_TABLE1_CONDITIONS, PAPER_TABLE1_P_FAIL, side_by_side
from sb3_latentswarm.evaluation.runner import (
    EPISODE_COLUMNS,
    HELD_OUT_SEED,
    check_held_out,
    evaluate,
    evaluate_conditions,
    evaluate_p_fail_sweep,
    seed_range,
)
from sb3_latentswarm.evaluation.tables import COLLISIONS_COLUMN, COVERAGE_COLUMN, STEPS_COLUMN, summarize, to_markdown

__all__ = [
    "COLLISIONS_COLUMN",
    "CONDITIONS",
    "CONDITION_LABELS",
    "CONDITION_TABLE",
    "COVERAGE_COLUMN",
    "Condition",
    "DEPTH_BINS",
    "DEPTH_COLUMNS",
    "DIAGNOSTIC_COLUMNS",
    "EPISODE_COLUMNS",
    "EXTRA_CONDITIONS",
    "HELD_OUT_SEED",
    "PAPER_P_FAILS",
    "PAPER_TABLE1_CONDITIONS",
    "PAPER_TABLE1_P_FAIL",
    "STEPS_COLUMN",
    "check_condition",
    "check_held_out",
    "condition_config",
    "evaluate",
    "evaluate_conditions",
    "evaluate_p_fail_sweep",
    "policy_switches",
    "seed_range",
    "side_by_side",
    "summarize",
    "to_markdown",
]
