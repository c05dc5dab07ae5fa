"""Runs nobody can corrupt (issue 34): the output-folder lock, checkpoints read under the model-file rules, the choice
of the newest valid checkpoint, and the related file checks. The crafted-checkpoint table is the one of
``benchmarks/hostile_checkpoints.py``; a seeded subset runs here."""

from __future__ import annotations

import importlib.util
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from sb3_latentswarm.experiments import SweepSpec
from sb3_latentswarm.experiments.spec import MAX_GRID_POINTS
from sb3_latentswarm.latent_ppo.model_file import read_data
from sb3_latentswarm.runs.checkpoints import (
    CheckpointError,
    StopOnSignal,
    list_checkpoints,
    newest_valid_checkpoint,
    resume_tensorboard,
)
from sb3_latentswarm.utils.atomic import check_real_path, read_json
from sb3_latentswarm.utils.locks import LOCK_NAME, OutputInUseError, output_lock

ROOT = Path(__file__).resolve().parents[1]


def _load_benchmark():
    path = ROOT / "benchmarks" / "hostile_checkpoints.py"
    spec = importlib.util.spec_from_file_location("benchmark_hostile_checkpoints", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


hostile = _load_benchmark()
CASES = {case.name: case for case in hostile.cases()}
_crafted = [name for name, case in CASES.items() if case.group not in ("damage", "fault")]
SUBSET = sorted(set(random.Random(34).sample(_crafted, 60)) | {
    "model widths 4096", "model n_steps 2,000,000 (rollout buffer)", "model 5000-digit integer",
    "duplicate state.json (second names a TensorBoard folder)", "bit_generator 'exec'", "tensorboard_log ABS",
    "core n_covered -117", "num_timesteps=-1", "model p_fail edited (env of another config)",
    "arrays.npz with a pickled object array", "tensors.pth with a pickled payload",
})


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile") / "sandbox"
    return root, hostile.train_base(root / "base")


# ---------------------------------------------------------------------------------------------- the lock
HOLD = ("import sys; from sb3_latentswarm.utils.locks import output_lock\n"
        "with output_lock(sys.argv[1]):\n    print('held', flush=True); sys.stdin.read()")


def _holder(folder: Path) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], env={**os.environ, "PYTHONPATH": str(ROOT)},
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_a_second_writer_is_refused_naming_the_folder_and_the_holder_and_a_dead_holder_never_blocks(tmp_path):
    holder = _holder(tmp_path / "run")
    try:
        with pytest.raises(OutputInUseError, match=rf"{tmp_path / 'run'} is in use by another run \(pid {holder.pid} "):
            with output_lock(tmp_path / "run"):
                pass
    finally:
        holder.kill()  # kill -9: the kernel releases the flock; the file it leaves does not block
        holder.wait()
    assert (tmp_path / "run" / LOCK_NAME).exists()
    with output_lock(tmp_path / "run") as folder:
        with output_lock(folder):  # re-entrant in one process (a run evaluating into its own folder)
            pass
        assert f"pid {os.getpid()}" in (folder / LOCK_NAME).read_text()
    assert not (tmp_path / "run" / LOCK_NAME).exists()  # removed at the end


def test_a_run_refused_before_writing_leaves_neither_its_folder_nor_new_parents(tmp_path):
    (tmp_path / "kept").mkdir()
    with pytest.raises(ValueError, match="refused"):
        with output_lock(tmp_path / "kept" / "new" / "deeper" / "run"):
            raise ValueError("refused")  # e.g. an env that fails its checks after the lock is taken
    assert (tmp_path / "kept").is_dir() and list((tmp_path / "kept").iterdir()) == []
    with output_lock(tmp_path / "kept" / "a" / "run") as folder:
        (folder / "model.zip").write_bytes(b"x")  # a run that wrote something keeps its folders
    assert (tmp_path / "kept" / "a" / "run" / "model.zip").exists()


def test_taking_the_lock_removes_temporaries_of_interrupted_writes_and_nothing_else(tmp_path):
    stale = [tmp_path / ".model.ab12cd34.tmp.zip", tmp_path / "checkpoints" / ".checkpoint_120_steps.x1y2z3w4.tmp.zip",
             tmp_path / ".write-probe.q1w2e3r4", tmp_path / ".progress.mn34op56.tmp.csv"]
    kept = [tmp_path / "model.zip", tmp_path / ".hidden", tmp_path / "notes.tmp.txt", tmp_path / "checkpoints" / "a.zip"]
    for path in stale + kept:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x")
    other_run = tmp_path / "other_run"  # another output folder, held by its own run: never touched
    (other_run / "checkpoints").mkdir(parents=True)
    (other_run / LOCK_NAME).write_text("pid 1")
    in_progress = other_run / "checkpoints" / ".checkpoint_240_steps.ab12cd34.tmp.zip"
    in_progress.write_bytes(b"being written")
    with output_lock(tmp_path):
        pass
    assert not any(p.exists() for p in stale) and all(p.exists() for p in kept) and in_progress.exists()


def test_an_output_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match="is an existing file"):
        with output_lock(tmp_path / "f"):
            pass


