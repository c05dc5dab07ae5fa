"""The opt-in MAPPO training options of LatentSwarmPPO: value normalization, Huber loss, per-group clipping, std bound."""

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.logger import configure
from test_latent_ppo import SMALL, TINY_POLICY, collected_model, make_model, random_obs, random_state

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.latent_ppo.value_norm import ValueNorm


def test_value_norm_tracks_moments_and_inverts():
    norm = ValueNorm(beta=0.5)
    mean, var = norm.mean_var()
    assert mean.item() == 0.0 and var.item() == 1.0
    gen = th.Generator().manual_seed(0)
    targets = 3.0 + 2.0 * th.randn(10_000, generator=gen)
    norm.update(targets)
    mean, var = norm.mean_var()  # debiased: exactly the batch moments after one update
    assert mean.item() == pytest.approx(targets.mean().item(), rel=1e-5)
    assert var.sqrt().item() == pytest.approx(targets.std(unbiased=False).item(), rel=1e-4)
    normalized = norm.normalize(targets)
    assert normalized.mean().item() == pytest.approx(0.0, abs=1e-4)
    assert normalized.std().item() == pytest.approx(1.0, rel=1e-3)
    th.testing.assert_close(norm.denormalize(normalized), targets)
    with pytest.raises(ValueError, match="beta"):
        ValueNorm(beta=1.0)


def test_value_normalization_trains_and_round_trips_through_save_load(tmp_path):
    model = make_model(normalize_value=True)
    model.learn(total_timesteps=2 * 20 * 3 * 2)
    normalizer = model.policy.value_normalizer
    assert normalizer is not None and normalizer.debiasing_term.item() > 0
    mean, var = normalizer.mean_var()
    assert var.item() != 1.0  # statistics moved away from their initial values
    path = tmp_path / "model.zip"
    model.save(path)
    loaded = LatentSwarmPPO.load(path)
    assert loaded.normalize_value and loaded.policy.value_normalizer is not None
    for name in ("running_mean", "running_mean_sq", "debiasing_term"):
        assert th.equal(getattr(loaded.policy.value_normalizer, name), getattr(normalizer, name)), name
    obs = {k: th.as_tensor(v) for k, v in make_vec_env(2, config=SMALL, seed=5).reset().items()}
    th.testing.assert_close(loaded.policy.predict_values(obs), model.policy.predict_values(obs))
    # predict_values is in return units: the critic's raw output denormalized
    th.testing.assert_close(model.policy.predict_values(obs), normalizer.denormalize(model.policy.critic_output(obs)))


def test_normalized_critic_learns_normalized_returns():
    model = collected_model(normalize_value=True)
    model.train()
    normalizer = model.policy.value_normalizer
    batch = next(model.rollout_buffer.get(model.batch_size))
    losses = model._minibatch_losses(batch, clip_range=0.2, clip_range_vf=None)
    with th.no_grad():
        evaluation = model.policy.evaluate_sequences(
            batch.observations, batch.actions, batch.latent_state, batch.episode_starts
        )
    expected = ((normalizer.normalize(batch.returns) - evaluation.values) ** 2).mean()
    assert losses["value"].item() == pytest.approx(expected.item(), rel=1e-5)


def test_huber_value_loss():
    model = collected_model(value_loss="huber", huber_delta=0.5)
    batch = next(model.rollout_buffer.get(model.batch_size))
    losses = model._minibatch_losses(batch, clip_range=0.2, clip_range_vf=None)
    with th.no_grad():
        evaluation = model.policy.evaluate_sequences(
            batch.observations, batch.actions, batch.latent_state, batch.episode_starts
        )
    error = (batch.returns - evaluation.values).abs()
    expected = th.where(error <= 0.5, 0.5 * error**2, 0.5 * (error - 0.25)).mean()
    assert losses["value"].item() == pytest.approx(expected.item(), rel=1e-5)


