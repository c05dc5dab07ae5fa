"""SwarmReconEnv: PettingZoo API, spaces, dynamics invariants, the Sec. II-B reward on hand-built scenarios, errors."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys

import cloudpickle
import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import ACTOR_OBS_KEYS, OBS_KEYS, SwarmReconEnv, parallel_env, swarm_recon_v0

# 50-step episodes (b_0 / kappa = 5 / 0.1) on a 20 x 20 grid: fast, and long enough to move around.
SMALL = SwarmConfig(grid_width=20, grid_height=20, num_obstacles=20, initial_energy=5.0, energy_decay=0.1, max_steps=1000)
# Deterministic motion and sensing for hand-built scenarios: 12 x 12 grid, 3 x 3 footprint, 1 cell per step.
EXACT = SwarmConfig(
    n_agents=2,
    grid_width=12,
    grid_height=12,
    sensor_range=1,
    num_obstacles=10,
    actuation_noise_std=0.0,
    sensor_flip_prob=0.0,
    cell_size=1.0,
    v_max=1.0,
    dt=1.0,
)
Z = 10.0  # altitude used in the scenarios (metres)


def swarm_proprio(obs: dict) -> np.ndarray:
    """{e_t^j} (N, 8) from the agents' own ``proprio``, in agent order."""
    return np.stack([agent_obs["proprio"] for agent_obs in obs.values()])


def zero_actions(env: SwarmReconEnv) -> dict[str, np.ndarray]:
    return {agent: np.zeros(4, dtype=np.float32) for agent in env.agents}


def footprint_cells(env: SwarmReconEnv, positions: np.ndarray) -> set[tuple[int, int]]:
    """(iy, ix) of the cells inside the grid sensed from ``positions`` (reference implementation with loops)."""
    cfg = env.config
    r = cfg.sensor_range
    cells = set()
    for x, y, _ in positions:
        cx = min(int(math.floor(x / cfg.cell_size)), cfg.grid_width - 1)
        cy = min(int(math.floor(y / cfg.cell_size)), cfg.grid_height - 1)
        for iy in range(cy - r, cy + r + 1):
            for ix in range(cx - r, cx + r + 1):
                if 0 <= ix < cfg.grid_width and 0 <= iy < cfg.grid_height:
                    cells.add((iy, ix))
    return cells


# ---------------------------------------------------------------------------------------------------- PettingZoo API
def test_parallel_api_test_small_config():
    parallel_api_test(SwarmReconEnv(SMALL), num_cycles=120)  # two resets, episodes of 50 steps end inside the test


def test_parallel_api_test_critic_view_and_delay():
    parallel_api_test(SwarmReconEnv(SMALL, critic_keys=True), num_cycles=60)
    delayed = SMALL.replace(message_delay=1, message_delay_model="uniform", message_expiry=2)
    env = SwarmReconEnv(delayed)
    assert tuple(env.observation_space("uav_0").spaces) == (*ACTOR_OBS_KEYS, "link_age")  # the age is the agent's own
    parallel_api_test(env, num_cycles=60)


def test_parallel_api_test_paper_config():
    parallel_api_test(SwarmReconEnv(), num_cycles=30)


def test_parallel_seed_test():
    parallel_seed_test(lambda: SwarmReconEnv(SMALL), num_cycles=60)


@pytest.mark.filterwarnings("ignore:Observation is not a NumPy array", "ignore:Observation space for each agent")
def test_aec_api_test():
    api_test(swarm_recon_v0.env(config=SMALL), num_cycles=60)


def test_same_seed_same_episode_including_links():
    def rollout(seed: int) -> list:
        env = parallel_env(config=SMALL)
        obs, _ = env.reset(seed=seed)
        space_rng = np.random.default_rng(123)
        record = [obs]
        while env.agents:
            actions = {a: space_rng.uniform(-1, 1, 4).astype(np.float32) for a in env.agents}
            record.append(env.step(actions))
        return record

    first, second, other = rollout(7), rollout(7), rollout(8)
    assert len(first) == len(second) == 51
    for a, b in zip(first[1:], second[1:]):
        for agent in a[0]:
            assert tuple(a[0][agent]) == ACTOR_OBS_KEYS
            for key in ACTOR_OBS_KEYS:
                np.testing.assert_array_equal(a[0][agent][key], b[0][agent][key])
        assert a[1:] == b[1:]
    links_first = np.array([step[0]["uav_0"]["link_row"] for step in first[1:]])
    links_other = np.array([step[0]["uav_0"]["link_row"] for step in other[1:]])
    assert not np.array_equal(links_first, links_other)
    assert not np.array_equal(first[0]["uav_0"]["proprio"], other[0]["uav_0"]["proprio"])


