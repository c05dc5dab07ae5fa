"""Conditions, trained substitute learners, evaluation and the CLI on an adapted env (``--env``, issue 35)."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sb3_latentswarm.cli import main
from sb3_latentswarm.envs.adapted_env import REGISTERED_ENVS, AdaptedEnv, parse_env_kwargs
from sb3_latentswarm.evaluation import CONDITIONS, EXTRA_CONDITIONS
from sb3_latentswarm.evaluation.adapted import (
    ADAPTED_COLUMNS,
    adapted_episodes,
    evaluate_adapted_conditions,
    summarize_adapted,
)
from sb3_latentswarm.evaluation.conditions import condition_config
from sb3_latentswarm.evaluation.diagnostics import DIAGNOSTIC_COLUMNS
from sb3_latentswarm.presets import get_preset

pytest.importorskip("mpe2.simple_spread_v3", reason="the mpe extra is not installed")

SPREAD_KWARGS = {"N": 3, "max_cycles": 25, "num_agent_neighbors": 1, "num_landmark_neighbors": 1}
SPREAD = AdaptedEnv("mpe2:simple_spread_v3", SPREAD_KWARGS)
LINKS = ["link_model=outage", "outage_model=gilbert_elliott", "p_fail=0.5", "mean_outage_steps=4"]
RENDEZVOUS_MODULE = textwrap.dedent('''
    import numpy as np
    from gymnasium import spaces
    from pettingzoo import ParallelEnv


    class Line(ParallelEnv):
        metadata = {"name": "line_v0", "render_modes": [], "is_parallelizable": True}

        def __init__(self, n_agents=2, max_steps=10):
            self.possible_agents = [f"a{i}" for i in range(n_agents)]
            self.max_steps, self.render_mode, self.rng = max_steps, None, np.random.default_rng()
            self.space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)

        def observation_space(self, agent):
            return self.space

        def action_space(self, agent):
            return self.space

        def reset(self, seed=None, options=None):
            if seed is not None:
                self.rng = np.random.default_rng(seed)
            self.agents, self.t = list(self.possible_agents), 0
            self.x = self.rng.uniform(-1, 1, len(self.agents))
            return self._obs(), {a: {} for a in self.agents}

        def step(self, actions):
            self.x = np.clip(self.x + 0.1 * np.array([actions[a][0] for a in self.agents]), -1, 1)
            self.t += 1
            done, agents = self.t >= self.max_steps, self.agents
            self.agents = [] if done else agents
            r = -float(np.ptp(self.x))
            return (self._obs(), {a: r for a in agents}, {a: False for a in agents}, {a: done for a in agents},
                    {a: {} for a in agents})

        def _obs(self):
            return {a: self.x[i : i + 1].astype(np.float32) for i, a in enumerate(self.possible_agents)}

        def state(self):
            return self.x.astype(np.float32)


    def make_line(**kwargs):
        return Line(**kwargs)
''')


def spread_args(*extra: str) -> list[str]:
    return ["--env", "mpe2:simple_spread_v3", "--env-kwargs", json.dumps(SPREAD_KWARGS), *extra]


@pytest.fixture(scope="module")
def zero_learner():
    """A ``zero_substitute`` learner (zeros in place of the predicted message during dropout) trained a few hundred
    agent-steps on simple_spread with Gilbert-Elliott outages."""
    preset = get_preset("smoke").with_env(SPREAD).with_overrides(
        link_model="outage", outage_model="gilbert_elliott", p_fail=0.5, mean_outage_steps=4, message_substitute="zero"
    )
    env = preset.make_env(0)
    model = preset.make_model(env, seed=0, device="cpu")
    model.learn(240)
    return preset, model


# ---------------------------------------------------------------------------------------------- the env by name
def test_adapted_env_names_kwargs_and_the_file_rule():
    assert "mpe2:simple_spread_v3" in REGISTERED_ENVS and not SPREAD.entry_point
    assert AdaptedEnv("my_pkg.envs:make_env").entry_point
    for bad in ("nosuch", "a:b:c", "pkg.:f", ""):
        with pytest.raises(ValueError, match="--env must be a registered env"):
            AdaptedEnv(bad)
    for text in ("[1]", "{bad json", '"N"'):
        with pytest.raises(ValueError, match="--env-kwargs must be a JSON object"):
            parse_env_kwargs(text)
    # a registered name may come back from a file, an entry point only when the command names it again
    assert AdaptedEnv.from_record(SPREAD.to_dict(), None, "state.json") == SPREAD
    assert AdaptedEnv.from_record({}, None, "state.json") is None
    entry = AdaptedEnv("my_pkg.envs:make_env", {"n": 2})
    with pytest.raises(ValueError, match="never names code to import"):
        AdaptedEnv.from_record(entry.to_dict(), None, "state.json")
    assert AdaptedEnv.from_record(entry.to_dict(), entry, "state.json") == entry
    with pytest.raises(ValueError, match="differs from"):
        AdaptedEnv.from_record(entry.to_dict(), AdaptedEnv("my_pkg.envs:make_env", {"n": 3}), "state.json")


def test_preset_on_an_adapted_env_takes_its_agents_actions_and_bernoulli_links():
    preset = get_preset("demo").with_env(AdaptedEnv("mpe2:simple_spread_v3", {"N": 4}))
    assert preset.config.n_agents == 4 and preset.config.link_model == "outage"
    assert preset.agent_steps_per_update == preset.algo_kwargs["n_steps"] * preset.n_envs * 4
    # MPE2's actions are in [0, 1]: the squashed Gaussian (in [-1, 1]) gives way to the paper's Gaussian
    assert preset.algo_kwargs["policy_kwargs"]["action_distribution"] == "gaussian"
    with pytest.raises(ValueError, match="backend 'supersuit' steps the swarm env only"):
        preset.make_env(0, backend="supersuit")


# ---------------------------------------------------------------------------------------------- conditions
def test_every_condition_runs_on_the_adapted_env_with_its_own_metrics(zero_learner):
    preset, model = zero_learner
    assert model.policy.message_substitute == "zero"
    conditions = CONDITIONS + EXTRA_CONDITIONS
    table = evaluate_adapted_conditions(model, SPREAD, preset.config, conditions, n_episodes=3, seed=1_000_000)
    assert tuple(table.columns[: len(ADAPTED_COLUMNS)]) == ADAPTED_COLUMNS
    assert {"final_landmarks_covered", "sum_collisions"} <= set(table.columns)
    assert list(table["condition"].unique()) == list(conditions) and len(table) == 3 * len(conditions)
    assert (table["length"] == 25).all() and (table["p_fail"] == 0.5).all()
    assert table["final_landmarks_covered"].between(0, 1).all() and (table["sum_collisions"] >= 0).all()
    assert model.policy.message_substitute == "zero" and not model.policy.no_memory  # the switches are restored
    by = table.set_index(["condition", "episode"])["return"]
    # the policy reads the links: forcing them all down or up changes the episodes of the same seeds
    assert not np.allclose(by["no_comm"].to_numpy(), by["full_comm"].to_numpy())
    again = evaluate_adapted_conditions(model, SPREAD, preset.config, ("proposed",), n_episodes=3, seed=1_000_000)
    np.testing.assert_array_equal(again["return"].to_numpy(), by["proposed"].to_numpy())  # seeded
    summary = summarize_adapted(table)
    assert list(summary["condition"]) == list(conditions) and "±" in summary.loc[0, "return"]
    assert list(summary.columns[:3]) == ["condition", "episodes", "return"] and "seed" not in summary.columns
    with pytest.raises(ValueError, match="allowed conditions"):
        evaluate_adapted_conditions(model, SPREAD, preset.config, ("nope",))


def test_adapted_conditions_report_the_message_diagnostics_without_changing_the_episodes(zero_learner):
    preset, model = zero_learner
    conditions = ("proposed", "full_comm", "no_comm", "no_predictor")
    table = evaluate_adapted_conditions(model, SPREAD, preset.config, conditions, n_episodes=3, seed=1_000_000)
    by = table.set_index("condition")
    assert {"map_error", "pred_error_dropout", *DIAGNOSTIC_COLUMNS} <= set(table.columns)
    assert (table["map_error"] >= 0).all() and np.isfinite(table["map_error"]).all()
    # every link up: never in dropout, so no substitute error; every link down: always in dropout, one run per agent
    assert (by.loc["full_comm", "dropout_share"] == 0).all() and by.loc["full_comm", "pred_error_dropout"].isna().all()
    assert (by.loc["no_comm", "dropout_share"] == 1).all() and (by.loc["no_comm", "dropout_run_mean"] == 25).all()
    assert (by.loc["no_comm", "pred_error_dropout"] >= 0).all()
    assert by.loc["proposed", "dropout_share"].between(0, 1).all()
    # zeros in place of the message (no_predictor on a zero-substitute learner): the error is the sent message's size
    assert (by.loc["no_predictor", "pred_error_dropout"].dropna() > 0).all()
    # the diagnostics step beside predict and draw nothing: the episodes are what predict alone plays
    cell = condition_config(preset.config, "proposed", preset.config.p_fail)
    alone = adapted_episodes(model, lambda copies, first: SPREAD.make_vec_env(copies, cell, first, monitor=False), 3,
                             seed=1_000_000, n_envs=3)
    np.testing.assert_array_equal(by.loc["proposed", "return"].to_numpy(), [episode["return"] for episode in alone])


# ---------------------------------------------------------------------------------------------- the CLI
def test_cli_train_evaluate_on_simple_spread_writes_a_model_and_the_env_metrics(tmp_path):
    out = tmp_path / "run"
    argv = ["train", "--preset", "smoke", *spread_args(), "--set", *LINKS, "eval_episodes=3",
            "--total-timesteps", "240", "--output", str(out), "--evaluate", "--no-progress"]
    assert main(argv) == 0
    assert (out / "model.zip").is_file()
    table = pd.read_csv(out / "conditions.csv")
    assert list(table["condition"].unique()) == list(CONDITIONS)
    assert {"return", "final_landmarks_covered", "sum_collisions"} <= set(table.columns)
    record = json.loads((out / "evaluation.json").read_text())
    assert record["env"] == SPREAD.to_dict() and record["config"]["link_model"] == "outage"
    # evaluate: the model file does not name its env, so --env is needed again
    with pytest.raises(SystemExit):
        main(["evaluate", "--model", str(out / "model.zip"), "--no-baselines"])
    # without --preset, the link model is the run's (its config.json); --set changes it
    evaluation = tmp_path / "evaluation"
    argv = ["evaluate", "--model", str(out / "model.zip"), *spread_args(), "--episodes", "2", "--output", str(evaluation)]
    assert main(argv) == 0
    assert len(pd.read_csv(evaluation / "conditions.csv")) == 2 * len(CONDITIONS)
    config = json.loads((evaluation / "evaluation.json").read_text())["config"]
    assert (config["outage_model"], config["p_fail"], config["mean_outage_steps"]) == ("gilbert_elliott", 0.5, 4)
    argv = [*argv[:-1], str(tmp_path / "bernoulli"), "--set", "outage_model=bernoulli", "p_fail=0.2"]
    assert main(argv) == 0
    config = json.loads((tmp_path / "bernoulli" / "evaluation.json").read_text())["config"]
    assert (config["link_model"], config["outage_model"], config["p_fail"]) == ("outage", "bernoulli", 0.2)


def test_render_draws_an_adapted_episode_in_the_envs_own_frames(zero_learner, tmp_path, monkeypatch):
    from PIL import Image

    from sb3_latentswarm.rendering import render_adapted_episode

    preset, model = zero_learner
    paths = [render_adapted_episode(model, SPREAD, preset.config, tmp_path / f"{k}.gif", seed=3, deterministic=False)
             for k in range(2)]
    assert paths[0].read_bytes() == paths[1].read_bytes()  # seeded: the same call gives the same file
    with Image.open(paths[0]) as gif:
        assert gif.n_frames == 25  # one frame per step of the 25-step episode
    # the command line: random actions without --model; --env with a model of the swarm env is refused
    assert main(["render", *spread_args(), "--output", str(tmp_path / "random.gif"), "--seed", "1"]) == 0
    assert (tmp_path / "random.gif").stat().st_size > 0
    swarm_model = Path(__file__).parent / "data" / "models" / "coordination-proposed-seed0.zip"
    with pytest.raises(SystemExit):
        main(["render", "--model", str(swarm_model), *spread_args(), "--output", str(tmp_path / "swarm.gif")])
    assert not (tmp_path / "swarm.gif").exists()
    # an env factory without render_mode gives no frames: a clear error, nothing written
    (tmp_path / "line_env.py").write_text(RENDEZVOUS_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ValueError, match="must accept render_mode='rgb_array'"):
        render_adapted_episode(None, AdaptedEnv("line_env:make_line", {"n_agents": 2}), preset.config,
                               tmp_path / "line.gif")
    assert not (tmp_path / "line.gif").exists()


def test_cli_trains_a_substitute_learner_and_resumes_an_entry_point_only_when_named(tmp_path, monkeypatch, capsys):
    (tmp_path / "line_env.py").write_text(RENDEZVOUS_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "run"
    entry = ["--env", "line_env:make_line", "--env-kwargs", '{"n_agents": 2}']
    base = ["train", "--preset", "smoke", "--set", "message_substitute=hold_last", "--no-progress", "--output", str(out)]
    assert main([*base, *entry, "--total-timesteps", "80"]) == 0
    state = json.loads((out / "config.json").read_text())
    assert state["n_agents"] == 2
    capsys.readouterr()
    with pytest.raises(SystemExit):  # the checkpoint names an entry point: not imported unless --env names it
        main(["train", "--resume", "--output", str(out), "--total-timesteps", "160", "--no-progress"])
    assert "never names code to import" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train", "--resume", "--output", str(out), "--total-timesteps", "160", "--no-progress", "--env",
              "line_env:make_line", "--env-kwargs", '{"n_agents": 3}'])
    assert "was started with other settings: env_kwargs" in capsys.readouterr().err
    assert main(["train", "--resume", "--output", str(out), "--total-timesteps", "160", "--no-progress", *entry]) == 0


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--env", "nosuch"], "--env must be a registered env"),
        (["--env", "mpe2:simple_spread_v3", "--env-kwargs", "[3]"], "--env-kwargs must be a JSON object"),
        (["--env-kwargs", "{}"], "--env-kwargs needs --env"),
        (["--env", "no_such_module_here:make"], "cannot import no_such_module_here"),
        (["--env", "mpe2:simple_spread_v3", "--env-kwargs", '{"bogus": 1}'], "unexpected keyword argument 'bogus'"),
        (["--env", "mpe2:simple_spread_v3", "--backend", "supersuit"], "--backend supersuit steps the swarm env only"),
        (["--env", "mpe2:simple_spread_v3", "--env-kwargs", '{"continuous_actions": false}'], "continuous_actions=True"),
    ],
)
def test_bad_env_flags_are_refused_before_any_file_is_written(tmp_path, capsys, extra, message):
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--preset", "smoke", "--output", str(out), "--no-progress", *extra])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------------------------------------- sweep
def adapted_spec(variants=("zero_substitute",)):
    from sb3_latentswarm.experiments import SweepSpec

    return SweepSpec.create("smoke", 1, variants=variants, overrides={"link_model": "outage", "p_fail": 0.5},
                            eval_episodes=2, total_timesteps=120, env=SPREAD)


@pytest.mark.slow  # about 20 s: matplotlib's import and the report's figures
def test_a_sweep_trial_on_the_adapted_env_trains_evaluates_and_reports_its_metrics(tmp_path):
    """The sweep's trial and report path (what each Ray Tune trial runs), without starting Ray."""
    from sb3_latentswarm.experiments import SweepSpec
    from sb3_latentswarm.experiments.report import write_report
    from sb3_latentswarm.experiments.sweep import plan_trials
    from sb3_latentswarm.experiments.trial import train_and_evaluate

    spec = adapted_spec()
    assert spec.point_preset({}).env == SPREAD and spec.point_preset({}).config.n_agents == 3
    spec.save(tmp_path / "sweep.json")
    assert SweepSpec.load(tmp_path / "sweep.json") == spec  # the env round-trips through sweep.json
    reports = []
    for trial in plan_trials(spec, commit="test"):
        record = train_and_evaluate(trial, tmp_path / "trials" / trial["trial_id"], report=reports.append)
        assert record["env"] == SPREAD.to_dict() and record["eval_coverage"] is None
    # Ray's status table gets the adapted env's progress only: no NaN coverage or collisions columns
    assert reports and all(set(r) == {"agent_steps", "episode_reward"} for r in reports)
    episodes = pd.read_csv(tmp_path / "trials" / "zero_substitute-seed0" / "episodes.csv")
    assert {"return", "final_landmarks_covered", "sum_collisions"} <= set(episodes.columns)
    # outage links have no range: full_comm_in_range would repeat full_comm, so table1 leaves it out
    table1 = set(episodes.query("eval_set == 'table1'")["condition"])
    assert "full_comm" in table1 and "full_comm_in_range" not in table1
    assert sorted(episodes["seed"].unique()) == [1_000_000, 1_000_001]
    aggregate = write_report(tmp_path)
    assert {"return", "final_landmarks_covered", "sum_collisions"} <= set(aggregate["metric"])
    assert set(aggregate["variant"]) == {"zero_substitute"}
    assert "on the adapted env mpe2:simple_spread_v3" in (tmp_path / "run.md").read_text()


