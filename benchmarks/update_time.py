"""Where the time of a ``LatentSwarmPPO`` update goes, on CPU or GPU: env, policy, train forward/backward/optimizer,
host syncs and peak memory, for any preset, and what the preset's budget costs at that speed.

One update is ``n_steps * n_envs * n_agents`` agent-steps (the ``paper`` preset: 600 * 40 * 3 = 72,000, with d = 512).
The model is timed from outside (the algorithm's code is unchanged): the benchmark wraps ``VecEnv.step``, the
policy's ``forward`` and ``predict_values`` during the rollout, ``Tensor.backward``, ``clip_grad_norm_`` and the
optimizer's ``step``/``zero_grad`` during the training, and the model's ``collect_rollouts`` and ``train``. On CUDA
each wrapper synchronizes the device before and after its range, so that asynchronous kernels count where they were
launched. The first ``--warmup`` update is not timed; the first warm-up update counts the host syncs with the GPU's
semantics on any device (``benchmarks/_syncs.py``: reads of device values by the host and data-dependent shapes, not
the optimizer's host-side step counters; by call site) and, under ``torch.profiler``, the aten ops per minibatch.
The output format is documented in ``docs/benchmarks.md``.

``--compare REV --rounds R`` measures the package of git revision ``REV`` against the working tree's: each round runs
this script once on each (old first) in a fresh one-thread subprocess (``benchmarks/_compare.py``), then prints per
update the process CPU seconds (user + sys of the timed updates), wall seconds and the rollout/train split, medians
over the rounds, and the old/new ratio. The warm-up updates run as asked but are not profiled (``--no-profile``).

    python benchmarks/update_time.py --device cuda --preset paper --updates 3 --json update_time_cuda.json
    python benchmarks/update_time.py --device cpu --preset paper --updates 1 --warmup 0 --threads 1
    python benchmarks/update_time.py --device cpu --preset smoke --updates 2 --json /tmp/smoke.json
    python benchmarks/update_time.py --preset paper --compare d4e6afc --rounds 2 --updates 1 --threads 1
"""

from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import platform
import resource
import statistics
import sys
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sb3_latentswarm.presets import PRESETS, get_preset
from sb3_latentswarm.utils.atomic import write_text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="paper", choices=sorted(PRESETS))
    parser.add_argument("--device", default="cpu", help="torch device: cpu, cuda, cuda:1")
    parser.add_argument("--updates", type=int, default=1, help="updates timed (default 1)")
    parser.add_argument("--warmup", type=int, default=1, help="updates run first, not timed (default 1; 0: no sync count)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: the package default of one)")
    parser.add_argument("--backend", default="batched", help="make_vec_env backend: batched or supersuit")
    parser.add_argument("--no-profile", action="store_true", help="do not count host syncs in the warm-up update")
    parser.add_argument("--autocast", default=None, help="passed as LatentSwarmPPO(autocast=...), where supported")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", default=None, metavar="PATH",
                        help="also write the results as JSON to PATH ('-': print them as one JSON line last)")
    parser.add_argument("--compare", metavar="REV", help="git revision whose package is measured against the work tree")
    parser.add_argument("--rounds", type=int, default=2, help="with --compare: alternating old/new subprocess rounds")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import torch as th  # noqa: E402

import sb3_latentswarm  # noqa: E402
from sb3_latentswarm import LatentSwarmPPO, make_vec_env  # noqa: E402
from sb3_latentswarm.envs.vec_env import BACKENDS  # noqa: E402

try:
    from sb3_latentswarm.utils.threads import set_torch_threads
except ImportError:  # a package before the thread guard (measured by --compare)
    def set_torch_threads(threads: int) -> int:
        th.set_num_threads(threads)
        return th.get_num_threads()

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared helper, also when loaded by path (tests)
from _compare import Run, alternate, check_revision  # noqa: E402
from _syncs import SyncCounter  # noqa: E402

RANGES = ("update", "rollout", "env", "policy", "rollout_other", "train", "train_forward", "backward", "optimizer")
"""Keys of ``seconds`` and ``cpu_seconds`` in the output (per update; see ``docs/benchmarks.md``)."""

SYNC_OPS = ("aten::_local_scalar_dense", "aten::nonzero", "cudaStreamSynchronize", "cudaDeviceSynchronize")
"""Profiler events that may block the host (reported as ``profiler_events`` for reference only: on CPU they include
reads of host-side values, e.g. Adam's step counters, that never wait on a device; the counts are :class:`SyncCounter`'s)."""


