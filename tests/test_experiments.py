"""Multi-seed sweeps: the across-seed intervals on data with known answers, bad input, and one smoke sweep on Ray."""

import dataclasses
import gzip
import json
import os
import re
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
    SweepSpec,
    aggregate_scores,
    finished_trials,
    interquartile_mean,
    interval_estimates,
    mean,
    plan_trials,
    stratified_bootstrap_ci,
    trial_id,
    write_report,
)
from sb3_latentswarm.experiments.spec import MAX_TRIAL_ID_LENGTH

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
    spec = SweepSpec.create("smoke", 2, variants=["proposed", "independent"], grid={"p_fail": [0.1, 0.5]})
    trials = plan_trials(spec, "abc")
    assert len(trials) == 2 * 2 * 2 and len({t["trial_id"] for t in trials}) == 8
    assert {"proposed-seed1-p_fail=0.5", "independent-seed0-p_fail=0.1"} <= {t["trial_id"] for t in trials}
    # --set eval_episodes is the default of --eval-episodes; a larger n_envs moves the training seeds up
    assert SweepSpec.create("smoke", 1, overrides={"eval_episodes": 7}).eval_episodes == 7
    with pytest.raises(ValueError, match="overlaps the training env seeds"):
        SweepSpec.create("smoke", 3, overrides={"n_envs": 400_000})
    eval_sets = [s.name for s in spec.eval_sets]
    assert eval_sets[0] == "table1" and "p_fail=0.5" in eval_sets  # Table I's conditions and its p_f sweep


