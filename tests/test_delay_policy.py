"""Delayed messages (an extension): every policy pools each message as it was sent; a delay-aware one
(``delay_aware=True``) also reads its age, an input of the task and memory updates and the predictor; exact replay,
the per-UAV agent, ONNX and the UAV processes, the adapter.

What it receives is defined in ``docs/concepts.md``, "Delayed messages"."""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import CallbackList

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.agent import LatentSwarmAgent
from sb3_latentswarm.envs import LinkSpec, make_adapted_vec_env, make_vec_env
from sb3_latentswarm.envs.batched_core import SwarmBatch
from sb3_latentswarm.evaluation.actors import LatentActor
from sb3_latentswarm.latent_ppo.recurrence import pool_delayed_messages

DELAYED = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=12, num_obstacles=4, link_model="outage",
                      p_fail=0.3, message_delay=1, message_delay_model="uniform", message_expiry=2)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)
AWARE = dict(TINY_POLICY, delay_aware=True)
ACTION_ATOL = 1e-5


def aware_model(config=DELAYED, n_envs=2, seed=0, **kwargs):
    params = dict(n_steps=12, chunk_length=4, batch_size=18, n_epochs=1, policy_kwargs=AWARE, seed=seed)
    params.update(kwargs)
    return LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(n_envs, config=config, seed=seed), **params)


