"""The ``sb3-latentswarm`` command: ``train``, ``evaluate``, ``render`` and ``sweep``.

    sb3-latentswarm train --preset demo --evaluate          # the README's main job
    sb3-latentswarm evaluate --model runs/demo/model.zip --p-fail-sweep   # on the env config saved with the model
    sb3-latentswarm render --model runs/demo/model.zip --output episode.gif
    sb3-latentswarm sweep --preset fast --seeds 5           # seeds x variants on Ray Tune, across-seed intervals
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import hashlib
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_latentswarm.presets import PRESETS, Preset, get_preset, override_targets
from sb3_latentswarm.version import __version__


def _literal(raw: str) -> Any:
    """A ``--set`` value as Python reads it (``3`` int, ``2.5`` and ``1e-4`` float, ``True``, ``None``, ``(1, 2)``),
    else the text itself (``full``)."""
    if raw.lower() in ("true", "false"):
        return raw.lower() == "true"
    try:
        return ast.literal_eval(raw)
    except (ValueError, SyntaxError):
        return raw


def parse_overrides(pairs: list[str]) -> dict[str, Any]:
    """Turn ``["p_fail=0.5", "n_agents=4", "learning_rate=1e-4"]`` into ``{name: value}`` settings.

    Values are read as Python literals and not converted: ``n_agents=2.5`` stays a float, which ``SwarmConfig``
    rejects, as it would in Python. Names are checked against :func:`~sb3_latentswarm.presets.override_targets`
    (``SwarmConfig`` fields, ``n_envs``/``eval_episodes``, ``LatentSwarmPPO`` and ``LatentSwarmPolicy`` arguments);
    :meth:`Preset.with_overrides <sb3_latentswarm.presets.Preset.with_overrides>` routes them and validates.
    """
    targets = override_targets()
    valid = {name for names in targets.values() for name in names}
    overrides: dict[str, Any] = {}
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"--set expects NAME=VALUE, got {pair!r}")
        name, raw = pair.split("=", 1)
        if name not in valid:
            listing = "; ".join(f"{target}: {', '.join(names)}" for target, names in targets.items())
            raise ValueError(f"--set: unknown setting {name!r}; valid settings are {listing}")
        if name in overrides:
            raise ValueError(f"--set {name} given twice ({overrides[name]!r} and {raw!r})")
        overrides[name] = _literal(raw)
    return overrides


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _preset_from_args(args: argparse.Namespace, model: Any = None, training: bool = False) -> Preset:
    """The ``--preset`` named, or, without one, the training config saved with ``model`` (else ``demo``), with the
    ``--set`` overrides; algorithm settings only when ``training``."""
    if args.preset is not None:
        preset = get_preset(args.preset)
    elif getattr(model, "swarm_config", None) is not None:
        preset = Preset(
            name="saved",
            config=model.swarm_config,
            n_envs=1,
            total_timesteps=0,
            description="the env config saved with the model",
        )
    else:
        preset = get_preset("demo")
    overrides = parse_overrides(args.set or [])
    if not training:
        targets = override_targets()
        for name in overrides:
            if name in targets["LatentSwarmPPO"] + targets["LatentSwarmPolicy"] + ("n_envs",):
                raise ValueError(f"--set {name}: a training setting, which only `train` uses")
    return preset.with_overrides(**overrides) if overrides else preset


def _print_table(title: str, markdown: str) -> None:
    print(f"\n### {title}\n")
    print(markdown)


def command_train(args: argparse.Namespace) -> int:
    from sb3_latentswarm.envs import make_vec_env
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    preset = _preset_from_args(args, training=True)
    output = Path(args.output or f"runs/{preset.name}")
    output.mkdir(parents=True, exist_ok=True)
    total = args.total_timesteps or preset.total_timesteps
    env = make_vec_env(preset.n_envs, config=preset.config, seed=args.seed, backend=args.backend)
    model = LatentSwarmPPO(
        "LatentSwarmPolicy",
        env,
        seed=args.seed,
        device=args.device,
        verbose=args.verbose,
        tensorboard_log=args.tensorboard,
        **preset.algo_kwargs,
    )
    print(f"Training preset '{preset.name}'{' with ' + ' '.join(args.set) if args.set else ''} for {total:,} agent-steps: {preset.n_envs} swarms of {preset.config.n_agents}, n_steps {model.n_steps}, {-(-total // (model.n_steps * env.num_envs))} updates, seed {args.seed}")  # noqa: E501
    start = time.perf_counter()
    model.learn(total_timesteps=total, progress_bar=not args.no_progress, tb_log_name=f"latentswarm_{preset.name}")
    train_seconds = time.perf_counter() - start
    model_path = output / "model.zip"
    model.save(model_path)
    (output / "config.json").write_text(json.dumps(preset.config.to_dict(), indent=2))
    print(f"Trained in {train_seconds:.0f} s; saved {model_path}")
    if args.evaluate:
        _evaluate_and_print(model, preset, args, output, p_fail_sweep=False, baselines=True)
    return 0


def _evaluate_and_print(
    model, preset: Preset, args: argparse.Namespace, output: Path, p_fail_sweep: bool, baselines: bool
) -> None:
    from sb3_latentswarm.evaluation import (
        CONDITIONS,
        evaluate,
        evaluate_conditions,
        evaluate_p_fail_sweep,
        summarize,
        to_markdown,
    )

    config, episodes, seed = preset.config, preset.eval_episodes, args.seed
    progress_bar = sys.stderr.isatty() and not args.no_progress
    policy_kwargs = dict(
        n_episodes=episodes, seed=seed, config=config, deterministic=not args.stochastic, progress_bar=progress_bar
    )
    frames = [evaluate_conditions(model, conditions=CONDITIONS, p_fail=config.p_fail, **policy_kwargs)]
    if baselines:
        from sb3_latentswarm.baselines import FrontierPlanner, LawnmowerPlanner, RandomPlanner

        for label, planner in (
            ("random", RandomPlanner(config, seed=seed)),
            ("lawnmower", LawnmowerPlanner(config)),
            ("frontier", FrontierPlanner(config)),
        ):
            frame = evaluate(
                planner, p_fail=config.p_fail, n_episodes=episodes, seed=seed, config=config, progress_bar=progress_bar
            )
            frame["condition"] = label
            frames.append(frame)
    import pandas as pd

    table = pd.concat(frames, ignore_index=True)
    table.to_csv(output / "conditions.csv", index=False)
    summary = summarize(table, by="condition")
    actions = "sampled" if args.stochastic else "mean"
    _print_table(f"Conditions (p_f = {config.p_fail}, {episodes} episodes each, {actions} actions)", to_markdown(summary))
    (output / "conditions.md").write_text(to_markdown(summary) + "\n")
    if p_fail_sweep:
        sweep = evaluate_p_fail_sweep(model, p_fails=preset.p_fails, **policy_kwargs)
        sweep.to_csv(output / "p_fail_sweep.csv", index=False)
        sweep_summary = summarize(sweep, by="p_fail")
        _print_table("p_f sweep (proposed)", to_markdown(sweep_summary))
        (output / "p_fail_sweep.md").write_text(to_markdown(sweep_summary) + "\n")
    print(f"\nTables written to {output}/")


def _load_model(args: argparse.Namespace):
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    if not Path(args.model).exists():
        raise ValueError(f"--model: no file at {args.model}")
    return LatentSwarmPPO.load(args.model, device=args.device, trust_pickle=args.trust_pickle)


EVALUATION_RECORD = "evaluation.json"
"""Written beside every evaluation's tables: what they were made from (config, episodes, seed, actions, model)."""


