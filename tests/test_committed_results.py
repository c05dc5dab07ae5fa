"""Committed result models still load and evaluate to their published numbers (issue 33's check on a sample).

The models of ``docs/results/coordination_round2_600/`` and ``coordination_heavy_dropout/`` are weight-only (Adam's
moments removed, every other zip entry byte for byte: ``examples/weight_only_models.py``'s ``weight_only_copy``).
This test re-evaluates a sample of them on the first held-out episodes of their ``table1`` cell, with the trial's own
evaluation config, seeds and action mode (``trial.json``), and compares the rows with the trial's published
``episodes.csv``. Float columns are compared at the tolerance of ``tests/test_evaluation_reference.py`` (another CPU
rounds float32 GEMMs differently in the last bit); counts are exact.
"""

import json
import warnings
from pathlib import Path

import pandas as pd
import pytest

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.experiments.report import trial_file

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
SAMPLE = [  # (results folder, trial): the headline learner, a trained substitute, a heavy-dropout learner
    ("coordination_round2_600", "proposed-seed0"),
    ("coordination_round2_600", "zero_substitute-seed3"),
    ("coordination_heavy_dropout", "hold_last-seed2"),
]
N_EPISODES = 2
EXACT = ["episode", "seed", "collisions", "episode_length"]
FLOAT = ["coverage", "episode_return", "link_up_rate", "map_error"]
FLOAT_RTOL = 1e-5  # as tests/test_evaluation_reference.py


@pytest.mark.parametrize("folder, trial_id", SAMPLE)
def test_a_committed_weight_only_model_evaluates_to_its_published_rows(folder, trial_id):
    trial_dir = RESULTS / folder / "trials" / trial_id
    record = json.loads((trial_dir / "trial.json").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a weight-only file loads without a warning
        model = LatentSwarmPPO.load(trial_dir / "model.zip", device="cpu")
    assert not model.policy.optimizer.state  # weight-only: a fresh optimizer, Adam's moments not in the file
    published = pd.read_csv(trial_file(trial_dir, "episodes.csv"))  # episodes.csv or its gzip form
    condition = "proposed"  # a substitute learner's own substitute is part of its model
    expected = published[(published["eval_set"] == "table1") & (published["condition"] == condition)]
    expected = expected.head(N_EPISODES).reset_index(drop=True)
    assert len(expected) == N_EPISODES
    config = SwarmConfig(**record["eval_config"])
    seed = record["eval_env_seeds"][0]
    rows = evaluate(
        model, condition, n_episodes=N_EPISODES, seed=seed, config=config, deterministic=record["deterministic"]
    )
    pd.testing.assert_frame_equal(rows[EXACT], expected[EXACT], check_dtype=False)
    pd.testing.assert_frame_equal(rows[FLOAT], expected[FLOAT], check_dtype=False, rtol=FLOAT_RTOL, atol=0)

