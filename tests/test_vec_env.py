"""make_vec_env, both backends (SwarmVecEnv over SuperSuit, BatchedSwarmVecEnv over SwarmBatch): slot layout, per-copy
seeding, episode ends, SB3 readiness (SuperSuit traps), and identical trajectories across the backends."""

from __future__ import annotations

import numpy as np
import pytest
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.vec_env import VecMonitor

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import OBS_KEYS, BatchedSwarmVecEnv, SwarmReconEnv, SwarmVecEnv, make_vec_env
from sb3_latentswarm.envs.vec_env import BACKENDS, SerialOnlyError

SMALL = SwarmConfig(n_agents=2, grid_width=12, grid_height=12, num_obstacles=8)
# Episodes of exactly 10 steps (b_0 / kappa = 1 / 0.1).
SHORT = SMALL.replace(initial_energy=1.0, energy_decay=0.1)
N = SMALL.n_agents
backends = pytest.mark.parametrize("backend", BACKENDS)


def assert_obs_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert set(a) == set(b) == set(OBS_KEYS)
    for key in OBS_KEYS:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def random_actions(vec_env, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(-1.0, 1.0, (vec_env.num_envs, 4)).astype(np.float32)


@backends
def test_wrapper_stack_and_attributes(backend):
    vec_env = make_vec_env(3, config=SMALL, seed=0, backend=backend)
    expected = {"batched": BatchedSwarmVecEnv, "supersuit": SwarmVecEnv}[backend]
    assert isinstance(vec_env, VecMonitor) and isinstance(vec_env.venv, expected)
    assert vec_env.num_envs == 3 * N
    assert vec_env.n_agents == N and vec_env.n_swarms == 3 and vec_env.config == SMALL
    assert vec_env.get_attr("config", indices=[0]) == [SMALL]
    assert vec_env.render_mode is None and vec_env.get_attr("render_mode") == [None] * 6
    assert vec_env.observation_space["global_map"].shape == (12, 12)
    assert vec_env.observation_space == SwarmReconEnv(SMALL, critic_keys=True).observation_space("uav_0")
    assert vec_env.action_space == SwarmReconEnv(SMALL).action_space("uav_0")
    assert make_vec_env(1, n_agents=4, grid_width=20, backend=backend).n_agents == 4  # SwarmConfig overrides
    assert make_vec_env(1, config=SMALL, render_mode="rgb_array", backend=backend).render_mode == "rgb_array"


def test_batched_slots_are_env_major_agent_minor():
    vec_env = make_vec_env(3, config=SMALL, seed=0, backend="batched")
    core = vec_env.unwrapped.core
    obs = vec_env.reset()
    rng = np.random.default_rng(0)
    for _ in range(3):
        for k in range(vec_env.num_envs):
            swarm, agent = divmod(k, N)
            np.testing.assert_array_equal(obs["local_obs"][k], core.local_obs[swarm, agent])
            np.testing.assert_array_equal(obs["proprio"][k], core.proprio[swarm, agent])
            np.testing.assert_array_equal(obs["link_row"][k], core.link_rows[swarm, agent])
            np.testing.assert_array_equal(obs["swarm_proprio"][k], core.proprio[swarm])
            np.testing.assert_array_equal(obs["global_map"][k], core.global_map[swarm])
            assert obs["link_row"][k][agent] == 0.0  # own entry
        obs = vec_env.step(random_actions(vec_env, rng))[0]
    positions = vec_env.get_attr("positions")
    for k in range(vec_env.num_envs):
        np.testing.assert_array_equal(positions[k], core.positions[k // N])


def test_slots_are_env_major_agent_minor():
    vec_env = make_vec_env(3, config=SMALL, seed=0, backend="supersuit")
    obs = vec_env.reset()
    envs = vec_env.swarm_envs
    assert len(envs) == 3
    rng = np.random.default_rng(0)
    for _ in range(3):
        for k in range(vec_env.num_envs):
            copy, agent = divmod(k, N)
            expected = envs[copy]._last_obs[f"uav_{agent}"]
            for key in OBS_KEYS:
                np.testing.assert_array_equal(obs[key][k], expected[key], err_msg=f"slot {k} {key}")
        obs = vec_env.step(random_actions(vec_env, rng))[0]
    positions = vec_env.get_attr("positions")
    for k in range(vec_env.num_envs):
        np.testing.assert_array_equal(positions[k], envs[k // N].positions)


@backends
def test_action_of_slot_k_moves_agent_k_mod_n_of_copy_k_div_n(backend):
    cfg = SMALL.replace(actuation_noise_std=0.0)
    vec_env = make_vec_env(2, config=cfg, seed=1, backend=backend)
    vec_env.reset()
    before = vec_env.get_attr("positions", indices=[0, 2])
    actions = np.zeros((4, 4), dtype=np.float32)
    actions[3, 2] = 1.0  # slot 3 = uav_1 of copy 1 climbs
    vec_env.step(actions)
    after = vec_env.get_attr("positions", indices=[0, 2])
    moved = np.array([[not np.array_equal(b[i], a[i]) for i in range(N)] for b, a in zip(before, after)])
    np.testing.assert_array_equal(moved, [[False, False], [False, True]])
    assert after[1][1, 2] == pytest.approx(before[1][1, 2] + cfg.vz_max * cfg.dt)


@backends
def test_copies_differ_with_and_without_seed(backend):
    for seed in (None, 0):
        obs = make_vec_env(3, config=SMALL, seed=seed, backend=backend).reset()
        proprio = obs["proprio"].reshape(3, N, -1)
        for c in range(1, 3):
            assert not np.array_equal(proprio[0], proprio[c]), f"seed={seed}: copy {c} equals copy 0"
    a = make_vec_env(2, config=SMALL, backend=backend).reset()
    b = make_vec_env(2, config=SMALL, backend=backend).reset()
    assert not np.array_equal(a["proprio"], b["proprio"])  # seed=None: a random base seed per vec env


@backends
def test_same_seed_reproduces_and_seed_then_reset_reproduces(backend):
    first = make_vec_env(2, config=SMALL, seed=5, backend=backend)
    second = make_vec_env(2, config=SMALL, seed=5, backend=backend)
    other = make_vec_env(2, config=SMALL, seed=6, backend=backend)
    obs_first, obs_second, obs_other = first.reset(), second.reset(), other.reset()
    assert_obs_equal(obs_first, obs_second)
    assert not np.array_equal(obs_first["proprio"], obs_other["proprio"])
    # Copy c is seeded with seed + c: copy 0 of seed 6 is copy 1 of seed 5.
    np.testing.assert_array_equal(obs_other["proprio"][:N], obs_first["proprio"][N:])
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    for _ in range(15):
        step_first = first.step(random_actions(first, rng_a))
        step_second = second.step(random_actions(second, rng_b))
        assert_obs_equal(step_first[0], step_second[0])
        np.testing.assert_array_equal(step_first[1], step_second[1])

    assert first.seed(5) == [5, 5, 6, 6]  # seed of the copy of every slot
    assert_obs_equal(first.reset(), obs_first)
    first.step(random_actions(first, rng_a))
    assert not np.array_equal(first.reset()["proprio"], obs_first["proprio"])  # no pending seed: RNG continues


def test_multiprocess_matches_serial():
    serial = make_vec_env(4, config=SMALL, seed=3, backend="supersuit")
    parallel = make_vec_env(4, config=SMALL, seed=3, num_cpus=2, backend="supersuit")
    try:
        assert_obs_equal(serial.reset(), parallel.reset())
        rng = np.random.default_rng(0)
        for _ in range(5):
            actions = random_actions(serial, rng)
            obs_s, rew_s, done_s, _ = serial.step(actions)
            obs_p, rew_p, done_p, _ = parallel.step(actions)
            assert_obs_equal(obs_s, obs_p)
            np.testing.assert_array_equal(rew_s, rew_p)
        with pytest.raises(SerialOnlyError, match="serial"):
            parallel.get_attr("positions")
    finally:
        parallel.close()


@backends
def test_episode_end_is_shared_by_the_slots_of_a_copy(backend):
    vec_env = make_vec_env(2, config=SHORT, seed=0, backend=backend)
    vec_env.reset()
    rng = np.random.default_rng(0)
    returns = np.zeros(vec_env.num_envs)
    for t in range(1, 11):
        obs, rewards, dones, infos = vec_env.step(random_actions(vec_env, rng))
        returns += rewards
        if t < 10:
            assert not dones.any()
            assert all("swarm_summary" not in info for info in infos)
    assert dones.all()
    for k, info in enumerate(infos):
        summary = info["swarm_summary"]
        assert summary["length"] == 10 and summary["truncated"] is False
        assert info["TimeLimit.truncated"] is False
        assert set(info["terminal_observation"]) == set(OBS_KEYS)
        assert info["episode"]["l"] == 10  # VecMonitor
        assert info["episode"]["r"] == pytest.approx(summary["episode_return"], rel=1e-5)
        assert returns[k] == pytest.approx(summary["episode_return"], rel=1e-5)
        assert "coverage" in info and info["coverage"] == summary["coverage"]  # final step, not the next reset
        assert info["terminal_observation"]["proprio"][7] == 0.0  # the energy of the finished episode is spent
    # The copies restarted: the returned observation is the new episode's, energy full again.
    np.testing.assert_array_equal(obs["proprio"][:, 7], 1.0)


@backends
def test_episode_ends_of_different_copies_are_independent(backend):
    # A 6 x 6 grid with a 5 x 5 footprint is covered after a few random steps, at different times per copy.
    cfg = SMALL.replace(grid_width=6, grid_height=6, sensor_range=2, num_obstacles=2, v_max=1.5)
    vec_env = make_vec_env(4, config=cfg, seed=0, backend=backend)
    vec_env.reset()
    rng = np.random.default_rng(0)
    done_steps = []
    for t in range(60):
        _, _, dones, infos = vec_env.step(random_actions(vec_env, rng))
        per_copy = dones.reshape(4, N)
        assert (per_copy == per_copy[:, :1]).all(), f"step {t}: slots of one copy disagree: {per_copy}"
        for k in np.flatnonzero(dones):
            assert infos[k]["swarm_summary"]["coverage"] == 1.0
            assert "terminal_observation" in infos[k]
        done_steps.append(per_copy[:, 0].copy())
    done_steps = np.array(done_steps)
    assert done_steps.any(axis=0).all()  # every copy finished at least once
    assert not (done_steps == done_steps[:, :1]).all()  # copies finished at different steps


@backends
def test_truncation_is_reported_to_sb3(backend):
    vec_env = make_vec_env(1, config=SMALL.replace(max_steps=4), seed=0, backend=backend)
    vec_env.reset()
    for _ in range(4):
        _, _, dones, infos = vec_env.step(np.zeros((N, 4), dtype=np.float32))
    assert dones.all()
    assert all(info["TimeLimit.truncated"] is True for info in infos)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"n_envs": 0}, "n_envs"),
        ({"n_envs": -2}, "n_envs"),
        ({"n_envs": 1.5}, "n_envs"),
        ({"n_envs": True}, "n_envs"),
        ({"n_envs": 1, "num_cpus": -1}, "num_cpus"),
        ({"n_envs": 1, "num_cpus": 0.5}, "num_cpus"),
        ({"n_envs": 1, "seed": -1}, "seed"),
        ({"n_envs": 1, "backend": "vmas"}, "backend"),
        ({"n_envs": 1, "num_cpus": 2, "backend": "batched"}, "num_cpus"),
    ],
)
def test_make_vec_env_validates_arguments(kwargs, field):
    with pytest.raises((TypeError, ValueError), match=field):
        make_vec_env(config=SMALL, **kwargs)


def test_make_vec_env_rejects_unknown_overrides():
    with pytest.raises(TypeError, match="n_drones"):
        make_vec_env(1, n_drones=3)


@backends
def test_recurrent_ppo_smoke(backend):
    vec_env = make_vec_env(2, config=SHORT, seed=0, backend=backend)
    model = RecurrentPPO(
        "MultiInputLstmPolicy",
        vec_env,
        n_steps=16,
        batch_size=32,
        n_epochs=2,  # a smoke test: the default 10 epochs only cost time
        seed=0,
        policy_kwargs=dict(lstm_hidden_size=16, net_arch=[16]),
        device="cpu",
    )
    model.learn(64)
    assert model.num_timesteps == 64
    assert len(model.ep_info_buffer) > 0  # VecMonitor episodes (10-step episodes)
    assert all(info["l"] == 10 for info in model.ep_info_buffer)


# ---------------------------------------------------------------------------------------------------- backends agree
def assert_infos_equal(a: list[dict], b: list[dict]) -> None:
    assert len(a) == len(b)
    for info_a, info_b in zip(a, b):
        assert list(info_a) == list(info_b)  # same keys in the same order
        for key in info_a:
            if key == "terminal_observation":
                assert_obs_equal(info_a[key], info_b[key])
            elif key == "episode":  # VecMonitor: "t" is wall time
                assert (info_a[key]["r"], info_a[key]["l"]) == (info_b[key]["r"], info_b[key]["l"])
            else:
                assert info_a[key] == info_b[key], key


@pytest.mark.parametrize(
    "cfg",
    [
        SMALL.replace(max_steps=25),
        SMALL.replace(n_agents=3, grid_width=8, grid_height=8, num_obstacles=4, v_max=1.0, action_frame="body", max_steps=20),
        SMALL.replace(outage_model="gilbert_elliott", mean_outage_steps=4.0, start_region="corner", max_steps=15),
        SMALL.replace(link_mode="full", sensor_flip_prob=0.0, actuation_noise_std=0.0, max_steps=12),
    ],
    ids=["default", "body-frame-3-agents", "gilbert-elliott-corner", "full-comm-noise-free"],
)
def test_backends_give_identical_trajectories(cfg):
    """Same seed, same actions: observations, rewards, dones and infos are equal, episode ends and restarts included."""
    supersuit = make_vec_env(4, config=cfg, seed=11, backend="supersuit")
    batched = make_vec_env(4, config=cfg, seed=11, backend="batched")
    assert_obs_equal(supersuit.reset(), batched.reset())
    rng = np.random.default_rng(3)
    finished = 0
    for _ in range(60):
        actions = rng.uniform(-1.0, 1.0, (supersuit.num_envs, 4)).astype(np.float32)
        obs_s, rew_s, done_s, infos_s = supersuit.step(actions)
        obs_b, rew_b, done_b, infos_b = batched.step(actions)
        assert_obs_equal(obs_s, obs_b)
        assert rew_s.dtype == rew_b.dtype == np.float32
        np.testing.assert_array_equal(rew_s, rew_b)
        np.testing.assert_array_equal(done_s.astype(bool), done_b)
        assert_infos_equal(infos_s, infos_b)
        finished += int(done_b.sum()) // cfg.n_agents
    assert finished >= 8  # every copy went through episode ends and restarts
    for name in ("positions", "coverage", "energy", "links", "ground_truth", "global_map", "reward_terms"):
        for value_s, value_b in zip(supersuit.get_attr(name), batched.get_attr(name)):
            np.testing.assert_array_equal(value_s, value_b, err_msg=name)
    assert supersuit.env_method("swarm_summary") == batched.env_method("swarm_summary")
    # After seed(), both restart every swarm from the same seeds.
    assert supersuit.seed(4) == batched.seed(4)
    assert_obs_equal(supersuit.reset(), batched.reset())


def test_batched_env_method_and_attributes():
    vec_env = make_vec_env(2, config=SMALL.replace(actuation_noise_std=0.0), seed=0, backend="batched")
    vec_env.reset()
    target = np.array([[5.5, 5.5, 10.0], [8.5, 2.5, 12.0]])
    vec_env.env_method("set_positions", target, indices=[2])  # slot 2 = copy 1
    positions = vec_env.get_attr("positions")
    np.testing.assert_array_equal(positions[2], target)
    np.testing.assert_array_equal(positions[3], target)
    assert not np.array_equal(positions[0], target)
    assert vec_env.env_method("swarm_summary", indices=[0])[0]["length"] == 0
    assert vec_env.has_attr("coverage") and not vec_env.has_attr("no_such_thing")
    with pytest.raises(AttributeError, match="no_such_thing"):
        vec_env.get_attr("no_such_thing")
    with pytest.raises(AttributeError, match="render"):
        vec_env.env_method("render")
    with pytest.raises(AttributeError, match="positions"):
        vec_env.set_attr("positions", target)
    assert vec_env.env_is_wrapped(VecMonitor) == [False] * 4


def test_batched_rejects_bad_actions_naming_the_agent_and_swarm():
    vec_env = make_vec_env(3, config=SMALL, seed=0, backend="batched")
    vec_env.reset()
    actions = np.zeros((6, 4), dtype=np.float32)
    actions[5, 1] = 1.5  # slot 5 = uav_1 of swarm 2
    with pytest.raises(ValueError, match=r"uav_1 of swarm 2 is outside \[-1, 1\]"):
        vec_env.step(actions)
    actions[5, 1] = np.nan
    with pytest.raises(ValueError, match="uav_1 of swarm 2 is not finite"):
        vec_env.step(actions)
    with pytest.raises(ValueError, match=r"shape \(6, 4\)"):
        vec_env.step(np.zeros((5, 4), dtype=np.float32))


def test_batched_render_tiles_the_pictures_of_the_swarms():
    vec_env = make_vec_env(2, config=SMALL, seed=0, render_mode="rgb_array", backend="batched")
    vec_env.reset()
    vec_env.step(np.zeros((4, 4), dtype=np.float32))
    env = SwarmReconEnv(SMALL, render_mode="rgb_array")
    env.reset(seed=1)  # swarm 1 of seed 0
    env.step({agent: np.zeros(4) for agent in env.agents})
    images = vec_env.get_images()
    assert len(images) == 4 and images[2] is images[3]  # one picture per swarm, shared by its slots
    np.testing.assert_array_equal(images[2], env.render())
    tiled = vec_env.render()
    assert tiled.dtype == np.uint8 and tiled.shape[2] == 3 and tiled.shape[0] >= images[0].shape[0]
