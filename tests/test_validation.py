"""Settings that cannot silently break training: validation at the door, and clear errors for every user mistake."""

import math
import tracemalloc

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env
from sb3_latentswarm.callbacks import SwarmEvalCallback
from sb3_latentswarm.channel import A2AChannel
from sb3_latentswarm.cli import main
from sb3_latentswarm.config import FLOAT_BOUNDS
from sb3_latentswarm.envs import SwarmReconEnv
from sb3_latentswarm.latent_ppo import NonFiniteLossError, validate_algorithm_kwargs
from sb3_latentswarm.rendering import render_episode

SMALL = SwarmConfig(n_agents=3, grid_width=8, grid_height=8, max_steps=12, num_obstacles=3)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)


def make_model(env=None, **kwargs):
    params = dict(n_steps=12, chunk_length=4, batch_size=24, n_epochs=2, learning_rate=3e-4, policy_kwargs=TINY_POLICY,
                  seed=0, device="cpu")
    return LatentSwarmPPO("LatentSwarmPolicy", env or make_vec_env(2, config=SMALL, seed=0), **{**params, **kwargs})


# ---------------------------------------------------------------------------------------------- algorithm settings
@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        (dict(learning_rate=0.0), ValueError, r"learning_rate must be a finite number in \(0.0, 1.0\], got 0.0"),
        (dict(learning_rate=1e999), ValueError, r"learning_rate must be a finite number in \(0.0, 1.0\], got inf"),
        (dict(learning_rate=1e6), ValueError, r"learning_rate must be a finite number in \(0.0, 1.0\], got 1000000.0"),
        (dict(learning_rate="abc"), TypeError, r"learning_rate must be a number, got str \('abc'\)"),
        (dict(learning_rate=lambda p: 10 * p), ValueError, r"learning_rate \(its value at progress_remaining=1.0\)"),
        (dict(clip_range=-0.2), ValueError, r"clip_range must be a finite number in \(0.0, 1.0\], got -0.2"),
        (dict(clip_range=float("nan")), ValueError, r"clip_range must be a finite number"),
        (dict(target_kl=-1), ValueError, r"target_kl \(None deactivates it\) must be a finite number in \(0.0, inf\)"),
        (dict(target_kl=float("nan")), ValueError, r"target_kl"),
        (dict(clip_range_vf=-0.1), ValueError, r"clip_range_vf \(None deactivates it\)"),
        (dict(normalize_value="yes"), TypeError, r"normalize_value must be True or False"),
        (dict(learning_rat=1e-3), TypeError, r"unknown LatentSwarmPPO argument\(s\) \['learning_rat'\]"),
    ],
)
def test_algorithm_settings_are_validated_by_one_function(kwargs, error, message):
    with pytest.raises(error, match=message):
        validate_algorithm_kwargs(**kwargs)
    if "learning_rat" not in kwargs:
        with pytest.raises(error, match=message):
            make_model(**kwargs)


def test_schedules_may_decay_to_zero_and_load_validates_overrides(tmp_path):
    validate_algorithm_kwargs(learning_rate=lambda progress: 3e-4 * progress)  # SB3's linear schedule to 0
    model = make_model()
    model.save(tmp_path / "model.zip")
    with pytest.raises(ValueError, match=r"learning_rate must be a finite number in \(0.0, 1.0\], got inf"):
        LatentSwarmPPO.load(tmp_path / "model.zip", learning_rate=float("inf"))
    with pytest.raises(ValueError, match=r"clip_range must be a finite number in \(0.0, 1.0\], got -0.2"):
        LatentSwarmPPO.load(tmp_path / "model.zip", clip_range=-0.2)


def test_cli_bad_setting_is_one_line_and_exit_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--preset", "smoke", "--set", "learning_rate=abc", "--output", str(tmp_path / "run")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "learning_rate must be a number, got str ('abc')" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_nan_loss_stops_training_naming_the_update_and_the_term():
    model = make_model()
    original = model._minibatch_losses

    def poisoned(*args, **kwargs):
        losses = original(*args, **kwargs)
        losses["map"] = losses["map"] * float("nan")
        return losses

    model._minibatch_losses = poisoned
    with pytest.raises(NonFiniteLossError, match=r"the map loss is nan in update 1 \(epoch 1, minibatch 1\)"):
        model.learn(12 * 6)


