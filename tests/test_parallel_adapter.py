"""The adapter (``make_adapted_vec_env``): any PettingZoo ParallelEnv with Box spaces as LatentSwarmPPO's VecEnv."""

import functools
import runpy
from pathlib import Path

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.envs import AdaptedVecEnv, LinkSpec, make_adapted_vec_env
from sb3_latentswarm.envs.mpe import mpe_positions, simple_spread_metrics
from sb3_latentswarm.envs.observations import SWARM_LAYOUT, observation_layout
from sb3_latentswarm.evaluation.adapted import evaluate_adapted

EXAMPLE = runpy.run_path(str(Path(__file__).resolve().parents[1] / "examples" / "own_env.py"))
Rendezvous = EXAMPLE["Rendezvous"]
rendezvous_positions = EXAMPLE["rendezvous_positions"]

SMALL_POLICY = dict(latent_dim=8, predictor_hidden=8, decoder_hidden=8, critic_hidden=8, actor_hidden=8)
LINK_SPECS = {
    "bernoulli": LinkSpec(link_model="outage", p_fail=0.4),
    "gilbert_elliott": LinkSpec(link_model="outage", outage_model="gilbert_elliott", p_fail=0.5, mean_outage_steps=4),
    "distance": LinkSpec(link_model="distance", link_range=0.5, p_fail=0.1),
    "a2a": LinkSpec(link_model="a2a"),
    "none": LinkSpec(link_mode="none"),
}


def small_model(env, **kwargs):
    n_agents = env.get_attr("n_agents", indices=0)[0]
    episode = kwargs.pop("episode", 20)
    kwargs.setdefault("policy_kwargs", SMALL_POLICY)
    return LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=episode, chunk_length=episode, n_epochs=2,
                          batch_size=episode * n_agents * env.num_envs // n_agents, seed=0, **kwargs)


def simple_spread(continuous_actions=True, **kwargs):
    mpe = pytest.importorskip("mpe2.simple_spread_v3", reason="the mpe extra is not installed")
    return mpe.parallel_env(N=3, continuous_actions=continuous_actions, max_cycles=10, num_agent_neighbors=1,
                            num_landmark_neighbors=1, **kwargs)


# ---------------------------------------------------------------------------------------------- layout and stepping
def test_observation_layout_of_the_adapted_env_and_of_the_swarm_env():
    env = make_adapted_vec_env(Rendezvous, 2, position_fn=rendezvous_positions, seed=0)
    layout = observation_layout(env.observation_space)
    assert layout.actor_keys == ("local_obs", "proprio", "link_row", "position")
    assert layout.state_keys == ("global_state",) and layout.referent_key == "global_state"
    assert layout.position_dims == 3
    assert env.observation_space["proprio"].shape == (0,)
    bare = make_adapted_vec_env(Rendezvous, 1, seed=0, referent_fn=lambda e: e.x.mean(keepdims=True))
    layout = observation_layout(bare.observation_space)
    assert layout.position_key is None and layout.position_dims == 0
    assert layout.state_keys == ("global_state", "referent") and layout.referent_key == "referent"
    from sb3_latentswarm import make_vec_env

    assert observation_layout(make_vec_env(1, seed=0).observation_space) == SWARM_LAYOUT


def test_slots_are_env_major_agent_minor_and_copies_are_seeded_apart():
    env = AdaptedVecEnv(Rendezvous, 2, position_fn=rendezvous_positions, seed=7)
    obs = env.reset()
    assert obs["local_obs"].shape == (6, 1)
    for c, copy in enumerate(env.envs):
        np.testing.assert_allclose(obs["local_obs"][3 * c: 3 * c + 3, 0], copy.x.astype(np.float32))
        np.testing.assert_allclose(obs["global_state"][3 * c: 3 * c + 3], np.tile(copy.x, (3, 1)), rtol=1e-6)
    assert not np.allclose(env.envs[0].x, env.envs[1].x)
    again = AdaptedVecEnv(Rendezvous, 2, position_fn=rendezvous_positions, seed=7).reset()
    for key in obs:
        np.testing.assert_array_equal(obs[key], again[key])


