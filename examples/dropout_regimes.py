"""When does prediction help? Coverage of the dropout substitutes across dropout regimes (issue 23, item 2; a map the
paper does not have).

For each saved model (default: the five second-round ``proposed`` learners, ``docs/results/coordination_round2``)
this script evaluates the conditions that differ only in what replaces the received message
during dropout (Sec. III-C) or in the memory: ``proposed`` (the prediction mhat_t), ``no_predictor`` (a zero vector),
``hold_last`` (the last message received) and ``no_memory`` (rho_t zeroed), across a grid of dropout regimes: link
failure probability p_f (``--p-fail``) x mean outage length in steps (``--mean-outage``; 1 means independent Bernoulli
draws, Eq. (1); L > 1 the Gilbert-Elliott chain of ``SwarmConfig.outage_model="gilbert_elliott"`` with
``mean_outage_steps=L``). At p_f = 0 and p_f = 1 the outage length is moot (no link fails / every link fails): those
cells run once, as Bernoulli draws. Each cell is ``--episodes`` held-out episodes (episode k: env seed
``--eval-seed + k``, default :data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`) with sampled actions by default (the
paper's protocol), and records per model the mean coverage and collisions, the MEASURED share of agent-steps in dropout
and mean dropout run (a UAV is in dropout when it has no live in-link: distance drops links too, and an agent with
several peers is in dropout only when all its links fail), and the substitute's squared error against the
full-connectivity message by dropout depth (:mod:`sb3_latentswarm.evaluation.diagnostics`).

Models trained with another substitute in place of the prediction (the sweep's ``zero_substitute`` and ``hold_last``
learners, ``message_substitute`` "zero" / "hold_last") are recognized from their files and evaluated under
``--learner-conditions`` (default ``proposed``: their own substitute, the setting they were trained in); they appear
as their own lines ("zero_substitute learner", "hold_last learner") beside the proposed models' conditions.

Writes into ``--output``:

- ``cells.csv``: one row per (model, actions, p_f, mean outage, condition), rewritten atomically after every cell.
  Cells already there are skipped, so an interrupted run resumes where it stopped (same ``--episodes`` and
  ``--eval-seed`` required);
- ``regimes.csv`` / ``regimes.md``: across-model means with stratified-bootstrap 95 % intervals
  (:func:`sb3_latentswarm.experiments.aggregate.aggregate_scores`) per regime and condition;
- ``coverage_vs_dropout.png``: coverage against the measured dropout share (top) and mean dropout run (bottom), one
  panel per outage length, one line per condition, across-model 95 % intervals;
- ``error_by_depth.png``: the substitute's message error by dropout depth, one panel per outage length;
- ``run.md``: the command, commit, machine and what is in the folder.

    python examples/dropout_regimes.py --episodes 100 --output docs/results/archive/coordination_dropout_regimes

Of ``docs/results/coordination_round2/`` only ``proposed-seed0`` and ``no_comm-seed0`` stay in the tree; bring the
other models back first with ``git restore --source=1cd9a80 -- docs/results/coordination_round2/trials`` (the working
tree only; ``docs/results/README.md``, "Model files", says how to undo it).
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MODELS_COMMIT = "1cd9a80"
"""The last commit whose tree holds every model of ``docs/results/coordination_round2/`` (docs/results/README.md)."""
DEFAULT_MODELS = tuple(f"docs/results/coordination_round2/trials/proposed-seed{seed}/model.zip" for seed in range(5))
"""The second round's committed ``proposed`` learners (training seeds 0-4).
``docs/results/archive/coordination_dropout_regimes`` was made with the first round's three squashed models
(``git checkout 206f0d5 -- docs/results/actor_choice/models``)."""
REGIME_CONDITIONS = ("proposed", "no_predictor", "hold_last", "no_memory")
"""The conditions compared in every regime (names of :data:`~sb3_latentswarm.evaluation.CONDITION_TABLE`)."""
P_FAILS = (0.0, 0.15, 0.3, 0.5, 0.7, 0.9, 1.0)
"""The link failure probabilities p_f of the grid."""
MEAN_OUTAGES = (1.0, 10.0, 25.0, 50.0)
"""The mean outage lengths of the grid, in steps; 1 stands for independent Bernoulli draws (Eq. (1))."""
LEARNERS = {"predicted": "proposed", "zero": "zero_substitute", "hold_last": "hold_last"}
"""The learner a model file is, from the substitute it was trained with (``LatentSwarmPolicy.message_substitute``)."""
LEARNER_LABELS = {"zero_substitute": "Trained with zeros", "hold_last": "Trained with hold-last"}
"""Figure and table labels of the trained-substitute learners' lines."""
KEY_COLUMNS = ("model", "actions", "p_fail", "mean_outage", "condition")
"""The columns that name one cell of ``cells.csv``."""
HELD_OUT_SEED = 1_000_000
"""The first episode seed by default: :data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, a literal: --help loads no torch."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS),
                        help="saved LatentSwarmPPO files, one per training seed (each evaluated on its training config)")
    parser.add_argument("--conditions", nargs="+", default=list(REGIME_CONDITIONS),
                        help="test-time conditions of the proposed models")
    parser.add_argument("--learner-conditions", nargs="+", default=["proposed"],
                        help="test-time conditions of models trained with another substitute (default: their own)")
    parser.add_argument("--episodes", type=int, default=100, help="held-out episodes per cell and model")
    parser.add_argument("--eval-seed", type=int, default=HELD_OUT_SEED, help="episode k uses env seed eval_seed + k")
    parser.add_argument("--p-fail", type=float, nargs="+", default=list(P_FAILS), help="link failure probabilities")
    parser.add_argument("--mean-outage", type=float, nargs="+", default=list(MEAN_OUTAGES),
                        help="mean outage lengths in steps (1: Bernoulli draws; > 1: Gilbert-Elliott)")
    parser.add_argument("--actions", choices=("sampled", "mean"), default="sampled",
                        help="sampled (the paper's protocol, default) or mean actions")
    parser.add_argument("--output", required=True, help="result folder (resumed if it holds cells.csv)")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dropout_diagnostics import DEPTH_LABELS, summarize_diagnostics  # noqa: E402  (the sibling example's table)

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig  # noqa: E402
from sb3_latentswarm.evaluation import (  # noqa: E402
    CONDITION_LABELS,
    DEPTH_COLUMNS,
    check_condition,
    evaluate,
    seed_range,
    to_markdown,
)
from sb3_latentswarm.experiments.aggregate import aggregate_scores  # noqa: E402
from sb3_latentswarm.experiments.run_record import git_commit, write_run_record  # noqa: E402
from sb3_latentswarm.utils.atomic import atomic_path, write_text  # noqa: E402
from sb3_latentswarm.utils.checks import check_float, check_int  # noqa: E402

METRICS = ("coverage", "collisions", "dropout_share", "dropout_run_mean", "pred_error_dropout", *DEPTH_COLUMNS)
"""Per-cell means over the episodes (NaN-ignoring for the error columns), aggregated across models."""
CELL_COLUMNS = (*KEY_COLUMNS, "learner", "outage_model", "episodes", "eval_seed", *METRICS, "episodes_deepest", "seconds")
"""The columns of ``cells.csv``, in order."""


@dataclass(frozen=True)
class Regime:
    """One dropout regime of the grid: p_f and the mean outage length (1: Bernoulli draws)."""

    p_fail: float
    mean_outage: float

    def config(self, base: SwarmConfig) -> SwarmConfig:
        """``base`` with this regime's channel (validated by ``SwarmConfig``)."""
        if self.mean_outage == 1.0:
            return base.replace(p_fail=self.p_fail, outage_model="bernoulli")
        return base.replace(p_fail=self.p_fail, outage_model="gilbert_elliott", mean_outage_steps=self.mean_outage)