class UpdateProfiler:
    """Wraps a model's hot methods from outside and accumulates wall and per-thread CPU seconds per range.

    Ranges nest: ``env`` and ``policy`` lie inside ``rollout``; ``backward`` and ``optimizer`` inside ``train``. The
    remainders (``rollout_other``, ``train_forward``) are computed by :meth:`per_update`.
    """

    def __init__(self, model: LatentSwarmPPO) -> None:
        self.model = model
        self.cuda = model.device.type == "cuda"
        self.device_sync = self.cuda  # synchronize around each range (off while counting syncs: they would count)
        self.wall: Counter[str] = Counter()
        self.cpu: Counter[str] = Counter()
        self.minibatches = 0
        self.train_logs: dict[str, float] = {}
        self._phase = ""  # "rollout" or "train" while inside one
        self._active: set[str] = set()  # ranges being timed now (a range called inside itself is timed once)
        self.profiled: set[str] = set()  # ranges run under torch.profiler (count_syncs)
        self.profiles: dict[str, Any] = {}  # range -> the profiler's key_averages of its last run
        self.syncs: dict[str, SyncCounter] = {}  # range -> the host syncs of its last profiled run

    # ------------------------------------------------------------------ wrapping
    def _sync(self) -> None:
        if self.device_sync:
            th.cuda.synchronize(self.model.device)

    @contextlib.contextmanager
    def timed(self, key: str) -> Iterator[None]:
        self._sync()
        wall, cpu = time.perf_counter(), time.thread_time()
        try:
            if key in self.profiled:
                activities = [th.profiler.ProfilerActivity.CPU]
                if self.cuda:
                    activities.append(th.profiler.ProfilerActivity.CUDA)
                with th.profiler.profile(activities=activities) as prof, SyncCounter(self.model.device) as syncs:
                    yield
                self.profiles[key] = prof.key_averages()
                self.syncs[key] = syncs
            else:
                yield
        finally:
            self._sync()
            self.wall[key] += time.perf_counter() - wall
            self.cpu[key] += time.thread_time() - cpu

    def _wrap(self, owner: Any, name: str, key: str, phase: str | None, enter: str | None = None) -> None:
        """Replace ``owner.name`` by a timed version, counted only inside ``phase`` (if given) and not re-entrantly."""
        original = getattr(owner, name)

        def wrapper(*args, **kwargs):
            if (phase is not None and self._phase != phase) or key in self._active:
                return original(*args, **kwargs)
            previous = self._phase
            self._phase = enter or previous
            self._active.add(key)
            try:
                with self.timed(key):
                    return original(*args, **kwargs)
            finally:
                self._active.discard(key)
                self._phase = previous

        setattr(owner, name, wrapper)

    def install(self) -> None:
        model, policy = self.model, self.model.policy
        self._wrap(model, "collect_rollouts", "rollout", None, enter="rollout")
        self._wrap(model.env, "step", "env", "rollout")
        self._wrap(policy, "forward", "policy", "rollout")
        self._wrap(policy, "predict_values", "policy", "rollout")
        original_train = model.train

        def train_with_logs() -> None:
            original_train()
            self.train_logs = {k: float(v) for k, v in model.logger.name_to_value.items() if k.startswith("train/")}

        model.train = train_with_logs  # type: ignore[method-assign]
        self._wrap(model, "train", "train", None, enter="train")
        self._wrap(th.Tensor, "backward", "backward", "train")
        self._wrap(th.nn.utils, "clip_grad_norm_", "optimizer", "train")
        self._wrap(policy.optimizer, "zero_grad", "optimizer", "train")
        original_step = policy.optimizer.step

        def counted_step(*args, **kwargs):
            if self._phase == "train":
                self.minibatches += 1
            return original_step(*args, **kwargs)

        policy.optimizer.step = counted_step  # type: ignore[method-assign]
        self._wrap(policy.optimizer, "step", "optimizer", "train")

    def reset(self) -> None:
        self.wall.clear()
        self.cpu.clear()
        self.minibatches = 0

    def per_update(self, clock: Counter[str], updates: int) -> dict[str, float]:
        """Seconds per update of every range in :data:`RANGES`."""
        seconds = {key: clock[key] / updates for key in RANGES}
        seconds["rollout_other"] = seconds["rollout"] - seconds["env"] - seconds["policy"]
        seconds["train_forward"] = seconds["train"] - seconds["backward"] - seconds["optimizer"]
        return seconds

    def restore(self) -> None:
        """Undo the class-level patches (``Tensor.backward``, ``clip_grad_norm_``); the model's stay."""
        th.Tensor.backward = _ORIGINAL_BACKWARD  # type: ignore[method-assign]
        th.nn.utils.clip_grad_norm_ = _ORIGINAL_CLIP


