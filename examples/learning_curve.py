"""Table I (left) along training: evaluate saved checkpoints of one run under the five conditions, both ways of acting.

The paper reports one trained model, acting in a way it does not state. This script evaluates each ``--models``
checkpoint (e.g. the successive ``examples/continue_training.py`` outputs of one run) under every condition of Sec. IV,
once with the policy's mean action (``deterministic=True``, SB3's evaluation default) and once sampling it (the policy
PPO optimizes), on the same episode seeds. It writes into ``--output``:

* ``learning_curve.csv``: one row per episode (columns of :func:`sb3_latentswarm.evaluation.evaluate` plus
  ``updates``, ``agent_steps`` and ``actions``)
* ``learning_curve.md``: coverage (mean ± std) per checkpoint, way of acting and condition, and Proposed's collisions
* ``learning_curve.png``: mean coverage against PPO updates per condition, with 95 % confidence bands of the mean
* ``run.md``: command, commit, machine, models, seeds, wall time

    python examples/learning_curve.py --preset fast --episodes 100 --output docs/results/archive/fast_learning_curve \\
        --models docs/results/fast/model.zip docs/results/fast_600_updates/model.zip ...

(those models left the tree after commit 206f0d5: ``git checkout 206f0d5 -- docs/results/fast/model.zip ...``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sb3_latentswarm.presets import PRESETS, get_preset

ACTIONS = {"mean": True, "sampled": False}  # label -> deterministic


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", required=True, help="saved checkpoints of one run, in training order")
    parser.add_argument("--preset", default="fast", choices=sorted(PRESETS), help="the preset the models trained on")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per condition, checkpoint and way of acting")
    parser.add_argument("--seed", type=int, default=0, help="episode k uses env (and action-noise) seed seed + k")
    parser.add_argument("--output", required=True, help="result folder")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: the package default, one)")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO  # noqa: E402
from sb3_latentswarm.evaluation import (  # noqa: E402
    CONDITION_LABELS,
    CONDITIONS,
    COVERAGE_COLUMN,
    evaluate_conditions,
    summarize,
    to_markdown,
)
from sb3_latentswarm.experiments.run_record import git_commit, write_run_record  # noqa: E402


def evaluate_checkpoints(models: list[str], config, episodes: int, seed: int) -> pd.DataFrame:
    frames, seen = [], {}
    for path in models:
        model = LatentSwarmPPO.load(path, device="cpu")
        updates = model.num_timesteps // (model.n_steps * model.n_envs)  # one PPO update per rollout
        if updates in seen:
            raise ValueError(f"--models: {seen[updates]} and {path} both have {updates} updates; pass checkpoints of one run")
        seen[updates] = path
        for actions, deterministic in ACTIONS.items():
            frame = evaluate_conditions(
                model, p_fail=config.p_fail, n_episodes=episodes, seed=seed, config=config, deterministic=deterministic
            )
            frames.append(frame.assign(updates=updates, agent_steps=model.num_timesteps, actions=actions, model=path))
        print(f"evaluated {path} ({updates} updates)", flush=True)
    return pd.concat(frames, ignore_index=True)


def coverage_table(summary: pd.DataFrame) -> pd.DataFrame:
    """One row per (updates, actions): coverage of each condition and Proposed's collisions, as 'mean ± std'."""
    table = summary.pivot(index=["updates", "actions"], columns="condition", values=COVERAGE_COLUMN)
    table = table[list(CONDITIONS)].rename(columns=lambda c: f"{CONDITION_LABELS[c]} coverage (%)")
    proposed = summary[summary["condition"] == "proposed"].set_index(["updates", "actions"])
    table["Proposed collisions"] = proposed["Collisions"]
    return table.reset_index()


def plot(summary: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(ACTIONS), figsize=(10, 4), sharey=True)
    for ax, actions in zip(axes, ACTIONS):
        for condition in CONDITIONS:
            rows = summary[(summary["actions"] == actions) & (summary["condition"] == condition)]
            half_width = 1.96 * rows["coverage_std"] / np.sqrt(rows["n_runs"])  # 95 % CI of the mean
            ax.plot(rows["updates"], rows["coverage_mean"], marker="o", label=CONDITION_LABELS[condition])
            ax.fill_between(
                rows["updates"], rows["coverage_mean"] - half_width, rows["coverage_mean"] + half_width, alpha=0.15
            )
        ax.set_title(f"{actions} actions")
        ax.set_xlabel("PPO updates")
    axes[0].set_ylabel("final coverage (%)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    missing = [path for path in args.models if not Path(path).exists()]
    if missing:
        parser.error(f"--models: no file at {', '.join(missing)}")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.threads:
        th.set_num_threads(args.threads)
    commit = git_commit()
    config = get_preset(args.preset).config
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    try:
        episodes = evaluate_checkpoints(args.models, config, args.episodes, args.seed)
    except ValueError as error:
        parser.error(str(error))
    seconds = time.perf_counter() - start
    episodes.to_csv(output / "learning_curve.csv", index=False)
    summary = summarize(episodes, by=["updates", "actions", "condition"])
    table = to_markdown(coverage_table(summary))
    (output / "learning_curve.md").write_text(table + "\n")
    plot(summary, output / "learning_curve.png")

    facts = [
        "models: " + ", ".join(f"`{path}`" for path in args.models),
        f"evaluation: {args.episodes} episodes per cell, env seeds {args.seed}..{args.seed + args.episodes - 1} "
        f"(the same maps and starts in every cell), p_f = {config.p_fail}; 'mean' acts with the Gaussian's mean, "
        "'sampled' samples it with action-noise seed = env seed",
        f"wall time: {seconds:.0f} s",
    ]
    write_run_record(output, f"Learning curve: preset `{args.preset}`", commit, facts, [table])


if __name__ == "__main__":
    main()