def regime_grid(p_fails: tuple[float, ...], mean_outages: tuple[float, ...]) -> list[Regime]:
    """The cells of ``p_fails x mean_outages``; p_f = 0 and p_f = 1 once each (outage length 1), since no link / every
    link fails there whatever the outage length.

    :raise ValueError: for p_f outside [0, 1], a mean outage < 1, or a Gilbert-Elliott cell whose mean outage is below
        the Bernoulli run 1 / (1 - p_f) (``SwarmConfig``'s rule)
    """
    for p in p_fails:
        check_float("--p-fail", p, 0.0, 1.0)
    for length in mean_outages:
        check_float("--mean-outage", length, 1.0, 1e6)
    regimes: list[Regime] = []
    for p in dict.fromkeys(float(p) for p in p_fails):
        lengths = (1.0,) if p in (0.0, 1.0) else tuple(dict.fromkeys(float(length) for length in mean_outages))
        for length in lengths:
            if length > 1.0 and length < 1.0 / (1.0 - p) * (1.0 - 1e-12):
                raise ValueError(
                    f"--mean-outage {length:g} is below the Bernoulli run length 1 / (1 - p_f) = {1 / (1 - p):.4g} "
                    f"steps at --p-fail {p:g}; drop that pair or use --mean-outage 1 (Bernoulli draws)"
                )
            regimes.append(Regime(p, length))
    return regimes