def test_two_writers_into_one_folder_give_one_clear_refusal_and_one_intact_run(tmp_path, base):
    _, checkpoints = base
    outcome, detail = hostile.fault_concurrent_runs(tmp_path, checkpoints)
    assert outcome == "clear error", detail


# ---------------------------------------------------------------------------------------------- crafted checkpoints
@pytest.mark.parametrize("name", SUBSET)
def test_crafted_checkpoint(name, base):
    root, checkpoints = base
    case = CASES[name]
    outcome, detail = hostile.run_case(case, checkpoints, root, SUBSET.index(name))
    assert outcome == ("clear error" if case.refuse else "works"), detail


@pytest.mark.parametrize("fraction", [0.05, 0.5, 0.95])
def test_a_bit_flipped_newest_checkpoint_resumes_from_the_older_one_and_says_so(tmp_path, base, fraction):
    _, checkpoints = base
    hostile.bytes_damage(fraction)(tmp_path, checkpoints)
    lines: list[str] = []
    chosen, contents = newest_valid_checkpoint(list_checkpoints(tmp_path), report=lines.append)
    assert chosen.name == checkpoints[-2].name and contents.state["num_timesteps"] == 240
    assert len(lines) == 1 and checkpoints[-1].name in lines[0] and "resuming from the older" in lines[0]
    outcome, detail = hostile.resume_from(tmp_path, checkpoints)
    assert outcome == "works", detail


def test_no_valid_checkpoint_fails_naming_each(tmp_path, base):
    _, checkpoints = base
    for path in checkpoints:
        (tmp_path / path.name).write_bytes(path.read_bytes()[:200])
    with pytest.raises(CheckpointError, match="no valid checkpoint") as error:
        newest_valid_checkpoint(list_checkpoints(tmp_path), report=None)
    assert all(path.name in str(error.value) for path in checkpoints)


@pytest.mark.parametrize("name", [
    "a writer after a holder killed with kill -9", "a write that fails leaves the earlier checkpoints",
    "SIGHUP during training writes a checkpoint and stops", "a symlinked checkpoint is not a checkpoint",
    "a checkpoint passed to LatentSwarmPPO.load", "an env of another config", "all checkpoints damaged",
])
def test_fault(name, base):
    root, checkpoints = base
    case = CASES[name]
    outcome, detail = hostile.run_case(case, checkpoints, root, 1000 + list(CASES).index(name))
    assert outcome == ("clear error" if case.refuse else "works"), detail


def test_nothing_is_written_outside_the_output_folder(tmp_path, base):
    """A checkpoint naming TensorBoard folders outside the run (absolute, ``..``) makes the resumed run write nothing
    there: load_checkpoint takes no path from the file, and resume_tensorboard uses a stored folder only inside."""
    root, checkpoints = base
    for index, name in enumerate(n for n, case in CASES.items() if case.group == "paths"):
        outcome, detail = hostile.run_case(CASES[name], checkpoints, root, 2000 + index)
        assert outcome == "works", (name, detail)
    output = tmp_path / "run"
    assert resume_tensorboard(output, None, {"tensorboard": str(tmp_path / "elsewhere")}, "x")[:2] == (None, None)
    inside = str(output / "tb")
    assert resume_tensorboard(output, None, {"tensorboard": inside, "tensorboard_run": f"{inside}/x_3"}, "x") == (
        inside, f"{inside}/x_3", None)


def test_stop_on_signal_handles_sighup_like_sigterm():
    assert signal.SIGHUP in StopOnSignal.SIGNALS
    with StopOnSignal() as stop:
        os.kill(os.getpid(), signal.SIGHUP)
    assert stop.signum == signal.SIGHUP and stop.exit_code == 129


# ---------------------------------------------------------------------------------------------- model files and records
def test_a_checkpoint_given_as_a_model_names_load_checkpoint(base, capsys):
    from sb3_latentswarm.cli import main

    _, checkpoints = base
    with pytest.raises(SystemExit) as error:
        main(["evaluate", "--model", str(checkpoints[-1]), "--episodes", "1"])
    err = capsys.readouterr().err
    assert error.value.code == 2 and str(checkpoints[-1]) in err and "load_checkpoint" in err


def test_a_5000_digit_integer_in_a_model_file_is_refused_naming_the_file(tmp_path, base):
    _, checkpoints = base
    parts = hostile.read_parts(checkpoints[-1])
    path = tmp_path / "model.zip"
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in parts["model"].items():
            long = content.replace(b'"n_epochs": 1', b'"n_epochs": ' + b"9" * 5000)
            archive.writestr(name, long if name == "data" else content)
    with pytest.raises(ValueError, match=rf"{path}: its 'data' entry is not valid JSON \(an integer of 5000 digits"):
        read_data(path)


def test_damaged_records_name_their_file(tmp_path):
    for name in ("evaluation.json", "sweep.json", "trial.json"):
        (tmp_path / name).write_text('{"a": ')
        with pytest.raises(ValueError, match=rf"{tmp_path / name} is damaged: it is not valid JSON"):
            read_json(tmp_path / name)
    with pytest.raises(ValueError, match=rf"{tmp_path / 'sweep.json'} is not a sweep spec"):
        SweepSpec.load(tmp_path / "sweep.json")


