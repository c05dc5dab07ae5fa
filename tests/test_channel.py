"""Tests of the A2A channel of Eq. (1) (``sb3_latentswarm.channel``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from sb3_latentswarm.channel import A2AChannel, ChannelDraws, link_probability, sample_rician_power
from sb3_latentswarm.config import SwarmConfig

DISTANCES = np.array([5.0, 20.0, 35.0, 50.0, 80.0])
N_SE = 5.0  # tolerance in binomial standard errors


def pair_batch(distances: np.ndarray, reps: int, z_a: float = 10.0, z_b: float = 10.0) -> np.ndarray:
    """Batch (len(distances) * reps, 2, 3) of UAV pairs, pair k at 3D distance distances[k // reps]."""
    d = np.repeat(distances, reps)
    pos = np.zeros((d.size, 2, 3))
    pos[:, 0, 2] = z_a
    pos[:, 1, 2] = z_b
    pos[:, 1, 0] = np.sqrt(np.maximum(d**2 - (z_a - z_b) ** 2, 0.0))
    return pos


def assert_rates_match(links: np.ndarray, expected: np.ndarray, groups: int) -> None:
    """``links`` (groups * reps, N, N); compare the off-diagonal rate of each group to ``expected``."""
    n = links.shape[-1]
    off = ~np.eye(n, dtype=bool)
    per_group = links.reshape(groups, -1, n, n)[..., off]  # (groups, reps, n*(n-1))
    rate = per_group.reshape(groups, -1).mean(axis=1)
    count = per_group.reshape(groups, -1).shape[1]
    se = np.sqrt(np.maximum(expected * (1 - expected), 1e-4) / count)
    assert np.all(np.abs(rate - expected) <= N_SE * se), (rate, expected, se)


# ---------------------------------------------------------------- empirical rate vs closed form
@pytest.mark.parametrize("p_fail", [0.0, 0.3, 0.5])
def test_link_rate_matches_closed_form(p_fail: float) -> None:
    cfg = SwarmConfig(p_fail=p_fail)
    channel = A2AChannel(cfg)
    reps = 10_000  # two directed links per pair -> 20000 samples per distance
    links = channel.sample(pair_batch(DISTANCES, reps), np.random.default_rng(1))
    expected = link_probability(DISTANCES, cfg)
    assert_rates_match(links, expected, len(DISTANCES))
    # the distances span the interesting range (from "almost surely up" to "almost surely down")
    assert expected[0] > 0.99 * (1 - p_fail) and expected[-1] < 0.01


@pytest.mark.parametrize(
    "changes",
    [
        {"rician_k": 0.0},  # Rayleigh
        {"interference_max": 0.0},  # no averaging over I
        {"path_loss_exponent": 2.7, "tx_power_dbm": 30.0},  # general alpha
    ],
)
def test_link_rate_matches_closed_form_other_channels(changes: dict) -> None:
    cfg = SwarmConfig(**changes)
    links = A2AChannel(cfg).sample(pair_batch(DISTANCES, 10_000), np.random.default_rng(2))
    assert_rates_match(links, link_probability(DISTANCES, cfg), len(DISTANCES))


def test_link_rate_with_altitude_slope() -> None:
    cfg = SwarmConfig(rician_k_altitude_slope=1.0)
    channel = A2AChannel(cfg)
    rng = np.random.default_rng(3)
    expected_by_alt = {}
    for z_a, z_b in [(5.0, 5.0), (5.0, 20.0), (20.0, 20.0)]:
        links = channel.sample(pair_batch(DISTANCES, 10_000, z_a, z_b), rng)
        expected = link_probability(DISTANCES, cfg, altitude=0.5 * (z_a + z_b))
        assert_rates_match(links, expected, len(DISTANCES))
        expected_by_alt[(z_a, z_b)] = expected
    # higher K (higher altitude) helps at short range and hurts at long range (less deep fading, fewer lucky peaks)
    low, high = expected_by_alt[(5.0, 5.0)], expected_by_alt[(20.0, 20.0)]
    assert not np.allclose(low, high, atol=1e-3)
    # the slope must change the answer relative to the flat-K model
    flat = link_probability(DISTANCES, cfg.replace(rician_k_altitude_slope=0.0))
    np.testing.assert_allclose(low, flat, rtol=1e-9)  # at min_altitude K is the base K
    assert not np.allclose(high, flat, atol=1e-3)


def test_link_rate_three_agents_collinear() -> None:
    """N = 3 in a line: distances 20, 30 and 50; receivers share their interference draw."""
    cfg = SwarmConfig()
    pos = np.zeros((20_000, 3, 3))
    pos[..., 2] = 10.0
    pos[:, 1, 0] = 20.0
    pos[:, 2, 0] = 50.0
    links = A2AChannel(cfg).sample(pos, np.random.default_rng(4))
    dist = np.array([[0, 20, 50], [20, 0, 30], [50, 30, 0]], dtype=float)
    expected = link_probability(dist, cfg)
    rate = links.mean(axis=0)
    se = np.sqrt(np.maximum(expected * (1 - expected), 1e-4) / pos.shape[0])
    off = ~np.eye(3, dtype=bool)
    assert np.all(np.abs(rate - expected)[off] <= N_SE * se[off]), (rate, expected)
    assert not links[:, np.arange(3), np.arange(3)].any()


# ---------------------------------------------------------------- closed form
def test_link_probability_rayleigh_analytic() -> None:
    """K = 0: E_I[exp(-c (sigma2 + I))] = exp(-c sigma2) (1 - exp(-c I_max)) / (c I_max), checks the quadrature."""
    cfg = SwarmConfig(rician_k=0.0, p_fail=0.2)
    c = cfg.sinr_threshold * DISTANCES**2 / (cfg.tx_power_mw * cfg.atmospheric_loss)
    imax = cfg.interference_max
    exact = 0.8 * np.exp(-c * cfg.noise_power) * (1 - np.exp(-c * imax)) / (c * imax)
    np.testing.assert_allclose(link_probability(DISTANCES, cfg), exact, rtol=1e-10)


def test_link_probability_properties() -> None:
    cfg = SwarmConfig()
    d = np.linspace(0.0, 150.0, 301)
    p = link_probability(d, cfg)
    assert p.shape == d.shape
    assert np.all(np.diff(p) <= 1e-12) and p[0] == pytest.approx(1 - cfg.p_fail, abs=1e-5)
    assert link_probability(np.inf, cfg) == 0.0
    # below min_link_distance the distance is clamped
    assert link_probability(0.0, cfg) == link_probability(cfg.min_link_distance, cfg)
    assert np.ndim(link_probability(10.0, cfg)) == 0
    np.testing.assert_array_equal(link_probability(d[:300].reshape(3, 100), cfg), p[:300].reshape(3, 100))
    assert np.all(link_probability(d, cfg.replace(link_mode="full")) == 1.0)
    assert np.all(link_probability(d, cfg.replace(link_mode="none")) == 0.0)
    assert np.all(link_probability(d, cfg.replace(p_fail=1.0)) == 0.0)


def test_link_probability_bad_inputs() -> None:
    cfg = SwarmConfig()
    with pytest.raises(ValueError, match="distance"):
        link_probability(-1.0, cfg)
    with pytest.raises(ValueError, match="distance"):
        link_probability(np.array([1.0, np.nan]), cfg)
    with pytest.raises(ValueError, match="altitude"):
        link_probability(10.0, cfg.replace(rician_k_altitude_slope=0.5))


# ---------------------------------------------------------------- Rician fading
@pytest.mark.parametrize("k_factor", [0.0, 1.0, 5.0, 20.0])
def test_rician_power_law(k_factor: float) -> None:
    g = sample_rician_power(k_factor, (200_000,), np.random.default_rng(5))
    assert g.mean() == pytest.approx(1.0, abs=5 * g.std() / np.sqrt(g.size))
    # 2 (K+1) |h|^2 ~ ncx2(2, 2K): compare the empirical CDF at a few quantiles
    scale = 2 * (k_factor + 1)
    law = stats.chi2(2) if k_factor == 0 else stats.ncx2(2, 2 * k_factor)
    for q in (0.05, 0.25, 0.5, 0.75, 0.95):
        x = law.ppf(q) / scale
        assert np.mean(g <= x) == pytest.approx(q, abs=5 * np.sqrt(q * (1 - q) / g.size))
    # variance of |h|^2 is (2K + 1) / (K + 1)^2
    assert g.var() == pytest.approx((2 * k_factor + 1) / (k_factor + 1) ** 2, rel=0.03)


def test_rician_power_array_k_and_bad_k() -> None:
    k = np.array([[0.0], [5.0]])
    g = sample_rician_power(k, (2, 100_000), np.random.default_rng(6))
    assert g.shape == (2, 100_000)
    np.testing.assert_allclose(g.var(axis=1), [1.0, 11 / 36], rtol=0.03)
    with pytest.raises(ValueError, match="k_factor"):
        sample_rician_power(-1.0, (3,), np.random.default_rng(0))


def test_draw_uses_rician_sampler() -> None:
    """The fading of ``draw`` (and hence ``sample``) is exactly ``sample_rician_power`` on the same stream."""
    cfg = SwarmConfig()
    pos = np.random.default_rng(7).uniform(0, 50, (4, 3, 3))
    draws = A2AChannel(cfg).draw(pos, np.random.default_rng(8))
    expected = sample_rician_power(cfg.rician_k, (4, 3, 3), np.random.default_rng(8))
    np.testing.assert_array_equal(draws.h_power, expected)
    assert draws.interference.shape == (4, 3) and draws.xi.shape == (4, 3, 3) and draws.xi.dtype == bool
    assert np.all((draws.interference >= 0) & (draws.interference < cfg.interference_max))


# ---------------------------------------------------------------- Eq. (1)
def test_sinr_matches_eq1_by_hand() -> None:
    cfg = SwarmConfig()
    channel = A2AChannel(cfg)
    pos = np.array([[0.0, 0.0, 10.0], [30.0, 40.0, 10.0], [0.0, 0.0, 10.05]])  # d01 = 50, d02 = 0.05 < d_min
    h_power = np.array([[9.0, 0.5, 2.0], [1.5, 9.0, 0.7], [0.3, 1.2, 9.0]])
    interference = np.array([0.1, 0.4, 0.25])
    xi = np.array([[True, True, False], [True, True, True], [True, True, True]])
    gamma = channel.sinr_from_draws(pos, ChannelDraws(h_power, interference, xi))
    p_mw = 100.0  # 20 dBm
    # receiver 0 from sender 1: P / (1 + 0.1) * 0.5 * 50^-2 * 0.9
    assert gamma[0, 1] == pytest.approx(p_mw / 1.1 * 0.5 / 2500.0 * 0.9, rel=1e-12)
    # receiver 1 from sender 0: P / (1 + 0.4) * 1.5 * 50^-2 * 0.9
    assert gamma[1, 0] == pytest.approx(p_mw / 1.4 * 1.5 / 2500.0 * 0.9, rel=1e-12)
    # receiver 2 from sender 0: distance 0.05 m clamped to min_link_distance = 0.1 m
    assert gamma[2, 0] == pytest.approx(p_mw / 1.25 * 0.3 / 0.1**2 * 0.9, rel=1e-12)
    assert gamma[0, 2] == 0.0  # xi = 0: abrupt failure
    assert np.all(np.diag(gamma) == 0.0)
    # with the default constants: 0.5 * 100 / 1.1 * 0.9 / 2500 = 0.0164 < 0.05 (down), 1.5 * ... / 1.4 = 0.0386 (down)
    assert gamma[0, 1] < cfg.sinr_threshold and gamma[1, 0] < cfg.sinr_threshold
    assert gamma[2, 0] > cfg.sinr_threshold


@pytest.mark.parametrize(
    "changes, span", [({}, 60.0), ({"rician_k_altitude_slope": 0.3}, 60.0), ({"path_loss_exponent": 3.0}, 20.0)]
)
def test_sample_is_sinr_threshold(changes: dict, span: float) -> None:
    """Same rng state: ``sample`` == (Eq. (1) SINR >= beta_th) and xi, off the diagonal."""
    cfg = SwarmConfig(**changes)
    channel = A2AChannel(cfg)
    pos = np.random.default_rng(9).uniform(0, span, (5000, 3, 3))
    pos[..., 2] = np.random.default_rng(10).uniform(5, 20, (5000, 3))
    links = channel.sample(pos, np.random.default_rng(11))
    draws = channel.draw(pos, np.random.default_rng(11))
    gamma = channel.sinr_from_draws(pos, draws)
    expected = (gamma >= cfg.sinr_threshold) & draws.xi & ~np.eye(3, dtype=bool)
    # allow disagreement only at the threshold itself (floating point rounding of the rearranged comparison)
    near = np.isclose(gamma, cfg.sinr_threshold, rtol=1e-9)
    assert np.array_equal(links[~near], expected[~near])
    assert 0.05 < links.mean() < 0.6  # both outcomes occur
    np.testing.assert_array_equal(channel.sinr(pos, np.random.default_rng(11)), gamma)


# ---------------------------------------------------------------- modes, shapes, determinism
def test_full_and_none_modes() -> None:
    pos = np.random.default_rng(12).uniform(0, 1000, (7, 4, 3))
    full = A2AChannel(SwarmConfig(link_mode="full"))
    none = A2AChannel(SwarmConfig(link_mode="none"))
    rng = np.random.default_rng(13)
    state = rng.bit_generator.state
    off = ~np.eye(4, dtype=bool)
    np.testing.assert_array_equal(full.sample(pos, rng), np.broadcast_to(off, (7, 4, 4)))
    np.testing.assert_array_equal(full.sample(pos[0], rng), off)
    assert not none.sample(pos, rng).any() and none.sample(pos, rng).shape == (7, 4, 4)
    assert not none.sample(pos[0], rng).any() and none.sample(pos[0], rng).shape == (4, 4)
    assert rng.bit_generator.state == state  # no random draws in these modes
    out = full.sample(pos[0], rng)
    out[0, 1] = False  # the returned matrix is writable and does not alias the cached mask
    np.testing.assert_array_equal(full.sample(pos[0], rng), off)


def test_shapes_dtype_and_diagonal() -> None:
    channel = A2AChannel(SwarmConfig(p_fail=0.0))
    rng = np.random.default_rng(14)
    pos = np.zeros((5, 3))  # all co-located: every off-diagonal link up, never the diagonal
    links = channel.sample(pos, rng)
    assert links.shape == (5, 5) and links.dtype == bool
    np.testing.assert_array_equal(links, ~np.eye(5, dtype=bool))
    batch = channel.sample(np.zeros((6, 3, 3)), rng)
    assert batch.shape == (6, 3, 3) and batch.dtype == bool
    np.testing.assert_array_equal(batch, np.broadcast_to(~np.eye(3, dtype=bool), (6, 3, 3)))
    assert channel.sample(np.zeros((1, 3)), rng).shape == (1, 1)
    assert channel.sample([[0, 0, 5], [10, 0, 5]], rng).shape == (2, 2)  # lists and ints are accepted


def test_same_seed_same_links_and_batch_agrees_with_single() -> None:
    channel = A2AChannel(SwarmConfig())
    pos = np.array([[0.0, 0.0, 10.0], [30.0, 0.0, 10.0], [15.0, 35.0, 12.0]])
    a = channel.sample(pos, np.random.default_rng(15))
    b = channel.sample(pos, np.random.default_rng(15))
    np.testing.assert_array_equal(a, b)
    # a batch of B copies has the same link rates as B sequential single draws
    rng_single, rng_batch = np.random.default_rng(16), np.random.default_rng(17)
    reps = 10_000
    single = np.stack([channel.sample(pos, rng_single) for _ in range(reps)])
    batch = channel.sample(np.broadcast_to(pos, (reps, 3, 3)), rng_batch)
    p = 0.5 * (single.mean(0) + batch.mean(0))
    se = np.sqrt(np.maximum(2 * p * (1 - p), 1e-4) / reps)
    assert np.all(np.abs(single.mean(0) - batch.mean(0)) <= N_SE * se)
    # batch rows are independent draws (not one matrix repeated)
    assert len({row.tobytes() for row in batch[:200]}) > 1


# ---------------------------------------------------------------- sanity
def test_p_fail_one_and_short_distance() -> None:
    rng = np.random.default_rng(18)
    close = np.random.default_rng(19).uniform(0, 1.0, (2000, 3, 3))  # pairs within ~1.7 m
    assert not A2AChannel(SwarmConfig(p_fail=1.0)).sample(close, rng).any()
    links = A2AChannel(SwarmConfig(p_fail=0.0)).sample(close, rng)
    off = ~np.eye(3, dtype=bool)
    assert links[:, off].mean() > 0.999
    assert link_probability(1.7, SwarmConfig(p_fail=0.0)) > 0.999


@pytest.mark.parametrize(
    "bad",
    [np.zeros((3,)), np.zeros((3, 2)), np.zeros((2, 3, 4)), np.zeros((1, 2, 3, 3)), np.array([[0, 0, np.nan], [1, 1, 1]])],
)
def test_bad_positions_raise(bad: np.ndarray) -> None:
    channel = A2AChannel(SwarmConfig())
    with pytest.raises(ValueError, match="positions"):
        channel.sample(bad, np.random.default_rng(0))
    with pytest.raises(ValueError, match="positions"):
        channel.sinr(bad, np.random.default_rng(0))
    with pytest.raises(ValueError, match="positions"):
        A2AChannel(SwarmConfig(link_mode="full")).sample(bad, np.random.default_rng(0))
