"""Wall time of ``LatentSwarmPPO.learn`` updates of a preset (rollout + training), and what the preset's budget costs.

One update is ``n_steps * n_envs * n_agents`` agent-steps (the ``paper`` preset: 600 * 40 * 3 = 72,000, with d = 512).
The estimate for the whole budget multiplies the mean update time by the preset's number of updates.

    python benchmarks/update_time.py --preset paper --updates 1 --threads 1
"""

from __future__ import annotations

import argparse
import platform
import time

import torch as th

from sb3_latentswarm import LatentSwarmPPO, make_vec_env
from sb3_latentswarm.presets import PRESETS, get_preset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper", choices=sorted(PRESETS))
    parser.add_argument("--updates", type=int, default=1)
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: the package default)")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    if args.threads:
        th.set_num_threads(args.threads)

    preset = get_preset(args.preset)
    env = make_vec_env(preset.n_envs, config=preset.config, seed=0)
    model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=0, device=args.device, **preset.algo_kwargs)
    per_update = preset.algo_kwargs["n_steps"] * preset.n_envs * preset.config.n_agents
    parameters = sum(p.numel() for p in model.policy.parameters())
    start = time.perf_counter()
    model.learn(args.updates * per_update)
    seconds = (time.perf_counter() - start) / args.updates

    print(f"Python {platform.python_version()}, torch {th.__version__}, {th.get_num_threads()} thread(s), {args.device}")
    print(f"preset {preset.name}: {parameters:,} parameters, {per_update:,} agent-steps per update")
    print(f"one update: {seconds:.0f} s ({per_update / seconds:,.0f} agent-steps/s)")
    print(f"{preset.updates} updates (the preset's budget): {preset.updates * seconds / 3600:.1f} h")


if __name__ == "__main__":
    main()