# ---------------------------------------------------------------------------------------------- the definition
def test_pooled_message_and_age_on_a_hand_built_case():
    # 1 swarm, 3 agents, d = 1, expiry E = 2; sent[0, j, a] = 10 a + j: what j sent a steps before the on-time message
    sent = (10.0 * th.arange(3.0)[None, None, :, None] + th.arange(3.0)[None, :, None, None])  # (1, N, E + 1, 1)
    mask = th.tensor([[[0.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    age = th.tensor([[[0.0, 2.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    received, has_message, message_age = pool_delayed_messages(sent, mask, age, expiry=2)
    # agent 0: j = 1 two steps late (21) and j = 2 on time (2); agent 1: nothing; agent 2: j = 0 one step late (10)
    np.testing.assert_allclose(received[:, 0].numpy(), [(21.0 + 2.0) / 2, 0.0, 10.0])
    np.testing.assert_allclose(message_age[:, 0].numpy(), [(2.0 + 0.0) / 2 / 2, 0.0, 1.0 / 2])
    assert has_message.tolist() == [True, False, True]


@pytest.mark.parametrize("delay_aware", [True, False])
def test_the_policy_pools_what_each_sender_sent_on_a_delay_and_expiry_sequence(delay_aware):
    """A hand-built delivery sequence (mean delay 1, expiry E = 1: a message 2 steps late is lost; of two messages of
    one sender arriving together the fresher is kept): the pooled message at t is the mean of z_{t-1-a}^j over what
    arrived, the z each sender broadcast a steps before t (its ``sent_message`` at step t - a), for every policy; the
    age input (the mean delay / E) only for a delay-aware one."""
    env = make_vec_env(1, config=DELAYED.replace(message_expiry=1), seed=0)
    policy = LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=4, chunk_length=4, batch_size=12,
                            policy_kwargs=dict(TINY_POLICY, delay_aware=delay_aware), seed=0).policy
    assert policy.message_expiry == 1
    # link 1 -> 0 (receiver 0 reads row 0): sent at t with delay d, delivered at t + d when d <= 1
    #   t0: d = 2 (lost); t1: d = 1 (arrives t2); t2: d = 0 (arrives t2, fresher: kept); t3: d = 1 (arrives t4)
    # link 2 -> 0: on time at every step; link 0 -> 2: sent at t2 with d = 1 (arrives t3); no other link delivers
    mask = np.zeros((5, 3, 3), dtype=np.float32)
    age = np.zeros((5, 3, 3), dtype=np.float32)
    mask[:, 0, 2] = 1.0
    mask[2, 0, 1], mask[4, 0, 1], age[4, 0, 1] = 1.0, 1.0, 1.0
    mask[3, 2, 0], age[3, 2, 0] = 1.0, 1.0
    rng = np.random.default_rng(0)
    state = policy.initial_state(3)
    sent_at: list[np.ndarray] = []  # sent_at[t][j] = z_{t-1}^j, what j broadcast for step t
    for t in range(5):
        obs = {"local_obs": th.as_tensor(rng.integers(-1, 2, (3, *env.observation_space["local_obs"].shape)),
                                         dtype=th.float32),
               "proprio": th.as_tensor(rng.random((3, policy.proprio_dim)), dtype=th.float32),
               "link_row": th.as_tensor(mask[t]), "link_age": th.as_tensor(age[t])}
        with th.no_grad():
            step = policy.latent_step(obs, state, th.tensor([1.0 if t == 0 else 0.0] * 3))
        sent_at.append(step.sent_message.numpy())
        for i in range(3):
            senders = np.flatnonzero(mask[t, i])
            expected = np.mean([sent_at[t - int(age[t, i, j])][j] for j in senders], axis=0) if len(senders) else 0.0
            np.testing.assert_allclose(step.received_message[i].numpy(), expected, rtol=0, atol=1e-6)
            expected_age = age[t, i, senders].mean() / 1 if len(senders) else 0.0
            if delay_aware:
                assert step.state.prev_message_age[i, 0].item() == pytest.approx(expected_age)
            else:
                assert step.state.prev_message_age.shape == (3, 0)
        state = step.state
    # the late messages carried older z than the on-time ones would have
    assert not np.allclose(sent_at[3][1], sent_at[4][1])


def test_delay_aware_is_opt_in_and_off_changes_nothing():
    config = DELAYED
    kwargs = dict(n_steps=4, chunk_length=4, batch_size=12, policy_kwargs=TINY_POLICY, seed=0)
    # without delay: no link_age, both delay fields have zero columns (the paper's policy)
    paper = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=config.replace(message_delay=0), seed=0),
                           **kwargs).policy
    assert not paper.delayed_links and paper.latent_dims[6:] == (0, 0) and "link_age" not in paper.layout.actor_keys
    # under delay without delay_aware: arrivals pooled as sent (the history is carried), no age input
    off = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=config, seed=0), **kwargs).policy
    assert not off.delay_aware and off.delayed_links and "link_age" in off.layout.actor_keys
    assert off.latent_dims[6:] == (2 * off.message_dim, 0)
    assert "delay_aware" not in off._get_constructor_parameters()
    assert off.task_encoder.weight_ih.shape == paper.task_encoder.weight_ih.shape
    on = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=config, seed=0), n_steps=4, chunk_length=4, batch_size=12,
                        policy_kwargs=AWARE, seed=0).policy
    assert on.latent_dims[6:] == (2 * on.message_dim, 1)
    assert on.task_encoder.weight_ih.shape[1] == off.task_encoder.weight_ih.shape[1] + 1
    assert on.memory_encoder.weight_ih.shape[1] == off.memory_encoder.weight_ih.shape[1] + 1
    assert on.message_predictor[0].weight.shape[1] == off.message_predictor[0].weight.shape[1] + 1
    # without delay (no link_age), delay_aware=True is refused
    with pytest.raises(ValueError, match="delay_aware=True reads the observation key 'link_age'"):
        LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=config.replace(message_delay=0), seed=0),
                       policy_kwargs=AWARE)
    with pytest.raises(TypeError, match="delay_aware must be a bool"):
        LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=config, seed=0), policy_kwargs=dict(delay_aware=1))


# ---------------------------------------------------------------------------------------------- training
def test_replayed_log_probs_match_the_rollout_under_delay():
    model = aware_model(config=DELAYED.replace(max_steps=7))
    model.learn(total_timesteps=1, log_interval=None)
    callback = CallbackList([])
    callback.init_callback(model)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, model.n_steps)
    buffer = model.rollout_buffer
    ages = buffer.observations["link_age"]
    assert (ages > 0).any() and (buffer.episode_starts[1:].nonzero()[0] % model.chunk_length != 0).any()
    max_diff = 0.0
    with th.no_grad():
        for batch in buffer.get(model.batch_size):
            assert batch.latent_state.sent_history.shape[-1] == 2 * model.policy.message_dim
            evaluation = model.policy.evaluate_sequences(batch.observations, batch.actions, batch.latent_state,
                                                         batch.episode_starts)
            max_diff = max(max_diff, (evaluation.log_prob - batch.old_log_prob).abs().max().item())
    assert max_diff < 1e-5


