"""Model files are plain data: loading one runs no code from it, unless the caller trusts pickles explicitly."""

import base64
import json
import pickle
import runpy
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from stable_baselines3.common.utils import LinearSchedule

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env
from sb3_latentswarm.baselines import IndependentRecurrentPPO
from sb3_latentswarm.cli import main
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.latent_ppo.model_file import UnsafeModelFileError, read_data
from sb3_latentswarm.latent_ppo.schedules import StepSchedule

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "tests" / "data" / "models"  # weight-only copies of committed models (examples/weight_only_models.py)
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
    # a rule over every committed model file, wherever the results folders are (none is needed by name)
    files = sorted((ROOT / "tests" / "data" / "models").glob("*.zip")) + sorted((ROOT / "docs" / "results").rglob("*.zip"))
    assert files
    for path in files:
        assert read_data(path)[1] == [], path
    model = LatentSwarmPPO.load(MODELS / "fast_1800_updates.zip", device="cpu")
    assert model.num_timesteps == 25_920_000 and model.tensorboard_log is None
    IndependentRecurrentPPO.load(MODELS / "fast_1800_updates-independent_ppo.zip", device="cpu")


# ---------------------------------------------------------------------------------------------- weight-only files
def test_a_weight_only_file_loads_evaluates_alike_and_warns_once_when_training(tmp_path):
    model = make_model()
    model.learn(40)
    model.save(tmp_path / "full.zip")
    model.save(tmp_path / "weights.zip", include_optimizer=False)
    with zipfile.ZipFile(tmp_path / "weights.zip") as weights, zipfile.ZipFile(tmp_path / "full.zip") as full:
        assert set(full.namelist()) - set(weights.namelist()) == {"policy.optimizer.pth"}
    assert (tmp_path / "weights.zip").stat().st_size < 0.5 * (tmp_path / "full.zip").stat().st_size
    loaded = LatentSwarmPPO.load(tmp_path / "weights.zip", env=make_vec_env(2, config=SMALL, seed=0))
    for name, tensor in model.policy.state_dict().items():
        assert loaded.policy.state_dict()[name].equal(tensor), name
    kwargs = dict(n_episodes=2, seed=7, deterministic=False)
    pd.testing.assert_frame_equal(evaluate(loaded, "proposed", **kwargs), evaluate(model, "proposed", **kwargs))
    with pytest.warns(UserWarning, match="weight-only file .* the optimizer starts fresh"):
        loaded.learn(40, reset_num_timesteps=False)
    assert loaded.policy.optimizer.state  # Adam has moments now: the next learn continues them, silently
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*weight-only.*")
        loaded.learn(40, reset_num_timesteps=False)
    # a file with its optimizer state trains on without the warning
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*weight-only.*")
        LatentSwarmPPO.load(tmp_path / "full.zip", env=make_vec_env(2, config=SMALL, seed=0)).learn(40)


def test_a_weight_only_file_must_still_hold_the_policy(tmp_path):
    make_model().save(tmp_path / "weights.zip", include_optimizer=False)
    with zipfile.ZipFile(tmp_path / "weights.zip") as original, zipfile.ZipFile(tmp_path / "empty.zip", "w") as out:
        for item in original.infolist():
            if item.filename != "policy.pth":
                out.writestr(item, original.read(item.filename))
    with pytest.raises(ValueError, match="no policy weights"):
        LatentSwarmPPO.load(tmp_path / "empty.zip")


def test_the_fixture_script_copies_every_entry_but_the_optimizer_state(tmp_path):
    script = runpy.run_path(str(ROOT / "examples" / "weight_only_models.py"))
    model = make_model()
    for source in script["FIXTURES"].values():  # a small stand-in at each source path
        model.save(tmp_path / "repo" / source)
    script["main"](script["Args"](output=tmp_path / "out", source_root=tmp_path / "repo"))
    for name, source in script["FIXTURES"].items():
        with zipfile.ZipFile(tmp_path / "repo" / source) as full, zipfile.ZipFile(tmp_path / "out" / name) as copy:
            assert set(full.namelist()) - set(copy.namelist()) == {"policy.optimizer.pth"}
            assert all(copy.read(entry) == full.read(entry) for entry in copy.namelist())
    loaded = LatentSwarmPPO.load(tmp_path / "out" / next(iter(script["FIXTURES"])))
    for name, tensor in model.policy.state_dict().items():
        assert loaded.policy.state_dict()[name].equal(tensor), name
    with pytest.raises(SystemExit, match="git checkout 206f0d5"):
        script["main"](script["Args"](output=tmp_path / "out", source_root=tmp_path / "nowhere"))