@pytest.mark.parametrize(
    "args, message",
    [
        (["--variant", "mappo"], "invalid choice"),
        (["--seeds", "0"], "--seeds must be an int in [1, inf), got 0"),
        (["--only", "proposed-seed7"], "--only: unknown trial id(s) ['proposed-seed7']"),
        (["--grid", "warp_speed=1,2"], "--grid: unknown setting"),
        (["--grid", "p_fail=0.1,2.0"], "p_fail"),
        (["--eval-set", "bad=warp_speed=3"], "unknown setting 'warp_speed'"),
        (["--eval-set", "bad=learning_rate=0.1"], "--eval-set bad: unknown SwarmConfig field"),
        (["--eval-set", "bad=p_fail=0.7,conditions=proposed+telepathy"], "unknown condition 'telepathy'"),
        (["--address", "127.0.0.1:1"], "no Ray cluster answers there"),
        (["--cpus-per-trial", "0"], "--cpus-per-trial must be a finite number in (0.0, inf), got 0.0"),
        (["--gpus-per-trial", "-1"], "--gpus-per-trial must be a finite number in [0.0, inf), got -1.0"),
        (["--address", "nonsense"], "HOST:PORT"),
        # issue 18: refused before anything starts
        (["--grid", "p_fail=0.1,0.10"], "--grid p_fail: the values [0.1, 0.1] repeat [0.1]"),
        (["--grid", "n_epochs=1,1.0"], "--grid n_epochs: the values [1, 1.0] repeat"),
        (["--grid", "eval_episodes=1,5"], "--grid eval_episodes: changes the evaluation only"),
        (["--grid", "p_fail=0.1", "--grid", "p_fail=0.5"], "--grid p_fail given twice"),
        (["--grid", "p_fail=0.1,0.5", "--set", "p_fail=0.2"], "--grid p_fail is also given in --set"),
        (["--set", "n_epochs=0"], "n_epochs must be an int in [1, inf), got 0"),
        (["--set", "learning_rate=-1"], "learning_rate must be a finite number in (0.0, 1.0], got -1.0"),
        (["--set", "latent_dim=0"], "latent_dim must be an int in [1, inf), got 0"),
        (["--set", "latent_dim=32.5"], "latent_dim must be an int, got float (32.5)"),
        (["--set", "memory_dim=2.0"], "memory_dim must be an int, got float (2.0)"),
        (["--set", "batch_size=1"], "batch_size must hold at least one whole swarm sequence"),
        (["--grid", "batch_size=30,1"], "--grid point {'batch_size': 1}: batch_size must hold"),
        (["--set", "n_envs=0"], "n_envs must be an int in"),
        (["--storage", "/proc/no-such-storage"], "--storage /proc/no-such-storage: cannot write there"),
        (["--storage", "nosuchscheme://bucket/x"], "--storage nosuchscheme://bucket/x: cannot write there"),
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
    spec = SweepSpec.create("smoke", 1, extra_eval_sets=[EvalSet("pf07", {"p_fail": 0.7}, ("proposed", "no_memory"))])
    assert spec.eval_sets[-1] == EvalSet("pf07", {"p_fail": 0.7}, ("proposed", "no_memory"))
    assert spec.to_dict()["eval_sets"][-1] == {
        "name": "pf07", "overrides": {"p_fail": 0.7}, "conditions": ["proposed", "no_memory"]
    }
    with pytest.raises(ValueError, match="unique"):
        SweepSpec.create("smoke", 1, extra_eval_sets=[EvalSet("table1")])


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
        "proposed", "full_comm", "full_comm_in_range", "no_comm", "no_predictor", "no_memory", "hold_last", "own_message"
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
    assert not (output / "running").exists()  # the trials' work folder goes once they are all collected

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


# ---------------------------------------------------------------------------------------------- spec, ids, folder checks
def test_spec_round_trips_through_sweep_json(tmp_path):
    spec = SweepSpec.create(
        "smoke", 2, variants=["proposed"], grid={"p_fail": [0.1, 0.5], "log_std_bounds": [(-5.0, 0.0), (-4.0, 0.0)]}
    )
    spec.save(tmp_path / "sweep.json")
    assert SweepSpec.load(tmp_path / "sweep.json") == spec
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.eval_episodes = 3  # type: ignore[misc]
    (tmp_path / "bad.json").write_text(json.dumps({**spec.to_dict(), "eval_episode": 5}))
    with pytest.raises(ValueError, match="bad.json is not a sweep spec"):
        SweepSpec.load(tmp_path / "bad.json")


def test_trial_ids_are_unique_readable_and_short():
    assert trial_id("proposed", 0, {"p_fail": 0.5}) == "proposed-seed0-p_fail=0.5"
    # characters a folder name should not hold are replaced, and the exact point is hashed into the tail
    a, b = trial_id("proposed", 0, {"log_std_bounds": (-5.0, 0.0)}), trial_id("proposed", 0, {"log_std_bounds": (-5.0, 1.0)})
    assert a.startswith("proposed-seed0-log_std_bounds=_-5.0__0.0_-") and a != b
    # the 14-field grid of issue 18 gave a 312-character id that Ray Tune could not use as a folder name
    fields = ["p_fail", "grid_width", "grid_height", "num_obstacles", "max_steps", "v_max", "d_safe", "cell_size",
              "initial_energy", "n_epochs", "ent_coef", "vf_coef", "gamma", "gae_lambda"]
    long = {name: 0.123456789 for name in fields}
    ids = {trial_id("independent", 12, long), trial_id("independent", 12, {**long, "gamma": 0.5})}
    assert len(ids) == 2 and all(len(i) <= MAX_TRIAL_ID_LENGTH for i in ids)
    assert all(i.startswith("independent-seed12-p_fail=0.123456789-grid_width=") for i in ids)


def test_a_second_sweep_into_a_locked_folder_refuses(tmp_path, capsys):
    output = tmp_path / "sweep"
    holder = subprocess.Popen(  # issue 18: two sweeps 2 s apart both trained the same trial
        [sys.executable, "-c", "import sys; from sb3_latentswarm.utils.locks import output_lock\n"
         f"with output_lock({str(output)!r}):\n    print('held', flush=True); sys.stdin.read()"],
        env={**os.environ, "PYTHONPATH": str(ROOT)}, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(SystemExit) as error:
            main(["sweep", "--preset", "smoke", "--seeds", "1", "--output", str(output)])
        assert error.value.code == 2 and f"{output} is in use by another run (pid {holder.pid}" in capsys.readouterr().err
    finally:
        holder.kill()
        holder.wait()


def _fake_sweep(output: Path, spec: SweepSpec, episodes_per_cell: int | None = None) -> None:
    """A finished sweep without training: every trial folder as train_and_evaluate writes it, made-up scores."""
    from sb3_latentswarm.evaluation import EPISODE_COLUMNS
    from sb3_latentswarm.experiments.trial import conditions_for, grid_labels

    spec.save(output / "sweep.json")
    n = episodes_per_cell or spec.eval_episodes
    rng = np.random.default_rng(0)
    for trial in plan_trials(spec, "abc"):
        folder = output / "trials" / trial["trial_id"]
        folder.mkdir(parents=True)
        labels = {"trial_id": trial["trial_id"], "variant": trial["variant"], "train_seed": trial["train_seed"],
                  **grid_labels(trial["grid_point"])}
        rows = []
        for eval_set in spec.eval_sets:
            p_fail = eval_set.overrides.get("p_fail", trial["grid_point"].get("p_fail", 0.3))
            for condition in conditions_for(trial["variant"], eval_set.conditions or ("proposed", "no_comm")):
                for episode in range(n):
                    row = dict.fromkeys(EPISODE_COLUMNS, 0.0)
                    row.update(episode=episode, seed=spec.eval_seed + episode, condition=condition, p_fail=p_fail,
                               coverage=rng.uniform(50, 90), steps_to_90=np.nan, eval_set=eval_set.name)
                    rows.append(row)
        pd.DataFrame(rows).assign(**labels).to_csv(folder / "episodes.csv", index=False)
        pd.DataFrame({"agent_steps": [120.0, 240.0], "episode_reward": [1.0, 2.0], "coverage": [40.0, 50.0],
                      "collisions": [1.0, 0.0]}).assign(**labels).to_csv(folder / "progress.csv", index=False)
        (folder / "model.zip").write_bytes(b"PK")
        record = {**labels, "grid_point": trial["grid_point"], "preset": spec.preset, "commit": "abc", "machine": "cpu",
                  "node": "host-a", "ray_node_id": "n" * 56, "budget_agent_steps": 240, "trained_agent_steps": 240,
                  "train_seconds": 1.0, "eval_env_seeds": [spec.eval_seed, spec.eval_seed + spec.eval_episodes - 1],
                  "eval_sets": [s.to_dict() for s in spec.eval_sets], "deterministic": spec.deterministic}
        (folder / "trial.json").write_text(json.dumps(record))


def test_a_grid_over_a_table_column_writes_the_report(tmp_path):
    # issue 18: `--grid p_fail=0.1,0.5` (the docs' example) trained everything, then failed with
    # "cannot insert p_fail, already exists"; the grid point is now the column grid.p_fail, the cell's p_f stays p_fail
    spec = SweepSpec.create("smoke", 2, variants=["proposed", "no_comm"], grid={"p_fail": [0.1, 0.5]})
    _fake_sweep(tmp_path, spec)
    aggregate = write_report(tmp_path)
    scores = pd.read_csv(tmp_path / "scores.csv")
    assert set(scores["grid.p_fail"]) == {0.1, 0.5}
    table1 = scores.query("eval_set == 'table1'")
    assert (table1["p_fail"] == table1["grid.p_fail"]).all()  # Table I's cell runs at the trial's p_f
    assert set(scores.query("eval_set == 'p_fail=0.5'")["p_fail"]) == {0.5}  # a p_f cell keeps its own p_f
    assert set(aggregate.query("metric == 'coverage'")["n_runs"]) == {2}
    run_md = (tmp_path / "run.md").read_text()
    assert "8 finished of the 8 planned" in run_md and "host-a (Ray node nnnn" in run_md
    for name in ("aggregate.md", "intervals_coverage.png", "learning_curves.png"):
        assert (tmp_path / name).stat().st_size > 0


def test_run_md_states_the_episodes_the_files_hold(tmp_path):
    # an edited sweep.json said 50 episodes while scores.csv had 300: run.md now counts the stored episodes
    spec = SweepSpec.create("smoke", 1, variants=["proposed"], eval_episodes=2)
    _fake_sweep(tmp_path, spec, episodes_per_cell=3)
    write_report(tmp_path)
    run_md = (tmp_path / "run.md").read_text()
    assert "evaluation: 3 episodes per cell and run (scores.csv), env seeds 1000000..1000002" in run_md


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda t: shutil.copytree(t / "proposed-seed0", t / "proposed-seed0 copy"),
         "proposed-seed0 copy is not a trial of this sweep"),
        (lambda t: (shutil.rmtree(t / "proposed-seed1"), shutil.copytree(t / "proposed-seed0", t / "proposed-seed1")),
         "proposed-seed1 holds trial 'proposed-seed0', not 'proposed-seed1'"),
        (lambda t: (t / "proposed-seed0" / "episodes.csv").unlink(), "proposed-seed0 is damaged: no episodes.csv"),
        (lambda t: (t / "proposed-seed0" / "trial.json").write_text("{"), "proposed-seed0/trial.json is damaged"),
        (lambda t: pd.read_csv(t / "proposed-seed0" / "episodes.csv").drop(columns="eval_set").to_csv(
            t / "proposed-seed0" / "episodes.csv", index=False), "proposed-seed0/episodes.csv has no column(s) ['eval_set']"),
        (lambda t: (t / "proposed-seed0" / "trial.json").write_text(json.dumps(
            {**json.loads((t / "proposed-seed0" / "trial.json").read_text()), "eval_env_seeds": [1_000_000, 1_000_299]})),
         "proposed-seed0 was evaluated with other eval_env_seeds"),
    ],
)
def test_stray_or_damaged_trial_folders_are_named(tmp_path, capsys, damage, message):
    spec = SweepSpec.create("smoke", 2, variants=["proposed"])
    _fake_sweep(tmp_path, spec)
    assert list(finished_trials(tmp_path, spec)) == ["proposed-seed0", "proposed-seed1"]
    damage(tmp_path / "trials")
    with pytest.raises(ValueError, match=re.escape(message)):
        finished_trials(tmp_path, spec)
    # the sweep refuses it before Ray starts, with the same message (exit status 2)
    with pytest.raises(SystemExit) as error:
        main(["sweep", "--preset", "smoke", "--seeds", "2", "--variant", "proposed", "--output", str(tmp_path), "--resume",
              "--deterministic"])  # the spec above evaluates with the mean action (SweepSpec's default)
    assert error.value.code == 2 and message in capsys.readouterr().err