_ORIGINAL_BACKWARD = th.Tensor.backward
_ORIGINAL_CLIP = th.nn.utils.clip_grad_norm_


def _sync_summary(events: Any, syncs: SyncCounter) -> dict[str, Any]:
    return {
        "count": syncs.count,
        "by_site": dict(syncs.sites.most_common()),
        "profiler_events": {e.key: int(e.count) for e in events if e.key in SYNC_OPS},
        "seconds": sum(e.cpu_time_total for e in events if e.key in SYNC_OPS) / 1e6,
        "aten_ops": sum(int(e.count) for e in events if e.key.startswith("aten::")),
    }


def count_syncs(model: LatentSwarmPPO, timer: UpdateProfiler, per_update: int, first: bool) -> dict[str, Any]:
    """One (warm-up) update with its rollout and its training each under ``torch.profiler``: host syncs and aten ops."""
    timer.reset()
    timer.profiled, timer.device_sync = {"rollout", "train"}, False
    try:
        model.learn(per_update, reset_num_timesteps=first)
    finally:
        timer.profiled, timer.device_sync = set(), timer.cuda
    rollout, train = (_sync_summary(timer.profiles[key], timer.syncs[key]) for key in ("rollout", "train"))
    minibatches = max(timer.minibatches, 1)
    train["minibatches"] = timer.minibatches
    train["per_minibatch"] = train["count"] / minibatches
    train["aten_ops_per_minibatch"] = train["aten_ops"] / minibatches
    rollout["per_step"] = rollout["count"] / model.n_steps
    rollout["aten_ops_per_step"] = rollout["aten_ops"] / model.n_steps
    return {
        "per_update": rollout["count"] + train["count"],
        "rollout": rollout,
        "train": train,
        "measured_in": "the first warm-up update, under torch.profiler (its times are not in 'seconds')",
        "counted": "host syncs with the GPU's semantics (benchmarks/_syncs.py): reads of device values by the host and "
                   "data-dependent shapes, not reads inside torch.optim (its step counters live on the host)",
    }


def peak_memory(device: th.device) -> tuple[int, str]:
    if device.type == "cuda":
        return int(th.cuda.max_memory_allocated(device)), "torch.cuda.max_memory_allocated over the timed updates"
    # Linux reports ru_maxrss in KiB, macOS in bytes
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * (1 if sys.platform == "darwin" else 1024)
    return int(rss), "peak resident set size of the process (resource.getrusage), whole run"


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> th.device:
    """Refuse bad arguments before any work: counts, the device, the backend, an ``--autocast`` this version lacks."""
    if args.updates < 1 or args.warmup < 0 or args.threads < 0 or args.rounds < 1:
        parser.error(f"--updates and --rounds must be >= 1, --warmup and --threads >= 0 (got {args.updates}, "
                     f"{args.rounds}, {args.warmup}, {args.threads})")
    try:
        device = th.device(args.device)
    except RuntimeError as error:
        parser.error(f"--device {args.device}: {error}")
    if device.type == "cuda" and not th.cuda.is_available():
        parser.error(f"--device {args.device}: CUDA is not available on this machine (torch {th.__version__})")
    if args.backend not in BACKENDS:
        parser.error(f"--backend must be one of {', '.join(BACKENDS)}, got {args.backend!r}")
    if device.type not in ("cpu", "cuda"):
        parser.error(f"--device must be cpu or cuda[:N], got {args.device}")
    if args.autocast is not None and "autocast" not in inspect.signature(LatentSwarmPPO.__init__).parameters:
        parser.error("--autocast: this version of LatentSwarmPPO has no autocast option")
    if args.compare:
        try:
            check_revision(args.compare)
        except ValueError as error:
            parser.error(str(error))
    return device