def read_cells(path: Path, episodes: int, eval_seed: int) -> pd.DataFrame:
    """The cells already in ``path`` (an empty table if none).

    :raise ValueError: if they were evaluated with other episodes or seeds (they cannot be mixed with new ones)
    """
    if not path.exists():
        return pd.DataFrame(columns=list(CELL_COLUMNS))
    cells = pd.read_csv(path)
    if "learner" not in cells.columns:  # tables written before trained-substitute learners were mapped: proposed models
        cells.insert(len(KEY_COLUMNS), "learner", "proposed")
    missing = sorted(set(CELL_COLUMNS) - set(cells.columns))
    if missing:
        raise ValueError(f"{path} is not a cells table of this script (missing columns {missing}); use another --output")
    other = cells[(cells["episodes"] != episodes) | (cells["eval_seed"] != eval_seed)]
    if len(other):
        first = other.iloc[0]
        raise ValueError(
            f"{path} holds cells of --episodes {int(first['episodes'])} --eval-seed {int(first['eval_seed'])}; "
            f"this run asks for --episodes {episodes} --eval-seed {eval_seed}; use another --output to keep them apart"
        )
    return cells


def cell_key(model: str, actions: str, p_fail: float, mean_outage: float, condition: str) -> tuple:
    return (model, actions, round(float(p_fail), 9), round(float(mean_outage), 9), condition)


def series_name(learner: str, condition: str) -> str:
    """The line a cell belongs to: the condition for ``proposed`` models, else the trained learner (and the condition
    when it is not the learner's own setting)."""
    if learner == "proposed":
        return condition
    return f"{learner} learner" if condition == "proposed" else f"{learner} learner, {condition}"


def series_label(name: str) -> str:
    """The figure / table label of a :func:`series_name`."""
    if name in CONDITION_LABELS:
        return CONDITION_LABELS[name]
    learner, _, rest = name.partition(" learner")
    return LEARNER_LABELS.get(learner, learner) + rest


def write_csv(path: Path, table: pd.DataFrame) -> None:
    buffer = io.StringIO()
    table.to_csv(buffer, index=False)
    write_text(path, buffer.getvalue())


def evaluate_cell(model: LatentSwarmPPO, condition: str, config: SwarmConfig, episodes: int, eval_seed: int,
                  actions: str) -> dict[str, float]:
    """Means over ``episodes`` held-out episodes of one condition in one regime (the :data:`METRICS` columns and
    ``episodes_deepest``), via :func:`~sb3_latentswarm.evaluation.evaluate` and the dropout-diagnostics summary."""
    frame = evaluate(model, condition, n_episodes=episodes, seed=eval_seed, config=config,
                     deterministic=actions == "mean")
    row = summarize_diagnostics(frame).iloc[0]
    return {name: float(row[name]) for name in (*METRICS, "episodes_deepest")}


def summarize_regimes(cells: pd.DataFrame) -> pd.DataFrame:
    """Across-model mean and stratified-bootstrap 95 % interval of every metric, per (actions, p_f, mean outage,
    line): long format of :func:`~sb3_latentswarm.experiments.aggregate.aggregate_scores`; the ``condition`` column
    holds the line's :func:`series_name` (the condition itself for ``proposed`` models)."""
    learners = cells["learner"] if "learner" in cells.columns else pd.Series("proposed", index=cells.index)
    lines = [series_name(learner, condition) for learner, condition in zip(learners, cells["condition"])]
    return aggregate_scores(cells.assign(condition=lines), by=("actions", "p_fail", "mean_outage", "condition"),
                            metrics=METRICS)