def test_a_results_folder_without_its_models_still_reports_but_is_no_warm_start(tmp_path):
    # issue 33: committed results folders keep their trials' records and leave most model files in the history
    spec = SweepSpec.create("smoke", 2, variants=["proposed"])
    (tmp_path / "a").mkdir()
    _fake_sweep(tmp_path / "a", spec)
    (tmp_path / "a" / "trials" / "proposed-seed1" / "model.zip").unlink()
    # and keeps a trial's episode table gzipped
    episodes = tmp_path / "a" / "trials" / "proposed-seed1" / "episodes.csv"
    expected = pd.read_csv(episodes)
    episodes.with_name("episodes.csv.gz").write_bytes(gzip.compress(episodes.read_bytes()))
    episodes.unlink()
    assert list(finished_trials(tmp_path / "a", spec)) == ["proposed-seed0", "proposed-seed1"]
    write_report(tmp_path / "a")
    assert set(pd.read_csv(tmp_path / "a" / "scores.csv")["trial_id"]) == {"proposed-seed0", "proposed-seed1"}
    rebuilt = pd.read_csv(tmp_path / "a" / "episodes.csv").query("trial_id == 'proposed-seed1'").reset_index(drop=True)
    pd.testing.assert_frame_equal(rebuilt, expected)
    budget = SweepSpec.create("smoke", 1).point_preset({}).total_timesteps
    with pytest.raises(ValueError, match=r"not finished there: \['proposed-seed1'\] \(each needs trial.json, model.zip"):
        SweepSpec.create("smoke", 2, variants=["proposed"], warm_start=tmp_path / "a", total_timesteps=2 * budget)


