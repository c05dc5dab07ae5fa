"""make_vec_env / SwarmVecEnv: slot layout, per-copy seeding, episode ends, SB3 readiness (SuperSuit traps)."""

from __future__ import annotations

import numpy as np
import pytest
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.vec_env import VecMonitor

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import OBS_KEYS, SwarmVecEnv, make_vec_env
from sb3_latentswarm.envs.vec_env import SerialOnlyError

SMALL = SwarmConfig(n_agents=2, grid_width=12, grid_height=12, num_obstacles=8)
# Episodes of exactly 10 steps (b_0 / kappa = 1 / 0.1).
SHORT = SMALL.replace(initial_energy=1.0, energy_decay=0.1)
N = SMALL.n_agents


def assert_obs_equal(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert set(a) == set(b) == set(OBS_KEYS)
    for key in OBS_KEYS:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def random_actions(vec_env, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(-1.0, 1.0, (vec_env.num_envs, 4)).astype(np.float32)


def test_wrapper_stack_and_attributes():
    vec_env = make_vec_env(3, config=SMALL, seed=0)
    assert isinstance(vec_env, VecMonitor) and isinstance(vec_env.venv, SwarmVecEnv)
    assert vec_env.num_envs == 3 * N
    assert vec_env.n_agents == N and vec_env.n_swarms == 3 and vec_env.config == SMALL
    assert vec_env.render_mode is None and vec_env.get_attr("render_mode") == [None] * 6
    assert vec_env.observation_space["global_map"].shape == (12, 12)
    assert make_vec_env(1, n_agents=4, grid_width=20).n_agents == 4  # SwarmConfig overrides
    assert make_vec_env(1, config=SMALL, render_mode="rgb_array").render_mode == "rgb_array"


def test_slots_are_env_major_agent_minor():
    vec_env = make_vec_env(3, config=SMALL, seed=0)
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


def test_action_of_slot_k_moves_agent_k_mod_n_of_copy_k_div_n():
    cfg = SMALL.replace(actuation_noise_std=0.0)
    vec_env = make_vec_env(2, config=cfg, seed=1)
    vec_env.reset()
    before = [env.positions for env in vec_env.swarm_envs]
    actions = np.zeros((4, 4), dtype=np.float32)
    actions[3, 2] = 1.0  # slot 3 = uav_1 of copy 1 climbs
    vec_env.step(actions)
    after = [env.positions for env in vec_env.swarm_envs]
    moved = np.array([[not np.array_equal(b[i], a[i]) for i in range(N)] for b, a in zip(before, after)])
    np.testing.assert_array_equal(moved, [[False, False], [False, True]])
    assert after[1][1, 2] == pytest.approx(before[1][1, 2] + cfg.vz_max * cfg.dt)


def test_copies_differ_with_and_without_seed():
    for seed in (None, 0):
        obs = make_vec_env(3, config=SMALL, seed=seed).reset()
        proprio = obs["proprio"].reshape(3, N, -1)
        for c in range(1, 3):
            assert not np.array_equal(proprio[0], proprio[c]), f"seed={seed}: copy {c} equals copy 0"
    a = make_vec_env(2, config=SMALL).reset()
    b = make_vec_env(2, config=SMALL).reset()
    assert not np.array_equal(a["proprio"], b["proprio"])  # seed=None: a random base seed per vec env


def test_same_seed_reproduces_and_seed_then_reset_reproduces():
    first = make_vec_env(2, config=SMALL, seed=5)
    second = make_vec_env(2, config=SMALL, seed=5)
    other = make_vec_env(2, config=SMALL, seed=6)
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
    serial = make_vec_env(4, config=SMALL, seed=3)
    parallel = make_vec_env(4, config=SMALL, seed=3, num_cpus=2)
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


def test_episode_end_is_shared_by_the_slots_of_a_copy():
    vec_env = make_vec_env(2, config=SHORT, seed=0)
    vec_env.reset()
    rng = np.random.default_rng(0)
    returns = np.zeros(vec_env.num_envs)
    for t in range(1, 11):
        _, rewards, dones, infos = vec_env.step(random_actions(vec_env, rng))
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
    # The copies restarted: energy is full again.
    np.testing.assert_array_equal(vec_env.swarm_envs[0]._last_obs["uav_0"]["proprio"][7], 1.0)


def test_episode_ends_of_different_copies_are_independent():
    # A 6 x 6 grid with a 5 x 5 footprint is covered after a few random steps, at different times per copy.
    cfg = SMALL.replace(grid_width=6, grid_height=6, sensor_range=2, num_obstacles=2, v_max=1.5)
    vec_env = make_vec_env(4, config=cfg, seed=0)
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


def test_truncation_is_reported_to_sb3():
    vec_env = make_vec_env(1, config=SMALL.replace(max_steps=4), seed=0)
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
    ],
)
def test_make_vec_env_validates_arguments(kwargs, field):
    with pytest.raises(ValueError, match=field):
        make_vec_env(config=SMALL, **kwargs)


def test_make_vec_env_rejects_unknown_overrides():
    with pytest.raises(TypeError, match="n_drones"):
        make_vec_env(1, n_drones=3)


def test_recurrent_ppo_smoke():
    vec_env = make_vec_env(2, config=SHORT, seed=0)
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
