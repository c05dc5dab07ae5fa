"""Sample efficiency of a sweep's learners from their training curves: agent-steps to target levels and the curve's area.

Regenerates ``docs/results/coordination_sample_efficiency/`` (issue 35: does the predictor's learner learn faster
than the learners trained with a substitute message?)::

    python examples/sample_efficiency.py --sweep docs/results/coordination_round2_600 \\
        --against zero_substitute hold_last no_comm --targets 80 85 90 \\
        --output docs/results/coordination_sample_efficiency

Input: a finished sweep folder, of which only ``trials/<trial_id>/progress.csv`` is read (one row per rollout:
``agent_steps``, the metric, ``variant``, ``train_seed``; a committed folder without ``model.zip`` will do). These
are TRAINING curves: the episodes the learner finished while it trained, under the training channel, with sampled
actions; not a held-out evaluation.

Per trial, the metric's curve is smoothed by a trailing moving average over ``--window`` rollouts (the first points
average what exists), cut at the common budget (the smallest final ``agent_steps`` of the trials compared, so every
learner is scored over the same steps), and read two ways:

- agent-steps to target: the first ``agent_steps`` at which the smoothed curve is at or above each ``--targets``
  level (not reached: NaN in the CSV);
- normalized AUC: the trapezoid area under the smoothed curve over the common span of agent-steps, divided by that
  span, i.e. the curve's mean level in the metric's units (points of coverage).

Per learner (``variant``), the mean across training seeds with a 95 % percentile-bootstrap interval
(:func:`sb3_latentswarm.experiments.aggregate.stratified_bootstrap_ci`, 10,000 replicates, generator seed 0); the
mean steps to a target only when every seed reached it. Paired: per training seed both learners have, ``--reference``
minus each ``--against`` learner, for the AUC and each target's steps (over the seeds where both reached it).

Output (``--output``, a folder, files written atomically): ``per_trial.csv`` and ``sample_efficiency.md`` (also
printed).
"""

from __future__ import annotations

import argparse
import csv
import gzip
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd

BOOTSTRAP_REPS = 10_000
"""Bootstrap replicates of every interval (generator seed 0, as in ``paired_comparison.py``)."""
MIN_PAIRS = 3
"""Fewer paired seeds than this are flagged: a bootstrap over one or two differences says little."""


@dataclass(frozen=True)
class Args:
    sweep: Path
    """A finished sweep folder (``trials/<trial_id>/progress.csv``)."""
    targets: tuple[float, ...]
    """Levels of the smoothed curve, in the metric's units (coverage: %), whose first agent-steps are reported."""
    output: Path
    """The folder the tables are written to (created)."""
    reference: str = "proposed"
    """The learner compared with the others (a ``variant`` value)."""
    against: tuple[str, ...] = ()
    """The learners it is compared with (empty: every other variant of the sweep)."""
    metric: str = "coverage"
    """The progress.csv column read (coverage of the finished training episodes, in %)."""
    window: int = 10
    """Rollouts of the trailing moving average (1: the raw curve)."""


def _first_row(path: Path) -> tuple[list[str], dict[str, str] | None]:
    """The header and the first data row of a (possibly gzipped) CSV file, read without pandas."""
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="") as handle:
        reader = csv.DictReader(handle)
        return list(reader.fieldnames or []), next(reader, None)


