"""Model files are plain data: loading one runs no code from it, unless the caller trusts pickles explicitly."""

import base64
import json
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.utils import LinearSchedule

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env
from sb3_latentswarm.baselines import IndependentRecurrentPPO
from sb3_latentswarm.cli import main
from sb3_latentswarm.common.schedules import StepSchedule
from sb3_latentswarm.common.serialization import UnsafeModelFileError, read_data
from sb3_latentswarm.evaluation import evaluate

ROOT = Path(__file__).resolve().parents[1]
SMALL = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=30, num_obstacles=5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)


def make_model(**kwargs):
    params = dict(n_steps=20, chunk_length=5, batch_size=30, n_epochs=1, policy_kwargs=TINY_POLICY, seed=0)
    return LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(2, config=SMALL, seed=0), **{**params, **kwargs})


class Payload:
    """Unpickling this writes a marker file: what a hostile model file would do."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",)


def rewrite_data(source: Path, target: Path, change) -> Path:
    with zipfile.ZipFile(source) as original, zipfile.ZipFile(target, "w") as out:
        for item in original.infolist():
            content = original.read(item.filename)
            if item.filename == "data":
                data = json.loads(content)
                change(data)
                content = json.dumps(data).encode()
            out.writestr(item, content)
    return target


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "model.zip"
    make_model().save(path)
    return path


@pytest.fixture
def hostile(saved, tmp_path):
    """A real model file whose swarm_config entry is an SB3-style cloudpickle blob carrying :class:`Payload`."""
    marker = tmp_path / "marker"
    blob = base64.b64encode(pickle.dumps(Payload(marker))).decode()
    entry = {":type:": "<class 'sb3_latentswarm.config.SwarmConfig'>", ":serialized:": blob}
    return rewrite_data(saved, tmp_path / "hostile.zip", lambda data: data.update(swarm_config=entry)), marker


def test_hostile_file_is_refused_by_load_and_runs_its_code_only_when_trusted(hostile):
    path, marker = hostile
    with pytest.raises(UnsafeModelFileError, match=r"trust_pickle=True"):
        LatentSwarmPPO.load(path)
    assert not marker.exists()
    with pytest.raises(ValueError, match="trust_pickle=True"):
        evaluate(str(path), n_episodes=1)
    with pytest.raises(ValueError, match="trust_pickle=True"):
        IndependentRecurrentPPO.load(path)
    assert not marker.exists()
    # the payload is live: a caller who trusts the file runs it (which is why that must be asked for)
    try:
        LatentSwarmPPO.load(path, trust_pickle=True)
    except Exception:  # noqa: BLE001 - the payload replaced swarm_config; only the side effect matters here
        pass
    assert marker.read_text() == "pwned"


@pytest.mark.parametrize("command", ["evaluate", "render"])
def test_hostile_file_is_refused_by_the_cli(hostile, command, tmp_path, capsys):
    path, marker = hostile
    extra = ["--episodes", "1", "--no-baselines"] if command == "evaluate" else ["--output", str(tmp_path / "e.gif")]
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--model", str(path), "--preset", "smoke", *extra])
    assert exit_info.value.code == 2
    assert "--trust-pickle" in capsys.readouterr().err
    assert not marker.exists()


def test_saved_files_hold_no_pickle_no_machine_path_and_round_trip(tmp_path):
    log_dir = tmp_path / "machine_specific_tb"
    model = make_model(
        learning_rate=StepSchedule(3e-4, 1e-5, 0.5), clip_range=LinearSchedule(0.3, 0.1, 1.0), tensorboard_log=str(log_dir)
    )
    model.learn(120)
    path = tmp_path / "model.zip"
    model.save(path)
    raw, pickled = read_data(path)
    assert pickled == []
    assert str(tmp_path) not in json.dumps(raw) and raw["tensorboard_log"] is None
    loaded = LatentSwarmPPO.load(path)
    assert loaded.tensorboard_log is None
    assert repr(loaded.learning_rate) == repr(model.learning_rate)
    assert [loaded.clip_range(p) for p in (1.0, 0.5, 0.0)] == pytest.approx([0.3, 0.2, 0.1])
    assert loaded.swarm_config == SMALL and loaded.num_timesteps == model.num_timesteps
    obs = model.env.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    # a schedule given as a plain function cannot be stored: saved as its current value, with a warning
    model.learning_rate = lambda progress: 1e-3 * progress
    with pytest.warns(UserWarning, match="learning_rate is a function"):
        model.save(tmp_path / "lambda.zip")
    # here training has ended (progress_remaining 0): a constant 0 would not load, so the initial value is kept
    assert model._current_progress_remaining <= 0
    assert LatentSwarmPPO.load(tmp_path / "lambda.zip").learning_rate == pytest.approx(1e-3)
    model._current_progress_remaining = 0.5
    with pytest.warns(UserWarning, match="saved as its current value 0.0005"):
        model.save(tmp_path / "lambda.zip")
    assert LatentSwarmPPO.load(tmp_path / "lambda.zip").learning_rate == pytest.approx(5e-4)


def test_load_overrides_pass_the_constructor_checks(saved):
    with pytest.raises(ValueError, match="map_coef"):
        LatentSwarmPPO.load(saved, map_coef=-5)
    with pytest.raises(ValueError, match="batch_size must hold at least one whole swarm"):
        LatentSwarmPPO.load(saved, batch_size=10)
    with pytest.raises(TypeError, match="unknown keyword argument.*valid: .*learning_rate"):
        LatentSwarmPPO.load(saved, learning_rat=1e-3)
    assert LatentSwarmPPO.load(saved, n_epochs=3, tensorboard_log="tb").n_epochs == 3


def test_committed_models_are_plain_data_and_load_by_default():
    files = sorted((ROOT / "docs" / "results").glob("*/*.zip"))
    assert files
    for path in files:
        assert read_data(path)[1] == [], path
    model = LatentSwarmPPO.load(ROOT / "docs" / "results" / "fast_1800_updates" / "model.zip", device="cpu")
    assert model.num_timesteps == 25_920_000 and model.tensorboard_log is None
    IndependentRecurrentPPO.load(ROOT / "docs" / "results" / "fast_1800_updates" / "independent_ppo.zip", device="cpu")


def test_files_of_another_save_format_fail_clearly(saved, tmp_path):
    assert LatentSwarmPPO.load(saved).save_format == 2
    newer = rewrite_data(saved, tmp_path / "newer.zip", lambda d: d.update(save_format=99, saved_by_version="9.0.0"))
    with pytest.raises(ValueError, match="saved by a newer sb3-latentswarm \\(9.0.0, save format 99\\)"):
        LatentSwarmPPO.load(newer)
    foreign = rewrite_data(saved, tmp_path / "foreign.zip", lambda d: d.pop("save_format"))
    with pytest.raises(ValueError, match="not saved by LatentSwarmPPO"):
        LatentSwarmPPO.load(foreign)
