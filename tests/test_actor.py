"""The actor pi_xi(a | tau_t) (Sec. III-D): the smooth std bound, the tanh-squashed Gaussian, and old model files."""

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.distributions import SquashedDiagGaussianDistribution
from torch.distributions import Normal, TanhTransform, TransformedDistribution

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env
from sb3_latentswarm.cli import main, parse_overrides
from sb3_latentswarm.latent_ppo.model_file import read_data
from sb3_latentswarm.latent_ppo.policies import (
    LatentSwarmPolicy,
    TanhSquashedGaussianDistribution,
    inverse_smooth_log_std,
    smooth_log_std,
)
from sb3_latentswarm.presets import get_preset

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "data" / "actor_reference.npz"
REFERENCE_MODELS = {
    "coordination_proposed_seed0": ROOT / "tests/data/models/coordination-proposed-seed0.zip",
    "fast_1800_updates": ROOT / "tests/data/models/fast_1800_updates.zip",
}
ACTOR_KEYS = ("local_obs", "proprio", "link_row")
CRITIC_KEYS = ("swarm_proprio", "global_map")
SMALL = SwarmConfig(n_agents=3, grid_width=8, grid_height=8, max_steps=7, num_obstacles=3, p_fail=0.5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)


def make_model(seed=0, **policy_kwargs):
    return LatentSwarmPPO(
        "LatentSwarmPolicy",
        make_vec_env(2, config=SMALL, seed=seed),
        n_steps=12,
        chunk_length=4,
        batch_size=24,
        n_epochs=1,
        policy_kwargs={**TINY_POLICY, **policy_kwargs},
        seed=seed,
        device="cpu",
    )


def task_states(policy, n=32, scale=1.0, seed=0):
    return scale * th.randn(n, policy.task_dim, generator=th.Generator().manual_seed(seed))


def std_head_grad_norm(policy, raw_value):
    """The c05 loss (log-prob of own samples plus an entropy bonus): the largest gradient entry reaching the std's
    parameters (a max, not a norm: squares of gradients of 1e-25 underflow in float32)."""
    with th.no_grad():
        if policy.state_dependent_std:
            policy.action_log_std.bias.fill_(raw_value)
        else:
            policy.log_std.fill_(raw_value)
    params = list(policy.action_log_std.parameters()) if policy.state_dependent_std else [policy.log_std]
    distribution = policy.action_distribution(task_states(policy))
    actions = distribution.get_actions().detach()
    loss = -(distribution.log_prob(actions).mean() + 0.01 * policy.action_entropy(distribution).mean())
    policy.zero_grad()
    loss.backward()
    return th.cat([p.grad.flatten() for p in params]).abs().max().item()


# ---------------------------------------------------------------------------------------------- the std bound
@pytest.mark.parametrize("state_dependent_std", [True, False])
@pytest.mark.parametrize("action_distribution", ["gaussian", "squashed_gaussian"])
def test_std_head_gradient_is_nonzero_at_every_output_value(state_dependent_std, action_distribution):
    policy = make_model(state_dependent_std=state_dependent_std, action_distribution=action_distribution).policy
    assert policy.log_std_mapping == "tanh"  # the default of new policies
    for raw in (-30.0, -10.0, -3.0, 0.0, 1.0, 3.0, 10.0, 30.0):  # bounds (-5, 2): 3, 10 and 30 are far past the clamp
        assert std_head_grad_norm(policy, raw) > 0.0, raw


def test_clamp_mapping_has_the_zero_gradient_the_tanh_mapping_removes():
    policy = make_model(log_std_mapping="clamp").policy
    assert std_head_grad_norm(policy, 1.0) > 0.1
    assert std_head_grad_norm(policy, 3.0) == 0.0  # c05: past the bound no loss term reaches the head


def test_smooth_log_std_is_cleanrls_mapping_with_a_gradient_everywhere():
    low, high = -5.0, 2.0
    raw64 = th.linspace(-8.0, 8.0, 401, dtype=th.float64)
    cleanrl = low + 0.5 * (high - low) * (th.tanh(raw64) + 1.0)
    th.testing.assert_close(smooth_log_std(raw64, low, high), cleanrl, rtol=0.0, atol=1e-12)
    raw = th.linspace(-40.0, 40.0, 801, requires_grad=True)  # float32, as in training
    log_std = smooth_log_std(raw, low, high)
    log_std.sum().backward()
    assert (raw.grad > 0).all()
    assert log_std.min().item() >= low and log_std.max().item() <= high
    for target in (-4.9, -0.5, 0.0, 1.9):
        assert smooth_log_std(th.tensor(inverse_smooth_log_std(target, low, high)), low, high).item() == pytest.approx(
            target, abs=1e-6
        )


