"""Evaluation on the batched core replays the episodes of the per-copy runner it replaced, row for row.

The reference rows (tests/data/evaluation_reference.csv, tests/data/run_episode_reference.npz) were written by the
evaluation code of commit 7559e37 with tests/data/make_evaluation_reference.py, on the committed coordination model
docs/results/coordination/trials/proposed-seed0; the test loads its weight-only copy
tests/data/models/coordination-proposed-seed0.zip (the same weights, bit for bit: examples/weight_only_models.py).

On the CPU that recorded them the rows are equal bit for bit. Another CPU (the references come from an Intel machine
with AMX; CI also runs on AMD EPYC with AVX-512) rounds float32 GEMMs differently in the last bit, so the float
columns are compared at ``FLOAT_RTOL`` (relative 1e-5, about 80 float32 ulps): far below any change a code change
makes (one cell of coverage is 2.5e-3, one collision is 1), while discrete columns (episode, seed, steps, lengths,
rates, collisions) stay exact.
"""

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.baselines import FrontierPlanner
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.rendering import run_episode

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).with_name("data")
MODEL = DATA / "models" / "coordination-proposed-seed0.zip"  # the committed model's weights (weight_only_models.py)
SEED, N_EPISODES = 4242, 3  # as in make_evaluation_reference.py
# every column of the old runner (the diagnostics are summed in the same order)
COLUMNS = ["episode", "seed", "coverage", "collisions", "steps_to_90", "episode_return", "episode_length",
           "link_up_rate", "dropout_rate", "map_error", "pred_error_dropout"]
FLOAT_RTOL = 1e-5  # float32 rounding across CPUs (module docstring); integer columns are compared exactly


@pytest.fixture(scope="module")
def model():
    return LatentSwarmPPO.load(MODEL, device="cpu")


@pytest.fixture(scope="module")
def reference():
    return pd.read_csv(DATA / "evaluation_reference.csv")


@pytest.mark.parametrize("deterministic", [True, False])
@pytest.mark.parametrize("condition", ["proposed", "no_comm", "no_predictor", "no_memory", "full_comm"])
def test_policy_rows_equal_the_reference(model, reference, condition, deterministic):
    expected = reference[
        (reference["actor"] == "proposed-seed0") & (reference["deterministic"] == deterministic)
        & (reference["condition"] == condition)
    ].reset_index(drop=True)
    assert len(expected) == N_EPISODES
    df = evaluate(model, condition, n_episodes=N_EPISODES, seed=SEED, deterministic=deterministic, n_envs=2)
    pd.testing.assert_frame_equal(df[COLUMNS], expected[COLUMNS], check_dtype=False, rtol=FLOAT_RTOL, atol=0)


def test_planner_rows_equal_the_reference(model, reference):
    expected = reference[reference["actor"] == "frontier"].reset_index(drop=True)
    df = evaluate(FrontierPlanner(model.swarm_config), "proposed", n_episodes=N_EPISODES, seed=SEED, config=model.swarm_config)
    pd.testing.assert_frame_equal(df[COLUMNS], expected[COLUMNS], check_dtype=False, rtol=0, atol=0)  # no network
    assert df["map_error"].isna().all()


@pytest.mark.parametrize("name, condition, deterministic", [("mean", "proposed", True), ("sampled", "no_predictor", False)])
def test_run_episode_equals_the_reference(model, name, condition, deterministic):
    reference = np.load(DATA / "run_episode_reference.npz")
    frames, positions, dropouts, infos = run_episode(
        model, model.swarm_config, seed=SEED, condition=condition, deterministic=deterministic
    )
    np.testing.assert_allclose(positions, reference[f"{name}_positions"], rtol=FLOAT_RTOL, atol=FLOAT_RTOL)  # metres
    np.testing.assert_array_equal(dropouts, reference[f"{name}_dropouts"])
    assert hashlib.sha256(np.ascontiguousarray(frames).tobytes()).hexdigest() == str(reference[f"{name}_frames_sha256"])
    assert infos["uav_0"]["swarm_summary"]["coverage"] == float(reference[f"{name}_coverage"])
