"""The tables, plots and ``run.md`` of a sweep, computed from its finished trials' raw files only.

``write_report(output)`` can be rerun at any time (``sb3-latentswarm sweep ... --resume`` does it after the trials):

* ``episodes.csv``: every evaluation episode of every trial (tidy: one row per trial x cell x episode);
* ``scores.csv``: one row per trial and cell, the run's scores (:func:`~.trial.score_metrics`);
* ``aggregate.csv`` / ``aggregate.md``: per (grid point, variant, cell) and metric, across training seeds, the IQM and
  the mean, each with its 95 % stratified-bootstrap interval (:mod:`.aggregate`);
* ``intervals_<metric>.png``: bars (IQM) with interval whiskers per cell and variant, a panel per evaluation set;
* ``learning_curves.png``: coverage and episode return during training, mean across seeds with a 95 % band;
* ``run.md``: command, commit, machines, budget and seeds, then the tables.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from sb3_latentswarm.experiments.aggregate import aggregate_scores, mean, stratified_bootstrap_ci
from sb3_latentswarm.experiments.spec import SweepSpec, trial_id
from sb3_latentswarm.experiments.trial import all_conditions, grid_labels, run_scores, score_metrics
from sb3_latentswarm.utils.atomic import atomic_path, check_real_path, read_json, write_text

METRIC_LABELS = {
    "coverage": "Coverage (%)",
    "collisions": "Collisions per episode",
    "steps_to_90": "Steps to 90 % coverage",
    "reached_90": "Episodes reaching 90 % (%)",
}
CELL_COLUMNS = ("eval_set", "condition", "p_fail")


RESULT_FILES = ("trial.json", "episodes.csv", "progress.csv")
"""The results of a finished trial: what its report reads, and what a finished trial folder must hold."""
TRIAL_FILES = (*RESULT_FILES, "model.zip")
"""What a sweep writes into a finished trial folder: its results and the trained model. A committed results folder
may keep only :data:`RESULT_FILES` (its models left the tree: ``docs/results/README.md``); it still reports and
resumes, but a ``--warm-start`` from it needs the models back."""


def trial_file(folder: str | Path, name: str) -> Path:
    """``folder/name``, or ``folder/name.gz`` when only that exists: a committed results folder may keep a trial's
    tables gzipped (``docs/results/README.md``); pandas reads either."""
    path = Path(folder) / name
    gzipped = path.with_name(f"{name}.gz")
    return gzipped if not path.is_file() and gzipped.is_file() else path


def finished_trials(output: str | Path, spec: SweepSpec) -> dict[str, dict[str, Any]]:
    """The finished trials of the sweep in ``output``, ``{trial_id: trial.json record}``, in folder-name order.

    Every folder of ``output/trials`` must be a complete trial of ``spec`` (the hidden ``.<trial_id>.partial``
    folders of an interrupted copy are skipped): one named after a trial of ``spec``, holding :data:`RESULT_FILES`,
    whose ``trial.json`` names the same trial and the evaluation ``spec`` asks for.

    :raises ValueError: naming the folder, for a stray folder (not a trial of ``spec``, or a copy of another trial) or
        a damaged one (a file missing, or results of other evaluation settings), with what to do about it
    """
    trials_dir = Path(output) / "trials"
    planned = {trial_id(v, s, p) for p in spec.grid_points() for s in spec.seeds for v in spec.variants}
    expected_eval = {
        "eval_env_seeds": [spec.eval_seed, spec.eval_seed + spec.eval_episodes - 1],
        "eval_sets": [s.to_dict() for s in spec.eval_sets],
        "deterministic": spec.deterministic,
    }
    expected_eval = json.loads(json.dumps(expected_eval))
    records = {}
    folders = sorted(p for p in trials_dir.iterdir() if not p.name.startswith(".")) if trials_dir.is_dir() else []
    for folder in folders:
        if folder.name not in planned:
            raise ValueError(
                f"{folder} is not a trial of this sweep (its trials are {sorted(planned)}); move it out of {trials_dir}"
            )
        check_real_path(folder, Path(output), "trial folder")
        for name in TRIAL_FILES:
            if (folder / name).is_symlink():
                check_real_path(folder / name, Path(output), "trial's file")
        missing = [name for name in RESULT_FILES if not trial_file(folder, name).is_file()]
        if missing:
            raise ValueError(
                f"{folder} is damaged: no {', '.join(missing)}; delete the folder and --resume trains the trial again"
            )
        try:
            record = read_json(folder / "trial.json")
        except ValueError as error:
            raise ValueError(f"{error}; delete the folder and --resume trains it again") from None
        if record.get("trial_id") != folder.name:
            raise ValueError(
                f"{folder} holds trial {record.get('trial_id')!r}, not {folder.name!r} (a copied folder?); "
                f"move it out of {trials_dir}"
            )
        header = list(pd.read_csv(trial_file(folder, "episodes.csv"), nrows=0).columns)
        absent = [c for c in (*grid_labels(record.get("grid_point") or {}), *CELL_COLUMNS, "trial_id") if c not in header]
        if absent:
            raise ValueError(
                f"{folder}/episodes.csv has no column(s) {absent} (written by an older version, whose p_fail column held "
                "the grid point); delete the folder and --resume trains the trial again"
            )
        differ = [key for key, value in expected_eval.items() if record.get(key) != value]
        if differ:
            raise ValueError(
                f"{folder} was evaluated with other {', '.join(differ)} than sweep.json asks "
                f"({ {k: record.get(k) for k in differ} }); delete the folder and --resume trains it again"
            )
        records[folder.name] = record
    return records


def _read_trials(output: Path, ids: list[str], name: str) -> pd.DataFrame:
    frames = []
    for path in (trial_file(output / "trials" / i, name) for i in ids):
        try:
            frames.append(pd.read_csv(path))
        except pd.errors.EmptyDataError:  # a trial that wrote no row (an empty progress.csv)
            continue
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _interval_text(point: float, low: float, high: float) -> str:
    return "N/A" if np.isnan(point) else f"{point:.2f} [{low:.2f}, {high:.2f}]"


def aggregate_markdown(aggregate: pd.DataFrame, group_columns: list[str]) -> str:
    """One markdown table per metric: a row per group, its seeds, IQM and mean with their 95 % intervals."""
    from sb3_latentswarm.evaluation import to_markdown

    sections = []
    for metric, rows in aggregate.groupby("metric", sort=False):
        table = rows[group_columns].copy()
        table["seeds"] = rows["n_runs"]
        table["IQM [95 % CI]"] = [_interval_text(*v) for v in rows[["iqm", "iqm_low", "iqm_high"]].to_numpy()]
        table["mean [95 % CI]"] = [_interval_text(*v) for v in rows[["mean", "mean_low", "mean_high"]].to_numpy()]
        sections.append(f"### {METRIC_LABELS.get(metric, metric)}\n\n{to_markdown(table)}\n")
    return "\n".join(sections)


def _interval_panels(rows: pd.DataFrame, cell_columns: list[str]) -> list[tuple[str, list[tuple[str, pd.DataFrame]]]]:
    """``(title, [(x label, rows of that cell), ...])`` per panel: one panel per evaluation set, and the sets of a
    single cell (a p_f sweep's points) side by side in one panel."""
    panel_columns = [c for c in cell_columns if c == "eval_set"] or cell_columns[:1]
    other = [c for c in cell_columns if c not in panel_columns]
    panels, singles = [], []
    for panel, panel_rows in rows.groupby(panel_columns, sort=False):
        name = ", ".join(map(str, panel if isinstance(panel, tuple) else (panel,)))
        cells = [(" ".join(map(str, cell if isinstance(cell, tuple) else (cell,))).replace("_", " "), cell_rows)
                 for cell, cell_rows in panel_rows.groupby(other, sort=False)] if other else [(name, panel_rows)]
        if len(cells) == 1:
            singles.append((f"{name}: {cells[0][0]}" if other else name, cells[0][1]))
        else:
            panels.append((name, cells))
    if singles:
        panels.append(("one-cell evaluation sets", singles))
    return panels


def plot_intervals(aggregate: pd.DataFrame, group_columns: list[str], output: Path) -> list[str]:
    """``intervals_<metric>.png``: a panel per evaluation set (two a row; the one-cell sets share a panel), a bar
    per condition and variant with its interval."""
    from matplotlib.figure import Figure  # no pyplot: the caller's matplotlib backend is left alone

    cell_columns = [c for c in group_columns if c != "variant"]
    names = []
    for metric, rows in aggregate.groupby("metric", sort=False):
        variants = list(dict.fromkeys(rows["variant"]))
        panels = _interval_panels(rows, cell_columns)
        n_cols = 2 if len(panels) > 2 else 1  # two panels a row, stacked when there are only two
        n_rows = -(-len(panels) // n_cols)
        figure = Figure(figsize=(6.0 * n_cols, 3.4 * n_rows))
        axes = figure.subplots(n_rows, n_cols, squeeze=False)
        width = 0.8 / len(variants)
        for axis, (title, cells) in zip(axes.flat, panels):
            for k, variant in enumerate(variants):
                x, height, low, high = [], [], [], []
                for i, (_, cell_rows) in enumerate(cells):
                    found = cell_rows[cell_rows["variant"] == variant]
                    if len(found) and not np.isnan(found["iqm"].iloc[0]):
                        r = found.iloc[0]
                        x.append(i + (k - (len(variants) - 1) / 2) * width)
                        height.append(r["iqm"])
                        low.append(r["iqm"] - r["iqm_low"])
                        high.append(r["iqm_high"] - r["iqm"])
                axis.bar(x, height, width, yerr=[low, high], capsize=2, label=variant, color=f"C{k}")
            axis.set_xticks(range(len(cells)), [label for label, _ in cells], fontsize=10, rotation=20, ha="right")
            axis.set_title(title, fontsize=12)
            axis.tick_params(axis="y", labelsize=10)
        for axis in axes.flat[len(panels):]:
            axis.set_visible(False)
        handles, labels = axes[0, 0].get_legend_handles_labels()
        figure.legend(handles, labels, loc="upper right", ncol=len(variants), fontsize=11, frameon=False)
        figure.supylabel(f"{METRIC_LABELS.get(metric, metric)}, IQM across training seeds", fontsize=12)
        figure.suptitle("IQM across training seeds, 95 % stratified-bootstrap CIs", fontsize=12, x=0.02, ha="left")
        figure.tight_layout(rect=(0, 0, 1, 1 - 0.4 / (3.4 * n_rows)))
        name = f"intervals_{metric}.png"
        with atomic_path(output / name) as path:
            figure.savefig(path, dpi=100)
        names.append(name)
    return names


def plot_cells(
    aggregate: pd.DataFrame,
    cells: list[tuple[str, dict[str, object]]],
    path: str | Path,
    metric: str = "coverage",
    title: str = "",
    reference: tuple[float, str] | None = None,
) -> Path:
    """A row per chosen cell of an aggregate table: the across-seed mean (point) with its 95 % interval (whiskers).

    :param aggregate: the long table of :func:`~.aggregate.aggregate_scores` (``aggregate.csv``)
    :param cells: ``(label, {column: value, ...})`` per bar, top to bottom; each must select exactly one row of
        ``metric`` (e.g. ``{"eval_set": "table1", "condition": "no_comm", "variant": "proposed"}``)
    :param path: the PNG to write (6.4 in wide at 120 dpi: legible at a documentation page's width)
    :param reference: ``(value, label)`` of a vertical dashed line (a target or the paper's number)
    :raises ValueError: when a cell selects no row or several
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's matplotlib backend is left alone

    rows = []
    for label, selection in cells:
        mask = aggregate["metric"] == metric
        for column, value in selection.items():
            mask &= aggregate[column].astype(str) == str(value)
        if mask.sum() != 1:
            raise ValueError(f"cell {label!r} ({selection}) selects {int(mask.sum())} rows of {metric}, expected 1")
        rows.append(aggregate[mask].iloc[0])
    means = np.array([r["mean"] for r in rows])
    errors = np.array([[r["mean"] - r["mean_low"], r["mean_high"] - r["mean"]] for r in rows]).T
    figure = Figure(figsize=(6.4, 0.42 * len(rows) + 1.0))
    axis = figure.subplots()
    y = np.arange(len(rows))[::-1]
    for k, (yi, value) in enumerate(zip(y, means)):  # a point with its interval: no bar to cut at an axis limit
        axis.errorbar(value, yi, xerr=errors[:, k : k + 1], fmt="o", ms=6, capsize=4, color=f"C{k}")
        axis.text(value + errors[1, k], yi + 0.12, f"  {value:.1f}", va="bottom", ha="left", fontsize=8)
    axis.set_yticks(y, [label for label, _ in cells], fontsize=9)
    axis.grid(axis="x", alpha=0.3)
    if reference is not None:
        axis.axvline(reference[0], color="black", ls="--", lw=1)
        axis.text(reference[0], y.max() + 0.6, f" {reference[1]}", fontsize=8, va="bottom")
    low = float(np.nanmin([r["mean_low"] for r in rows]))
    high = float(np.nanmax([r["mean_high"] for r in rows] + ([reference[0]] if reference else [])))
    margin = 0.12 * (high - low) + 0.3
    axis.set_xlim(max(0.0, low - margin), high + 2 * margin)
    axis.set_ylim(-0.7, len(rows) - 0.1 + (0.6 if reference else 0.0))
    axis.set_xlabel(f"{METRIC_LABELS.get(metric, metric)}: mean across training seeds, 95 % CI", fontsize=9)
    axis.tick_params(axis="x", labelsize=8)
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    return Path(path)


def _plot_learning_curves(progress: pd.DataFrame, grid_columns: list[str], output: Path) -> str | None:
    from matplotlib.figure import Figure  # no pyplot: the caller's matplotlib backend is left alone

    if progress.empty:
        return None
    progress = progress.assign(report=progress.groupby("trial_id").cumcount())
    metrics = [m for m in ("coverage", "episode_reward") if progress[m].notna().any()]
    if not metrics:
        return None
    figure = Figure(figsize=(5.5 * len(metrics), 3.8))
    axes = figure.subplots(1, len(metrics), squeeze=False)
    for axis, metric in zip(axes[0], metrics):
        for group, runs in progress.groupby([*grid_columns, "variant"], sort=False):
            group = group if isinstance(group, tuple) else (group,)
            curves = runs.pivot(index="train_seed", columns="report", values=metric)  # (n_seeds, n_reports)
            steps = runs.groupby("report")["agent_steps"].mean().to_numpy()
            points = [stratified_bootstrap_ci(c[np.isfinite(c)], mean, reps=2000) if np.isfinite(c).any() else (np.nan,) * 3
                      for c in curves.to_numpy().T]
            point, low, high = np.array(points).T
            label = ", ".join(map(str, group))
            axis.plot(steps, point, marker="o" if len(steps) < 30 else None, label=f"{label} ({len(curves)} seeds)")
            axis.fill_between(steps, low, high, alpha=0.25)
        axis.set_xlabel("agent-steps")
        axis.set_ylabel({"coverage": "coverage of finished episodes (%)", "episode_reward": "episode return"}[metric])
        axis.legend(fontsize=8)
    figure.suptitle("Training: mean across seeds, 95 % bootstrap band")
    figure.tight_layout()
    with atomic_path(output / "learning_curves.png") as path:
        figure.savefig(path, dpi=120)
    return "learning_curves.png"


PLATEAU_FRACTION = 1 / 3
"""The share of a training run, at its end, over which :func:`training_plateau` fits its slope."""


def training_plateau(progress: pd.DataFrame, grid_columns: list[str], fraction: float = PLATEAU_FRACTION) -> pd.DataFrame:
    """Whether the training curves have flattened: per trial, the least-squares slope of the training coverage (finished
    episodes of each rollout, %) over the last ``fraction`` of its reports, in points per million agent-steps, and the
    mean coverage over that window; then per (grid point, variant) the across-seed mean and range of both.

    :param progress: the trials' ``progress.csv`` rows (``agent_steps``, ``coverage``, ``trial_id``, ``variant``,
        ``train_seed`` and the grid columns)
    :return: one row per (grid point, variant): ``seeds``, ``final_coverage`` / ``_min`` / ``_max`` and
        ``slope_per_M`` / ``_min`` / ``_max`` (empty when no trial logged coverage)
    :raises ValueError: for ``fraction`` outside (0, 1]
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    rows = []
    for run_id, runs in progress.dropna(subset=["coverage"]).groupby("trial_id", sort=False):
        tail = runs.iloc[-max(2, int(round(len(runs) * fraction))):]
        if len(tail) < 2:
            continue
        slope = np.polyfit(tail["agent_steps"].to_numpy(float) / 1e6, tail["coverage"].to_numpy(float), 1)[0]
        rows.append({**{c: runs[c].iloc[0] for c in [*grid_columns, "variant", "train_seed"]}, "trial_id": run_id,
                     "final_coverage": float(tail["coverage"].mean()), "slope_per_M": float(slope)})
    if not rows:
        return pd.DataFrame()
    per_trial = pd.DataFrame(rows)
    grouped = per_trial.groupby([*grid_columns, "variant"], sort=False)
    summary = grouped.agg(seeds=("train_seed", "size"),
                          final_coverage=("final_coverage", "mean"), final_coverage_min=("final_coverage", "min"),
                          final_coverage_max=("final_coverage", "max"), slope_per_M=("slope_per_M", "mean"),
                          slope_per_M_min=("slope_per_M", "min"), slope_per_M_max=("slope_per_M", "max"))
    return summary.reset_index()


def _plateau_markdown(plateau: pd.DataFrame, grid_columns: list[str], fraction: float = PLATEAU_FRACTION) -> str:
    rows = [{**{c: row[c] for c in [*grid_columns, "variant"]}, "seeds": int(row["seeds"]),
             f"training coverage, last {fraction:.0%} (%)":
                 f"{row['final_coverage']:.1f} [{row['final_coverage_min']:.1f}, {row['final_coverage_max']:.1f}]",
             "slope (points per 1M agent-steps)":
                 f"{row['slope_per_M']:+.2f} [{row['slope_per_M_min']:+.2f}, {row['slope_per_M_max']:+.2f}]"}
            for _, row in plateau.iterrows()]
    from sb3_latentswarm.evaluation import to_markdown

    return to_markdown(pd.DataFrame(rows))


def _in_sweep_order(frame: pd.DataFrame, columns: list[str], spec: SweepSpec) -> pd.DataFrame:
    """``frame`` sorted by ``columns``, with variants, evaluation sets and conditions in the order the sweep names them."""
    ranks = {"variant": spec.variants, "eval_set": [s.name for s in spec.eval_sets], "condition": all_conditions()}

    def rank(column: pd.Series) -> pd.Series:
        return column.map({value: i for i, value in enumerate(ranks[column.name])}) if column.name in ranks else column

    return frame.sort_values(columns, key=rank, kind="stable", ignore_index=True)


def _counts(values: pd.Series) -> str:
    """``"50"``, or ``"50 (3 runs), 300 (1 run)"`` when the stored files disagree."""
    counts = values.value_counts(sort=False).sort_index()
    if len(counts) == 1:
        return f"{counts.index[0]:,}"
    return ", ".join(f"{value:,} ({n} run{'s' if n > 1 else ''})" for value, n in counts.items())


def write_report(output: str | Path, commit: str | None = None) -> pd.DataFrame:
    """Write the tables, plots and ``run.md`` of the sweep in ``output`` from its finished trials.

    ``run.md`` states what the stored files show: episode counts and seeds from the episodes, budgets, machines and
    nodes from the trials' records; ``sweep.json`` gives only what was planned.

    :param commit: the code that writes the report (default: the first trial's); each trial records its own
    :return: the aggregate table (long format, see :func:`~.aggregate.aggregate_scores`)
    :raises ValueError: when no trial is finished, or a trial folder is stray or damaged (:func:`finished_trials`)
    """
    from sb3_latentswarm.experiments.run_record import write_run_record

    output = Path(output)
    spec = SweepSpec.load(output / "sweep.json")
    by_id = finished_trials(output, spec)
    if not by_id:
        raise ValueError(f"{output}: no finished trial to report")
    ids, records = list(by_id), list(by_id.values())
    grid_columns = list(grid_labels(dict.fromkeys(spec.grid)))
    episodes = _read_trials(output, ids, "episodes.csv")
    with atomic_path(output / "episodes.csv") as path:
        episodes.to_csv(path, index=False)
    run_columns = [*grid_columns, *CELL_COLUMNS, "variant", "train_seed", "trial_id"]
    scores = _in_sweep_order(run_scores(episodes, run_columns), run_columns, spec)
    with atomic_path(output / "scores.csv") as path:
        scores.to_csv(path, index=False)
    group_columns = [*grid_columns, *CELL_COLUMNS, "variant"]  # the variants of one cell side by side
    aggregate = aggregate_scores(scores, group_columns, score_metrics(episodes))
    with atomic_path(output / "aggregate.csv") as path:
        aggregate.to_csv(path, index=False)
    markdown = aggregate_markdown(aggregate, group_columns)
    write_text(output / "aggregate.md", markdown)
    figures = plot_intervals(aggregate, group_columns, output)
    progress = _read_trials(output, ids, "progress.csv")
    curves = _plot_learning_curves(progress, grid_columns, output)
    if curves:
        figures.append(curves)
    plateau = training_plateau(progress, grid_columns) if "coverage" in progress.columns else pd.DataFrame()

    seeds = scores.groupby("variant", sort=False)["train_seed"].unique()
    seeds_per_variant = {variant: sorted(int(seed) for seed in values) for variant, values in seeds.items()}
    machines = sorted({f"{r['node']}: {r['machine']}" for r in records})
    nodes: dict[str, list[str]] = {}
    for r in records:
        nodes.setdefault(f"{r['node']} (Ray node {r.get('ray_node_id') or 'not recorded'})", []).append(r["trial_id"])
    cells = scores.drop_duplicates("eval_set")
    eval_sets = ", ".join(
        f"{s.name} ({', '.join(f'{k}={v}' for k, v in s.overrides.items()) or 'preset config'}; "
        f"{', '.join(s.conditions) if s.conditions else 'every condition'})"
        for s in spec.eval_sets
        if s.name in set(cells["eval_set"])
    )
    presets = sorted({r["preset"] for r in records})
    overrides = f", with {spec.overrides}" if spec.overrides else ""
    on_env = "" if spec.env is None else f", on the adapted env {spec.env.name} {json.dumps(dict(spec.env.kwargs))}"
    facts = [
        f"preset: {', '.join(presets)}{overrides}{on_env}",
        f"variants and training seeds finished: {seeds_per_variant}",
        f"trials: {len(records)} finished of the {spec.n_trials} planned in sweep.json"
        + (f"; grid {dict(spec.grid)}" if spec.grid else ""),
        f"budget: {_counts(pd.Series([r['budget_agent_steps'] for r in records]))} agent-steps per trial "
        f"(trained: {_counts(pd.Series([r['trained_agent_steps'] for r in records]))}; SB3 finishes the last rollout)",
        f"evaluation: {_counts(scores['episodes'])} episode{'' if set(scores['episodes']) == {1} else 's'} per cell and "
        "run (scores.csv), env seeds "
        f"{episodes['seed'].min()}..{episodes['seed'].max()} (episodes.csv), "
        f"{' and '.join(sorted({'mean' if r['deterministic'] else 'sampled' for r in records}))} actions; cells: {eval_sets}",
        "intervals: across training seeds, a run's score in a cell is its mean over the cell's episodes; IQM and mean "
        "with 95 % stratified percentile-bootstrap CIs (10,000 replicates, our NumPy port of rliable's method)",
        f"trial commits: {', '.join(sorted({r['commit'] for r in records}))}",
        f"trial machines: {'; '.join(machines)}",
        "trial nodes: " + "; ".join(f"{node}: {', '.join(sorted(ran))}" for node, ran in nodes.items()),
        f"train wall time per trial: {np.median([r['train_seconds'] for r in records]):.0f} s (median)",
    ]
    warm = [r["warm_start"] for r in records if r.get("warm_start")]
    if warm:
        earlier_seconds = [w["train_seconds"] for w in warm if w.get("train_seconds") is not None]
        facts.append(
            f"warm start: {len(warm)} of {len(records)} trials continue the models of {sorted({w['sweep'] for w in warm})} "
            f"from {_counts(pd.Series([w['agent_steps'] for w in warm]))} agent-steps (trained at commits "
            f"{', '.join(sorted({str(w.get('commit')) for w in warm}))}"
            + (f", {np.median(earlier_seconds):.0f} s median" if earlier_seconds else "")
            + "); the train wall time above is the continuation's"
        )
    body = ["## Across-seed intervals", "", markdown]
    if not plateau.empty:
        body += ["## Have the training curves flattened?", "",
                 f"Per trial, the least-squares slope of the training coverage over the last {PLATEAU_FRACTION:.0%} of "
                 "its updates (finished episodes of each rollout, the training actions); across-seed mean [min, max].",
                 "", _plateau_markdown(plateau, grid_columns), ""]
    body += ["## Figures", "", *(f"![{name}]({name})" for name in figures), ""]
    write_run_record(output, f"Sweep: preset `{spec.preset}`", commit or records[0]["commit"], facts, body)
    return aggregate
