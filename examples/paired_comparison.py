"""Paired across-seed comparison of one learner against others, cell by cell, against a stated threshold.

Regenerates the verdict table of a pre-registered test (e.g. ``docs/results/coordination_heavy_dropout/``): for each
other learner S and evaluation cell, the paired differences ``reference(seed k) - S(seed k)`` over the training seeds
both finished, their mean, and a 95 % percentile-bootstrap interval over seeds (our NumPy port of rliable's method,
:func:`sb3_latentswarm.experiments.aggregate.stratified_bootstrap_ci`, 10,000 replicates, generator seed 0). A cell
is **met** when the mean difference is at least ``--threshold`` points and the interval's lower end is above 0; fewer
than ``--min-seeds`` finished pairs (3) give no verdict.

    python examples/paired_comparison.py --scores runs/sweeps/coordination_heavy_dropout/scores.csv \
        --reference proposed --against zero_substitute hold_last --cells table1 pf0.9 pf1 --threshold 3 \
        --output docs/results/coordination_heavy_dropout/paired.md

A learner swept apart joins with a second ``--scores`` (the same cells and evaluation episodes), and
``--against-condition`` reads the other learners at another test-time condition than the reference, e.g. the learner
trained without links in its own condition (every link down) against ``proposed`` at the training channel:

    python examples/paired_comparison.py --scores docs/results/simple_spread_ge_pilot/scores.csv \
        docs/results/simple_spread_ge_pilot/no_comm/scores.csv --against no_comm --against-condition no_comm \
        --cells table1 --metric return --threshold 0.86

Input: sweeps' ``scores.csv`` (one row per trial and cell: ``eval_set``, ``condition``, ``variant``,
``train_seed``, the metric column). Output: a markdown table (printed, and written atomically with ``--output``).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Args:
    scores: tuple[Path, ...]
    """Sweeps' scores.csv files, read as one table (a learner swept apart joins its sweep)."""
    reference: str
    """The learner whose lead is tested (a ``variant`` value)."""
    against: tuple[str, ...]
    """The learners it is compared with."""
    cells: tuple[str, ...]
    """Evaluation cells (``eval_set`` values), each read at ``condition``."""
    condition: str = "proposed"
    """The test-time condition of the reference's rows (``proposed``: each learner with its own substitute)."""
    against_condition: str | None = None
    """The test-time condition of the other learners' rows (``None``: :attr:`condition`)."""
    metric: str = "coverage"
    """The score column (coverage in %, so the threshold is in points)."""
    threshold: float = 3.0
    """Points the mean paired difference must reach."""
    output: Path | None = None
    """Where to write the markdown table (atomically); printed in any case."""
    min_seeds: int = 3
    """Fewer finished pairs than this give no verdict (the interval over one or two seeds says nothing)."""


def parse_args(argv: list[str] | None = None) -> Args:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scores", type=Path, nargs="+", required=True,
                        help="a sweep's scores.csv; more files (learners swept apart) are read as one table")
    parser.add_argument("--reference", default="proposed", help="the learner whose lead is tested (default proposed)")
    parser.add_argument("--against", nargs="+", required=True, help="learners to compare it with")
    parser.add_argument("--cells", nargs="+", required=True, help="eval_set values (e.g. table1 pf0.9 pf1)")
    parser.add_argument("--condition", default="proposed",
                        help="test-time condition of the reference's rows (default proposed)")
    parser.add_argument("--against-condition", default=None, metavar="CONDITION",
                        help="test-time condition of the other learners' rows (default: --condition's), e.g. no_comm "
                             "for the learner trained without links")
    parser.add_argument("--metric", default="coverage", help="score column (default coverage, in %%)")
    parser.add_argument("--threshold", type=float, default=3.0, help="points the mean difference must reach (3)")
    parser.add_argument("--output", type=Path, default=None, help="write the markdown table here")
    parser.add_argument("--min-seeds", type=int, default=3, help="fewer finished pairs give no verdict (default 3)")
    ns = parser.parse_args(argv)
    for path in ns.scores:
        if not path.is_file():
            parser.error(f"--scores: {path} is not a file")
    if ns.min_seeds < 2:
        parser.error(f"--min-seeds must be >= 2, got {ns.min_seeds}")
    return Args(tuple(ns.scores), ns.reference, tuple(ns.against), tuple(ns.cells), ns.condition,
                ns.against_condition, ns.metric, ns.threshold, ns.output, ns.min_seeds)


def paired_table(args: Args) -> str:
    """The verdict table as markdown: one row per (other learner, cell)."""
    import pandas as pd

    from sb3_latentswarm.experiments.aggregate import mean, stratified_bootstrap_ci

    against_condition = args.condition if args.against_condition is None else args.against_condition
    frames = []
    for path in args.scores:
        frame = pd.read_csv(path)
        missing = {"eval_set", "condition", "variant", "train_seed", args.metric} - set(frame.columns)
        if missing:
            raise ValueError(f"{path} lacks the column(s) {sorted(missing)}")
        frames.append(frame)
    scores = pd.concat(frames, ignore_index=True)
    reference, other_name = args.reference, "other"
    if against_condition != args.condition:  # say which condition each side was read at
        reference, other_name = f"{reference} ({args.condition})", f"other ({against_condition})"
    rows = [
        f"| vs | cell | seeds | {reference} | {other_name} | mean difference [95 % CI] | >= {args.threshold:g} and CI > 0 |",
        "|---|---|---|---|---|---|---|",
    ]
    for other in args.against:
        for cell in args.cells:
            cell_rows = scores[scores["eval_set"] == cell]
            part = pd.concat([  # the reference at its condition, the other learner at its own
                cell_rows[(cell_rows["variant"] == args.reference) & (cell_rows["condition"] == args.condition)],
                cell_rows[(cell_rows["variant"] == other) & (cell_rows["condition"] == against_condition)],
            ])
            by_seed = part.pivot_table(index="train_seed", columns="variant", values=args.metric)
            if args.reference not in by_seed or other not in by_seed:
                rows.append(f"| {other} | {cell} | 0 | n/a | n/a | no finished pair | not tested |")
                continue
            pairs = by_seed[[args.reference, other]].dropna()
            if pairs.empty:
                rows.append(f"| {other} | {cell} | 0 | n/a | n/a | no finished pair | not tested |")
                continue
            difference = (pairs[args.reference] - pairs[other]).to_numpy()
            point, low, high = stratified_bootstrap_ci(difference, mean)
            met = point >= args.threshold and low > 0.0
            too_few = len(pairs) < args.min_seeds
            verdict = f"no verdict (< {args.min_seeds} seeds)" if too_few else ("met" if met else "not met")
            seeds = ",".join(str(int(s)) for s in pairs.index)
            rows.append(
                f"| {other} | {cell} | {len(pairs)} ({seeds}) | {pairs[args.reference].mean():.2f} | "
                f"{pairs[other].mean():.2f} | {point:+.2f} [{low:+.2f}, {high:+.2f}] | {verdict} |"
            )
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    table = paired_table(args)
    print(table, end="")
    if args.output is not None:
        from sb3_latentswarm.utils.atomic import write_text

        write_text(args.output, table)


if __name__ == "__main__":
    main()
