"""The evaluation harness: the five conditions of Sec. IV, the per-episode metrics, Table I's format."""

import math

import numpy as np
import pandas as pd
import pytest
import torch as th

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env
from sb3_latentswarm.evaluation import (
    CONDITIONS,
    EPISODE_COLUMNS,
    PAPER_P_FAILS,
    PAPER_TABLE1_CONDITIONS,
    PAPER_TABLE1_P_FAIL,
    evaluate,
    evaluate_conditions,
    evaluate_p_fail_sweep,
    policy_switches,
    side_by_side,
    summarize,
    to_markdown,
)

SMALL = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=40, num_obstacles=5)
TINY_POLICY = dict(latent_dim=16, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)


@pytest.fixture(scope="module")
def model():
    env = make_vec_env(1, config=SMALL, seed=0)
    return LatentSwarmPPO(
        "LatentSwarmPolicy", env, n_steps=10, chunk_length=5, batch_size=30, policy_kwargs=TINY_POLICY, seed=0, device="cpu"
    )


@pytest.fixture(scope="module")
def conditions_df(model):
    return evaluate_conditions(model, n_episodes=3, seed=0)


def check_well_formed(df: pd.DataFrame, n_rows: int, config: SwarmConfig = SMALL) -> None:
    assert list(df.columns) == list(EPISODE_COLUMNS)
    assert len(df) == n_rows
    assert df["coverage"].between(0.0, 100.0).all()
    assert (df["coverage"] > 0).all()  # the first footprint is sensed at reset
    assert (df["collisions"] >= 0).all() and df["collisions"].dtype.kind == "i"
    assert df["episode_length"].between(1, config.max_steps).all()
    reached = df["steps_to_90"].dropna()
    assert (reached >= 0).all() and (reached <= df.loc[reached.index, "episode_length"]).all()
    assert df["link_up_rate"].between(0.0, 1.0).all() and df["dropout_rate"].between(0.0, 1.0).all()
    assert np.isfinite(df["map_error"]).all() and (df["map_error"] >= 0).all()
    assert np.isfinite(df["episode_return"]).all()


# ---------------------------------------------------------------------------------------------- conditions
def test_all_conditions_are_well_formed(conditions_df):
    check_well_formed(conditions_df, 3 * len(CONDITIONS))
    assert conditions_df["condition"].tolist() == [c for c in CONDITIONS for _ in range(3)]
    assert conditions_df["episode"].tolist() == [0, 1, 2] * len(CONDITIONS)
    assert conditions_df["seed"].tolist() == [0, 1, 2] * len(CONDITIONS)
    assert (conditions_df["p_fail"] == 0.3).all()


def test_forced_links(conditions_df):
    by = conditions_df.set_index("condition")
    assert (by.loc["full_comm", "link_up_rate"] == 1.0).all() and (by.loc["full_comm", "dropout_rate"] == 0.0).all()
    assert (by.loc["no_comm", "link_up_rate"] == 0.0).all() and (by.loc["no_comm", "dropout_rate"] == 1.0).all()
    assert by.loc["full_comm", "pred_error_dropout"].isna().all()
    assert np.isfinite(by.loc["no_comm", "pred_error_dropout"]).all()
    # the channel conditions really draw links: some up, some down
    assert by.loc["proposed", "link_up_rate"].between(0.01, 0.99).all()


def test_p_fail_sweep(model):
    df = evaluate_p_fail_sweep(model, n_episodes=2, seed=0)
    check_well_formed(df, 2 * len(PAPER_P_FAILS))
    assert df["p_fail"].tolist() == [p for p in PAPER_P_FAILS for _ in range(2)]
    assert (df["condition"] == "proposed").all()
    up = df.groupby("p_fail")["link_up_rate"].mean()
    # xi ~ Bernoulli(1 - p_f) multiplies the channel's own success rate (about 1 on a 10 m arena)
    assert up[0.0] > 0.9 and up[0.5] < 0.65, up


def test_switches_take_effect_and_are_restored(model, conditions_df):
    policy = model.policy
    assert policy.no_predictor is False and policy.no_memory is False
    by = conditions_df.set_index("condition")
    # same seeds, same links: only the substitute message differs
    proposed, no_predictor, no_memory = (
        by.loc[c, "pred_error_dropout"].to_numpy() for c in ("proposed", "no_predictor", "no_memory")
    )
    assert not np.allclose(proposed, no_predictor) and not np.allclose(proposed, no_memory)

    policy.no_predictor, policy.no_memory = True, True
    try:
        evaluate(model, "proposed", n_episodes=1)
        assert policy.no_predictor is True and policy.no_memory is True
        policy.train()
        with pytest.raises(RuntimeError, match="boom"), policy_switches(policy, "no_predictor"):
            assert policy.no_predictor is True and policy.no_memory is False and not policy.training
            raise RuntimeError("boom")
        assert policy.no_predictor is True and policy.no_memory is True and policy.training
    finally:
        policy.no_predictor, policy.no_memory = False, False
        policy.set_training_mode(False)