# ---------------------------------------------------------------------------------------------- ValueNorm + clip
class FirstMinibatchGradients(BaseCallback):
    """At the end of the first rollout: the critic's gradient of the value loss with and without value clipping."""

    def _on_step(self):
        return True

    def _on_rollout_end(self):
        m = self.model
        m.policy.value_normalizer.update(th.as_tensor(m.rollout_buffer.returns))  # what train() does first
        batch = next(m.rollout_buffer.get(None))
        self.norms = []
        for clip in (None, 0.2):
            losses = m._minibatch_losses(batch, 0.2, clip)
            m.policy.zero_grad()
            losses["value"].backward()
            self.norms.append(float(th.sqrt(sum((p.grad**2).sum() for p in m.policy.critic_parameters if p.grad is not None))))
        raise KeyboardInterrupt


def test_value_clipping_with_value_norm_clips_nothing_before_the_first_step():
    model = make_model(normalize_value=True, clip_range_vf=0.2)
    callback = FirstMinibatchGradients()
    with pytest.raises(KeyboardInterrupt):
        model.learn(12 * 6, callback=callback)
    unclipped, clipped = callback.norms
    assert unclipped > 0 and clipped == pytest.approx(unclipped, rel=1e-6)


# ---------------------------------------------------------------------------------------------- VecNormalize
def test_vec_normalize_of_observations_is_refused_with_the_reason():
    with pytest.raises(ValueError, match="VecNormalize\\(norm_obs=True\\) is refused.*link_row.*No observation key"):
        make_model(VecNormalize(make_vec_env(2, config=SMALL, seed=0), norm_reward=False))
    make_model(VecNormalize(make_vec_env(2, config=SMALL, seed=0), norm_obs=False))  # rewards only: fine


# ---------------------------------------------------------------------------------------------- SwarmEvalCallback
@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(n_eval_episodes=0), r"n_eval_episodes must be an int in \[1, inf\)"),
        (dict(p_fail=2.0), r"p_fail must be a finite number in \[0.0, 1.0\], got 2.0"),
        (dict(seed=-1), r"seed must be an int in \[0, inf\), got -1"),
        (dict(condition="everything"), r"Unknown condition"),
    ],
)
def test_swarm_eval_callback_validates_at_construction(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SwarmEvalCallback(eval_freq=10, **kwargs)


def test_swarm_eval_callback_accepts_full_comm_in_range_and_refuses_a_file_as_folder(tmp_path):
    assert SwarmEvalCallback(eval_freq=10, condition="full_comm_in_range").condition == "full_comm_in_range"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="best_model_save_path .* is an existing file"):
        SwarmEvalCallback(eval_freq=10, best_model_save_path=tmp_path / "file")
    with pytest.raises(ValueError, match="is inside .*file, which is an existing file"):
        SwarmEvalCallback(eval_freq=10, best_model_save_path=tmp_path / "file" / "best")