def regimes_markdown(summary: pd.DataFrame, conditions: tuple[str, ...]) -> str:
    """One row per regime: measured dropout share and run (under ``proposed``, else the first condition) and each
    condition's coverage as ``mean [low, high]`` across models."""
    wide = summary.set_index(["actions", "p_fail", "mean_outage", "condition", "metric"])
    rows = []
    for (actions, p_fail, mean_outage), _ in summary.groupby(["actions", "p_fail", "mean_outage"], sort=True):
        present = [c for c in conditions if (actions, p_fail, mean_outage, c, "coverage") in wide.index]
        reference = "proposed" if "proposed" in present else present[0]
        row: dict[str, object] = {
            "actions": actions,
            "p_f": p_fail,
            "outage": "Bernoulli" if mean_outage == 1.0 else f"mean {mean_outage:g}",
            "dropout share": wide.loc[(actions, p_fail, mean_outage, reference, "dropout_share"), "mean"],
            "dropout run": wide.loc[(actions, p_fail, mean_outage, reference, "dropout_run_mean"), "mean"],
            "models": int(wide.loc[(actions, p_fail, mean_outage, reference, "coverage"), "n_runs"]),
        }
        for condition in conditions:
            key = (actions, p_fail, mean_outage, condition, "coverage")
            row[series_label(condition)] = (
                f"{wide.loc[key, 'mean']:.1f} [{wide.loc[key, 'mean_low']:.1f}, {wide.loc[key, 'mean_high']:.1f}]"
                if key in wide.index else ""
            )
        rows.append(row)
    return to_markdown(pd.DataFrame(rows), decimals=3)


RUN_TICKS = (1, 2, 5, 10, 20, 50, 100)
"""Labelled ticks of the log-scaled dropout-run axis (steps)."""


def _log_scale(axis, axis_name: str, values: list[np.ndarray]) -> None:
    """Log scale on ``axis_name`` ("x": the dropout run, labelled at :data:`RUN_TICKS`; "y") unless no value is finite
    and positive (nothing to scale: no dropout)."""
    from matplotlib.ticker import NullFormatter

    if not any(np.any(np.isfinite(v) & (v > 0)) for v in values):
        return
    if axis_name == "x":
        axis.set_xscale("log")
        axis.set_xticks(RUN_TICKS, [str(t) for t in RUN_TICKS])
        axis.xaxis.set_minor_formatter(NullFormatter())
    else:
        axis.set_yscale("log")


def _outage_label(mean_outage: float) -> str:
    return "Bernoulli draws (Eq. (1))" if mean_outage == 1.0 else f"Gilbert-Elliott, mean outage {mean_outage:g} steps"