def _evaluation_record(preset: Preset, args: argparse.Namespace) -> dict[str, Any]:
    return {
        "model": str(args.model),
        "preset": preset.name,
        "config": preset.config.to_dict(),
        "episodes": preset.eval_episodes,
        "seed": args.seed,
        "actions": "sampled" if args.stochastic else "mean",
        "baselines": not args.no_baselines,
        "sb3_latentswarm": __version__,
    }


def _holds_other_tables(folder: Path, record: dict[str, Any]) -> bool:
    """Whether ``folder`` holds tables of an evaluation other than ``record`` (or of an unrecorded one)."""
    if not any(folder.glob("*.csv")):
        return False
    path = folder / EVALUATION_RECORD
    if not path.exists():
        return True
    recorded = json.loads(path.read_text())
    return any(recorded.get(key) != value for key, value in record.items() if key != "sb3_latentswarm")


def _evaluation_folder(args: argparse.Namespace, record: dict[str, Any]) -> Path:
    """``--output``, or ``evaluation/`` next to the model; never a folder with tables of another evaluation.

    Without ``--output``, an ``evaluation/`` that holds other tables is kept and this evaluation goes to
    ``evaluation-HASH/`` (HASH: of its record); an ``--output`` that holds other tables is an error.
    """
    if args.output:
        folder = Path(args.output)
        if _holds_other_tables(folder, record):
            raise ValueError(
                f"--output {folder} holds the tables of another evaluation (see its {EVALUATION_RECORD}); pass an empty "
                f"or new folder"
            )
        return folder
    folder = Path(args.model).parent / "evaluation"
    if _holds_other_tables(folder, record):
        digest = hashlib.sha1(json.dumps(record, sort_keys=True).encode()).hexdigest()[:8]
        folder = folder.with_name(f"evaluation-{digest}")
        print(f"{folder.parent / 'evaluation'} holds another evaluation's tables; writing to {folder}")
    return folder