def test_train_evaluate_with_zero_episodes_fails_before_training(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--preset", "smoke", "--evaluate", "--set", "eval_episodes=0", "--output", str(tmp_path / "run")])
    assert exit_info.value.code == 2
    assert "eval_episodes must be an int in [1, inf), got 0" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


# ---------------------------------------------------------------------------------------------- actions
def _step_errors(actions_per_backend):
    errors = []
    for backend in ("batched", "supersuit"):
        env = make_vec_env(1, config=SMALL, seed=0, backend=backend)
        env.reset()
        with pytest.raises((TypeError, ValueError)) as info:
            env.step(actions_per_backend)
        errors.append((type(info.value), str(info.value)))
    env = SwarmReconEnv(SMALL)
    env.reset(seed=0)
    with pytest.raises((TypeError, ValueError)) as info:
        env.step(dict(zip(env.agents, actions_per_backend)))
    errors.append((type(info.value), str(info.value)))
    return errors


@pytest.mark.parametrize("actions", [np.zeros((3, 4)) + 0.5j, np.full((3, 4), "0.5"), np.full((3, 4), 2.0)])
def test_the_three_front_ends_check_actions_alike(actions):
    errors = _step_errors(actions)
    assert len({e for e in errors}) == 1, errors
    assert "real numbers" in errors[0][1] or "outside [-1, 1]" in errors[0][1]


@pytest.mark.parametrize("backend", ["batched", "supersuit"])
def test_stepping_before_reset_is_a_clear_error(backend):
    env = make_vec_env(1, config=SMALL, seed=0, backend=backend)
    with pytest.raises(RuntimeError, match=r"call reset\(\) first"):
        env.step(np.zeros((3, 4), dtype=np.float32))


def test_vec_env_shape_errors_name_the_expected_shape():
    for backend in ("batched", "supersuit"):
        env = make_vec_env(1, config=SMALL, seed=0, backend=backend)
        env.reset()
        with pytest.raises(ValueError, match=r"actions must have shape \(3, 4\) \(one row per slot\), got shape \(3, 3\)"):
            env.step(np.zeros((3, 3)))


# ---------------------------------------------------------------------------------------------- SwarmConfig bounds
@pytest.mark.parametrize("field, value", [("tx_power_dbm", -1e308), ("tx_power_dbm", 1e308), ("w_cov", 1e308),
                                          ("noise_power", 0.0), ("path_loss_exponent", 50.0), ("n_agents", 10**6)])
def test_swarm_config_refuses_values_that_break_the_env(field, value):
    with pytest.raises(ValueError, match=f"SwarmConfig.{field} must be"):
        SwarmConfig(**{field: value})


def test_the_extreme_accepted_config_gives_finite_rewards_and_sinr():
    extreme = {name: FLOAT_BOUNDS[name][1] for name in ("w_cov", "w_red", "w_coll", "stall_penalty", "tx_power_dbm")}
    config = SMALL.replace(**extreme, noise_power=FLOAT_BOUNDS["noise_power"][0], interference_max=0.0,
                           path_loss_exponent=FLOAT_BOUNDS["path_loss_exponent"][1],
                           min_link_distance=FLOAT_BOUNDS["min_link_distance"][0], rician_k=FLOAT_BOUNDS["rician_k"][1])
    channel = A2AChannel(config)
    positions = np.zeros((3, 3)) + [1.0, 1.0, 10.0]  # co-located: the largest path gain
    sinr = channel.sinr_from_draws(positions, channel.draw(positions, np.random.default_rng(0)))
    assert np.isfinite(sinr).all()
    env = SwarmReconEnv(config)
    env.reset(seed=0)
    for _ in range(5):
        _, rewards, *_ = env.step({agent: np.ones(4, dtype=np.float32) for agent in env.agents})
        assert all(math.isfinite(r) for r in rewards.values())


# ---------------------------------------------------------------------------------------------- render
def test_render_refuses_a_model_of_another_map_or_sensor_range(tmp_path, capsys):
    model = make_model()
    path = tmp_path / "model.zip"
    model.save(path)
    for overrides in (["grid_width=12", "grid_height=12"], ["sensor_range=1"]):
        with pytest.raises(SystemExit) as exit_info:
            main(["render", "--model", str(path), "--set", *overrides, "--output", str(tmp_path / "e.gif")])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert "trained on another map or sensor range" in err and "Traceback" not in err
    assert not (tmp_path / "e.gif").exists()


def test_render_streams_frames_and_writes_gif_durations_in_milliseconds(tmp_path):
    from PIL import Image

    config = SMALL.replace(grid_width=10, grid_height=10, max_steps=150)  # 480 x 480 pixels, 151 frames of 0.7 MB
    tracemalloc.start()
    path = render_episode(None, config, tmp_path / "e.gif", fps=4, max_frames=20)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    with Image.open(path) as gif:
        durations = []
        for k in range(gif.n_frames):
            gif.seek(k)
            durations.append(gif.info["duration"])
    assert 2 <= len(durations) <= 20
    assert durations == [250] * len(durations)  # 1 / fps seconds, in ms
    assert peak < 40 * 2**20, f"peak {peak / 2**20:.0f} MiB: frames are held in memory"


# ---------------------------------------------------------------------------------------------- CLI errors
def test_cli_errors_are_one_line_exit_2(tmp_path, capsys, monkeypatch):
    (tmp_path / "taken").write_text("x")
    cases = [
        (["render", "--preset", "smoke", "--device", "bogus", "--output", str(tmp_path / "e.gif")], "--device must be"),
        (["train", "--preset", "smoke", "--output", str(tmp_path / "taken")], "is an existing file, not a folder"),
    ]
    for argv, message in cases:
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err

    import sb3_latentswarm.cli.render as cli

    def torch_fails(args):
        raise RuntimeError("mat1 and mat2 shapes cannot be multiplied (3x25 and 9x8)\nmore torch text")

    monkeypatch.setattr(cli, "command_render", torch_fails)
    with pytest.raises(SystemExit) as exit_info:
        main(["render", "--preset", "smoke", "--output", str(tmp_path / "e.gif")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "RuntimeError: mat1 and mat2" in err and len(err.strip().splitlines()) == 1


def test_cli_says_when_cuda_falls_back_to_the_cpu(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    assert main(["render", "--preset", "smoke", "--device", "cuda", "--output", str(tmp_path / "e.gif")]) == 0
    assert "CUDA is not available here; running on the CPU" in capsys.readouterr().err


def test_train_with_zero_envs_names_the_setting(tmp_path, capsys):
    from sb3_latentswarm.cli import main

    with pytest.raises(SystemExit) as stop:
        main(["train", "--preset", "smoke", "--set", "n_envs=0", "--output", str(tmp_path / "run"), "--no-progress"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "n_envs must be an int in [1, inf), got 0" in err and "ZeroDivisionError" not in err
    assert not (tmp_path / "run").exists()
