"""CPU seconds per `coordination` update: the old code with the old settings against this tree with the new ones.

Alternating blocks of fresh single-thread subprocesses (one per block and side), each building the preset with the
given ``--set`` overrides, running one warm-up update and then timing ``--updates`` updates with ``time.thread_time``;
the old side imports the package of git revision ``--old-rev`` (exported with ``git archive``). Prints each block and
the ratio of medians.

    python docs/results/coordination_time_to_coverage/update_cost.py --old-rev b250de8 --blocks 3 --updates 3 \\
        --new-set batch_size=3840 n_epochs=3 learning_rate=0.001
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
CHILD = """
import json, sys, time
import torch as th
th.set_num_threads(1)
from sb3_latentswarm import LatentSwarmPPO, make_vec_env
from sb3_latentswarm.presets import get_preset
overrides = json.loads(sys.argv[1]); updates = int(sys.argv[2])
preset = get_preset("coordination").with_overrides(**overrides)
env = make_vec_env(preset.n_envs, config=preset.config, seed=0)
model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=0, **preset.algo_kwargs)
per_update = preset.algo_kwargs["n_steps"] * preset.n_envs * preset.config.n_agents
model.learn(per_update)
times = []
for _ in range(updates):
    start = time.thread_time()
    model.learn(per_update, reset_num_timesteps=False)
    times.append(time.thread_time() - start)
print(json.dumps(times))
"""


def _overrides(items: list[str]) -> dict:
    out: dict = {}
    for item in items:
        name, _, text = item.partition("=")
        for kind in (int, float):
            try:
                out[name] = kind(text)
                break
            except ValueError:
                continue
        else:
            out[name] = text
    return out


def _run(root: Path, overrides: dict, updates: int) -> list[float]:
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    # cwd=root: ``python -c`` puts the working folder first on sys.path, ahead of PYTHONPATH, so run from another
    # folder the old side would import the package found there (a run from the repository measured new against new)
    result = subprocess.run([sys.executable, "-c", CHILD, json.dumps(overrides), str(updates)], env=env, check=True,
                            capture_output=True, text=True, cwd=root)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old-rev", required=True)
    parser.add_argument("--old-set", nargs="*", default=[])
    parser.add_argument("--new-set", nargs="*", default=[])
    parser.add_argument("--blocks", type=int, default=3)
    parser.add_argument("--updates", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as old_root:
        archive = subprocess.run(["git", "-C", str(REPO), "archive", args.old_rev, "sb3_latentswarm"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", old_root], input=archive, check=True)
        sides = {f"old ({args.old_rev}, {args.old_set or 'preset'})": (Path(old_root), _overrides(args.old_set)),
                 f"new (tree, {args.new_set or 'preset'})": (REPO, _overrides(args.new_set))}
        times: dict[str, list[float]] = {name: [] for name in sides}
        for block in range(args.blocks):
            for name, (root, overrides) in sides.items():
                block_times = _run(root, overrides, args.updates)
                times[name] += block_times
                print(f"block {block}: {name}: {' '.join(f'{t:.2f}' for t in block_times)} CPU s per update", flush=True)
    medians = {name: statistics.median(values) for name, values in times.items()}
    for name, value in medians.items():
        print(f"{name}: median {value:.3f} CPU s per update over {len(times[name])} updates")
    old, new = medians.values()
    print(f"ratio old / new: {old / new:.2f}x")


if __name__ == "__main__":
    main()