def test_episode_ends_for_all_agents_together_and_auto_resets():
    env = AdaptedVecEnv(Rendezvous, 2, link_model=LINK_SPECS["bernoulli"], seed=0,
                        metrics_fn=lambda e: {"t": e.t, "spread": np.ptp(e.x)})
    env.reset()
    reference = Rendezvous()
    reference.reset(seed=0)  # copy 0's episode
    action = np.full((6, 1), 0.01, dtype=np.float32)
    for step in range(20):
        obs, rewards, dones, infos = env.step(action)
        reference.step({agent: action[0] for agent in reference.possible_agents})
        assert rewards.shape == (6,) and np.all(rewards[:3] == rewards[0])
        assert dones.all() == (step == 19) and dones.any() == (step == 19)
    terminal = infos[0]["terminal_observation"]
    assert infos[0]["TimeLimit.truncated"] and terminal["local_obs"].shape == (1,)
    np.testing.assert_allclose(terminal["global_state"], reference.x, rtol=1e-6)  # s_T, the final state
    metrics = infos[0]["episode_metrics"]
    assert metrics["length"] == 20 and metrics["final_t"] == 20 and metrics["sum_t"] == sum(range(1, 21))
    assert metrics["final_spread"] == pytest.approx(np.ptp(reference.x))  # measured before the copy resets
    assert {copy.t for copy in env.envs} == {0}


def test_link_rows_follow_the_link_model():
    env = AdaptedVecEnv(Rendezvous, 4, link_model=LINK_SPECS["none"], seed=0)
    assert env.reset()["link_row"].sum() == 0
    env = AdaptedVecEnv(Rendezvous, 4, seed=0)  # default: every link up
    np.testing.assert_array_equal(env.reset()["link_row"].reshape(4, 3, 3), np.broadcast_to(1 - np.eye(3), (4, 3, 3)))
    env = AdaptedVecEnv(Rendezvous, 4, link_model=LINK_SPECS["distance"], position_fn=rendezvous_positions, seed=0)
    rows = env.reset()["link_row"].reshape(4, 3, 3)
    positions = np.stack([copy.x for copy in env.envs])
    in_range = np.abs(positions[:, :, None] - positions[:, None, :]) <= 0.5
    assert np.all(rows <= in_range)  # a link delivers only within range


# ---------------------------------------------------------------------------------------------- refused input
class Heterogeneous(Rendezvous):
    def observation_space(self, agent):
        return spaces.Box(-1.0, 1.0, (2 if agent == "agent_2" else 1,), dtype=np.float32)


class EarlyExit(Rendezvous):
    def step(self, actions):
        out = super().step(actions)
        out[2]["agent_0"] = True  # agent_0 terminates alone
        return out


def test_bad_input_is_refused_before_any_training():
    with pytest.raises(ValueError, match="homogeneous agents"):
        make_adapted_vec_env(Heterogeneous, 1)
    with pytest.raises(ValueError, match=r"position_fn must return .* got shape \(3,\)"):
        make_adapted_vec_env(Rendezvous, 1, position_fn=lambda env: env.x)
    with pytest.raises(TypeError, match=r"LinkSpec got unknown field\(s\) \['link_modle'\]"):
        LinkSpec(link_modle="distance")
    with pytest.raises(ValueError, match=r"position_fn returned a non-finite position"):
        make_adapted_vec_env(Rendezvous, 1, position_fn=lambda env: np.full((len(env.possible_agents), 2), np.nan))
    with pytest.raises(ValueError, match=r"referent_fn changed shape from \(1,\) to \(2,\)"):
        make_adapted_vec_env(Rendezvous, 1, referent_fn=lambda env: np.ones(env.t + 1))
    with pytest.raises(ValueError, match="DistanceLinks needs the agents' positions: pass position_fn"):
        make_adapted_vec_env(Rendezvous, 1, link_model=LINK_SPECS["distance"])
    with pytest.raises(ValueError, match="built for 2 swarms of 3 agents"):
        make_adapted_vec_env(Rendezvous, 1, link_model=LINK_SPECS["bernoulli"](2, 3))
    env = make_adapted_vec_env(EarlyExit, 1)
    env.reset()
    with pytest.raises(ValueError, match=r"\['agent_0'\] ended before the others"):
        env.step(np.zeros((3, 1), dtype=np.float32))


def test_discrete_actions_name_the_continuous_alternative():
    with pytest.raises(TypeError, match=r"Box action spaces.*Discrete.*continuous_actions=True"):
        make_adapted_vec_env(functools.partial(simple_spread, continuous_actions=False), 1)