def test_reset_without_seed_continues_the_rng():
    env = SwarmReconEnv(SMALL)
    first, _ = env.reset(seed=3)
    second, _ = env.reset()
    assert not np.array_equal(first["uav_0"]["proprio"], second["uav_0"]["proprio"])


# ---------------------------------------------------------------------------------------------------- spaces
def test_metadata_agents_and_overrides():
    env = SwarmReconEnv(n_agents=5, grid_width=30)
    assert env.metadata["name"] == "swarm_recon_v0"
    assert env.metadata["is_parallelizable"] is True
    assert set(env.metadata["render_modes"]) == {"human", "rgb_array"}
    assert env.render_mode is None
    assert env.possible_agents == [f"uav_{i}" for i in range(5)]
    assert env.n_agents == 5 and env.config.n_agents == 5 and env.config.grid_width == 30
    assert env.observation_space("uav_3") is env.observation_space("uav_3")
    assert env.action_space("uav_3") is env.action_space("uav_3")
    env2 = SwarmReconEnv(SMALL, n_agents=4)
    assert env2.config.grid_width == 20 and env2.n_agents == 4
    assert isinstance(swarm_recon_v0.parallel_env(n_agents=2), SwarmReconEnv)
    assert swarm_recon_v0.env(n_agents=2).possible_agents == ["uav_0", "uav_1"]


def test_observation_keys_dtypes_shapes():
    env = SwarmReconEnv(SMALL, n_agents=4)
    obs, infos = env.reset(seed=0)
    fw = 2 * SMALL.sensor_range + 1
    expected = {  # what the agent may see when it acts (PettingZoo's convention): no global key
        "local_obs": ((fw * fw,), np.int8),
        "proprio": ((8,), np.float32),
        "link_row": ((4,), np.float32),
    }
    for agent in env.possible_agents:
        space = env.observation_space(agent)
        assert tuple(space.spaces) == ACTOR_OBS_KEYS
        assert set(obs[agent]) == set(expected)
        for key, (shape, dtype) in expected.items():
            assert space[key].shape == shape and space[key].dtype == dtype, key
            assert obs[agent][key].shape == shape and obs[agent][key].dtype == dtype, key
        assert space.contains(obs[agent])
        assert env.action_space(agent).shape == (4,) and env.action_space(agent).dtype == np.float32
        assert infos[agent] == {}
    step_obs = env.step(zero_actions(env))[0]
    for agent in env.possible_agents:
        assert env.observation_space(agent).contains(step_obs[agent])
    assert env.state().shape == env.state_space.shape == (4 * 8 + 400,)
    assert env.state().dtype == np.float32


def test_the_global_state_comes_from_state_and_critic_keys_add_it_to_the_observation():
    env, critic_view = SwarmReconEnv(SMALL, n_agents=4), SwarmReconEnv(SMALL, n_agents=4, critic_keys=True)
    obs, _ = env.reset(seed=2)
    full, _ = critic_view.reset(seed=2)
    for _ in range(3):
        state = env.state()
        np.testing.assert_array_equal(state, critic_view.state())
        np.testing.assert_array_equal(state[: 4 * 8].reshape(4, 8), swarm_proprio(obs))
        np.testing.assert_array_equal(state[4 * 8 :].reshape(20, 20), env.global_map)
        for agent in env.possible_agents:
            assert tuple(critic_view.observation_space(agent).spaces) == OBS_KEYS
            assert critic_view.observation_space(agent).contains(full[agent])
            for key in ACTOR_OBS_KEYS:
                np.testing.assert_array_equal(obs[agent][key], full[agent][key])
            np.testing.assert_array_equal(full[agent]["swarm_proprio"], swarm_proprio(obs))
            np.testing.assert_array_equal(full[agent]["global_map"], env.global_map)
        actions = {a: np.full(4, 0.3, dtype=np.float32) for a in env.agents}
        obs, full = env.step(actions)[0], critic_view.step(actions)[0]
    with pytest.raises(TypeError, match="critic_keys"):
        SwarmReconEnv(SMALL, critic_keys=1)


