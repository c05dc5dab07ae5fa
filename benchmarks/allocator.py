"""glibc's allocator thresholds on a training minibatch: with and without ``MALLOC_MMAP_THRESHOLD_`` /
``MALLOC_TRIM_THRESHOLD_``, in alternating subprocesses, medians, and the peak memory each costs.

By default glibc serves a large block (over a threshold that adapts up to 32 MiB) with a fresh ``mmap`` and gives
freed memory at the top of the heap back to the kernel once more than twice that is free: a training step that
allocates and frees the same large activations every minibatch then pays page faults (zeroed pages, system time) for
them every time. Setting both variables fixes the thresholds: blocks up to ``MALLOC_MMAP_THRESHOLD_`` come from the
heap and are reused, and the heap keeps up to ``MALLOC_TRIM_THRESHOLD_`` of free memory. The cost is resident memory.
The variables are read once at process start, so each setting runs in its own subprocess:

    python benchmarks/allocator.py --preset coordination --rounds 4
    MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=1073741824 sb3-latentswarm train ...   # opt in

Each round runs one subprocess per setting (the order alternates between rounds, so that a change in the machine's
load falls on both). A subprocess builds the preset's model with a rollout of ``--minibatches`` minibatches
(``benchmarks/minibatch_ops.py``'s ``build``, one torch thread), runs ``train()`` once to warm up, then ``--repeats``
times; per minibatch it reports the user and system CPU seconds and the minor page faults of the timed calls
(``resource.getrusage``; one thread, so the process's figures are the training's), and the process's peak resident set
size. The table gives the median over the rounds per setting and the ratio default / tuned.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

TUNED = {"MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "1073741824"}
"""The tuned setting: glibc's largest mmap threshold on 64-bit (32 MiB) and 1 GiB of free heap kept."""
ALLOCATOR_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_ARENA_MAX")
FIGURES = ("cpu_s", "user_s", "sys_s", "minor_faults", "peak_rss_mib", "end_rss_mib")
"""Per-minibatch figures of a child (``peak_rss_mib``: the whole process's peak; ``end_rss_mib``: its resident memory
after the timed calls, what the heap kept)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="coordination", help="preset whose training minibatch is measured")
    parser.add_argument("--minibatches", type=int, default=2, help="minibatches per train() call (default 2)")
    parser.add_argument("--repeats", type=int, default=3, help="timed train() calls per subprocess (default 3)")
    parser.add_argument("--rounds", type=int, default=4, help="rounds of one subprocess per setting (default 4)")
    parser.add_argument("--set", nargs="+", default=[f"{k}={v}" for k, v in TUNED.items()], metavar="NAME=VALUE",
                        help="the tuned setting's environment variables (default: %(default)s)")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the rows and the summary as JSON")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    return parser


def child(args: argparse.Namespace) -> dict[str, Any]:
    """One setting: build, warm up, time ``train()``; per-minibatch figures as one JSON line."""
    import torch as th

    th.set_num_threads(1)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from minibatch_ops import build

    model = build(args.preset, args.minibatches)
    model.train()  # a second warm-up: the allocator's state after a few minibatches
    before = resource.getrusage(resource.RUSAGE_SELF)
    start = time.thread_time()
    for _ in range(args.repeats):
        model.train()
    thread_cpu = time.thread_time() - start
    after = resource.getrusage(resource.RUSAGE_SELF)
    n = args.repeats * args.minibatches
    return {
        "cpu_s": thread_cpu / n,
        "user_s": (after.ru_utime - before.ru_utime) / n,
        "sys_s": (after.ru_stime - before.ru_stime) / n,
        "minor_faults": (after.ru_minflt - before.ru_minflt) / n,
        "peak_rss_mib": after.ru_maxrss / 1024,  # Linux: KiB
        "end_rss_mib": _current_rss_mib(),
        "allocator_env": {k: os.environ[k] for k in ALLOCATOR_VARIABLES if k in os.environ},
    }


def _current_rss_mib() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def run_child(args: argparse.Namespace, extra: dict[str, str]) -> dict[str, Any]:
    env = {k: v for k, v in os.environ.items() if k not in ALLOCATOR_VARIABLES}
    env.update({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", **extra})
    command = [sys.executable, __file__, "--child", "--preset", args.preset, "--minibatches", str(args.minibatches),
               "--repeats", str(args.repeats)]
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"child with {extra or 'the default allocator'} failed ({done.returncode}): "
                           f"{done.stderr.strip()[-500:]}")
    return json.loads(lines[-1])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.child:
        result = child(args)
        print(json.dumps(result))
        return result
    if args.minibatches < 1 or args.repeats < 1 or args.rounds < 1:
        parser.error("--minibatches, --repeats and --rounds must be >= 1")
    try:
        tuned = dict(item.split("=", 1) for item in args.set)
    except ValueError:
        parser.error(f"--set takes NAME=VALUE pairs, got {args.set}")
    settings = {"default": {}, "tuned": tuned}
    load_before = os.getloadavg()
    rows: list[dict[str, Any]] = []
    for index in range(args.rounds):
        order = list(settings) if index % 2 == 0 else list(settings)[::-1]
        for name in order:
            row = {"round": index, "setting": name, **run_child(args, settings[name])}
            rows.append(row)
            print(f"round {index + 1}, {name}: {row['cpu_s']:.3f} CPU s per minibatch (sys {row['sys_s']:.3f}), "
                  f"{row['minor_faults']:,.0f} minor faults, peak RSS {row['peak_rss_mib']:,.0f} MiB", flush=True)
    medians = {name: {f: statistics.median(r[f] for r in rows if r["setting"] == name) for f in FIGURES}
               for name in settings}
    summary = {
        "cpu": cpu_name(),
        "preset": args.preset,
        "tuned": tuned,
        "rounds": args.rounds,
        "minibatches_per_child": args.minibatches * args.repeats,
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "medians": medians,
        "speedup": medians["default"]["cpu_s"] / medians["tuned"]["cpu_s"],
        "round_speedups": [
            next(r["cpu_s"] for r in rows if r["round"] == i and r["setting"] == "default")
            / next(r["cpu_s"] for r in rows if r["round"] == i and r["setting"] == "tuned")
            for i in range(args.rounds)
        ],
        "peak_rss_ratio": medians["tuned"]["peak_rss_mib"] / medians["default"]["peak_rss_mib"],
    }
    print(f"\n{summary['cpu']}, preset {args.preset}, {args.rounds} alternating rounds, load "
          f"{load_before[0]:.2f} -> {summary['load_average']['after'][0]:.2f}; medians per training minibatch:")
    print("| setting | CPU s | user s | sys s | minor faults | peak RSS MiB | RSS at the end MiB |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, m in medians.items():
        print(f"| {name} | {m['cpu_s']:.3f} | {m['user_s']:.3f} | {m['sys_s']:.3f} | {m['minor_faults']:,.0f} | "
              f"{m['peak_rss_mib']:,.0f} | {m['end_rss_mib']:,.0f} |")
    rounds = ", ".join(f"{ratio:.2f}" for ratio in summary["round_speedups"])
    print(f"default / tuned CPU s: {summary['speedup']:.2f}x (per round {rounds}); peak RSS tuned / default: "
          f"{summary['peak_rss_ratio']:.3f} ({' '.join(args.set)})")
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": summary, "rows": rows}, indent=1) + "\n")
    return summary


if __name__ == "__main__":
    main()
