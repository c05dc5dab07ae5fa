"""The paper's claims as testable targets, checked on a finished (or partial) `sb3-latentswarm sweep` output.

Reads the sweep's run scores (one row per trial and evaluation cell: a run's mean over the cell's episodes) and writes
``claims.md`` / ``claims.csv``: each claim, its target, the measured across-seed means with 95 % stratified-bootstrap
intervals (the sweep's aggregation), and whether the target is met, for each action mode of ``--actions``: by
default sampled actions first (the paper's protocol, Sec. III-D: commands are sampled from the Gaussian policy at
execution), then mean actions. A mode the sweep evaluated in is read from its ``scores.csv``; another mode is
measured here on the sweep's saved models, in the same cells, on the same held-out episode seeds, and its scores are
written as ``scores_<mode>.csv`` in ``--output`` (reused on the next call, which measures only the trials finished
since). One figure per claim
(``claim_<k>_<name>.png``: the cells the claim compares, with their intervals). Nothing is tuned here.

    python examples/paper_claims.py --sweep runs/sweeps/coordination --burst-cells table1=10 burst30=30
    python examples/paper_claims.py --sweep docs/results/coordination_round2_600 --burst-cells table1=10 burst30=30 \\
        --with-sweep docs/results/coordination_round2_independent_600   # the independent baseline, swept apart

The claims (issue "The evidence"):

1. Proposed beats the best message-free learner (``no_comm`` in its own condition, or ``independent``) by >= 10
   coverage points, or reaches 90 % in <= 0.8x the steps, with non-overlapping 95 % intervals.
2. Full comm is within 1.5 points of Proposed or above it (the paper: an upper bound).
3. Under bursty outages, Proposed beats No predictor and No memory (test-time conditions of the proposed models)
   and the learners trained with zeros (``zero_substitute``) or the last received message (``hold_last``) in place of
   the prediction, each in its own setting, by >= 5 points each.
4. Coverage stays within 3 points across p_f 0 .. 0.5.
5. Collisions per episode with the evaluated actions are at most the paper's 8.7.

On another env (a sweep with ``--env``, e.g. MPE2 simple_spread) the claims read another metric: ``--metric return
--metric-range LOW HIGH``. The paper's thresholds, points on its 0-100 coverage scale, become the same percentages of
``HIGH - LOW`` (state the range before reading the results, e.g. the untrained policy's return and the best trained
learner's of an earlier check): claim 1 >= 10 %, claim 2 within 1.5 %, claim 3 >= 5 %, claim 4 a spread <= 3 %. The
steps-to-90 % criterion of claim 1 exists only for coverage, and claim 5 reports the collisions (``collisions``, else
``sum_collisions``) without a target: the paper's 8.7 is a figure of its own task.

    python examples/paper_claims.py --sweep docs/results/simple_spread_ge_pilot --actions sampled \\
        --metric return --metric-range -34.4 -25.8 --burst-cells table1=5 pf0.9=10
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Collection
from pathlib import Path
from typing import NamedTuple

from sb3_latentswarm.utils.atomic import write_text

ACTION_MODES = ("sampled", "mean")
"""``--actions`` choices; ``deterministic`` of ``evaluate`` is ``mode == "mean"``."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sweep", required=True, help="a sweep output folder (with scores.csv and sweep.json)")
    parser.add_argument("--base-cell", default="table1", help="the cell at the training config (Table I's conditions)")
    parser.add_argument("--burst-cells", nargs="*", default=[], metavar="CELL=MEAN_OUTAGE_STEPS",
                        help="cells with bursty outages, and their mean outage length")
    parser.add_argument("--actions", nargs="+", choices=ACTION_MODES, default=list(ACTION_MODES),
                        help="action modes, in the order reported (default: sampled, the paper's protocol, then mean)")
    parser.add_argument("--output", default=None, help="folder for claims.md/csv (default: the sweep folder)")
    parser.add_argument("--metric", default="coverage",
                        help="the scores.csv column the claims read (default coverage, in %%; e.g. return)")
    parser.add_argument("--metric-range", nargs=2, type=float, default=None, metavar=("LOW", "HIGH"),
                        help="the metric's range, whose percentages replace the paper's coverage points (default "
                             "0 100 for coverage; required for another metric)")
    parser.add_argument("--with-sweep", nargs="+", default=[], metavar="SWEEP",
                        help="other sweeps whose learners join the comparison (e.g. the independent baseline swept "
                             "separately): same preset, --set, cells, episodes and seeds; their other action mode is "
                             "measured into their own scores_<mode>.csv")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402

