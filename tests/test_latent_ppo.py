"""LatentSwarmPPO and LatentSwarmPolicy: the latent updates of Sec. III, the swarm buffer and the joint loss."""

import copy

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.latent_ppo.buffers import SwarmRolloutBuffer
from sb3_latentswarm.latent_ppo.policies import SequenceEvaluation
from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.latent_ppo.update import auxiliary_losses

SMALL = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=30, num_obstacles=5, p_fail=0.5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)


def make_model(config=SMALL, n_envs=2, seed=0, **kwargs):
    params = dict(n_steps=20, chunk_length=5, batch_size=30, n_epochs=2, policy_kwargs=TINY_POLICY, seed=seed)
    params.update(kwargs)
    return LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(n_envs, config=config, seed=seed), **params)


def random_obs(policy, n_swarms, n_agents, seed=0, link_prob=0.5):
    rng = np.random.default_rng(seed)
    batch = n_swarms * n_agents
    link_row = (rng.random((batch, n_agents)) < link_prob).astype(np.float32)
    link_row.reshape(n_swarms, n_agents, n_agents)[:, np.arange(n_agents), np.arange(n_agents)] = 0.0
    return {
        "local_obs": th.as_tensor(rng.integers(-1, 2, (batch, policy.local_obs_dim)), dtype=th.int8),
        "proprio": th.as_tensor(rng.random((batch, policy.proprio_dim)), dtype=th.float32),
        "link_row": th.as_tensor(link_row),
    }


def random_state(policy, batch, seed=0):
    gen = th.Generator().manual_seed(seed)
    return LatentState(*(th.randn(batch, dim, generator=gen) for dim in policy.latent_dims))


@pytest.fixture(scope="module")
def policy():
    return make_model().policy


def test_aggregation_is_masked_mean(policy):
    obs = random_obs(policy, n_swarms=2, n_agents=3)
    state = random_state(policy, 6)
    out = policy.latent_step(obs, state, th.zeros(6))
    messages = th.cat([state.map_state, state.task_state], dim=-1).view(2, 3, -1)
    link = obs["link_row"].view(2, 3, 3)
    for swarm in range(2):
        for i in range(3):
            senders = th.nonzero(link[swarm, i]).flatten()
            row = swarm * 3 + i
            if len(senders) == 0:
                assert not out.has_message[row]
                assert th.all(out.received_message[row] == 0)
            else:
                assert out.has_message[row]
                th.testing.assert_close(out.received_message[row], messages[swarm, senders].mean(0))


def test_permuting_agents_permutes_outputs(policy):
    obs = random_obs(policy, n_swarms=1, n_agents=3, seed=1, link_prob=0.6)
    state = random_state(policy, 3, seed=1)
    perm = th.tensor([2, 0, 1])
    permuted_obs = {key: value[perm] for key, value in obs.items()}
    permuted_obs["link_row"] = obs["link_row"][perm][:, perm]
    permuted_state = LatentState(*(field[perm] for field in state))
    out = policy.latent_step(obs, state, th.zeros(3))
    out_perm = policy.latent_step(permuted_obs, permuted_state, th.zeros(3))
    for field, field_perm in zip(out.state, out_perm.state):
        th.testing.assert_close(field[perm], field_perm)
    th.testing.assert_close(out.predicted_message[perm], out_perm.predicted_message)


def perturbed_predictor(policy):
    other = copy.deepcopy(policy)
    with th.no_grad():
        for param in other.message_predictor.parameters():
            param.add_(th.randn_like(param))
    return other


def test_asymmetric_map_update(policy):
    obs = random_obs(policy, n_swarms=2, n_agents=3, seed=2)
    obs["link_row"][:3] = 0.0  # swarm 0: nobody receives anything
    obs["link_row"][3:] = 1.0 - th.eye(3)  # swarm 1: everybody receives everything
    state = random_state(policy, 6, seed=2)
    other = perturbed_predictor(policy)
    out = policy.latent_step(obs, state, th.zeros(6))
    out_other = other.latent_step(obs, state, th.zeros(6))
    # without links the map state never sees the predictor ...
    th.testing.assert_close(out.state.map_state[:3], out_other.state.map_state[:3])
    # ... while the task state does (the predicted message replaces the missing one)
    assert not th.allclose(out.state.task_state[:3], out_other.state.task_state[:3])
    # with links the map state depends on the received map message m^mu
    changed = LatentState(state.map_state + 1.0, *state[1:])
    out_changed = policy.latent_step(obs, changed, th.zeros(6))
    map_delta = (out_changed.state.map_state - out.state.map_state).abs().sum(-1)
    assert th.all(map_delta[3:] > 1e-4)


