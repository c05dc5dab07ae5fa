"""``sb3-latentswarm train --seeds K --jobs J``: one single-thread ``train`` process per seed, resumable."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch as th

import sb3_latentswarm.utils.threads
from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.cli import main
from sb3_latentswarm.runs.train_seeds import (
    SEEDS_RECORD,
    SeedRun,
    child_environment,
    last_coverage,
    run_seed_processes,
    seed_state,
)

ROOT = Path(__file__).resolve().parents[1]
SMOKE_FILES = {"model.zip", "config.json", "progress.csv", "checkpoints"}  # what one smoke `train` writes


def parameters(path: Path) -> dict[str, th.Tensor]:
    return LatentSwarmPPO.load(path, device="cpu").policy.state_dict()


def run_main(*argv: str) -> tuple[int, str, str]:
    """``main(argv)`` with its output captured (``SystemExit`` -> its code)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(argv))
        except SystemExit as exit_:
            code = exit_.code
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(autouse=True)
def children_run_this_checkout(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(ROOT))


@pytest.fixture(scope="module")
def two_seeds(tmp_path_factory) -> tuple[Path, str, str]:
    """``train --preset smoke --seeds 2 --jobs 2`` on a process that may run on one core (so it warns)."""
    output = tmp_path_factory.mktemp("seeds") / "run"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("PYTHONPATH", str(ROOT))
        patch.setattr(sb3_latentswarm.utils.threads, "available_cores", lambda: 1)
        code, out, err = run_main("train", "--preset", "smoke", "--seeds", "2", "--jobs", "2", "--output", str(output))
    assert code == 0, out + err
    return output, out, err


def test_two_seeds_with_two_jobs_write_two_complete_seed_folders_whose_models_differ(two_seeds, tmp_path):
    output, out, err = two_seeds
    assert {p.name for p in output.iterdir()} == {SEEDS_RECORD, "seed0", "seed1"}
    assert f"If stopped, resume with: sb3-latentswarm train --resume --output {output}" in out
    for seed in (0, 1):
        folder = output / f"seed{seed}"
        assert {p.name for p in folder.iterdir()} == SMOKE_FILES | {"train.log"}
        log = (folder / "train.log").read_text()
        # the sweep's rule: seed k's n_envs = 2 copies are 2k, 2k + 1
        assert f"--seed {seed} --env-seed {2 * seed} " in log.splitlines()[0]
        assert f"seed {seed} (env copies {2 * seed}..{2 * seed + 1})" in log
        assert f"seed {seed}: trained in" in out and "s CPU, last rollout coverage" in out
    first, second = parameters(output / "seed0" / "model.zip"), parameters(output / "seed1" / "model.zip")
    assert any(not th.equal(first[key], second[key]) for key in first)
    assert "--jobs 2 runs 2 torch thread(s) at once, but this process may run on 1 core(s)" in err

    # a seed folder holds what the single-seed train with its env seed writes, with the same model
    single = tmp_path / "single"
    argv = ["train", "--preset", "smoke", "--seed", "1", "--env-seed", "2", "--output", str(single), "--no-progress"]
    assert main(argv) == 0
    assert {p.name for p in single.iterdir()} == SMOKE_FILES
    assert all(th.equal(value, second[key]) for key, value in parameters(single / "model.zip").items())

    record = json.loads((output / SEEDS_RECORD).read_text())
    assert record["seeds"] == 2 and record["settings"]["preset"] == "smoke" and record["settings"]["seed"] == 0
    assert record["env_seeds"] == {"0": [0, 1], "1": [2, 3]} and "env_seed" not in record["settings"]
    for seed in ("0", "1"):
        result = record["results"][seed]
        assert result["status"] == "trained" and result["exit_code"] == 0 and result["cpu_seconds"] > 0
        assert result["coverage"] == last_coverage(output / f"seed{seed}")


