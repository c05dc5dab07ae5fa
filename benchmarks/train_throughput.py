"""Training throughput: LatentSwarmPPO against sb3-contrib RecurrentPPO("MultiInputLstmPolicy") on the same VecEnv.

Both train on ``make_vec_env`` with the paper's observation sizes (50x50 map, N = 3) and the same hidden size, rollout
length, minibatch size (in agent-steps) and number of epochs. Prints agent-steps per second and their ratio.

    python benchmarks/train_throughput.py --hidden 64 --n-envs 8 --n-steps 128 --iterations 3
"""

from __future__ import annotations

import argparse
import time

import torch as th
from sb3_contrib import RecurrentPPO

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import make_vec_env


def measure(model, total_timesteps: int) -> float:
    model.learn(total_timesteps=model.n_steps * model.n_envs)  # warm-up rollout + update
    start = time.perf_counter()
    model.learn(total_timesteps=total_timesteps, reset_num_timesteps=True)
    return model.num_timesteps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hidden", type=int, default=64, help="latent size d (ours) and LSTM hidden size (theirs)")
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--n-steps", type=int, default=128)
    parser.add_argument("--chunk-length", type=int, default=32)
    parser.add_argument("--n-epochs", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=3, help="rollout/update iterations timed")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: the package default)")
    args = parser.parse_args()
    if args.threads:
        th.set_num_threads(args.threads)

    config = SwarmConfig()
    batch_size = config.n_agents * args.chunk_length * 4
    total = args.iterations * args.n_steps * args.n_envs * config.n_agents
    common = dict(n_steps=args.n_steps, batch_size=batch_size, n_epochs=args.n_epochs, seed=0, device="cpu")

    ours = LatentSwarmPPO(
        "LatentSwarmPolicy",
        make_vec_env(args.n_envs, config=config, seed=0),
        chunk_length=args.chunk_length,
        policy_kwargs=dict(latent_dim=args.hidden),
        **common,
    )
    theirs = RecurrentPPO(
        "MultiInputLstmPolicy",
        make_vec_env(args.n_envs, config=config, seed=0),
        policy_kwargs=dict(lstm_hidden_size=args.hidden, net_arch=[args.hidden]),
        **common,
    )
    ours_params = sum(p.numel() for p in ours.policy.parameters())
    theirs_params = sum(p.numel() for p in theirs.policy.parameters())
    ours_fps = measure(ours, total)
    theirs_fps = measure(theirs, total)
    print(f"hidden={args.hidden} n_envs={args.n_envs} n_steps={args.n_steps} batch={batch_size} epochs={args.n_epochs}")
    print("| model | parameters | agent-steps/s |\n|---|---|---|")
    print(f"| LatentSwarmPPO (LatentSwarmPolicy) | {ours_params:,} | {ours_fps:,.0f} |")
    print(f"| RecurrentPPO (MultiInputLstmPolicy) | {theirs_params:,} | {theirs_fps:,.0f} |")
    print(f"ratio ours/theirs: {ours_fps / theirs_fps:.2f}")


if __name__ == "__main__":
    main()