def test_predictor_does_not_affect_action_with_live_link(policy):
    obs = random_obs(policy, n_swarms=1, n_agents=3, seed=3)
    obs["link_row"][:] = th.tensor([[0, 1, 0], [0, 0, 0], [1, 1, 0]], dtype=th.float32)
    state = random_state(policy, 3, seed=3)
    other = perturbed_predictor(policy)
    dist = policy.action_distribution(policy.latent_step(obs, state, th.zeros(3)).state.task_state)
    dist_other = other.action_distribution(other.latent_step(obs, state, th.zeros(3)).state.task_state)
    mean, mean_other = dist.distribution.mean, dist_other.distribution.mean
    th.testing.assert_close(mean[[0, 2]], mean_other[[0, 2]])
    th.testing.assert_close(dist.distribution.stddev[[0, 2]], dist_other.distribution.stddev[[0, 2]])
    assert not th.allclose(mean[1], mean_other[1])  # agent 1 is in dropout: the predictor drives it


def test_episode_start_resets_state(policy):
    obs = random_obs(policy, n_swarms=1, n_agents=3, seed=4)
    fresh = policy.latent_step(obs, policy.initial_state(3), th.zeros(3))
    reset = policy.latent_step(obs, random_state(policy, 3, seed=4), th.ones(3))
    for field, field_reset in zip(fresh.state, reset.state):
        th.testing.assert_close(field, field_reset)


def test_pred_loss_counts_only_communication_steps():
    gen = th.Generator().manual_seed(0)
    shape = (4, 6, 10)
    has_message = th.rand(4, 6, generator=gen) > 0.5
    received = th.randn(shape, generator=gen)
    predicted = th.randn(shape, generator=gen)
    evaluation = SequenceEvaluation(
        values=th.zeros(4, 6),
        log_prob=th.zeros(4, 6),
        entropy=th.zeros(4, 6),
        map_reconstruction=th.zeros(4, 6, 9),
        received_message=received,
        predicted_message=predicted,
        has_message=has_message,
    )
    global_map = th.ones(4, 6, 3, 3)
    map_loss, pred_loss = auxiliary_losses(evaluation, global_map)
    assert map_loss.item() == pytest.approx(1.0)
    expected = ((predicted - received) ** 2).mean(-1)[has_message].mean()
    assert pred_loss.item() == pytest.approx(expected.item(), rel=1e-6)
    # garbage at dropout steps changes nothing
    predicted_garbage = th.where(has_message.unsqueeze(-1), predicted, predicted + 100.0)
    _, pred_loss_garbage = auxiliary_losses(evaluation._replace(predicted_message=predicted_garbage), global_map)
    assert pred_loss_garbage.item() == pytest.approx(pred_loss.item(), rel=1e-6)


def collected_model(swarm_keys=None, **kwargs):
    """A model whose buffer holds one rollout with dropouts and episode ends inside chunks.

    :param swarm_keys: replace the buffer by one storing these keys once per swarm (``None``: the model's own buffer)
    """
    model = make_model(**kwargs)
    if swarm_keys is not None:
        buffer = model.rollout_buffer
        model.rollout_buffer = SwarmRolloutBuffer(
            model.n_steps,
            model.observation_space,
            model.action_space,
            latent_dims=buffer.latent_dims,
            n_agents=buffer.n_agents,
            chunk_length=buffer.chunk_length,
            gamma=model.gamma,
            gae_lambda=model.gae_lambda,
            n_envs=model.n_envs,
            swarm_keys=swarm_keys,
        )
    model.learn(total_timesteps=1, log_interval=None)  # sets up the logger and env, collects one rollout, trains once
    callback = CallbackList([])  # SB3's no-op callback
    callback.init_callback(model)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, model.n_steps)
    return model


def test_recomputed_log_probs_match_collection():
    model = collected_model(config=SMALL.replace(max_steps=7))
    buffer = model.rollout_buffer
    starts = buffer.episode_starts
    assert starts[1:].sum() > 0 and (starts[1:].nonzero()[0] % model.chunk_length != 0).any()
    assert (buffer.observations["link_row"].sum(-1) == 0).any()  # some dropouts
    max_diff, max_value_diff = 0.0, 0.0
    with th.no_grad():
        for batch in buffer.get(model.batch_size):
            evaluation = model.policy.evaluate_sequences(
                batch.observations, batch.actions, batch.latent_state, batch.episode_starts
            )
            max_diff = max(max_diff, (evaluation.log_prob - batch.old_log_prob).abs().max().item())
            max_value_diff = max(max_value_diff, (evaluation.values - batch.old_values).abs().max().item())
    assert max_diff < 1e-5
    assert max_value_diff < 1e-5


