"""The per-UAV agent: N agents fed the messages routed by the env's link mask fly the batched policy's episodes.

Tolerance: actions agree to ACTION_ATOL = 1e-5 (the agent runs each UAV's GEMMs with batch 1, the batched policy with
batch N, which may round differently in the last float32 bit); the episodes (coverage, collisions) are equal.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.agent import LatentSwarmAgent
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.envs.batched_core import SwarmBatch
from sb3_latentswarm.evaluation import HELD_OUT_SEED, evaluate, policy_switches
from sb3_latentswarm.evaluation.actors import LatentActor
from sb3_latentswarm.evaluation.conditions import condition_config

CONFIG = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=15, num_obstacles=4, p_fail=0.5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)
ACTION_ATOL = 1e-5
NOISE_STREAM = 0x5EED  # the evaluation runner's action-noise stream: episode seed s draws from default_rng([s, 0x5EED])
CONDITIONS = {"predicted": "proposed", "zero": "no_predictor", "hold_last": "hold_last", "own_message": "own_message"}


def tiny_model():
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=CONFIG, seed=0), n_steps=10, chunk_length=5,
                           batch_size=15, policy_kwargs=TINY_POLICY, seed=0)
    generator = th.Generator().manual_seed(1)
    with th.no_grad():  # an untrained actor's mean is ~0 (gain 0.01): give it actions that move the swarm
        model.policy.action_mean.weight.copy_(th.randn(model.policy.action_mean.weight.shape, generator=generator))
    return model


@pytest.fixture(scope="module")
def model():
    return tiny_model()


def fly(model, condition, seed, deterministic):
    """One episode twice in lockstep: N LatentSwarmAgents with messages routed by the link mask, and the evaluation
    runner's batched actor. Returns both swarm summaries and the largest action difference."""
    policy = model.policy
    config = condition_config(CONFIG, condition, CONFIG.p_fail)
    n, action_dim = config.n_agents, policy.action_dim
    cores = SwarmBatch(config, 1), SwarmBatch(config, 1)
    for core in cores:
        core.reset(seeds=[seed])
    agents = [LatentSwarmAgent(model) for _ in range(n)]
    for agent in agents:
        agent.reset()
    batched = LatentActor(policy, n, n)
    rng = np.random.default_rng([seed, NOISE_STREAM])
    starts = np.ones(n, dtype=np.float32)
    largest = 0.0
    while True:
        noise = None if deterministic else rng.standard_normal((n, action_dim)).astype(np.float32)
        # the agents: every UAV broadcasts z_{t-1}, UAV i receives the rows j with link_rows[i, j] = 1
        core = cores[0]
        sent = np.stack([agent.message() for agent in agents])
        links = core.link_rows[0]
        actions = np.stack([
            agent.step({"local_obs": core.local_obs[0, i], "proprio": core.proprio[0, i]}, sent[links[i] > 0],
                       deterministic=deterministic, noise=None if noise is None else noise[i])
            for i, agent in enumerate(agents)
        ])
        # the batched actor on its own copy of the episode
        other = cores[1]
        obs = {"local_obs": other.local_obs.reshape(n, -1).copy(), "proprio": other.proprio.reshape(n, -1).copy(),
               "link_row": other.link_rows.reshape(n, n).copy(), "global_map": other.global_map.copy()}
        batched_actions = batched.act(obs, starts, noise)[0]
        starts[:] = 0.0
        largest = max(largest, float(np.abs(actions - batched_actions).max()))
        done = [c.step(c.check_actions(a.reshape(1, n, -1)))[1:] for c, a in zip(cores, (actions, batched_actions))]
        assert done[0] == done[1]
        if done[0][0][0] or done[0][1][0]:
            return cores[0].swarm_summary(0), cores[1].swarm_summary(0), largest


