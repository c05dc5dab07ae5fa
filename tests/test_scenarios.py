"""Opt-in scenario extensions (issue 10): start regions, bursty Gilbert-Elliott outages, the full-in-range link mode."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_latentswarm.channel import (
    XI_UNSET,
    A2AChannel,
    link_probability,
    outage_thresholds,
    outage_transition_probabilities,
    step_link_outages,
    usable_link_range,
)
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env
from sb3_latentswarm.envs.start_positions import sample_start_positions

N_SE = 5.0  # tolerance in standard errors


def run_outage_chain(config: SwarmConfig, n_links: int, n_steps: int, seed: int) -> np.ndarray:
    """xi of ``n_links`` independent co-located pairs (links that never fail on SINR), shape (n_steps, n_links)."""
    channel = A2AChannel(config)
    positions = np.zeros((n_links // 2, 2, 3))
    positions[..., 2] = config.initial_altitude
    positions[:, 1, 0] = 0.5  # 0.5 m apart: Eq. (1) succeeds with probability 1 - 1e-300
    xi_state = np.full((n_links // 2, 2, 2), XI_UNSET, dtype=np.int8)
    rng = np.random.default_rng(seed)
    off = ~np.eye(2, dtype=bool)
    return np.stack([channel.sample(positions, rng, xi_state)[:, off].ravel() for _ in range(n_steps)])


def failure_runs(xi: np.ndarray) -> np.ndarray:
    """Lengths of the complete failure runs (preceded and followed by an up step) in ``xi`` (n_steps, n_links)."""
    padded = np.concatenate([np.ones((1, xi.shape[1]), bool), xi, np.ones((1, xi.shape[1]), bool)]).T.astype(np.int8)
    edges = np.diff(padded, axis=1)  # -1: a run starts at the next step, +1: it ended
    starts_link, starts_t = np.nonzero(edges == -1)
    ends_link, ends_t = np.nonzero(edges == 1)
    lengths = ends_t - starts_t  # runs pair up in order within each link
    assert np.array_equal(starts_link, ends_link)
    complete = (starts_t > 0) & (ends_t < xi.shape[0])
    return lengths[complete]


# ---------------------------------------------------------------------------------------------- Gilbert-Elliott
@pytest.mark.parametrize("p_fail, mean_outage_steps", [(0.3, 10.0), (0.5, 4.0), (0.1, 25.0)])
def test_gilbert_elliott_stationary_failure_and_mean_run(p_fail: float, mean_outage_steps: float) -> None:
    config = SwarmConfig(p_fail=p_fail, outage_model="gilbert_elliott", mean_outage_steps=mean_outage_steps)
    xi = run_outage_chain(config, n_links=1000, n_steps=1500, seed=3)
    # the failure fraction is p_f at every step (the chain starts stationary), so at the first step too
    first = 1.0 - xi[0].mean()
    assert abs(first - p_fail) <= N_SE * np.sqrt(p_fail * (1 - p_fail) / xi.shape[1])
    # over time: successive steps are correlated, so use a generous tolerance for the pooled fraction
    assert abs((1.0 - xi.mean()) - p_fail) < 0.02
    runs = failure_runs(xi)
    se = runs.std() / np.sqrt(runs.size)
    # complete runs inside a window of 1500 steps are biased short by about L / 1500: inside the tolerance
    assert abs(runs.mean() - mean_outage_steps) <= N_SE * se + mean_outage_steps * 0.02, (runs.mean(), se)


def test_bernoulli_runs_are_short_and_the_bernoulli_run_length_gives_bernoulli_draws() -> None:
    p_fail = 0.3
    bernoulli = run_outage_chain(SwarmConfig(p_fail=p_fail), n_links=1000, n_steps=500, seed=4)
    runs = failure_runs(bernoulli)
    assert abs(runs.mean() - 1.0 / (1.0 - p_fail)) < 0.03  # geometric: 1 / (1 - p_f) = 1.43 steps
    # L = 1 / (1 - p_f): the chain's thresholds all equal p_f, the same draws as Bernoulli
    chain = SwarmConfig(p_fail=p_fail, outage_model="gilbert_elliott", mean_outage_steps=1.0 / (1.0 - p_fail))
    np.testing.assert_allclose(outage_thresholds(chain), [p_fail] * 3)
    np.testing.assert_array_equal(run_outage_chain(chain, 1000, 500, seed=4), bernoulli)


def test_link_probability_holds_at_every_step_of_the_chain() -> None:
    config = SwarmConfig(outage_model="gilbert_elliott", mean_outage_steps=8.0)
    distances = np.array([5.0, 30.0, 45.0])
    reps = 8000
    d = np.repeat(distances, reps)
    positions = np.zeros((d.size, 2, 3))
    positions[..., 2] = 10.0
    positions[:, 1, 0] = d
    channel = A2AChannel(config)
    xi_state = np.full((d.size, 2, 2), XI_UNSET, dtype=np.int8)
    rng = np.random.default_rng(5)
    expected = link_probability(distances, config)
    off = ~np.eye(2, dtype=bool)
    for step in range(40):
        links = channel.sample(positions, rng, xi_state)
        if step in (0, 39):  # the marginal across independent pairs, at the first and at a late step
            rate = links[:, off].reshape(len(distances), -1).mean(axis=1)
            se = np.sqrt(expected * (1 - expected) / (2 * reps))
            assert np.all(np.abs(rate - expected) <= N_SE * se), (step, rate, expected)


def test_outage_transition_probabilities() -> None:
    fail, recover = outage_transition_probabilities(0.3, 10.0)
    assert recover == pytest.approx(0.1) and fail / (fail + recover) == pytest.approx(0.3)
    assert outage_transition_probabilities(0.0, 5.0) == (0.0, 0.2)
    assert outage_transition_probabilities(1.0, 5.0) == (1.0, 0.0)


@pytest.mark.parametrize("p_fail, all_up", [(0.0, True), (1.0, False)])
def test_gilbert_elliott_extreme_failure_probabilities(p_fail: float, all_up: bool) -> None:
    config = SwarmConfig(p_fail=p_fail, outage_model="gilbert_elliott", mean_outage_steps=3.0)
    xi = run_outage_chain(config, n_links=200, n_steps=100, seed=6)
    assert xi.all() if all_up else not xi.any()


def test_step_link_outages_any_leading_shape() -> None:
    thresholds = outage_thresholds(SwarmConfig(p_fail=0.3, outage_model="gilbert_elliott", mean_outage_steps=10.0))
    xi_state = np.array([XI_UNSET, 0, 1, 0, 1, XI_UNSET], dtype=np.int8).reshape(1, 2, 3)
    xi_state = np.broadcast_to(xi_state, (4, 5, 2, 3)).copy()
    uniforms = np.full(xi_state.shape, 0.5)
    xi = step_link_outages(xi_state, uniforms, thresholds)
    assert xi.shape == xi_state.shape and xi.dtype == bool
    # u = 0.5: unset -> up (0.5 >= 0.3), failed stays failed (0.5 < 0.9), up stays up (0.5 >= f = 0.043)
    np.testing.assert_array_equal(xi[0, 0], [[True, False, True], [False, True, True]])


def test_gilbert_elliott_needs_its_state_and_bernoulli_ignores_it() -> None:
    positions = np.array([[0.0, 0.0, 10.0], [3.0, 0.0, 10.0], [0.0, 4.0, 10.0]])
    with pytest.raises(ValueError, match="xi_state"):
        A2AChannel(SwarmConfig(outage_model="gilbert_elliott")).sample(positions, np.random.default_rng(0))
    with pytest.raises(ValueError, match="int8"):
        A2AChannel(SwarmConfig(outage_model="gilbert_elliott")).sample(
            positions, np.random.default_rng(0), np.zeros((3, 3), dtype=bool)
        )
    bernoulli = A2AChannel(SwarmConfig())
    xi_state = np.full((3, 3), XI_UNSET, dtype=np.int8)
    with_state = bernoulli.sample(positions, np.random.default_rng(1), xi_state)
    np.testing.assert_array_equal(with_state, bernoulli.sample(positions, np.random.default_rng(1)))
    assert (xi_state == XI_UNSET).all()


def link_rows_of_episode(config: SwarmConfig, seed: int) -> np.ndarray:
    env = SwarmReconEnv(config)
    obs, _ = env.reset(seed=seed)
    rows = []
    while env.agents:
        rows.append(np.stack([obs[a]["link_row"] for a in env.possible_agents]))
        obs, *_ = env.step({a: np.zeros(4, np.float32) for a in env.agents})
    return np.stack(rows)


def test_env_gilbert_elliott_reseeding_reproduces_and_outages_last() -> None:
    config = SwarmConfig(
        grid_width=10, grid_height=10, max_steps=300, outage_model="gilbert_elliott", mean_outage_steps=12.0, p_fail=0.3
    )
    first = link_rows_of_episode(config, seed=7)
    np.testing.assert_array_equal(first, link_rows_of_episode(config, seed=7))
    assert not np.array_equal(first, link_rows_of_episode(config, seed=8))
    # hovering UAVs 10 m apart at most: the SINR rarely fails, so a failed link stays down for about L steps
    off = ~np.eye(config.n_agents, dtype=bool)
    runs = failure_runs(first[:, off] > 0.5)
    assert runs.size > 5 and runs.mean() > 5.0
    # the outage state restarts at reset: the same seed after another episode gives the same episode again
    env = SwarmReconEnv(config)
    env.reset(seed=7)
    for _ in range(20):
        env.step({a: np.zeros(4, np.float32) for a in env.agents})
    obs, _ = env.reset(seed=7)
    np.testing.assert_array_equal(np.stack([obs[a]["link_row"] for a in env.possible_agents]), first[0])


# ---------------------------------------------------------------------------------------------- full_in_range
def test_full_in_range_forces_exactly_the_links_within_the_usable_range() -> None:
    config = SwarmConfig(link_mode="full_in_range")
    link_range = usable_link_range(config)
    channel_only = config.replace(link_mode="channel", p_fail=0.0)
    assert float(link_probability(link_range, channel_only)) == pytest.approx(config.link_range_probability, abs=1e-6)
    assert usable_link_range(config.replace(link_range_probability=0.05)) > link_range  # a smaller probability reaches further
    positions = np.array([[0.0, 0.0, 10.0], [link_range - 0.1, 0.0, 10.0], [0.0, link_range + 0.1, 10.0]])
    channel = A2AChannel(config)
    assert channel.link_range == pytest.approx(link_range)
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    links = channel.sample(positions, rng)
    assert rng.bit_generator.state == state  # no random draws
    np.testing.assert_array_equal(links, [[False, True, False], [True, False, False], [False, False, False]])
    np.testing.assert_array_equal(link_probability([link_range - 0.1, link_range + 0.1], config), [1.0, 0.0])
    assert usable_link_range(config.replace(path_loss_exponent=0.0)) == np.inf


# ---------------------------------------------------------------------------------------------- start regions
def test_uniform_start_keeps_the_paper_draws() -> None:
    config = SwarmConfig()
    positions = sample_start_positions(config, np.random.default_rng(11))
    reference = np.random.default_rng(11).random((config.n_agents, 2)) * config.arena_size  # the original reset draw
    assert positions.shape == (1, config.n_agents, 3)
    np.testing.assert_array_equal(positions[0, :, :2], reference)
    assert np.all(positions[..., 2] == config.initial_altitude)
    env = SwarmReconEnv(config)
    env.reset(seed=12)
    np.testing.assert_array_equal(env.positions, sample_start_positions(config, _rng_after_obstacles(config, 12))[0])


def _rng_after_obstacles(config: SwarmConfig, seed: int) -> np.random.Generator:
    """The env's generator after reset's obstacle draw, the draw before the start positions."""
    from gymnasium.utils import seeding

    rng, _ = seeding.np_random(seed)
    rng.choice(config.n_cells, size=config.num_obstacles, replace=False)
    return rng


def test_corner_start_through_make_vec_env() -> None:
    size = 6.0
    config = SwarmConfig(grid_width=20, grid_height=20, cell_size=2.5, start_region="corner", start_region_size=size)
    venv = make_vec_env(40, config=config, seed=0)
    obs = venv.reset()
    arena_x, arena_y = config.arena_size
    xy = obs["proprio"][:, :2] * (arena_x, arena_y)  # e_t = [x/X, y/Y, ...]
    assert np.all((xy >= 0.0) & (xy <= size + 1e-4))
    # uniform jitter inside the square: mean s/2, std s/sqrt(12) per axis over 120 UAVs
    assert np.all(np.abs(xy.mean(axis=0) - size / 2) < N_SE * size / np.sqrt(12 * xy.shape[0]))
    assert len({tuple(p) for p in np.round(xy, 6)}) == xy.shape[0]  # no two UAVs share a start
    venv.close()


def test_start_positions_batch_shape_and_region() -> None:
    config = SwarmConfig(n_agents=4, start_region="corner", start_region_size=3.0, initial_altitude=12.0)
    positions = sample_start_positions(config, np.random.default_rng(0), n_swarms=5)
    assert positions.shape == (5, 4, 3)
    assert np.all(positions[..., :2] <= 3.0) and np.all(positions[..., 2] == 12.0)
    again = sample_start_positions(config, np.random.default_rng(0), n_swarms=5)
    np.testing.assert_array_equal(positions, again)


def test_random_corner_launches_each_swarm_from_one_drawn_corner() -> None:
    config = SwarmConfig(n_agents=5, start_region="random_corner", start_region_size=7.5)
    positions = sample_start_positions(config, np.random.default_rng(3), n_swarms=400)
    corner_config = config.replace(start_region="corner")
    base = sample_start_positions(corner_config, np.random.default_rng(3), n_swarms=400)  # the same jitter draw
    arena_x, arena_y = config.arena_size
    far_x = positions[..., 0] > arena_x / 2
    far_y = positions[..., 1] > arena_y / 2
    # all UAVs of a swarm share its corner, and the jitter is the corner square's, mirrored
    assert np.all(far_x == far_x[:, :1]) and np.all(far_y == far_y[:, :1])
    np.testing.assert_allclose(np.where(far_x, arena_x - positions[..., 0], positions[..., 0]), base[..., 0])
    np.testing.assert_allclose(np.where(far_y, arena_y - positions[..., 1], positions[..., 1]), base[..., 1])
    counts = np.bincount(far_x[:, 0] + 2 * far_y[:, 0], minlength=4)
    assert np.all(np.abs(counts - 100) < 4 * np.sqrt(400 * 0.25 * 0.75))  # the four corners equally likely


# ---------------------------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "changes, match",
    [
        ({"start_region": "center"}, r"start_region must be one of \('uniform', 'corner', 'random_corner'\), got 'center'"),
        ({"start_region_size": 0.0}, r"start_region_size must be a finite number in \(0.0, inf\), got 0.0"),
        ({"start_region": "corner", "start_region_size": 60.0}, r"start_region_size must be in \(0, 50.0\].*got 60.0"),
        ({"outage_model": "markov"}, r"outage_model must be one of \('bernoulli', 'gilbert_elliott'\), got 'markov'"),
        ({"mean_outage_steps": 0.5}, r"mean_outage_steps must be a finite number in \[1.0, 1000000.0\], got 0.5"),
        (
            {"outage_model": "gilbert_elliott", "p_fail": 0.9, "mean_outage_steps": 5.0},
            r"mean_outage_steps must be >= 1 / \(1 - p_fail\) = 10 steps.*p_fail=0.9, got 5.0",
        ),
        ({"link_range_probability": 1.0}, r"link_range_probability must be a finite number in \(0.0, 1.0\), got 1.0"),
        ({"link_mode": "near"}, r"link_mode must be one of"),
    ],
)
def test_bad_scenario_fields_raise(changes: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SwarmConfig(**changes)


def test_boundary_values_are_accepted() -> None:
    SwarmConfig(outage_model="gilbert_elliott", p_fail=0.5, mean_outage_steps=2.0)  # exactly the Bernoulli run length
    SwarmConfig(outage_model="gilbert_elliott", p_fail=1.0, mean_outage_steps=1.0)  # every link down
    SwarmConfig(start_region="corner", start_region_size=50.0)  # the whole arena


def test_full_comm_in_range_condition_in_evaluate() -> None:
    from sb3_latentswarm.baselines import LawnmowerPlanner
    from sb3_latentswarm.evaluation import CONDITIONS, EXTRA_CONDITIONS, condition_config, evaluate

    assert "full_comm_in_range" in EXTRA_CONDITIONS and "full_comm_in_range" not in CONDITIONS
    config = SwarmConfig(grid_width=30, grid_height=30, cell_size=2.0, max_steps=60, start_region="uniform")
    assert condition_config(config, "full_comm_in_range", 0.3).link_mode == "full_in_range"
    planner = LawnmowerPlanner(config)
    in_range = evaluate(planner, "full_comm_in_range", n_episodes=4, seed=0, config=config)
    full = evaluate(planner, "full_comm", n_episodes=4, seed=0, config=config)
    # the lawnmower ignores links, so only the link statistics differ: 60 m arena, 36.4 m range
    np.testing.assert_array_equal(in_range["coverage"], full["coverage"])
    assert (full["link_up_rate"] == 1.0).all() and (in_range["link_up_rate"] < 1.0).all()