# ---------------------------------------------------------------------------------------------- training
@pytest.mark.parametrize("link", list(LINK_SPECS))
def test_latent_ppo_trains_on_the_custom_env_with_each_link_model(link):
    env = make_adapted_vec_env(Rendezvous, 2, link_model=LINK_SPECS[link], position_fn=rendezvous_positions, seed=0)
    model = small_model(env)
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(2 * 20 * 6, log_interval=10**6)
    assert model.num_timesteps == 240
    assert any(not th.equal(a, b) for a, b in zip(before, model.policy.parameters()))
    assert 0.0 < model.logger.name_to_value["train/map_loss"] < np.inf
    link_up = model.logger.name_to_value["rollout/link_up_rate"]
    assert link_up == 0.0 if link == "none" else 0.0 < link_up <= 1.0


def test_training_without_positions_and_with_a_referent_under_bf16_replay():
    env = make_adapted_vec_env(Rendezvous, 2, link_model=LINK_SPECS["bernoulli"],
                               referent_fn=lambda e: np.array([e.x.mean(), e.x.std()]), seed=0)
    model = small_model(env, autocast="bf16")
    assert model.policy.chunked_replay and model.policy.map_encoder.input_size == 1 + 0 + 8
    model.learn(2 * 20 * 6, log_interval=10**6)
    assert model.policy.map_decoder[-1].out_features == 2
    assert 0.0 < model.logger.name_to_value["train/map_loss"] < np.inf


@pytest.mark.parametrize("link", ["gilbert_elliott", "distance", "a2a"])
def test_latent_ppo_trains_on_mpe2_simple_spread(link):
    env = make_adapted_vec_env(simple_spread, 2, link_model=LINK_SPECS[link], position_fn=mpe_positions,
                               metrics_fn=simple_spread_metrics, seed=0)
    assert env.action_space == spaces.Box(0.0, 1.0, (5,), dtype=np.float32)
    model = small_model(env, episode=10)
    model.learn(2 * 10 * 6, log_interval=10**6)
    assert 0.0 < model.logger.name_to_value["train/value_loss"] < np.inf
    results = evaluate_adapted(model, lambda n, seed: make_adapted_vec_env(
        simple_spread, n, link_model=LINK_SPECS[link], position_fn=mpe_positions, metrics_fn=simple_spread_metrics,
        seed=seed), n_episodes=3, seed=100)
    assert 0.0 <= results["final_landmarks_covered"] <= 1.0 and results["sum_collisions"] >= 0
    assert results["length"] == 10 and np.isfinite(results["return"])


def test_squashed_actor_on_simple_spread_acts_in_its_0_1_box():
    """The opt-in squashed Gaussian on MPE2's [0, 1] actions: the buffer keeps tanh's a in [-1, 1], the env and
    ``predict`` get (a + 1) / 2."""
    env = make_adapted_vec_env(simple_spread, 2, link_model=LINK_SPECS["gilbert_elliott"], position_fn=mpe_positions,
                               metrics_fn=simple_spread_metrics, seed=0)
    model = small_model(env, episode=10, policy_kwargs={**SMALL_POLICY, "action_distribution": "squashed_gaussian"})
    model.learn(2 * 10 * 6, log_interval=10**6)
    buffer = model.rollout_buffer
    assert np.abs(buffer.actions).max() <= 1.0 and buffer.actions.min() < 0.0  # tanh's a, not the env's action
    assert model.logger.name_to_value["rollout/actions_in_box"] == 1.0
    obs = env.reset()
    actions, _ = model.predict(obs, deterministic=True)
    with th.no_grad():
        step = model.policy.latent_step({k: th.as_tensor(v) for k, v in obs.items() if k in model.policy.layout.actor_keys},
                                        model.policy.initial_state(len(actions)), th.ones(len(actions)))
        mean = th.tanh(model.policy.action_distribution(step.state.task_state).distribution.mean)
    np.testing.assert_allclose(actions, (mean.numpy() + 1.0) / 2.0, atol=1e-6)
    assert 0.0 <= actions.min() and actions.max() <= 1.0


def test_simple_spread_metrics_on_a_hand_placed_world():
    env = simple_spread()
    env.reset(seed=0)
    world = env.unwrapped.world
    for agent, landmark in zip(world.agents, world.landmarks):
        agent.state.p_pos = landmark.state.p_pos + 0.05
    world.agents[2].state.p_pos = world.agents[1].state.p_pos + 0.1  # 0.1 < 0.15 + 0.15: agents 1 and 2 collide
    metrics = simple_spread_metrics(env)
    assert metrics["collisions"] >= 1
    assert metrics["landmarks_covered"] >= 1 / 3


