"""Training-health figures of a saved LatentSwarmPPO (the before/after table of issue "MAPPO-grade training").

For one model on its preset's env: the fraction of sampled actions inside the [-1, 1] box (per element, and whole
action vectors), the policy's mean std, the gradient norm of every weighted term of the joint loss on the first
minibatch of a fresh rollout, and coverage, collisions and steps to 90 % with mean and with sampled actions on
held-out episode seeds. Writes ``diagnostics.csv``, ``diagnostics.md`` and ``run.md`` into ``--output``.

    python examples/training_diagnostics.py --model docs/results/coordination_round2/trials/proposed-seed0/model.zip \\
        --preset coordination --output runs/diagnostics/coordination_round2
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sb3_latentswarm.presets import PRESETS, get_preset


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, action="append", help="saved LatentSwarmPPO (repeat for several)")
    parser.add_argument("--label", action="append", help="a name per --model (default: the file's folder)")
    parser.add_argument("--preset", default="fast", choices=sorted(PRESETS), help="the preset the model trained on")
    parser.add_argument("--episodes", type=int, default=50, help="held-out episodes per action mode")
    parser.add_argument("--rollout-envs", type=int, default=8, help="swarms in the diagnostic rollout")
    parser.add_argument("--output", required=True, help="result folder")
    parser.add_argument("--threads", type=int, default=1)
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO, make_vec_env  # noqa: E402
from sb3_latentswarm.evaluation import evaluate, to_markdown  # noqa: E402
from sb3_latentswarm.experiments.run_record import git_commit, write_run_record  # noqa: E402

HELD_OUT_SEED = 1_000_000
"""Episode seeds start here: far from the training env seeds (0 .. n_envs - 1 and their continuations)."""


def rollout_figures(model: LatentSwarmPPO, n_envs: int, seed: int) -> dict[str, float]:
    """Collect one rollout with the model's sampling policy and measure actions and per-term gradient norms."""
    model.set_env(make_vec_env(n_envs, config=model.swarm_config, seed=seed))
    model.tensorboard_log = None  # a diagnostic rollout writes no logs, wherever the model was trained
    _, callback = model._setup_learn(total_timesteps=1, reset_num_timesteps=False)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, model.n_steps)
    actions = model.rollout_buffer.actions  # sampled, before clipping to the box
    inside = np.abs(actions) <= 1.0
    figures = {
        "actions in box (elements)": float(inside.mean()),
        "actions in box (vectors)": float(inside.all(axis=-1).mean()),
    }
    model.policy.set_training_mode(True)
    batch = next(model.rollout_buffer.get(model.batch_size))
    losses = model._minibatch_losses(batch, clip_range=0.2, clip_range_vf=None)
    figures.update({f"grad norm {term}": norm for term, norm in model.loss_gradient_norms(losses).items()})
    # entropy of a diagonal Gaussian = sum_k (0.5 log(2 pi e) + log sigma_k): its mean log sigma, then the std
    action_dim = actions.shape[-1]
    mean_log_std = -losses["entropy"].item() / action_dim - 0.5 * np.log(2 * np.pi * np.e)
    figures["policy std (geometric mean)"] = float(np.exp(mean_log_std))
    return figures


def episode_figures(model: LatentSwarmPPO, episodes: int) -> dict[str, float]:
    figures = {}
    for label, deterministic in (("mean", True), ("sampled", False)):
        df = evaluate(model, "proposed", p_fail=None, n_episodes=episodes, seed=HELD_OUT_SEED, deterministic=deterministic)
        figures[f"coverage % ({label})"] = float(df["coverage"].mean())
        figures[f"collisions ({label})"] = float(df["collisions"].mean())
        figures[f"steps to 90% ({label})"] = float(df["steps_to_90"].mean())
        figures[f"reach 90% ({label})"] = float(df["steps_to_90"].notna().mean())
    return figures


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    labels = args.label or [Path(m).parent.name for m in args.model]
    if len(labels) != len(args.model):
        parser.error("give one --label per --model")
    th.set_num_threads(args.threads)
    commit = git_commit()
    preset = get_preset(args.preset)
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows = []
    for label, path in zip(labels, args.model):
        th.manual_seed(0)
        np.random.seed(0)
        model = LatentSwarmPPO.load(path, device="cpu")
        model.swarm_config = model.swarm_config or preset.config
        row = {"model": label, "agent-steps trained": model.num_timesteps}
        row.update(rollout_figures(model, args.rollout_envs, seed=HELD_OUT_SEED))
        row.update(episode_figures(model, args.episodes))
        rows.append(row)
    table = pd.DataFrame(rows).set_index("model").T
    table.to_csv(output / "diagnostics.csv")
    markdown = to_markdown(table.reset_index().rename(columns={"index": "figure"}), decimals=3)
    (output / "diagnostics.md").write_text(markdown + "\n")
    print(markdown)
    facts = [
        "models: " + ", ".join(f"`{p}` ({label})" for label, p in zip(labels, args.model)),
        f"rollout: {args.rollout_envs} swarms x the model's n_steps, sampled actions, env seed {HELD_OUT_SEED}; gradient "
        "norms of each weighted loss term on its first minibatch, before clipping",
        f"episodes: {args.episodes} per action mode, env seeds from {HELD_OUT_SEED}, condition proposed at the model's p_f",
        f"wall time: {time.perf_counter() - start:.0f} s",
    ]
    write_run_record(output, f"Training diagnostics: preset `{args.preset}`", commit, facts, [markdown])


if __name__ == "__main__":
    main()