def test_proprio_matches_state():
    cfg = SMALL.replace(action_frame="world")
    env = SwarmReconEnv(cfg)
    env.reset(seed=4)
    obs = env.step({a: np.array([0.5, -0.5, 1.0, 0.5], dtype=np.float32) for a in env.agents})[0]
    x_max, y_max = cfg.arena_size
    pos = env.positions
    for i, agent in enumerate(env.possible_agents):
        e = obs[agent]["proprio"]
        np.testing.assert_allclose(e[:3], [pos[i, 0] / x_max, pos[i, 1] / y_max, (pos[i, 2] - 5.0) / 15.0], rtol=1e-6)
        assert -1.0 <= e[6] < 1.0
        assert e[7] == pytest.approx((5.0 - 0.1) / 5.0)
        np.testing.assert_array_equal(env.state()[i * 8 : (i + 1) * 8], e)
    # Noise-free velocity is the command: vx/v_max = 0.5, vz/vz_max = 1.
    exact = SwarmReconEnv(EXACT)
    exact.reset(seed=0, options={"positions": [[5.5, 5.5, Z], [9.5, 9.5, Z]]})
    e = exact.step({a: np.array([0.5, -0.25, 1.0, 0.0], dtype=np.float32) for a in exact.agents})[0]["uav_0"]["proprio"]
    np.testing.assert_allclose(e[3:6], [0.5, -0.25, 1.0], rtol=1e-6)


def test_observations_are_read_only_and_not_mutated_later():
    env = SwarmReconEnv(SMALL, critic_keys=True)
    obs, _ = env.reset(seed=1)
    snapshot = {key: obs["uav_0"][key].copy() for key in OBS_KEYS}
    for key in OBS_KEYS:
        assert not obs["uav_0"][key].flags.writeable, key
    rng = np.random.default_rng(0)
    for _ in range(10):
        env.step({a: rng.uniform(-1, 1, 4).astype(np.float32) for a in env.agents})
    for key in OBS_KEYS:
        np.testing.assert_array_equal(obs["uav_0"][key], snapshot[key])


def test_pickled_copy_keeps_its_state_consistent():
    env = SwarmReconEnv(EXACT)
    env.reset(seed=0, options={"positions": [[5.5, 5.5, Z], [9.5, 9.5, Z]]})
    for copy in (cloudpickle.loads(cloudpickle.dumps(env)), pickle.loads(pickle.dumps(env))):
        obs = copy.step({a: np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32) for a in copy.agents})[0]
        np.testing.assert_allclose(copy.positions[:, 0], [6.5, 10.5])
        assert obs["uav_0"]["proprio"][0] == pytest.approx(6.5 / 12.0)
        np.testing.assert_array_equal(copy.global_map.ravel(), copy.state()[2 * 8 :])
        assert (copy.global_map >= 0).sum() == 18 + 3 + 3  # the copy's M_hat view follows its own map
    np.testing.assert_allclose(env.positions[:, 0], [5.5, 9.5])  # the original did not move


# ---------------------------------------------------------------------------------------------------- reset
def test_reset_state_follows_the_paper():
    env = SwarmReconEnv(SMALL.replace(n_agents=6))
    obs, _ = env.reset(seed=5)
    pos = env.positions
    assert np.all((pos[:, :2] >= 0.0) & (pos[:, :2] <= 20.0))
    np.testing.assert_array_equal(pos[:, 2], SMALL.initial_altitude)
    e = swarm_proprio(obs)
    np.testing.assert_array_equal(e[:, 3:6], 0.0)  # zero velocity
    assert np.all((e[:, 6] >= -1.0) & (e[:, 6] < 1.0)) and np.unique(e[:, 6]).size == 6  # random headings
    np.testing.assert_array_equal(e[:, 7], 1.0)  # full energy
    assert env.ground_truth.sum() == SMALL.num_obstacles
    assert 0.0 < env.coverage <= 6 * 25 / 400  # sensed once at reset
    assert (env.global_map >= 0).sum() == round(env.coverage * 400)
    other = SwarmReconEnv(SMALL.replace(n_agents=6))
    other.reset(seed=6)
    assert not np.array_equal(env.ground_truth, other.ground_truth)  # a new map every episode


