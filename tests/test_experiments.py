"""Multi-seed sweeps: the across-seed intervals on data with known answers, bad input, and one smoke sweep on Ray."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sb3_latentswarm.cli import main
from sb3_latentswarm.experiments import (
    EvalSet,
    aggregate_scores,
    interquartile_mean,
    interval_estimates,
    make_spec,
    mean,
    plan_trials,
    stratified_bootstrap_ci,
)

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------- aggregation
def test_iqm_is_the_mean_of_the_middle_half():
    scores = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 100.0])[:, None]
    assert interquartile_mean(scores) == pytest.approx(4.5)  # mean of 3, 4, 5, 6: the outlier 100 is cut
    assert mean(scores) == pytest.approx(16.0)


def test_identical_seeds_give_a_zero_width_interval():
    for aggregate in (interquartile_mean, mean):
        point, low, high = stratified_bootstrap_ci(np.full(5, 83.0), aggregate)
        assert point == low == high == pytest.approx(83.0)


def test_a_shifted_copy_shifts_the_interval_by_the_shift():
    scores = np.array([[70.0, 10.0], [75.0, 12.0], [90.0, 11.0], [82.0, 30.0], [60.0, 14.0]])  # (runs, tasks)
    for aggregate in (interquartile_mean, mean):
        point, low, high = stratified_bootstrap_ci(scores, aggregate)
        shifted = stratified_bootstrap_ci(scores + 7.5, aggregate)
        assert shifted == pytest.approx((point + 7.5, low + 7.5, high + 7.5))
        assert low < point < high


def test_the_interval_narrows_with_more_seeds_and_covers_the_truth():
    rng = np.random.default_rng(1)
    few = stratified_bootstrap_ci(rng.normal(50.0, 5.0, 4), mean)
    many = stratified_bootstrap_ci(rng.normal(50.0, 5.0, 400), mean)
    assert many[2] - many[1] < 0.25 * (few[2] - few[1])
    assert many[1] < 50.0 < many[2]


def test_one_task_matches_scipys_percentile_bootstrap():
    from scipy import stats

    scores = np.array([81.0, 85.5, 90.2, 78.4, 88.8, 84.1])
    _, low, high = stratified_bootstrap_ci(scores, mean, reps=20_000)
    reference = stats.bootstrap((scores,), np.mean, n_resamples=20_000, method="percentile", rng=0).confidence_interval
    assert low == pytest.approx(reference.low, abs=0.15) and high == pytest.approx(reference.high, abs=0.15)


def test_the_bootstrap_resamples_within_each_task():
    # task 0 varies across runs, task 1 is constant: a stratified replicate always holds 3 runs of each task, so the
    # mean never leaves [mean of task 1 with task 0's min, ... max]
    scores = np.array([[0.0, 10.0], [1.0, 10.0], [2.0, 10.0]])
    _, low, high = stratified_bootstrap_ci(scores, mean, reps=5000)
    assert (0.0 + 10.0) / 2 <= low <= high <= (2.0 + 10.0) / 2


def test_interval_estimates_has_rliables_shape():
    table = interval_estimates({"a": np.ones((3, 2)), "b": np.arange(6.0).reshape(3, 2)})
    assert list(table["algorithm"]) == ["a", "b"]
    assert {"iqm", "iqm_low", "iqm_high", "mean", "mean_low", "mean_high", "n_runs"} <= set(table.columns)
    assert table.loc[0, "iqm_low"] == table.loc[0, "iqm_high"] == 1.0


def test_aggregate_scores_per_group_drops_runs_without_a_score():
    runs = pd.DataFrame(
        {
            "variant": ["a", "a", "a", "b", "b", "b"],
            "coverage": [80.0, 80.0, 80.0, 60.0, 70.0, 80.0],
            "steps_to_90": [100.0, np.nan, 120.0, np.nan, np.nan, np.nan],
        }
    )
    table = aggregate_scores(runs, ["variant"], ["coverage", "steps_to_90"]).set_index(["variant", "metric"])
    assert table.loc[("a", "coverage"), ["mean", "mean_low", "mean_high"]].tolist() == [80.0, 80.0, 80.0]
    assert table.loc[("a", "steps_to_90"), "n_runs"] == 2 and table.loc[("a", "steps_to_90"), "mean"] == 110.0
    assert table.loc[("b", "steps_to_90"), "n_runs"] == 0 and np.isnan(table.loc[("b", "steps_to_90"), "iqm"])
    with pytest.raises(ValueError, match="finite"):
        stratified_bootstrap_ci([1.0, np.nan], mean)


# ---------------------------------------------------------------------------------------------- planning and bad input
def test_plan_crosses_variants_seeds_and_grid_points():
    spec = make_spec("smoke", 2, ["proposed", "independent"], grid={"p_fail": [0.1, 0.5]})
    trials = plan_trials(spec, "abc")
    assert len(trials) == 2 * 2 * 2 and len({t["trial_id"] for t in trials}) == 8
    assert {"proposed-seed1-p_fail=0.5", "independent-seed0-p_fail=0.1"} <= {t["trial_id"] for t in trials}
    # --set eval_episodes is the default of --eval-episodes; a larger n_envs moves the training seeds up
    assert make_spec("smoke", 1, overrides={"eval_episodes": 7})["eval_episodes"] == 7
    with pytest.raises(ValueError, match="overlaps the training env seeds"):
        make_spec("smoke", 3, overrides={"n_envs": 400_000})
    eval_sets = [s["name"] for s in spec["eval_sets"]]
    assert eval_sets[0] == "table1" and "p_fail=0.5" in eval_sets  # Table I's conditions and its p_f sweep


@pytest.mark.parametrize(
    "args, message",
    [
        (["--variant", "mappo"], "invalid choice"),
        (["--seeds", "0"], "--seeds must be an int >= 1, got 0"),
        (["--only", "proposed-seed7"], "--only: unknown trial id(s) ['proposed-seed7']"),
        (["--grid", "warp_speed=1,2"], "--grid: unknown setting"),
        (["--grid", "p_fail=0.1,2.0"], "p_fail"),
        (["--eval-set", "bad=warp_speed=3"], "unknown setting 'warp_speed'"),
        (["--eval-set", "bad=learning_rate=0.1"], "--eval-set bad: unknown SwarmConfig field"),
        (["--eval-set", "bad=p_fail=0.7,conditions=proposed+telepathy"], "unknown condition 'telepathy'"),
        (["--address", "127.0.0.1:1"], "no Ray cluster answers there"),
        (["--cpus-per-trial", "0"], "--cpus-per-trial must be > 0"),
        (["--gpus-per-trial", "-1"], "--gpus-per-trial must be >= 0"),
        (["--address", "nonsense"], "HOST:PORT"),
    ],
)
def test_bad_sweep_input_exits_2_before_training(tmp_path, capsys, args, message):
    output = tmp_path / "sweep"
    argv = ["sweep", "--preset", "smoke", "--output", str(output), *args]
    if "--seeds" not in args:
        argv += ["--seeds", "2"]
    with pytest.raises(SystemExit) as error:
        main(argv)
    assert error.value.code == 2
    assert message in capsys.readouterr().err
    assert not output.exists()  # nothing started


def test_eval_set_parsing():
    spec = make_spec("smoke", 1, extra_eval_sets=[EvalSet("pf07", {"p_fail": 0.7}, ("proposed", "no_memory"))])
    assert spec["eval_sets"][-1] == {"name": "pf07", "overrides": {"p_fail": 0.7}, "conditions": ["proposed", "no_memory"]}
    with pytest.raises(ValueError, match="unique"):
        make_spec("smoke", 1, extra_eval_sets=[EvalSet("table1")])


# ---------------------------------------------------------------------------------------------- the sweep, end to end
def run_sweep_command(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-m", "sb3_latentswarm.cli", "sweep", *args]
    return subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_sweep_smoke_end_to_end_and_resume(tmp_path):
    output = tmp_path / "sweep"
    args = ("--preset", "smoke", "--seeds", "2", "--eval-episodes", "2", "--output", str(output), "--verbose", "0")
    burst = "burst10=outage_model=gilbert_elliott,mean_outage_steps=10,p_fail=0.5,conditions=proposed+no_memory"
    extra = ("--eval-set", burst)  # an evaluation cell of issue #12: bursty outages
    result = run_sweep_command(*args, *extra)
    assert result.returncode == 0, result.stderr[-3000:]

    scores = pd.read_csv(output / "scores.csv")
    assert scores.groupby("variant")["train_seed"].unique().map(sorted).to_dict() == {
        "proposed": [0, 1],
        "no_comm": [0, 1],
        "independent": [0, 1],
    }
    aggregate = pd.read_csv(output / "aggregate.csv")
    assert {"iqm", "iqm_low", "iqm_high", "mean", "mean_low", "mean_high", "n_runs"} <= set(aggregate.columns)
    coverage = aggregate.query("metric == 'coverage'")
    assert (coverage["n_runs"] == 2).all() and (coverage["iqm_low"] <= coverage["iqm_high"]).all()
    # the extra cell: the latent variants under both of its conditions, the independent learner only where it can act
    cell = scores.query("eval_set == 'burst10'")
    assert set(cell.query("variant == 'proposed'")["condition"]) == {"proposed", "no_memory"}
    assert set(cell.query("variant == 'independent'")["condition"]) == {"proposed"}
    assert (cell["p_fail"] == 0.5).all()
    assert set(scores.query("eval_set == 'table1'")["condition"]) == {
        "proposed", "full_comm", "full_comm_in_range", "no_comm", "no_predictor", "no_memory"
    }

    episodes = pd.read_csv(output / "episodes.csv")
    assert episodes["seed"].min() >= 1_000_000  # held-out evaluation seeds
    record = json.loads((output / "trials" / "no_comm-seed1" / "trial.json").read_text())
    assert record["train_config"]["link_mode"] == "none" and record["eval_config"]["link_mode"] == "channel"
    assert record["training_env_seeds"] == [2, 3] and record["commit"] and record["machine"]
    assert (output / "trials" / "proposed-seed0" / "model.zip").stat().st_size > 0
    progress = pd.read_csv(output / "trials" / "proposed-seed0" / "progress.csv")
    assert progress["agent_steps"].tolist() == [120.0, 240.0]
    for name in ("aggregate.md", "run.md", "intervals_coverage.png", "learning_curves.png"):
        assert (output / name).stat().st_size > 0, name
    assert "IQM [95 % CI]" in (output / "run.md").read_text()

    # --resume on a finished sweep retrains nothing and starts no Ray run
    models = {p: p.stat().st_mtime_ns for p in (output / "trials").glob("*/model.zip")}
    ray_runs = sorted((output / "ray").iterdir())
    result = run_sweep_command(*args, *extra, "--resume")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "6 trials, 6 already finished" in result.stdout
    assert {p: p.stat().st_mtime_ns for p in (output / "trials").glob("*/model.zip")} == models
    assert sorted((output / "ray").iterdir()) == ray_runs

    # a sweep interrupted before a trial finished: --resume trains that trial only
    shutil.rmtree(output / "trials" / "no_comm-seed1")
    result = run_sweep_command(*args, *extra, "--resume")
    assert result.returncode == 0, result.stderr[-3000:]
    assert "6 trials, 5 already finished" in result.stdout
    assert (output / "trials" / "no_comm-seed1" / "trial.json").exists()
    kept = {p: t for p, t in models.items() if p.parent.name != "no_comm-seed1"}
    assert {p: p.stat().st_mtime_ns for p in kept} == kept
    assert pd.read_csv(output / "scores.csv").groupby("variant")["train_seed"].nunique().to_dict() == {
        "proposed": 2,
        "no_comm": 2,
        "independent": 2,
    }

    # the same output without --resume, or with other arguments, is refused
    again = run_sweep_command(*args, *extra)
    assert again.returncode == 2 and "pass --resume" in again.stderr
    other = run_sweep_command(*args, "--resume")
    assert other.returncode == 2 and "differs" in other.stderr


def test_only_selects_among_the_unfinished_trials_in_plan_order():
    from sb3_latentswarm.experiments.sweep import select_trials

    trials = [{"trial_id": t} for t in ("proposed-seed0", "no_comm-seed0", "independent-seed0", "proposed-seed1")]
    ids = lambda selected: [t["trial_id"] for t in selected]  # noqa: E731
    assert ids(select_trials(trials, {"proposed-seed0"})) == ["no_comm-seed0", "independent-seed0", "proposed-seed1"]
    only = ["proposed-seed1", "proposed-seed0", "no_comm-seed0"]
    assert ids(select_trials(trials, {"proposed-seed0"}, only)) == ["no_comm-seed0", "proposed-seed1"]
    with pytest.raises(ValueError, match="unknown trial id"):
        select_trials(trials, set(), ["proposed-seed9"])