def test_the_chunked_sequence_replay_agrees_with_the_rollout_step_under_delay():
    from sb3_latentswarm.latent_ppo.recurrence import replay_sequence

    policy = aware_model(n_envs=1).policy
    rng = np.random.default_rng(0)
    n_steps, batch = 6, 3
    link_row = (rng.random((n_steps, batch, 3)) < 0.6).astype(np.float32) * (1 - np.eye(3, dtype=np.float32))
    obs = {"local_obs": th.as_tensor(rng.integers(-1, 2, (n_steps, batch, policy.local_obs_dim)), dtype=th.float32),
           "proprio": th.as_tensor(rng.random((n_steps, batch, policy.proprio_dim)), dtype=th.float32),
           "link_row": th.as_tensor(link_row),
           "link_age": th.as_tensor(rng.integers(0, 3, link_row.shape).astype(np.float32) * link_row)}
    starts = th.zeros(n_steps, batch)
    starts[3] = 1.0  # an episode starts inside the sequence: the carried history is zeroed there
    state = policy.initial_state(batch)
    state = state._replace(sent_history=th.randn(state.sent_history.shape), map_state=th.randn(state.map_state.shape))
    inputs = policy.step_inputs(obs, starts)
    with th.no_grad():
        eager, sequence = (replay_sequence(policy, inputs, state, linears) for linears in ("eager", "sequence"))
    for a, b in zip(eager, sequence):
        np.testing.assert_allclose(a.float().numpy(), b.float().numpy(), rtol=0, atol=1e-5)


def test_evaluation_runs_a_delay_aware_model_under_the_conditions():
    from sb3_latentswarm.evaluation import evaluate

    model = aware_model(n_envs=1)
    for condition in ("proposed", "no_comm", "hold_last"):
        df = evaluate(model, condition, n_episodes=1, seed=5, n_envs=1)
        assert len(df) == 1 and np.isfinite(df["coverage"]).all()
    # without delay there is no age to read: a clear error before any episode, not a missing observation key
    with pytest.raises(ValueError, match="delay-aware.*message_delay=0"):
        evaluate(model, "proposed", n_episodes=1, seed=5, n_envs=1, config=model.swarm_config.replace(message_delay=0))


def test_a_seeded_run_trains_saves_and_resumes_exactly(tmp_path):
    from sb3_latentswarm.runs.checkpoints import SwarmCheckpointCallback, load_checkpoint

    per_update = 12 * 2 * 3
    model = aware_model()
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(3 * per_update, callback=SwarmCheckpointCallback(per_update, tmp_path, keep=10))
    assert any(not th.equal(a, b) for a, b in zip(before, model.policy.parameters()))
    assert np.isfinite(model.logger.name_to_value["train/pred_loss"])
    resumed = load_checkpoint(tmp_path / f"checkpoint_{per_update}_steps.zip",
                              env=make_vec_env(2, config=DELAYED, seed=99))
    assert resumed.policy.delay_aware
    resumed.learn(3 * per_update - resumed.num_timesteps, reset_num_timesteps=False)
    for a, b in zip(model.policy.state_dict().values(), resumed.policy.state_dict().values()):
        assert th.equal(a, b)
    model.save(tmp_path / "model.zip")
    loaded = LatentSwarmPPO.load(tmp_path / "model.zip")
    assert loaded.policy.delay_aware and loaded.policy.message_expiry == DELAYED.message_expiry


