"""Environment throughput: raw ``SwarmReconEnv`` swarm steps/s and ``make_vec_env(40)`` agent steps/s (one core).

Paper configuration (N = 3, 50 x 50 grid, channel links); random actions sampled before the clock starts; the raw env
is reset when an episode ends (the vec env resets itself). The target for the raw env is >= 10,000 swarm steps/s.

    python benchmarks/env_throughput.py --steps 20000 --vec-steps 500
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env


def raw_env_steps_per_second(config: SwarmConfig, steps: int, seed: int) -> tuple[float, int]:
    """Swarm steps per second of one env, and the number of episodes finished."""
    env = SwarmReconEnv(config)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    commands = rng.uniform(-1.0, 1.0, (steps, env.n_agents, 4)).astype(np.float32)
    actions = [dict(zip(env.possible_agents, command)) for command in commands]
    episodes = 0
    start = time.perf_counter()
    for action in actions:
        env.step(action)
        if not env.agents:
            env.reset()
            episodes += 1
    return steps / (time.perf_counter() - start), episodes


def vec_env_agent_steps_per_second(config: SwarmConfig, n_envs: int, steps: int, seed: int) -> float:
    """Agent steps (SB3 timesteps) per second of ``make_vec_env(n_envs)`` in this process."""
    vec_env = make_vec_env(n_envs, config=config, seed=seed)
    vec_env.reset()
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, (steps, vec_env.num_envs, 4)).astype(np.float32)
    start = time.perf_counter()
    for action in actions:
        vec_env.step(action)
    elapsed = time.perf_counter() - start
    vec_env.close()
    return steps * vec_env.num_envs / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000, help="swarm steps of the raw env (default: 20000)")
    parser.add_argument("--vec-steps", type=int, default=500, help="steps of the vec env (default: 500)")
    parser.add_argument("--n-envs", type=int, default=40, help="swarm copies in the vec env (paper: 40)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.steps < 1 or args.vec_steps < 1 or args.n_envs < 1:
        parser.error(f"--steps, --vec-steps and --n-envs must be >= 1, got {args.steps}, {args.vec_steps}, {args.n_envs}")

    config = SwarmConfig()
    raw, episodes = raw_env_steps_per_second(config, args.steps, args.seed)
    vec = vec_env_agent_steps_per_second(config, args.n_envs, args.vec_steps, args.seed)
    n = config.n_agents
    print(f"Paper config: N={n}, {config.grid_width}x{config.grid_height} grid, link_mode={config.link_mode!r}")
    print(f"Python {platform.python_version()}, numpy {np.__version__}, {platform.processor() or platform.machine()}")
    print()
    print("| environment | steps | swarm steps/s | agent steps/s |")
    print("|---|---:|---:|---:|")
    print(f"| SwarmReconEnv (raw, {episodes} resets) | {args.steps} | {raw:,.0f} | {raw * n:,.0f} |")
    print(f"| make_vec_env({args.n_envs}), serial | {args.vec_steps} | {vec / n:,.0f} | {vec:,.0f} |")
    print()
    print(f"raw env target >= 10,000 swarm steps/s: {'met' if raw >= 10_000 else 'NOT met'}")


if __name__ == "__main__":
    main()