def test_noise_free_sensing_reads_the_truth():
    env = SwarmReconEnv(EXACT)
    obs, _ = env.reset(seed=2, options={"positions": [[0.5, 0.5, Z], [6.5, 6.5, Z]]})
    truth = env.ground_truth
    estimate = env.global_map
    known = estimate >= 0
    np.testing.assert_array_equal(estimate[known], truth[known])
    assert {tuple(c) for c in np.argwhere(known)} == footprint_cells(env, env.positions)
    # Agent 0 sits in the corner cell (0, 0): the patch rows/cols at -1 are outside the arena.
    patch = obs["uav_0"]["local_obs"].reshape(3, 3)
    np.testing.assert_array_equal(patch[0], -1)
    np.testing.assert_array_equal(patch[:, 0], -1)
    np.testing.assert_array_equal(patch[1:, 1:], truth[0:2, 0:2])
    patch1 = obs["uav_1"]["local_obs"].reshape(3, 3)
    np.testing.assert_array_equal(patch1, truth[5:8, 5:8])


def test_sensor_flip_rate():
    cfg = SMALL.replace(sensor_flip_prob=0.2, num_obstacles=0, actuation_noise_std=0.0)
    env = SwarmReconEnv(cfg)
    env.reset(seed=0)
    readings = []
    for _ in range(40):
        obs = env.step(zero_actions(env))[0]
        readings.append(np.stack([obs[a]["local_obs"] for a in env.possible_agents]))
    readings = np.concatenate(readings).ravel()
    inside = readings[readings >= 0]
    assert inside.size > 2000
    assert abs(inside.mean() - 0.2) < 0.03  # free cells read as occupied with probability 0.2


# ---------------------------------------------------------------------------------------------------- invariants
def _policy(kind: str, rng: np.random.Generator, t: int, n: int) -> np.ndarray:
    if kind == "random":
        return rng.uniform(-1.0, 1.0, (n, 4))
    if kind == "plus":
        return np.ones((n, 4))
    if kind == "minus":
        return -np.ones((n, 4))
    return np.full((n, 4), 1.0 if t % 2 == 0 else -1.0)  # alternating


@pytest.mark.parametrize("frame", ["world", "body"])
@pytest.mark.parametrize("kind", ["random", "plus", "minus", "alternating"])
def test_invariants_under_random_and_adversarial_actions(kind, frame):
    cfg = SMALL.replace(action_frame=frame, v_max=3.0, vz_max=4.0)
    env = SwarmReconEnv(cfg)
    obs, _ = env.reset(seed=11)
    rng = np.random.default_rng(0)
    x_max, y_max = cfg.arena_size
    coverage = env.coverage
    previous_map = env.global_map
    t = 0
    while True:
        actions = _policy(kind, rng, t, env.n_agents).astype(np.float32)
        obs, rewards, terms, truncs, infos = env.step(dict(zip(env.possible_agents, actions)))
        t += 1
        pos = env.positions
        assert np.all((pos[:, 0] >= 0.0) & (pos[:, 0] <= x_max) & (pos[:, 1] >= 0.0) & (pos[:, 1] <= y_max))
        assert np.all((pos[:, 2] >= cfg.min_altitude) & (pos[:, 2] <= cfg.max_altitude))
        e = swarm_proprio(obs)
        np.testing.assert_allclose(e[:, 7], (cfg.initial_energy - cfg.energy_decay * t) / cfg.initial_energy, atol=1e-6)
        assert np.all((e[:, 6] >= -1.0) & (e[:, 6] < 1.0))
        assert env.energy == pytest.approx(max(cfg.initial_energy - cfg.energy_decay * t, 0.0))
        assert env.coverage >= coverage
        coverage = env.coverage
        assert all(info["coverage"] == coverage for info in infos.values())
        current_map = env.global_map
        changed = {tuple(c) for c in np.argwhere(current_map != previous_map)}
        assert changed <= footprint_cells(env, pos)
        previous_map = current_map
        assert len(set(rewards.values())) == 1  # shared reward
        assert len(set(terms.values())) == 1 and len(set(truncs.values())) == 1  # all agents together
        if any(terms.values()) or any(truncs.values()):
            break
    assert t == 50  # T = b_0 / kappa
    assert all(terms.values()) and not any(truncs.values())
    assert env.agents == []
    summary = infos["uav_0"]["swarm_summary"]
    assert summary["length"] == 50 and summary["truncated"] is False
    assert summary["coverage"] == pytest.approx(coverage)