def plot_regimes(summary: pd.DataFrame, conditions: tuple[str, ...], path: Path, title: str) -> None:
    """Coverage (across-model mean, 95 % interval) against the measured dropout share (top row) and the mean dropout run
    (bottom row, log scale), one panel per outage length; the moot cells p_f = 0 and 1 appear in every panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    wide = summary.set_index(["p_fail", "mean_outage", "condition", "metric"])[["mean", "mean_low", "mean_high"]]
    wide = wide.unstack("metric")  # keeps all-NaN metrics (no dropout run at p_f = 0 on a short episode)
    lengths = sorted(length for length in summary["mean_outage"].unique())
    fig, axes = plt.subplots(2, len(lengths), figsize=(3.6 * len(lengths), 6.4), squeeze=False, sharey=True)
    for column, length in enumerate(lengths):
        runs: list[np.ndarray] = []
        for condition in conditions:
            rows = wide[(wide.index.get_level_values("condition") == condition)
                        & ((wide.index.get_level_values("mean_outage") == length)
                           | wide.index.get_level_values("p_fail").isin([0.0, 1.0]))]
            if rows.empty:
                continue
            for row, x_metric in enumerate(("dropout_share", "dropout_run_mean")):
                ordered = rows.sort_values(("mean", x_metric))
                x = ordered[("mean", x_metric)].to_numpy(float)
                if x_metric == "dropout_run_mean":
                    runs.append(x)
                y = ordered[("mean", "coverage")].to_numpy(float)
                error = np.abs(np.stack([y - ordered[("mean_low", "coverage")].to_numpy(float),
                                         ordered[("mean_high", "coverage")].to_numpy(float) - y]))
                axes[row, column].errorbar(x, y, yerr=error, marker="o", markersize=3, capsize=2,
                                           label=series_label(condition))
        axes[0, column].set_title(_outage_label(length), fontsize=9)
        axes[0, column].set_xlabel("measured share of agent-steps in dropout")
        axes[1, column].set_xlabel("measured mean dropout run (steps)")
        _log_scale(axes[1, column], "x", runs)
        for row in range(2):
            axes[row, column].grid(alpha=0.3, which="both")
    for row in range(2):
        axes[row, 0].set_ylabel("coverage (%)")
    _finish(fig, axes, title, path)


def _finish(fig, axes, title: str, path: Path) -> None:  # noqa: ANN001 - matplotlib objects
    """Legend, title, layout, then the figure written atomically and closed."""
    import matplotlib.pyplot as plt

    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def plot_error_by_depth(summary: pd.DataFrame, conditions: tuple[str, ...], path: Path, title: str) -> None:
    """The substitute's squared error vs the full-connectivity message by dropout depth, one panel per outage length,
    one line per condition: the mean over that panel's p_f cells of the across-model means (cells without a dropout
    step at a depth do not count for it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    errors = summary[summary["metric"].isin(DEPTH_COLUMNS)]
    lengths = sorted(errors["mean_outage"].unique())
    fig, axes = plt.subplots(1, len(lengths), figsize=(3.6 * len(lengths), 4.4), squeeze=False, sharey=True)
    positions = np.arange(len(DEPTH_COLUMNS))
    for column, length in enumerate(lengths):
        axis = axes[0, column]
        values: list[np.ndarray] = []
        for condition in conditions:
            rows = errors[(errors["mean_outage"] == length) & (errors["condition"] == condition)]
            if rows.empty:
                continue
            by_depth = rows.groupby("metric")["mean"].mean().reindex(list(DEPTH_COLUMNS)).to_numpy(float)
            values.append(by_depth)
            axis.plot(positions, by_depth, marker="o", label=series_label(condition))
        axis.set_xticks(positions, DEPTH_LABELS)
        _log_scale(axis, "y", values)
        axis.set_xlabel("dropout depth (steps)")
        axis.set_title(_outage_label(length), fontsize=9)
        axis.grid(alpha=0.3, which="both")
    axes[0, 0].set_ylabel("squared error per element\nvs full-connectivity message")
    _finish(fig, axes, title, path)


