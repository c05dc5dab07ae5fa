"""The paper's numbers: Table I (left: the five conditions at p_f = 0.3; right: the p_f sweep), and our summaries
beside them."""

from __future__ import annotations

import math
from typing import Any

import pandas as pd

from sb3_latentswarm.evaluation.conditions import CONDITION_LABELS
from sb3_latentswarm.evaluation.tables import COLLISIONS_COLUMN, COVERAGE_COLUMN, STEPS_COLUMN, format_mean_std

__all__ = ["PAPER_P_FAILS", "PAPER_TABLE1_CONDITIONS", "PAPER_TABLE1_P_FAIL", "side_by_side"]

PAPER_P_FAILS = (0.0, 0.05, 0.15, 0.3, 0.5)
"""The link failure probabilities of the robustness sweep (Table I, right)."""


def _paper_table(rows: list[tuple], key: str) -> pd.DataFrame:
    """Build a paper table: numeric columns plus the strings as printed in the paper."""
    records = []
    for key_value, cov_mean, cov_std, coll_mean, coll_std, steps_mean, steps_std in rows:
        record: dict[str, Any] = {key: key_value}
        if key == "condition":
            record["label"] = CONDITION_LABELS[key_value]
        record[COVERAGE_COLUMN] = format_mean_std(cov_mean, cov_std, 2)
        if key == "condition":
            record[COLLISIONS_COLUMN] = format_mean_std(coll_mean, coll_std, 2)
        record[STEPS_COLUMN] = (
            "N/A" if math.isnan(steps_mean) else format_mean_std(steps_mean, steps_std, 2 if key == "condition" else 0)
        )
        record.update(
            coverage_mean=cov_mean,
            coverage_std=cov_std,
            collisions_mean=coll_mean,
            collisions_std=coll_std,
            steps_to_90_mean=steps_mean,
            steps_to_90_std=steps_std,
        )
        records.append(record)
    return pd.DataFrame(records)


_NAN = math.nan
PAPER_TABLE1_CONDITIONS = _paper_table(
    [
        ("full_comm", 92.40, 2.64, 10.30, 12.54, 732.71, 90.58),
        ("proposed", 90.98, 2.92, 8.70, 8.49, 692.71, 189.04),
        ("no_memory", 81.90, 5.51, 41.50, 24.08, _NAN, _NAN),
        ("no_comm", 83.44, 4.80, 31.90, 21.85, _NAN, _NAN),
        ("no_predictor", 70.30, 3.61, 54.90, 26.12, _NAN, _NAN),
    ],
    key="condition",
)
"""Table I (left) of the paper, p_f = 0.3, 10 Monte Carlo runs; "N/A": no run reached 90 % coverage."""

PAPER_TABLE1_P_FAIL = _paper_table(
    [
        (0.00, 91.66, 2.33, _NAN, _NAN, 665.0, _NAN),
        (0.05, 92.59, 2.04, _NAN, _NAN, 593.0, _NAN),
        (0.15, 91.36, 2.00, _NAN, _NAN, 758.0, _NAN),
        (0.30, 90.89, 2.18, _NAN, _NAN, 651.0, _NAN),
        (0.50, 90.96, 2.17, _NAN, _NAN, 677.0, _NAN),
    ],
    key="p_fail",
)
"""Table I (right) of the paper: the proposed model under a sweep of p_f (steps to 90 % without a std)."""


def side_by_side(summary: pd.DataFrame, paper: pd.DataFrame | None = None) -> pd.DataFrame:
    """Our formatted columns next to the paper's, matched on the paper table's key (``condition`` or ``p_fail``).

    :param summary: the output of :func:`summarize` grouped by ``condition`` or by ``p_fail``
    :param paper: :data:`PAPER_TABLE1_CONDITIONS` or :data:`PAPER_TABLE1_P_FAIL` (default: by the summary's key)
    :return: key column, then for each formatted column of the paper table ``"<column>"`` (ours) and
        ``"<column> (paper)"``; rows in the summary's order, "-" where the paper has no such row
    """
    if paper is None:
        paper = PAPER_TABLE1_CONDITIONS if "condition" in summary.columns else PAPER_TABLE1_P_FAIL
    key = "condition" if "condition" in paper.columns else "p_fail"
    if key not in summary.columns:
        raise ValueError(f"The summary has no {key!r} column to match the paper table on; columns: {list(summary.columns)}")
    text_columns = [c for c in (COVERAGE_COLUMN, COLLISIONS_COLUMN, STEPS_COLUMN) if c in paper.columns]
    paper_rows = {(round(float(v), 6) if key == "p_fail" else v): i for i, v in enumerate(paper[key])}
    records = []
    for _, row in summary.iterrows():
        value = row[key]
        match = paper_rows.get(round(float(value), 6) if key == "p_fail" else value)
        record: dict[str, Any] = {key: value}
        if key == "condition":
            record["label"] = CONDITION_LABELS.get(value, value)
        for column in text_columns:
            record[column] = row[column]
            record[f"{column} (paper)"] = "-" if match is None else paper[column].iloc[match]
        records.append(record)
    return pd.DataFrame(records)