def test_per_group_clipping_keeps_the_critic_from_scaling_the_actor():
    grads = {}
    for mode in ("global", "per_group"):
        model = collected_model(grad_clip=mode, max_grad_norm=0.5, vf_coef=1e4)  # a critic gradient that dwarfs the rest
        critic_ids = {id(p) for p in model.policy.critic_parameters}
        batch = next(model.rollout_buffer.get(model.batch_size))
        losses = model._minibatch_losses(batch, clip_range=0.2, clip_range_vf=None)
        weights = model._loss_weights()
        model.policy.optimizer.zero_grad()
        sum(weights[t] * losses[t] for t in weights).backward()
        for group in model._parameter_groups():
            th.nn.utils.clip_grad_norm_(group, model.max_grad_norm)
        actor = [p.grad for p in model.policy.parameters() if id(p) not in critic_ids and p.grad is not None]
        critic = [p.grad for p in model.policy.critic_parameters]
        grads[mode] = (th.cat([g.flatten() for g in actor]).norm().item(), th.cat([g.flatten() for g in critic]).norm().item())
    assert grads["per_group"][1] == pytest.approx(0.5, rel=1e-4)
    assert grads["per_group"][0] <= 0.5 + 1e-6
    assert grads["global"][0] < 0.01 * grads["per_group"][0]  # under one global clip the actor's share all but vanishes


def test_std_bound_holds_for_any_task_state():
    for dependent in (True, False):
        model = make_model(
            policy_kwargs=dict(TINY_POLICY, log_std_bounds=(-5.0, 0.0), log_std_init=-0.5, state_dependent_std=dependent)
        )
        policy = model.policy
        with th.no_grad():
            if dependent:
                policy.action_log_std.bias.fill_(3.0)
            else:
                policy.log_std.fill_(3.0)
            task_state = 10.0 * th.randn(64, policy.task_dim, generator=th.Generator().manual_seed(0))
            std = policy.action_distribution(task_state).distribution.stddev
        assert std.max().item() <= 1.0 + 1e-6
    assert not hasattr(make_model(policy_kwargs=dict(TINY_POLICY, state_dependent_std=False)).policy, "action_log_std")


def test_state_independent_std_round_trips(tmp_path):
    model = make_model(policy_kwargs=dict(TINY_POLICY, state_dependent_std=False, log_std_init=-0.5))
    model.learn(total_timesteps=2 * 20 * 3)
    model.save(tmp_path / "m.zip")
    loaded = LatentSwarmPPO.load(tmp_path / "m.zip")
    assert th.equal(loaded.policy.log_std, model.policy.log_std)
    obs = random_obs(model.policy, n_swarms=1, n_agents=3)
    state = random_state(model.policy, 3)
    a = model.policy.action_distribution(state.task_state).distribution.stddev
    b = loaded.policy.action_distribution(state.task_state).distribution.stddev
    th.testing.assert_close(a, b)
    assert obs["link_row"].shape == (3, 3)


def test_training_options_are_logged(tmp_path):
    model = make_model(
        config=SMALL.replace(max_steps=10), normalize_value=True, grad_clip="per_group", log_grad_norms=True
    )
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(total_timesteps=2 * 20 * 6)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in ("rollout/actions_in_box", "train/grad_norm_actor", "train/grad_norm_critic", "train/grad_norm_value",
                "train/grad_norm_policy", "train/grad_norm_map", "train/grad_norm_pred", "train/value_norm_std"):
        assert key in header, key
    rows = (tmp_path / "progress.csv").read_text().splitlines()
    in_box = [float(r.split(",")[header.index("rollout/actions_in_box")]) for r in rows[1:]]
    assert all(0.0 <= v <= 1.0 for v in in_box)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(grad_clip="sometimes"), "grad_clip must be one of"),
        (dict(value_loss="l1"), "value_loss must be one of"),
        (dict(huber_delta=0.0), "huber_delta"),
        (dict(normalize_value=False, policy_kwargs=dict(TINY_POLICY, normalize_value=True)), "contradicts"),
        (dict(policy_kwargs=dict(TINY_POLICY, log_std_bounds=(1.0, -1.0))), "log_std_bounds"),
        (dict(policy_kwargs=dict(TINY_POLICY, log_std_bounds=(-5.0, 0.0), log_std_init=1.0)), "log_std_init"),
    ],
)
def test_bad_training_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_model(**kwargs)


def test_defaults_keep_the_papers_training():
    model = make_model()
    assert model.grad_clip == "global" and model.value_loss == "mse" and not model.normalize_value
    assert model.policy.value_normalizer is None and model.policy.state_dependent_std
    assert np.allclose(model.policy.log_std_bounds, (-5.0, 2.0))
