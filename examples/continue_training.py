"""Continue training a saved LatentSwarmPPO (SB3's ``load`` + ``learn(reset_num_timesteps=False)``).

This is how ``docs/results/archive/fast_600_updates`` was made from the 300-update ``fast`` model (removed from the tree to
keep it light: ``git checkout 206f0d5 -- docs/results/fast/model.zip`` brings it back, optimizer state included):

    python examples/continue_training.py --model docs/results/fast/model.zip --preset fast \
        --output runs/fast_600_updates/model.zip --env-seed 1
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from sb3_latentswarm.presets import PRESETS, get_preset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, help="saved model to continue from")
    parser.add_argument("--preset", default="fast", choices=sorted(PRESETS), help="env config and budget per call")
    parser.add_argument("--output", required=True, help="where to save the continued model (.zip)")
    parser.add_argument("--total-timesteps", type=int, default=None, help="extra agent-steps (default: the preset's)")
    parser.add_argument("--env-seed", type=int, default=1, help="seed of the new env copies")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: the package default, one)")
    args = parser.parse_args()  # before the imports: --help and bad arguments answer without loading torch
    import torch as th
    from stable_baselines3.common.logger import configure

    from sb3_latentswarm import LatentSwarmPPO

    if args.threads:
        th.set_num_threads(args.threads)

    preset = get_preset(args.preset)
    output = Path(args.output)
    output.parent.mkdir(parents=True, exist_ok=True)
    env = preset.make_env(args.env_seed)
    model = LatentSwarmPPO.load(args.model, env=env)
    model.set_logger(configure(str(output.parent), ["stdout", "csv"]))
    start = time.perf_counter()
    model.learn(args.total_timesteps or preset.total_timesteps, reset_num_timesteps=False)
    model.save(output)
    print(f"Continued for {time.perf_counter() - start:.0f} s to {model.num_timesteps:,} agent-steps; saved {output}")


if __name__ == "__main__":
    main()
