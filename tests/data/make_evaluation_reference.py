"""Write tests/data/evaluation_reference.csv (per-episode rows of ``evaluate`` on a committed coordination model) and
tests/data/run_episode_reference.npz (positions, dropouts and a frame digest of ``rendering.run_episode``).

The rows were produced by the evaluation code of commit 7559e37 (before evaluation moved onto the batched core);
``tests/test_evaluation_reference.py`` checks that today's ``evaluate`` gives the same rows for the same seeds.

Command (from the repository root)::

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python tests/data/make_evaluation_reference.py
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import torch as th

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.baselines import FrontierPlanner
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.rendering import run_episode

ROOT = Path(__file__).resolve().parents[2]
# the committed model's weights, weight-only; at 7559e37 (no weight-only files) use the original from 206f0d5
MODEL = ROOT / "tests/data/models/coordination-proposed-seed0.zip"
OUTPUT = Path(__file__).with_name("evaluation_reference.csv")
EPISODE_OUTPUT = Path(__file__).with_name("run_episode_reference.npz")
SEED = 4242
N_EPISODES = 3
CONDITIONS = ("proposed", "no_comm", "no_predictor", "no_memory", "full_comm")


def main() -> None:
    th.set_num_threads(1)
    model = LatentSwarmPPO.load(MODEL, device="cpu")
    frames = []
    for deterministic in (True, False):
        for condition in CONDITIONS:
            # n_envs=2 < n_episodes: a finished copy starts the next pending episode
            df = evaluate(model, condition, n_episodes=N_EPISODES, seed=SEED, deterministic=deterministic, n_envs=2)
            df.insert(0, "actor", "proposed-seed0")
            df.insert(1, "deterministic", deterministic)
            frames.append(df)
    planner = FrontierPlanner(model.swarm_config)
    df = evaluate(planner, "proposed", n_episodes=N_EPISODES, seed=SEED, config=model.swarm_config)
    df.insert(0, "actor", "frontier")
    df.insert(1, "deterministic", True)
    frames.append(df)
    pd.concat(frames, ignore_index=True).to_csv(OUTPUT, index=False, float_format="%.17g")
    print(f"wrote {OUTPUT.relative_to(ROOT)}", file=sys.stderr)

    arrays = {}
    for name, condition, deterministic in (("mean", "proposed", True), ("sampled", "no_predictor", False)):
        frames, positions, dropouts, infos = run_episode(
            model, model.swarm_config, seed=SEED, condition=condition, deterministic=deterministic
        )
        arrays[f"{name}_positions"] = positions
        arrays[f"{name}_dropouts"] = dropouts
        arrays[f"{name}_frames_sha256"] = np.array(hashlib.sha256(np.ascontiguousarray(frames).tobytes()).hexdigest())
        arrays[f"{name}_coverage"] = np.array(infos["uav_0"]["swarm_summary"]["coverage"])
    np.savez_compressed(EPISODE_OUTPUT, **arrays)
    print(f"wrote {EPISODE_OUTPUT.relative_to(ROOT)}", file=sys.stderr)


if __name__ == "__main__":
    main()