# ---------------------------------------------------------------------------------------------- the per-UAV agent
def test_agents_fed_each_message_as_sent_fly_the_batched_episode():
    """N LatentSwarmAgents, each given the messages that arrived as their senders broadcast them (z_{t-1-a}) with their
    ages, act as the batched policy on the same episode."""
    model = _moving_aware_model()
    policy, n = model.policy, DELAYED.n_agents
    cores = SwarmBatch(DELAYED, 1), SwarmBatch(DELAYED, 1)
    for core in cores:
        core.reset(seeds=[5])
    agents = [LatentSwarmAgent(model) for _ in range(n)]
    for agent in agents:
        agent.reset()
    batched = LatentActor(policy, n, n)
    starts = np.ones(n, dtype=np.float32)
    sent_at: list[np.ndarray] = []
    late = 0
    for _ in range(DELAYED.max_steps):
        core, other = cores
        sent_at.append(np.stack([agent.message() for agent in agents]))
        links, ages = core.link_rows[0], core.link_ages[0].astype(int)
        actions = []
        for i, agent in enumerate(agents):
            senders = np.flatnonzero(links[i] > 0)
            messages = np.array([sent_at[-1 - ages[i, j]][j] for j in senders]).reshape(len(senders), agent.message_dim)
            late += int((ages[i, senders] > 0).sum())
            actions.append(agent.step({"local_obs": core.local_obs[0, i], "proprio": core.proprio[0, i]}, messages,
                                      deterministic=True, message_ages=ages[i, senders]))
        obs = {"local_obs": other.local_obs.reshape(n, -1).copy(), "proprio": other.proprio.reshape(n, -1).copy(),
               "link_row": other.link_rows.reshape(n, n).copy(), "link_age": other.link_ages.reshape(n, n).copy(),
               "global_map": other.global_map.copy()}
        batched_actions = batched.act(obs, starts, None)[0]
        starts[:] = 0.0
        np.testing.assert_allclose(np.stack(actions), batched_actions, rtol=0, atol=ACTION_ATOL)
        done = [c.step(c.check_actions(a.reshape(1, n, -1)))[1:] for c, a in zip(cores, (np.stack(actions),
                                                                                          batched_actions))]
        if done[0][0][0] or done[0][1][0]:
            break
    assert late > 0


def test_agent_message_ages_are_checked():
    model = aware_model(n_envs=1)
    agent = LatentSwarmAgent(model)
    agent.reset(seed=0)
    assert agent.delay_aware and agent.message_expiry == DELAYED.message_expiry
    obs = {"local_obs": np.zeros(model.observation_space["local_obs"].shape), "proprio": np.zeros(8)}
    two = np.zeros((2, agent.message_dim))
    with pytest.raises(ValueError, match=r"message_ages must hold one age in \[0, 2\] \(steps\) per received message"):
        agent.step(obs, two, message_ages=[0, 3])
    with pytest.raises(ValueError, match="message_ages must hold"):
        agent.step(obs, two, message_ages=[1])
    agent.step(obs, two, message_ages=[0, 2])
    plain = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=DELAYED, seed=0), policy_kwargs=TINY_POLICY)
    other = LatentSwarmAgent(plain)
    other.reset(seed=0)
    assert not other.delay_aware
    with pytest.raises(ValueError, match="does not read message ages .* without their ages, or train with"):
        other.step(obs, two, message_ages=[0, 1])


def test_a_delayed_model_takes_another_swarm_size_and_names_a_missing_delay():
    model = aware_model(n_envs=1)
    model.set_env(make_vec_env(1, config=DELAYED.replace(n_agents=4), seed=0))  # link_age (N,) follows N
    assert model.n_agents == 4
    with pytest.raises(ValueError, match=r"'link_age' of training .* is missing from the new env .*message_delay > 0"):
        model.set_env(make_vec_env(1, config=DELAYED.replace(message_delay=0), seed=0))


def _moving_aware_model():
    model = aware_model(n_envs=1)
    generator = th.Generator().manual_seed(1)
    with th.no_grad():  # give the untrained actor actions that move the swarm
        model.policy.action_mean.weight.copy_(th.randn(model.policy.action_mean.weight.shape, generator=generator))
    return model