def test_an_adapted_model_saves_loads_and_acts_the_same(tmp_path):
    make = functools.partial(make_adapted_vec_env, Rendezvous, 2, link_model=LINK_SPECS["bernoulli"],
                             position_fn=rendezvous_positions)
    model = small_model(make(seed=0))
    model.learn(240)
    model.save(tmp_path / "model.zip")
    loaded = LatentSwarmPPO.load(tmp_path / "model.zip", env=make(seed=1))
    obs = make(seed=3).reset()
    actions, _ = model.predict(obs, deterministic=True)
    loaded_actions, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(actions, loaded_actions)
    loaded.learn(120)


# ---------------------------------------------------------------------------------------------- the example scripts
def test_own_env_example_runs_with_a_tiny_budget():
    results = EXAMPLE["main"](["--env", "custom", "--link", "distance", "--timesteps", "240", "--n-envs", "2",
                               "--eval-episodes", "2"])
    assert results["length"] == 20 and np.isfinite(results["return"])


def test_simple_spread_comm_check_runs_and_reports(tmp_path):
    pytest.importorskip("mpe2")
    script = runpy.run_path(str(Path(__file__).resolve().parents[1] / "examples" / "simple_spread_comm_check.py"))
    script["main"](["--seeds", "0", "--timesteps", "300", "--n-envs", "2", "--eval-episodes", "2", "--max-cycles", "5",
                    "--output", str(tmp_path)])
    report = (tmp_path / "run.md").read_text()
    assert "| links | 1 |" in report and "| no_links | 1 |" in report and "links ahead by >= 10 % of the range" in report
    assert sorted(p.name for p in (tmp_path / "per_run").iterdir()) == ["links_seed0.json", "no_links_seed0.json"]


def test_unbounded_action_boxes_are_refused_when_the_env_is_built():
    """SB3's PPO needs a bounded action box: the adapter says so before any training (SB3 asserted later)."""

    class Unbounded(Rendezvous):
        def action_space(self, agent):
            return spaces.Box(-np.inf, np.inf, (2,), np.float32)

    with pytest.raises(ValueError, match=r"finite bounds.*agent 'agent_0' has Box\(-inf, inf"):
        make_adapted_vec_env(Unbounded, 2, link_model=LINK_SPECS["bernoulli"])


@pytest.mark.parametrize("env_name", ["simple_spread_positions", "rendezvous_no_positions"])
def test_per_uav_agents_act_as_model_predict_on_an_adapted_env(env_name):
    """The per-UAV LatentSwarmAgent steps any layout: N agents fed the messages routed by the link rows act as the
    batched model.predict (p_t from the observation's `position` key, or none). Its ONNX export (formats 3 and 4):
    ``tests/test_onnx_adapted.py``."""
    from sb3_latentswarm.agent import LatentSwarmAgent

    if env_name == "simple_spread_positions":
        make = functools.partial(make_adapted_vec_env, simple_spread, 1, link_model=LINK_SPECS["gilbert_elliott"],
                                 position_fn=mpe_positions)
    else:
        make = functools.partial(make_adapted_vec_env, Rendezvous, 1, link_model=LINK_SPECS["bernoulli"])
    env = make(seed=5)
    model = small_model(make(seed=0), policy_kwargs={**SMALL_POLICY, "action_distribution": "squashed_gaussian"})
    with th.no_grad():  # an untrained actor's mean is ~0 (gain 0.01): give it actions that differ between agents
        model.policy.action_mean.weight.copy_(th.randn(model.policy.action_mean.weight.shape,
                                                       generator=th.Generator().manual_seed(1)))
    n_agents = env.get_attr("n_agents", indices=0)[0]
    agents = [LatentSwarmAgent(model) for _ in range(n_agents)]
    assert agents[0].spec.position_key == ("position" if env_name == "simple_spread_positions" else None)
    for agent in agents:
        agent.reset()
    obs, state, starts = env.reset(), None, np.ones(n_agents)
    dropped = 0
    for _ in range(8):
        expected, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
        sent = np.stack([agent.message() for agent in agents])
        actions = np.stack([
            agent.step({key: obs[key][i] for key in obs}, sent[obs["link_row"][i] > 0], deterministic=True)
            for i, agent in enumerate(agents)
        ])
        np.testing.assert_allclose(actions, expected, rtol=0, atol=1e-5)
        dropped += int((obs["link_row"].sum(-1) == 0).sum())
        obs, _, starts, _ = env.step(expected)
        assert not starts.any()
    assert dropped > 0  # the predictor's path ran too
