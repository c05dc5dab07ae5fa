"""Training throughput: LatentSwarmPPO against sb3-contrib RecurrentPPO("MultiInputLstmPolicy") on the same VecEnv,
or (``--backends``) one whole update of a preset with each ``make_vec_env`` backend.

Default mode: ``LatentSwarmPPO`` and ``RecurrentPPO`` train on ``make_vec_env`` with the paper's observation sizes
(50x50 map, N = 3) at each ``--hidden`` size (default 64 and 512: ours with d_mu = d_tau = d_rho = hidden and the
default 256-wide predictor, decoder and critic; theirs with an LSTM of that size and one layer of that width), with
the same rollout length, minibatch size (in agent-steps) and number of epochs. After one warm-up update each, all
models train in alternating blocks of whole updates (so that a change in the machine's load hits every model alike),
on one torch thread, timed by this thread's CPU time (``time.thread_time``). Prints agent-steps per CPU second (and
per wall second) of each, and the ratio ours / theirs per hidden size. ``--autocast bf16`` adds a third model per
hidden size, ``LatentSwarmPPO(autocast="bf16")`` (the ``paper`` preset's setting; ``RecurrentPPO`` has no such
option), and its ratio to ``RecurrentPPO``.

``--backends``: ``LatentSwarmPPO`` with the preset's settings (default ``fast``) on the ``"supersuit"`` and the
``"batched"`` backend (same seed, hence the same episodes), updates timed in alternation after one warm-up update
each; reports the rollout (env + policy), the training and the whole update in per-thread CPU seconds (torch runs on
this one thread) and wall seconds, and the ratio of the whole update (target >= 1.25x on ``fast``).

    python benchmarks/train_throughput.py --hidden 64 512 --blocks 2
    python benchmarks/train_throughput.py --hidden 64 512 --blocks 2 --autocast bf16
    python benchmarks/train_throughput.py --backends --preset fast --iterations 2 --threads 1
"""

from __future__ import annotations

import argparse
import os
import time

from sb3_latentswarm.presets import PRESETS, get_preset


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--hidden", type=int, nargs="+", default=[64, 512], help="latent size d (ours) and LSTM hidden size (theirs)"
    )
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--n-steps", type=int, default=128)
    parser.add_argument("--chunk-length", type=int, default=32)
    parser.add_argument("--n-epochs", type=int, default=4)
    parser.add_argument("--blocks", type=int, default=2, help="alternating timing blocks per model")
    parser.add_argument("--autocast", choices=["bf16"], default=None,
                        help="also time LatentSwarmPPO(autocast=...) at each hidden size (default: float32 only)")
    parser.add_argument("--updates-per-block", type=int, default=1, help="updates per model per block")
    parser.add_argument("--iterations", type=int, default=3, help="updates timed per backend (--backends)")
    parser.add_argument("--threads", type=int, default=0,
                        help="torch threads of --backends (0: the package default of one; the "
                             "RecurrentPPO comparison always runs on one)")
    parser.add_argument("--backends", action="store_true", help="compare the vec env backends on a preset's update")
    parser.add_argument("--preset", default="fast", choices=sorted(PRESETS), help="preset of --backends")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import torch as th  # noqa: E402
from sb3_contrib import RecurrentPPO  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig  # noqa: E402
from sb3_latentswarm.envs import make_vec_env  # noqa: E402
from sb3_latentswarm.envs.vec_env import BACKENDS  # noqa: E402
from sb3_latentswarm.utils.threads import set_torch_threads  # noqa: E402


class LearnTimer:
    """One model trained in blocks of whole updates; accumulates this thread's CPU seconds and wall seconds."""

    def __init__(self, model) -> None:
        self.model = model
        self.per_update = model.n_steps * model.n_envs
        self.parameters = sum(p.numel() for p in model.policy.parameters())
        model.learn(self.per_update)  # warm-up rollout + update, not counted
        self.cpu = self.wall = 0.0
        self.agent_steps = 0

    def block(self, updates: int) -> None:
        cpu, wall = time.thread_time(), time.perf_counter()
        self.model.learn(updates * self.per_update, reset_num_timesteps=False)
        self.cpu += time.thread_time() - cpu
        self.wall += time.perf_counter() - wall
        self.agent_steps += updates * self.per_update