from sb3_latentswarm.evaluation import seed_range, to_markdown  # noqa: E402
from sb3_latentswarm.experiments.aggregate import aggregate_scores  # noqa: E402
from sb3_latentswarm.experiments.report import plot_cells  # noqa: E402
from sb3_latentswarm.experiments.trial import finished_trial_dirs  # noqa: E402

PAPER_COLLISIONS = 8.7
"""Collisions per episode of the paper's Proposed model (Table I, N = 3)."""


class Scale(NamedTuple):
    """The metric the claims read and its range: the paper's thresholds are points of a 0-100 coverage scale, so on
    another metric each becomes the same percentage of ``high - low``."""

    metric: str = "coverage"
    """The run-score column (``scores.csv``) of claims 1-4."""
    low: float = 0.0
    high: float = 100.0

    @property
    def coverage(self) -> bool:
        """Whether the claims read the paper's own metric on its own scale (coverage, 0-100 %): then the steps-to-90 %
        criterion and the paper's collision figure apply."""
        return self.metric == "coverage" and (self.low, self.high) == (0.0, 100.0)

    @property
    def point(self) -> float:
        """One of the paper's coverage points in the metric's units: ``(high - low) / 100``."""
        return (self.high - self.low) / 100.0

    def target(self, points: float) -> str:
        """A threshold of ``points`` coverage points, as the target column states it."""
        if self.coverage:
            return f"{points:g} points"
        return f"{points:g} % of the range ({points * self.point:.2f})"


COVERAGE = Scale()


def _interval(row: pd.Series) -> str:
    return f"{row['mean']:.2f} [{row['mean_low']:.2f}, {row['mean_high']:.2f}] (n={int(row['n_runs'])})"


def outside_range(scores: pd.DataFrame, scale: Scale) -> str:
    """A sentence naming the run scores of ``scale.metric`` outside ``[scale.low, scale.high]``, or ``""``."""
    values = scores[scale.metric].dropna()
    if values.empty or (values.min() >= scale.low and values.max() <= scale.high):
        return ""
    low, high = values.min(), values.max()
    return (f"run scores of `{scale.metric}` from {low:.2f} to {high:.2f} lie outside the stated range "
            f"{scale.low:g} to {scale.high:g}")


def collisions_column(scores: pd.DataFrame) -> str:
    """The collisions per episode of a sweep's scores: ``collisions`` (the swarm env) or ``sum_collisions`` (an
    adapted env's metrics, e.g. simple_spread's)."""
    return "collisions" if "collisions" in scores.columns or "sum_collisions" not in scores.columns else "sum_collisions"


class Cells:
    """Across-seed mean and interval of one metric for (variant, evaluation set, condition)."""

    def __init__(self, scores: pd.DataFrame, metric: str = "coverage") -> None:
        by = ["variant", "eval_set", "condition"]
        self.metric = metric
        self.collisions = collisions_column(scores)
        wanted = [metric, self.collisions, "steps_to_90", "reached_90"]
        self.table = aggregate_scores(scores, by, [c for c in dict.fromkeys(wanted) if c in scores.columns]).set_index(
            [*by, "metric"]
        )

    def get(self, variant: str, eval_set: str, condition: str, metric: str | None = None) -> pd.Series | None:
        """The aggregate row of ``metric`` (default: the claims' metric), or None where the cell has no score."""
        key = (variant, eval_set, condition, metric or self.metric)
        if key not in self.table.index or pd.isna(self.table.loc[key, "mean"]):
            return None
        return self.table.loc[key]


