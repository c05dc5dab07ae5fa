"""Regenerate Table I of the paper (ablations, left; p_f sweep, right) and the comparisons it does not have.

Trains ``LatentSwarmPPO`` on a preset (or loads ``--model``), evaluates the five conditions of Sec. IV and the p_f sweep
over ``eval_episodes`` Monte Carlo runs each, with sampled actions (the paper's protocol, Sec. III-D: commands are
sampled from the Gaussian policy at execution) and with mean actions beside them, on held-out episode seeds
(default from :data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, never a training env copy's), adds the baselines
(random, lawnmower, frontier explorer with explicit map sharing, independent RecurrentPPO without messages), and
writes into ``--output`` (default ``runs/table1_PRESET/``; results published in the documentation are copied to
``docs/results/`` by hand):

* ``conditions.csv`` / ``conditions.md`` (ours next to the paper's numbers; sampled actions first, then mean actions;
  the ``actions`` column of the CSV says which), ``p_fail_sweep.csv`` / ``.md``, ``baselines.csv`` / ``.md``
* ``coverage_vs_time.png`` (mean coverage against time per condition) and ``coverage_vs_p_fail.png`` (sampled
  actions; ``*_mean_actions.png`` beside them)
* ``run.md``: command, commit, machine, wall times, seeds
* ``evaluation.json``: what the tables were made from (the model file's SHA-256, config, episodes, env seeds,
  actions, p_f values) and which are complete; each table is written, atomically, as soon as it is complete. A folder
  holding another model's tables is refused

    python examples/reproduce_table1.py --preset smoke            # seconds, checks the pipeline
    python examples/reproduce_table1.py --preset fast             # ~45 min on a 2-core CPU
    python examples/reproduce_table1.py --preset paper --device cuda
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sb3_latentswarm.presets import PRESETS, get_preset
from sb3_latentswarm.utils.atomic import atomic_path, probe_writable, write_json, write_text

ACTION_MODES = ("both", "sampled", "mean")
DETERMINISTIC = {"sampled": False, "mean": True}
"""``evaluate(deterministic=...)`` of each action mode."""
HELD_OUT_SEED = 1_000_000
"""The first episode seed by default: :data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, a literal: --help loads no torch."""


def option(default, help: str):  # noqa: A002 - argparse's name
    """A field of :class:`Args` with the help text that ``--help`` shows."""
    return field(default=default, metadata={"help": help})


@dataclass
class Args:
    preset: str = option("fast", "experiment budget: paper, fast, demo or smoke")
    model: str | None = option(None, "evaluate this saved model instead of training one")
    output: str | None = option(None, "result folder (default: runs/table1_PRESET)")
    seed: int = option(0, "training seed (env copy c uses env seed seed + c) and the random planner's seed")
    eval_seed: int = option(
        HELD_OUT_SEED, "first evaluation episode seed (episode k uses env seed eval_seed + k; default: held out from training)"
    )
    episodes: int | None = option(None, "Monte Carlo runs per condition (default: the preset's, 10 for paper and fast)")
    no_independent_ppo: bool = option(False, "skip training the independent RecurrentPPO baseline")
    baseline_timesteps: int | None = option(None, "agent-steps of the independent RecurrentPPO (default: the preset's)")
    independent_model: str | None = option(
        None, "evaluate this saved independent RecurrentPPO (independent_ppo.zip of an earlier run) instead of training one"
    )
    actions: str = option(
        "both", "actions of the learned policies: sampled (the paper's protocol), mean, or both (sampled first)"
    )
    model_notes: str | None = option(None, "how a --model was trained, written into run.md next to its path")
    device: str = option("auto", "torch device: auto, cpu or cuda")
    threads: int = option(0, "torch CPU threads (0: the package default, one; see sb3_latentswarm.utils.threads)")


def parse_args() -> Args:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for spec in dataclasses.fields(Args):
        flag = "--" + spec.name.replace("_", "-")
        text = spec.metadata["help"]
        if spec.type == "bool":
            parser.add_argument(flag, action="store_true", help=text)
        elif spec.name == "preset":
            parser.add_argument(flag, default=spec.default, choices=sorted(PRESETS), help=f"{text} (default: %(default)s)")
        elif spec.name == "actions":
            parser.add_argument(flag, default=spec.default, choices=ACTION_MODES, help=f"{text} (default: %(default)s)")
        else:
            kind = int if spec.type in ("int", "int | None") else str
            parser.add_argument(flag, type=kind, default=spec.default, help=text)
    return Args(**vars(parser.parse_args()))


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO  # noqa: E402
from sb3_latentswarm.baselines import (  # noqa: E402
    FrontierPlanner,
    IndependentRecurrentPPO,
    LawnmowerPlanner,
    RandomPlanner,
    train_independent_ppo,
)
from sb3_latentswarm.evaluation import (  # noqa: E402
    CONDITION_LABELS,
    PAPER_TABLE1_P_FAIL,
    check_held_out,
    evaluate,
    evaluate_conditions,
    evaluate_p_fail_sweep,
    seed_range,
    side_by_side,
    summarize,
    to_markdown,
)
from sb3_latentswarm.experiments.run_record import git_commit, write_run_record  # noqa: E402


def plot_curves(curves: dict, labels: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for key, curve in curves.items():
        mean, std = curve.mean(0), curve.std(0)
        steps = np.arange(len(mean))
        ax.plot(steps, mean, label=labels.get(key, str(key)))
        ax.fill_between(steps, mean - std, mean + std, alpha=0.15)
    ax.axhline(90, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("step")
    ax.set_ylabel("coverage (%)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def plot_p_fail(sweep: pd.DataFrame, paper: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grouped = sweep.groupby("p_fail")["coverage"]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.errorbar(grouped.mean().index, grouped.mean(), yerr=grouped.std(), marker="o", capsize=3, label="ours")
    ax.errorbar(paper["p_fail"], paper["coverage_mean"], yerr=paper["coverage_std"], marker="s", capsize=3, label="paper")
    ax.set_xlabel("link failure probability $p_f$")
    ax.set_ylabel("final coverage (%)")
    ax.legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def write_table(output: Path, name: str, frame: pd.DataFrame, markdown: str, record: dict) -> None:
    """Write ``NAME.csv`` and ``NAME.md`` atomically as soon as the table is complete, and record it."""
    with atomic_path(output / f"{name}.csv") as tmp:
        frame.to_csv(tmp, index=False)
    write_text(output / f"{name}.md", markdown + "\n")
    record["tables"].append(name)
    write_json(output / RECORD, record)


RECORD = "evaluation.json"
"""What the tables in the output folder were made from (model file hash, config, episodes, seeds, actions)."""
TABLES = ("conditions", "p_fail_sweep", "baselines")


def check_output(output: Path, record: dict | None) -> None:
    """Refuse an output folder holding the tables of another model or evaluation (``record``: this one's identity;
    ``None`` before a model is trained, when any earlier table is another model's)."""
    present = [name for name in TABLES if (output / f"{name}.csv").exists()]
    if not present:
        return
    recorded = json.loads((output / RECORD).read_text()) if (output / RECORD).exists() else None
    keys = ("model_sha256", "config", "episodes", "env_seeds", "actions", "p_fails")
    if record is None:
        reason = "a model trained now would not be the one they were made from"
    elif recorded is None:
        reason = f"they have no {RECORD}"
    else:
        differ = [key for key in keys if recorded.get(key) != record.get(key)]
        if not differ:
            return
        reason = f"they were made with another {', '.join(differ)}"
    raise SystemExit(
        f"reproduce_table1.py: {output} holds the tables of another run ({', '.join(present)}; {reason}); pass another "
        f"--output"
    )


def main() -> None:
    args = parse_args()
    if args.threads:
        th.set_num_threads(args.threads)
    preset = get_preset(args.preset)
    if args.episodes:
        preset = dataclasses.replace(preset, eval_episodes=args.episodes)
    config, episodes, seed, eval_seed = preset.config, preset.eval_episodes, args.seed, args.eval_seed
    if not args.model:  # the episodes must not replay the first episode of a training env copy
        check_held_out(eval_seed, episodes, seed, preset.n_envs)
    output = Path(args.output or f"runs/table1_{preset.name}")
    if not args.model:
        check_output(output, None)  # before hours of training
    probe_writable(output, room_bytes=1 << 20)
    timings: dict[str, float] = {}
    modes = ["sampled", "mean"] if args.actions == "both" else [args.actions]  # the learned policies'; planners have rules
    commit = git_commit()  # the code that runs, before anything is written

    start = time.perf_counter()
    if args.model:
        model = LatentSwarmPPO.load(args.model, device=args.device)
        trained = f"loaded from `{args.model}` ({args.model_notes or 'trained elsewhere; see the notes next to this file'})"
    else:
        env = preset.make_env(seed, config=config)
        model = preset.make_model(env, seed=seed, device=args.device)
        model.learn(total_timesteps=preset.total_timesteps, progress_bar=sys.stdout.isatty())
        model.save(output / "model.zip")  # atomic: a failed save leaves no partial file
        trained = f"trained here for {preset.total_timesteps:,} agent-steps ({preset.updates} updates), seed {seed}"
    timings["LatentSwarmPPO loading" if args.model else "LatentSwarmPPO training"] = time.perf_counter() - start

    record = {
        "model": str(args.model or output / "model.zip"),
        "model_sha256": hashlib.sha256(Path(args.model or output / "model.zip").read_bytes()).hexdigest(),
        "preset": preset.name,
        "config": config.to_dict(),
        "episodes": episodes,
        "env_seeds": [eval_seed, eval_seed + episodes - 1],
        "actions": modes,
        "p_fails": list(preset.p_fails),
        "tables": [],
    }
    check_output(output, record)
    write_json(output / RECORD, record)

    # Table I, left: the five conditions; right: the p_f sweep; in every action mode, the same episodes
    start = time.perf_counter()
    condition_frames, sweep_frames, condition_tables, sweep_tables = [], [], {}, {}
    for mode in modes:
        conditions, condition_curves = evaluate_conditions(
            model,
            p_fail=config.p_fail,
            n_episodes=episodes,
            seed=eval_seed,
            config=config,
            return_curves=True,
            deterministic=DETERMINISTIC[mode],
        )
        condition_frames.append(conditions.assign(actions=mode))
        condition_tables[mode] = side_by_side(summarize(conditions, by="condition"))
        suffix = "" if mode == modes[0] else f"_{mode}_actions"
        plot_curves(
            condition_curves,
            CONDITION_LABELS,
            output / f"coverage_vs_time{suffix}.png",
            f"Coverage against time ({preset.name}, {mode} actions)",
        )
        sweep = evaluate_p_fail_sweep(
            model, p_fails=preset.p_fails, n_episodes=episodes, seed=eval_seed, config=config,
            deterministic=DETERMINISTIC[mode],
        )
        sweep_frames.append(sweep.assign(actions=mode))
        sweep_tables[mode] = side_by_side(summarize(sweep, by="p_fail"))
        plot_p_fail(sweep, PAPER_TABLE1_P_FAIL, output / f"coverage_vs_p_fail{suffix}.png")
    conditions = pd.concat(condition_frames, ignore_index=True)
    seeds = seed_range(eval_seed, episodes)
    write_table(output, "conditions", conditions, _tables_by_mode(condition_tables, seeds), record)
    sweeps = pd.concat(sweep_frames, ignore_index=True)
    write_table(output, "p_fail_sweep", sweeps, _tables_by_mode(sweep_tables, seeds), record)
    timings["evaluation of conditions and p_f sweep"] = time.perf_counter() - start

    # Beyond the paper: classical planners and an independent learner, same env, metrics and seeds
    start = time.perf_counter()
    rows = []
    planners = {"random": RandomPlanner(config, seed=seed), "lawnmower": LawnmowerPlanner(config)}
    for name, planner in planners.items():
        frame = evaluate(planner, "proposed", n_episodes=episodes, seed=eval_seed, config=config)
        rows.append(frame.assign(condition=name, actions="planner"))
    frontier = FrontierPlanner(config)
    for condition in ("proposed", "full_comm", "no_comm"):
        frame = evaluate(frontier, condition, n_episodes=episodes, seed=eval_seed, config=config)
        rows.append(frame.assign(condition=f"frontier ({condition})", actions="planner"))
    if args.independent_model:
        independent = IndependentRecurrentPPO.load(args.independent_model, device=args.device)
    elif (args.baseline_timesteps or preset.baseline_timesteps) and not args.no_independent_ppo:
        independent_env = preset.make_env(seed, config=config)
        independent = train_independent_ppo(independent_env, args.baseline_timesteps or preset.baseline_timesteps, seed)
        independent.save(output / "independent_ppo.zip")
    else:
        independent = None
    for mode in modes:
        if independent is not None:
            steps = independent.model.num_timesteps
            with th.random.fork_rng():  # its sampled actions come from torch's generator: seed it, restore it after
                th.manual_seed(eval_seed)
                frame = evaluate(
                    independent, "proposed", n_episodes=episodes, seed=eval_seed, config=config,
                    deterministic=DETERMINISTIC[mode],
                )
            rows.append(frame.assign(condition=f"independent RecurrentPPO ({steps:,} steps, {mode})", actions=mode))
        proposed = conditions[(conditions["condition"] == "proposed") & (conditions["actions"] == mode)]
        rows.append(proposed.assign(condition=f"LatentSwarmPPO (proposed, {mode})"))
    baselines = pd.concat(rows, ignore_index=True)
    baseline_summary = summarize(baselines, by="condition")
    write_table(output, "baselines", baselines, f"Episode {seeds}.\n\n" + to_markdown(baseline_summary), record)
    timings["baselines"] = time.perf_counter() - start

    facts = [
        f"model: {trained}",
        f"preset: {preset.description}",
        f"evaluation: {episodes} episodes per row, env {seeds} (held out from the training env seeds "
        f"{seed}..{seed + preset.n_envs - 1} when trained here), actions of the learned policies: "
        f"{' and '.join(modes)}, p_f = {config.p_fail} unless swept",
        *(f"wall time, {name}: {seconds:.0f} s" for name, seconds in timings.items()),
    ]
    body = [
        "## Conditions (Table I, left)\n",
        _tables_by_mode(condition_tables, seeds, level="###"),
        "",
        "## p_f sweep (Table I, right)\n",
        _tables_by_mode(sweep_tables, seeds, level="###"),
        "",
        "## Baselines (not in the paper)\n",
        f"Episode {seeds}.\n",
        to_markdown(baseline_summary),
    ]
    write_run_record(output, f"Table I run: preset `{preset.name}`", commit, facts, body, device=model.device)


def _tables_by_mode(tables: dict[str, pd.DataFrame], seeds: str, level: str = "##") -> str:
    """One markdown table per action mode, sampled (the paper's protocol) first, each headed by its mode and seeds."""
    parts = []
    for mode, table in tables.items():
        note = " (the paper's protocol, Sec. III-D)" if mode == "sampled" else " (the Gaussian's mean)"
        parts += [f"{level} {mode.capitalize()} actions{note}, episode {seeds}\n", to_markdown(table), ""]
    return "\n".join(parts).rstrip()


if __name__ == "__main__":
    main()
