"""Table I's format: per-condition (or per-p_f) summaries of the per-episode rows, and GitHub markdown tables."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from sb3_latentswarm.evaluation.diagnostics import EPISODE_COLUMNS

__all__ = ["COLLISIONS_COLUMN", "COVERAGE_COLUMN", "STEPS_COLUMN", "format_mean_std", "summarize", "to_markdown"]

# Names of the formatted columns of :func:`summarize` (Table I's headers).
COVERAGE_COLUMN = "Coverage (%)"
COLLISIONS_COLUMN = "Collisions"
STEPS_COLUMN = "Steps to 90%"
# Per-episode columns whose mean is also reported by summarize (NaN-ignoring): every metric after Table I's three.
_EXTRA_MEANS = EPISODE_COLUMNS[EPISODE_COLUMNS.index("steps_to_90") + 1 :]


def _mean_std(values: np.ndarray, ddof: int) -> tuple[float, float]:
    if values.size == 0:
        return math.nan, math.nan
    std = float(np.std(values, ddof=ddof)) if values.size > ddof else math.nan
    return float(np.mean(values)), std


def format_mean_std(mean: float, std: float, decimals: int) -> str:
    if math.isnan(mean):
        return "N/A"
    if math.isnan(std):
        return f"{mean:.{decimals}f}"
    return f"{mean:.{decimals}f} ± {std:.{decimals}f}"


def summarize(df: pd.DataFrame, by: str | Sequence[str] = "condition", ddof: int = 1, decimals: int = 2) -> pd.DataFrame:
    """Table I's format: per group, mean ± std of coverage and collisions, and steps to 90 % over the runs that got there.

    :param df: per-episode rows from :func:`evaluate` (columns ``coverage``, ``collisions``, ``steps_to_90``)
    :param by: the grouping column(s), e.g. ``"condition"`` or ``"p_fail"``; groups keep their order of appearance
    :param ddof: delta degrees of freedom of the std (1: the sample std; the paper does not say which)
    :param decimals: decimals of the formatted strings (the paper: 2)
    :return: one row per group: the group column(s); ``"Coverage (%)"``, ``"Collisions"`` and ``"Steps to 90%"``
        as strings (``"692.71 ± 189.04 (7/10)"``: 7 of 10 runs reached 90 %, mean ± std over those 7; ``"N/A"`` when
        none did; the std is left out when it is undefined); ``n_runs``, ``n_reached`` and numeric
        ``{coverage,collisions,steps_to_90}_{mean,std}``; and the means of the other per-episode metrics present
        (NaN-ignoring for the diagnostics). ``attrs["display_columns"]`` names the columns :func:`to_markdown` shows.
    """
    keys = [by] if isinstance(by, str) else list(by)
    missing = [c for c in (*keys, "coverage", "collisions", "steps_to_90") if c not in df.columns]
    if missing:
        raise ValueError(f"summarize needs the column(s) {missing}; the DataFrame has {list(df.columns)}")
    rows = []
    for group, runs in df.groupby(keys, sort=False):
        group = group if isinstance(group, tuple) else (group,)
        coverage_mean, coverage_std = _mean_std(runs["coverage"].to_numpy(float), ddof)
        collisions_mean, collisions_std = _mean_std(runs["collisions"].to_numpy(float), ddof)
        steps = runs["steps_to_90"].to_numpy(float)
        reached = steps[~np.isnan(steps)]
        steps_mean, steps_std = _mean_std(reached, ddof)
        steps_text = (
            "N/A"
            if reached.size == 0
            else f"{format_mean_std(steps_mean, steps_std, decimals)} ({reached.size}/{steps.size})"
        )
        row: dict[str, Any] = dict(zip(keys, group))
        row.update(
            {
                COVERAGE_COLUMN: format_mean_std(coverage_mean, coverage_std, decimals),
                COLLISIONS_COLUMN: format_mean_std(collisions_mean, collisions_std, decimals),
                STEPS_COLUMN: steps_text,
                "n_runs": int(steps.size),
                "n_reached": int(reached.size),
                "coverage_mean": coverage_mean,
                "coverage_std": coverage_std,
                "collisions_mean": collisions_mean,
                "collisions_std": collisions_std,
                "steps_to_90_mean": steps_mean,
                "steps_to_90_std": steps_std,
            }
        )
        for column in _EXTRA_MEANS:
            if column in runs.columns:
                values = runs[column].to_numpy(float)
                row[f"{column}_mean"] = float(np.nanmean(values)) if (~np.isnan(values)).any() else math.nan
        rows.append(row)
    summary = pd.DataFrame(rows)
    summary.attrs["display_columns"] = [*keys, COVERAGE_COLUMN, COLLISIONS_COLUMN, STEPS_COLUMN]
    return summary



def to_markdown(df: pd.DataFrame, columns: Sequence[str] | None = None, decimals: int = 2) -> str:
    """A GitHub markdown table of ``df`` (no ``tabulate`` needed); floats with ``decimals`` decimals, NaN as "N/A".

    :param columns: the columns to show, in order; default: ``df.attrs["display_columns"]`` if set and all present
        (a :func:`summarize` output shows its group columns and Table I's three formatted columns), else all
    """
    if columns is None:
        display = list(df.attrs.get("display_columns", ()))
        # attrs survive some pandas operations that select columns: then show what was selected
        columns = display if display and set(display) <= set(df.columns) else list(df.columns)
    columns = list(columns)
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"Unknown column(s) {missing}; the DataFrame has {list(df.columns)}")

    def cell(value: Any) -> str:
        if isinstance(value, (float, np.floating)):
            return "N/A" if math.isnan(value) else f"{value:.{decimals}f}"
        return str(value).replace("|", "\\|")

    body = [[cell(v) for v in row] for row in df[columns].itertuples(index=False, name=None)]
    header = [str(c).replace("|", "\\|") for c in columns]
    widths = [max(len(header[i]), *(len(r[i]) for r in body)) if body else len(header[i]) for i in range(len(columns))]
    lines = [
        "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths)) + " |",
        "|" + "|".join("-" * (w + 2) for w in widths) + "|",
    ]
    lines += ["| " + " | ".join(v.ljust(w) for v, w in zip(r, widths)) + " |" for r in body]
    return "\n".join(lines)