def main(argv: list[str] | None = None) -> None:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:  # every argument is checked before a model is loaded or a file written
        check_int("--episodes", args.episodes, 1)
        check_int("--eval-seed", args.eval_seed, 0)
        conditions = tuple(dict.fromkeys(check_condition(c).name for c in args.conditions))
        learner_conditions = tuple(dict.fromkeys(check_condition(c).name for c in args.learner_conditions))
        regimes = regime_grid(tuple(args.p_fail), tuple(args.mean_outage))
        missing = [m for m in args.models if not Path(m).is_file()]
        if missing:
            raise ValueError(
                f"--models: no file at {missing} (most committed models left the tree: docs/results/README.md, "
                f"'Model files', names the commit that has them, e.g. git restore --source={MODELS_COMMIT} -- "
                "docs/results/coordination_round2/trials)"
            )
        models = list(dict.fromkeys(args.models))
        learner_of = {m: LEARNERS[LatentSwarmPPO.load(m, device="cpu").policy.message_substitute] for m in models}
        output = Path(args.output)
        cells = read_cells(output / "cells.csv", args.episodes, args.eval_seed)
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    th.set_num_threads(1)
    commit = git_commit()
    output.mkdir(parents=True, exist_ok=True)
    done = {cell_key(*row) for row in cells[list(KEY_COLUMNS)].itertuples(index=False)}
    plan = [(m, r, c) for m in models for r in regimes
            for c in (conditions if learner_of[m] == "proposed" else learner_conditions)]
    total = len(plan)
    todo = [(m, r, c) for m, r, c in plan if cell_key(m, args.actions, r.p_fail, r.mean_outage, c) not in done]
    counts = pd.Series(list(learner_of.values())).value_counts().to_dict()
    print(f"{total} cells ({len(models)} models {counts} x {len(regimes)} regimes x their conditions), "
          f"{total - len(todo)} already in {output / 'cells.csv'}, {len(todo)} to run", flush=True)
    start = time.perf_counter()
    loaded: dict[str, LatentSwarmPPO] = {}
    records = cells.to_dict("records")
    for index, (model_path, regime, condition) in enumerate(todo, 1):
        if model_path not in loaded:
            loaded.clear()  # one model in memory at a time
            loaded[model_path] = LatentSwarmPPO.load(model_path, device="cpu")
        model = loaded[model_path]
        config = regime.config(model.swarm_config)
        cell_start = time.perf_counter()
        metrics = evaluate_cell(model, condition, config, args.episodes, args.eval_seed, args.actions)
        row = {
            "model": model_path, "actions": args.actions, "p_fail": regime.p_fail, "mean_outage": regime.mean_outage,
            "condition": condition, "learner": learner_of[model_path], "outage_model": config.outage_model,
            "episodes": args.episodes, "eval_seed": args.eval_seed, **metrics, "seconds": time.perf_counter() - cell_start,
        }
        records.append(row)
        cells = pd.DataFrame(records, columns=list(CELL_COLUMNS))
        write_csv(output / "cells.csv", cells)  # after every cell: an interruption loses at most the running one
        print(f"[{index}/{len(todo)}] {model_path} p_f={regime.p_fail:g} outage={regime.mean_outage:g} {condition}: "
              f"coverage {metrics['coverage']:.1f}, dropout share {metrics['dropout_share']:.3f}, "
              f"run {metrics['dropout_run_mean']:.2f} ({row['seconds']:.1f} s)", flush=True)
    seconds = time.perf_counter() - start

    cells = cells[cells["actions"] == args.actions]
    summary = summarize_regimes(cells)
    write_csv(output / "regimes.csv", summary)
    lines = tuple(dict.fromkeys([*conditions, *(series_name(learner_of[m], c) for m in models if learner_of[m] != "proposed"
                                                for c in learner_conditions)]))
    markdown = regimes_markdown(summary, lines)
    seeds = seed_range(args.eval_seed, args.episodes)
    write_text(output / "regimes.md",
               f"Coverage (%) across {len(models)} model(s): mean [95 % stratified-bootstrap interval]; episode {seeds}, "
               f"{args.actions} actions; dropout share and run measured under Proposed.\n\n{markdown}\n")
    setting = f"{len(models)} model(s), {args.episodes} episodes per cell, {args.actions} actions"
    plot_regimes(summary, lines, output / "coverage_vs_dropout.png",
                 f"Coverage vs measured dropout ({setting}; 95 % intervals across models)")
    plot_error_by_depth(summary, lines, output / "error_by_depth.png",
                        f"Substitute message error by dropout depth ({setting})")
    n_done = len(cells)
    facts = [
        f"models: {', '.join(f'`{m}`' for m in models)}, each evaluated on its training config with the channel replaced",
        f"conditions: {', '.join(conditions)} (proposed models), {', '.join(learner_conditions)} (models trained with "
        f"another substitute: {sum(v != 'proposed' for v in learner_of.values())})",
        f"regimes: p_f in {sorted({r.p_fail for r in regimes})} x mean outage in "
        f"{sorted({r.mean_outage for r in regimes})} steps (1: Bernoulli; p_f 0 and 1 once)",
        f"episodes: {args.episodes} per cell and model, episode {seeds} (held out from training), {args.actions} actions",
        f"cells: {n_done} of {total} in cells.csv ({len(todo)} run now in {seconds:.0f} s"
        + (f", {seconds / len(todo):.1f} s per cell" if todo else "") + ")",
    ]
    body = [
        "`cells.csv`: one row per model and cell (means over the episodes); `regimes.csv`: across-model mean and IQM with "
        "95 % stratified-bootstrap intervals; `regimes.md`:\n",
        markdown,
        "",
        "![Coverage vs measured dropout](coverage_vs_dropout.png)",
        "",
        "![Substitute error by dropout depth](error_by_depth.png)",
    ]
    write_run_record(output, "When does prediction help? Coverage across dropout regimes", commit, facts, body, device="cpu")


if __name__ == "__main__":
    main()