def command_evaluate(args: argparse.Namespace) -> int:
    model = _load_model(args)
    preset = _preset_from_args(args, model)
    if args.episodes:
        preset = dataclasses.replace(preset, eval_episodes=args.episodes)
    record = _evaluation_record(preset, args)
    output = _evaluation_folder(args, record)
    output.mkdir(parents=True, exist_ok=True)
    (output / EVALUATION_RECORD).write_text(json.dumps(record, indent=2))
    _evaluate_and_print(model, preset, args, output, p_fail_sweep=args.p_fail_sweep, baselines=not args.no_baselines)
    return 0


def command_render(args: argparse.Namespace) -> int:
    from sb3_latentswarm.rendering import render_episode

    model = _load_model(args) if args.model else None
    preset = _preset_from_args(args, model)
    path = render_episode(
        model,
        preset.config,
        args.output,
        seed=args.seed,
        condition=args.condition,
        fps=args.fps,
        deterministic=not args.stochastic,
    )
    print(f"Wrote {path}")
    return 0


def _overrides_of(option: str, pairs: list[str]) -> dict[str, Any]:
    """:func:`parse_overrides` for another option than ``--set`` (its messages name that option)."""
    try:
        return parse_overrides(pairs)
    except ValueError as error:
        raise ValueError(str(error).replace("--set", option, 1)) from None


def _parse_grid(pairs: list[str]) -> dict[str, Sequence[Any]]:
    """``["p_fail=0.1,0.3"]`` -> ``{"p_fail": [0.1, 0.3]}`` (values typed like ``--set``'s)."""
    grid: dict[str, Sequence[Any]] = {}
    for pair in pairs:
        name, _, raw = pair.partition("=")
        if not raw:
            raise ValueError(f"--grid expects FIELD=V1,V2,..., got {pair!r}")
        grid[name] = [_overrides_of("--grid", [f"{name}={value}"])[name] for value in raw.split(",")]
    return grid


def _parse_eval_set(text: str):
    """``"burst10=outage_model=gilbert_elliott,mean_outage_steps=10,conditions=proposed+no_predictor"`` -> EvalSet."""
    from sb3_latentswarm.experiments import EvalSet

    name, _, raw = text.partition("=")
    if not name or not raw:
        raise ValueError(f"--eval-set expects NAME=FIELD=VALUE[,FIELD=VALUE...][,conditions=C1+C2], got {text!r}")
    pairs = raw.split(",")
    conditions = [pair.partition("=")[2] for pair in pairs if pair.startswith("conditions=")]
    overrides = _overrides_of(f"--eval-set {name}", [pair for pair in pairs if not pair.startswith("conditions=")])
    return EvalSet(name, overrides, tuple(conditions[-1].split("+")) if conditions else None)