def test_paper_defaults_terminate_at_step_1000():
    env = SwarmReconEnv()
    env.reset(seed=0)
    actions = zero_actions(env)
    for t in range(1, 1001):
        _, _, terms, truncs, infos = env.step(actions)
        if t < 1000:
            assert not any(terms.values()) and not any(truncs.values())
    assert all(terms.values()) and not any(truncs.values()) and env.agents == []
    assert infos["uav_0"]["swarm_summary"]["length"] == 1000


def test_heading_wraps_and_body_frame_rotates_the_command():
    env = SwarmReconEnv(EXACT.replace(action_frame="body", yaw_rate_max=3.0))
    obs, _ = env.reset(seed=3, options={"positions": [[6.0, 6.0, Z], [3.0, 3.0, Z]]})
    chi = swarm_proprio(obs)[:, 6].astype(np.float64) * math.pi
    before = env.positions
    obs = env.step({a: np.array([1.0, 0.5, 0.0, 1.0], dtype=np.float32) for a in env.agents})[0]
    # Body frame: (forward, lateral) = (1, 0.5) m/s rotated by the heading before the update.
    expected = np.stack([np.cos(chi) - 0.5 * np.sin(chi), np.sin(chi) + 0.5 * np.cos(chi)], axis=1)
    np.testing.assert_allclose(env.positions[:, :2] - before[:, :2], expected, atol=1e-5)
    new_chi = swarm_proprio(obs)[:, 6].astype(np.float64) * math.pi
    wrapped = (chi + 3.0 + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(new_chi, wrapped, atol=1e-5)
    for _ in range(5):
        e = env.step({a: np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32) for a in env.agents})[0]["uav_0"]["proprio"]
        assert -1.0 <= e[6] < 1.0


# ---------------------------------------------------------------------------------------------------- reward
def test_coverage_reward_counts_new_cells_minus_stall_penalty():
    env = SwarmReconEnv(EXACT)
    env.reset(seed=0, options={"positions": [[2.5, 2.5, Z], [9.5, 9.5, Z]]})
    assert env.coverage == pytest.approx(18 / 144)
    _, rewards, *_ = env.step(zero_actions(env))  # hovering: nothing new
    assert env.reward_terms == (-EXACT.stall_penalty, 0.0, 0.0)
    assert rewards["uav_0"] == pytest.approx(EXACT.w_cov * -EXACT.stall_penalty)
    # UAV 0 moves one cell in +x: a new column of 3 cells.
    actions = {"uav_0": np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32), "uav_1": np.zeros(4, dtype=np.float32)}
    _, rewards, *_ = env.step(actions)
    assert env.reward_terms == (3 - EXACT.stall_penalty, 0.0, 0.0)
    assert rewards["uav_1"] == pytest.approx(EXACT.w_cov * (3 - EXACT.stall_penalty))
    assert env.coverage == pytest.approx(21 / 144)


def test_redundancy_and_proximity_penalties():
    cfg = EXACT.replace(d_safe=2.0)
    env = SwarmReconEnv(cfg)
    env.reset(seed=0, options={"positions": [[1.5, 1.5, Z], [10.5, 10.5, Z]]})
    # Footprints x in 4..6 and 5..7, y in 4..6: 12 new cells, 6 seen by both, UAVs 1 m apart.
    env.set_positions([[5.5, 5.5, Z], [6.5, 5.5, Z]])
    _, rewards, *_ = env.step(zero_actions(env))
    r_cov, r_red, r_coll = env.reward_terms
    assert (r_cov, r_red, r_coll) == (12 - cfg.stall_penalty, -6.0, -1.0)
    expected = cfg.w_cov * r_cov + cfg.w_red * r_red + cfg.w_coll * r_coll
    assert rewards["uav_0"] == pytest.approx(expected)
    # The same cells again: no longer new, so no redundancy; the pair is still too close.
    _, rewards, *_ = env.step(zero_actions(env))
    assert env.reward_terms == (-cfg.stall_penalty, 0.0, -1.0)
    assert env.step(zero_actions(env))[4]["uav_1"]["collisions"] == 3