def test_rerun_skips_finished_seeds_continues_unfinished_ones_and_names_a_failed_seed(two_seeds, tmp_path):
    output = tmp_path / "run"
    shutil.copytree(two_seeds[0], output)
    finished = (output / "seed0" / "model.zip").read_bytes()
    reference = parameters(output / "seed1" / "model.zip")

    code, _, err = run_main("train", "--preset", "smoke", "--seeds", "2", "--output", str(output))
    assert code == 2 and "holds the seeds of an earlier run" in err and "--resume" in err
    code, out, _ = run_main("train", "--resume", "--output", str(output))
    assert code == 0 and "seed 0: already trained, skipped" in out and "seed 1: already trained, skipped" in out

    # seed 1 lost its model (stopped after its last checkpoint); seed 2 is new and has a broken checkpoint
    (output / "seed1" / "model.zip").unlink()
    (output / "seed2" / "checkpoints").mkdir(parents=True)
    (output / "seed2" / "checkpoints" / "checkpoint_120_steps.zip").write_bytes(b"not a zip")
    code, out, err = run_main("train", "--resume", "--seeds", "3", "--output", str(output), "--no-progress")
    assert code == 1
    assert "seed 0: already trained, skipped" in out and (output / "seed0" / "model.zip").read_bytes() == finished
    assert "seed 1: continuing from its newest checkpoint" in out and "seed 1: trained in" in out
    assert all(th.equal(value, reference[key]) for key, value in parameters(output / "seed1" / "model.zip").items())
    assert f"seed 2: exit code 2, log {output / 'seed2' / 'train.log'}" in err and "is not a checkpoint" in err
    assert "train --resume --output" in err
    record = json.loads((output / SEEDS_RECORD).read_text())
    assert record["seeds"] == 3 and record["results"]["2"]["status"] == "failed"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--seeds", "0"], "--seeds: expected an int >= 1, got '0'"),
        (["--seeds", "2", "--jobs", "0"], "--jobs: expected an int >= 1, got '0'"),
        (["--seeds", "2", "--set", "p_fail=1.5"], "p_fail must be a finite number in [0.0, 1.0]"),
        (["--seeds", "2", "--set", "n_steps=0"], "n_steps"),
        # seed 2's copies are 4, 5 (the sweep's rule), not 2, 3
        (["--seeds", "3", "--evaluate", "--eval-seed", "5"], "overlap the training env copies' seeds 4-5"),
        (["--evaluate", "--env-seed", "3", "--eval-seed", "4"], "overlap the training env copies' seeds 3-4"),
        (["--env-seed", "-1"], "--env-seed: expected an int >= 0, got '-1'"),
        (["--env-seed", "1.5"], "--env-seed: expected an int >= 0, got '1.5'"),
        (["--seeds", "2", "--env-seed", "3"], "--env-seed 3 with --seeds"),
        (["--seeds", "2", "--resume"], "no run of train --seeds in"),
    ],
)
def test_bad_arguments_fail_before_any_file_is_written(tmp_path, argv, message):
    output = tmp_path / "run"
    code, out, err = run_main("train", "--preset", "smoke", "--output", str(output), *argv)
    assert code == 2 and message in err and "started" not in out
    assert not output.exists()


def test_folders_holding_other_runs_are_refused_before_any_process_starts(two_seeds, tmp_path):
    taken = tmp_path / "file"
    taken.write_text("a file")
    code, _, err = run_main("train", "--preset", "smoke", "--seeds", "2", "--output", str(taken))
    assert code == 2 and "is an existing file, not a folder" in err

    single = tmp_path / "single"
    (single / "checkpoints").mkdir(parents=True)
    shutil.copy(next((two_seeds[0] / "seed0" / "checkpoints").iterdir()), single / "checkpoints")
    code, _, err = run_main("train", "--preset", "smoke", "--seeds", "2", "--output", str(single))
    assert code == 2 and "holds a single-seed run" in err

    stray = tmp_path / "stray"
    shutil.copytree(two_seeds[0] / "seed1", stray / "seed1")
    code, _, err = run_main("train", "--preset", "smoke", "--seeds", "2", "--output", str(stray))
    assert code == 2 and f"{stray / 'seed1'} holds an earlier run" in err
    assert sorted(p.name for p in stray.iterdir()) == ["seed1"]

    copy = tmp_path / "copy"
    shutil.copytree(two_seeds[0], copy)
    code, _, err = run_main("train", "--resume", "--seed", "5", "--output", str(copy))
    assert code == 2 and "seed (seeds.json: 0, command: 5)" in err
    # a larger budget extends a single run, not a --seeds run (whose finished seeds would be skipped)
    code, _, err = run_main("train", "--resume", "--total-timesteps", "100000", "--output", str(copy))
    assert code == 2 and f"train --resume --output {copy}/seedN --total-timesteps 100000" in err