@pytest.mark.parametrize("deterministic", [True, False])
@pytest.mark.parametrize("substitute", list(CONDITIONS))
def test_agents_fly_the_batched_episodes(model, substitute, deterministic):
    condition = CONDITIONS[substitute]
    seed = HELD_OUT_SEED + 7
    with policy_switches(model.policy, condition):
        assert model.policy.message_substitute == substitute
        rows = []
        for k in range(2):
            agents_summary, batched_summary, largest = fly(model, condition, seed + k, deterministic)
            assert largest < ACTION_ATOL
            assert agents_summary["coverage"] == batched_summary["coverage"]
            assert agents_summary["collisions"] == batched_summary["collisions"]
            assert agents_summary["dropout_rate"] > 0  # the substitute was used
            rows.append(agents_summary)
    df = evaluate(model, condition, n_episodes=2, seed=seed, deterministic=deterministic, n_envs=1)
    np.testing.assert_allclose(df["coverage"], [100.0 * row["coverage"] for row in rows], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(df["collisions"], [row["collisions"] for row in rows])


def test_deterministic_agents_act_as_model_predict(model):
    env = make_vec_env(1, config=CONFIG, seed=HELD_OUT_SEED)
    obs = env.reset()
    agents = [LatentSwarmAgent(model) for _ in range(CONFIG.n_agents)]
    for agent in agents:
        agent.reset()
    state, starts = None, np.ones(CONFIG.n_agents)
    for _ in range(6):
        expected, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
        sent = np.stack([agent.message() for agent in agents])
        actions = np.stack([
            agent.step({key: obs[key][i] for key in obs}, sent[obs["link_row"][i] > 0], deterministic=True)
            for i, agent in enumerate(agents)
        ])
        np.testing.assert_allclose(actions, expected, rtol=0, atol=ACTION_ATOL)
        obs, _, dones, _ = env.step(expected)
        starts = dones
        assert not dones.any()


def test_message_is_the_state_and_info_is_consistent(model):
    agent = LatentSwarmAgent(model)
    agent.reset(seed=3)
    d = agent.message_dim
    np.testing.assert_array_equal(agent.message(), np.zeros(d, dtype=np.float32))
    obs = {"local_obs": np.zeros(model.policy.observation_space["local_obs"].shape), "proprio": np.full(8, 0.5)}
    action, info = agent.step(obs, np.ones((2, d)), return_info=True)
    assert action.shape == (model.policy.action_dim,) and action.dtype == np.float32
    np.testing.assert_array_equal(info.message, agent.message())
    np.testing.assert_array_equal(info.received_message, np.ones(d))
    np.testing.assert_array_equal(info.best_message, info.received_message)
    assert info.has_message
    _, info = agent.step(obs, [], return_info=True)  # nothing arrived: the predictor's message
    assert not info.has_message
    np.testing.assert_allclose(info.best_message, info.predicted_message, atol=0)
    # the agent's own generator, seeded by reset: the same sampled actions after the same reset
    agent.reset(seed=3)
    first = [agent.step(obs, []) for _ in range(3)]
    agent.reset(seed=3)
    np.testing.assert_array_equal(first, [agent.step(obs, []) for _ in range(3)])


def test_bad_inputs_raise_and_leave_the_state_unchanged(model):
    agent = LatentSwarmAgent(model)
    d = agent.message_dim
    obs = {"local_obs": np.zeros(model.policy.observation_space["local_obs"].shape), "proprio": np.zeros(8)}
    with pytest.raises(RuntimeError, match="reset"):
        agent.step(obs, [])
    with pytest.raises(RuntimeError, match="reset"):
        agent.message()
    agent.reset(seed=0)
    agent.step(obs, np.ones((1, d)), deterministic=True)
    before = agent.message()
    nan_message = np.ones((2, d))
    nan_message[1, 0] = np.nan
    cases = [
        (ValueError, rf"shape \(k, {d}\)", dict(observation=obs, received_messages=np.ones((1, d + 1)))),
        (ValueError, r"rows \[1\] hold a non-finite", dict(observation=obs, received_messages=nan_message)),
        (ValueError, "local_obs'] must have shape", dict(observation={**obs, "local_obs": np.zeros(3)}, received_messages=[])),
        (ValueError, "proprio'] must have shape", dict(observation={**obs, "proprio": np.zeros(9)}, received_messages=[])),
        (ValueError, "lacks the key", dict(observation={"proprio": np.zeros(8)}, received_messages=[])),
        (TypeError, "mapping", dict(observation=np.zeros(8), received_messages=[])),
        (TypeError, "numbers", dict(observation=obs, received_messages=[["a"] * d])),
        (ValueError, "noise must have shape", dict(observation=obs, received_messages=[], noise=np.zeros(2))),
        (ValueError, "mean action", dict(observation=obs, received_messages=[], deterministic=True, noise=np.zeros(4))),
    ]
    for error, match, kwargs in cases:
        with pytest.raises(error, match=match):
            agent.step(**kwargs)
        np.testing.assert_array_equal(agent.message(), before)
    with pytest.raises(TypeError, match="LatentSwarmPPO or a LatentSwarmPolicy"):
        LatentSwarmAgent(object())


# ---------------------------------------------------------------------------------------------- ONNX export
ONNX_ATOL = 1e-5


def fly_pair(agents, others, config, seed):
    """One sampled episode of one swarm, stepped by ``agents`` (messages routed by the link mask); ``others`` get the
    same inputs. Returns the largest difference of actions and messages between the two."""
    n = config.n_agents
    core = SwarmBatch(config, 1)
    core.reset(seeds=[seed])
    for agent in (*agents, *others):
        agent.reset()
    rng = np.random.default_rng([seed, NOISE_STREAM])
    largest, steps = 0.0, 0
    while True:
        noise = rng.standard_normal((n, 4)).astype(np.float32)
        links = core.link_rows[0]
        sent = [np.stack([agent.message() for agent in group]) for group in (agents, others)]
        largest = max(largest, float(np.abs(sent[0] - sent[1]).max()))
        actions = []
        for group, messages in zip((agents, others), sent):
            actions.append(np.stack([
                agent.step({"local_obs": core.local_obs[0, i], "proprio": core.proprio[0, i]}, messages[links[i] > 0],
                           noise=noise[i])
                for i, agent in enumerate(group)
            ]))
        largest = max(largest, float(np.abs(actions[0] - actions[1]).max()))
        steps += 1
        _, terminated, truncated = core.step(core.check_actions(actions[0].reshape(1, n, -1)))
        if terminated[0] or truncated[0]:
            return largest, steps


def test_onnx_agent_equals_the_torch_agent(model, tmp_path):
    pytest.importorskip("onnxruntime")
    from sb3_latentswarm.agent import OnnxSwarmAgent, export_onnx

    path = tmp_path / "uav.onnx"
    check = export_onnx(model, path)
    assert check.max_abs_error <= check.tolerance == ONNX_ATOL and check.autocast_max_abs_error is None
    assert path.stat().st_size == check.size_bytes and not list(tmp_path.glob("*.tmp*"))
    onnx_agents = [OnnxSwarmAgent(path) for _ in range(CONFIG.n_agents)]
    torch_agents = [LatentSwarmAgent(model) for _ in range(CONFIG.n_agents)]
    largest, steps = fly_pair(onnx_agents, torch_agents, CONFIG, HELD_OUT_SEED + 11)
    assert steps == CONFIG.max_steps and largest < ONNX_ATOL
    # the same checks as the torch agent
    agent = onnx_agents[0]
    with pytest.raises(ValueError, match="non-finite"):
        agent.step({"local_obs": np.zeros(25), "proprio": np.zeros(8)}, np.full((1, agent.message_dim), np.nan))
    with pytest.raises(RuntimeError, match="reset"):
        OnnxSwarmAgent(path).message()


def test_bf16_model_exports_in_float32_and_reports_its_difference(tmp_path):
    pytest.importorskip("onnxruntime")
    from sb3_latentswarm.agent import export_onnx

    model = tiny_model()
    model.policy.autocast = "bf16"
    check = export_onnx(model, tmp_path / "bf16.onnx", n_check_steps=4)
    assert check.max_abs_error <= ONNX_ATOL
    assert 0 < check.autocast_max_abs_error < 0.1  # bf16 rounding of the model's own step
    assert model.policy.autocast == "bf16"


def test_a_failed_check_writes_nothing(model, tmp_path, monkeypatch):
    pytest.importorskip("onnxruntime")
    from sb3_latentswarm.agent import export, export_onnx

    path = tmp_path / "uav.onnx"
    path.write_bytes(b"old")
    monkeypatch.setattr(export, "EXPORT_TOLERANCE", -1.0)
    with pytest.raises(RuntimeError, match="nothing written"):
        export_onnx(model, path, n_check_steps=2)
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["uav.onnx"]


def test_the_onnx_runtime_does_not_import_torch(model, tmp_path):
    pytest.importorskip("onnxruntime")
    from sb3_latentswarm.agent import export_onnx

    path = tmp_path / "uav.onnx"
    export_onnx(model, path, n_check_steps=2)
    code = (
        "import sys, numpy as np\n"
        "from sb3_latentswarm.agent import OnnxSwarmAgent\n"
        f"agent = OnnxSwarmAgent({str(path)!r})\n"
        "agent.reset(seed=0)\n"
        "action = agent.step({'local_obs': np.zeros(25), 'proprio': np.zeros(8)}, [agent.message()])\n"
        "assert action.shape == (4,), action.shape\n"
        "assert 'torch' not in sys.modules, sorted(m for m in sys.modules if m.startswith('torch'))\n"
    )
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 0, result.stderr


def test_squashed_actor_on_another_box_flies_the_same_in_onnx_and_torch(tmp_path):
    """The squashed Gaussian rescaled to a box other than [-1, 1] (LatentSwarmPolicy.env_actions): the exported graph
    and the torch agent act alike, inside the box, and the torch agent's action is the policy's own mapping."""
    pytest.importorskip("onnxruntime")
    from gymnasium import spaces

    from sb3_latentswarm import LatentSwarmPolicy
    from sb3_latentswarm.agent import OnnxSwarmAgent, export_onnx

    env = make_vec_env(1, config=CONFIG, seed=0)
    low, high = np.array([-0.5, 0.0, -1.0, 0.2], np.float32), np.array([1.0, 0.5, 1.0, 0.9], np.float32)
    policy = LatentSwarmPolicy(env.observation_space, spaces.Box(low, high), lambda _: 3e-4,
                               action_distribution="squashed_gaussian", **TINY_POLICY)
    path = tmp_path / "squashed.onnx"
    assert export_onnx(policy, path).max_abs_error <= ONNX_ATOL
    onnx_agents = [OnnxSwarmAgent(path) for _ in range(CONFIG.n_agents)]
    torch_agents = [LatentSwarmAgent(policy) for _ in range(CONFIG.n_agents)]
    largest, steps = fly_pair(onnx_agents, torch_agents, CONFIG, HELD_OUT_SEED + 12)
    assert steps == CONFIG.max_steps and largest < ONNX_ATOL
    # the same weights on the [-1, 1] box give tanh's a itself: the box only rescales it
    unit = LatentSwarmPolicy(env.observation_space, env.action_space, lambda _: 3e-4,
                             action_distribution="squashed_gaussian", **TINY_POLICY)
    unit.load_state_dict(policy.state_dict())
    observation = {"local_obs": np.zeros(25, np.float32), "proprio": np.zeros(8, np.float32)}
    noise = np.random.default_rng(3).standard_normal(4).astype(np.float32) * 3
    actions = []
    for agent in (LatentSwarmAgent(policy), LatentSwarmAgent(unit)):
        agent.reset()
        actions.append(agent.step(observation, np.zeros((0, agent.message_dim), np.float32), noise=noise))
    assert np.all(low <= actions[0]) and np.all(actions[0] <= high) and np.abs(actions[1]).max() <= 1.0
    np.testing.assert_allclose(actions[0], low + (actions[1] + 1) * (high - low) / 2, atol=1e-6)