def test_redundancy_counts_pairs_per_cell_and_collisions_are_3d():
    cfg = EXACT.replace(n_agents=3, d_safe=2.0)
    env = SwarmReconEnv(cfg)
    env.reset(seed=0, options={"positions": [[0.5, 0.5, Z], [11.5, 0.5, Z], [0.5, 11.5, Z]]})
    # Three UAVs over one cell: 9 new cells, each seen by 3 UAVs -> 3 pairs per cell; 3 close pairs.
    env.set_positions([[6.5, 6.5, 6.0], [6.5, 6.5, 7.0], [6.5, 6.5, 7.5]])
    env.step(zero_actions(env))
    assert env.reward_terms == (9 - cfg.stall_penalty, -27.0, -3.0)
    # Same column, altitudes 6, 9, 12: 3 m apart vertically -> no pair closer than d_safe = 2 m.
    env.set_positions([[9.5, 9.5, 6.0], [9.5, 9.5, 9.0], [9.5, 9.5, 12.0]])
    _, _, _, _, infos = env.step(zero_actions(env))
    assert env.reward_terms == (9 - cfg.stall_penalty, -27.0, 0.0)
    assert infos["uav_0"]["collisions"] == 3


def test_reward_weights_combine_the_terms():
    cfg = EXACT.replace(w_cov=1.5, w_red=0.25, w_coll=2.0, stall_penalty=0.75)
    env = SwarmReconEnv(cfg)
    env.reset(seed=0, options={"positions": [[1.5, 1.5, Z], [10.5, 10.5, Z]]})
    env.set_positions([[5.5, 5.5, Z], [6.5, 5.5, Z]])
    _, rewards, *_ = env.step(zero_actions(env))
    assert rewards["uav_0"] == pytest.approx(1.5 * (12 - 0.75) + 0.25 * -6.0 + 2.0 * -1.0)
    summary_return = rewards["uav_0"]
    _, rewards, *_ = env.step(zero_actions(env))
    assert env.swarm_summary()["episode_return"] == pytest.approx(summary_return + rewards["uav_0"])


# ---------------------------------------------------------------------------------------------------- episode end
def test_map_covered_at_reset_terminates_at_the_first_step():
    env = SwarmReconEnv(grid_width=5, grid_height=5, sensor_range=2, n_agents=2, num_obstacles=3)
    env.reset(seed=0, options={"positions": [[2.5, 2.5, Z], [0.5, 0.5, Z]]})
    assert env.coverage == 1.0
    _, rewards, terms, truncs, infos = env.step(zero_actions(env))
    assert all(terms.values()) and not any(truncs.values()) and env.agents == []
    summary = infos["uav_0"]["swarm_summary"]
    assert summary["coverage"] == 1.0 and summary["steps_to_90"] == 0 and summary["length"] == 1
    assert rewards["uav_0"] == pytest.approx(env.config.w_cov * -env.config.stall_penalty)


def test_success_termination_mid_episode():
    cfg = EXACT.replace(n_agents=1, grid_width=6, grid_height=3, num_obstacles=2)
    env = SwarmReconEnv(cfg)
    env.reset(seed=0, options={"positions": [[1.5, 1.5, Z]]})
    forward = {"uav_0": np.array([1.0, 0.0, 0.0, 0.0], dtype=np.float32)}
    for _ in range(2):
        _, _, terms, truncs, _ = env.step(forward)
        assert not terms["uav_0"] and not truncs["uav_0"]
    _, _, terms, truncs, infos = env.step(forward)
    assert terms["uav_0"] and not truncs["uav_0"]
    summary = infos["uav_0"]["swarm_summary"]
    assert summary["coverage"] == 1.0 and summary["steps_to_90"] == 3 and summary["length"] == 3
    assert summary["collisions"] == 0 and summary["truncated"] is False