@pytest.mark.slow  # a trial process trained, killed and resumed: 31 s at load 5 (the trial-level kill test stays fast)
def test_a_sweep_trial_killed_mid_way_resumes_from_its_checkpoint(tmp_path):
    from sb3_latentswarm.runs.checkpoints import latest_checkpoint, read_checkpoint_state

    spec = SweepSpec.create("smoke", 1, variants=["proposed"], eval_episodes=1)
    output = tmp_path / "sweep"
    output.mkdir()
    spec.save(output / "sweep.json")
    trial = plan_trials(spec, "test")[0]
    work = output / "running" / trial["trial_id"]  # where the sweep's trainable trains this trial
    script = (
        "import json, sys, time\nfrom pathlib import Path\n"
        "from sb3_latentswarm.runs.checkpoints import SwarmCheckpointCallback\n"
        "from sb3_latentswarm.experiments import SweepSpec, train_and_evaluate\nwrite = SwarmCheckpointCallback.write\n"
        "def write_then_hang(self):\n    path = write(self)\n    print('CHECKPOINT', flush=True)\n    time.sleep(600)\n"
        "SwarmCheckpointCallback.write = write_then_hang\ntrial = json.loads(sys.argv[1])\n"
        "train_and_evaluate({**trial, 'spec': SweepSpec.from_dict(trial['spec'])}, Path(sys.argv[2]), device='cpu')\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-c", script, json.dumps({**trial, "spec": spec.to_dict()}), str(work)],
                               env=env, stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "CHECKPOINT"
    process.kill()  # the sweep's trial, killed with kill -9 after its first checkpoint
    process.wait(timeout=60)
    stopped = read_checkpoint_state(latest_checkpoint(work / "checkpoints"))["num_timesteps"]

    result = run_sweep_command("--preset", "smoke", "--seeds", "1", "--variant", "proposed", "--eval-episodes", "1",
                               "--output", str(output), "--resume", "--verbose", "0",
                               "--deterministic")  # as the spec above was built (SweepSpec's default)
    assert result.returncode == 0, result.stderr[-3000:]
    record = json.loads((output / "trials" / trial["trial_id"] / "trial.json").read_text())
    assert 0 < record["resumed_from_agent_steps"] == stopped < record["trained_agent_steps"]
    assert not work.exists() and not (output / "trials" / trial["trial_id"] / "checkpoints").exists()


