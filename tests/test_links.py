"""Tests of the link models (``sb3_latentswarm.links``): closed-form rates, delay and expiry on a hand-built sequence,
the config checks, and the link state through a checkpoint."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_latentswarm.channel import A2AChannel, outage_transition_probabilities
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import SwarmReconEnv
from sb3_latentswarm.envs.vec_env import make_vec_env
from sb3_latentswarm.links import (
    ALL,
    A2ALinks,
    DelayedLinks,
    DistanceLinks,
    FixedLinks,
    LinkModel,
    LinkStep,
    OutageLinks,
    draw_delays,
    make_link_model,
)

N_SE = 5.0  # tolerance in standard errors


def rngs(n: int, seed: int = 0) -> list[np.random.Generator]:
    return [np.random.default_rng([seed, k]) for k in range(n)]


def positions(n_swarms: int, n: int, seed: int = 0) -> np.ndarray:
    pos = np.random.default_rng(seed).uniform(0.0, 50.0, (n_swarms, n, 3))
    pos[..., 2] = 10.0
    return pos


# ---------------------------------------------------------------- the interface
@pytest.mark.parametrize(
    "changes, kind",
    [
        ({}, A2ALinks),
        ({"outage_model": "gilbert_elliott"}, A2ALinks),
        ({"link_model": "outage"}, OutageLinks),
        ({"link_model": "distance"}, DistanceLinks),
        ({"link_mode": "full"}, FixedLinks),
        ({"link_mode": "none"}, FixedLinks),
        ({"link_mode": "full_in_range"}, DistanceLinks),
        ({"message_delay": 2}, DelayedLinks),
        ({"message_delay": 1, "message_delay_model": "geometric", "link_model": "distance"}, DelayedLinks),
    ],
)
def test_every_model_gives_a_boolean_mask_without_self_links(changes, kind):
    config = SwarmConfig(n_agents=4, **changes)
    model = make_link_model(config, n_swarms=3)
    assert isinstance(model, kind) and isinstance(model, LinkModel)
    model.reset(ALL)
    for _ in range(3):
        mask, age = model.step(ALL, rngs(3), positions(3, 4))
        assert mask.shape == (3, 4, 4) and mask.dtype == bool
        assert not mask[:, np.arange(4), np.arange(4)].any()
        assert (age is None) == (config.message_delay == 0)
        if age is not None:
            assert age.shape == (3, 4, 4) and (age[~mask] == 0).all() and (age <= config.message_expiry).all()


def test_the_a2a_model_draws_what_the_channel_draws():
    config = SwarmConfig(n_agents=3)
    pos = positions(2, 3)
    model = make_link_model(config, 2)
    model.reset(ALL)
    mask = model.step(ALL, rngs(2, seed=5), pos).mask
    for k, rng in enumerate(rngs(2, seed=5)):
        np.testing.assert_array_equal(mask[k], A2AChannel(config).sample(pos[k], rng))


# ---------------------------------------------------------------- closed-form rates
def test_bernoulli_delivery_rate_is_one_minus_p_fail():
    config = SwarmConfig(n_agents=5, link_model="outage", p_fail=0.3)
    model = make_link_model(config, 200)
    model.reset(ALL)
    mask = np.stack([model.step(ALL, rngs(200, seed=t), None).mask for t in range(20)])
    off = mask[..., ~np.eye(5, dtype=bool)]  # (20, 200, 20) directed links
    count = off.size
    assert abs(off.mean() - 0.7) <= N_SE * np.sqrt(0.7 * 0.3 / count)
    # independent draws: P(up at t+1 | up at t) is the same 0.7
    after_up = off[1:][off[:-1]]
    assert abs(after_up.mean() - 0.7) <= N_SE * np.sqrt(0.21 / after_up.size)


def failure_runs(up: np.ndarray) -> np.ndarray:
    """Lengths of the completed failure runs of each column of ``up`` (T, L) bool (runs cut by the ends dropped)."""
    lengths = []
    for column in up.T:
        edges = np.flatnonzero(np.diff(column.astype(np.int8)))  # last index before each change
        starts = edges[column[edges] & ~column[edges + 1]] + 1  # up -> down
        ends = edges[~column[edges] & column[edges + 1]] + 1  # down -> up
        ends = ends[ends > starts[0]] if starts.size else ends[:0]
        k = min(starts.size, ends.size)
        lengths.append(ends[:k] - starts[:k])
    return np.concatenate(lengths)


def test_gilbert_elliott_stationary_rate_and_mean_failure_run():
    p_fail, mean_outage = 0.4, 8.0
    config = SwarmConfig(n_agents=6, link_model="outage", outage_model="gilbert_elliott", p_fail=p_fail,
                         mean_outage_steps=mean_outage)
    model = make_link_model(config, 4)
    model.reset(ALL)
    streams = rngs(4, seed=1)
    mask = np.stack([model.step(ALL, streams, None).mask for _ in range(4000)])
    up = mask[..., ~np.eye(6, dtype=bool)].reshape(4000, -1)  # (T, 120 directed links)
    # stationary from the first step (the first draw is Bernoulli(1 - p_f)): the rate is 1 - p_f at every step
    assert abs(up[0].mean() - (1 - p_fail)) <= N_SE * np.sqrt(p_fail * (1 - p_fail) / up.shape[1])
    fail, recover = outage_transition_probabilities(p_fail, mean_outage)
    assert fail / (fail + recover) == pytest.approx(p_fail)
    # the time average: positively correlated steps, so the error is sqrt((1 + rho) / (1 - rho)) larger
    rho = 1.0 - fail - recover
    se = np.sqrt(p_fail * (1 - p_fail) / up.size * (1 + rho) / (1 - rho))
    assert abs(up.mean() - (1 - p_fail)) <= N_SE * se
    runs = failure_runs(up)  # geometric with mean L: std = sqrt(L (L - 1))
    assert abs(runs.mean() - mean_outage) <= N_SE * np.sqrt(mean_outage * (mean_outage - 1) / runs.size)


def test_distance_model_cuts_off_at_its_range():
    config = SwarmConfig(n_agents=2, link_model="distance", link_range=20.0, p_fail=0.5)
    d = np.repeat([19.9, 20.0, 20.1, 35.0], 2000)
    pos = np.zeros((d.size, 2, 3))
    pos[:, 1, 0] = d
    model = make_link_model(config, d.size)
    model.reset(ALL)
    mask = model.step(ALL, rngs(d.size, seed=3), pos).mask
    rate = mask[:, [0, 1], [1, 0]].reshape(4, -1).mean(axis=1)
    assert (rate[2:] == 0.0).all()
    assert np.all(np.abs(rate[:2] - 0.5) <= N_SE * np.sqrt(0.25 / 4000))
    # without failures (Full comm in range) exactly the links within range
    in_range = make_link_model(config.replace(link_mode="full_in_range"), d.size)
    assert in_range.step(ALL, rngs(d.size), pos).mask[:, 0, 1].tolist() == (d <= 20.0).tolist()


# ---------------------------------------------------------------- delay
class ScriptedRng:
    """Hands out the given U(0, 1) values (the delay draws) in order."""

    def __init__(self, values: list[float]) -> None:
        self.values = iter(values)

    def random(self, out: np.ndarray) -> np.ndarray:
        out[...] = next(self.values)
        return out


class ScriptedLinks(LinkModel):
    """Base model whose transmissions ``1 -> 0`` get through at the scripted steps (nothing else)."""

    def __init__(self, sent: list[bool]) -> None:
        super().__init__(1, 2)
        self.sent = iter(sent)

    def step(self, swarms, rngs, positions, distances2=None) -> LinkStep:
        mask = np.zeros((1, 2, 2), dtype=bool)
        mask[0, 0, 1] = next(self.sent)
        return LinkStep(mask, None)


def test_delay_and_expiry_on_a_hand_built_sequence():
    # uniform delays with D = 1: d = floor(3 u) in {0, 1, 2}; expiry 1 loses d = 2
    u_for = {0: 0.1, 1: 0.5, 2: 0.9}
    sent = [True, True, True, True, False, True, False, False]
    delays = [2, 1, 0, 1, 0, 1, 0, 0]  # drawn for every link and step; used only where something is sent
    model = DelayedLinks(ScriptedLinks(sent), mean_delay=1, delay_model="uniform", expiry=1)
    model.reset(ALL)
    rng = ScriptedRng([u_for[d] for d in delays])
    arrived, ages = [], []
    for _ in sent:
        mask, age = model.step(ALL, [rng], None)
        arrived.append(bool(mask[0, 0, 1]))
        ages.append(int(age[0, 0, 1]))
        assert not mask[0, 1, 0] and not mask[0].diagonal().any()
    # t0: d = 2 > expiry, lost. t1: d = 1, arrives at t2 -- where the message sent at t2 with d = 0 also arrives: the
    # fresher one (age 0) is kept. t3: d = 1, arrives at t4 (age 1). t5: d = 1, arrives at t6. t7: nothing.
    assert arrived == [False, False, True, False, True, False, True, False]
    assert ages == [0, 0, 0, 0, 1, 0, 1, 0]


def test_fixed_delay_shifts_the_base_model_and_a_reset_drops_messages_in_flight():
    config = SwarmConfig(n_agents=3, link_model="outage", p_fail=0.5)
    base = make_link_model(config, 2)
    delayed = make_link_model(config.replace(message_delay=2, message_expiry=2), 2)
    base.reset(ALL)
    delayed.reset(ALL)
    a, b = rngs(2, seed=7), rngs(2, seed=7)
    sent = [base.step(ALL, a, None).mask for _ in range(6)]
    got = [delayed.step(ALL, b, None) for _ in range(6)]  # fixed delays draw nothing: the same base draws
    for t in range(6):
        expected = sent[t - 2] if t >= 2 else np.zeros_like(sent[0])
        np.testing.assert_array_equal(got[t].mask, expected)
        assert (got[t].age[got[t].mask] == 2).all()
    delayed.reset(np.array([1]))
    mask = delayed.step(ALL, b, None).mask
    assert not mask[1].any() and (mask[0] == sent[4][0]).all()


def test_delay_draws_have_the_configured_mean():
    u = np.random.default_rng(0).random(200_000)
    assert (draw_delays("fixed", 3, None, (4,)) == 3).all()
    uniform = draw_delays("uniform", 2, u, u.shape)
    assert set(np.unique(uniform).tolist()) == {0, 1, 2, 3, 4} and uniform.mean() == pytest.approx(2.0, abs=0.02)
    geometric = draw_delays("geometric", 2, u, u.shape)
    q = 2 / 3
    assert geometric.mean() == pytest.approx(2.0, abs=0.03)
    assert (geometric >= 3).mean() == pytest.approx(q**3, abs=0.005)


def test_delay_adds_link_age_to_the_observation_only_when_on():
    env = SwarmReconEnv(SwarmConfig(n_agents=3))
    assert "link_age" not in env.observation_space("uav_0").spaces
    env = SwarmReconEnv(SwarmConfig(n_agents=3, message_delay=1, message_delay_model="uniform", message_expiry=2))
    obs, _ = env.reset(seed=0)
    assert env.observation_space("uav_0")["link_age"].shape == (3,)
    for _ in range(10):
        obs, *_ = env.step({agent: np.zeros(4, dtype=np.float32) for agent in env.agents})
        for agent in env.agents:
            assert obs[agent] in env.observation_space(agent)
            assert (obs[agent]["link_age"][obs[agent]["link_row"] == 0] == 0).all()


# ---------------------------------------------------------------- configuration
@pytest.mark.parametrize(
    "changes, message",
    [
        ({"message_delay": -1}, r"SwarmConfig\.message_delay must be an int in \[0, 1000\], got -1"),
        ({"message_expiry": 1001}, r"SwarmConfig\.message_expiry must be an int in \[0, 1000\], got 1001"),
        ({"message_delay": 3, "message_expiry": 2}, r"SwarmConfig\.message_expiry must be an int in \[3, 1000\]"),
        ({"link_range": 0.0}, r"SwarmConfig\.link_range must be a finite number in \(0\.0, 1000000\.0\]"),
        ({"link_model": "disk"}, r"SwarmConfig\.link_model must be one of \('a2a', 'outage', 'distance'\)"),
        ({"message_delay_model": "poisson"}, r"SwarmConfig\.message_delay_model must be one of \('fixed', 'uniform'"),
    ],
)
def test_bad_link_settings_name_the_field_and_the_allowed_range(changes, message):
    with pytest.raises(ValueError, match=message):
        SwarmConfig(**changes)


def test_defaults_are_the_papers_channel_without_delay():
    config = SwarmConfig()
    assert (config.link_model, config.message_delay) == ("a2a", 0)
    assert isinstance(make_link_model(config, 1), A2ALinks)


# ---------------------------------------------------------------- state
def test_link_state_round_trip_and_checks():
    config = SwarmConfig(n_agents=3, outage_model="gilbert_elliott", p_fail=0.5, mean_outage_steps=5.0,
                         message_delay=1, message_delay_model="geometric", message_expiry=3)
    model = make_link_model(config, 2)
    model.reset(ALL)
    pos = positions(2, 3)
    streams = rngs(2, seed=11)
    for _ in range(4):
        model.step(ALL, streams, pos)
    state = model.get_state()
    assert sorted(state) == ["base.xi_state", "in_flight"]
    saved_rngs = [rng.bit_generator.state for rng in streams]
    first = [model.step(ALL, streams, pos) for _ in range(5)]
    model.set_state(state)
    for rng, saved in zip(streams, saved_rngs):
        rng.bit_generator.state = saved
    again = [model.step(ALL, streams, pos) for _ in range(5)]
    for x, y in zip(first, again):
        np.testing.assert_array_equal(x.mask, y.mask)
        np.testing.assert_array_equal(x.age, y.age)
    with pytest.raises(ValueError, match="state has keys"):
        model.set_state({"in_flight": state["in_flight"]})
    with pytest.raises(ValueError, match="must be int16 of shape"):
        model.set_state({**state, "in_flight": state["in_flight"][:1]})


@pytest.mark.parametrize("legacy", [False, True])
def test_a_checkpoint_restores_the_link_state_of_running_episodes(legacy, tmp_path):
    import io
    import zipfile

    from sb3_latentswarm.latent_ppo import LatentSwarmPPO
    from sb3_latentswarm.presets import get_preset
    from sb3_latentswarm.runs.checkpoints import SwarmCheckpointCallback, load_checkpoint

    smoke = get_preset("smoke")
    config = smoke.config.replace(outage_model="gilbert_elliott", p_fail=0.6, mean_outage_steps=6.0,
                                  **({} if legacy else {"message_delay": 1, "message_delay_model": "uniform"}))
    per_update = smoke.algo_kwargs["n_steps"] * smoke.n_envs * config.n_agents
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(smoke.n_envs, config=config, seed=3), seed=3,
                           **smoke.algo_kwargs)
    model.learn(per_update, callback=SwarmCheckpointCallback(per_update, tmp_path, keep=10))
    checkpoint = tmp_path / f"checkpoint_{per_update}_steps.zip"
    if legacy:  # a checkpoint written before the link models kept the Gilbert-Elliott chains as the core's _xi_state
        with zipfile.ZipFile(checkpoint) as archive:
            entries = {name: archive.read(name) for name in archive.namelist()}
        arrays = dict(np.load(io.BytesIO(entries["arrays.npz"])))
        arrays["env.core._xi_state"] = arrays.pop("env.core.link_model.xi_state")
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        entries["arrays.npz"] = buffer.getvalue()
        with zipfile.ZipFile(checkpoint, "w", zipfile.ZIP_STORED) as archive:
            for name, content in entries.items():
                archive.writestr(name, content)
    resumed = load_checkpoint(checkpoint, env=make_vec_env(smoke.n_envs, config=config, seed=99))
    actions = np.random.default_rng(0).uniform(-1, 1, (6, model.env.num_envs, 4)).astype(np.float32)
    for a in actions:  # the running episodes go on identically, link draws included
        first, again = model.env.step(a)[0], resumed.env.step(a)[0]
        assert first.keys() == again.keys() and ("link_age" in first) == (not legacy)
        for key in first:
            np.testing.assert_array_equal(first[key], again[key])


def test_the_policy_trains_on_delayed_links_and_resumes_exactly(tmp_path):
    import torch as th

    from sb3_latentswarm.latent_ppo import LatentSwarmPPO
    from sb3_latentswarm.presets import get_preset
    from sb3_latentswarm.runs.checkpoints import SwarmCheckpointCallback, load_checkpoint

    smoke = get_preset("smoke")
    config = smoke.config.replace(outage_model="gilbert_elliott", p_fail=0.5, mean_outage_steps=5.0, message_delay=2,
                                  message_delay_model="geometric", message_expiry=4)
    per_update = smoke.algo_kwargs["n_steps"] * smoke.n_envs * config.n_agents
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(smoke.n_envs, config=config, seed=3), seed=3,
                           **smoke.algo_kwargs)
    model.learn(3 * per_update, callback=SwarmCheckpointCallback(per_update, tmp_path, keep=10))
    assert "link_age" in model._last_obs
    resumed = load_checkpoint(tmp_path / f"checkpoint_{per_update}_steps.zip",
                              env=make_vec_env(smoke.n_envs, config=config, seed=99))
    resumed.learn(3 * per_update - resumed.num_timesteps, reset_num_timesteps=False)
    for a, b in zip(model.policy.state_dict().values(), resumed.policy.state_dict().values()):
        assert th.equal(a, b)
