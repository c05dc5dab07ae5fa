"""What a new user meets first: a fast ``--help``, ``--version``, help on every option, clear policy_kwargs errors."""

import argparse
import ast
import subprocess
import sys
from pathlib import Path

import pytest

import sb3_latentswarm
from sb3_latentswarm.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]


def run_python(code: str) -> str:
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_help_imports_neither_torch_nor_stable_baselines3():
    code = (
        "import sys\n"
        "from sb3_latentswarm.cli import build_parser\n"
        "build_parser().format_help()\n"
        "print(sorted(m for m in ('torch', 'stable_baselines3', 'sb3_contrib', 'pandas') if m in sys.modules))\n"
    )
    assert run_python(code).strip() == "[]"


SCRIPTS = sorted(  # the scripts a user runs (``_compare.py`` is a module the benchmarks import)
    p.relative_to(ROOT).as_posix()
    for folder in ("examples", "benchmarks")
    for p in (ROOT / folder).glob("*.py")
    if not p.name.startswith("_")
)
HEAVY = ("torch", "stable_baselines3", "sb3_contrib", "pandas", "matplotlib")


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_example_and_benchmark_answers_help_before_importing_torch(script):
    # -X importtime lists every module the interpreter imported, on stderr: `import time: self | cumulative | name`
    result = subprocess.run(
        [sys.executable, "-X", "importtime", script, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.startswith("usage: "), result.stdout[:200]
    imported = {line.rsplit("|", 1)[-1].strip() for line in result.stderr.splitlines() if line.startswith("import time:")}
    assert sorted(imported & set(HEAVY)) == []
    summary = ast.get_docstring(ast.parse((ROOT / script).read_text())).split("\n")[0]
    assert " ".join(summary.split()[:6]) in " ".join(result.stdout.split())  # the module docstring is the description


def test_the_scripts_held_out_seed_literals_are_the_evaluation_default():
    from sb3_latentswarm.evaluation import HELD_OUT_SEED

    literals = {}
    for script in SCRIPTS:
        for node in ast.parse((ROOT / script).read_text()).body:
            if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["HELD_OUT_SEED"]:
                literals[script] = ast.literal_eval(node.value)
    assert len(literals) >= 4 and set(literals.values()) == {HELD_OUT_SEED}, literals


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"sb3-latentswarm {sb3_latentswarm.__version__}"


def test_every_option_of_every_subcommand_has_a_help_text():
    parser = build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = [
        f"{name} {action.option_strings[0]}"
        for name, sub in subparsers.choices.items()
        for action in sub._actions
        if action.option_strings and not action.help
    ]
    assert missing == []
    assert set(subparsers.choices) == {"train", "evaluate", "render", "sweep"}


def test_public_names_load_on_first_use():
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    assert sb3_latentswarm.LatentSwarmPPO is LatentSwarmPPO
    assert set(sb3_latentswarm.__all__) <= set(dir(sb3_latentswarm))
    with pytest.raises(AttributeError, match="no attribute 'LatentPPO'"):
        sb3_latentswarm.LatentPPO  # noqa: B018


def test_common_names_load_on_first_use_through_the_same_mechanism():
    code = (
        "import sys\n"
        "import sb3_latentswarm.common as common\n"
        "print('torch' in sys.modules, sorted(common.__all__) == sorted(n for n in dir(common) if n in common.__all__))\n"
        "from sb3_latentswarm.latent_ppo.value_norm import ValueNorm\n"
        "import warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    print(common.ValueNorm is ValueNorm, 'ValueNorm' in vars(common), caught[0].category.__name__)\n"
        "try:\n"
        "    common.ValueNormalizer\n"
        "except AttributeError as error:\n"
        "    print(error)\n"
    )
    assert run_python(code).splitlines() == [
        "False True",
        "True True DeprecationWarning",
        "module 'sb3_latentswarm.common' has no attribute 'ValueNormalizer'",
    ]


def test_the_threads_module_of_0_1_still_imports_from_its_old_path_with_a_deprecation_warning():
    code = (
        "import warnings\n"
        "warnings.filterwarnings('error', message='sb3_latentswarm')\n"
        "import sb3_latentswarm.utils.threads as threads\n"  # the new path imports without a warning
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    from sb3_latentswarm.common.threads import apply_default_torch_threads\n"
        "print(apply_default_torch_threads is threads.apply_default_torch_threads, caught[0].category.__name__)\n"
        "print(caught[0].message)\n"
    )
    assert run_python(code).splitlines() == [
        "True DeprecationWarning",
        "sb3_latentswarm.common.threads moved to sb3_latentswarm.utils.threads; the old path will be removed in 0.3",
    ]


def test_the_thread_default_is_applied_once_so_a_later_choice_is_kept():
    code = (
        "import torch\n"
        "from sb3_latentswarm import LatentSwarmPPO\n"
        "first = torch.get_num_threads()\n"
        "torch.set_num_threads(3)\n"
        "import sb3_latentswarm.envs, sb3_latentswarm.baselines\n"
        "print(first, torch.get_num_threads())\n"
    )
    assert run_python(code).split() == ["1", "3"]


def test_sb3_policy_kwargs_get_the_valid_names():
    from sb3_latentswarm import LatentSwarmPPO, make_vec_env
    from sb3_latentswarm.presets import get_preset

    env = make_vec_env(1, config=get_preset("smoke").config, seed=0)
    sb3_style = {"net_arch": [64], "lstm_hidden_size": 8}
    with pytest.raises(TypeError) as error:
        LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=20, chunk_length=5, batch_size=30, policy_kwargs=sb3_style)
    message = str(error.value)
    assert "['lstm_hidden_size', 'net_arch']" in message
    assert "net_arch -> predictor_hidden, decoder_hidden, critic_hidden, actor_hidden" in message
    assert "lstm_hidden_size -> latent_dim" in message
    assert "Valid policy_kwargs are: latent_dim, map_dim" in message


@pytest.mark.parametrize("name", ["MultiInputPolicy", "MlpPolicy", "MultiInputLstmPolicy", "latentswarmpolicy"])
def test_an_sb3_policy_name_gets_an_error_naming_the_supported_policy(name):
    from sb3_latentswarm import LatentSwarmPPO, make_vec_env
    from sb3_latentswarm.presets import get_preset

    env = make_vec_env(1, config=get_preset("smoke").config, seed=0)
    expected = f"LatentSwarmPPO has no policy '{name}': the only one it supports is 'LatentSwarmPolicy'"
    with pytest.raises(ValueError, match=expected):
        LatentSwarmPPO(name, env, n_steps=20, chunk_length=5, batch_size=30)


def test_an_sb3_policy_class_is_refused_before_it_is_built():
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy

    from sb3_latentswarm import LatentSwarmPolicy, LatentSwarmPPO, make_vec_env
    from sb3_latentswarm.presets import get_preset

    env = make_vec_env(1, config=get_preset("smoke").config, seed=0)
    with pytest.raises(TypeError, match="policy must be 'LatentSwarmPolicy' or a subclass of LatentSwarmPolicy, got <class"):
        LatentSwarmPPO(MultiInputActorCriticPolicy, env, n_steps=20, chunk_length=5, batch_size=30)

    class WiderCritic(LatentSwarmPolicy):
        pass

    model = LatentSwarmPPO(WiderCritic, env, n_steps=20, chunk_length=5, batch_size=30)
    assert type(model.policy) is WiderCritic


@pytest.mark.slow  # trains and loads two committed models: about 10 s unloaded, minutes on a loaded machine
def test_the_demo_script_runs_and_reads_its_tables(tmp_path):
    result = subprocess.run(
        [sys.executable, "examples/demo.py", "--total-timesteps", "720", "--episodes", "2", "--coordination-episodes", "2"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    out = result.stdout
    for text in ("### Demo task", "### Coordination task", "| proposed", "| no_comm", "| random swarm",
                 "| lawnmower planner", "| frontier planner",
                 "| learner trained without links", "| full_comm", "| no_predictor", "| no_memory",
                 "What the tables show:", "docs/results.md", "episode seeds 1,000,000..1,000,001", "Demo time:"):
        assert text in out, text
    reading = out.split("What the tables show:")[1].strip().splitlines()
    assert len([line for line in reading if line.startswith("- ")]) == 5
    # the reading compares the learned swarm with the scripted planners, and reads the ablation rows
    assert "lawnmower planner" in reading[1] and "frontier planner" in reading[1]
    assert "No predictor" in reading[3] and "No memory" in reading[3]


@pytest.mark.parametrize("command, dest", [("evaluate", "episodes"), ("sweep", "eval_episodes")])
@pytest.mark.parametrize("spelling", ["--episodes", "--eval-episodes"])
def test_evaluate_and_sweep_take_both_spellings_of_the_episode_count(command, dest, spelling):
    required = {"evaluate": ["--model", "m.zip"], "sweep": ["--preset", "smoke", "--seeds", "1"]}[command]
    args = build_parser().parse_args([command, *required, spelling, "7"])
    assert getattr(args, dest) == 7