@pytest.mark.parametrize("state_dependent_std", [True, False])
def test_initial_std_is_log_std_init_under_the_tanh_mapping(state_dependent_std):
    policy = make_model(state_dependent_std=state_dependent_std, log_std_bounds=(-5.0, 0.0), log_std_init=-0.5).policy
    raw = policy.action_log_std.bias if state_dependent_std else policy.log_std
    th.testing.assert_close(policy.bound_log_std(raw.detach()), th.full((4,), -0.5), rtol=0.0, atol=1e-6)
    std = policy.action_distribution(task_states(policy)).distribution.stddev
    # the std head's weights start at gain 0.01: the std of every state is exp(-0.5) up to that
    th.testing.assert_close(std, th.full_like(std, math.exp(-0.5)), rtol=0.05, atol=0.0)


@pytest.mark.parametrize(
    "policy_kwargs, match",
    [
        (dict(log_std_mapping="softplus"), "log_std_mapping must be one of 'tanh', 'clamp'"),
        (dict(action_distribution="beta"), "action_distribution must be one of 'gaussian', 'squashed_gaussian'"),
        (dict(log_std_bounds=(-5.0, 0.0), log_std_init=0.0), r"log_std_init .*log_std_mapping='tanh'.* \(-5.0, 0.0\)"),
        (dict(log_std_bounds=(-5.0, 0.0), log_std_init=1.0, log_std_mapping="clamp"), "log_std_init must lie in"),
    ],
)
def test_bad_actor_options_raise_naming_the_field(policy_kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_model(**policy_kwargs)


def test_squashed_gaussian_needs_a_bounded_box():
    env = make_vec_env(1, config=SMALL, seed=0)
    unbounded = spaces.Box(np.array([-1, -1, 0, -np.inf], np.float32), np.array([1, 1, 1, np.inf], np.float32))
    with pytest.raises(ValueError, match=r"squashed_gaussian.*finite bounds.*gaussian"):
        LatentSwarmPolicy(env.observation_space, unbounded, lambda _: 3e-4, action_distribution="squashed_gaussian",
                          **TINY_POLICY)
    policy = LatentSwarmPolicy(env.observation_space, unbounded, lambda _: 3e-4, **TINY_POLICY)  # the Gaussian clips
    actions = th.tensor([[-3.0, 0.5, 2.0, -7.0]])
    assert th.equal(policy.env_actions(actions), th.tensor([[-1.0, 0.5, 1.0, -7.0]]))


def test_squashed_actions_are_rescaled_to_any_box_and_gaussian_ones_clipped():
    """SB3's unscale_action: a in [-1, 1] maps linearly onto [low, high]; the [-1, 1] box keeps a as it is."""
    env = make_vec_env(1, config=SMALL, seed=0)
    box = spaces.Box(np.array([-0.5, 0.0, -1.0, 0.2], np.float32), np.array([1.0, 0.5, 1.0, 0.9], np.float32))
    squashed = LatentSwarmPolicy(env.observation_space, box, lambda _: 3e-4, action_distribution="squashed_gaussian",
                                 **TINY_POLICY)
    gaussian = LatentSwarmPolicy(env.observation_space, box, lambda _: 3e-4, **TINY_POLICY)
    corners = th.tensor([[-1.0] * 4, [0.0] * 4, [1.0] * 4])
    expected = th.tensor([[-0.5, 0.0, -1.0, 0.2], [0.25, 0.25, 0.0, 0.55], [1.0, 0.5, 1.0, 0.9]])
    assert squashed.rescale_actions and not gaussian.rescale_actions
    th.testing.assert_close(squashed.env_actions(corners), expected)
    assert th.equal(gaussian.env_actions(corners), th.tensor([[-0.5, 0.0, -1.0, 0.2], [0.0, 0.0, 0.0, 0.2],
                                                              [1.0, 0.5, 1.0, 0.9]]))
    assert "action_low" not in squashed.state_dict()  # the bounds come from the saved space, not the weights
    unit = make_model(action_distribution="squashed_gaussian").policy
    tanh_actions = th.tanh(th.randn(16, 4, generator=th.Generator().manual_seed(2)) * 3)
    assert not unit.rescale_actions and th.equal(unit.env_actions(tanh_actions), tanh_actions)


# ---------------------------------------------------------------------------------------------- the squashed Gaussian
def test_squashed_log_prob_is_the_exact_change_of_variables():
    gen = th.Generator().manual_seed(0)
    mean = 2.0 * th.randn(256, 4, generator=gen, dtype=th.float64)
    log_std = th.empty(256, 4, dtype=th.float64).uniform_(-2.0, 1.0, generator=gen)
    gaussian_actions = mean + log_std.exp() * th.randn(256, 4, generator=gen, dtype=th.float64)
    gaussian_actions = gaussian_actions.clamp(-6.0, 6.0)  # |a| < 1 - 1e-5: atanh(a) recovers u in float64
    actions = th.tanh(gaussian_actions)
    distribution = TanhSquashedGaussianDistribution(4).proba_distribution(mean, log_std)
    # reference 1: torch.distributions' change of variables
    reference = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()]).log_prob(actions).sum(-1)
    # reference 2: by hand, log N(atanh a) - log(1 - a^2)
    u = 0.5 * np.log((1 + actions.numpy()) / (1 - actions.numpy()))
    sigma = log_std.exp().numpy()
    by_hand = (
        -0.5 * ((u - mean.numpy()) / sigma) ** 2 - np.log(sigma) - 0.5 * np.log(2 * np.pi) - np.log(1 - actions.numpy() ** 2)
    ).sum(-1)
    for ours in (distribution.log_prob(actions), distribution.log_prob(actions, gaussian_actions)):
        th.testing.assert_close(ours, reference, rtol=0.0, atol=1e-6)
        np.testing.assert_allclose(ours.numpy(), by_hand, rtol=0.0, atol=1e-6)
    # SB3's log(1 - a^2 + 1e-6) is off by up to log(1 + 1e-6 / (1 - a^2)) for actions near the box's edge
    sb3 = SquashedDiagGaussianDistribution(4).proba_distribution(mean, log_std).log_prob(actions, gaussian_actions)
    assert (sb3 - reference).abs().max().item() > 1e-3