def test_seeds_make_rows_reproducible(model):
    first = evaluate(model, "proposed", n_episodes=3, seed=7, deterministic=False)
    again = evaluate(model, "proposed", n_episodes=3, seed=7, deterministic=False)
    pd.testing.assert_frame_equal(first, again)
    other = evaluate(model, "proposed", n_episodes=3, seed=8, deterministic=False)
    assert not first.drop(columns=["episode", "seed"]).equals(other.drop(columns=["episode", "seed"]))
    # row k depends on seed + k only: not on the other episodes, nor on how many copies run in lockstep
    shifted = evaluate(model, "proposed", n_episodes=2, seed=8, deterministic=False, n_envs=1)
    metrics = ["coverage", "collisions", "episode_length", "link_up_rate", "map_error", "pred_error_dropout"]
    pd.testing.assert_frame_equal(
        first.loc[1:, metrics].reset_index(drop=True), shifted[metrics], check_exact=False, rtol=1e-4
    )
    deterministic = evaluate(model, "proposed", n_episodes=3, seed=7)
    assert not deterministic["map_error"].equals(first["map_error"])


def test_diagnostics_match_the_policy_step_by_step(model):
    """map_error and pred_error_dropout recomputed from the policy's own predict(), one env, no lockstep.

    The evaluated episode is the second one run in its env copy, so the state must have been reset in between.
    """
    policy = model.policy
    df = evaluate(model, "no_comm", n_episodes=2, seed=2, n_envs=1).set_index("seed")
    env = SwarmReconEnv(SMALL.replace(link_mode="none"))
    obs, _ = env.reset(seed=3)
    state, start = None, np.ones(SMALL.n_agents)
    map_errors, pred_errors = [], []
    n = SMALL.n_agents
    for _ in range(SMALL.max_steps):
        sent = np.zeros((n, policy.message_dim)) if state is None else np.concatenate([state[0], state[1]], -1)
        actions, state = policy.predict(obs, state, start, deterministic=True)
        start = np.zeros(n)
        with th.no_grad():
            decoded = policy.decode_map(th.as_tensor(state.map_state)).numpy()
        target = env.global_map.reshape(1, -1).astype(np.float64)
        map_errors.append(((decoded - target) ** 2).mean(-1))
        full_message = (sent.sum(0, keepdims=True) - sent) / (n - 1)
        # no_comm: every step is a dropout, so the best available message (kept in the state) is mhat_t
        pred_errors.append(((state.prev_message - full_message) ** 2).mean(-1))
        obs, _, terminations, truncations, _ = env.step(actions)
        if any(terminations.values()) or any(truncations.values()):
            break
    assert df.loc[3, "episode_length"] == env.swarm_summary()["length"]
    assert df.loc[3, "coverage"] == pytest.approx(100.0 * env.coverage)
    assert df.loc[3, "map_error"] == pytest.approx(float(np.mean(map_errors)), rel=1e-4)
    assert df.loc[3, "pred_error_dropout"] == pytest.approx(float(np.mean(pred_errors)), rel=1e-4)


def test_coverage_curves(model):
    df, curves = evaluate(model, "full_comm", n_episodes=3, seed=1, return_curves=True, deterministic=False)
    assert curves.shape == (3, SMALL.max_steps + 1)
    assert np.isfinite(curves).all() and (np.diff(curves, axis=1) >= 0).all()
    np.testing.assert_allclose(curves[:, -1], df["coverage"])
    assert (curves[:, 0] > 0).all()
    _, by_condition = evaluate_conditions(model, ("no_comm",), n_episodes=2, return_curves=True)
    assert set(by_condition) == {"no_comm"} and by_condition["no_comm"].shape == (2, SMALL.max_steps + 1)