def test_a_sweep_spec_never_imports_an_entry_point_read_from_sweep_json(tmp_path):
    from sb3_latentswarm.experiments import SweepSpec

    (tmp_path / "sweep.json").write_text(json.dumps({**adapted_spec().to_dict(), "env": "line_env:make_line",
                                                     "env_kwargs": {}}))
    loaded = SweepSpec.load(tmp_path / "sweep.json")
    assert loaded.env is not None and loaded.env.entry_point and not loaded.env.named_by_user
    with pytest.raises(ValueError, match="never names code to import"):
        loaded.point_preset({})
    with pytest.raises(ValueError, match="independent RecurrentPPO baseline is evaluated on the swarm env only"):
        adapted_spec(variants=("proposed", "independent"))


@pytest.mark.slow
def test_sweep_command_on_simple_spread(tmp_path):
    output = tmp_path / "sweep"
    argv = ["sweep", "--preset", "smoke", "--seeds", "1", "--variant", "proposed", "hold_last", *spread_args(),
            "--set", *LINKS, "--total-timesteps", "120", "--eval-episodes", "2", "--output", str(output), "--verbose", "0"]
    assert main(argv) == 0
    scores = pd.read_csv(output / "scores.csv")
    assert set(scores["variant"]) == {"proposed", "hold_last"}
    assert {"return", "final_landmarks_covered", "sum_collisions"} <= set(scores.columns)
    assert json.loads((output / "sweep.json").read_text())["env"] == "mpe2:simple_spread_v3"


@pytest.mark.slow  # two training processes
def test_train_seeds_on_simple_spread_passes_the_env_to_every_seed(tmp_path):
    out = tmp_path / "seeds"
    argv = ["train", "--preset", "smoke", *spread_args(), "--seeds", "2", "--jobs", "1", "--total-timesteps", "120",
            "--output", str(out), "--no-progress"]
    assert main(argv) == 0
    for seed in (0, 1):
        assert (out / f"seed{seed}" / "model.zip").is_file()
    record = json.loads((out / "seeds.json").read_text())
    assert record["settings"]["env"] == "mpe2:simple_spread_v3" and record["settings"]["env_kwargs"] == SPREAD_KWARGS
