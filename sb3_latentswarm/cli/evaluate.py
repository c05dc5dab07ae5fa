"""``sb3-latentswarm evaluate``: a saved model on the five conditions of Table I (and the p_f sweep, the planners),
its tables written beside ``evaluation.json``, the record of what they were made from; ``train --evaluate`` uses the
same :func:`evaluate_and_print`."""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import pandas as pd

import sb3_latentswarm.evaluation as evaluation
from sb3_latentswarm.baselines import FrontierPlanner, LawnmowerPlanner, RandomPlanner
from sb3_latentswarm.cli.settings import eval_seed, preset_from_args
from sb3_latentswarm.latent_ppo import LatentSwarmPPO
from sb3_latentswarm.presets import Preset
from sb3_latentswarm.utils.atomic import atomic_path, probe_writable, read_json, write_json, write_text
from sb3_latentswarm.utils.locks import output_lock
from sb3_latentswarm.version import __version__

EVALUATION_RECORD = "evaluation.json"
"""Written beside every evaluation's tables: what they were made from (model file hash, config, conditions, p_f values,
episodes and seeds, actions) and which tables are complete."""

EVALUATION_TABLES = ("conditions", "p_fail_sweep")
"""The tables an evaluation writes (``NAME.csv`` and ``NAME.md``)."""


RECORD_IDENTITY = ("model_sha256", "config", "env", "episodes", "env_seeds", "actions")
"""What every table of one evaluation folder shares; each table adds its own inputs (``requested``)."""


def command_evaluate(args: argparse.Namespace) -> int:
    """``evaluate``: the model on the five conditions and the planners (``--p-fail-sweep``: Table I's right side),
    on the env config saved with it unless ``--preset`` / ``--set`` say otherwise; tables into
    :func:`_evaluation_folder`."""
    model = load_model(args)
    check_model_env(args, model)
    preset = preset_from_args(args, model)
    if args.episodes:
        preset = dataclasses.replace(preset, eval_episodes=args.episodes)
    record = _evaluation_record(preset, args)
    output = _evaluation_folder(args, record)
    with output_lock(output):  # one writer of the evaluation folder for the whole evaluation
        _check_evaluation_folder(output, record)  # again: another evaluation may have written it meanwhile
        probe_writable(output, room_bytes=1 << 20)
        evaluate_and_print(model, preset, args, output, p_fail_sweep=args.p_fail_sweep, baselines=not args.no_baselines)
    return 0


def check_model_env(args: argparse.Namespace, model: LatentSwarmPPO) -> None:
    """Refuse ``--env`` with a model of the swarm env, and a model of an adapted env without ``--env``.

    :raise ValueError: naming ``--model`` and ``--env`` and what to pass
    """
    adapted_model = "global_map" not in getattr(model.observation_space, "spaces", {})
    if adapted_model and args.adapted_env is None:
        raise ValueError(
            f"--model {args.model} was trained on an adapted env (its observations have no global_map); the model file "
            "does not name the env (a file never names code to import): pass --env NAME --env-kwargs JSON as in train"
        )
    if not adapted_model and args.adapted_env is not None:
        raise ValueError(f"--env {args.env}: --model {args.model} was trained on the swarm env; use it without --env")


def load_model(args: argparse.Namespace) -> LatentSwarmPPO:
    """``--model``'s LatentSwarmPPO (``--trust-pickle``: also a file with pickled attributes), on ``--device``."""
    if not Path(args.model).exists():
        raise ValueError(f"--model: no file at {args.model}")
    if not Path(args.model).is_file():
        raise ValueError(f"--model {args.model} is not a regular file (a directory or a FIFO?); pass a model .zip")
    return LatentSwarmPPO.load(args.model, device=args.device, trust_pickle=args.trust_pickle)