def test_neighbouring_seeds_env_copies_share_no_reset_seed(two_seeds):
    """Copy 1 of seed 0 and copy 0 of seed 1 start from different seeds (with ``--seed`` alone they were one stream)."""
    from sb3_latentswarm.presets import get_preset

    record = json.loads((two_seeds[0] / SEEDS_RECORD).read_text())
    copies = [set(range(first, last + 1)) for first, last in record["env_seeds"].values()]
    assert len(copies) == 2 and not copies[0] & copies[1]
    preset = get_preset("smoke")
    agents = preset.config.n_agents

    def reset(base: int, copy: int) -> dict:
        env = preset.make_env(base)
        try:
            return {key: value[copy * agents:(copy + 1) * agents] for key, value in env.reset().items()}
        finally:
            env.close()

    seed0_copy1, seed1_copy0 = reset(record["env_seeds"]["0"][0], 1), reset(record["env_seeds"]["1"][0], 0)
    assert any(not np.array_equal(seed0_copy1[key], seed1_copy0[key]) for key in seed0_copy1)
    old_seed1_copy0 = reset(1, 0)  # train --seed 1: copy 0 seeded 1, copy 1 of seed 0 too
    assert all(np.array_equal(seed0_copy1[key], old_seed1_copy0[key]) for key in seed0_copy1)


def test_a_single_train_seed_keeps_its_env_copies_and_resume_keeps_the_env_seed(tmp_path):
    from sb3_latentswarm.runs.checkpoints import latest_checkpoint, list_checkpoints, read_checkpoint_state

    output = tmp_path / "run"
    argv = ["train", "--preset", "smoke", "--seed", "1", "--total-timesteps", "240", "--save-freq", "120"]
    code, out, _ = run_main(*argv, "--output", str(output), "--no-progress")
    assert code == 0 and "seed 1 (env copies 1..2)" in out  # unchanged: copy k gets --seed + k
    assert f"If stopped, resume with: sb3-latentswarm train --resume --output {output}" in out
    reference = parameters(output / "model.zip")
    assert read_checkpoint_state(latest_checkpoint(output / "checkpoints"))["settings"]["env_seed"] == 1

    # the same run with --env-seed 1 is the same model; stopped after its first update, it resumes on the same envs
    other = tmp_path / "other"
    assert run_main(*argv, "--env-seed", "1", "--output", str(other), "--no-progress")[0] == 0
    assert all(th.equal(value, reference[key]) for key, value in parameters(other / "model.zip").items())
    (other / "model.zip").unlink()
    latest_checkpoint(other / "checkpoints").unlink()
    assert len(list_checkpoints(other / "checkpoints")) == 1
    code, _, err = run_main("train", "--resume", "--env-seed", "5", "--output", str(other))
    assert code == 2 and "env_seed (checkpoint: 1, command: 5)" in err
    code, out, _ = run_main("train", "--resume", "--output", str(other), "--no-progress")
    assert code == 0 and "seed 1 (env copies 1..2)" in out
    assert all(th.equal(value, reference[key]) for key, value in parameters(other / "model.zip").items())


def test_a_checkpoint_from_before_env_seed_resumes_on_copies_of_its_seed():
    import argparse

    from sb3_latentswarm.cli.settings import train_settings

    args = argparse.Namespace(preset=None, set=None, seed=None, env_seed=None, total_timesteps=None, backend=None,
                              output="run")
    stored = {"preset": "smoke", "set": [], "seed": 3, "total_timesteps": 240, "backend": "batched"}
    assert train_settings(args, stored)["env_seed"] == 3
    assert train_settings(args)["env_seed"] == 0  # a new run: --seed's default
    args.env_seed = 4
    with pytest.raises(ValueError, match=r"env_seed \(checkpoint: 3, command: 4\)"):
        train_settings(args, stored)


def test_the_resume_command_uses_the_name_the_user_ran(monkeypatch):
    import importlib.metadata

    from sb3_latentswarm.cli import resume_command

    scripts = [importlib.metadata.EntryPoint("swarm", "sb3_latentswarm.cli:main", "console_scripts"),
               importlib.metadata.EntryPoint("other", "another.cli:main", "console_scripts")]
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: scripts)
    for argv0, name in [("/venv/bin/swarm", "swarm"), ("/venv/bin/swarm.exe", "swarm"),
                        ("/venv/bin/other", "sb3-latentswarm"), ("/x/sb3_latentswarm/cli.py", "sb3-latentswarm"),
                        ("", "sb3-latentswarm")]:
        monkeypatch.setattr(sys, "argv", [argv0])
        assert resume_command(Path("runs/a b")) == f"{name} train --resume --output 'runs/a b'"