def test_a_delay_aware_policy_exports_with_its_age_input_and_flies_in_the_simulator(tmp_path):
    """Format 2: the exported step reads the age; the simulator relays each late message as it was sent with its age
    (wire version 2); the ONNX UAVs fly the episode of the torch UAVs, and the torch UAVs the batched evaluation's."""
    pytest.importorskip("onnxruntime")
    from sb3_latentswarm.agent import OnnxSwarmAgent, export_onnx
    from sb3_latentswarm.agent.processes import InProcessSwarm, Simulator
    from sb3_latentswarm.evaluation import evaluate

    model = _moving_aware_model()
    check = export_onnx(model, tmp_path / "aware.onnx")
    assert check.max_abs_error <= check.tolerance
    onnx_agent = OnnxSwarmAgent(tmp_path / "aware.onnx")
    assert onnx_agent.metadata["format"] == 2 and onnx_agent.delay_aware
    assert onnx_agent.message_expiry == DELAYED.message_expiry
    assert [i.name for i in onnx_agent.session.get_inputs()][6:] == [
        "prev_message_age", "local_obs", "proprio", "message_mean", "message_count", "message_age", "noise"]
    # one step with and without ages differs (the age is read), and bad ages are refused as by the torch agent
    obs = {"local_obs": np.zeros(model.observation_space["local_obs"].shape), "proprio": np.zeros(8)}
    two = np.ones((2, onnx_agent.message_dim))
    actions = []
    for ages in ([0, 0], [2, 2]):
        onnx_agent.reset(seed=0)
        actions.append(onnx_agent.step(obs, two, deterministic=True, message_ages=ages))
    assert not np.allclose(*actions)
    with pytest.raises(ValueError, match="message_ages must hold"):
        onnx_agent.step(obs, two, message_ages=[0, 3])

    seed = 11
    torch_uavs = Simulator(InProcessSwarm([LatentSwarmAgent(model) for _ in range(DELAYED.n_agents)]), DELAYED)
    onnx_uavs = Simulator(InProcessSwarm([OnnxSwarmAgent(tmp_path / "aware.onnx") for _ in range(DELAYED.n_agents)]),
                          DELAYED)
    reference = torch_uavs.fly(seed, deterministic=True)
    record = onnx_uavs.fly(seed, deterministic=True)
    np.testing.assert_allclose(record.actions, reference.actions, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(record.delivered, reference.delivered)
    row = evaluate(model, "proposed", n_episodes=1, seed=seed, deterministic=True, n_envs=1).iloc[0]
    assert row["coverage"] == pytest.approx(100.0 * reference.summary["coverage"], abs=1e-9)
    assert row["collisions"] == reference.summary["collisions"]
    with pytest.raises(ValueError, match="fly it with the delayed links it was trained with"):
        Simulator(InProcessSwarm([onnx_agent] * DELAYED.n_agents), DELAYED.replace(message_delay=0))


def test_delay_aware_uav_processes_fly_the_in_process_episode(tmp_path):
    """The same episode through real UAV processes (UDP, the ages on the wire) as in process, bit for bit."""
    pytest.importorskip("onnxruntime")
    from sb3_latentswarm.agent import OnnxSwarmAgent, export_onnx
    from sb3_latentswarm.agent.processes import InProcessSwarm, ProcessSwarm, Simulator

    path = tmp_path / "aware.onnx"
    export_onnx(_moving_aware_model(), path, n_check_steps=2)
    expected = Simulator(InProcessSwarm([OnnxSwarmAgent(path) for _ in range(DELAYED.n_agents)]), DELAYED).fly(3)
    with ProcessSwarm(path, DELAYED.n_agents) as swarm:
        assert swarm.spec.delay_aware and swarm.spec.message_expiry == DELAYED.message_expiry
        record = Simulator(swarm, DELAYED, deadline=20.0).fly(3)
    assert not record.missed.any()
    np.testing.assert_array_equal(record.actions, expected.actions)
    np.testing.assert_array_equal(record.delivered, expected.delivered)


def test_the_wire_carries_message_ages():
    from sb3_latentswarm.agent.wire import Kind, Wire, WireSpec

    spec = WireSpec(4, 2, 3, 2, delay_aware=True, message_expiry=6)
    wire = Wire(spec)
    hello = wire.decode(Wire.hello(1, 1234, spec))
    assert hello is not None and hello.spec == spec
    data = wire.step(0, 5, 1, np.zeros(4), np.ones(2), [0, 2], np.arange(6.0).reshape(2, 3), ages=[0, 4])
    packet = wire.decode(data)
    assert packet is not None and packet.kind == Kind.STEP
    assert packet.senders.tolist() == [0, 2] and packet.ages.tolist() == [0, 4]
    np.testing.assert_array_equal(packet.messages, np.arange(6.0).reshape(2, 3))
    assert wire.decode(wire.step(0, 5, 1, np.zeros(4), np.ones(2), [], np.zeros((0, 3)))).ages.tolist() == []
    with pytest.raises(ValueError, match="one age per sender"):
        wire.step(0, 5, 1, np.zeros(4), np.ones(2), [0, 2], np.zeros((2, 3)), ages=[1])
    assert wire.decode(b"LSW1" + data[4:]) is None  # version 1 (no ages) is not read


# ---------------------------------------------------------------------------------------------- the adapter
EXAMPLE = runpy.run_path(str(Path(__file__).resolve().parents[1] / "examples" / "own_env.py"))
DELAYED_SPEC = LinkSpec(link_model="outage", p_fail=0.2, message_delay=1, message_delay_model="uniform",
                        message_expiry=2)


def test_the_adapter_gives_link_ages_of_a_delayed_link_model():
    env = make_adapted_vec_env(EXAMPLE["Rendezvous"], 2, link_model=DELAYED_SPEC, seed=0, monitor=False)
    assert env.observation_space["link_age"] == env.observation_space["link_age"].__class__(0.0, 2.0, (3,), np.float32)
    obs = env.reset()
    seen_late = False
    for _ in range(30):
        assert all({key: value[k] for key, value in obs.items()} in env.observation_space for k in range(6))
        assert (obs["link_age"][obs["link_row"] == 0] == 0).all()
        seen_late |= bool((obs["link_age"] > 0).any())
        obs, _, dones, infos = env.step(np.zeros((6, 1), dtype=np.float32))
        for slot in np.flatnonzero(dones):
            assert (infos[slot]["terminal_observation"]["link_age"] == 0).all()
    assert seen_late
    assert "link_age" not in make_adapted_vec_env(EXAMPLE["Rendezvous"], 1, seed=0).observation_space.spaces


def test_a_delayed_link_model_without_an_expiry_is_refused():
    from sb3_latentswarm.links import FixedLinks

    class LateLinks(FixedLinks):
        has_delay = True  # but no expiry: the link_age space would have no bound

    with pytest.raises(ValueError, match=r"LateLinks has delay but no int expiry >= 0 .* got expiry=None"):
        make_adapted_vec_env(EXAMPLE["Rendezvous"], 1, link_model=LateLinks(1, 3, up=True))


def test_latent_ppo_trains_delay_aware_on_the_custom_env():
    env = make_adapted_vec_env(EXAMPLE["Rendezvous"], 2, link_model=DELAYED_SPEC,
                               position_fn=EXAMPLE["rendezvous_positions"], seed=0)
    model = LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=20, chunk_length=20, n_epochs=2, batch_size=60,
                           policy_kwargs=dict(AWARE, latent_dim=8), seed=0)
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(2 * 20 * 6, log_interval=10**6)
    assert any(not th.equal(a, b) for a, b in zip(before, model.policy.parameters()))
    assert np.isfinite(model.logger.name_to_value["train/pred_loss"])
    assert model.logger.name_to_value["train/approx_kl"] < 0.1


def test_latent_ppo_trains_delay_aware_on_mpe2_simple_spread():
    mpe = pytest.importorskip("mpe2.simple_spread_v3", reason="the mpe extra is not installed")
    from sb3_latentswarm.envs.mpe import mpe_positions

    def simple_spread():
        return mpe.parallel_env(N=3, continuous_actions=True, max_cycles=10, num_agent_neighbors=1,
                                num_landmark_neighbors=1)

    env = make_adapted_vec_env(simple_spread, 2, link_model=DELAYED_SPEC, position_fn=mpe_positions, seed=0)
    model = LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=10, chunk_length=10, n_epochs=1, batch_size=30,
                           policy_kwargs=AWARE, seed=0)
    model.learn(2 * 10 * 6, log_interval=10**6)
    assert model.num_timesteps == 120
    assert np.isfinite(model.logger.name_to_value["train/pred_loss"])
