"""Non-learned planners: the coordinated lawnmower and frontier explorer, and the message-free heuristics."""

import math

import numpy as np
import pytest

from sb3_latentswarm import SwarmConfig
from sb3_latentswarm.baselines import (
    COORDINATED_PLANNERS,
    MESSAGE_FREE_PLANNERS,
    FrontierPlanner,
    IndependentRecurrentPPO,
    LawnmowerPlanner,
    RandomPlanner,
    RandomStripPlanner,
    SpiralPlanner,
    SweepPlanner,
    train_independent_ppo,
)
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env
from sb3_latentswarm.evaluation import EPISODE_COLUMNS, evaluate


def lawnmower_step_bound(config: SwarmConfig) -> int:
    """Steps a lawnmower needs at most without actuation noise.

    A leg to a waypoint takes at most ceil(Chebyshev distance / (v_max dt)) steps (both axes move at once, proportional
    to the remaining offset), with v_max dt = 1 cell here. Worst strip: L = ceil(widest strip / (2r + 1)) lanes. Legs:
    the start to the first waypoint (< max(W, H) cells), L lanes of H - 1 - 2r cells, L - 1 lane changes of at most
    2r + 1 cells. Coverage is complete once the last lane has been flown.
    """
    width, height, n, fw = config.grid_width, config.grid_height, config.n_agents, config.footprint_width
    widest = max(((i + 1) * width) // n - (i * width) // n for i in range(n))
    lanes = math.ceil(widest / fw)
    return max(width, height) + lanes * (height - fw) + (lanes - 1) * fw


NOISELESS = dict(actuation_noise_std=0.0, max_steps=1000, v_max=1.0)


@pytest.mark.parametrize(
    "config",
    [
        SwarmConfig(n_agents=3, grid_width=15, grid_height=15, sensor_range=2, num_obstacles=0, **NOISELESS),
        SwarmConfig(n_agents=2, grid_width=17, grid_height=13, sensor_range=1, num_obstacles=10, **NOISELESS),
        SwarmConfig(n_agents=4, grid_width=9, grid_height=20, sensor_range=1, num_obstacles=0, **NOISELESS),
    ],
    ids=["15x15-N3-r2", "17x13-N2-r1", "9x20-N4-r1"],
)
def test_lawnmower_covers_everything_within_the_bound(config):
    df = evaluate(LawnmowerPlanner(config), "no_comm", n_episodes=4, seed=0, config=config)
    assert (df["coverage"] == 100.0).all(), df
    bound = lawnmower_step_bound(config)
    assert (df["episode_length"] <= bound).all(), (df["episode_length"].tolist(), bound)


def test_lawnmower_in_the_body_frame():
    """Commands are rotated into the body frame; a diagonal move may slow to v_max / sqrt(2) per axis."""
    config = SwarmConfig(
        n_agents=3, grid_width=15, grid_height=15, sensor_range=2, action_frame="body", num_obstacles=0, **NOISELESS
    )
    df = evaluate(LawnmowerPlanner(config), "no_comm", n_episodes=4, seed=0, config=config)
    assert (df["coverage"] == 100.0).all(), df
    bound = math.ceil(math.sqrt(2) * lawnmower_step_bound(config))
    assert (df["episode_length"] <= bound).all(), (df["episode_length"].tolist(), bound)


@pytest.mark.parametrize(
    "width, n_agents, sensor_range", [(15, 3, 2), (17, 2, 1), (50, 3, 2), (7, 5, 1), (4, 6, 0), (11, 1, 3)]
)
def test_lawnmower_lanes_cover_every_column(width, n_agents, sensor_range):
    config = SwarmConfig(n_agents=n_agents, grid_width=width, grid_height=12, sensor_range=sensor_range)
    table, lengths = LawnmowerPlanner(config).routes(n_agents)
    covered = np.zeros(width, dtype=bool)
    for agent in range(n_agents):
        for order in range(4):
            lanes = np.unique(table[agent, order, : lengths[agent, order], 0])
            assert (lanes >= min(sensor_range, width - 1)).all() and (lanes <= max(width - 1 - sensor_range, 0)).all()
            if order == 0:
                for x in lanes:
                    covered[max(x - sensor_range, 0) : x + sensor_range + 1] = True
    assert covered.all()


def test_frontier_covers_a_small_map():
    config = SwarmConfig(n_agents=3, grid_width=15, grid_height=15, max_steps=150)
    df = evaluate(FrontierPlanner(config), "proposed", n_episodes=4, seed=0, config=config)
    assert (df["coverage"] >= 95.0).all(), df["coverage"].tolist()


def test_frontier_explores_faster_with_shared_maps():
    """Within a tight horizon, map sharing over full links must beat isolated exploration clearly."""
    config = SwarmConfig(n_agents=3, grid_width=20, grid_height=20, max_steps=40, v_max=1.0)
    planner = FrontierPlanner(config)
    full = evaluate(planner, "full_comm", n_episodes=5, seed=0, config=config)["coverage"]
    alone = evaluate(planner, "no_comm", n_episodes=5, seed=0, config=config)["coverage"]
    assert full.mean() >= alone.mean() + 15.0, (full.tolist(), alone.tolist())


@pytest.mark.parametrize("link_mode", ["full", "channel", "none"])
def test_frontier_maps_follow_the_links(link_mode):
    """Per-UAV maps hold exactly what the UAV sensed or received over a live link."""
    config = SwarmConfig(
        n_agents=3, grid_width=12, grid_height=10, sensor_range=1, max_steps=15, link_mode=link_mode, p_fail=0.5
    )
    env = SwarmReconEnv(config)
    planner = FrontierPlanner(config)
    obs, _ = env.reset(seed=4)
    state, start = None, np.ones(config.n_agents)
    sensed_before = np.zeros((config.grid_height, config.grid_width), dtype=bool)
    for _ in range(config.max_steps):
        links = np.stack([obs[a]["link_row"] for a in env.possible_agents]) > 0.5
        previous = None if state is None else state.known.copy()
        actions, state = planner.predict(obs, state, start)
        start = np.zeros(config.n_agents)
        sensed = env.global_map >= 0
        np.testing.assert_array_equal(state.known.any(axis=0), sensed)  # own patches, placed where the env sensed
        if previous is not None:
            for i in range(config.n_agents):
                received = previous[links[i]].any(axis=0)
                assert (state.known[i] >= received).all()
                if link_mode == "full":
                    assert (state.known[i] >= sensed_before).all()
                if link_mode == "none":
                    assert np.isnan(state.peer_cell[i]).all()
        assert all(np.abs(a).max() <= 1.0 for a in actions.values())
        sensed_before = sensed
        obs, _, terminations, truncations, _ = env.step(actions)
        if any(terminations.values()) or any(truncations.values()):
            break


def test_state_resets_at_episode_start():
    config = SwarmConfig(n_agents=2, grid_width=10, grid_height=10, max_steps=10)
    env = SwarmReconEnv(config)
    obs, _ = env.reset(seed=0)
    stacked = {key: np.stack([obs[a][key] for a in env.possible_agents]) for key in ("local_obs", "proprio", "link_row")}
    all_planners = [cls(config) for cls in (*COORDINATED_PLANNERS.values(), *MESSAGE_FREE_PLANNERS.values(), RandomPlanner)]
    for planner in all_planners:
        actions, state = planner.predict(stacked)
        assert actions.shape == (2, 4) and (np.abs(actions) <= 1.0).all()
        _, continued = planner.predict(stacked, state, np.zeros(2))
        _, restarted = planner.predict(stacked, continued, np.ones(2))
        fresh_actions, fresh = planner.predict(stacked, None, np.ones(2))
        for field, fresh_field in zip(restarted, fresh):
            np.testing.assert_array_equal(field, fresh_field)
        with pytest.raises(ValueError, match="slots"):
            planner.predict({key: value[:1] for key, value in stacked.items()}, state)


def test_evaluate_runs_the_planners():
    config = SwarmConfig(n_agents=3, grid_width=12, grid_height=12, max_steps=30)
    all_planners = [cls(config) for cls in (*COORDINATED_PLANNERS.values(), *MESSAGE_FREE_PLANNERS.values(), RandomPlanner)]
    for planner in all_planners:
        df = evaluate(planner, "proposed", n_episodes=3, seed=2)  # the planner's own config is the default
        assert list(df.columns) == list(EPISODE_COLUMNS) and len(df) == 3
        assert df["map_error"].isna().all() and df["pred_error_dropout"].isna().all()
        assert df["episode_length"].le(30).all() and df["coverage"].between(0, 100).all()
        again = evaluate(planner, "proposed", n_episodes=3, seed=2)
        assert df.equals(again)
        with pytest.raises(ValueError, match="no_predictor"):
            evaluate(planner, "no_predictor", n_episodes=1)
        with pytest.raises(ValueError, match="geometry"):
            evaluate(planner, n_episodes=1, config=config.replace(grid_width=13))


def test_random_planner_is_uniform_and_reproducible():
    config = SwarmConfig(n_agents=3, grid_width=12, grid_height=12, max_steps=50)
    rng = np.random.default_rng(0)
    obs = {
        "local_obs": rng.integers(-1, 2, (300, config.footprint_width**2)).astype(np.int8),
        "proprio": rng.random((300, 8)).astype(np.float32),
        "link_row": np.zeros((300, 3), dtype=np.float32),
    }
    actions, _ = RandomPlanner(config, seed=1).predict(obs)
    horizontal = actions[:, :2].ravel()
    assert horizontal.min() >= -1.0 and horizontal.max() < 1.0
    # 600 uniform draws on [-1, 1): mean 0 (std 0.024), and each quarter of the range holds about 150
    assert abs(horizontal.mean()) < 0.1
    assert (np.histogram(horizontal, bins=4, range=(-1, 1))[0] > 100).all()
    assert np.isfinite(actions).all() and (actions[:, 3] == 0).all()

    planner = RandomPlanner(config, seed=1)
    df = evaluate(planner, "proposed", n_episodes=3, seed=5)
    pd_equal = df.equals(evaluate(planner, "proposed", n_episodes=3, seed=5, n_envs=1))
    assert pd_equal  # an episode depends on its env seed only, not on the lockstep copies
    other = evaluate(RandomPlanner(config, seed=2), "proposed", n_episodes=3, seed=5)
    assert not df["coverage"].equals(other["coverage"])
    with pytest.raises(ValueError, match="seed"):
        RandomPlanner(config, seed=-1)


# ---------------------------------------------------------------------------------------------- message-free heuristics
def covered_by_route(points: np.ndarray, config: SwarmConfig) -> np.ndarray:
    """(H, W) bool: cells within the footprint of some cell on the axis-aligned legs between consecutive waypoints."""
    covered = np.zeros((config.grid_height, config.grid_width), dtype=bool)
    r = config.sensor_range
    for (x0, y0), (x1, y1) in zip(points, points[1:] if len(points) > 1 else points):
        assert x0 == x1 or y0 == y1, "legs of these routes are axis-aligned"
        xs, ys = sorted((x0, x1)), sorted((y0, y1))
        covered[max(ys[0] - r, 0) : ys[1] + r + 1, max(xs[0] - r, 0) : xs[1] + r + 1] = True
    return covered


@pytest.mark.parametrize("planner_class", [SweepPlanner, SpiralPlanner])
@pytest.mark.parametrize("width, height, sensor_range", [(20, 20, 2), (17, 13, 1), (9, 20, 1), (5, 5, 2), (11, 30, 3)])
def test_whole_map_routes_cover_every_cell_and_ignore_the_agent(planner_class, width, height, sensor_range):
    config = SwarmConfig(grid_width=width, grid_height=height, sensor_range=sensor_range, num_obstacles=0)
    table, lengths = planner_class(config).routes(3)
    assert (table == table[:1]).all() and (lengths == lengths[:1]).all()  # no agent index in the plan
    for variant in range(table.shape[1]):
        points = table[0, variant, : lengths[0, variant]]
        assert covered_by_route(points, config).all(), (variant, points.tolist())


@pytest.mark.parametrize("planner_class", [SweepPlanner, SpiralPlanner, RandomStripPlanner])
def test_message_free_planner_alone_covers_the_map(planner_class):
    config = SwarmConfig(n_agents=1, grid_width=15, grid_height=12, sensor_range=1, num_obstacles=0, **NOISELESS)
    df = evaluate(planner_class(config), "no_comm", n_episodes=3, seed=0, config=config)
    assert (df["coverage"] == 100.0).all(), df


def test_random_strip_picks_strips_uniformly_and_independently_of_the_agent():
    config = SwarmConfig(n_agents=3, grid_width=15, grid_height=15)
    planner = RandomStripPlanner(config, seed=3)
    rng = np.random.default_rng(0)
    n_swarms = 600
    obs = {
        "local_obs": np.zeros((3 * n_swarms, config.footprint_width**2), dtype=np.int8),
        "proprio": rng.random((3 * n_swarms, 8)).astype(np.float32) * 0.1,  # every UAV near the corner
        "link_row": np.zeros((3 * n_swarms, 3), dtype=np.float32),
    }
    _, state = planner.predict(obs)
    strip = (state.route // 4).reshape(n_swarms, 3)
    # each of the 3 strips about 600 times per agent index (binomial std 11.5)
    for agent in range(3):
        assert (np.abs(np.bincount(strip[:, agent], minlength=3) - n_swarms / 3) < 5 * 11.5).all()
    same = (strip[:, 0] == strip[:, 1]).mean()  # independent picks: P = 1/3 (std 0.019)
    assert abs(same - 1 / 3) < 0.1
    # the route of strip k starts with the lawnmower's route of strip k
    lawn_table, lawn_lengths = LawnmowerPlanner(config).routes(3)
    table, _ = planner.routes(3)
    for k in range(3):
        n = lawn_lengths[k, 0]
        np.testing.assert_array_equal(table[0, 4 * k, :n], lawn_table[k, 0, :n])
    again, _ = RandomStripPlanner(config, seed=3).predict(obs)
    np.testing.assert_array_equal(again, planner.predict(obs)[0])
    with pytest.raises(ValueError, match="seed"):
        RandomStripPlanner(config, seed=-2)


def test_coordination_preset_needs_coordination():
    """On the coordination preset the best coordinated planner beats every message-free heuristic by >= 15 points."""
    from sb3_latentswarm.presets import get_preset

    config = get_preset("coordination").config
    coverage = {}
    for name, planner_class in {**COORDINATED_PLANNERS, **MESSAGE_FREE_PLANNERS}.items():
        coverage[name] = evaluate(planner_class(config), "proposed", None, 20, 20_000, config)["coverage"].mean()
    coverage["frontier_no_links"] = evaluate(FrontierPlanner(config), "no_comm", None, 20, 20_000, config)["coverage"].mean()
    best_coordinated = max(coverage[name] for name in COORDINATED_PLANNERS)
    best_free = max(value for name, value in coverage.items() if name not in COORDINATED_PLANNERS)
    assert best_coordinated - best_free >= 15.0, coverage


def test_independent_ppo_sees_only_its_own_observation_and_round_trips(tmp_path):
    config = SwarmConfig(n_agents=2, grid_width=8, grid_height=8, max_steps=10, num_obstacles=2)
    independent = train_independent_ppo(make_vec_env(2, config=config, seed=0), 2 * 2 * 16, n_steps=16, batch_size=32)
    assert set(independent.model.observation_space.spaces) == {"local_obs", "proprio"}
    independent.save(tmp_path / "independent.zip")
    loaded = IndependentRecurrentPPO.load(tmp_path / "independent.zip", device="cpu")
    env = make_vec_env(2, config=config, seed=1)
    obs = env.reset()
    starts = np.ones(env.num_envs, dtype=bool)
    first, _ = independent.predict(obs, None, starts, deterministic=True)
    second, _ = loaded.predict(obs, None, starts, deterministic=True)
    np.testing.assert_array_equal(first, second)
    with pytest.raises(ValueError, match="no file at"):
        IndependentRecurrentPPO.load(tmp_path / "missing.zip")