def test_one_seed_keeps_the_single_run_layout(tmp_path):
    output = tmp_path / "run"
    code, out, _ = run_main("train", "--preset", "smoke", "--seeds", "1", "--output", str(output), "--no-progress")
    assert code == 0 and "Training preset 'smoke'" in out
    assert {p.name for p in output.iterdir()} == SMOKE_FILES


def test_seed_state_and_last_coverage(tmp_path):
    assert seed_state(tmp_path) == "new" and last_coverage(tmp_path) is None
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "checkpoint_120_steps.zip").write_bytes(b"")
    assert seed_state(tmp_path) == "unfinished"
    (tmp_path / "model.zip").write_bytes(b"")
    assert seed_state(tmp_path) == "finished" and seed_state(tmp_path, evaluate=True) == "unfinished"
    (tmp_path / "conditions.csv").write_text("")
    assert seed_state(tmp_path, evaluate=True) == "finished"
    (tmp_path / "progress.csv").write_text("time/total_timesteps,rollout/coverage\n120,0.25\n240,\n360,0.5\n480,\n")
    assert last_coverage(tmp_path) == 0.5
    assert child_environment(1)["OMP_NUM_THREADS"] == "1" and child_environment(1)["MKL_NUM_THREADS"] == "1"


@dataclass(frozen=True)
class ScriptRun(SeedRun):
    """A :class:`SeedRun` whose process is a Python snippet instead of ``train``."""

    script: str = ""

    @property
    def command(self) -> list[str]:
        return [sys.executable, "-c", self.script]


def test_run_seed_processes_keeps_at_most_jobs_running_and_reports_exit_codes(tmp_path):
    running, most = set(), [0]

    def started(run):
        running.add(run.seed)
        most[0] = max(most[0], len(running))

    def finished(result):
        running.discard(result.seed)

    runs = [ScriptRun(seed, tmp_path / f"seed{seed}", ("x",), script="import time; time.sleep(0.3)") for seed in range(3)]
    runs.append(ScriptRun(3, tmp_path / "seed3", ("x",), script="import sys; print('boom'); sys.exit(3)"))
    results, signum = run_seed_processes(runs, jobs=2, on_start=started, on_finish=finished, poll_seconds=0.05)
    assert signum is None and most[0] == 2
    assert [(r.seed, r.status, r.exit_code) for r in results] == [(0, "trained", 0), (1, "trained", 0), (2, "trained", 0),
                                                                  (3, "failed", 3)]
    assert all(r.cpu_seconds is not None and r.wall_seconds >= 0 for r in results)
    assert (tmp_path / "seed3" / "train.log").read_text().splitlines() == ["$ sb3-latentswarm x", "boom"]
    with pytest.raises(ValueError, match="jobs must be an int in"):
        run_seed_processes(runs, jobs=0)


@pytest.mark.slow  # three seeds of 40 updates on two processes, stopped, then resumed: about a minute at load 3
def test_sigint_stops_every_seed_at_a_checkpoint_and_resume_finishes_them(tmp_path):
    output = tmp_path / "run"
    argv = ["train", "--preset", "smoke", "--seeds", "3", "--jobs", "2", "--total-timesteps", "4800", "--save-freq", "120"]
    process = subprocess.Popen(
        [sys.executable, "-m", "sb3_latentswarm.cli", *argv, "--output", str(output), "--tensorboard", str(tmp_path / "tb")],
        env={**child_environment(1), "PYTHONPATH": str(ROOT)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not all(any((output / f"seed{s}" / "checkpoints").glob("*.zip")) for s in (0, 1)):
        assert time.monotonic() < deadline and process.poll() is None
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130, out + err
    assert "seed(s) 2 not started" in err and f"sb3-latentswarm train --resume --output {output}" in err
    assert "Traceback" not in err and not (output / "seed2").exists()
    for seed in (0, 1):
        assert not (output / f"seed{seed}" / "model.zip").exists()
        assert "Stopped by SIGINT" in (output / f"seed{seed}" / "train.log").read_text()

    code, out, err = run_main("train", "--resume", "--output", str(output))
    assert code == 0, out + err
    for seed in (0, 1, 2):
        rows = list(csv.DictReader((output / f"seed{seed}" / "progress.csv").open()))
        assert [int(row["time/total_timesteps"]) for row in rows] == [120 * k for k in range(1, 41)]
        assert (output / f"seed{seed}" / "model.zip").is_file()
        # each seed logs into a TensorBoard folder of its own, one run each (continued in place on resume)
        assert [p.name for p in (tmp_path / "tb" / f"seed{seed}").iterdir()] == ["latentswarm_smoke_1"]