def test_truncation_at_max_steps():
    env = SwarmReconEnv(SMALL.replace(max_steps=7))
    env.reset(seed=0)
    for _ in range(6):
        _, _, terms, truncs, infos = env.step(zero_actions(env))
        assert not any(terms.values()) and not any(truncs.values())
        assert "swarm_summary" not in infos["uav_0"]
    _, _, terms, truncs, infos = env.step(zero_actions(env))
    assert not any(terms.values()) and all(truncs.values()) and env.agents == []
    summary = infos["uav_2"]["swarm_summary"]
    assert summary["truncated"] is True and summary["length"] == 7
    assert set(summary) == {
        "coverage",
        "collisions",
        "steps_to_90",
        "length",
        "episode_return",
        "link_up_rate",
        "dropout_rate",
        "truncated",
    }
    assert "episode" not in infos["uav_2"]
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_zero_energy_decay_never_depletes():
    env = SwarmReconEnv(SMALL.replace(energy_decay=0.0, max_steps=60))
    env.reset(seed=0)
    for _ in range(59):
        env.step(zero_actions(env))
    _, _, terms, truncs, _ = env.step(zero_actions(env))
    assert not any(terms.values()) and all(truncs.values())


# ---------------------------------------------------------------------------------------------------- links
def test_link_modes_reflect_in_link_row_and_infos():
    full = SwarmReconEnv(SMALL, link_mode="full", n_agents=4)
    obs, _ = full.reset(seed=0)
    for i, agent in enumerate(full.possible_agents):
        expected = np.ones(4, dtype=np.float32)
        expected[i] = 0.0
        np.testing.assert_array_equal(obs[agent]["link_row"], expected)
    _, _, _, _, infos = full.step(zero_actions(full))
    assert all(info["link_up_rate"] == 1.0 and info["dropout"] is False for info in infos.values())

    none = SwarmReconEnv(SMALL, link_mode="none", max_steps=3)
    none.reset(seed=0)
    for _ in range(3):
        obs, _, _, _, infos = none.step(zero_actions(none))
        for agent in none.possible_agents:
            np.testing.assert_array_equal(obs[agent]["link_row"], 0.0)
            assert infos[agent]["dropout"] is True and infos[agent]["link_up_rate"] == 0.0
    summary = infos["uav_0"]["swarm_summary"]
    assert summary["dropout_rate"] == 1.0 and summary["link_up_rate"] == 0.0


def test_channel_links_are_intermittent_and_statistics_consistent():
    env = SwarmReconEnv(SMALL.replace(max_steps=40, initial_energy=100.0))
    obs, _ = env.reset(seed=0)
    rows = [np.stack([obs[a]["link_row"] for a in env.possible_agents])]
    while env.agents:
        obs, _, _, _, infos = env.step(zero_actions(env))
        rows.append(np.stack([obs[a]["link_row"] for a in env.possible_agents]))
        for i, agent in enumerate(env.possible_agents):
            assert infos[agent]["dropout"] == (rows[-1][i].sum() == 0)
    rows = np.array(rows)  # (T + 1, N, N)
    assert np.all(rows[:, np.arange(3), np.arange(3)] == 0.0)  # own entry
    assert 0.0 < rows.mean() < 1.0  # p_f = 0.3: some links up, some down
    share = rows.sum(axis=2) / 2.0  # (T + 1, N)
    for i, agent in enumerate(env.possible_agents):
        assert infos[agent]["link_up_rate"] == pytest.approx(share[:, i].mean())
    summary = infos["uav_0"]["swarm_summary"]
    assert summary["link_up_rate"] == pytest.approx(share.mean())
    assert summary["dropout_rate"] == pytest.approx((rows.sum(axis=2) == 0).mean())


# ---------------------------------------------------------------------------------------------------- errors
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_action_raises(bad):
    env = SwarmReconEnv(SMALL)
    env.reset(seed=0)
    actions = zero_actions(env)
    actions["uav_1"] = np.array([0.0, bad, 0.0, 0.0], dtype=np.float32)
    with pytest.raises(ValueError, match="uav_1.*not finite"):
        env.step(actions)


