"""Evaluation time: ``evaluate`` on the batched core against the per-copy runner it replaced, in one run.

The old runner (``SwarmReconEnv`` copies stepped one at a time) is loaded from git, the module
``sb3_latentswarm/evaluation.py`` of ``--baseline-commit``, and runs on the same package otherwise. Both evaluate the
committed ``coordination`` model (``docs/results/coordination/trials/proposed-seed0``) on the same held-out episodes,
in blocks that alternate old / new, timed by per-thread CPU time (``time.thread_time``: what this process got of a
loaded machine) and wall time; the rows of both must be equal. Target (issue 22): new at least 2x faster.

    python benchmarks/evaluation_time.py --episodes 32 --repeats 3
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
import types
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-commit", default="7559e37", help="commit of the old evaluation.py")
    parser.add_argument("--episodes", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=3, help="old / new blocks, alternating")
    parser.add_argument("--sampled", action="store_true", help="sampled actions (default: mean actions)")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402
import torch as th  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO  # noqa: E402
from sb3_latentswarm.evaluation import HELD_OUT_SEED, evaluate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# the first round's coordination proposed-seed0, weight-only (the same weights: examples/weight_only_models.py)
MODEL = ROOT / "tests/data/models/coordination-proposed-seed0.zip"


def load_old_evaluation(commit: str) -> types.ModuleType:
    """The module ``sb3_latentswarm/evaluation.py`` as it was at ``commit``, under the name ``old_evaluation``."""
    source = subprocess.run(
        ["git", "show", f"{commit}:sb3_latentswarm/evaluation.py"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout
    spec = importlib.util.spec_from_loader("old_evaluation", loader=None)
    module = importlib.util.module_from_spec(spec)
    sys.modules["old_evaluation"] = module  # dataclasses look their module up
    exec(compile(source, f"{commit}:sb3_latentswarm/evaluation.py", "exec"), module.__dict__)
    return module


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    th.set_num_threads(1)
    old = load_old_evaluation(args.baseline_commit)
    model = LatentSwarmPPO.load(MODEL, device="cpu")
    kwargs = dict(n_episodes=args.episodes, seed=HELD_OUT_SEED, deterministic=not args.sampled)
    times: dict[str, list[tuple[float, float]]] = {"old": [], "new": []}
    frames = {}
    for _ in range(args.repeats):
        for name, function in (("old", old.evaluate), ("new", evaluate)):
            cpu, wall = time.thread_time(), time.perf_counter()
            frames[name] = function(model, "proposed", **kwargs)
            times[name].append((time.thread_time() - cpu, time.perf_counter() - wall))
    columns = list(frames["old"].columns)
    pd.testing.assert_frame_equal(frames["new"][columns], frames["old"], check_dtype=False, rtol=0, atol=0)
    print(f"python {' '.join(sys.argv)}")
    print(f"coordination proposed-seed0, {args.episodes} episodes, {'sampled' if args.sampled else 'mean'} actions, "
          f"{args.repeats} alternating blocks; rows equal: yes")
    print("| runner | CPU s per evaluate (min / median) | wall s (median) |")
    print("|---|---|---|")
    for name in ("old", "new"):
        cpu = sorted(t[0] for t in times[name])
        wall = sorted(t[1] for t in times[name])
        print(f"| {name} | {cpu[0]:.3f} / {cpu[len(cpu) // 2]:.3f} | {wall[len(wall) // 2]:.3f} |")
    ratio = sorted(t[0] for t in times["old"])[args.repeats // 2] / sorted(t[0] for t in times["new"])[args.repeats // 2]
    print(f"speed-up (median CPU time): {ratio:.2f}x")


if __name__ == "__main__":
    main()
