"""Checkpoints, resume, signals, atomic saves and evaluation records (docs/long_runs.md)."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_latentswarm import LatentSwarmPPO, make_vec_env
from sb3_latentswarm.cli import main
from sb3_latentswarm.latent_ppo import model_file as serialization
from sb3_latentswarm.latent_ppo.model_file import read_data
from sb3_latentswarm.presets import get_preset
from sb3_latentswarm.runs.checkpoints import (
    CheckpointError,
    SwarmCheckpointCallback,
    default_save_freq,
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    read_checkpoint_state,
)

ROOT = Path(__file__).resolve().parents[1]
SMOKE = get_preset("smoke")
PER_UPDATE = SMOKE.algo_kwargs["n_steps"] * SMOKE.n_envs * SMOKE.config.n_agents  # 120 agent-steps
CLI_UPDATES = 30


def smoke_model(seed: int = 3, **kwargs) -> LatentSwarmPPO:
    env = make_vec_env(SMOKE.n_envs, config=SMOKE.config, seed=seed)
    return LatentSwarmPPO("LatentSwarmPolicy", env, seed=seed, **{**SMOKE.algo_kwargs, **kwargs})


def assert_same_training_state(a: LatentSwarmPPO, b: LatentSwarmPPO) -> None:
    for key, value in a.policy.state_dict().items():
        assert th.equal(value, b.policy.state_dict()[key]), key
    states_a, states_b = a.policy.optimizer.state_dict()["state"], b.policy.optimizer.state_dict()["state"]
    for group_a, group_b in zip(states_a.values(), states_b.values()):
        for name in group_a:
            assert th.equal(group_a[name], group_b[name]), name
    assert (a.num_timesteps, a._n_updates, a._current_progress_remaining) == (
        b.num_timesteps,
        b._n_updates,
        b._current_progress_remaining,
    )


def model_parameters(path: Path) -> dict[str, th.Tensor]:
    return LatentSwarmPPO.load(path, device="cpu").policy.state_dict()


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "sb3_latentswarm.cli", *args]


def subprocess_env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def wait_for(condition, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.05)


# ---------------------------------------------------------------------------------------------- Python API
def test_resume_from_a_checkpoint_equals_the_uninterrupted_run(tmp_path):
    total = 5 * PER_UPDATE
    uninterrupted = smoke_model()
    callback = SwarmCheckpointCallback(PER_UPDATE, tmp_path, keep=10)
    uninterrupted.learn(total, callback=callback)
    assert [p.name for p in list_checkpoints(tmp_path)] == [f"checkpoint_{k * PER_UPDATE}_steps.zip" for k in range(1, 6)]

    # stopped after update 2, resumed for the remaining 3: the same bits as the run that never stopped
    checkpoint = tmp_path / f"checkpoint_{2 * PER_UPDATE}_steps.zip"
    resumed = load_checkpoint(checkpoint, env=make_vec_env(SMOKE.n_envs, config=SMOKE.config, seed=99))
    assert resumed.num_timesteps == 2 * PER_UPDATE and resumed._n_updates == 2 * SMOKE.algo_kwargs["n_epochs"]
    resumed.learn(total - resumed.num_timesteps, reset_num_timesteps=False)
    assert_same_training_state(uninterrupted, resumed)
    for key, value in uninterrupted._last_obs.items():
        np.testing.assert_array_equal(value, resumed._last_obs[key])

    # training ended inside a rollout (here by another callback): the state at that rollout's start is written
    class StopMidRollout(BaseCallback):
        def _on_step(self) -> bool:
            return self.num_timesteps < 2 * PER_UPDATE + PER_UPDATE // 2

    cut = tmp_path / "cut"
    smoke_model().learn(total, callback=[StopMidRollout(), SwarmCheckpointCallback(0, cut)])
    (written,) = list_checkpoints(cut)
    assert written.name == f"checkpoint_{2 * PER_UPDATE}_steps.zip"
    again = load_checkpoint(written, env=make_vec_env(SMOKE.n_envs, config=SMOKE.config, seed=99))
    again.learn(total - again.num_timesteps, reset_num_timesteps=False)
    assert_same_training_state(uninterrupted, again)

    # a checkpoint is plain data: the model entry has no pickle, arrays and tensors are read without unpickling
    with zipfile.ZipFile(checkpoint) as archive:
        assert sorted(archive.namelist()) == ["arrays.npz", "model.zip", "state.json", "tensors.pth"]
        assert read_data(io.BytesIO(archive.read("model.zip")))[1] == []
    assert read_checkpoint_state(checkpoint)["num_timesteps"] == 2 * PER_UPDATE


def test_the_supersuit_backend_resumes_from_new_episodes(tmp_path):
    def supersuit_env():
        return make_vec_env(SMOKE.n_envs, config=SMOKE.config, seed=3, backend="supersuit")

    model = LatentSwarmPPO("LatentSwarmPolicy", supersuit_env(), seed=3, **SMOKE.algo_kwargs)
    model.learn(2 * PER_UPDATE, callback=SwarmCheckpointCallback(PER_UPDATE, tmp_path))
    resumed = load_checkpoint(latest_checkpoint(tmp_path), env=supersuit_env())
    assert resumed._last_obs is None  # its env copies could not be saved: new episodes at the next learn
    for key, value in model.policy.state_dict().items():
        assert th.equal(value, resumed.policy.state_dict()[key]), key
    resumed.learn(PER_UPDATE, reset_num_timesteps=False)
    assert resumed.num_timesteps == 3 * PER_UPDATE


def test_checkpoint_callback_keeps_the_newest_k_and_checks_its_arguments(tmp_path):
    model = smoke_model()
    model.learn(4 * PER_UPDATE, callback=SwarmCheckpointCallback(PER_UPDATE, tmp_path, keep=2))
    assert [p.name for p in list_checkpoints(tmp_path)] == [f"checkpoint_{k * PER_UPDATE}_steps.zip" for k in (3, 4)]
    with pytest.raises(ValueError, match="keep"):
        SwarmCheckpointCallback(PER_UPDATE, tmp_path, keep=0)
    with pytest.raises(TypeError, match="save_freq"):
        SwarmCheckpointCallback(1.5, tmp_path)  # type: ignore[arg-type]
    assert default_save_freq(100 * PER_UPDATE, PER_UPDATE) == 5 * PER_UPDATE  # 5 % of the budget, whole updates
    assert default_save_freq(PER_UPDATE // 2, PER_UPDATE) == PER_UPDATE


def test_a_checkpoint_refuses_an_env_that_does_not_fit(tmp_path):
    model = smoke_model()
    model.learn(PER_UPDATE, callback=SwarmCheckpointCallback(PER_UPDATE, tmp_path))
    with pytest.raises(CheckpointError, match="slots|swarms"):
        load_checkpoint(latest_checkpoint(tmp_path), env=make_vec_env(3, config=SMOKE.config))
    (tmp_path / "checkpoint_999_steps.zip").write_bytes(b"not a zip")
    with pytest.raises(CheckpointError, match="not a checkpoint"):
        read_checkpoint_state(tmp_path / "checkpoint_999_steps.zip")


def test_progress_csv_resumes_after_the_checkpoint_without_a_row_cut_off_by_a_kill(tmp_path):
    from sb3_latentswarm.runs.checkpoints import ResumableCSVOutputFormat

    path = tmp_path / "progress.csv"
    path.write_text("a,time/total_timesteps\n1,120\n2,240\n3,360\n4,48")  # killed while writing the 4th row
    writer = ResumableCSVOutputFormat(path, resume_step=240)
    writer.write({"a": 5, "time/total_timesteps": 360}, {"a": None, "time/total_timesteps": None})
    writer.close()
    assert path.read_text() == "a,time/total_timesteps\n1,120\n2,240\n5,360\n"


def test_tensorboard_continues_in_the_same_run_folder_after_load(tmp_path, monkeypatch):
    pytest.importorskip("tensorboard")
    monkeypatch.chdir(tmp_path)
    model = smoke_model(tensorboard_log="tb")  # relative: kept in the model file, as SB3 keeps it
    model.learn(PER_UPDATE)
    model.save("model.zip")
    loaded = LatentSwarmPPO.load("model.zip", env=make_vec_env(SMOKE.n_envs, config=SMOKE.config, seed=1))
    assert loaded.tensorboard_log == "tb"
    loaded.learn(PER_UPDATE, reset_num_timesteps=False)
    (run,) = Path("tb").iterdir()
    assert run.name == "LatentSwarmPPO_1" and len(list(run.glob("events.out.tfevents.*"))) == 2


def test_a_failed_save_leaves_the_previous_model_intact(tmp_path, monkeypatch):
    model = smoke_model()
    path = tmp_path / "model.zip"
    model.save(path)
    good = path.read_bytes()

    def full_disk(save_path, *args, **kwargs):
        Path(save_path).write_bytes(b"PK" + b"\0" * 1000)  # a partial file, as a full disk leaves it
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(serialization, "save_to_zip_file", full_disk)
    with pytest.raises(OSError, match="No space"):
        model.save(path)
    assert path.read_bytes() == good and sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]
    monkeypatch.undo()
    LatentSwarmPPO.load(path)


# ---------------------------------------------------------------------------------------------- the CLI
@pytest.fixture(scope="module")
def uninterrupted_cli_run(tmp_path_factory) -> Path:
    output = tmp_path_factory.mktemp("uninterrupted")
    args = ["train", "--preset", "smoke", "--total-timesteps", str(CLI_UPDATES * PER_UPDATE), "--no-progress"]
    assert main([*args, "--save-freq", str(PER_UPDATE), "--output", str(output)]) == 0
    return output


# SIGKILL (no checkpoint written at the kill) trains three times: 10 s at load 5, so slow; SIGINT stays fast
@pytest.mark.parametrize("signum", [signal.SIGINT, pytest.param(signal.SIGKILL, marks=pytest.mark.slow)])
def test_cli_stopped_mid_training_resumes_to_the_uninterrupted_model(tmp_path, signum, uninterrupted_cli_run):
    output = tmp_path / "run"
    command = ["train", "--preset", "smoke", "--total-timesteps", str(CLI_UPDATES * PER_UPDATE), "--output", str(output)]
    process = subprocess.Popen(
        cli(*command, "--save-freq", str(PER_UPDATE), "--no-progress", "--tensorboard", str(output / "tb")),
        env=subprocess_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    wait_for(lambda: latest_checkpoint(output / "checkpoints") is not None)
    process.send_signal(signum)
    _, err = process.communicate(timeout=120)
    stopped = read_checkpoint_state(latest_checkpoint(output / "checkpoints"))["num_timesteps"]
    assert 0 < stopped < CLI_UPDATES * PER_UPDATE and not (output / "model.zip").exists()
    if signum == signal.SIGINT:
        assert process.returncode == 130
        assert "Traceback" not in err and "Error" not in err
        assert f"sb3-latentswarm train --resume --output {output}" in err

    assert main(["train", "--resume", "--output", str(output), "--no-progress"]) == 0
    resumed, reference = model_parameters(output / "model.zip"), model_parameters(uninterrupted_cli_run / "model.zip")
    for key, value in reference.items():
        assert th.equal(value, resumed[key]), key
    # the learning curve continues in the same progress.csv: every update once, in order
    every_update = [k * PER_UPDATE for k in range(1, CLI_UPDATES + 1)]
    steps = [int(row["time/total_timesteps"]) for row in csv.DictReader((output / "progress.csv").open())]
    assert steps == every_update
    # and in the same TensorBoard run folder, whose resumed events file purges what was logged after the checkpoint
    # (TensorBoard reads the files in the order of the timestamps in their names; this VM's clock can step back, so
    # the test checks the content, not TensorBoard's ordering)
    from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

    (run,) = (output / "tb").iterdir()
    events = [event for path in run.glob("events.out.tfevents.*") for event in EventFileLoader(str(path)).Load()]
    coverage = {event.step for event in events for value in event.summary.value if value.tag == "rollout/coverage"}
    assert coverage == set(every_update)
    assert [event.step for event in events if event.HasField("session_log")] == [stopped + 1]


def test_cli_resume_refuses_other_settings_and_a_run_folder_is_not_reused(tmp_path, capsys):
    output = str(tmp_path / "run")
    with pytest.raises(SystemExit):
        main(["train", "--resume", "--output", output])
    assert "no checkpoint in" in capsys.readouterr().err and not Path(output).exists()
    assert main(["train", "--preset", "smoke", "--output", output, "--no-progress"]) == 0
    with pytest.raises(SystemExit):
        main(["train", "--resume", "--output", output, "--seed", "7", "--set", "p_fail=0.5"])
    err = capsys.readouterr().err
    assert "seed (checkpoint: 0, command: 7)" in err and "p_fail=0.5" in err
    with pytest.raises(SystemExit):
        main(["train", "--preset", "smoke", "--output", output])
    assert "holds the checkpoints of an earlier run" in capsys.readouterr().err
    assert main(["train", "--resume", "--output", output, "--preset", "smoke"]) == 0  # complete: saved again, 0
    assert "nothing to train" in capsys.readouterr().out


def test_cli_resume_with_a_larger_budget_trains_the_run_on(tmp_path, capsys):
    from sb3_latentswarm import LatentSwarmPPO

    output = str(tmp_path / "run")
    budget = 2 * PER_UPDATE
    assert main(["train", "--preset", "smoke", "--output", output, "--no-progress", "--total-timesteps", str(budget)]) == 0
    with pytest.raises(SystemExit):  # a smaller budget than the run's is another run
        main(["train", "--resume", "--output", output, "--total-timesteps", str(PER_UPDATE)])
    assert f"total_timesteps (checkpoint: {budget}, command: {PER_UPDATE})" in capsys.readouterr().err
    assert main(["train", "--resume", "--output", output, "--no-progress", "--total-timesteps", str(2 * budget)]) == 0
    assert f"budget grows from {budget:,} to {2 * budget:,}" in capsys.readouterr().out
    assert LatentSwarmPPO.load(Path(output) / "model.zip", device="cpu").num_timesteps == 2 * budget
    progress = pd.read_csv(Path(output) / "progress.csv")
    assert progress["time/total_timesteps"].tolist() == [PER_UPDATE * k for k in range(1, 5)]
    # the extended budget is the run's now: a plain --resume keeps it
    assert main(["train", "--resume", "--output", output, "--no-progress"]) == 0
    assert f"at {2 * budget:,} of {2 * budget:,} agent-steps" in capsys.readouterr().out


def test_cli_a_checkpoint_that_cannot_be_written_keeps_the_earlier_ones(tmp_path, capsys, monkeypatch):
    import sb3_latentswarm.runs.checkpoints as checkpoints

    write, calls = checkpoints.write_bytes, []

    def disk_full_on_the_second(path, data):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        write(path, data)

    monkeypatch.setattr(checkpoints, "write_bytes", disk_full_on_the_second)
    output = tmp_path / "run"
    args = ["train", "--preset", "smoke", "--total-timesteps", str(5 * PER_UPDATE), "--save-freq", str(PER_UPDATE)]
    assert main([*args, "--output", str(output), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and f"train --resume --output {output}" in err
    (kept,) = list_checkpoints(output / "checkpoints")
    assert read_checkpoint_state(kept)["num_timesteps"] == PER_UPDATE and not (output / "model.zip").exists()
    monkeypatch.undo()
    assert main(["train", "--resume", "--output", str(output), "--no-progress"]) == 0


def test_cli_unwritable_or_full_output_fails_before_training(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("a regular file")
    with pytest.raises(SystemExit):
        main(["train", "--preset", "smoke", "--output", str(blocker / "run")])
    captured = capsys.readouterr()
    assert "not writable" in captured.err and "Training preset" not in captured.out

    # a size limit below one checkpoint (a full disk, as the process sees it): refused before training, and the good
    # model.zip already in the folder survives
    output = tmp_path / "run"
    output.mkdir()
    smoke_model().save(output / "model.zip")
    good = (output / "model.zip").read_bytes()

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (200 * 1024, resource.RLIM_INFINITY))

    result = subprocess.run(
        cli("train", "--preset", "demo", "--total-timesteps", "640", "--output", str(output)),
        env=subprocess_env(),
        capture_output=True,
        text=True,
        preexec_fn=limit,
    )
    assert result.returncode == 2 and "no room" in result.stderr and "Training preset" not in result.stdout
    assert (output / "model.zip").read_bytes() == good and sorted(p.name for p in output.iterdir()) == ["model.zip"]


def test_cli_evaluations_record_the_model_hash_and_never_mix(tmp_path, capsys, monkeypatch):
    first, second = tmp_path / "a", tmp_path / "b"
    for folder, seed in ((first, "0"), (second, "7")):
        assert main(["train", "--preset", "smoke", "--seed", seed, "--output", str(folder), "--no-progress"]) == 0
    evaluate = ["evaluate", "--no-baselines", "--episodes", "1", "--no-progress"]
    tables = tmp_path / "tables"
    assert main([*evaluate, "--model", str(first / "model.zip"), "--output", str(tables), "--p-fail-sweep"]) == 0
    record = json.loads((tables / "evaluation.json").read_text())
    assert record["model_sha256"] == hashlib.sha256((first / "model.zip").read_bytes()).hexdigest()
    assert set(record["tables"]) == {"conditions", "p_fail_sweep"} and record["env_seeds"] == [1_000_000, 1_000_000]
    assert record["tables"]["p_fail_sweep"]["p_fails"] == list(SMOKE.p_fails)
    before = {p.name: p.read_bytes() for p in tables.iterdir()}

    # another model into the same folder: refused, naming the folder and what differs; nothing is touched
    with pytest.raises(SystemExit):
        main([*evaluate, "--model", str(second / "model.zip"), "--output", str(tables)])
    err = capsys.readouterr().err
    assert str(tables) in err and "model_sha256" in err
    assert {p.name: p.read_bytes() for p in tables.iterdir()} == before
    # the same model again without the sweep: the same evaluation, the sweep's table is kept and still recorded
    assert main([*evaluate, "--model", str(first / "model.zip"), "--output", str(tables)]) == 0
    assert set(json.loads((tables / "evaluation.json").read_text())["tables"]) == {"conditions", "p_fail_sweep"}

    # a model file replaced under the same path: the default folder is kept, the new tables go to a new one
    assert main([*evaluate, "--model", str(first / "model.zip")]) == 0
    shutil.copy(second / "model.zip", first / "model.zip")
    assert main([*evaluate, "--model", str(first / "model.zip")]) == 0
    assert "holds another evaluation's tables" in capsys.readouterr().out
    assert len(list(first.glob("evaluation-*"))) == 1

    # an interrupted evaluation keeps (and records) the tables it finished
    import sb3_latentswarm.evaluation as evaluation

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluation, "evaluate_p_fail_sweep", interrupted)
    partial = tmp_path / "partial"
    assert main([*evaluate, "--model", str(second / "model.zip"), "--output", str(partial), "--p-fail-sweep"]) == 130
    assert (partial / "conditions.csv").exists() and not (partial / "p_fail_sweep.csv").exists()
    assert set(json.loads((partial / "evaluation.json").read_text())["tables"]) == {"conditions"}


# ---------------------------------------------------------------------------------------------- sweep trials
TRIAL_SCRIPT = textwrap.dedent(
    """
    import json, sys, time
    from pathlib import Path
    from sb3_latentswarm.runs.checkpoints import SwarmCheckpointCallback
    from sb3_latentswarm.experiments import SweepSpec
    from sb3_latentswarm.experiments.trial import train_and_evaluate

    write = SwarmCheckpointCallback.write

    def write_then_hang(self):  # the first checkpoint is on disk: wait there to be killed
        path = write(self)
        print("CHECKPOINT", flush=True)
        time.sleep(600)
        return path

    SwarmCheckpointCallback.write = write_then_hang
    trial = json.loads(sys.argv[1])
    train_and_evaluate({**trial, "spec": SweepSpec.from_dict(trial["spec"])}, Path(sys.argv[2]), device="cpu")
    """
)


def smoke_trial() -> dict:
    from sb3_latentswarm.experiments import SweepSpec, plan_trials

    spec = SweepSpec.create("smoke", 1, variants=["proposed"], eval_episodes=1)
    return plan_trials(spec, commit="test")[0]


def test_a_trial_killed_mid_way_resumes_from_its_checkpoint(tmp_path):
    from sb3_latentswarm.experiments.trial import train_and_evaluate

    trial = smoke_trial()
    work = tmp_path / "work"
    process = subprocess.Popen(
        [sys.executable, "-c", TRIAL_SCRIPT, json.dumps({**trial, "spec": trial["spec"].to_dict()}), str(work)],
        env=subprocess_env(),
        stdout=subprocess.PIPE,
        text=True,
    )
    assert process.stdout.readline().strip() == "CHECKPOINT"
    process.kill()  # kill -9
    process.wait(timeout=60)
    assert not (work / "trial.json").exists()
    stopped = read_checkpoint_state(latest_checkpoint(work / "checkpoints"))["num_timesteps"]
    assert 0 < stopped < SMOKE.total_timesteps

    record = train_and_evaluate(trial, work, device="cpu")
    assert record["resumed_from_agent_steps"] == stopped and record["trained_agent_steps"] == SMOKE.total_timesteps
    reference = tmp_path / "reference"
    assert train_and_evaluate(trial, reference, device="cpu")["resumed_from_agent_steps"] is None
    for key, value in model_parameters(reference / "model.zip").items():
        assert th.equal(value, model_parameters(work / "model.zip")[key]), key
    for name in ("progress.csv", "episodes.csv"):
        assert (work / name).read_text() == (reference / name).read_text(), name

    other = {**trial, "train_seed": 1, "trial_id": "proposed-seed1"}
    with pytest.raises(CheckpointError, match="another trial"):
        train_and_evaluate(other, work, device="cpu")
