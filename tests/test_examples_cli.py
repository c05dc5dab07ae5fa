"""The example scripts and the ``sb3-latentswarm`` command, run end to end with the smoke preset."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch as th

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.cli import main, parse_overrides
from sb3_latentswarm.presets import get_preset
from sb3_latentswarm.rendering import render_episode, run_episode

ROOT = Path(__file__).resolve().parents[1]


def run_script(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_reproduce_table1_help_describes_every_option():
    result = run_script("examples/reproduce_table1.py", "--help")
    assert result.returncode == 0, result.stderr
    options = result.stdout.split("options:")[1]
    names = ("--preset", "--model", "--output", "--episodes", "--actions", "--eval-seed", "--independent-model", "--threads")
    for name in names:
        assert name in options, name
    assert "default: runs/table1_PRESET" in options and "Monte Carlo runs per condition" in options


@pytest.mark.slow  # trains and evaluates every Table I cell in a subprocess: 20 s at load 5
def test_reproduce_table1_smoke(tmp_path):
    # run from another folder without --output: the results go under runs/, never into docs/results/
    result = run_script(str(ROOT / "examples" / "reproduce_table1.py"), "--preset", "smoke", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert [p.relative_to(tmp_path).as_posix() for p in tmp_path.iterdir()] == ["runs"]
    tmp_path = tmp_path / "runs" / "table1_smoke"
    conditions = pd.read_csv(tmp_path / "conditions.csv")
    assert set(conditions["condition"]) == {"proposed", "full_comm", "no_comm", "no_predictor", "no_memory"}
    assert conditions["actions"].drop_duplicates().tolist() == ["sampled", "mean"]  # the paper's protocol first
    assert conditions["seed"].min() == 1_000_000  # held-out episode seeds by default
    conditions_md = (tmp_path / "conditions.md").read_text()
    assert conditions_md.index("Sampled actions") < conditions_md.index("Mean actions")
    assert "episode seeds 1000000-" in conditions_md
    sweep = pd.read_csv(tmp_path / "p_fail_sweep.csv")
    assert sorted(sweep["p_fail"].unique()) == [0.0, 0.05, 0.15, 0.3, 0.5]
    tables = ("conditions.md", "p_fail_sweep.md", "baselines.md", "run.md")
    for name in (*tables, "coverage_vs_time.png", "coverage_vs_p_fail.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "(paper)" in (tmp_path / "conditions.md").read_text()

    # --model evaluates a saved model again; --actions sampled evaluates only the paper's protocol
    again = tmp_path / "stochastic"
    result = run_script(
        "examples/reproduce_table1.py",
        *("--preset", "smoke", "--model", str(tmp_path / "model.zip"), "--output", str(again)),
        *(
            "--episodes",
            "2",
            *("--actions", "sampled"),
            "--independent-model",
            str(tmp_path / "independent_ppo.zip"),
            "--model-notes",
            "the smoke model",
        ),
    )
    assert result.returncode == 0, result.stderr
    report = (again / "run.md").read_text()
    assert "actions of the learned policies: sampled," in report and "(the smoke model)" in report
    assert report.startswith("# Table I run: preset `smoke`") and "- machine: " in report
    assert "- command: `python examples/reproduce_table1.py --preset smoke --model " in report
    sampled = pd.read_csv(again / "conditions.csv").query("condition == 'proposed'")
    mean_action = conditions.query("condition == 'proposed' and actions == 'mean'").head(2)
    assert len(sampled) == 2
    baselines = pd.read_csv(again / "baselines.csv")
    assert (baselines["condition"] == "independent RecurrentPPO (768 steps, sampled)").sum() == 2  # the saved one
    assert not (again / "independent_ppo.zip").exists()
    assert not np.allclose(sampled["episode_return"].to_numpy(), mean_action["episode_return"].to_numpy())


def test_train_example_smoke(tmp_path):
    result = run_script("examples/train.py", "--preset", "smoke", "--output", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "model.zip").exists()
    assert any((tmp_path / "tb").iterdir())  # TensorBoard events were written
    assert "Coverage (%)" in result.stdout


def test_cli_train_evaluate_render(tmp_path, capsys):
    assert main(["train", "--preset", "smoke", "--output", str(tmp_path), "--no-progress", "--evaluate"]) == 0
    out = capsys.readouterr().out
    assert "Conditions" in out and "lawnmower" in out and "no_predictor" in out
    model = str(tmp_path / "model.zip")
    assert main(["evaluate", "--preset", "smoke", "--model", model, "--p-fail-sweep", "--no-baselines"]) == 0
    assert (tmp_path / "evaluation" / "p_fail_sweep.csv").exists()  # beside the model, not over train's tables
    # without --preset, evaluate and render run on the env config saved with the model (smoke's 10x10, not demo's)
    assert main(["evaluate", "--model", model, "--no-baselines", "--episodes", "2", "--output", str(tmp_path / "e")]) == 0
    assert len(pd.read_csv(tmp_path / "e" / "conditions.csv")) == 5 * 2
    assert main(["render", "--model", model, "--output", str(tmp_path / "saved_config.gif")]) == 0
    gif = tmp_path / "episode.gif"
    assert main(["render", "--preset", "smoke", "--model", model, "--output", str(gif)]) == 0
    assert gif.stat().st_size > 0 and (tmp_path / "episode_trajectories.png").exists()
    video = tmp_path / "episode.mp4"
    assert main(["render", "--preset", "smoke", "--model", model, "--output", str(video)]) == 0
    assert video.read_bytes()[4:8] == b"ftyp"  # an MP4 container, written by imageio-ffmpeg

    # --stochastic samples the policy: in the evaluation tables and, reproducibly from --seed, in rendered episodes
    assert main(["evaluate", "--preset", "smoke", "--model", model, "--no-baselines", "--stochastic"]) == 0
    assert "sampled actions" in capsys.readouterr().out
    trained = LatentSwarmPPO.load(model)
    config = get_preset("smoke").config
    sampled = []
    for _ in range(2):
        th.rand(10)  # move the global torch generator: the episode's noise must come from seed alone
        torch_state = th.random.get_rng_state()
        sampled.append(run_episode(trained, config, seed=3, deterministic=False)[1])
        assert th.equal(th.random.get_rng_state(), torch_state)  # and the global generator is left alone
    mean_action = run_episode(trained, config, seed=3, deterministic=True)[1]
    np.testing.assert_array_equal(sampled[0], sampled[1])
    assert sampled[0].shape != mean_action.shape or not np.allclose(sampled[0], mean_action)


def test_render_episode_checks_its_arguments_before_running(tmp_path):
    config = get_preset("smoke").config
    with pytest.raises(ValueError, match="output must end in one of"):
        render_episode(None, config, tmp_path / "episode.avi")
    with pytest.raises(ValueError, match="fps must be > 0, got 0"):
        render_episode(None, config, tmp_path / "episode.gif", fps=0)
    with pytest.raises(ValueError, match="max_frames must be >= 2, got 1"):
        render_episode(None, config, tmp_path / "episode.gif", max_frames=1)
    assert not any(tmp_path.iterdir())


def test_render_episode_writes_mp4_with_odd_frame_sizes(tmp_path):
    import imageio.v2 as imageio

    config = get_preset("fast").config.replace(max_steps=4)  # 25x25 cells render to 475 pixels wide: odd for H.264
    path = render_episode(None, config, tmp_path / "episode.mp4")
    reader = imageio.get_reader(path)
    width, height = reader.get_meta_data()["size"]
    assert (width % 2, height % 2) == (0, 0) and reader.count_frames() == 5  # the reset frame and 4 steps
    assert (tmp_path / "episode_trajectories.png").exists()


def test_cli_overrides_are_typed_and_checked():
    overrides = parse_overrides(["p_fail=0.5", "n_agents=4", "link_mode=full"])
    assert overrides == {"p_fail": 0.5, "n_agents": 4, "link_mode": "full"}
    with pytest.raises(ValueError, match=r"unknown setting 'p_failure' \(did you mean p_fail\?\); `sb3-latentswarm train --l"):
        parse_overrides(["p_failure=0.5"])
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_overrides(["p_fail"])
    with pytest.raises(ValueError, match="given twice"):
        parse_overrides(["p_fail=0.5", "p_fail=0.6"])


def test_every_set_counts_and_reaches_config_algorithm_and_policy(tmp_path):
    args = ["--set", "p_fail=0.9", "--set", "n_agents=2", "learning_rate=1e-3", "--set", "latent_dim=4"]
    assert main(["train", "--preset", "smoke", "--output", str(tmp_path), "--no-progress", *args]) == 0
    model = LatentSwarmPPO.load(tmp_path / "model.zip")
    assert (model.swarm_config.p_fail, model.swarm_config.n_agents) == (0.9, 2)
    assert model.learning_rate == 1e-3 and model.policy.latent_dims[0] == 4
    preset = get_preset("smoke").with_overrides(**parse_overrides(["n_envs=3", "n_steps=40", "chunk_length=10"]))
    assert preset.n_envs == 3 and (preset.algo_kwargs["n_steps"], preset.algo_kwargs["chunk_length"]) == (40, 10)


def test_train_states_the_budget_rounded_up_to_whole_rollouts(tmp_path, capsys):
    # smoke: 2 swarms of 3 UAVs, n_steps 20: a rollout is 120 agent-steps, so 130 trains two of them
    assert main(["train", "--preset", "smoke", "--output", str(tmp_path), "--no-progress", "--total-timesteps", "130"]) == 0
    out = capsys.readouterr().out
    assert "for 240 agent-steps (130 rounded up to whole rollouts of 120): 2 swarms of 3, n_steps 20, 2 updates" in out
    # the PPO settings a user would otherwise have to dig out of presets.py (smoke: the paper's step schedule)
    assert "PPO: learning rate StepSchedule(0.0001, 1e-05, switch_fraction=" in out
    assert "minibatch 30 agent-steps, 1 epoch\n" in out
    assert LatentSwarmPPO.load(tmp_path / "model.zip").num_timesteps == 240


@pytest.mark.parametrize(
    "argv, message",
    [
        (["train", "--preset", "smoke", "--set", "p_fail=1.5"], "p_fail must be a finite number in [0.0, 1.0]"),
        (["evaluate", "--model", "does/not/exist.zip"], "no file at"),
        (["train", "--preset", "smoke", "--set", "grid_width=abc"], "grid_width must be an int, got str ('abc')"),
        (["train", "--preset", "smoke", "--set", "n_agents=2.5"], "n_agents must be an int, got float (2.5)"),
        (["train", "--preset", "smoke", "--set", "n_steps=2.5"], "n_steps must be an int"),
        (["train", "--preset", "smoke", "--set", "pred_coef='5'"], "pred_coef must be a number"),
        (["train", "--preset", "smoke", "--set", "lerning_rate=1"], "'lerning_rate' (did you mean learning_rate, "),
        (["train", "--preset", "smoke", "--set", "warp_speed=1"], "'warp_speed' (no close match); `sb3-latentswarm train"),
        (["render", "--preset", "smoke", "--set", "learning_rate=1e-3"], "a training setting"),
        (["render", "--preset", "smoke", "--output", "episode"], "output must end in one of"),
        (["render", "--preset", "smoke", "--output", "episode.png"], "output must end in one of"),
        (["render", "--preset", "smoke", "--fps", "0"], "--fps: expected an int >= 1, got '0'"),
        (["evaluate", "--model", "m.zip", "--episodes", "0"], "--episodes/--eval-episodes: expected an int >= 1, got '0'"),
        (["train", "--preset", "smoke", "--total-timesteps", "-5"], "--total-timesteps: expected an int >= 1, got '-5'"),
        (["train", "--preset", "smoke", "--save-freq", "1e3"], "--save-freq: expected an int >= 0, got '1e3'"),
    ],
)
def test_cli_bad_arguments_exit_with_a_clear_message(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_list_settings_prints_every_set_name_by_target_and_exits(capsys):
    from sb3_latentswarm.presets import override_targets

    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--list-settings"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    listed = {name.strip() for line in out.splitlines() if line.startswith("  ") for name in line.split(",")} - {""}
    targets = override_targets()
    assert listed == {name for names in targets.values() for name in names}
    headings = [line.split(":")[0] for line in out.splitlines() if line and not line.startswith("  ")]
    assert headings == list(targets)
    names = [name for names in targets.values() for name in names]
    assert len(names) == len(set(names))  # each name once: normalize_value only under LatentSwarmPPO
    assert "normalize_value" in targets["LatentSwarmPPO"] and "normalize_value" not in targets["LatentSwarmPolicy"]


@pytest.mark.parametrize("value", [False, True])
def test_set_normalize_value_goes_to_the_algorithm_which_sets_its_policys(value):
    preset = get_preset("smoke").with_overrides(**parse_overrides([f"normalize_value={value}"]))
    assert preset.algo_kwargs["normalize_value"] is value
    assert "normalize_value" not in preset.algo_kwargs.get("policy_kwargs", {})
    model = preset.make_model(preset.make_env(0))
    assert model.normalize_value is value and model.policy.normalize_value is value
    assert (model.policy.value_normalizer is not None) is value


def test_unknown_setting_names_get_at_most_three_close_matches():
    from sb3_latentswarm.presets import get_preset, unknown_settings_message

    message = unknown_settings_message(["n_agent", "zzz"])
    assert message.startswith("unknown settings 'n_agent' (did you mean n_agents")
    assert message.count(",", 0, message.index("?")) <= 2  # three names at most
    assert "'zzz' (no close match)" in message and "--list-settings" in message
    with pytest.raises(TypeError, match=r"'lerning_rate' \(did you mean learning_rate[,?]"):
        get_preset("smoke").with_overrides(lerning_rate=1e-3)


def test_cli_unknown_preset_is_rejected(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--preset", "huge"])
    assert "invalid choice" in capsys.readouterr().err


@pytest.mark.slow
def test_continue_training_example_smoke(tmp_path):
    first = tmp_path / "first"
    assert main(["train", "--preset", "smoke", "--output", str(first), "--no-progress"]) == 0
    result = run_script(
        "examples/continue_training.py",
        "--model",
        str(first / "model.zip"),
        "--preset",
        "smoke",
        "--output",
        str(tmp_path / "more" / "model.zip"),
    )
    assert result.returncode == 0, result.stderr
    assert "Continued" in result.stdout and (tmp_path / "more" / "progress.csv").exists()

    # the two checkpoints of this run along training, both ways of acting
    models = (str(first / "model.zip"), str(tmp_path / "more" / "model.zip"))
    curve = tmp_path / "curve"
    result = run_script(
        "examples/learning_curve.py", "--preset", "smoke", "--episodes", "2", "--output", str(curve), "--models", *models
    )
    assert result.returncode == 0, result.stderr
    episodes = pd.read_csv(curve / "learning_curve.csv")
    assert sorted(episodes["updates"].unique()) == [2, 4] and set(episodes["actions"]) == {"mean", "sampled"}
    assert len(episodes) == 2 * 2 * 5 * 2  # checkpoints x ways of acting x conditions x episodes
    assert (curve / "learning_curve.png").stat().st_size > 0 and "No comm (LB) coverage (%)" in (curve / "run.md").read_text()
    result = run_script(
        "examples/learning_curve.py", "--preset", "smoke", "--output", str(curve), "--models", models[0], models[0]
    )
    assert result.returncode == 2 and "both have 2 updates" in result.stderr

    # every link down: each UAV uses its substitute message at every step
    dropout = tmp_path / "dropout"
    result = run_script(
        "examples/sustained_dropout.py", "--preset", "smoke", "--model", models[1], "--episodes", "2", "--output", str(dropout)
    )
    assert result.returncode == 0, result.stderr
    episodes = pd.read_csv(dropout / "sustained_dropout.csv")
    assert len(episodes) == 2 * 3 * 2 and (episodes["link_up_rate"] == 0).all() and (episodes["dropout_rate"] == 1).all()
    assert "zero vector" in (dropout / "run.md").read_text()

    # training health: actions in the box, per-term gradient norms, mean vs sampled actions
    health = tmp_path / "health"
    result = run_script(
        "examples/training_diagnostics.py", "--preset", "smoke", "--model", models[1], "--label", "smoke",
        "--episodes", "2", "--rollout-envs", "2", "--output", str(health),
    )
    assert result.returncode == 0, result.stderr
    figures = pd.read_csv(health / "diagnostics.csv", index_col=0)["smoke"]
    assert 0.0 <= figures["actions in box (elements)"] <= 1.0 and figures["grad norm value"] > 0
    assert {"collisions (mean)", "collisions (sampled)", "grad norm pred"} <= set(figures.index)


def test_coordination_gap_benchmark_smoke():
    result = run_script("benchmarks/coordination_gap.py", "--preset", "smoke", "--horizons", "5", "8", "--episodes", "2")
    assert result.returncode == 0, result.stderr
    assert "| planner | T = 5 | T = 8 |" in result.stdout and "| **gap (points)** |" in result.stdout
    assert "random_strip (message-free)" in result.stdout and "frontier (coordinated)" in result.stdout


def test_cli_evaluations_record_their_config_and_never_mix(tmp_path, capsys):
    assert main(["train", "--preset", "smoke", "--output", str(tmp_path), "--no-progress"]) == 0
    model = str(tmp_path / "model.zip")
    evaluate = ["evaluate", "--model", model, "--no-baselines", "--episodes", "1"]
    assert main(evaluate) == 0
    first = tmp_path / "evaluation"
    assert json.loads((first / "evaluation.json").read_text())["config"]["p_fail"] == 0.3
    tables = (first / "conditions.csv").read_text()
    assert main([*evaluate, "--set", "p_fail=0.9"]) == 0  # another config: another folder, the first kept as it was
    assert (first / "conditions.csv").read_text() == tables
    (second,) = tmp_path.glob("evaluation-*")
    assert json.loads((second / "evaluation.json").read_text())["config"]["p_fail"] == 0.9
    assert set(pd.read_csv(second / "conditions.csv")["p_fail"]) == {0.9}
    assert main(evaluate) == 0  # the same evaluation again: the same folder
    assert sorted(p.name for p in tmp_path.glob("evaluation*")) == ["evaluation", second.name]
    with pytest.raises(SystemExit):
        main([*evaluate, "--set", "p_fail=0.5", "--output", str(first)])
    assert "holds the tables of another evaluation" in capsys.readouterr().err


def test_cli_evaluating_a_committed_model_writes_under_runs_not_into_docs(tmp_path, capsys, monkeypatch):
    committed = tmp_path / "docs" / "results" / "some_run"
    assert main(["train", "--preset", "smoke", "--output", str(committed), "--no-progress"]) == 0
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate", "--model", str(committed / "model.zip"), "--no-baselines", "--episodes", "1"]) == 0
    assert "is a committed result; writing this evaluation to runs/evaluate/some_run/evaluation" in capsys.readouterr().out
    assert (tmp_path / "runs" / "evaluate" / "some_run" / "evaluation" / "conditions.csv").exists()
    assert not (committed / "evaluation").exists()


@pytest.mark.parametrize("variables, expected", [({}, 1), ({"OMP_NUM_THREADS": "2"}, 2)])
def test_importing_the_package_applies_the_thread_default_unless_the_environment_chose(variables, expected):
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    code = "import torch; torch.set_num_threads(2); import sb3_latentswarm; print(torch.get_num_threads())"
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env={**env, **variables}, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert int(result.stdout) == expected


@pytest.mark.slow  # trains and evaluates in a subprocess: 9 s at load 5
def test_dropout_diagnostics_smoke(tmp_path):
    model = ROOT / "tests/data/models/coordination-proposed-seed0.zip"
    result = run_script(
        "examples/dropout_diagnostics.py",
        *("--model", str(model), "--episodes", "2", "--conditions", "proposed", "hold_last", "--output", str(tmp_path)),
    )
    assert result.returncode == 0, result.stderr
    table = pd.read_csv(tmp_path / "dropout_diagnostics.csv")
    assert table["condition"].tolist() == ["proposed", "hold_last"] and (table["episodes"] == 2).all()
    assert (tmp_path / "error_by_depth.png").stat().st_size > 0
    assert "Episode seeds 1000000-1000001, sampled actions" in (tmp_path / "dropout_diagnostics.md").read_text()


def _progress(folder: Path, coverage: list[float], cpu_per_update: float) -> Path:
    folder.mkdir(parents=True)
    rows = ["time/total_timesteps,rollout/coverage,time/cpu_seconds"]
    rows += [f"{1000 * (k + 1)},{c},{cpu_per_update * (k + 1)}" for k, c in enumerate(coverage)]
    (folder / "progress.csv").write_text("\n".join(rows) + "\n")
    return folder


def test_time_to_coverage_report_counts_a_run_that_misses_the_target_as_a_lower_bound(tmp_path):
    old = [_progress(tmp_path / "old-s0", [0.5, 0.8, 0.96, 0.97], 2.0),  # target at update 3: 3,000 steps, 6 CPU s
           _progress(tmp_path / "old-s1", [0.5, 0.7, 0.8, 0.9], 2.0)]  # never: counted at 4,000 steps, 8 CPU s
    new = [_progress(tmp_path / "new-s0", [0.6, 0.95, 0.97, 0.98], 1.0)]  # target at update 2: 2,000 steps, 2 CPU s
    result = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "time_to_coverage.py"), "report", *map(str, old + new),
         "--target", "0.95", "--reference", "old"],
        capture_output=True, text=True, check=True,
    )
    out = result.stdout
    assert "| old | old-s0 | 4 | 3,000 | 6 | 0.9700 | 2.00 |" in out
    assert "| old | old-s1 | 4 | > 4,000 | > 8 | 0.9000 | 2.00 |" in out
    assert "old: mean agent-steps to target >= 3,500, CPU s >= 7 (old / old: 1.00x agent-steps, 1.00x CPU s; 1 run(s)" in out
    assert "new: mean agent-steps to target 2,000, CPU s 2 (old / new: >= 1.75x agent-steps, >= 3.50x CPU s)" in out
    never = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "time_to_coverage.py"), "report", *map(str, old + new),
         "--target", "0.999", "--reference", "old"],
        capture_output=True, text=True, check=True,
    ).stdout
    assert "old / new: n/a, both have runs that never reached it" in never
    for bad, message in ((["--reference", "older"], "--reference 'older' is none of the labels found: old, new"),
                         ([str(tmp_path / "nothing-s0")], "no progress.csv in:"),
                         (["--plot", str(tmp_path / "no" / "curves.png")], "does not exist")):
        result = subprocess.run(
            [sys.executable, str(ROOT / "examples" / "time_to_coverage.py"), "report", *map(str, old + new), *bad],
            capture_output=True, text=True,
        )
        assert result.returncode == 1 and message in result.stderr


def test_the_command_line_samples_actions_by_default_and_deterministic_asks_for_the_mean():
    from sb3_latentswarm.cli.parser import build_parser

    parser = build_parser()
    for command in (["evaluate", "--model", "m.zip"], ["render", "--model", "m.zip"], ["train"],
                    ["sweep", "--preset", "smoke", "--seeds", "1"]):
        assert parser.parse_args(command).stochastic is True, command  # the paper's test-time protocol
        assert parser.parse_args([*command, "--deterministic"]).stochastic is False, command
        assert parser.parse_args([*command, "--stochastic"]).stochastic is True, command  # 0.1's spelling still parses
    with pytest.raises(SystemExit):
        parser.parse_args(["evaluate", "--model", "m.zip", "--deterministic", "--stochastic"])