def _finished_smoke_sweep(output: Path, variant: str = "proposed", **create) -> SweepSpec:
    """A one-trial smoke sweep (``variant``, seed 0) trained and evaluated into ``output`` without Ray."""
    from sb3_latentswarm.experiments import train_and_evaluate

    spec = SweepSpec.create("smoke", 1, variants=[variant], eval_episodes=1, **create)
    output.mkdir(parents=True)
    spec.save(output / "sweep.json")
    trial = plan_trials(spec, "test")[0]
    train_and_evaluate(trial, output / "trials" / trial["trial_id"], device="cpu")
    return spec


def _adam_steps(model_zip: Path, variant: str = "proposed") -> int:
    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.baselines import IndependentRecurrentPPO

    if variant == "independent":
        model = IndependentRecurrentPPO.load(model_zip, device="cpu").model
    else:
        model = LatentSwarmPPO.load(model_zip, device="cpu")
    state = model.policy.optimizer.state_dict()["state"]
    return int(next(iter(state.values()))["step"])


def test_a_warm_started_independent_baseline_continues_its_recurrent_ppo(tmp_path):
    earlier = _finished_smoke_sweep(tmp_path / "a", "independent")
    budget = earlier.point_preset({}).total_timesteps
    _finished_smoke_sweep(tmp_path / "b", "independent", warm_start=tmp_path / "a", total_timesteps=2 * budget)
    after = json.loads((tmp_path / "b" / "trials" / "independent-seed0" / "trial.json").read_text())
    assert after["warm_start"]["agent_steps"] == budget and after["trained_agent_steps"] >= 2 * budget
    steps = [_adam_steps(tmp_path / d / "trials" / "independent-seed0" / "model.zip", "independent") for d in "ab"]
    assert steps[1] == 2 * steps[0] > 0