def command_sweep(args: argparse.Namespace) -> int:
    from sb3_latentswarm.experiments import run_sweep

    try:
        run_sweep(
            args.preset,
            args.seeds,
            variants=args.variant or ("proposed", "no_comm", "independent"),
            grid=_parse_grid(args.grid or []),
            overrides=parse_overrides(args.set or []),
            extra_eval_sets=[_parse_eval_set(text) for text in args.eval_set or []],
            eval_episodes=args.eval_episodes,
            deterministic=not args.stochastic,
            address=args.address,
            cpus_per_trial=args.cpus_per_trial,
            gpus_per_trial=args.gpus_per_trial,
            output=args.output,
            resume=args.resume,
            verbose=args.verbose,
            only=args.only,
        )
    except RuntimeError as error:  # failed trials: the finished ones are reported, --resume retries the rest
        print(f"sb3-latentswarm sweep: {error}", file=sys.stderr)
        return 1
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-latentswarm", description="Train and evaluate latent-state UAV swarms.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    def add_common(p: argparse.ArgumentParser, default_preset: str | None) -> None:
        preset_help = (
            f"experiment budget and env (default: {default_preset})"
            if default_preset
            else "env config to run on (default: the one saved with --model; without a model, demo)"
        )
        p.add_argument("--preset", default=default_preset, choices=sorted(PRESETS), help=preset_help)
        p.add_argument(
            "--set",
            nargs="+",
            action="extend",
            metavar="NAME=VALUE",
            help="override a setting; repeatable, all count. SwarmConfig fields (p_fail=0.5), n_envs, eval_episodes, "
            "and for train LatentSwarmPPO / LatentSwarmPolicy arguments (learning_rate=1e-4, n_steps=100, "
            "latent_dim=32); values are Python literals, validated as in Python",
        )
        p.add_argument(
            "--seed",
            type=int,
            default=0,
            help="random seed (default 0): for train, the model's seed and the env copies' (copy k gets SEED + k); for "
            "evaluate and render, the episode seed the evaluation episodes start from",
        )
        p.add_argument(
            "--device",
            default="auto",
            help="torch device of the model, as SB3 takes it: auto (default: CUDA if available, else CPU), cpu, cuda, "
            "cuda:1",
        )
        p.add_argument(
            "--threads",
            type=int,
            default=0,
            help="torch CPU threads (default 0: the package default of one thread, the fastest for these small "
            "recurrent nets on a loaded CPU; see sb3_latentswarm.common.threads)",
        )
        p.add_argument("--no-progress", action="store_true", help="no progress bars (shown on a terminal otherwise)")
        p.add_argument(
            "--stochastic",
            action="store_true",
            help="sample the policy's Gaussian actions when evaluating or rendering (default: its mean action)",
        )

    def add_trust_pickle(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--trust-pickle",
            action="store_true",
            help="also load model files with pickled attributes (SB3's format, older sb3-latentswarm files); unpickling "
            "runs code from the file: only for files you trust",
        )

    train = sub.add_parser("train", help="train LatentSwarmPPO on a preset")
    add_common(train, "demo")
    train.add_argument("--total-timesteps", type=positive_int, default=None, help="override the preset's budget (agent-steps)")
    train.add_argument("--output", default=None, help="folder for model.zip and tables (default runs/PRESET)")
    train.add_argument("--evaluate", action="store_true", help="evaluate all conditions and baselines afterwards")
    train.add_argument("--tensorboard", default=None, help="TensorBoard log folder")
    train.add_argument(
        "--verbose",
        type=int,
        default=0,
        choices=(0, 1, 2),
        help="SB3's verbosity: 0 quiet (default), 1 the training log table every update, 2 also debug messages",
    )
    train.add_argument(
        "--backend",
        default="batched",
        choices=("batched", "supersuit"),
        help="vec env backend: 'batched' (default, fast) or 'supersuit' (PettingZoo env via SuperSuit); same episodes",
    )
    train.set_defaults(func=command_train)

    evaluate = sub.add_parser("evaluate", help="evaluate a saved model on the five conditions of Table I")
    add_common(evaluate, None)
    evaluate.add_argument("--model", required=True, help="a LatentSwarmPPO model.zip (e.g. runs/demo/model.zip)")
    add_trust_pickle(evaluate)
    evaluate.add_argument("--episodes", type=positive_int, default=None, help="episodes per row (default: the preset's)")
    evaluate.add_argument("--p-fail-sweep", action="store_true", help="also run the p_f sweep of Table I (right)")
    evaluate.add_argument(
        "--no-baselines", action="store_true", help="skip the random, lawnmower and frontier planners (default: run them)"
    )
    evaluate.add_argument(
        "--output",
        default=None,
        help="folder for the tables and evaluation.json, the record of what they were made from (default: evaluation/ "
        "next to the model; evaluation-HASH/ when that holds another evaluation's tables)",
    )
    evaluate.set_defaults(func=command_evaluate)

    render = sub.add_parser("render", help="write an animated GIF (or MP4) of one episode and a trajectory figure")
    add_common(render, None)
    render.add_argument("--model", default=None, help="saved model (default: random actions)")
    add_trust_pickle(render)
    render.add_argument(
        "--condition",
        default="proposed",
        help="test-time communication condition of sb3_latentswarm.evaluation.CONDITIONS (default proposed; also "
        "full_comm, no_comm, no_predictor, no_memory, ...)",
    )
    render.add_argument("--output", default="episode.gif", help="file ending in .gif or .mp4 (needs imageio-ffmpeg)")
    render.add_argument("--fps", type=positive_int, default=10, help="frames per second of the animation (default 10)")
    render.set_defaults(func=command_render)

    sweep = sub.add_parser("sweep", help="train seeds x variants (x a grid) on Ray Tune; across-seed intervals (extra sweep)")
    sweep.add_argument("--preset", required=True, choices=sorted(PRESETS), help="env, algorithm settings and budget")
    sweep.add_argument("--seeds", type=int, required=True, help="training seeds 0 .. K-1 per variant and grid point")
    sweep.add_argument(
        "--variant",
        nargs="+",
        choices=("proposed", "no_comm", "independent"),
        help="learners to train (default: all three); no_comm is LatentSwarmPPO trained with every link down",
    )
    sweep.add_argument(
        "--grid", action="append", metavar="NAME=V1,V2", help="settings to cross, any name --set takes (repeatable)"
    )
    sweep.add_argument(
        "--set", nargs="+", action="extend", metavar="NAME=VALUE", help="settings for every trial, as train's --set"
    )
    sweep.add_argument(
        "--eval-set",
        action="append",
        metavar="NAME=FIELD=V,...",
        help="an extra evaluation cell: config overrides, optionally conditions=C1+C2 (default: every condition)",
    )
    sweep.add_argument("--eval-episodes", type=positive_int, default=None, help="episodes per cell (default: the preset's)")
    sweep.add_argument("--stochastic", action="store_true", help="evaluate with sampled actions (default: the mean action)")
    sweep.add_argument("--address", default=None, help="Ray cluster to attach to (default: start Ray on this machine)")
    sweep.add_argument("--cpus-per-trial", type=float, default=1.0, help="CPUs per trial (and its torch threads; default 1)")
    sweep.add_argument("--gpus-per-trial", type=float, default=0.0, help="GPUs per trial (default 0: train on the CPU)")
    sweep.add_argument("--output", default=None, help="result folder (default runs/sweeps/PRESET)")
    sweep.add_argument(
        "--only", nargs="+", metavar="TRIAL_ID", default=None,
        help="run only these trials (e.g. proposed-seed2); the others stay pending for a later --resume",
    )
    sweep.add_argument("--resume", action="store_true", help="continue the sweep in --output; finished trials are kept")
    sweep.add_argument("--verbose", type=int, default=1, help="Ray Tune console: 0 silent, 1 status table, 2 trial results")
    sweep.set_defaults(func=command_sweep, threads=1)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.threads < 0:
        parser.exit(2, f"sb3-latentswarm {args.command}: error: --threads must be >= 0, got {args.threads}\n")
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    try:
        return args.func(args)
    except (ValueError, TypeError) as error:
        parser.exit(2, f"sb3-latentswarm {args.command}: error: {error}\n")
    return 1


if __name__ == "__main__":
    sys.exit(main())