def test_global_state_stored_once_per_swarm_feeds_identical_losses():
    per_swarm = collected_model(config=SMALL.replace(max_steps=7))  # the model's buffer: swarm_keys = the global state
    per_slot = collected_model(swarm_keys=(), config=SMALL.replace(max_steps=7))  # the old layout
    new, old = per_swarm.rollout_buffer, per_slot.rollout_buffer
    assert new.swarm_keys == ("swarm_proprio", "global_map") and old.swarm_keys == ()
    n_agents, n_swarms = new.n_agents, new.n_swarms
    assert new.observations["global_map"].shape == (20, n_swarms, 10, 10)
    assert old.observations["global_map"].shape == (20, n_swarms * n_agents, 10, 10)
    for key in ("swarm_proprio", "global_map"):  # the old layout held n_agents identical copies of each swarm's
        np.testing.assert_array_equal(np.repeat(new.observations[key], n_agents, axis=1), old.observations[key])
    saved = sum(old.observations[key].nbytes - new.observations[key].nbytes for key in new.swarm_keys)
    assert old.nbytes - new.nbytes == saved > 0
    clip_range = per_swarm.clip_range(1.0)
    np.random.seed(0)
    new_batches = list(new.get(per_swarm.batch_size))
    np.random.seed(0)
    old_batches = list(old.get(per_slot.batch_size))
    assert len(new_batches) == len(old_batches) > 1
    for new_batch, old_batch in zip(new_batches, old_batches):
        for key, value in old_batch.observations.items():
            assert th.equal(new_batch.observations[key], value), key
        new_losses = per_swarm._minibatch_losses(new_batch, clip_range, None)
        old_losses = per_slot._minibatch_losses(old_batch, clip_range, None)
        for term, value in old_losses.items():
            assert th.equal(new_losses[term], value), term


def test_one_train_step_reaches_every_parameter_group():
    model = collected_model()
    before = {name: param.detach().clone() for name, param in model.policy.named_parameters()}
    model.train()
    groups = ["map_encoder", "map_decoder", "task_encoder", "memory_encoder", "message_predictor", "action_", "critic_"]
    for group in groups:
        names = [name for name in before if name.startswith(group)]
        assert names, group
        assert any(not th.equal(before[n], dict(model.policy.named_parameters())[n]) for n in names), group


def test_map_loss_reaches_encoder_and_decoder_only():
    model = collected_model()
    batch = next(model.rollout_buffer.get(model.batch_size))
    evaluation = model.policy.evaluate_sequences(batch.observations, batch.actions, batch.latent_state, batch.episode_starts)
    map_loss, _ = auxiliary_losses(evaluation, batch.observations["global_map"])
    model.policy.zero_grad()
    map_loss.backward()
    for name, param in model.policy.named_parameters():
        reached = param.grad is not None and param.grad.abs().sum().item() > 0
        if name.startswith(("map_encoder", "map_decoder")):
            assert reached, name
        elif name.startswith(("action_", "critic_", "message_predictor")):
            assert not reached, name


def test_same_seed_same_parameters():
    params = []
    for _ in range(2):
        model = make_model(seed=3)
        model.learn(total_timesteps=2 * 20 * 3 * 2)
        params.append(th.cat([p.detach().flatten() for p in model.policy.parameters()]))
    assert th.equal(params[0], params[1])
    other = make_model(seed=4)
    other.learn(total_timesteps=2 * 20 * 3 * 2)
    assert not th.equal(params[0], th.cat([p.detach().flatten() for p in other.policy.parameters()]))


def test_save_load_roundtrip_and_other_swarm_size(tmp_path):
    model = make_model()
    model.learn(total_timesteps=120)
    path = tmp_path / "model.zip"
    model.save(path)
    env = make_vec_env(2, config=SMALL, seed=7)
    obs = env.reset()
    loaded = LatentSwarmPPO.load(path)
    actions, state = model.predict(obs, deterministic=True)
    actions_loaded, state_loaded = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(actions, actions_loaded)
    for field, field_loaded in zip(state, state_loaded):
        np.testing.assert_array_equal(field, field_loaded)
    # a model trained with N = 3 runs on a swarm of N = 5, also for further training
    env5 = make_vec_env(2, config=SMALL.replace(n_agents=5), seed=0)
    model5 = LatentSwarmPPO.load(path, env=env5)
    obs5 = env5.reset()
    actions5, state5 = model5.predict(obs5, episode_start=np.ones(10), deterministic=True)
    assert actions5.shape == (10, 4) and state5.map_state.shape[0] == 10
    model5.learn(total_timesteps=200)
    assert model5.n_agents == 5


def test_predict_accepts_pettingzoo_observations():
    from sb3_latentswarm.envs import SwarmReconEnv

    model = make_model()
    env = SwarmReconEnv(SMALL)
    observations, _ = env.reset(seed=0)
    actions, state = model.predict(observations, deterministic=True)
    assert set(actions) == set(env.agents)
    observations, *_ = env.step(actions)
    actions, _ = model.predict(observations, state=state, deterministic=True)
    assert all(env.action_space(a).contains(actions[a]) for a in env.agents)