def test_symlinks_in_a_result_folder_are_refused(tmp_path):
    (tmp_path / "sweep" / "trials").mkdir(parents=True)
    (tmp_path / "other").mkdir()
    (tmp_path / "sweep" / "trials" / "seed1").symlink_to(tmp_path / "other")
    with pytest.raises(ValueError, match="is a symlink .* must be a real folder inside"):
        check_real_path(tmp_path / "sweep" / "trials" / "seed1", tmp_path / "sweep", "trial folder")
    (tmp_path / "sweep" / "trials" / "seed0").mkdir()
    (tmp_path / "sweep" / "trials" / "seed0" / "model.zip").symlink_to(tmp_path / "other" / "model.zip")
    with pytest.raises(ValueError, match="model.zip is a symlink"):
        check_real_path(tmp_path / "sweep" / "trials" / "seed0" / "model.zip", tmp_path / "sweep", "trial's file")
    check_real_path(tmp_path / "sweep" / "trials" / "seed0", tmp_path / "sweep", "trial folder")


def test_a_grid_over_the_limit_is_refused_at_once():
    with pytest.raises(ValueError, match=rf"--grid has 10,000 points .* limit of {MAX_GRID_POINTS:,}"):
        SweepSpec.create("smoke", 1, grid={"p_fail": [i / 10_000 for i in range(10_000)]})


def test_provenance_names_the_package_checkout_not_the_current_folder(tmp_path):
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    code = "from sb3_latentswarm.experiments.run_record import git_commit; print(git_commit())"
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                         capture_output=True, text=True, check=True).stdout.strip()
    from sb3_latentswarm.version import __version__

    assert out.startswith(__version__)
    if (ROOT / ".git").exists() and shutil.which("git"):
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        assert f"commit {head.stdout.strip()}" in out


def test_state_json_round_trips_as_written(base):
    """The checks accept every checkpoint this package writes (no false refusal)."""
    _, checkpoints = base
    for path in checkpoints:
        chosen, contents = newest_valid_checkpoint([path], report=None)
        assert chosen == path and json.loads(json.dumps(contents.state)) == contents.state


CLI = "import sys; from sb3_latentswarm.cli import main; sys.exit(main())"


@pytest.mark.slow
def test_two_train_commands_into_one_folder_give_one_clear_refusal_and_one_intact_run(tmp_path):
    """The second ``train`` is refused at once naming the folder and the first's pid; the first, stopped later by
    SIGTERM, leaves a checkpoint that resumes and a clean progress.csv."""
    import time

    from sb3_latentswarm.runs.checkpoints import read_checkpoint

    output = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    argv = ["train", "--preset", "smoke", "--output", str(output), "--total-timesteps", "10000000", "--no-progress",
            "--save-freq", "120"]
    first = subprocess.Popen([sys.executable, "-c", CLI, *argv], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        deadline = time.time() + 240
        while not list_checkpoints(output / "checkpoints") and time.time() < deadline and first.poll() is None:
            time.sleep(0.5)
        assert list_checkpoints(output / "checkpoints"), first.communicate()
        second = subprocess.run([sys.executable, "-c", CLI, *argv], env=env, capture_output=True, text=True, timeout=240)
        assert second.returncode == 2
        assert f"error: {output} is in use by another run (pid {first.pid} " in second.stderr
        assert len(second.stderr.strip().splitlines()) == 1
        first.send_signal(signal.SIGTERM)
        _, err = first.communicate(timeout=240)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 143, err
    assert "train --resume --output" in err
    newest = list_checkpoints(output / "checkpoints")[-1]
    contents = read_checkpoint(newest)  # whole and valid
    assert contents.state["num_timesteps"] > 0
    progress = (output / "progress.csv").read_bytes()
    assert b"\0" not in progress and progress.endswith(b"\n")
    assert not (output / LOCK_NAME).exists()


@pytest.mark.slow
def test_sigterm_stops_a_sweep_cleanly_with_143_and_the_resume_command(tmp_path):
    """SIGTERM while trials run: Ray Tune stops them (no abort dump), the lock is released, exit 143, resume printed."""
    import time

    output = tmp_path / "sweep"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    argv = ["sweep", "--preset", "smoke", "--seeds", "1", "--variant", "proposed", "--total-timesteps", "1000000",
            "--output", str(output)]
    sweep = subprocess.Popen([sys.executable, "-c", CLI, *argv], env=env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 300
        while not list_checkpoints(output / "running" / "proposed-seed0" / "checkpoints") and time.time() < deadline:
            time.sleep(1)
        sweep.send_signal(signal.SIGTERM)
        _, err = sweep.communicate(timeout=300)
    finally:
        if sweep.poll() is None:
            sweep.kill()
    assert sweep.returncode == 143, err[-2000:]
    assert "stopped by SIGTERM" in err and f"--output {output} --resume" in err
    assert list_checkpoints(output / "running" / "proposed-seed0" / "checkpoints")  # the trial continues from here
    assert not (output / LOCK_NAME).exists()