def test_config_defaults_to_the_training_config(model):
    df = evaluate(model, "full_comm", n_episodes=1)
    assert df.loc[0, "episode_length"] <= SMALL.max_steps
    with pytest.raises(ValueError, match="grid"):
        evaluate(model, n_episodes=1, config=SwarmConfig(grid_width=12, grid_height=10, max_steps=5))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(condition="no_links"), "allowed conditions"),
        (dict(p_fail=1.5), "p_fail"),
        (dict(p_fail=-0.1), "p_fail"),
        (dict(n_episodes=0), "n_episodes"),
        (dict(seed=-1), "seed"),
        (dict(n_envs=0), "n_envs"),
    ],
)
def test_bad_arguments(model, kwargs, match):
    with pytest.raises(ValueError, match=match):
        evaluate(model, **kwargs)


def test_bad_conditions_are_rejected_before_running(model):
    with pytest.raises(ValueError, match="allowed conditions"):
        evaluate_conditions(model, ("proposed", "oops"), n_episodes=1)
    with pytest.raises(ValueError, match="p_fail"):
        evaluate_p_fail_sweep(model, (0.1, 2.0), n_episodes=1)


# ---------------------------------------------------------------------------------------------- tables
def hand_made() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "condition": ["a"] * 4 + ["b"] * 3,
            "coverage": [90.0, 92.5, 88.0, 95.0, 70.0, 71.0, 75.5],
            "collisions": [1, 3, 0, 10, 50, 40, 60],
            "steps_to_90": [600.0, 700.0, math.nan, 810.0, math.nan, math.nan, math.nan],
            "map_error": [0.1, 0.2, 0.3, 0.4, math.nan, math.nan, math.nan],
        }
    )


def test_summarize_matches_numpy():
    df = hand_made()
    summary = summarize(df)
    assert summary["condition"].tolist() == ["a", "b"]
    a, b = summary.iloc[0], summary.iloc[1]
    cov = df.loc[df.condition == "a", "coverage"].to_numpy()
    assert a["coverage_mean"] == pytest.approx(np.mean(cov)) and a["coverage_std"] == pytest.approx(np.std(cov, ddof=1))
    steps = np.array([600.0, 700.0, 810.0])
    assert a["steps_to_90_mean"] == pytest.approx(steps.mean()) and a["steps_to_90_std"] == pytest.approx(steps.std(ddof=1))
    assert a["Steps to 90%"] == f"{steps.mean():.2f} ± {steps.std(ddof=1):.2f} (3/4)"
    assert a["Coverage (%)"] == f"{np.mean(cov):.2f} ± {np.std(cov, ddof=1):.2f}"
    assert a["n_runs"] == 4 and a["n_reached"] == 3
    assert a["map_error_mean"] == pytest.approx(0.25)
    coll = np.array([50, 40, 60])
    assert b["Collisions"] == f"{coll.mean():.2f} ± {coll.std(ddof=1):.2f}"
    assert b["Steps to 90%"] == "N/A" and b["n_reached"] == 0 and math.isnan(b["steps_to_90_mean"])
    assert math.isnan(b["map_error_mean"])
    population = summarize(df, ddof=0)
    assert population.iloc[0]["coverage_std"] == pytest.approx(np.std(cov))


def test_summarize_single_run_and_several_keys():
    df = hand_made().iloc[[0, 4]].assign(p_fail=[0.3, 0.3])
    summary = summarize(df, by=["condition", "p_fail"])
    assert list(summary.columns[:2]) == ["condition", "p_fail"]
    assert summary.iloc[0]["Steps to 90%"] == "600.00 (1/1)"  # the std of one run is undefined: left out
    assert summary.iloc[0]["Coverage (%)"] == "90.00"
    with pytest.raises(ValueError, match="collisions"):
        summarize(df.drop(columns=["collisions"]))


def test_paper_tables():
    table = PAPER_TABLE1_CONDITIONS.set_index("condition")
    assert set(table.index) == set(CONDITIONS)
    assert table.loc["proposed", "Coverage (%)"] == "90.98 ± 2.92"
    assert table.loc["proposed", "Steps to 90%"] == "692.71 ± 189.04"
    assert table.loc["full_comm", "collisions_mean"] == 10.30 and table.loc["no_predictor", "collisions_std"] == 26.12
    assert (table.loc[["no_memory", "no_comm", "no_predictor"], "Steps to 90%"] == "N/A").all()
    sweep = PAPER_TABLE1_P_FAIL.set_index("p_fail")
    assert tuple(sweep.index) == PAPER_P_FAILS
    assert sweep["steps_to_90_mean"].tolist() == [665, 593, 758, 651, 677]
    assert sweep.loc[0.05, "Coverage (%)"] == "92.59 ± 2.04"


