"""Dropout diagnostics of evaluate (dropout share, run lengths, substitute error by dropout depth) and the hold_last /
own_message conditions, on hand-built dropout sequences."""

import math

import numpy as np
import pytest
import torch as th

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.evaluation import (
    CONDITION_TABLE,
    DEPTH_COLUMNS,
    DIAGNOSTIC_COLUMNS,
    EPISODE_COLUMNS,
    EXTRA_CONDITIONS,
    evaluate,
    policy_switches,
)
from sb3_latentswarm.evaluation.actors import LatentActor
from sb3_latentswarm.evaluation.diagnostics import EpisodeDiagnostics

CONFIG = SwarmConfig(n_agents=3, grid_width=9, grid_height=9, max_steps=30, num_obstacles=2)
TINY_POLICY = dict(latent_dim=6, predictor_hidden=8, decoder_hidden=8, critic_hidden=8, actor_hidden=8)


@pytest.fixture(scope="module")
def model():
    env = make_vec_env(1, config=CONFIG, seed=0)
    return LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=10, chunk_length=5, batch_size=30, policy_kwargs=TINY_POLICY,
                          seed=0)


def test_diagnostics_match_a_hand_computed_case():
    # one episode, two agents (slots 0, 1), 20 steps; agent 0: dropout at steps 1-3 and 5-19 (runs of 3 and 15),
    # agent 1: dropout at step 0 only (a run of 1); substitute errors: depth d of agent 0 has error d, agent 1's 100
    dropout = np.zeros((20, 2), dtype=bool)
    dropout[1:4, 0] = dropout[5:20, 0] = True
    dropout[0, 1] = True
    diagnostics = EpisodeDiagnostics(n_episodes=1, n_slots=2)
    depth = [0, 0]
    for t in range(20):
        errors = np.full(2, math.nan)
        for i in range(2):
            depth[i] = depth[i] + 1 if dropout[t, i] else 0
            if dropout[t, i]:
                errors[i] = 100.0 if i == 1 else float(depth[i])
        diagnostics.record(np.zeros(2, dtype=int), np.full(2, t == 0), dropout[t], np.full(2, 0.5), errors)
    row = diagnostics.row(0)
    assert row["dropout_share"] == 19 / 40  # 3 + 15 + 1 dropout agent-steps of 40
    assert row["dropout_run_mean"] == 19 / 3  # runs of 3, 15 and 1 steps
    assert row["map_error"] == 0.5
    # depth 1: agent 0's errors 1, 1 and agent 1's 100; depths 2-5: 2, 3 (first run), 2, 3, 4, 5 (second run)
    assert row["pred_error_depth_1"] == (1 + 1 + 100) / 3
    assert row["pred_error_depth_2_5"] == (2 + 3 + 2 + 3 + 4 + 5) / 6
    assert row["pred_error_depth_6_15"] == np.mean(np.arange(6, 16))
    assert math.isnan(row["pred_error_depth_16_plus"])  # no run reached 16 steps
    all_errors = [1, 2, 3, *range(1, 16), 100]
    assert row["pred_error_dropout"] == pytest.approx(np.mean(all_errors), rel=1e-15)


def test_depth_resets_at_an_episode_start_and_idle_slots_are_not_counted():
    diagnostics = EpisodeDiagnostics(n_episodes=2, n_slots=1)
    for t in range(17):  # episode 0: 17 dropout steps, the last at depth 17
        diagnostics.record(np.array([0]), np.array([t == 0]), np.array([True]), None, np.array([1.0]))
    diagnostics.record(np.array([-1]), np.array([False]), np.array([True]), None, np.array([9.0]))  # idle
    diagnostics.record(np.array([1]), np.array([True]), np.array([True]), None, np.array([2.0]))  # a new episode
    first, second = diagnostics.row(0), diagnostics.row(1)
    assert first["pred_error_depth_16_plus"] == 1.0 and first["dropout_run_mean"] == 17.0
    assert second["pred_error_depth_1"] == 2.0 and second["dropout_share"] == 1.0
    assert math.isnan(second["pred_error_depth_16_plus"])
    assert math.isnan(first["map_error"])  # no latent policy: no map error


