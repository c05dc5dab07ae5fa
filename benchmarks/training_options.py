"""Compare LatentSwarmPPO's training options on a preset for a fixed number of updates (same seed, same env).

Each option set trains from scratch for ``--updates`` updates; the table gives, over the last ``--window`` updates,
the rollout coverage and collisions (sampled actions), the fraction of sampled action elements inside the box, the
explained variance, and the gradient norm of each weighted loss term (first minibatch of each update). This is the
measurement behind the training defaults of the presets (docs/algorithm.md, "Training options").

    python benchmarks/training_options.py --preset fast --updates 40 --jobs 2
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--updates", type=int, default=40)
    parser.add_argument("--window", type=int, default=10, help="updates averaged at the end")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="option sets trained side by side (one thread each)")
    parser.add_argument("--output", default="runs/training_options")
    parser.add_argument("--summarize-only", action="store_true", help="only tabulate the logs already in --output")
    parser.add_argument("--sets", type=int, nargs="*", default=None, help="indices of OPTION_SETS to run (default: all)")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

from sb3_latentswarm.evaluation import to_markdown  # noqa: E402

PAPER_ALGO = dict(normalize_value=False, value_loss="mse", grad_clip="global")
MAPPO_ALGO = dict(normalize_value=True, value_loss="huber", grad_clip="per_group")
PAPER_POLICY = dict(log_std_bounds=(-5.0, 2.0), log_std_init=0.0, state_dependent_std=True)
BOUNDED_POLICY = dict(log_std_bounds=(-5.0, 0.0), log_std_init=-0.5)

OPTION_SETS: dict[str, tuple[dict, dict]] = {
    "paper (global clip, mse, std <= e^2)": (PAPER_ALGO, PAPER_POLICY),
    "MAPPO, state-dependent std <= 1": (MAPPO_ALGO, dict(BOUNDED_POLICY, state_dependent_std=True)),
    "MAPPO, state-independent std <= 1": (MAPPO_ALGO, dict(BOUNDED_POLICY, state_dependent_std=False)),
}
"""Name -> (LatentSwarmPPO options, LatentSwarmPolicy options), applied over the preset's."""

KEYS = {
    "rollout/coverage": "coverage",
    "rollout/collisions": "collisions",
    "rollout/actions_in_box": "in box",
    "train/explained_variance": "expl. var",
    "train/grad_norm_policy": "|g| policy",
    "train/grad_norm_value": "|g| value",
    "train/grad_norm_map": "|g| map",
    "train/grad_norm_pred": "|g| pred",
}


def train_one(job: tuple[str, str, int, int, str]) -> dict:
    from stable_baselines3.common.logger import configure

    from sb3_latentswarm.presets import get_preset

    name, preset_name, updates, seed, folder = job
    th.set_num_threads(1)
    preset = get_preset(preset_name)
    algo_options, policy_options = OPTION_SETS[name]
    kwargs = {**preset.algo_kwargs, **algo_options}
    kwargs["policy_kwargs"] = {**preset.algo_kwargs["policy_kwargs"], **policy_options}
    env = preset.make_env(seed)
    model = preset.make_model(env, seed=seed, log_grad_norms=True, **kwargs)
    log_dir = Path(folder) / f"option_set_{list(OPTION_SETS).index(name)}"
    model.set_logger(configure(str(log_dir), ["csv"]))
    start = time.process_time()
    model.learn(updates * model.n_steps * model.n_envs)
    return {"name": name, "log": str(log_dir / "progress.csv"), "cpu_s": time.process_time() - start}


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    folder = Path(args.output) / args.preset
    names = list(OPTION_SETS) if args.sets is None else [list(OPTION_SETS)[i] for i in args.sets]
    jobs = [(name, args.preset, args.updates, args.seed, str(folder)) for name in names]
    if args.summarize_only:
        results = [{"name": name, "log": str(folder / f"option_set_{list(OPTION_SETS).index(name)}" / "progress.csv"),
                    "cpu_s": float("nan")} for name in names]
    else:
        with mp.get_context("spawn").Pool(args.jobs) as pool:
            results = pool.map(train_one, jobs)
    rows = []
    for result in results:
        if not Path(result["log"]).exists():
            continue
        log = pd.read_csv(result["log"])
        tail = log.tail(args.window)
        row = {"option set": result["name"], "updates": len(log), "CPU s/update": result["cpu_s"] / args.updates}
        row.update({label: tail[key].mean() for key, label in KEYS.items() if key in tail})
        rows.append(row)
    table = pd.DataFrame(rows)
    print(f"preset {args.preset}, seed {args.seed}, mean of the last {args.window} updates of each run")
    print(to_markdown(table, decimals=3))
    table.to_csv(folder / "summary.csv", index=False)


if __name__ == "__main__":
    main()