def test_a_warm_started_sweep_continues_the_earlier_models(tmp_path):
    earlier = _finished_smoke_sweep(tmp_path / "a")
    budget = earlier.point_preset({}).total_timesteps
    spec = _finished_smoke_sweep(tmp_path / "b", warm_start=tmp_path / "a", total_timesteps=2 * budget)
    assert spec.warm_start == str((tmp_path / "a").resolve()) and spec.warm_start_depth == 1
    before, after = (json.loads((tmp_path / d / "trials" / "proposed-seed0" / "trial.json").read_text()) for d in "ab")
    assert after["warm_start"]["agent_steps"] == before["trained_agent_steps"] == budget
    assert after["trained_agent_steps"] == after["budget_agent_steps"] == 2 * budget
    # the continuation draws new env episodes: its copies are seeded WARM_START_SEED_STRIDE above the run's
    assert after["training_env_seeds"][0] == before["training_env_seeds"][0] + 500_000
    # the same optimizer, continued: Adam has taken the earlier run's gradient steps and as many again
    steps = [_adam_steps(tmp_path / d / "trials" / "proposed-seed0" / "model.zip") for d in "ab"]
    assert steps[1] == 2 * steps[0] > 0
    # progress.csv: the earlier run's rows unchanged, then the continuation's
    rows = [pd.read_csv(tmp_path / d / "trials" / "proposed-seed0" / "progress.csv") for d in "ab"]
    assert rows[1]["agent_steps"].tolist() == [120.0, 240.0, 360.0, 480.0]
    pd.testing.assert_frame_equal(rows[1].iloc[:2], rows[0], check_like=True)
    write_report(tmp_path / "b")
    assert f"warm start: 1 of 1 trials continue the models of ['{tmp_path / 'a'}'] from 240 agent-steps" in (
        tmp_path / "b" / "run.md"
    ).read_text()


def test_a_warm_start_that_cannot_continue_is_refused_before_training(tmp_path):
    _finished_smoke_sweep(tmp_path / "a")
    budget = SweepSpec.create("smoke", 1).point_preset({}).total_timesteps
    with pytest.raises(ValueError, match="as many agent-steps as this sweep.s budget"):
        SweepSpec.create("smoke", 1, variants=["proposed"], warm_start=tmp_path / "a")
    p_fail = SweepSpec.create("smoke", 1).point_preset({}).config.p_fail
    differ = rf"\{{'proposed-seed0': \{{'p_fail': \({p_fail}, 0.5\)\}}\}}"
    with pytest.raises(ValueError, match=rf"other settings than this sweep's \(there, here\): {differ}"):
        SweepSpec.create("smoke", 1, variants=["proposed"], overrides={"p_fail": 0.5}, warm_start=tmp_path / "a",
                         total_timesteps=2 * budget)
    with pytest.raises(ValueError, match=r"other settings \(grid: \{\} there, \{'p_fail': \[0.5\]\} here\)"):
        SweepSpec.create("smoke", 1, variants=["proposed"], grid={"p_fail": [0.5]}, warm_start=tmp_path / "a",
                         total_timesteps=2 * budget)
    with pytest.raises(ValueError, match=r"not finished there: \['no_comm-seed0', 'proposed-seed1', 'no_comm-seed1'\]"):
        SweepSpec.create("smoke", 2, variants=["proposed", "no_comm"], warm_start=tmp_path / "a", total_timesteps=2 * budget)
    with pytest.raises(ValueError, match=r"not finished there: \['independent-seed0'\]"):
        SweepSpec.create("smoke", 1, variants=["independent"], warm_start=tmp_path / "a", total_timesteps=2 * budget)
    with pytest.raises(ValueError, match="no sweep.json"):
        SweepSpec.create("smoke", 1, variants=["proposed"], warm_start=tmp_path, total_timesteps=2 * budget)
    with pytest.raises(ValueError, match="--total-timesteps"):
        SweepSpec.create("smoke", 1, total_timesteps=0)