def evaluate_and_print(
    model,
    preset: Preset,
    args: argparse.Namespace,
    output: Path,
    p_fail_sweep: bool,
    baselines: bool,
    model_path: Path | str | None = None,
) -> None:
    """Evaluate, print and write each table as soon as it is complete (atomically), with ``evaluation.json``.

    :raise ValueError: when ``output`` holds the tables of another evaluation (:func:`_check_evaluation_folder`)
    """
    if preset.env is not None:
        baselines = False  # the planners move UAVs over a map: the swarm env only
    record = _evaluation_record(preset, args, model_path or args.model, p_fail_sweep=p_fail_sweep, baselines=baselines)
    record = _check_evaluation_folder(output, record)
    output.mkdir(parents=True, exist_ok=True)
    write_json(output / EVALUATION_RECORD, record)

    def finished(name: str, frame, markdown: str) -> None:
        with atomic_path(output / f"{name}.csv") as tmp:
            frame.to_csv(tmp, index=False)
        write_text(output / f"{name}.md", markdown + "\n")
        record["tables"][name] = record["requested"][name]
        write_json(output / EVALUATION_RECORD, record)

    config, episodes, seed = preset.config, preset.eval_episodes, eval_seed(args)
    if preset.env is not None:
        _evaluate_adapted(model, preset, args, p_fail_sweep, finished)
        print(f"\nTables written to {output}/")
        return
    seeds = evaluation.seed_range(seed, episodes)
    progress_bar = sys.stderr.isatty() and not args.no_progress
    policy_kwargs: dict[str, Any] = dict(
        n_episodes=episodes, seed=seed, config=config, deterministic=not args.stochastic, progress_bar=progress_bar
    )
    frames = [evaluation.evaluate_conditions(model, conditions=evaluation.CONDITIONS, p_fail=config.p_fail, **policy_kwargs)]
    if baselines:
        for label, planner in (
            ("random", RandomPlanner(config, seed=args.seed)),
            ("lawnmower", LawnmowerPlanner(config)),
            ("frontier", FrontierPlanner(config)),
        ):
            frame = evaluation.evaluate(
                planner, p_fail=config.p_fail, n_episodes=episodes, seed=seed, config=config, progress_bar=progress_bar
            )
            frame["condition"] = label
            frames.append(frame)

    table = pd.concat(frames, ignore_index=True)
    summary = evaluation.summarize(table, by="condition")
    finished("conditions", table, evaluation.to_markdown(summary))
    actions = "sampled" if args.stochastic else "mean"
    title = f"Conditions (p_f = {config.p_fail}, {episodes} episodes each, episode {seeds}, {actions} actions)"
    _print_table(title, evaluation.to_markdown(summary))
    if p_fail_sweep:
        sweep = evaluation.evaluate_p_fail_sweep(model, p_fails=preset.p_fails, **policy_kwargs)
        sweep_summary = evaluation.summarize(sweep, by="p_fail")
        finished("p_fail_sweep", sweep, evaluation.to_markdown(sweep_summary))
        _print_table(f"p_f sweep (proposed, episode {seeds}, {actions} actions)", evaluation.to_markdown(sweep_summary))
    print(f"\nTables written to {output}/")


def _evaluate_adapted(model, preset: Preset, args: argparse.Namespace, p_fail_sweep: bool, finished) -> None:
    """The conditions (and the p_f sweep) on the adapted env of ``preset``, in the env's own metrics: mean episode
    return, length, and for a registered env its metrics (simple_spread: ``final_landmarks_covered``,
    ``sum_collisions``), each as mean ± std across episodes."""
    from sb3_latentswarm.evaluation.adapted import evaluate_adapted_conditions, summarize_adapted

    env, config, episodes, seed = preset.env, preset.config, preset.eval_episodes, eval_seed(args)
    assert env is not None
    settings: dict[str, Any] = dict(n_episodes=episodes, seed=seed, deterministic=not args.stochastic)
    actions = "sampled" if args.stochastic else "mean"
    where = f"{env.name}, {episodes} episodes each, episode {evaluation.seed_range(seed, episodes)}, {actions} actions"
    table = evaluate_adapted_conditions(model, env, config, evaluation.CONDITIONS, **settings)
    summary = summarize_adapted(table)
    finished("conditions", table, evaluation.to_markdown(summary))
    _print_table(f"Conditions (p_f = {config.p_fail}, link model {config.link_model}, {where})",
                 evaluation.to_markdown(summary))
    if p_fail_sweep:
        frames = [evaluate_adapted_conditions(model, env, config, ("proposed",), p_fail=p, **settings) for p in preset.p_fails]
        sweep = pd.concat(frames, ignore_index=True)
        sweep_summary = summarize_adapted(sweep, by="p_fail")
        finished("p_fail_sweep", sweep, evaluation.to_markdown(sweep_summary))
        _print_table(f"p_f sweep (proposed, {where})", evaluation.to_markdown(sweep_summary))


def _print_table(title: str, markdown: str) -> None:
    print(f"\n### {title}\n")
    print(markdown)


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _evaluation_record(
    preset: Preset,
    args: argparse.Namespace,
    model_path: str | Path | None = None,
    p_fail_sweep: bool | None = None,
    baselines: bool | None = None,
) -> dict[str, Any]:
    """What an evaluation is made from: the shared :data:`RECORD_IDENTITY` and, per table, its own inputs."""
    model_path = model_path if model_path is not None else args.model
    p_fail_sweep = bool(getattr(args, "p_fail_sweep", False)) if p_fail_sweep is None else p_fail_sweep
    baselines = (not getattr(args, "no_baselines", False)) if baselines is None else baselines
    episodes = preset.eval_episodes
    conditions = list(evaluation.CONDITIONS) + (["random", "lawnmower", "frontier"] if baselines else [])
    requested: dict[str, Any] = {"conditions": {"conditions": conditions, "p_fail": preset.config.p_fail}}
    if p_fail_sweep:
        requested["p_fail_sweep"] = {"conditions": ["proposed"], "p_fails": list(preset.p_fails)}
    return {
        "model": str(model_path),
        "model_sha256": file_sha256(model_path),
        "preset": preset.name,
        "config": preset.config.to_dict(),
        "env": None if preset.env is None else preset.env.to_dict(),
        "episodes": episodes,
        "seed": args.seed,
        "env_seeds": [eval_seed(args), eval_seed(args) + episodes - 1],
        "actions": "sampled" if args.stochastic else "mean",
        "requested": requested,
        "tables": {},
        "sb3_latentswarm": __version__,
    }