def _sweep_variants(parser: argparse.ArgumentParser, sweep: Path, metric: str) -> dict[str, list[str]]:
    """``{variant: [train_seed, ...]}`` of the sweep's trials, from the first row of each progress.csv."""
    from sb3_latentswarm.experiments.report import trial_file

    trials_dir = sweep / "trials"
    if not trials_dir.is_dir():
        parser.error(f"--sweep: {sweep} has no trials/ folder (a finished sweep's output folder holds one)")
    variants: dict[str, list[str]] = {}
    for folder in sorted(p for p in trials_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
        path = trial_file(folder, "progress.csv")
        if not path.is_file():
            parser.error(f"--sweep: trial {folder.name} has no progress.csv")
        header, row = _first_row(path)
        missing = {"agent_steps", "variant", "train_seed", metric} - set(header)
        if missing:
            parser.error(f"--sweep: {path} lacks the column(s) {sorted(missing)}")
        if row is None:
            parser.error(f"--sweep: {path} holds no rollout")
        seeds = variants.setdefault(row["variant"], [])
        if row["train_seed"] in seeds:
            parser.error(
                f"--sweep: {row['variant']} has several trials of training seed {row['train_seed']} (a sweep over grid "
                "points?); this script compares one trial per learner and seed"
            )
        seeds.append(row["train_seed"])
    if not variants:
        parser.error(f"--sweep: {trials_dir} holds no trial")
    return variants


def parse_args(argv: list[str] | None = None) -> Args:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sweep", type=Path, required=True, help="a finished sweep folder (trials/*/progress.csv)")
    parser.add_argument("--targets", type=float, nargs="+", required=True,
                        help="levels of the smoothed curve, in the metric's units (coverage: %%), e.g. 80 85 90")
    parser.add_argument("--output", type=Path, required=True, help="folder for per_trial.csv and sample_efficiency.md")
    parser.add_argument("--reference", default="proposed", help="the learner compared with the others (default proposed)")
    parser.add_argument("--against", nargs="+", default=[],
                        help="learners to compare it with (default: every other variant of the sweep)")
    parser.add_argument("--metric", default="coverage", help="progress.csv column (default coverage, in %%)")
    parser.add_argument("--window", type=int, default=10, help="rollouts of the trailing moving average (default 10)")
    ns = parser.parse_args(argv)
    if ns.window < 1:
        parser.error(f"--window must be >= 1, got {ns.window}")
    if not all(math.isfinite(t) for t in ns.targets):
        parser.error(f"--targets must be finite numbers, got {ns.targets}")
    targets = tuple(sorted(set(ns.targets)))
    if ns.output.exists() and not ns.output.is_dir():
        parser.error(f"--output: {ns.output} exists and is not a folder")
    variants = _sweep_variants(parser, ns.sweep, ns.metric)
    against = tuple(ns.against) or tuple(v for v in sorted(variants) if v != ns.reference)
    unknown = [name for name in (ns.reference, *against) if name not in variants]
    if unknown:
        parser.error(f"unknown variant(s) {', '.join(unknown)}; the sweep holds: {', '.join(sorted(variants))}")
    if ns.reference in against or len(set(against)) != len(against):
        parser.error(f"--against must name other learners than --reference {ns.reference!r}, each once: {list(against)}")
    if not against:
        parser.error(f"the sweep holds only {ns.reference!r}: nothing to compare it with")
    return Args(ns.sweep, targets, ns.output, ns.reference, against, ns.metric, ns.window)


# ---------------------------------------------------------------------------------------------- measures
def smoothed(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average over ``window`` points; the first ``window - 1`` points average what exists."""
    import numpy as np

    sums = np.cumsum(np.concatenate([[0.0], np.asarray(values, dtype=np.float64)]))
    ends = np.arange(1, len(values) + 1)
    starts = np.maximum(ends - window, 0)
    return (sums[ends] - sums[starts]) / (ends - starts)


def steps_to_target(steps: np.ndarray, values: np.ndarray, target: float) -> float:
    """The first of ``steps`` at which ``values`` is at or above ``target``; NaN when never."""
    import numpy as np

    reached = np.flatnonzero(np.asarray(values) >= target)
    return float(steps[reached[0]]) if reached.size else float("nan")


def normalized_auc(steps: np.ndarray, values: np.ndarray, start: float, stop: float) -> float:
    """Trapezoid area under the piecewise-linear curve ``(steps, values)`` from ``start`` to ``stop``, divided by
    ``stop - start``: the curve's mean level over that span (in the units of ``values``)."""
    import numpy as np

    if not steps[0] <= start < stop <= steps[-1]:
        raise ValueError(f"the span [{start}, {stop}] must lie inside the curve's steps [{steps[0]}, {steps[-1]}]")
    inside = steps[(steps > start) & (steps < stop)]
    x = np.concatenate([[start], inside, [stop]])
    y = np.interp(x, steps, values)
    return float(np.sum((y[1:] + y[:-1]) / 2.0 * np.diff(x)) / (stop - start))


def target_column(target: float) -> str:
    return f"steps_to_{target:g}"


@dataclass(frozen=True)
class Budget:
    start: float
    """The latest first rollout of the trials compared (agent-steps)."""
    stop: float
    """The smallest final agent-steps of the trials compared: the common budget."""


def read_curves(args: Args) -> dict[str, pd.DataFrame]:
    """``{trial_id: progress rows sorted by agent_steps}`` of the trials of the learners compared."""
    import pandas as pd

    from sb3_latentswarm.experiments.report import trial_file

    learners = {args.reference, *args.against}
    curves = {}
    for folder in sorted(p for p in (args.sweep / "trials").iterdir() if p.is_dir() and not p.name.startswith(".")):
        frame = pd.read_csv(trial_file(folder, "progress.csv"))
        if frame["variant"].iloc[0] in learners:
            curves[folder.name] = frame.sort_values("agent_steps", kind="stable").reset_index(drop=True)
    return curves


def per_trial(curves: dict[str, pd.DataFrame], args: Args) -> tuple[pd.DataFrame, Budget]:
    """One row per trial: its final agent-steps, the AUC and the smoothed level over the common budget, and the
    agent-steps to each target within it."""
    import numpy as np
    import pandas as pd

    budget = Budget(
        start=max(float(c["agent_steps"].iloc[0]) for c in curves.values()),
        stop=min(float(c["agent_steps"].iloc[-1]) for c in curves.values()),
    )
    if not budget.start < budget.stop:
        raise ValueError(f"the trials share no span of agent-steps (latest first rollout {budget.start:,.0f}, "
                         f"earliest last {budget.stop:,.0f})")
    rows = []
    for trial, curve in curves.items():
        steps = curve["agent_steps"].to_numpy(dtype=float)
        level = smoothed(curve[args.metric].to_numpy(dtype=float), args.window)
        within = steps <= budget.stop
        row = {
            "trial_id": trial,
            "variant": curve["variant"].iloc[0],
            "train_seed": int(curve["train_seed"].iloc[0]),
            "final_agent_steps": steps[-1],
            "auc": normalized_auc(steps, level, budget.start, budget.stop),
            "level_at_budget": float(np.interp(budget.stop, steps, level)),
        }
        for target in args.targets:
            row[target_column(target)] = steps_to_target(steps[within], level[within], target)
        rows.append(row)
    return pd.DataFrame(rows), budget


# ---------------------------------------------------------------------------------------------- tables
def _interval(values: np.ndarray, digits: int = 2, sign: str = "") -> str:
    from sb3_latentswarm.experiments.aggregate import mean, stratified_bootstrap_ci

    point, low, high = stratified_bootstrap_ci(values, mean, reps=BOOTSTRAP_REPS, rng=0)
    return f"{point:{sign},.{digits}f} [{low:{sign},.{digits}f}, {high:{sign},.{digits}f}]"


def learner_table(table: pd.DataFrame, args: Args) -> str:
    import numpy as np

    learners = [args.reference, *args.against]
    head = "| learner | seeds | AUC (mean level) | level at the budget |"
    head += "".join(f" steps to {t:g} |" for t in args.targets)
    rows = [head, "|---" * (4 + len(args.targets)) + "|"]
    for learner in learners:
        part = table[table["variant"] == learner].sort_values("train_seed")
        cells = [f"`{learner}`", str(len(part)), _interval(part["auc"].to_numpy()),
                 _interval(part["level_at_budget"].to_numpy())]
        for target in args.targets:
            steps = part[target_column(target)].to_numpy()
            reached = int(np.isfinite(steps).sum())
            if reached == len(steps):
                cells.append(f"{_interval(steps, digits=0)} (all {reached})")
            else:
                cells.append(f"{reached} of {len(steps)} seeds reached it")
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows) + "\n"


def paired_table(table: pd.DataFrame, args: Args) -> str:
    rows = [f"| {args.reference} minus | measure | pairs (seeds) | {args.reference} | other | difference [95 % CI] |",
            "|---|---|---|---|---|---|"]
    measures = [("auc", "AUC (points)", 2)] + [(target_column(t), f"steps to {t:g}", 0) for t in args.targets]
    for other in args.against:
        for column, label, digits in measures:
            by_seed = table[table["variant"].isin([args.reference, other])].pivot(
                index="train_seed", columns="variant", values=column
            )
            pairs = by_seed.reindex(columns=[args.reference, other]).dropna()
            if pairs.empty:
                rows.append(f"| `{other}` | {label} | 0 | | | no seed where both reached it |")
                continue
            seeds = ",".join(str(int(s)) for s in pairs.index)
            difference = (pairs[args.reference] - pairs[other]).to_numpy()
            text = _interval(difference, digits, sign="+") if len(pairs) > 1 else f"{difference[0]:+,.{digits}f}"
            if len(pairs) < MIN_PAIRS:
                text += f" (< {MIN_PAIRS} pairs: the interval says little)"
            rows.append(
                f"| `{other}` | {label} | {len(pairs)} ({seeds}) | {pairs[args.reference].mean():,.{digits}f} | "
                f"{pairs[other].mean():,.{digits}f} | {text} |"
            )
    return "\n".join(rows) + "\n"


def report(table: pd.DataFrame, budget: Budget, args: Args) -> str:
    targets = ", ".join(f"{t:g}" for t in args.targets)
    return (
        f"# Sample efficiency: `{args.sweep.as_posix()}`\n\n"
        f"Metric `{args.metric}` of the TRAINING curves as logged in progress.csv (one row per rollout: the episodes "
        f"finished while training, under the training channel, with sampled actions; not a held-out evaluation), "
        f"smoothed by a trailing moving average over {args.window} rollouts; targets {targets}; common budget "
        f"{budget.stop:,.0f} agent-steps (AUC over agent-steps {budget.start:,.0f} to {budget.stop:,.0f}, divided by "
        f"the span: the curve's mean level in the metric's units; steps to a target within the budget).\n\n"
        "## Per learner\n\n"
        f"Mean across training seeds [95 % percentile-bootstrap interval, {BOOTSTRAP_REPS:,} replicates]; the mean "
        "agent-steps to a target only where every seed reached it.\n\n"
        f"{learner_table(table, args)}\n"
        "## Paired by training seed\n\n"
        f"`{args.reference}` minus the other learner, per training seed both have (steps: over the seeds where both "
        f"reached the target; a negative difference means `{args.reference}` got there in fewer agent-steps).\n\n"
        f"{paired_table(table, args)}"
    )


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    from sb3_latentswarm.utils.atomic import atomic_path, write_text

    table, budget = per_trial(read_curves(args), args)
    table = table.sort_values(["variant", "train_seed"], kind="stable").reset_index(drop=True)
    markdown = report(table, budget, args)
    args.output.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.output / "per_trial.csv") as tmp:
        table.to_csv(tmp, index=False)
    write_text(args.output / "sample_efficiency.md", markdown)
    print(markdown, end="")


if __name__ == "__main__":
    main()
