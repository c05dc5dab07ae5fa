"""The one run path (:mod:`sb3_latentswarm.runs.run`): new, resume and warm start; ``train`` and sweep trials use it."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.cli import main
from sb3_latentswarm.presets import get_preset
from sb3_latentswarm.runs.checkpoints import CheckpointError, estimate_checkpoint_bytes, list_checkpoints
from sb3_latentswarm.runs.run import Run, RunHooks, RunSpec, RunStopped, find_start, required_room

SMOKE = get_preset("smoke")
PER_UPDATE = SMOKE.agent_steps_per_update  # 120 agent-steps


def train(output: Path, hooks: RunHooks | None = None, **spec) -> tuple[Run, object]:
    with Run(output) as run:
        result = run.train(RunSpec(SMOKE, output, device="cpu", **spec), hooks)
    return run, result


class SignalInSecondUpdate(RunHooks):
    """Sends this process SIGINT in the middle of the second rollout, as a user's Ctrl-C would."""

    class _Kill(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == PER_UPDATE + PER_UPDATE // 2:
                os.kill(os.getpid(), signal.SIGINT)
            return True

    def callbacks(self):
        return [self._Kill()]


def parameters(model) -> dict[str, th.Tensor]:
    return model.policy.state_dict()


def test_a_stopped_run_resumes_to_the_parameters_of_one_that_never_stopped(tmp_path):
    budget = 3 * PER_UPDATE
    with pytest.raises(RunStopped) as stopped:
        train(tmp_path / "a", SignalInSecondUpdate(), seed=1, total_timesteps=budget, save_freq=0)
    assert stopped.value.signum == signal.SIGINT and stopped.value.exit_code == 130 and not stopped.value.saved
    assert stopped.value.checkpoint == find_start(tmp_path / "a")
    assert stopped.value.checkpoint.name == f"checkpoint_{PER_UPDATE}_steps.zip"  # the rollout in progress is dropped
    assert not (tmp_path / "a" / "model.zip").exists()

    with Run(tmp_path / "a") as run:
        assert run.state["num_timesteps"] == PER_UPDATE
        with pytest.raises(CheckpointError, match="holds checkpoints"):  # never silently over an earlier run
            run.train(RunSpec(SMOKE, tmp_path / "a", seed=1, total_timesteps=budget, device="cpu"))
    run, resumed = train(tmp_path / "a", seed=1, total_timesteps=budget, resume=True)
    assert resumed.resumed_from == PER_UPDATE and resumed.trained_steps == budget
    _, reference = train(tmp_path / "b", seed=1, total_timesteps=budget)
    assert reference.resumed_from is None
    for key, value in parameters(reference.model).items():
        assert th.equal(value, parameters(resumed.model)[key]), key
    assert {p.name for p in (tmp_path / "a").iterdir()} == {"model.zip", "config.json", "progress.csv", "checkpoints"}


def test_a_warm_start_continues_the_model_optimizer_and_step_count(tmp_path):
    _, first = train(tmp_path / "a", seed=0)
    with pytest.raises(ValueError, match="not fewer than the run's budget"):
        train(tmp_path / "b", warm_start=first.model_path, seed=5)
    _, second = train(tmp_path / "c", warm_start=first.model_path, seed=5, total_timesteps=2 * SMOKE.total_timesteps)
    assert second.trained_steps == 2 * SMOKE.total_timesteps and second.resumed_from is None

    def adam_steps(path: Path) -> int:
        state = LatentSwarmPPO.load(path, device="cpu").policy.optimizer.state_dict()["state"]
        return int(next(iter(state.values()))["step"])

    assert adam_steps(second.model_path) == 2 * adam_steps(first.model_path) > 0


def test_train_and_a_sweep_trial_go_through_the_same_run(tmp_path, monkeypatch):
    from sb3_latentswarm.experiments import SweepSpec, plan_trials, train_and_evaluate

    specs: list[RunSpec] = []
    train_run = Run.train

    def recording(self, spec, hooks=None):
        specs.append(spec)
        return train_run(self, spec, hooks)

    monkeypatch.setattr(Run, "train", recording)
    assert main(["train", "--preset", "smoke", "--output", str(tmp_path / "cli"), "--no-progress"]) == 0
    sweep = SweepSpec.create("smoke", 1, variants=["proposed", "independent"], eval_episodes=1)
    for trial in plan_trials(sweep, commit="test"):
        train_and_evaluate(trial, tmp_path / trial["trial_id"], device="cpu")
    assert [(spec.output.name, spec.learner, spec.run_files) for spec in specs] == [
        ("cli", "latent_swarm_ppo", True),
        ("proposed-seed0", "latent_swarm_ppo", False),
        ("independent-seed0", "independent_ppo", False),
    ]
    assert list_checkpoints(tmp_path / "proposed-seed0" / "checkpoints")  # the trial's checkpoints, as train's
    assert not (tmp_path / "independent-seed0" / "checkpoints").exists()


def test_one_free_space_rule(tmp_path):
    with Run(tmp_path) as run:
        assert run.start is None and run.state is None
    model = SMOKE.make_model(SMOKE.make_env(0), device="cpu")
    assert required_room(model) == 2 * estimate_checkpoint_bytes(model)  # a new checkpoint before the oldest goes
    with pytest.raises(ValueError, match="learner must be one of"):
        RunSpec(SMOKE, tmp_path, learner="dqn").check()
    with pytest.raises(ValueError, match="no checkpoints to resume"):
        RunSpec(SMOKE, tmp_path, learner="independent_ppo", resume=True).check()