def test_the_weight_only_fixtures_are_the_committed_models_without_their_optimizer():
    paths = sorted(MODELS.glob("*.zip"))
    assert [p.name for p in paths] == sorted(runpy.run_path(str(ROOT / "examples" / "weight_only_models.py"))["FIXTURES"])
    for path in paths:
        with zipfile.ZipFile(path) as fixture:
            assert "policy.optimizer.pth" not in fixture.namelist() and "policy.pth" in fixture.namelist(), path
    assert sum(p.stat().st_size for p in paths) < 4 * 2**20  # small enough to keep in the repository


def test_files_of_another_save_format_fail_clearly(saved, tmp_path):
    assert LatentSwarmPPO.load(saved).save_format == 2
    newer = rewrite_data(saved, tmp_path / "newer.zip", lambda d: d.update(save_format=99, saved_by_version="9.0.0"))
    with pytest.raises(ValueError, match="saved by a newer sb3-latentswarm \\(9.0.0, save format 99\\)"):
        LatentSwarmPPO.load(newer)
    foreign = rewrite_data(saved, tmp_path / "foreign.zip", lambda d: d.pop("save_format"))
    with pytest.raises(ValueError, match="not saved by LatentSwarmPPO"):
        LatentSwarmPPO.load(foreign)


# ---------------------------------------------------------------------------------------------- hostile plain data
def rewrite_entry(source: Path, target: Path, name: str, content: bytes) -> Path:
    with zipfile.ZipFile(source) as original, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as out:
        for item in original.infolist():
            out.writestr(item, content if item.filename == name else original.read(item.filename))
    return target


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(set_parameters={"__torch_class__": "Identity"}), "entry 'set_parameters' is not an attribute"),
        (lambda d: d.update(save={"__schedule__": "constant", "value": 0}), "data entry 'save' is not an attribute"),
        (lambda d: d.update(predict="x"), "data entry 'predict' is not an attribute"),
        (lambda d: d.update(_setup_model=1), "data entry '_setup_model' is not an attribute"),
        (lambda d: d.update(device="cuda"), "data entry 'device' is not an attribute"),
        (lambda d: d.update(learning_rate=float("inf")), "learning_rate"),
        (lambda d: d.update(clip_range={"__schedule__": "constant", "value": float("nan")}), "data entry 'clip_range'"),
        (lambda d: d.update(target_kl=float("nan")), "data entry 'target_kl' must be None or a finite number"),
        (lambda d: d.update(save_format="2"), "data entry 'save_format' must be an int, got str"),
        (lambda d: d.update(n_agents=0), "data entry 'n_agents' must be an int >= 1"),
        (lambda d: d.update(n_agents=2), "data entry 'n_agents' is 2 but the observation 'link_row' has length 3"),
        (lambda d: d.pop("policy_class"), "no 'policy_class'"),
        (lambda d: d.update(policy_class={"__torch_class__": "Identity"}), "'policy_class' must be one of"),
        (lambda d: d.update(num_timesteps="many"), "data entry 'num_timesteps' must be an int >= 0"),
        (lambda d: d.update(policy_kwargs={"latent_dim": 10**6}), r"policy_kwargs\['latent_dim'\] must be at most 4096"),
        (lambda d: d["observation_space"]["spaces"]["global_map"].update(shape=[4000, 4000]) or
         d["observation_space"]["spaces"]["global_map"]["low"].update(shape=[4000, 4000]), "more than the limit"),
        (lambda d: d.update(ep_info_buffer={"__deque__": [], "maxlen": 10**12}), "maxlen"),
    ],
)
def test_plain_files_hold_only_what_save_writes(saved, tmp_path, change, message):
    path = rewrite_data(saved, tmp_path / "changed.zip", change)
    with pytest.raises(ValueError, match=message) as error:
        LatentSwarmPPO.load(path)
    assert str(path) in str(error.value)


