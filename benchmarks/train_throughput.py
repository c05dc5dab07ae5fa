"""Training throughput: LatentSwarmPPO against sb3-contrib RecurrentPPO("MultiInputLstmPolicy") on the same VecEnv,
or (``--backends``) one whole update of a preset with each ``make_vec_env`` backend.

Default mode: both algorithms train on ``make_vec_env`` with the paper's observation sizes (50x50 map, N = 3) and the
same hidden size, rollout length, minibatch size (in agent-steps) and number of epochs. Prints agent-steps per second
and their ratio.

``--backends``: ``LatentSwarmPPO`` with the preset's settings (default ``fast``) on the ``"supersuit"`` and the
``"batched"`` backend (same seed, hence the same episodes), updates timed in alternation after one warm-up update
each; reports the rollout (env + policy), the training and the whole update in per-thread CPU seconds (torch runs on
this one thread) and wall seconds, and the ratio of the whole update (target >= 1.25x on ``fast``).

``--compile``: the same measurement on the batched backend, with the eager and the ``torch.compile``-d latent step
(``compile_latent_step=True``); the first (warm-up) update carries the compilation, whose cost is reported.

    python benchmarks/train_throughput.py --hidden 64 --n-envs 8 --n-steps 128 --iterations 3
    python benchmarks/train_throughput.py --backends --preset fast --iterations 2 --threads 1
    python benchmarks/train_throughput.py --compile --preset fast --iterations 2 --threads 1
"""

from __future__ import annotations

import argparse
import time

import torch as th
from sb3_contrib import RecurrentPPO

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.envs.vec_env import BACKENDS
from sb3_latentswarm.presets import PRESETS, get_preset


def measure(model, total_timesteps: int) -> float:
    model.learn(total_timesteps=model.n_steps * model.n_envs)  # warm-up rollout + update
    start = time.perf_counter()
    model.learn(total_timesteps=total_timesteps, reset_num_timesteps=True)
    return model.num_timesteps / (time.perf_counter() - start)


class UpdateTimer:
    """A ``LatentSwarmPPO`` of a preset on one backend, with the CPU and wall time of its rollouts and trainings."""

    def __init__(self, preset_name: str, backend: str, compile_latent_step: bool = False) -> None:
        preset = get_preset(preset_name)
        env = make_vec_env(preset.n_envs, config=preset.config, seed=0, backend=backend)
        self.model = LatentSwarmPPO(
            "LatentSwarmPolicy", env, seed=0, device="cpu", compile_latent_step=compile_latent_step, **preset.algo_kwargs
        )
        self.per_update = preset.algo_kwargs["n_steps"] * preset.n_envs * preset.config.n_agents
        self.times = {"rollout": [0.0, 0.0], "train": [0.0, 0.0]}  # [CPU, wall] seconds
        self.updates = 0
        self._timed("collect_rollouts", "rollout")
        self._timed("train", "train")
        self.model.learn(self.per_update)  # warm-up update (compiles the latent step if asked), not counted
        self.warm_up = (self.times["rollout"][0] + self.times["train"][0], self.times["rollout"][1] + self.times["train"][1])
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


def compare_compiled(preset_name: str, iterations: int) -> None:
    timers = {"eager": UpdateTimer(preset_name, "batched"), "compiled": UpdateTimer(preset_name, "batched", True)}
    for _ in range(iterations):
        for timer in timers.values():
            timer.update()
    print(f"preset {preset_name}, batched backend: {iterations} update(s) after one warm-up update each, "
          f"torch {th.get_num_threads()} thread(s)")
    print("| latent step | first update s (CPU / wall) | rollout s (CPU) | train s (CPU) | update s (CPU) | update s (wall) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, timer in timers.items():
        print(
            f"| {name} | {timer.warm_up[0]:.1f} / {timer.warm_up[1]:.1f} | {timer.seconds('rollout', 0):.2f} | "
            f"{timer.seconds('train', 0):.2f} | {timer.seconds('update', 0):.2f} | {timer.seconds('update', 1):.2f} |"
        )
    eager, compiled = timers["eager"], timers["compiled"]
    compile_cpu, compile_wall = (
        (compiled.warm_up[clock] - compiled.seconds("update", clock)) - (eager.warm_up[clock] - eager.seconds("update", clock))
        for clock in (0, 1)
    )
    print(f"update, compiled vs eager: {eager.seconds('update', 0) / compiled.seconds('update', 0):.2f}x (CPU); "
          f"train alone {eager.seconds('train', 0) / compiled.seconds('train', 0):.2f}x")
    # inductor compiles in worker processes: this thread's CPU time misses their work, the wall time includes it
    print(f"compile cost (extra seconds of the first update): {compile_wall:.0f} s wall, {compile_cpu:.0f} s CPU here")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hidden", type=int, default=64, help="latent size d (ours) and LSTM hidden size (theirs)")
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--n-steps", type=int, default=128)
    parser.add_argument("--chunk-length", type=int, default=32)
    parser.add_argument("--n-epochs", type=int, default=4)
    parser.add_argument("--iterations", type=int, default=3, help="rollout/update iterations timed")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: the package default)")
    parser.add_argument("--backends", action="store_true", help="compare the vec env backends on a preset's update")
    parser.add_argument("--compile", action="store_true", help="compare the eager and the compiled latent step")
    parser.add_argument("--preset", default="fast", choices=sorted(PRESETS), help="preset of --backends and --compile")
    args = parser.parse_args()
    if args.threads:
        th.set_num_threads(args.threads)
    if args.backends:
        compare_backends(args.preset, args.iterations)
        return
    if args.compile:
        compare_compiled(args.preset, args.iterations)
        return

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