def make_pair(
    hidden: int, n_envs: int, n_steps: int, chunk_length: int, n_epochs: int, autocast: str | None = None
) -> dict[str, LearnTimer]:
    """LatentSwarmPPO and RecurrentPPO at latent / LSTM size ``hidden``, same env, rollout, minibatch and epochs; with
    ``autocast``, also ``LatentSwarmPPO(autocast=autocast)`` (keyed ``"LatentSwarmPPO (bf16)"``)."""
    config = SwarmConfig()  # the paper's observations: 50 x 50 map, N = 3
    batch_size = config.n_agents * chunk_length * 4  # agent-steps; 4 swarm sequences of chunk_length steps
    common = dict(n_steps=n_steps, batch_size=batch_size, n_epochs=n_epochs, seed=0, device="cpu")

    def ours(precision: str | None) -> LearnTimer:
        return LearnTimer(LatentSwarmPPO(
            "LatentSwarmPolicy",
            make_vec_env(n_envs, config=config, seed=0),
            chunk_length=chunk_length,
            policy_kwargs=dict(latent_dim=hidden),
            autocast=precision,
            **common,
        ))

    theirs = RecurrentPPO(
        "MultiInputLstmPolicy",
        make_vec_env(n_envs, config=config, seed=0),
        policy_kwargs=dict(lstm_hidden_size=hidden, net_arch=[hidden]),
        **common,
    )
    timers = {"LatentSwarmPPO": ours(None), "RecurrentPPO": LearnTimer(theirs)}
    if autocast is not None:
        timers[f"LatentSwarmPPO ({autocast})"] = ours(autocast)
    return timers


def compare_recurrent_ppo(args: argparse.Namespace) -> None:
    """Agent-steps per CPU second of both algorithms at every ``--hidden`` size, in alternating blocks, one run."""
    th.set_num_threads(1)  # per-thread CPU time would miss the work of other threads
    load_before = os.getloadavg()
    pairs = {
        hidden: make_pair(hidden, args.n_envs, args.n_steps, args.chunk_length, args.n_epochs, args.autocast)
        for hidden in args.hidden
    }
    for _ in range(args.blocks):  # alternate, so that a change of the machine's load hits every model alike
        for pair in pairs.values():
            for timer in pair.values():
                timer.block(args.updates_per_block)
    load_after = os.getloadavg()
    config = SwarmConfig()
    print(f"paper observations (50x50 map, N={config.n_agents}), n_envs={args.n_envs}, n_steps={args.n_steps}, "
          f"minibatch={config.n_agents * args.chunk_length * 4} agent-steps, epochs={args.n_epochs}, 1 torch thread; "
          f"{args.blocks} block(s) of {args.updates_per_block} update(s) per model after one warm-up update")
    print(f"{os.cpu_count()} cores ({th.backends.cpu.get_cpu_capability()} kernels), load average {load_before[0]:.2f} "
          f"before, {load_after[0]:.2f} after")
    print("| hidden | model | parameters | agent-steps per CPU s | agent-steps per wall s | CPU s per update |")
    print("|---:|---|---:|---:|---:|---:|")
    for hidden, pair in pairs.items():
        for name, timer in pair.items():
            print(
                f"| {hidden} | {name} | {timer.parameters:,} | {timer.agent_steps / timer.cpu:,.0f} | "
                f"{timer.agent_steps / timer.wall:,.0f} | {timer.cpu * timer.per_update / timer.agent_steps:.2f} |"
            )
    for hidden, pair in pairs.items():
        theirs = pair["RecurrentPPO"]
        for name, ours in pair.items():
            if name != "RecurrentPPO":
                ratio = (ours.agent_steps / ours.cpu) / (theirs.agent_steps / theirs.cpu)
                print(f"hidden {hidden}: {name} / RecurrentPPO = {ratio:.2f}x (agent-steps per CPU second)")