def check_claims(
    scores: pd.DataFrame,
    base_cell: str,
    burst_cells: dict[str, float],
    p_fail_cells: list[str],
    scale: Scale = COVERAGE,
) -> list[dict]:
    """The five claims' rows (``claim``, ``target``, ``measured``, ``met``: yes / no / n/a) on ``scale.metric``, each
    threshold ``scale.point`` metric units per paper coverage point (module docstring)."""
    cells = Cells(scores, scale.metric)
    unit = scale.point
    rows: list[dict] = []

    def row(claim: str, target: str, measured: str, met: bool | None) -> None:
        rows.append({"claim": claim, "target": target, "measured": measured,
                     "met": "n/a" if met is None else ("yes" if met else "no")})

    # 1. Proposed vs the best message-free learner, in the training setting of each
    proposed = cells.get("proposed", base_cell, "proposed")
    own_setting = {"no_comm": "no_comm", "independent": "proposed"}  # the condition each learner was trained in
    learners = {variant: cells.get(variant, base_cell, condition) for variant, condition in own_setting.items()}
    learners = {k: v for k, v in learners.items() if v is not None}
    if proposed is not None and learners:
        best_name, best = max(learners.items(), key=lambda item: item[1]["mean"])
        gap = proposed["mean"] - best["mean"]
        disjoint = proposed["mean_low"] > best["mean_high"]
        steps_p = cells.get("proposed", base_cell, "proposed", "steps_to_90")
        steps_b = cells.get(best_name, base_cell, own_setting[best_name], "steps_to_90")
        faster = (steps_p is not None and steps_b is not None and steps_p["mean"] <= 0.8 * steps_b["mean"]
                  and steps_p["mean_high"] < steps_b["mean_low"])
        if not scale.coverage:
            steps_text, target = "", f">= {scale.target(10)}, disjoint 95 % CIs"
        else:
            steps_text = (f"; steps to 90 %: {_interval(steps_p)} vs {_interval(steps_b)}"
                          if steps_p is not None and steps_b is not None
                          else "; steps to 90 %: not reached by every learner")
            target = f">= {scale.target(10)}, or <= 0.8x steps to 90 %, disjoint 95 % CIs"
        row("1. Proposed vs best message-free learner", target,
            f"Proposed {_interval(proposed)} vs {best_name} {_interval(best)}: {gap:+.2f}{steps_text}",
            bool((gap >= 10 * unit and disjoint) or faster))
    elif proposed is not None:
        row("1. Proposed vs best message-free learner", f">= {scale.target(10)}, disjoint 95 % CIs",
            "no message-free learner (`no_comm`, `independent`) in the sweep", None)
    # 2. Full comm as an upper bound (and the in-range variant beside it)
    for condition in ("full_comm", "full_comm_in_range"):
        full = cells.get("proposed", base_cell, condition)
        if proposed is not None and full is not None:
            row(f"2. {condition} vs Proposed", f">= Proposed - {scale.target(1.5)}",
                f"{_interval(full)} vs {_interval(proposed)}: {full['mean'] - proposed['mean']:+.2f}",
                bool(full["mean"] >= proposed["mean"] - 1.5 * unit))
    # 3. Bursty outages: Proposed vs No predictor and No memory (conditions of the proposed models), and vs the
    # learners trained with another substitute (their "proposed" condition is their own substitute)
    for cell, length in burst_cells.items():
        base = cells.get("proposed", cell, "proposed")
        rivals = {ablation: cells.get("proposed", cell, ablation) for ablation in ("no_predictor", "no_memory")}
        rivals.update({f"trained {variant}": cells.get(variant, cell, "proposed")
                       for variant in ("zero_substitute", "hold_last")})
        for name, other in rivals.items():
            if base is not None and other is not None:
                row(f"3. mean outage {length:g} steps: Proposed vs {name}", f">= {scale.target(5)}",
                    f"{_interval(base)} vs {_interval(other)}: {base['mean'] - other['mean']:+.2f}",
                    bool(base["mean"] - other["mean"] >= 5 * unit))
    # 4. Flat robustness curve over p_f
    sweep = {cell: cells.get("proposed", cell, "proposed") for cell in p_fail_cells}
    sweep = {k: v for k, v in sweep.items() if v is not None}
    if len(sweep) >= 2:
        means = {k: v["mean"] for k, v in sweep.items()}
        spread = max(means.values()) - min(means.values())
        row(f"4. {scale.metric} across p_f", f"max - min <= {scale.target(3)}",
            ", ".join(f"{k}: {v:.2f}" for k, v in means.items()) + f"; spread {spread:.2f}", bool(spread <= 3 * unit))
    # 5. Collisions: the paper's figure is a target only on its own task
    collisions = cells.get("proposed", base_cell, "proposed", cells.collisions)
    if collisions is not None:
        if scale.coverage:
            row("5. collisions per episode (Proposed)", f"<= {PAPER_COLLISIONS} (the paper's)", _interval(collisions),
                bool(collisions["mean"] <= PAPER_COLLISIONS))
        else:
            row("5. collisions per episode (Proposed)", "none (the paper's 8.7 is of its own task)",
                f"{cells.collisions}: {_interval(collisions)}", None)
    return rows


