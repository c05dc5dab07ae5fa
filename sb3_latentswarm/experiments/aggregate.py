"""Across-seed interval estimates, the way rliable computes them, in NumPy.

Scores follow rliable's layout: ``scores[algorithm]`` is an array ``(n_runs, n_tasks)``, one row per training seed and
one column per task (here: one evaluation cell, so ``n_tasks = 1`` unless a caller pools cells). A run's score in a
cell is the mean over its evaluation episodes; the intervals are across runs, never across the episodes of one model.

The confidence interval is rliable's stratified percentile bootstrap (``rly.get_interval_estimates``): each bootstrap
replicate resamples the runs with replacement independently within every task column, the aggregate is computed on
the replicate, and the interval is the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` percentiles of the
replicates. We implement it here (about twenty lines, vectorized over replicates) rather than depend on rliable,
which is published as source only and pins old library versions.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd
from scipy import stats

__all__ = [
    "AGGREGATES",
    "aggregate_scores",
    "interquartile_mean",
    "interval_estimates",
    "mean",
    "stratified_bootstrap_ci",
]


def interquartile_mean(scores: np.ndarray) -> np.ndarray:
    """IQM: the mean of the middle 50 % of all run x task scores (rliable's ``aggregate_iqm``).

    :param scores: ``(..., n_runs, n_tasks)``
    :return: ``(...)``
    """
    flat = scores.reshape(*scores.shape[:-2], -1)
    return stats.trim_mean(flat, proportiontocut=0.25, axis=-1)


def mean(scores: np.ndarray) -> np.ndarray:
    """The mean of all run x task scores (rliable's ``aggregate_mean``, with equal task weights).

    :param scores: ``(..., n_runs, n_tasks)``
    :return: ``(...)``
    """
    return scores.reshape(*scores.shape[:-2], -1).mean(axis=-1)


AGGREGATES: dict[str, Callable[[np.ndarray], np.ndarray]] = {"iqm": interquartile_mean, "mean": mean}
"""The aggregates of the sweep tables, by column prefix."""


def _as_scores(scores: np.ndarray | Sequence[float]) -> np.ndarray:
    array = np.asarray(scores, dtype=np.float64)
    if array.ndim == 1:
        array = array[:, None]
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(f"scores must be an array (n_runs, n_tasks) with n_runs, n_tasks >= 1, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError("scores must be finite; drop the runs without a score (NaN) first")
    return array


def stratified_bootstrap_ci(
    scores: np.ndarray | Sequence[float],
    aggregate: Callable[[np.ndarray], np.ndarray],
    confidence: float = 0.95,
    reps: int = 10_000,
    rng: np.random.Generator | int | None = 0,
) -> tuple[float, float, float]:
    """Point estimate and percentile-bootstrap interval of ``aggregate`` with runs resampled within each task.

    :param scores: ``(n_runs, n_tasks)`` (a 1-D array is one task)
    :param aggregate: maps ``(..., n_runs, n_tasks)`` to ``(...)``, e.g. :func:`interquartile_mean`
    :param confidence: coverage of the interval (0.95: the 2.5th and 97.5th percentiles)
    :param reps: bootstrap replicates (rliable's default is 50,000 for figures; 10,000 moves the bounds by < 1 %)
    :param rng: a generator or its seed (fixed by default, so that tables are reproducible)
    :return: ``(point, low, high)``
    """
    array = _as_scores(scores)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if reps < 1:
        raise ValueError(f"reps must be >= 1, got {reps!r}")
    rng = np.random.default_rng(rng)
    n_runs, n_tasks = array.shape
    # resample the runs of every task column independently: index (reps, n_runs, n_tasks)
    index = rng.integers(0, n_runs, size=(reps, n_runs, n_tasks))
    replicates = aggregate(np.take_along_axis(array[None], index, axis=1))  # (reps,)
    tail = 50.0 * (1.0 - confidence)
    low, high = np.percentile(replicates, [tail, 100.0 - tail])
    return float(aggregate(array)), float(low), float(high)


def interval_estimates(
    scores: dict[str, np.ndarray],
    aggregates: dict[str, Callable[[np.ndarray], np.ndarray]] = AGGREGATES,
    confidence: float = 0.95,
    reps: int = 10_000,
    seed: int = 0,
) -> pd.DataFrame:
    """rliable's ``get_interval_estimates`` as a table: one row per algorithm, three columns per aggregate.

    :param scores: ``{algorithm: (n_runs, n_tasks)}``
    :return: columns ``algorithm``, ``n_runs``, then ``<aggregate>``, ``<aggregate>_low``, ``<aggregate>_high``
    """
    rows = []
    for algorithm, algorithm_scores in scores.items():
        row: dict[str, object] = {"algorithm": algorithm, "n_runs": int(_as_scores(algorithm_scores).shape[0])}
        for name, aggregate in aggregates.items():
            row[name], row[f"{name}_low"], row[f"{name}_high"] = stratified_bootstrap_ci(
                algorithm_scores, aggregate, confidence, reps, seed
            )
        rows.append(row)
    return pd.DataFrame(rows)


def aggregate_scores(
    run_scores: pd.DataFrame,
    by: Sequence[str],
    metrics: Sequence[str],
    confidence: float = 0.95,
    reps: int = 10_000,
    seed: int = 0,
) -> pd.DataFrame:
    """Across-run IQM and mean with their stratified-bootstrap intervals, per group and metric.

    :param run_scores: one row per (run, cell): the group columns ``by`` and one column per metric (a run's mean over
        its evaluation episodes)
    :param by: the columns that name one aggregate (e.g. variant, evaluation set, condition); each group is one
        stratum, its rows are its runs
    :param metrics: the metric columns; a run whose metric is NaN (e.g. it never reached 90 % coverage) is left out
        of that metric's aggregate, and ``n_runs`` says how many remained
    :return: long format, one row per group and metric: ``by``, ``metric``, ``n_runs``, ``iqm``, ``iqm_low``,
        ``iqm_high``, ``mean``, ``mean_low``, ``mean_high`` (NaN where no run has a score)
    """
    missing = [c for c in (*by, *metrics) if c not in run_scores.columns]
    if missing:
        raise ValueError(f"aggregate_scores needs the column(s) {missing}; the table has {list(run_scores.columns)}")
    rows = []
    for group, runs in run_scores.groupby(list(by), sort=False, dropna=False):
        group = group if isinstance(group, tuple) else (group,)
        for metric in metrics:
            values = runs[metric].to_numpy(np.float64)
            values = values[np.isfinite(values)]
            row: dict[str, object] = {**dict(zip(by, group)), "metric": metric, "n_runs": int(values.size)}
            for name, aggregate in AGGREGATES.items():
                estimate = (
                    stratified_bootstrap_ci(values, aggregate, confidence, reps, seed) if values.size else (np.nan,) * 3
                )
                row[name], row[f"{name}_low"], row[f"{name}_high"] = estimate
            rows.append(row)
    return pd.DataFrame(rows)
