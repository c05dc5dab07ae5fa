"""Environment throughput: the two ``make_vec_env`` backends side by side, and the raw ``SwarmReconEnv`` (one core).

For the ``fast`` and ``paper`` configs and 16 and 40 swarms, one whole SB3 vec step (``vec_env.step(actions)``, auto-reset
included, under ``VecMonitor``) of the ``"supersuit"`` backend (PettingZoo env -> SuperSuit) and of the ``"batched"``
backend (one ``SwarmBatch`` for all swarms), in agent-steps per second, and their ratio. Both are timed in this one run,
block by block in alternation, by per-thread CPU time (``time.thread_time``: what this process got of a loaded machine)
and by wall time. Random actions are drawn before the clock starts. Target: batched / SuperSuit >= 15x at 16 swarms on
``fast``. The raw env (the B = 1 view of the same core) is reported in swarm steps per second (target >= 10,000 on
the paper config).

    python benchmarks/env_throughput.py --supersuit-steps 200 --batched-steps 2000
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.presets import get_preset


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--supersuit-steps", type=int, default=200, help="vec steps of the SuperSuit backend per cell")
    parser.add_argument("--batched-steps", type=int, default=2000, help="vec steps of the batched backend per cell")
    parser.add_argument("--blocks", type=int, default=4, help="alternating timing blocks per cell")
    parser.add_argument("--raw-steps", type=int, default=5000, help="swarm steps of the raw env (0 skips it)")
    parser.add_argument("--swarms", type=int, nargs="+", default=[16, 40])
    parser.add_argument("--seed", type=int, default=0)
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env  # noqa: E402


def raw_env_steps_per_second(config: SwarmConfig, steps: int, seed: int) -> tuple[float, int]:
    """Swarm steps per second (per-thread CPU time) of one env, and the number of episodes finished."""
    env = SwarmReconEnv(config)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    commands = rng.uniform(-1.0, 1.0, (steps, env.n_agents, 4)).astype(np.float32)
    actions = [dict(zip(env.possible_agents, command)) for command in commands]
    episodes = 0
    start = time.thread_time()
    for action in actions:
        env.step(action)
        if not env.agents:
            env.reset()
            episodes += 1
    return steps / (time.thread_time() - start), episodes


class VecTimer:
    """Times blocks of vec steps of one backend, accumulating per-thread CPU time and wall time."""

    def __init__(self, config: SwarmConfig, n_envs: int, backend: str, seed: int) -> None:
        self.vec_env = make_vec_env(n_envs, config=config, seed=seed, backend=backend)
        self.vec_env.reset()
        self.rng = np.random.default_rng(seed)
        self.steps = 0
        self.cpu = 0.0
        self.wall = 0.0

    def run(self, steps: int) -> None:
        actions = self.rng.uniform(-1.0, 1.0, (steps, self.vec_env.num_envs, 4)).astype(np.float32)
        cpu, wall = time.thread_time(), time.perf_counter()
        for action in actions:
            self.vec_env.step(action)
        self.cpu += time.thread_time() - cpu
        self.wall += time.perf_counter() - wall
        self.steps += steps

    def agent_steps_per_second(self) -> tuple[float, float]:
        """(per CPU second, per wall second)."""
        agent_steps = self.steps * self.vec_env.num_envs
        return agent_steps / self.cpu, agent_steps / self.wall


def compare(config: SwarmConfig, n_envs: int, supersuit_steps: int, batched_steps: int, blocks: int, seed: int) -> dict:
    supersuit = VecTimer(config, n_envs, "supersuit", seed)
    batched = VecTimer(config, n_envs, "batched", seed)
    for _ in range(blocks):  # alternate, so a change of machine load hits both
        supersuit.run(max(1, supersuit_steps // blocks))
        batched.run(max(1, batched_steps // blocks))
    (s_cpu, s_wall), (b_cpu, b_wall) = supersuit.agent_steps_per_second(), batched.agent_steps_per_second()
    return {
        "supersuit_cpu": s_cpu,
        "batched_cpu": b_cpu,
        "ratio_cpu": b_cpu / s_cpu,
        "ratio_wall": b_wall / s_wall,
        "batched_ms": 1e3 * batched.cpu / batched.steps,
        "supersuit_ms": 1e3 * supersuit.cpu / supersuit.steps,
    }


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if min(args.supersuit_steps, args.batched_steps, args.blocks, *args.swarms) < 1 or args.raw_steps < 0:
        parser.error("step counts, --blocks and --swarms must be >= 1 (--raw-steps >= 0)")

    print(f"Python {platform.python_version()}, numpy {np.__version__}, {platform.processor() or platform.machine()}")
    print("agent-steps/s of a whole vec step (per-thread CPU time); ratio = batched / SuperSuit (CPU time, wall time)")
    print()
    print("| config | swarms | SuperSuit agent-steps/s | batched agent-steps/s | SuperSuit ms/step | batched ms/step "
          "| ratio (CPU) | ratio (wall) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    target = None
    for name in ("fast", "paper"):
        config = get_preset(name).config
        for n_envs in args.swarms:
            row = compare(config, n_envs, args.supersuit_steps, args.batched_steps, args.blocks, args.seed)
            if name == "fast" and n_envs == 16:
                target = row["ratio_cpu"]
            print(
                f"| {name} | {n_envs} | {row['supersuit_cpu']:,.0f} | {row['batched_cpu']:,.0f} | "
                f"{row['supersuit_ms']:.2f} | {row['batched_ms']:.3f} | {row['ratio_cpu']:.1f}x | {row['ratio_wall']:.1f}x |"
            )
    if args.raw_steps:
        for name in ("fast", "paper"):
            raw, episodes = raw_env_steps_per_second(get_preset(name).config, args.raw_steps, args.seed)
            print(f"\nraw SwarmReconEnv ({name}, B = 1 view, {episodes} resets): {raw:,.0f} swarm steps/s (CPU time)")
        print(f"raw env target >= 10,000 swarm steps/s (paper config): {'met' if raw >= 10_000 else 'NOT met'}")
    if target is not None:
        verdict = "met" if target >= 15 else "NOT met"
        print(f"\nbatched vs SuperSuit at 16 swarms on fast: {target:.1f}x (target >= 15x: {verdict})")


if __name__ == "__main__":
    main()