def _hand_built_steps(policy, condition):
    """Five steps of one 3-UAV swarm through the evaluation actor; links [i, j] = receiver i got sender j. Step 0
    starts the episode (every z_{-1} is zero); at step 1 UAVs 0 and 1 hear everyone, UAV 2 nobody; steps 2 and 3 are
    dropouts for all; step 4 has every link up."""
    up = np.ones((3, 3), dtype=np.float32) - np.eye(3, dtype=np.float32)
    heard = up.copy()
    heard[2] = 0.0
    links = [up, heard, np.zeros((3, 3), np.float32), np.zeros((3, 3), np.float32), up]
    rng = np.random.default_rng(0)
    rows = []
    with policy_switches(policy, condition):
        actor = LatentActor(policy, 3, 3)
        for t, link_rows in enumerate(links):
            obs = {
                "local_obs": rng.integers(-1, 2, (3, policy.local_obs_dim)).astype(np.int8),
                "proprio": rng.random((3, policy.proprio_dim)).astype(np.float32),
                "link_row": link_rows,
                "global_map": rng.integers(-1, 2, (1, *policy.map_shape)).astype(np.int8),
            }
            before = actor.state
            _, _, pred_error = actor.act(obs, np.full(3, float(t == 0), dtype=np.float32), None)
            rows.append((before, actor.state, link_rows, pred_error))
    return rows


@pytest.mark.parametrize("condition", ["hold_last", "own_message"])
def test_hold_last_and_own_message_are_exact_on_a_hand_built_dropout_sequence(model, condition):
    policy = model.policy
    steps = _hand_built_steps(policy, condition)
    assert policy.message_substitute == "predicted"  # restored after the condition
    held = th.zeros(3, policy.message_dim)  # the last message each UAV actually received
    for t, (before, after, link_rows, pred_error) in enumerate(steps):
        keep = 0.0 if t == 0 else 1.0
        sent = th.cat([before.map_state, before.task_state], dim=-1) * keep  # z_{t-1}^j
        links = th.as_tensor(link_rows)
        n_in = links.sum(-1, keepdim=True)
        received = links @ sent / n_in.clamp(min=1.0)
        has_message = n_in.squeeze(-1) > 0
        substitute = held if condition == "hold_last" else sent
        expected = th.where(has_message.unsqueeze(-1), received, substitute)
        assert th.equal(after.prev_message, expected), t  # mbar_t: exactly the condition's substitute in dropout
        full = (sent.sum(0, keepdim=True) - sent) / 2.0
        error = ((substitute - full) ** 2).mean(-1).numpy().astype(np.float64)
        np.testing.assert_array_equal(pred_error, np.where(has_message.numpy(), np.nan, error))
        held = th.where(has_message.unsqueeze(-1), received, held)
    # steps 2 and 3 are dropouts for all: hold_last holds step 1's messages (UAV 2: zero, it never heard anything)
    if condition == "hold_last":
        for t in (2, 3):
            mbar = steps[t][1].prev_message
            assert th.all(mbar[2] == 0) and th.equal(mbar[0], steps[1][1].prev_message[0]) and not th.all(mbar[0] == 0)


def test_new_conditions_and_columns_in_evaluate(model):
    assert {"hold_last", "own_message"} <= set(EXTRA_CONDITIONS)
    assert CONDITION_TABLE["hold_last"].message_substitute == "hold_last" and CONDITION_TABLE["hold_last"].switches_policy
    assert CONDITION_TABLE["no_predictor"].message_substitute == "zero"
    assert CONDITION_TABLE["proposed"].message_substitute is None  # the policy's own substitute
    assert list(EPISODE_COLUMNS[-len(DIAGNOSTIC_COLUMNS):]) == list(DIAGNOSTIC_COLUMNS)
    for condition in ("hold_last", "own_message", "no_comm"):
        df = evaluate(model, condition, n_episodes=2, seed=5)
        assert list(df.columns) == list(EPISODE_COLUMNS)
        assert np.allclose(df["dropout_share"], df["dropout_rate"], atol=0.1)  # the actor's steps vs all link draws
        assert (df["dropout_run_mean"] >= 1).all()
    assert (df["dropout_share"] == 1.0).all() and (df["dropout_run_mean"] == df["episode_length"]).all()  # no_comm
    # every no_comm step of an episode is in one run: the depths 1 .. T fill every bin a 30-step episode reaches
    assert df[list(DEPTH_COLUMNS)].notna().all().all()


def test_every_condition_is_accepted_by_the_callback_and_the_sweep():
    from sb3_latentswarm.callbacks import SwarmEvalCallback
    from sb3_latentswarm.experiments.trial import all_conditions, conditions_for

    for condition in CONDITION_TABLE:
        assert SwarmEvalCallback(eval_freq=10, condition=condition).condition == condition
    assert set(all_conditions()) == set(CONDITION_TABLE)
    # the independent learner has no substitute or memory to switch: only the link conditions remain
    assert conditions_for("independent", list(CONDITION_TABLE)) == ["proposed", "full_comm", "no_comm", "full_comm_in_range"]
    with pytest.raises(ValueError, match="allowed conditions"):
        SwarmEvalCallback(eval_freq=10, condition="hold_first")
