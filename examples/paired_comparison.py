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
    """The test-time condition of every other learner's rows (``None``: :attr:`condition`)."""
    metric: str = "coverage"
    """The score column (coverage in %, so the threshold is in points)."""
    threshold: float = 3.0
    """Points the mean paired difference must reach."""
    output: Path | None = None
    """Where to write the markdown table (atomically); printed in any case."""
    min_seeds: int = 3
    """Fewer finished pairs than this give no verdict (the interval over one or two seeds says nothing)."""


def parse_args(argv: list[str] | None = None) -> Args:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scores", type=Path, nargs="+", required=True,
                        help="a sweep's scores.csv; more files (learners swept apart) are read as one table")
    parser.add_argument("--reference", default="proposed", help="the learner whose lead is tested (default proposed)")
    parser.add_argument("--against", nargs="+", required=True, help="learners to compare it with")
    parser.add_argument("--cells", nargs="+", required=True, help="eval_set values (e.g. table1 pf0.9 pf1)")
    parser.add_argument("--condition", default="proposed",
                        help="test-time condition of the reference's rows (default proposed)")
    parser.add_argument("--against-condition", default=None, metavar="CONDITION",
                        help="test-time condition of every --against learner's rows (default: --condition's), e.g. "
                             "no_comm for the learner trained without links")
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
    if ns.output is not None and not ns.output.parent.is_dir():
        parser.error(f"--output: the folder {ns.output.parent} does not exist")
    return Args(tuple(ns.scores), ns.reference, tuple(ns.against), tuple(ns.cells), ns.condition,
                ns.against_condition, ns.metric, ns.threshold, ns.output, ns.min_seeds)


def load_scores(args: Args):
    """The rows of every ``--scores`` file as one table, checked against the arguments.

    :raise ValueError: a file lacks a column; a (cell, condition, learner, seed) row comes twice (the same trial in two
        files, or files of different cells read as one); a learner, cell or condition named that no file has
    """
    import pandas as pd

    frames = []
    for path in args.scores:
        frame = pd.read_csv(path)
        missing = {"eval_set", "condition", "variant", "train_seed", args.metric} - set(frame.columns)
        if missing:
            raise ValueError(f"{path} lacks the column(s) {sorted(missing)}; it has {', '.join(frame.columns)}")
        frames.append(frame.assign(_file=str(path)))
    scores = pd.concat(frames, ignore_index=True)
    key = ["eval_set", "condition", "variant", "train_seed"]
    twice = scores[scores.duplicated(key, keep=False)]
    if not twice.empty:
        first = twice.iloc[0]
        files = sorted(set(twice[(twice[key] == first[key]).all(axis=1)]["_file"]))
        row = {name: first[name].item() if hasattr(first[name], "item") else first[name] for name in key}
        raise ValueError(
            f"the row {row} comes more than once (in {', '.join(files)}): the files must hold different "
            "learners of the same cells and evaluation episodes"
        )
    against_condition = args.condition if args.against_condition is None else args.against_condition
    for what, names, have in (("learner", (args.reference, *args.against), scores["variant"]),
                              ("cell", args.cells, scores["eval_set"]),
                              ("condition", (args.condition, against_condition), scores["condition"])):
        unknown = sorted(set(names) - set(have))
        if unknown:
            raise ValueError(f"no {what} {', '.join(map(repr, unknown))} in the scores; they have "
                             f"{', '.join(map(str, sorted(set(have))))}")
    return scores


def paired_table(args: Args) -> str:
    """The verdict table as markdown: one row per (other learner, cell).

    :raise ValueError: see :func:`load_scores`
    """
    from sb3_latentswarm.experiments.aggregate import mean, stratified_bootstrap_ci

    scores = load_scores(args)
    against_condition = args.condition if args.against_condition is None else args.against_condition
    reference, other_name = args.reference, "other"
    if against_condition != args.condition:  # say which condition each side was read at
        reference, other_name = f"{reference} ({args.condition})", f"other ({against_condition})"
    rows = [
        f"| vs | cell | seeds | {reference} | {other_name} | mean difference [95 % CI] | >= {args.threshold:g} and CI > 0 |",
        "|---|---|---|---|---|---|---|",
    ]

    def by_seed(cell: str, variant: str, condition: str):
        part = scores[(scores["eval_set"] == cell) & (scores["variant"] == variant) & (scores["condition"] == condition)]
        return part.set_index("train_seed")[args.metric]

    for other in args.against:
        for cell in args.cells:
            # the reference at its condition, the other learner at its own (a learner may be compared with itself)
            pairs = by_seed(cell, args.reference, args.condition).to_frame("reference").join(
                by_seed(cell, other, against_condition).rename("other"), how="inner").dropna()
            if pairs.empty:
                rows.append(f"| {other} | {cell} | 0 | n/a | n/a | no finished pair | not tested |")
                continue
            difference = (pairs["reference"] - pairs["other"]).to_numpy()
            point, low, high = stratified_bootstrap_ci(difference, mean)
            met = point >= args.threshold and low > 0.0
            too_few = len(pairs) < args.min_seeds
            verdict = f"no verdict (< {args.min_seeds} seeds)" if too_few else ("met" if met else "not met")
            seeds = ",".join(str(int(s)) for s in pairs.index)
            rows.append(
                f"| {other} | {cell} | {len(pairs)} ({seeds}) | {pairs['reference'].mean():.2f} | "
                f"{pairs['other'].mean():.2f} | {point:+.2f} [{low:+.2f}, {high:+.2f}] | {verdict} |"
            )
    return "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    try:
        table = paired_table(args)
    except ValueError as error:
        raise SystemExit(f"paired_comparison.py: error: {error}") from None
    print(table, end="")
    if args.output is not None:
        from sb3_latentswarm.utils.atomic import write_text

        write_text(args.output, table)


if __name__ == "__main__":
    main()