def sweep_mode(spec: dict) -> str:
    """The action mode the sweep evaluated in (sweeps before the ``deterministic`` key used mean actions)."""
    return "mean" if spec.get("deterministic", True) else "sampled"


def evaluate_sweep(sweep: Path, spec: dict, mode: str, skip: Collection[str] = ()) -> pd.DataFrame:
    """Run scores of the sweep's finished trials (but those in ``skip``, trial ids already measured) evaluated with
    ``mode`` actions, in the sweep's cells and episodes.

    The same cells (``spec["eval_sets"]``), episode count and seeds as the sweep's own evaluation
    (:func:`~sb3_latentswarm.experiments.trial.evaluate_sets`, :func:`~sb3_latentswarm.experiments.trial.run_scores`).
    The independent learner's sampled actions come from torch's generator, seeded with the sweep's ``eval_seed``.
    """
    import torch as th

    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.baselines import IndependentRecurrentPPO
    from sb3_latentswarm.experiments.report import CELL_COLUMNS
    from sb3_latentswarm.experiments.trial import EvalSet, evaluate_sets, run_scores, trial_preset

    eval_sets = [EvalSet.from_dict(s) for s in spec["eval_sets"]]
    frames = []
    for folder in finished_trial_dirs(sweep):
        if folder.name in skip:
            continue
        record = json.loads((folder / "trial.json").read_text())
        variant = record["variant"]
        preset = trial_preset(spec["preset"], spec["overrides"], record["grid_point"])
        learner = IndependentRecurrentPPO if variant == "independent" else LatentSwarmPPO
        model = learner.load(folder / "model.zip", device="cpu")
        print(f"evaluating {record['trial_id']} with {mode} actions", flush=True)
        with th.random.fork_rng():
            th.manual_seed(spec["eval_seed"])
            episodes = evaluate_sets(
                model, variant, preset.config, eval_sets, spec["eval_episodes"], spec["eval_seed"], mode == "mean"
            )
        frames.append(episodes.assign(variant=variant, train_seed=record["train_seed"], trial_id=record["trial_id"]))
    if not frames:
        raise ValueError(f"{sweep}: no finished trial with a model to evaluate with {mode} actions")
    return run_scores(pd.concat(frames, ignore_index=True), [*CELL_COLUMNS, "variant", "train_seed", "trial_id"])


SAME_EVALUATION = ("preset", "overrides", "eval_sets", "eval_episodes", "eval_seed")
"""What a ``--with-sweep`` must share with ``--sweep``: its scores then come from the same cells and episodes."""


def mode_scores(sweep: Path, spec: dict, mode: str, cache: Path) -> tuple[pd.DataFrame, str]:
    """The sweep's run scores with ``mode`` actions: its ``scores.csv`` when it evaluated in that mode, else measured
    here on its models (:func:`evaluate_sweep`) and kept in ``cache/scores_<mode>.csv``, which a later call extends
    by the trials finished since. Returns the scores and where they come from."""
    if mode == sweep_mode(spec):
        return pd.read_csv(sweep / "scores.csv"), f"`{sweep}/scores.csv`"
    path = cache / f"scores_{mode}.csv"
    earlier = pd.read_csv(path) if path.exists() else None
    done = set(earlier["trial_id"]) if earlier is not None else set()
    if any(folder.name not in done for folder in finished_trial_dirs(sweep)):  # trials finished since
        new = evaluate_sweep(sweep, spec, mode, skip=done)
        write_text(path, pd.concat([earlier, new], ignore_index=True).to_csv(index=False) if earlier is not None
                   else new.to_csv(index=False))
    return pd.read_csv(path), f"`{path}`, measured by this script on the sweep's models"


