"""The ``random_corner`` preset (issue 23, item 3), the dropout-regimes example (item 2) and the ``--set``/``--output``
options of the coordination-gap benchmark."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env
from sb3_latentswarm.presets import get_preset

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))
import dropout_regimes  # noqa: E402


def test_random_corner_preset_is_coordination_with_five_uavs_a_drawn_corner_and_bursty_outages():
    preset, coordination = get_preset("random_corner"), get_preset("coordination")
    config = preset.config
    assert (config.n_agents, config.start_region, config.max_steps) == (5, "random_corner", 48)
    assert config.initial_energy == pytest.approx(config.max_steps * config.energy_decay)  # b_0 / kappa = T
    assert (config.outage_model, config.p_fail, config.mean_outage_steps) == ("gilbert_elliott", 0.5, 25.0)
    same = ("grid_width", "grid_height", "cell_size", "v_max", "vz_max", "d_safe", "num_obstacles", "start_region_size")
    assert {f: getattr(config, f) for f in same} == {f: getattr(coordination.config, f) for f in same}
    # an update holds as many agent-steps as a `coordination` update, and the chunks tile the rollout
    per_update = preset.n_envs * preset.algo_kwargs["n_steps"] * config.n_agents
    assert per_update == coordination.n_envs * coordination.algo_kwargs["n_steps"] * coordination.config.n_agents == 7680
    assert preset.algo_kwargs["n_steps"] % preset.algo_kwargs["chunk_length"] == 0
    assert preset.total_timesteps == coordination.total_timesteps and preset.updates == coordination.updates
    # the algorithm accepts the preset's options (batch of whole swarm chunks)
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(preset.n_envs, config=config, seed=0), **preset.algo_kwargs)
    assert model.n_agents == 5 and model.swarm_config == config


def _corner(env: SwarmReconEnv, seed: int) -> tuple[int, int]:
    env.reset(seed=seed)
    positions = env.positions[:, :2]
    width, height = env.config.arena_size
    corners = {(int(x > width / 2), int(y > height / 2)) for x, y in positions}
    assert len(corners) == 1, f"seed {seed}: the swarm launched from several corners {corners}"
    return corners.pop()


def test_random_corner_preset_draws_the_launch_corner_per_episode_seed():
    env = SwarmReconEnv(get_preset("random_corner").config)
    corners = [_corner(env, seed) for seed in range(16)]
    assert len(set(corners)) == 4, corners  # every corner is drawn over these seeds
    assert _corner(env, 3) == corners[3]  # and an episode seed always gives the same corner


def test_regime_grid_runs_the_moot_cells_once_and_rejects_a_run_shorter_than_bernoulli():
    grid = dropout_regimes.regime_grid((0.0, 0.5, 1.0), (1.0, 10.0))
    assert [(r.p_fail, r.mean_outage) for r in grid] == [(0.0, 1.0), (0.5, 1.0), (0.5, 10.0), (1.0, 1.0)]
    base = get_preset("smoke").config
    assert grid[1].config(base).outage_model == "bernoulli"
    assert (grid[2].config(base).outage_model, grid[2].config(base).mean_outage_steps) == ("gilbert_elliott", 10.0)
    with pytest.raises(ValueError, match=r"--mean-outage 5 is below the Bernoulli run length .* at --p-fail 0.9"):
        dropout_regimes.regime_grid((0.9,), (5.0,))
    with pytest.raises(ValueError, match=r"--p-fail must be a finite number in \[0.0, 1.0\], got 1.5"):
        dropout_regimes.regime_grid((1.5,), (1.0,))


@pytest.fixture(scope="module")
def smoke_model(tmp_path_factory) -> str:
    preset = get_preset("smoke")
    env = make_vec_env(preset.n_envs, config=preset.config, seed=0)
    model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=0, **preset.algo_kwargs).learn(preset.total_timesteps)
    path = tmp_path_factory.mktemp("smoke_model") / "model.zip"
    model.save(path)
    return str(path)


def test_dropout_regimes_writes_cells_table_figures_and_resumes(smoke_model, tmp_path, capsys):
    argv = ["--models", smoke_model, "--episodes", "2", "--p-fail", "0", "0.5", "--mean-outage", "1", "10",
            "--conditions", "proposed", "hold_last", "--output", str(tmp_path)]
    dropout_regimes.main(argv)
    cells = pd.read_csv(tmp_path / "cells.csv")
    assert len(cells) == 3 * 2  # regimes (p_f 0 once; 0.5 Bernoulli and mean 10) x conditions
    assert set(zip(cells["p_fail"], cells["mean_outage"], cells["outage_model"])) == {
        (0.0, 1.0, "bernoulli"), (0.5, 1.0, "bernoulli"), (0.5, 10.0, "gilbert_elliott")}
    assert ((cells["dropout_share"] >= 0) & (cells["dropout_share"] <= 1)).all() and (cells["episodes"] == 2).all()
    assert cells[cells["p_fail"] == 0.5]["dropout_share"].gt(cells[cells["p_fail"] == 0.0]["dropout_share"].max()).all()
    for name in ("regimes.csv", "regimes.md", "coverage_vs_dropout.png", "error_by_depth.png", "run.md"):
        assert (tmp_path / name).stat().st_size > 0, name
    summary = pd.read_csv(tmp_path / "regimes.csv")
    coverage = summary[summary["metric"] == "coverage"]
    assert len(coverage) == 6 and (coverage["n_runs"] == 1).all()
    assert np.allclose(coverage["mean"], coverage["mean_low"]) and np.allclose(coverage["mean"], coverage["mean_high"])

    # a second run finds every cell and evaluates nothing; a third asks for a new cell and adds it
    capsys.readouterr()
    dropout_regimes.main(argv)
    assert "6 already in" in capsys.readouterr().out
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "cells.csv"), cells)
    dropout_regimes.main([*argv[:4], "--p-fail", "0", "1", *argv[7:]])
    assert len(pd.read_csv(tmp_path / "cells.csv")) == 8


def test_dropout_regimes_maps_a_learner_trained_with_another_substitute_as_its_own_line(smoke_model, tmp_path):
    trained = LatentSwarmPPO.load(smoke_model)
    trained.policy_kwargs["message_substitute"] = trained.policy.message_substitute = "zero"  # a zero_substitute learner
    trained_path = tmp_path / "zero_substitute.zip"
    trained.save(trained_path)
    dropout_regimes.main(["--models", smoke_model, str(trained_path), "--episodes", "2", "--p-fail", "0.5",
                          "--mean-outage", "1", "--conditions", "proposed", "no_predictor", "--output", str(tmp_path / "out")])
    cells = pd.read_csv(tmp_path / "out" / "cells.csv")
    assert sorted(zip(cells["learner"], cells["condition"])) == [
        ("proposed", "no_predictor"), ("proposed", "proposed"), ("zero_substitute", "proposed")]  # its own setting only
    lines = set(pd.read_csv(tmp_path / "out" / "regimes.csv")["condition"])
    assert lines == {"proposed", "no_predictor", "zero_substitute learner"}  # not merged into the proposed models' line
    # the zero-substitute learner in its own setting is the proposed model under No predictor: the same episodes
    coverage = cells.set_index(["learner", "condition"])["coverage"]
    assert coverage[("zero_substitute", "proposed")] == coverage[("proposed", "no_predictor")]
    assert "Trained with zeros" in (tmp_path / "out" / "regimes.md").read_text()


def test_dropout_regimes_refuses_to_mix_episode_counts_before_any_work(smoke_model, tmp_path, capsys):
    dropout_regimes.main(["--models", smoke_model, "--episodes", "1", "--p-fail", "0", "--conditions", "proposed",
                          "--output", str(tmp_path)])
    before = (tmp_path / "cells.csv").read_text()
    with pytest.raises(SystemExit):
        dropout_regimes.main(["--models", smoke_model, "--episodes", "2", "--p-fail", "0", "--output", str(tmp_path)])
    assert "holds cells of --episodes 1" in capsys.readouterr().err
    assert (tmp_path / "cells.csv").read_text() == before
    for bad, message in ((["--conditions", "nope"], "Unknown condition 'nope'"), (["--episodes", "0"], "--episodes"),
                         (["--models", str(tmp_path / "missing.zip")], "no file at")):
        with pytest.raises(SystemExit):
            dropout_regimes.main(["--models", smoke_model, "--output", str(tmp_path / "new"), *bad])
        assert message in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_coordination_gap_takes_config_fields_and_writes_its_table(tmp_path):
    output = tmp_path / "gap" / "gap.md"
    result = subprocess.run(
        [sys.executable, "benchmarks/coordination_gap.py", "--preset", "smoke", "--set", "n_agents=2", "--set",
         "start_region=random_corner", "--horizons", "5", "--episodes", "2", "--output", str(output)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    text = output.read_text()
    assert "with n_agents=2, start_region=random_corner" in text and "N=2" in text and "| **gap (points)** |" in text
    bad = subprocess.run([sys.executable, "benchmarks/coordination_gap.py", "--preset", "smoke", "--set", "n_steps=4"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "not SwarmConfig fields" in bad.stderr