def test_squashed_policy_acts_inside_the_box_and_its_mean_action_is_tanh_of_the_mean():
    policy = make_model(action_distribution="squashed_gaussian").policy
    tau = task_states(policy, n=64, scale=10.0)
    with th.no_grad():
        policy.action_mean.bias.fill_(3.0)  # means far outside the box
        distribution = policy.action_distribution(tau)
        gaussian = distribution.distribution
        sampled = distribution.get_actions()
        assert sampled.abs().max().item() <= 1.0
        th.testing.assert_close(distribution.get_actions(deterministic=True), th.tanh(gaussian.mean))
        th.testing.assert_close(policy.actions_from_noise(tau), th.tanh(gaussian.mean))
        noise = th.randn(64, 4, generator=th.Generator().manual_seed(1))
        th.testing.assert_close(policy.actions_from_noise(tau, noise), th.tanh(gaussian.mean + gaussian.stddev * noise))


def test_gaussian_actions_from_noise_is_mean_plus_std_times_noise():
    policy = make_model().policy
    tau = task_states(policy)
    noise = np.random.default_rng(0).standard_normal((32, 4)).astype(np.float32)
    with th.no_grad():
        gaussian = policy.action_distribution(tau).distribution
        assert th.equal(policy.actions_from_noise(tau), gaussian.mean)
        assert th.equal(policy.actions_from_noise(tau, noise), gaussian.mean + gaussian.stddev * th.as_tensor(noise))


def test_squashed_entropy_estimate_is_unbiased_and_differentiable():
    policy = make_model(action_distribution="squashed_gaussian").policy
    tau = task_states(policy, n=1).expand(20000, -1)
    th.manual_seed(0)
    distribution = policy.action_distribution(tau)
    estimate = policy.action_entropy(distribution)
    # Monte Carlo reference: H = H(N(mean, std^2)) + E[sum_k log(1 - tanh(u_k)^2)], u drawn independently here
    first = distribution.distribution
    gaussian = Normal(first.mean[0].detach().double(), first.stddev[0].detach().double())
    u = gaussian.sample((200000,))
    reference = gaussian.entropy().sum() + th.log1p(-th.tanh(u) ** 2).sum(-1).mean()
    assert estimate.mean().item() == pytest.approx(reference.item(), abs=0.03)
    estimate.mean().backward()
    assert policy.action_log_std.bias.grad.abs().min().item() > 0.0