def test_a_warm_start_compares_the_settings_the_earlier_trials_trained_with_not_todays_preset(tmp_path):
    # as if the preset's default had changed since the earlier sweep trained (issue 21 changed coordination's epochs)
    _finished_smoke_sweep(tmp_path / "a")
    record_path = tmp_path / "a" / "trials" / "proposed-seed0" / "trial.json"
    record = json.loads(record_path.read_text())
    record["algo_kwargs"]["n_epochs"] = 2
    record_path.write_text(json.dumps(record))
    budget = SweepSpec.create("smoke", 1).point_preset({}).total_timesteps
    with pytest.raises(ValueError, match=r"\{'n_epochs': \(2, 1\)\}.*for example --set n_epochs=2\)"):
        SweepSpec.create("smoke", 1, variants=["proposed"], warm_start=tmp_path / "a", total_timesteps=2 * budget)
    spec = SweepSpec.create("smoke", 1, variants=["proposed"], overrides={"n_epochs": 2}, warm_start=tmp_path / "a",
                            total_timesteps=2 * budget)
    assert spec.point_preset({}).algo_kwargs["n_epochs"] == 2


def test_a_warm_start_from_trials_older_than_an_opt_in_field_takes_the_field_at_its_default(tmp_path):
    # random_corner_round2's trials were recorded before link_model, message_delay, ... existed: absent means the
    # field's default (an extension's default is the earlier behaviour); a non-default value here still differs
    _finished_smoke_sweep(tmp_path / "a")
    record_path = tmp_path / "a" / "trials" / "proposed-seed0" / "trial.json"
    record = json.loads(record_path.read_text())
    for key in ("link_model", "message_delay", "message_expiry"):
        del record["train_config"][key]
    record_path.write_text(json.dumps(record))
    budget = SweepSpec.create("smoke", 1).point_preset({}).total_timesteps
    SweepSpec.create("smoke", 1, variants=["proposed"], warm_start=tmp_path / "a", total_timesteps=2 * budget)
    with pytest.raises(ValueError, match=r"'message_delay': \(None, 2\)"):
        SweepSpec.create("smoke", 1, variants=["proposed"], overrides={"message_delay": 2}, warm_start=tmp_path / "a",
                         total_timesteps=2 * budget)


def test_a_spec_written_before_budget_and_warm_start_existed_loads(tmp_path):
    spec = SweepSpec.create("smoke", 1, variants=["proposed"])
    old = {k: v for k, v in spec.to_dict().items() if k not in ("total_timesteps", "warm_start")}
    (tmp_path / "sweep.json").write_text(json.dumps(old))
    assert SweepSpec.load(tmp_path / "sweep.json") == spec


def test_a_continuation_of_a_continuation_needs_a_later_eval_seed(tmp_path):
    earlier = _finished_smoke_sweep(tmp_path / "a")
    budget = earlier.point_preset({}).total_timesteps
    _finished_smoke_sweep(tmp_path / "b", warm_start=tmp_path / "a", total_timesteps=2 * budget)
    # the second continuation seeds its env copies from 2 * 500,000 on: the default evaluation seeds would overlap them
    with pytest.raises(ValueError, match="give --eval-seed 1000002 or larger"):
        SweepSpec.create("smoke", 1, variants=["proposed"], warm_start=tmp_path / "b", total_timesteps=3 * budget)
    spec = SweepSpec.create(
        "smoke", 1, variants=["proposed"], warm_start=tmp_path / "b", total_timesteps=3 * budget, eval_seed=2_000_000
    )
    assert spec.warm_start_depth == 2