def run(args: argparse.Namespace, device: th.device) -> dict[str, Any]:
    if args.threads:
        set_torch_threads(args.threads)
    preset = get_preset(args.preset)
    kwargs = dict(preset.algo_kwargs)
    if args.autocast is not None:
        kwargs["autocast"] = args.autocast
    if hasattr(preset, "make_model"):
        env = preset.make_env(args.seed, backend=args.backend)
        model = preset.make_model(env, seed=args.seed, device=device, **kwargs)
    else:  # a package before Preset.make_env/make_model (measured by --compare): what those do
        env = make_vec_env(preset.n_envs, config=preset.config, seed=args.seed, backend=args.backend)
        model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=args.seed, device=device, **kwargs)
    per_update = model.n_steps * model.n_envs
    timer = UpdateProfiler(model)
    timer.install()
    load_before = os.getloadavg()
    try:
        syncs = None
        for index in range(args.warmup):  # the first learn call sets up the run (SB3's reset_num_timesteps)
            if index == 0 and not args.no_profile:
                syncs = count_syncs(model, timer, per_update, first=True)
            else:
                model.learn(per_update, reset_num_timesteps=index == 0)
        timer.reset()
        if device.type == "cuda":
            th.cuda.reset_peak_memory_stats(device)
        process_cpu = time.process_time()
        with timer.timed("update"):
            model.learn(args.updates * per_update, reset_num_timesteps=args.warmup == 0)
        process_cpu = time.process_time() - process_cpu
    finally:
        timer.restore()
    memory, memory_kind = peak_memory(device)
    seconds = timer.per_update(timer.wall, args.updates)
    minibatches = timer.minibatches / args.updates
    return {
        "preset": preset.name,
        "device": str(device),
        "device_name": th.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "cpu",
        "python": platform.python_version(),
        "torch": th.__version__,
        "torch_threads": th.get_num_threads(),
        "cores": os.cpu_count(),
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "backend": args.backend,
        "autocast": args.autocast,
        "parameters": sum(p.numel() for p in model.policy.parameters()),
        "agent_steps_per_update": per_update,
        "updates": args.updates,
        "warmup_updates": args.warmup,
        "minibatches_per_update": minibatches,
        "seconds": seconds,
        "cpu_seconds": timer.per_update(timer.cpu, args.updates),
        "process_cpu_seconds": process_cpu / args.updates,
        "package": str(Path(sb3_latentswarm.__file__).resolve().parent),
        "agent_steps_per_second": per_update / seconds["update"],
        "budget_updates": preset.updates,
        "budget_hours": preset.updates * seconds["update"] / 3600,
        "budget_cpu_hours": preset.updates * timer.per_update(timer.cpu, args.updates)["update"] / 3600,
        "host_syncs": syncs,
        "peak_memory_bytes": memory,
        "peak_memory_kind": memory_kind,
        "train_logs": timer.train_logs,
    }


def print_report(result: dict[str, Any]) -> None:
    s, c = result["seconds"], result["cpu_seconds"]
    load = result["load_average"]
    print(f"Python {result['python']}, torch {result['torch']}, {result['torch_threads']} thread(s), {result['device']} "
          f"({result['device_name']}), {result['cores']} cores, load {load['before'][0]:.2f} -> {load['after'][0]:.2f}")
    print(f"preset {result['preset']}: {result['parameters']:,} parameters, {result['agent_steps_per_update']:,} agent-steps "
          f"and {result['minibatches_per_update']:g} minibatches per update, {result['updates']} update(s) timed "
          f"after {result['warmup_updates']} warm-up")
    # on a shared CPU the wall clock counts other processes' time slices too: the share comes from this thread's CPU time
    share, share_clock = (c, "CPU") if result["device"] == "cpu" else (s, "wall")
    print(f"| range | wall s per update | CPU s per update (this thread) | share of the update ({share_clock}) |")
    print("|---|---:|---:|---:|")
    labels = {
        "update": "whole update (learn)", "rollout": "rollout", "env": "  env step", "policy": "  policy forward",
        "rollout_other": "  other (buffer, GAE)", "train": "train", "train_forward": "  forward (replay, losses, stats)",
        "backward": "  backward", "optimizer": "  optimizer (+ grad clip, zero_grad)",
    }
    for key in RANGES:
        print(f"| {labels[key]} | {s[key]:.3f} | {c[key]:.3f} | {100 * share[key] / share['update']:.0f} % |")
    print(f"{result['agent_steps_per_second']:,.0f} agent-steps per wall s; the preset's {result['budget_updates']} "
          f"updates: {result['budget_hours']:.2f} h wall, {result['budget_cpu_hours']:.2f} h of this thread's CPU time")
    syncs = result["host_syncs"]
    if syncs is not None:
        rollout, train = syncs["rollout"], syncs["train"]
        print(f"host syncs per update: {syncs['per_update']} (rollout {rollout['count']}, {rollout['per_step']:.1f} per "
              f"step, {rollout['seconds']:.3f} s; train {train['count']}, {train['per_minibatch']:.1f} per minibatch, "
              f"{train['seconds']:.3f} s)")
        for site, count in list(train["by_site"].items())[:4]:
            print(f"  train: {count / max(train['minibatches'], 1):.2f} per minibatch at {site}")
        print(f"aten ops (nested calls counted): {train['aten_ops_per_minibatch']:,.0f} per training minibatch, "
              f"{rollout['aten_ops_per_step']:,.0f} per rollout step (all slots)")
    print(f"peak memory: {result['peak_memory_bytes'] / 2**20:,.0f} MiB ({result['peak_memory_kind']})")