def claim_figures(
    scores: pd.DataFrame,
    base_cell: str,
    burst_cells: dict[str, float],
    p_fail_cells: list[str],
    output: Path,
    scale: Scale = COVERAGE,
) -> list[Path]:
    """One figure per claim, ``claim_<k>_<name>.png`` in ``output``, from the same cells as :func:`check_claims`."""
    table = Cells(scores, scale.metric)
    aggregate = table.table.reset_index()
    present = set(map(tuple, aggregate[["variant", "eval_set", "condition"]].to_numpy()))

    def cell(label: str, variant: str, eval_set: str, condition: str) -> list[tuple[str, dict[str, object]]]:
        selection = {"variant": variant, "eval_set": eval_set, "condition": condition}
        return [(label, selection)] if (variant, eval_set, condition) in present else []

    figures = {
        "claim_1_message_free_learners": dict(
            cells=cell("proposed, with links", "proposed", base_cell, "proposed")
            + cell("no_comm learner (trained without links)", "no_comm", base_cell, "no_comm")
            + cell("independent RecurrentPPO", "independent", base_cell, "proposed"),
            title="Claim 1: the proposed learner against the message-free learners",
            metric=scale.metric,
        ),
        "claim_2_full_comm": dict(
            cells=[c for condition in ("proposed", "full_comm", "full_comm_in_range")
                   for c in cell(condition.replace("_", " "), "proposed", base_cell, condition)],
            title="Claim 2: the proposed model with every link forced up",
            metric=scale.metric,
        ),
        "claim_3_bursty_outages": dict(
            cells=[c for name, length in burst_cells.items() for condition in ("proposed", "no_predictor", "no_memory")
                   for c in cell(f"{condition.replace('_', ' ')}, mean outage {length:g}", "proposed", name, condition)],
            title="Claim 3: predictor and memory under bursty outages",
            metric=scale.metric,
        ),
        "claim_4_p_fail": dict(
            cells=[c for name in p_fail_cells for c in cell(name.replace("=", " = "), "proposed", name, "proposed")],
            title=f"Claim 4: the proposed model's {scale.metric} across p_f",
            metric=scale.metric,
        ),
        "claim_5_collisions": dict(
            cells=cell("proposed", "proposed", base_cell, "proposed")
            + cell("no_comm learner (own condition)", "no_comm", base_cell, "no_comm")
            + cell("independent RecurrentPPO", "independent", base_cell, "proposed")
            + cell("zero_substitute learner", "zero_substitute", base_cell, "proposed")
            + cell("hold_last learner", "hold_last", base_cell, "proposed"),
            title="Claim 5: collisions per episode",
            metric=table.collisions,
            reference=(PAPER_COLLISIONS, f"paper: {PAPER_COLLISIONS}") if scale.coverage else None,
        ),
    }
    paths = []
    for name, figure in figures.items():
        if len(figure["cells"]) > 1:  # one bar compares nothing (claim 1 without a message-free learner)
            paths.append(plot_cells(aggregate, path=output / f"{name}.png", **figure))
    return paths