def test_out_of_range_action_raises_and_tolerance_is_clipped():
    env = SwarmReconEnv(EXACT)
    env.reset(seed=0, options={"positions": [[5.5, 5.5, Z], [9.5, 9.5, Z]]})
    actions = zero_actions(env)
    actions["uav_0"] = np.array([0.0, 0.0, 1.5, 0.0], dtype=np.float32)
    with pytest.raises(ValueError, match=r"uav_0.*outside \[-1, 1\].*1\.5"):
        env.step(actions)
    actions["uav_0"] = np.array([1.0 + 1e-7, 0.0, 0.0, 0.0])
    env.step(actions)
    assert env.positions[0, 0] == pytest.approx(6.5)  # clipped to 1


def test_missing_unknown_and_malformed_actions_raise():
    env = SwarmReconEnv(SMALL)
    env.reset(seed=0)
    actions = zero_actions(env)
    del actions["uav_2"]
    with pytest.raises(ValueError, match="uav_2"):
        env.step(actions)
    actions = zero_actions(env)
    actions["uav_9"] = np.zeros(4)
    with pytest.raises(ValueError, match="uav_9"):
        env.step(actions)
    actions = zero_actions(env)
    actions["uav_0"] = np.zeros(3)
    with pytest.raises(ValueError, match=r"shape"):
        env.step(actions)


def test_bad_configs_and_arguments_raise():
    with pytest.raises(TypeError, match="not_a_field"):
        SwarmReconEnv(not_a_field=1)
    with pytest.raises(ValueError, match="n_agents"):
        SwarmReconEnv(n_agents=0)
    with pytest.raises(ValueError, match="link_mode"):
        SwarmReconEnv(link_mode="sometimes")
    with pytest.raises(TypeError, match="SwarmConfig"):
        SwarmReconEnv(config={"n_agents": 3})
    with pytest.raises(ValueError, match="render_mode"):
        SwarmReconEnv(render_mode="ansi")
    env = SwarmReconEnv(EXACT)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(zero_actions(env))
    with pytest.raises(ValueError, match="positions"):
        env.reset(seed=0, options={"positions": [[50.0, 5.0, Z], [1.0, 1.0, Z]]})
    with pytest.raises(ValueError, match="shape"):
        env.reset(seed=0, options={"positions": [[5.0, 5.0, Z]]})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="positions"):
        env.set_positions([[5.0, 5.0, 30.0], [1.0, 1.0, Z]])  # above max_altitude


# ---------------------------------------------------------------------------------------------------- rendering
def test_rgb_array_render():
    env = SwarmReconEnv(SMALL, render_mode="rgb_array", link_mode="full")
    env.reset(seed=0)
    env.step(zero_actions(env))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.shape[0] > 100 and frame.shape[1] > 100
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 4  # map colours, UAVs, links
    with pytest.warns(UserWarning, match="render_mode"):
        assert SwarmReconEnv(SMALL).render() is None


def test_human_render_draws_a_matplotlib_figure():
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    env = SwarmReconEnv(SMALL, render_mode="human")
    env.reset(seed=0)
    figures = len(plt.get_fignums())
    assert env.render() is None
    env.step(zero_actions(env))
    assert env.render() is None
    assert len(plt.get_fignums()) == figures + 1
    env.close()
    assert len(plt.get_fignums()) == figures


def test_matplotlib_is_not_imported_by_the_env():
    code = (
        "import sys, numpy as np\n"
        "from sb3_latentswarm.envs import SwarmReconEnv\n"
        "env = SwarmReconEnv(render_mode='rgb_array')\n"
        "env.reset(seed=0)\n"
        "env.step({a: np.zeros(4, dtype=np.float32) for a in env.agents})\n"
        "env.render()\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_numpy_scalars_are_accepted_as_the_numbers_they_equal():
    config = SwarmConfig(n_agents=np.int64(3), grid_width=np.int32(20), p_fail=np.float32(0.5))
    assert config == SwarmConfig(n_agents=3, grid_width=20, p_fail=float(np.float32(0.5)))
    assert type(config.n_agents) is int and type(config.p_fail) is float
    with pytest.raises(TypeError, match="n_agents must be an int, got float64"):
        SwarmConfig(n_agents=np.float64(2.5))


def test_step_given_a_list_instead_of_a_dict_is_a_clear_type_error():
    env = SwarmReconEnv(SwarmConfig(grid_width=10, grid_height=10))
    env.reset(seed=0)
    with pytest.raises(TypeError, match="actions must be a dict .*got list"):
        env.step([np.zeros(4)] * 3)
