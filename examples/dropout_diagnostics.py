"""How close each dropout substitute is to the message full connectivity would have delivered (a diagnostic the
paper does not report).

At every dropout step (no live in-link, Sec. III-C) the policy acts on a substitute for the received message: the
memory-conditioned prediction mhat_t (``proposed``), a zero vector (``no_predictor``), the last message actually
received (``hold_last``) or the agent's own message (``own_message``). This script evaluates one saved model under
these conditions on held-out episodes (sampled actions by default, the paper's protocol) and reports, per condition,
the share of agent-steps in dropout, the mean dropout run length, and the substitute's per-element squared error
against the mean of the peers' messages z_{t-1}^j, overall and by dropout depth (1, 2-5, 6-15, > 15 steps into the
outage; columns of :mod:`sb3_latentswarm.evaluation.diagnostics`), with coverage and collisions beside them.
Writes into ``--output``: ``episodes.csv`` (one row per episode), ``dropout_diagnostics.csv`` / ``.md`` (the table),
``error_by_depth.png`` (the plot) and ``run.md``. How ``docs/results/archive/coordination_dropout_diagnostics`` was made
(its model is ``git checkout 206f0d5 -- docs/results/coordination/trials/proposed-seed0``, or the weight-only copy
``tests/data/models/coordination-proposed-seed0.zip``, which gives the same table):

    python examples/dropout_diagnostics.py --model docs/results/coordination/trials/proposed-seed0/model.zip \\
        --episodes 20 --output docs/results/archive/coordination_dropout_diagnostics
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

SUBSTITUTE_CONDITIONS = ("proposed", "no_predictor", "hold_last", "own_message")
"""The conditions that differ only in the dropout substitute (for a model trained with the predictor)."""
HELD_OUT_SEED = 1_000_000
"""The first episode seed by default: :data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, a literal: --help loads no torch."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, help="saved LatentSwarmPPO (evaluated on its training config)")
    parser.add_argument("--conditions", nargs="+", default=list(SUBSTITUTE_CONDITIONS), help="test-time conditions")
    parser.add_argument("--episodes", type=int, default=20, help="held-out episodes per condition")
    parser.add_argument("--eval-seed", type=int, default=HELD_OUT_SEED, help="episode k uses env seed eval_seed + k")
    parser.add_argument("--actions", choices=("sampled", "mean"), default="sampled",
                        help="sampled (the paper's protocol, default) or mean actions")
    parser.add_argument("--p-fail", type=float, default=None, help="link failure probability (default: the training one)")
    parser.add_argument("--mean-outage-steps", type=float, default=None,
                        help="mean Gilbert-Elliott outage length in steps (default: the training one)")
    parser.add_argument("--output", required=True, help="result folder")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO  # noqa: E402
from sb3_latentswarm.evaluation import (  # noqa: E402
    CONDITION_LABELS,
    DEPTH_BINS,
    DEPTH_COLUMNS,
    check_condition,
    evaluate,
    seed_range,
    to_markdown,
)
from sb3_latentswarm.experiments.run_record import git_commit, write_run_record  # noqa: E402

TABLE_COLUMNS = ("dropout_share", "dropout_run_mean", "pred_error_dropout", *DEPTH_COLUMNS, "coverage", "collisions")
DEPTH_LABELS = [
    f"{low}" if low == high else (f"> {low - 1}" if np.isinf(high) else f"{low}-{high}") for low, high in DEPTH_BINS
]


def summarize_diagnostics(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per condition: the mean over episodes of every :data:`TABLE_COLUMNS` column (NaN-ignoring: an
    episode without a dropout step at some depth does not count for that depth), and the episode count."""
    grouped = episodes.groupby("condition", sort=False)
    table = grouped[list(TABLE_COLUMNS)].mean()
    table.insert(0, "episodes", grouped.size())
    table["episodes_deepest"] = grouped[DEPTH_COLUMNS[-1]].count()  # episodes with a dropout run past the last bin start
    table.insert(0, "label", [CONDITION_LABELS[c] for c in table.index])
    return table.reset_index()


def plot_error_by_depth(table: pd.DataFrame, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    positions = np.arange(len(DEPTH_COLUMNS))
    for _, row in table.iterrows():
        ax.plot(positions, row[list(DEPTH_COLUMNS)].to_numpy(float), marker="o", label=row["label"])
    ax.set_xticks(positions, [f"{label} step{'' if label == '1' else 's'}" for label in DEPTH_LABELS])
    ax.set_yscale("log")
    ax.set_xlabel("dropout depth (steps since the last received message)")
    ax.set_ylabel("squared error per element\nvs the full-connectivity message")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if not Path(args.model).exists():
        parser.error(f"--model: no file at {args.model}")
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    for condition in args.conditions:
        check_condition(condition)
    th.set_num_threads(1)
    commit = git_commit()  # the code that runs, before anything is written
    model = LatentSwarmPPO.load(args.model, device="cpu")
    config = model.swarm_config
    if args.p_fail is not None:
        config = config.replace(p_fail=args.p_fail)
    if args.mean_outage_steps is not None:
        config = config.replace(mean_outage_steps=args.mean_outage_steps)
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    frames = [
        evaluate(
            model, condition, n_episodes=args.episodes, seed=args.eval_seed, config=config,
            deterministic=args.actions == "mean",
        )
        for condition in args.conditions
    ]
    seconds = time.perf_counter() - start
    episodes = pd.concat(frames, ignore_index=True)
    episodes.to_csv(output / "episodes.csv", index=False)
    table = summarize_diagnostics(episodes)
    table.to_csv(output / "dropout_diagnostics.csv", index=False)
    seeds = seed_range(args.eval_seed, args.episodes)
    channel = (f"p_f = {config.p_fail}, {config.outage_model} outages"
               + (f" of mean {config.mean_outage_steps:g} steps" if config.outage_model == "gilbert_elliott" else ""))
    markdown = to_markdown(table.rename(columns=dict(zip(DEPTH_COLUMNS, [f"error, depth {d}" for d in DEPTH_LABELS]))),
                           decimals=4)
    (output / "dropout_diagnostics.md").write_text(f"Episode {seeds}, {args.actions} actions, {channel}.\n\n{markdown}\n")
    plot_error_by_depth(table, output / "error_by_depth.png",
                        f"Substitute error by dropout depth ({Path(args.model).parent.name}, {args.actions} actions, "
                        f"{args.episodes} episodes)")
    facts = [
        f"model: `{args.model}`, evaluated on its training config"
        + ("" if args.p_fail is None and args.mean_outage_steps is None else " with the channel changed")
        + f" ({channel})",
        f"episodes: {args.episodes} per condition, episode {seeds} (held out from training), {args.actions} actions",
        f"wall time: {seconds:.0f} s",
    ]
    body = [
        "Means over episodes. `dropout_share`: share of agent-steps without a live in-link; `dropout_run_mean`: mean "
        "length of a dropout run (steps); `pred_error_dropout` and `error, depth d`: per-element squared error of the "
        "substitute message against the mean of the peers' messages z_{t-1}^j (what full connectivity would have "
        "delivered), over the dropout steps (at depth d: d steps into the outage); `episodes_deepest`: episodes with "
        f"a dropout run longer than {DEPTH_BINS[-1][0] - 1} steps (the last column's sample).\n",
        markdown,
        "",
        "![Substitute error by dropout depth](error_by_depth.png)",
    ]
    write_run_record(output, "Dropout diagnostics: the substitute message against full connectivity", commit, facts, body,
                     device="cpu")


if __name__ == "__main__":
    main()
