"""Torch threads for the README's training snippet: agent-steps per second with 1, 2, ... intra-op threads.

Trains the README's model (N = 2 on a 12 x 12 grid, 8 swarms, d = 32, n_steps 40) for a few updates with each thread
count, in one process and in alternation (so that a change in the machine's load hits every count alike), and prints
the speed of each count relative to one thread, next to the 1-minute load average and the number of cores.

    python benchmarks/threads.py --threads 1 2 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import time


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--updates", type=int, default=5, help="rollout/update iterations timed per measurement")
    parser.add_argument("--repeats", type=int, default=3)
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import torch as th  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env  # noqa: E402


def make_model() -> LatentSwarmPPO:
    config = SwarmConfig(n_agents=2, grid_width=12, grid_height=12, max_steps=40, v_max=1.0)
    env = make_vec_env(8, config=config, seed=0)
    return LatentSwarmPPO(
        "LatentSwarmPolicy", env, n_steps=40, chunk_length=10, batch_size=160, policy_kwargs=dict(latent_dim=32), seed=0
    )


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    model = make_model()
    per_update = model.n_steps * model.n_envs
    model.learn(per_update)  # warm-up
    speeds: dict[int, list[float]] = {n: [] for n in args.threads}
    for _ in range(args.repeats):
        for n in args.threads:
            th.set_num_threads(n)
            start = time.perf_counter()
            model.learn(args.updates * per_update)
            speeds[n].append(args.updates * per_update / (time.perf_counter() - start))
    load = os.getloadavg()[0]
    print(f"{os.cpu_count()} cores, 1-min load average {load:.1f}")
    base = sorted(speeds[args.threads[0]])[len(speeds[args.threads[0]]) // 2]
    for n, values in speeds.items():
        median = sorted(values)[len(values) // 2]
        relative = median / base
        print(f"{n} thread(s): {median:,.0f} agent-steps/s (median of {len(values)}), {relative:.2f}x of {args.threads[0]}")


if __name__ == "__main__":
    main()