def test_deep_nesting_and_a_huge_data_entry_are_refused(saved, tmp_path):
    nested = "[" * 100_000 + "]" * 100_000
    deep = rewrite_entry(saved, tmp_path / "deep.zip", "data", json.dumps({"plain_format": 1, "save_format": 2})[:-1].encode()
                         + b', "x": ' + nested.encode() + b"}")
    with pytest.raises(ValueError, match="nested deeper than the limit of 32"):
        LatentSwarmPPO.load(deep)
    with zipfile.ZipFile(saved) as archive:
        content = archive.read("data")
    big = rewrite_entry(saved, tmp_path / "big.zip", "data", content[:-1] + b" " * (9 * 2**20) + b"}")
    with pytest.raises(ValueError, match="'data' entry is 9,4.* bytes, more than the limit"):
        LatentSwarmPPO.load(big)
    garbage = rewrite_entry(saved, tmp_path / "notjson.zip", "data", b"\x00\xff not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        LatentSwarmPPO.load(garbage)


def test_a_huge_n_steps_allocates_no_rollout_buffer_without_an_env(saved, tmp_path):
    path = rewrite_data(saved, tmp_path / "steps.zip", lambda d: d.update(n_steps=2_000_000))
    model = LatentSwarmPPO.load(path)  # 4 GiB of buffer if it were allocated here
    assert getattr(model, "rollout_buffer", None) is None
    obs = make_vec_env(1, config=SMALL, seed=0).reset()
    assert model.predict(obs, deterministic=True)[0].shape == (3, 4)


def _rewrite_weights(saved: Path, target: Path, change) -> Path:
    import io

    import torch as th

    with zipfile.ZipFile(saved) as archive:
        weights = th.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    change(weights)
    buffer = io.BytesIO()
    th.save(weights, buffer)
    return rewrite_entry(saved, target, "policy.pth", buffer.getvalue())


def test_weights_are_checked_for_dtype_shape_and_finiteness(saved, tmp_path):
    import torch as th

    name = next(iter(LatentSwarmPPO.load(saved).policy.state_dict()))
    cases = [
        (lambda w: w.update({name: w[name].to(th.int64)}), f"policy.pth\\['{name}'\\] must be a torch.float32 tensor"),
        (lambda w: w.update({name: w[name].fill_(float("nan"))}), "holds NaN or infinite values"),
        (lambda w: w.update({name: w[name][:1]}), "of shape"),
        (lambda w: w.pop(name), "missing tensors"),
    ]
    for k, (change, message) in enumerate(cases):
        with pytest.raises(ValueError, match=message):
            LatentSwarmPPO.load(_rewrite_weights(saved, tmp_path / f"w{k}.zip", change))
    garbage = rewrite_entry(saved, tmp_path / "garbage.zip", "policy.pth", b"garbage" * 100)
    with pytest.raises(ValueError, match="cannot be read as plain tensors") as error:
        LatentSwarmPPO.load(garbage)
    assert "weights_only" not in str(error.value)


def test_pickled_file_claiming_the_plain_save_format_gets_a_consistent_message(saved, tmp_path):
    import cloudpickle

    blob = base64.b64encode(cloudpickle.dumps(SMALL)).decode()
    entry = {":type:": "<class 'sb3_latentswarm.config.SwarmConfig'>", ":serialized:": blob}
    path = rewrite_data(saved, tmp_path / "pickled2.zip", lambda data: data.update(swarm_config=entry))
    with pytest.raises(ValueError, match="holds pickled entries but declares save format 2") as error:
        LatentSwarmPPO.load(path, trust_pickle=True)
    assert "older" not in str(error.value)


@pytest.mark.parametrize("kind", ["directory", "fifo"])
def test_a_directory_or_fifo_as_model_fails_at_once(tmp_path, kind, capsys):
    import os

    path = tmp_path / "model.zip"
    path.mkdir() if kind == "directory" else os.mkfifo(path)
    with pytest.raises(ValueError, match="directory, not a model file" if kind == "directory" else "not a regular file"):
        LatentSwarmPPO.load(path)
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", "--model", str(path), "--preset", "smoke", "--no-baselines", "--episodes", "1"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert str(path) in err and "Traceback" not in err


def test_a_corrupted_evaluation_record_is_named(saved, tmp_path, capsys):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "conditions.csv").write_text("x\n1\n")
    (folder / "evaluation.json").write_text("{not json")
    with pytest.raises(SystemExit) as exit_info:
        main(["evaluate", "--model", str(saved), "--preset", "smoke", "--no-baselines", "--episodes", "1",
              "--output", str(folder)])
    assert exit_info.value.code == 2
    assert str(folder / "evaluation.json") in capsys.readouterr().err