# ---------------------------------------------------------------------------------------------- rollouts and replay
@pytest.mark.parametrize("action_distribution", ["gaussian", "squashed_gaussian"])
def test_replayed_log_probs_match_the_rollout(action_distribution):
    model = make_model(action_distribution=action_distribution)
    model.learn(total_timesteps=1, log_interval=None)  # one rollout and one update: the buffer holds that rollout
    buffer = model.rollout_buffer
    assert (buffer.episode_starts[1:] > 0).any() and (buffer.observations["link_row"].sum(-1) == 0).any()
    if action_distribution == "squashed_gaussian":
        assert np.abs(buffer.actions).max() <= 1.0  # the buffer holds the squashed action the env received
    else:
        assert np.abs(buffer.actions).max() > 1.0  # the Gaussian's samples, before the env's clip
    # the update changed the policy: collect again with it, then replay
    callback = CallbackList([])  # SB3's no-op callback
    callback.init_callback(model)
    model.collect_rollouts(model.env, callback, buffer, model.n_steps)
    max_diff = 0.0
    with th.no_grad():
        for batch in buffer.get(model.batch_size):
            evaluation = model.policy.evaluate_sequences(
                batch.observations, batch.actions, batch.latent_state, batch.episode_starts
            )
            max_diff = max(max_diff, (evaluation.log_prob - batch.old_log_prob).abs().max().item())
            assert th.isfinite(evaluation.entropy).all()
    assert max_diff < 1e-5


# ---------------------------------------------------------------------------------------------- model files
@pytest.mark.parametrize("name", sorted(REFERENCE_MODELS))
def test_old_model_files_act_as_recorded(name):
    """Recorded by tests/data/make_actor_reference.py before the actor options existed (commit 733f23f's parent).

    Bit for bit on the CPU that recorded it; another CPU rounds float32 GEMMs differently in the last bit (the file
    comes from an Intel machine with AMX, CI also runs on AMD EPYC), hence relative 1e-5 (about 80 float32 ulps), far
    below what a change of the actor (mapping, distribution, clamp) makes.
    """
    reference = np.load(REFERENCE)
    ref = {key.split("/", 1)[1]: reference[key] for key in reference.files if key.startswith(f"{name}/")}
    model = LatentSwarmPPO.load(REFERENCE_MODELS[name], device="cpu")
    policy = model.policy
    assert "log_std_mapping" not in read_data(REFERENCE_MODELS[name])[0]["policy_kwargs"]
    assert policy.log_std_mapping == "clamp" and policy.action_distribution_name == "gaussian"
    n_steps, n_slots = ref["episode_starts"].shape
    state, predict_state = policy.initial_state(n_slots), None
    with th.no_grad():
        for t in range(n_steps):
            obs = {key: ref[f"obs_{key}"][t] for key in ACTOR_KEYS + CRITIC_KEYS}
            starts = ref["episode_starts"][t]
            tensors = {key: th.as_tensor(value) for key, value in obs.items()}
            actions, values, log_prob, state = policy(tensors, state, th.as_tensor(starts), deterministic=True)
            distribution = policy.action_distribution(state.task_state)
            got = {
                "mean": distribution.distribution.mean,
                "stddev": distribution.distribution.stddev,
                "deterministic_actions": actions,
                "deterministic_log_prob": log_prob,
                "values": values,
                "given_log_prob": distribution.log_prob(th.as_tensor(ref["given_actions"][t])),
                "entropy": distribution.entropy(),
                "actions_from_noise": policy.actions_from_noise(state.task_state),
            }
            got["predict_actions"], predict_state = policy.predict(obs, predict_state, starts, deterministic=True)
            for key, value in got.items():
                expected = ref["mean" if key == "actions_from_noise" else key][t]
                np.testing.assert_allclose(
                    np.asarray(value), expected, rtol=1e-5, atol=1e-5, err_msg=f"{name} step {t}: {key}"
                )