def test_side_by_side_and_markdown():
    summary = summarize(hand_made().replace({"condition": {"a": "proposed", "b": "not_in_paper"}}))
    table = side_by_side(summary)
    assert table["Coverage (%) (paper)"].tolist() == ["90.98 ± 2.92", "-"]
    text = to_markdown(table)
    lines = text.splitlines()
    assert len(lines) == 2 + len(table)
    assert lines[0].startswith("| condition") and set(lines[1]) <= {"|", "-"}
    assert all(line.count("|") == table.shape[1] + 1 for line in lines)
    sweep = summarize(hand_made().assign(p_fail=[0.05] * 4 + [0.5] * 3), by="p_fail")
    assert side_by_side(sweep)["Steps to 90% (paper)"].tolist() == ["593", "677"]
    default = to_markdown(summary).splitlines()[0]
    assert [c.strip() for c in default.split("|")[1:-1]] == ["condition", "Coverage (%)", "Collisions", "Steps to 90%"]
    assert "coverage_mean" in to_markdown(summary, columns=list(summary.columns))
    numbers = to_markdown(pd.DataFrame({"x": [1.23456, math.nan], "y": ["a|b", "c"]}), decimals=1)
    assert "| 1.2 " in numbers and "N/A" in numbers and "a\\|b" in numbers


@pytest.mark.parametrize("n_agents", [1, 5])
def test_other_swarm_sizes(model, n_agents):
    df = evaluate(model, "no_comm", n_episodes=2, config=SMALL.replace(n_agents=n_agents))
    check_well_formed(df, 2)
    assert df["pred_error_dropout"].isna().all() if n_agents == 1 else np.isfinite(df["pred_error_dropout"]).all()


def test_the_configs_p_fail_is_honoured_unless_p_fail_is_given():
    from sb3_latentswarm.baselines import RandomPlanner

    config = SMALL.replace(p_fail=0.9)
    planner = RandomPlanner(config, seed=0)
    assert (evaluate(planner, config=config, n_episodes=1)["p_fail"] == 0.9).all()
    assert (evaluate_conditions(planner, ["proposed"], config=config, n_episodes=1)["p_fail"] == 0.9).all()
    assert (evaluate(planner, p_fail=0.1, config=config, n_episodes=1)["p_fail"] == 0.1).all()


def test_long_evaluations_can_show_progress(capsys):
    from sb3_latentswarm.baselines import RandomPlanner

    evaluate(RandomPlanner(SMALL, seed=0), config=SMALL, n_episodes=3, n_envs=2, progress_bar=True)
    err = capsys.readouterr().err
    assert "proposed, p_f=0.3" in err and "3/3" in err


# ---------------------------------------------------------------------------------------------- held-out seeds
def test_default_evaluation_seeds_never_overlap_the_training_seeds(model):
    import inspect

    from sb3_latentswarm.callbacks import SwarmEvalCallback
    from sb3_latentswarm.evaluation import HELD_OUT_SEED, check_held_out
    from sb3_latentswarm.experiments.trial import EVAL_SEED_BASE, training_env_seed
    from sb3_latentswarm.presets import PRESETS, get_preset

    for function in (evaluate, evaluate_conditions, evaluate_p_fail_sweep, SwarmEvalCallback.__init__):
        assert inspect.signature(function).parameters["seed"].default == HELD_OUT_SEED, function
    assert EVAL_SEED_BASE == HELD_OUT_SEED  # the sweep's evaluation seeds
    assert evaluate(model, n_episodes=2)["seed"].tolist() == [HELD_OUT_SEED, HELD_OUT_SEED + 1]
    # training env copy c of a run with seed S uses env seed S + c (CLI: S = --seed; sweep: train_seed * n_envs)
    for name in PRESETS:
        preset = get_preset(name)
        for train_seed in range(100):
            for base in (train_seed, training_env_seed(train_seed, preset.n_envs)):
                check_held_out(HELD_OUT_SEED, preset.eval_episodes, base, preset.n_envs)  # disjoint: no error
                assert base + preset.n_envs <= HELD_OUT_SEED
    with pytest.raises(ValueError, match="overlap the training env copies' seeds"):
        check_held_out(0, 10, 0, 16)  # the old default: episodes 0..9 replay the first episodes of copies 0..9
    with pytest.raises(ValueError, match="overlap"):
        check_held_out(HELD_OUT_SEED, 10, HELD_OUT_SEED - 3, 4)
    check_held_out(16, 10, 0, 16)  # right after the training seeds: disjoint
