"""Train LatentSwarmPPO: the script to copy and adapt.

Builds the swarm VecEnv, trains with a progress bar, TensorBoard logging and periodic checkpoints, then saves the
model and prints a short evaluation. Defaults are a small map that learns in minutes on a laptop CPU; pass
``--preset paper`` for the paper's setting (a GPU job).

    python examples/train.py --preset demo --output runs/demo
    tensorboard --logdir runs/demo/tb
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sb3_latentswarm.presets import PRESETS, get_preset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="demo", choices=sorted(PRESETS))
    parser.add_argument("--output", default=None, help="run folder (default runs/PRESET)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--total-timesteps", type=int, default=None, help="override the preset's budget (agent-steps)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: the package default, one)")
    args = parser.parse_args()  # before the imports: --help and bad arguments answer without loading torch
    import torch as th
    from stable_baselines3.common.callbacks import CheckpointCallback

    from sb3_latentswarm.evaluation import evaluate, summarize, to_markdown

    if args.threads:
        th.set_num_threads(args.threads)

    preset = get_preset(args.preset)
    output = Path(args.output or f"runs/{preset.name}")
    env = preset.make_env(args.seed)
    model = preset.make_model(env, seed=args.seed, tensorboard_log=str(output / "tb"), verbose=0)
    # a checkpoint every ~10 updates (save_freq counts vec-env steps, i.e. agent-steps / num_envs)
    checkpoints = CheckpointCallback(save_freq=10 * model.n_steps, save_path=str(output / "checkpoints"), name_prefix="model")
    model.learn(total_timesteps=args.total_timesteps or preset.total_timesteps, callback=checkpoints, progress_bar=True)
    model.save(output / "model.zip")

    results = evaluate(model, condition="proposed", n_episodes=preset.eval_episodes, seed=args.seed, config=preset.config)
    print(to_markdown(summarize(results)))
    print(f"Saved {output / 'model.zip'}")


if __name__ == "__main__":
    main()