def test_new_model_files_record_the_actor_and_round_trip(tmp_path):
    model = make_model(action_distribution="squashed_gaussian")
    model.save(tmp_path / "new.zip")
    saved = read_data(tmp_path / "new.zip")[0]["policy_kwargs"]
    assert saved["log_std_mapping"] == "tanh" and saved["action_distribution"] == "squashed_gaussian"
    loaded = LatentSwarmPPO.load(tmp_path / "new.zip", device="cpu")
    assert loaded.policy.log_std_mapping == "tanh" and loaded.policy.action_distribution_name == "squashed_gaussian"
    tau = task_states(model.policy)
    with th.no_grad():
        assert th.equal(loaded.policy.actions_from_noise(tau), model.policy.actions_from_noise(tau))
    # the same file without the two keys (as written before they existed) loads with the old actor
    with zipfile.ZipFile(tmp_path / "new.zip") as original, zipfile.ZipFile(tmp_path / "old.zip", "w") as out:
        for item in original.infolist():
            content = original.read(item.filename)
            if item.filename == "data":
                data = json.loads(content)
                del data["policy_kwargs"]["log_std_mapping"], data["policy_kwargs"]["action_distribution"]
                content = json.dumps(data).encode()
            out.writestr(item, content)
    old = LatentSwarmPPO.load(tmp_path / "old.zip", device="cpu")
    assert old.policy.log_std_mapping == "clamp" and old.policy.action_distribution_name == "gaussian"


def test_pickled_old_files_load_with_the_old_actor(tmp_path):
    """A file of save format 1 (SB3's pickled attributes) from before the options: SB3's own save, keys removed."""
    model = make_model()
    for key in ("log_std_mapping", "action_distribution"):
        del model.policy_kwargs[key]
    model.save_format = 1
    super(LatentSwarmPPO, model).save(tmp_path / "pickled.zip")
    loaded = LatentSwarmPPO.load(tmp_path / "pickled.zip", device="cpu", trust_pickle=True)
    assert loaded.policy.log_std_mapping == "clamp"


# ---------------------------------------------------------------------------------------------- presets and the CLI
def test_presets_name_their_actor_and_set_reaches_the_policy(tmp_path):
    from sb3_latentswarm.presets import ACTOR, PAPER_ACTOR

    for name in ("paper", "fast", "coordination", "demo", "smoke"):
        policy_kwargs = get_preset(name).algo_kwargs["policy_kwargs"]
        actor = ACTOR if get_preset(name).algo_kwargs.get("normalize_value") else PAPER_ACTOR  # the CPU presets' options
        assert {key: policy_kwargs[key] for key in actor} == actor, name
    assert get_preset("paper").algo_kwargs["policy_kwargs"]["action_distribution"] == "gaussian"  # Sec. III-D
    assert get_preset("coordination").algo_kwargs["policy_kwargs"]["action_distribution"] == "squashed_gaussian"
    preset = get_preset("coordination").with_overrides(**parse_overrides(["action_distribution=gaussian"]))
    assert preset.algo_kwargs["policy_kwargs"]["action_distribution"] == "gaussian"
    assert preset.algo_kwargs["policy_kwargs"]["latent_dim"] == 64  # the rest of the preset's policy is kept
    args = ["--set", "action_distribution=squashed_gaussian", "log_std_mapping=clamp", "--output", str(tmp_path)]
    assert main(["train", "--preset", "smoke", "--no-progress", *args]) == 0
    trained = LatentSwarmPPO.load(tmp_path / "model.zip", device="cpu")
    assert trained.policy.action_distribution_name == "squashed_gaussian" and trained.policy.log_std_mapping == "clamp"


# ---------------------------------------------------------------------------------------------- the independent baseline
def test_independent_baseline_trains_with_the_presets_ppo_settings():
    from sb3_latentswarm.baselines import train_independent_ppo

    coordination = get_preset("coordination")
    kwargs = coordination.independent_ppo_kwargs()
    assert (kwargs["n_steps"], kwargs["batch_size"], kwargs["n_epochs"]) == (160, 3840, 3)
    assert kwargs["learning_rate"] == 1e-3 and kwargs["policy_kwargs"] == {"log_std_init": -0.5}
    assert get_preset("random_corner").independent_ppo_kwargs()["learning_rate"] == 6e-4  # its results' setting
    smoke = get_preset("smoke")
    env = make_vec_env(smoke.n_envs, config=smoke.config, seed=0)
    model = train_independent_ppo(env, 1, device="cpu", **smoke.independent_ppo_kwargs()).model
    assert (model.n_steps, model.batch_size, model.n_epochs) == (20, 30, 1)
    assert model.policy.lstm_actor.hidden_size == 64  # the LSTM sizes stay the baseline's own
    th.testing.assert_close(model.policy.log_std.detach(), th.full((4,), -0.5), rtol=0.0, atol=1e-3)  # after one update