def main(argv: list[str] | None = None) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    sweep = Path(args.sweep)
    if not (sweep / "scores.csv").exists():
        parser.error(f"--sweep: no scores.csv in {sweep} (run the sweep, or write its report, first)")
    if args.metric_range is None and args.metric != "coverage":
        parser.error(f"--metric {args.metric}: give --metric-range LOW HIGH (e.g. the untrained and the best trained "
                     "learner's return), whose percentages replace the paper's coverage points")
    low, high = args.metric_range if args.metric_range is not None else (0.0, 100.0)
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        parser.error(f"--metric-range must be two finite numbers LOW < HIGH, got {low} {high}")
    scale = Scale(args.metric, low, high)
    header_row = pd.read_csv(sweep / "scores.csv", nrows=0).columns
    if args.metric not in header_row:
        hint = (" (a sweep on an adapted env: give --metric return --metric-range LOW HIGH, docs/own_env.md)"
                if args.metric == "coverage" and "return" in header_row else "")
        parser.error(f"--metric {args.metric}: not a column of {sweep / 'scores.csv'}{hint}; it has "
                     f"{', '.join(header_row)}")
    spec = json.loads((sweep / "sweep.json").read_text())
    others = []
    for folder in map(Path, args.with_sweep):
        if not (folder / "scores.csv").exists():
            parser.error(f"--with-sweep: no scores.csv in {folder}")
        other = json.loads((folder / "sweep.json").read_text())
        differ = [key for key in SAME_EVALUATION if other.get(key) != spec.get(key)]
        if differ:
            parser.error(f"--with-sweep {folder}: its {', '.join(differ)} differ from --sweep's; the claims compare "
                         "learners on the same cells and episodes")
        others.append((folder, other))
    burst_cells = {}
    for item in args.burst_cells:
        name, _, length = item.partition("=")
        try:
            burst_cells[name] = float(length)
        except ValueError:
            parser.error(f"--burst-cells takes CELL=MEAN_OUTAGE_STEPS (e.g. table1=10), got {item!r}")
    cells = set(pd.read_csv(sweep / "scores.csv", usecols=["eval_set"])["eval_set"])
    unknown = [name for name in (args.base_cell, *burst_cells) if name not in cells]
    if unknown:
        parser.error(f"unknown cell(s) {', '.join(unknown)} (--base-cell / --burst-cells); the sweep's cells are "
                     f"{', '.join(sorted(cells))}")
    p_fail_cells = [
        s["name"] for s in spec["eval_sets"] if set(s["overrides"]) == {"p_fail"} and s["overrides"]["p_fail"] <= 0.5
    ]
    output = Path(args.output) if args.output else sweep
    output.mkdir(parents=True, exist_ok=True)
    seeds = (f"episode {seed_range(spec['eval_seed'], spec['eval_episodes'])}" if "eval_seed" in spec
             else "the sweep's episode seeds")
    tables, sections, first_scores = [], [], None
    for mode in dict.fromkeys(args.actions):  # in the given order, each once
        parts = [mode_scores(sweep, spec, mode, output), *(mode_scores(f, o, mode, f) for f, o in others)]
        scores = pd.concat([part for part, _ in parts], ignore_index=True)
        source = "; ".join(where for _, where in parts)
        first_scores = scores if first_scores is None else first_scores
        table = pd.DataFrame(check_claims(scores, args.base_cell, burst_cells, p_fail_cells, scale))
        table.insert(0, "actions", mode)
        tables.append(table)
        note = " (the paper's protocol, Sec. III-D)" if mode == "sampled" else " (the Gaussian's mean)"
        sections.append(f"## {mode.capitalize()} actions{note}\n\nScores from {source}; {seeds}.\n\n"
                        + to_markdown(table.drop(columns="actions")) + "\n")
    write_text(output / "claims.csv", pd.concat(tables, ignore_index=True).to_csv(index=False))
    seeds_per_variant = first_scores.groupby("variant")["train_seed"].nunique().to_dict()
    joined = f" with {', '.join(f'`{f}`' for f, _ in others)}" if others else ""
    header = (f"Claims on sweep `{sweep}`{joined} (preset `{spec['preset']}`, overrides {spec['overrides']}; training seeds "
              f"per variant: {seeds_per_variant}). Means across training seeds with 95 % stratified-bootstrap "
              "intervals.\n\n")
    if not scale.coverage:
        outside = outside_range(first_scores, scale)
        if outside:
            header += (f"**Note:** {outside}; the range should come from the same setting (env, N, budget) as this "
                       "sweep, or the thresholds mean something else.\n\n")
        header += (f"The claims read `{scale.metric}`; the paper's thresholds, points on its 0-100 coverage scale, are "
                   f"the same percentages of the range {scale.low:g} to {scale.high:g} ({scale.point:.3f} per "
                   "point).\n\n")
    markdown = header + "\n".join(sections)
    write_text(output / "claims.md", markdown)
    figures = claim_figures(first_scores, args.base_cell, burst_cells, p_fail_cells, output, scale)  # the first mode's cells
    print(markdown)
    print("Figures: " + ", ".join(str(path) for path in figures))


if __name__ == "__main__":
    main()