class UpdateTimer:
    """A ``LatentSwarmPPO`` of a preset on one backend, with the CPU and wall time of its rollouts and trainings."""

    def __init__(self, preset_name: str, backend: str) -> None:
        preset = get_preset(preset_name)
        env = make_vec_env(preset.n_envs, config=preset.config, seed=0, backend=backend)
        self.model = LatentSwarmPPO(
            "LatentSwarmPolicy", env, seed=0, device="cpu", **preset.algo_kwargs
        )
        self.per_update = preset.algo_kwargs["n_steps"] * preset.n_envs * preset.config.n_agents
        self.times = {"rollout": [0.0, 0.0], "train": [0.0, 0.0]}  # [CPU, wall] seconds
        self.updates = 0
        self._timed("collect_rollouts", "rollout")
        self._timed("train", "train")
        self.model.learn(self.per_update)  # warm-up update, not counted
        self.times = {"rollout": [0.0, 0.0], "train": [0.0, 0.0]}

    def _timed(self, method: str, key: str) -> None:
        original = getattr(self.model, method)

        def wrapper(*args, **kwargs):
            cpu, wall = time.thread_time(), time.perf_counter()
            result = original(*args, **kwargs)
            self.times[key][0] += time.thread_time() - cpu
            self.times[key][1] += time.perf_counter() - wall
            return result

        setattr(self.model, method, wrapper)

    def update(self) -> None:
        self.model.learn(self.per_update, reset_num_timesteps=False)
        self.updates += 1

    def seconds(self, key: str, clock: int) -> float:
        """Seconds per update of ``key`` ("rollout", "train" or "update") on clock 0 (CPU) or 1 (wall)."""
        if key == "update":
            return (self.times["rollout"][clock] + self.times["train"][clock]) / self.updates
        return self.times[key][clock] / self.updates


def compare_backends(preset_name: str, iterations: int) -> None:
    timers = {backend: UpdateTimer(preset_name, backend) for backend in BACKENDS}
    for _ in range(iterations):  # alternate, so a change of machine load hits both
        for timer in timers.values():
            timer.update()
    per_update = timers["batched"].per_update
    print(f"preset {preset_name}: {per_update:,} agent-steps per update, {iterations} update(s) per backend, "
          f"torch {th.get_num_threads()} thread(s)")
    print("| backend | rollout s (CPU) | train s (CPU) | update s (CPU) | update s (wall) | agent-steps/s (CPU) |")
    print("|---|---:|---:|---:|---:|---:|")
    for backend, timer in timers.items():
        update = timer.seconds("update", 0)
        print(
            f"| {backend} | {timer.seconds('rollout', 0):.2f} | {timer.seconds('train', 0):.2f} | {update:.2f} | "
            f"{timer.seconds('update', 1):.2f} | {per_update / update:,.0f} |"
        )
    batched, supersuit = timers["batched"], timers["supersuit"]
    ratio_cpu = supersuit.seconds("update", 0) / batched.seconds("update", 0)
    ratio_wall = supersuit.seconds("update", 1) / batched.seconds("update", 1)
    rollout = supersuit.seconds("rollout", 0) / batched.seconds("rollout", 0)
    print(f"whole update, batched vs supersuit: {ratio_cpu:.2f}x (CPU), {ratio_wall:.2f}x (wall)")
    print(f"rollout alone: {rollout:.2f}x (CPU)")


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    counts = [*args.hidden, args.n_envs, args.n_steps, args.chunk_length, args.n_epochs, args.blocks, args.updates_per_block]
    if min(counts) < 1 or args.iterations < 1:
        parser.error("--hidden, --n-envs, --n-steps, --chunk-length, --n-epochs, --blocks, --updates-per-block and "
                     "--iterations must be >= 1")
    if args.n_steps % args.chunk_length:
        parser.error(f"--chunk-length {args.chunk_length} must divide --n-steps {args.n_steps}")
    if args.threads < 0:
        parser.error(f"--threads must be >= 0 (0: the package default of one), got {args.threads}")
    if args.autocast and args.backends:
        parser.error("--autocast applies to the RecurrentPPO comparison only, not to --backends")
    if args.threads > 1 and not args.backends:
        parser.error("the RecurrentPPO comparison runs on one torch thread (it times this thread's CPU seconds); "
                     "--threads applies to --backends")
    if args.threads:
        set_torch_threads(args.threads)
    if args.backends:
        compare_backends(args.preset, args.iterations)
        return

    compare_recurrent_ppo(args)


if __name__ == "__main__":
    main()