def test_clear_errors_for_unsuitable_envs():
    import gymnasium as gym

    with pytest.raises(TypeError, match="Dict observation space"):
        LatentSwarmPPO("LatentSwarmPolicy", DummyVecEnv([lambda: gym.make("Pendulum-v1")]))
    with pytest.raises(ValueError, match="batch_size must hold at least one whole swarm"):
        make_model(batch_size=10)


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        (dict(n_steps=0), ValueError, "n_steps must be an int in \\[1, inf\\), got 0"),
        (dict(n_steps=-5), ValueError, "n_steps must be an int in \\[1, inf\\), got -5"),
        (dict(n_steps=2.5), TypeError, r"n_steps must be an int, got float \(2.5\)"),
        (dict(pred_coef="5"), TypeError, r"pred_coef must be a number, got str \('5'\)"),
        (dict(map_coef=float("nan")), ValueError, "map_coef must be a finite number in \\[0.0, inf\\), got nan"),
        (dict(vf_coef=float("inf")), ValueError, "vf_coef must be a finite number"),
        (dict(ent_coef=-0.1), ValueError, "ent_coef must be a finite number in"),
        (dict(max_grad_norm=0.0), ValueError, "max_grad_norm must be a finite number in \\(0.0"),
        (dict(gamma=1.5), ValueError, "gamma must be a finite number in \\[0.0, 1.0\\]"),
    ],
)
def test_bad_hyperparameters_fail_up_front(kwargs, error, message):
    with pytest.raises(error, match=message):
        make_model(**kwargs)


@pytest.mark.parametrize("n_steps, chunk_length", [(32, 16), (100, 25), (21, 21), (26, 13)])
def test_rollouts_the_chunk_length_does_not_divide_train_on_fitting_chunks(n_steps, chunk_length):
    config = SMALL.replace(max_steps=10)
    env = make_vec_env(2, config=config, seed=0)
    kwargs = dict(n_steps=n_steps, batch_size=6 * n_steps, n_epochs=1, policy_kwargs=TINY_POLICY, seed=0)
    if n_steps % 25:
        with pytest.warns(UserWarning, match=f"training sequences of {chunk_length} steps"):
            model = LatentSwarmPPO("LatentSwarmPolicy", env, **kwargs)
    else:
        model = LatentSwarmPPO("LatentSwarmPolicy", env, **kwargs)
    assert model.chunk_length == chunk_length
    model.learn(total_timesteps=6 * n_steps)
    assert model._n_updates == 1


def test_logs_paper_keys(tmp_path):
    from stable_baselines3.common.logger import configure

    model = make_model(config=SMALL.replace(max_steps=10))
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(total_timesteps=2 * 20 * 6)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in (
        "train/map_loss",
        "train/pred_loss",
        "rollout/coverage",
        "rollout/collisions",
        "rollout/link_up_rate",
        "rollout/dropout_rate",
        "rollout/ep_rew_mean",
    ):
        assert key in header, key


def test_truncated_swarms_are_bootstrapped_with_the_critic():
    model = make_model()
    obs = model.env.reset()
    n_slots = model.env.num_envs
    dones = np.zeros(n_slots, dtype=bool)
    dones[3:6] = True  # swarm 1 cut off by the horizon
    infos = [{} for _ in range(n_slots)]
    for slot in range(3, 6):
        infos[slot] = {"TimeLimit.truncated": True, "terminal_observation": {k: v[slot] for k, v in obs.items()}}
    bootstrap = model._truncation_values(infos, dones)
    with th.no_grad():
        expected = model.policy.predict_values({k: th.as_tensor(v) for k, v in obs.items()}).flatten().numpy()
    np.testing.assert_allclose(bootstrap[3:6], expected[3:6], rtol=1e-5)
    assert np.all(bootstrap[:3] == 0)
    for slot in range(3, 6):
        infos[slot]["TimeLimit.truncated"] = False  # terminated, not truncated: no bootstrap
    assert np.all(model._truncation_values(infos, dones) == 0)


def test_compile_latent_step_is_removed_with_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="compile_latent_step=True was removed.*never paid back"):
        make_model(compile_latent_step=True)
    model = make_model(compile_latent_step=False)  # the old default still accepted
    assert not hasattr(model.policy, "compile_latent_step")
    model.compile_latent_step = True  # what a file saved with the flag on holds
    model.save(tmp_path / "compiled")
    with pytest.warns(DeprecationWarning, match="runs eagerly"):
        loaded = LatentSwarmPPO.load(tmp_path / "compiled", env=model.env)
    assert not hasattr(loaded, "compile_latent_step")
    loaded.learn(loaded.n_steps * loaded.n_envs)