COMPARED = ("process_cpu_s", "wall_s", "rollout_cpu_s", "train_cpu_s", "rollout_wall_s", "train_wall_s", "child_cpu_s")
"""Per-update figures of ``--compare`` (medians over the rounds), in the order of its table."""


def compared_figures(run: Run) -> dict[str, float]:
    """The :data:`COMPARED` figures of one ``--compare`` run (per update; ``child_cpu_s`` is the whole subprocess)."""
    result = run.result
    seconds, cpu = result["seconds"], result["cpu_seconds"]
    return {
        "process_cpu_s": result["process_cpu_seconds"],
        "wall_s": seconds["update"],
        "rollout_cpu_s": cpu["rollout"],
        "train_cpu_s": cpu["train"],
        "rollout_wall_s": seconds["rollout"],
        "train_wall_s": seconds["train"],
        "child_cpu_s": run.child_cpu_s,
    }


def compare(args: argparse.Namespace) -> dict[str, Any]:
    """``args.compare``'s package (old) against the working tree's (new), alternating subprocesses; medians and ratios."""
    arguments = ["--preset", args.preset, "--device", args.device, "--updates", str(args.updates), "--warmup",
                 str(args.warmup), "--threads", str(args.threads), "--backend", args.backend, "--seed", str(args.seed),
                 "--no-profile"]
    if args.autocast is not None:
        arguments += ["--autocast", args.autocast]
    shown = list(arguments)  # what the report names (without the JSON plumbing); --autocast was dropped before
    arguments += ["--json", "-"]
    header = "| code | round | " + " | ".join(COMPARED) + " | load before -> after |"
    print(f"old: {args.compare}, new: the working tree; {args.rounds} alternating round(s) of `update_time.py "
          f"{' '.join(shown)}`; seconds per update (child_cpu_s: the whole subprocess)", flush=True)
    print(header + "\n" + "|---" * (header.count("|") - 1) + "|", flush=True)

    def show(run: Run) -> None:
        figures, load = compared_figures(run), run.result["load_average"]
        print(f"| {run.code} | {run.round} | " + " | ".join(f"{figures[key]:.3f}" for key in COMPARED)
              + f" | {load['before'][0]:.2f} -> {load['after'][0]:.2f} |", flush=True)

    load_before = os.getloadavg()
    runs = alternate(__file__, arguments, args.compare, args.rounds, on_run=show)
    medians = {code: {key: statistics.median(compared_figures(run)[key] for run in code_runs) for key in COMPARED}
               for code, code_runs in runs.items()}
    for code, figures in medians.items():
        print(f"| {code} | median | " + " | ".join(f"{figures[key]:.3f}" for key in COMPARED) + " | |")
    ratios = {key: medians["old"][key] / medians["new"][key] if medians["new"][key] > 0 else float("nan")
              for key in COMPARED}
    print(f"old {args.compare} / new per update: process CPU s {ratios['process_cpu_s']:.2f}x, wall s "
          f"{ratios['wall_s']:.2f}x, rollout CPU s {ratios['rollout_cpu_s']:.2f}x, train CPU s {ratios['train_cpu_s']:.2f}x "
          f"({args.rounds} alternating round(s), load {load_before[0]:.2f} -> {os.getloadavg()[0]:.2f})")
    return {
        "compare": args.compare,
        "rounds": args.rounds,
        "arguments": shown,
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "medians": medians,
        "ratios": ratios,
        "runs": [{"code": run.code, "round": run.round, **compared_figures(run), "result": run.result}
                 for code_runs in runs.values() for run in code_runs],
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = build_parser()
    args = parser.parse_args(argv)
    device = check_args(parser, args)
    if args.compare:
        result = compare(args)
    else:
        result = run(args, device)
        print_report(result)
    if args.json == "-":
        print(json.dumps(result), flush=True)
    elif args.json:
        write_text(args.json, json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