def _evaluation_conflict(folder: Path, record: dict[str, Any]) -> str | None:
    """Why ``folder``'s tables cannot sit beside those of ``record`` (``None``: they can).

    Tables without a record, a record of another model file, config, episodes, seeds or actions, or a table this
    evaluation would rewrite from other inputs are conflicts. Tables of the same model and settings are kept.
    """
    present = [name for name in EVALUATION_TABLES if (folder / f"{name}.csv").exists()]
    if not present:
        return None
    path = folder / EVALUATION_RECORD
    if not path.exists():
        return f"it holds {', '.join(f'{n}.csv' for n in present)} without an {EVALUATION_RECORD} saying what they are"
    try:
        recorded = read_json(path)
    except (OSError, ValueError) as error:  # read_json's message names the file
        return f"{error}; remove it or pass another --output"
    if not isinstance(recorded, dict):
        return f"its {path} must hold a JSON object (an evaluation record); remove it or pass another --output"
    differ = [key for key in RECORD_IDENTITY if recorded.get(key) != record[key]]
    if differ:
        return f"its tables were made with other settings: {', '.join(differ)} (see its {EVALUATION_RECORD})"
    tables = recorded.get("tables") or {}
    unrecorded = [name for name in present if name not in tables]
    if unrecorded:
        return f"{', '.join(unrecorded)}.csv is not recorded in its {EVALUATION_RECORD} (an interrupted or older evaluation)"
    changed = [name for name in record["requested"] if name in tables and tables[name] != record["requested"][name]]
    if changed:
        return f"its {', '.join(changed)} table was made from other inputs (see its {EVALUATION_RECORD})"
    return None


def _check_evaluation_folder(folder: Path, record: dict[str, Any]) -> dict[str, Any]:
    """The record to write into ``folder``: ``record`` with the folder's other complete tables of the same evaluation.

    :raise ValueError: naming the folder and what differs when it holds another evaluation's tables
    """
    conflict = _evaluation_conflict(folder, record)
    if conflict:
        raise ValueError(
            f"{folder} holds the tables of another evaluation: {conflict}. Pass an empty or new --output (tables are "
            f"never mixed or overwritten by another model's)"
        )
    path = folder / EVALUATION_RECORD
    kept = read_json(path).get("tables", {}) if path.exists() else {}
    kept = {name: inputs for name, inputs in kept.items() if (folder / f"{name}.csv").exists()}
    return {**record, "tables": {name: inputs for name, inputs in kept.items() if name not in record["requested"]}}


def _evaluation_folder(args: argparse.Namespace, record: dict[str, Any]) -> Path:
    """``--output``, or ``evaluation/`` next to the model (``runs/evaluate/<model folder>/evaluation/`` for a model
    under ``docs/results/``, so that evaluating a committed model leaves the repository clean); never a folder with
    tables of another evaluation.

    Without ``--output``, an ``evaluation/`` that holds other tables is kept and this evaluation goes to
    ``evaluation-HASH/`` (HASH: of what it is made from), and says so; an ``--output`` that holds other tables is an
    error naming the folder and what differs.
    """
    if args.output:
        folder = Path(args.output)
        _check_evaluation_folder(folder, record)
        return folder
    model_folder = Path(args.model).resolve().parent
    if "docs" in model_folder.parts and "results" in model_folder.parts:  # a committed result: keep the tree clean
        folder = Path("runs") / "evaluate" / model_folder.name / "evaluation"
        print(f"{args.model} is a committed result; writing this evaluation to {folder} (choose with --output)")
    else:
        folder = model_folder / "evaluation"
    if _evaluation_conflict(folder, record):
        identity = {key: record[key] for key in (*RECORD_IDENTITY, "requested")}
        digest = hashlib.sha1(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:8]
        reason = _evaluation_conflict(folder, record)
        folder = folder.with_name(f"evaluation-{digest}")
        print(f"{folder.parent / 'evaluation'} holds another evaluation's tables ({reason}); writing to {folder}")
    return folder
