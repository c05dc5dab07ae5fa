"""``run_sweep``: training seeds x variants x grid points as Ray Tune trials, then the across-seed tables.

Layout of ``output`` (default ``runs/sweeps/<preset>/``)::

    sweep.json                 what was asked (preset, variants, seeds, grid, overrides, evaluation cells)
    trials/<trial_id>/         one finished trial: model.zip, trial.json (config, commit, machine), episodes.csv
                               (one row per evaluation episode), progress.csv (one row per rollout)
    ray/                       Ray Tune's experiment folders (its checkpoints are where finished trials come from)
    episodes.csv, scores.csv   all trials' episodes; one row per trial and evaluation cell (the runs' scores)
    aggregate.csv, aggregate.md, *.png, run.md    the across-seed intervals (see :mod:`.report`)

A trial is finished when ``trials/<trial_id>/trial.json`` exists: it is copied there, complete, from the checkpoint
the trial reports to Tune when it is done. ``resume=True`` runs only the trials that are not finished.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.experiments.trial import (
    EVAL_SEED_BASE,
    VARIANTS,
    EvalSet,
    all_conditions,
    default_eval_sets,
    finished_trial_dirs,
    train_and_evaluate,
    training_env_seed,
    trial_preset,
)
from sb3_latentswarm.presets import get_preset, override_targets

_CONFIG_FIELDS = tuple(f.name for f in dataclasses.fields(SwarmConfig) if f.name != "extra")


def _check_fields(names: Sequence[str], what: str) -> None:
    """Evaluation cells change the env only: their names must be SwarmConfig fields."""
    unknown = [name for name in names if name not in _CONFIG_FIELDS]
    if unknown:
        raise ValueError(f"{what}: unknown SwarmConfig field(s) {unknown}; fields: {', '.join(sorted(_CONFIG_FIELDS))}")


def _check_settings(names: Sequence[str], what: str) -> None:
    """Training settings (``--set``, ``--grid``) may be anything ``Preset.with_overrides`` routes."""
    targets = override_targets()
    unknown = [name for name in names if not any(name in settings for settings in targets.values())]
    if unknown:
        valid = "; ".join(f"{target}: {', '.join(settings)}" for target, settings in targets.items())
        raise ValueError(f"{what}: unknown setting(s) {unknown}; valid settings are {valid}")


def trial_id(variant: str, train_seed: int, grid_point: dict[str, Any]) -> str:
    """``proposed-seed0`` or ``proposed-seed0-p_fail=0.5``: a folder name (characters outside ``[\\w.=-]`` become ``_``)."""
    parts = [variant, f"seed{train_seed}", *(f"{name}={value}" for name, value in grid_point.items())]
    return re.sub(r"[^\w.=-]", "_", "-".join(parts))


def plan_trials(spec: dict[str, Any], commit: str) -> list[dict[str, Any]]:
    """Every (variant, training seed, grid point) of ``spec``, as the trial dicts :func:`train_and_evaluate` takes."""
    grid = spec["grid"]
    points = [dict(zip(grid, values)) for values in itertools.product(*grid.values())]
    return [
        {
            "trial_id": trial_id(variant, seed, point),
            "variant": variant,
            "train_seed": seed,
            "grid_point": point,
            "spec": spec,
            "commit": commit,
        }
        # seed-major: an interrupted sweep has every variant at its first seeds, not all seeds of the first variant
        for point in points
        for seed in spec["seeds"]
        for variant in spec["variants"]
    ]


def make_spec(
    preset: str,
    seeds: int,
    variants: Sequence[str] = VARIANTS,
    grid: dict[str, Sequence[Any]] | None = None,
    overrides: dict[str, Any] | None = None,
    eval_sets: Sequence[EvalSet] | None = None,
    extra_eval_sets: Sequence[EvalSet] = (),
    eval_episodes: int | None = None,
    eval_seed: int = EVAL_SEED_BASE,
    deterministic: bool = True,
) -> dict[str, Any]:
    """Validate a sweep's arguments (see :func:`run_sweep`) and return its JSON-able spec; nothing is trained."""
    get_preset(preset)  # an unknown name fails here
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"--seeds must be an int >= 1, got {seeds!r}")
    variants = list(dict.fromkeys(variants))
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown or not variants:
        raise ValueError(f"--variant: unknown variant(s) {unknown or variants}; choose from {list(VARIANTS)}")
    grid = {name: list(values) for name, values in (grid or {}).items()}
    overrides = dict(overrides or {})
    _check_settings(list(grid), "--grid")
    _check_settings(list(overrides), "--set")
    empty = [name for name, values in grid.items() if not values]
    if empty:
        raise ValueError(f"--grid: no values for {empty}")
    base = trial_preset(preset, overrides, {})
    if eval_episodes is None:
        eval_episodes = base.eval_episodes
    if isinstance(eval_episodes, bool) or not isinstance(eval_episodes, int) or eval_episodes < 1:
        raise ValueError(f"--eval-episodes must be an int >= 1, got {eval_episodes!r}")
    eval_sets = [*(default_eval_sets(base) if eval_sets is None else eval_sets), *extra_eval_sets]
    names = [s.name for s in eval_sets]
    if len(set(names)) != len(names):
        raise ValueError(f"evaluation set names must be unique, got {names}")
    for eval_set in eval_sets:
        _check_fields(list(eval_set.overrides), f"--eval-set {eval_set.name}")
        for condition in eval_set.conditions or ():
            if condition not in all_conditions():
                raise ValueError(
                    f"--eval-set {eval_set.name}: unknown condition {condition!r}; allowed: {list(all_conditions())}"
                )
    # build every trial's config and every evaluation cell's config now, so a bad value fails before any training
    presets = [trial_preset(preset, overrides, dict(zip(grid, values))) for values in itertools.product(*grid.values())]
    for eval_set in eval_sets:
        for point_preset in presets:
            point_preset.config.replace(**eval_set.overrides)
    largest_training_seed = training_env_seed(seeds, max(p.n_envs for p in presets))
    if eval_seed < largest_training_seed:
        raise ValueError(
            f"eval_seed={eval_seed} overlaps the training env seeds (up to {largest_training_seed - 1}); use a larger one"
        )
    return {
        "preset": preset,
        "variants": variants,
        "seeds": list(range(seeds)),
        "grid": grid,
        "overrides": overrides,
        "eval_sets": [s.to_dict() for s in eval_sets],
        "eval_episodes": eval_episodes,
        "eval_seed": eval_seed,
        "deterministic": deterministic,
    }


def check_address(address: str) -> None:
    """Fail fast (``ValueError``) when ``address`` (``HOST:PORT``, ``ray://HOST:PORT`` or ``auto``) answers nothing."""
    if address == "auto":
        return  # ray.init finds the local cluster or raises ConnectionError at once
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--address must be HOST:PORT, ray://HOST:PORT or auto, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=5.0).close()
    except OSError as error:
        raise ValueError(f"--address {address}: no Ray cluster answers there ({error})") from None


def finished_trials(output: Path) -> set[str]:
    """The ids of the trials whose results are complete in ``output / "trials"``."""
    return {path.name for path in finished_trial_dirs(output)}


def select_trials(trials: list[dict[str, Any]], done: set[str], only: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """The trials still to run, in plan order: not finished, and among ``only`` when it is given."""
    if only is not None:
        ids = [trial["trial_id"] for trial in trials]
        unknown = [trial_id for trial_id in only if trial_id not in ids]
        if unknown or not only:
            raise ValueError(f"--only: unknown trial id(s) {unknown or list(only)}; this sweep's trials are {ids}")
    return [t for t in trials if t["trial_id"] not in done and (only is None or t["trial_id"] in only)]


def _check_output(output: Path, spec: dict[str, Any], resume: bool) -> None:
    saved_path = output / "sweep.json"
    if not saved_path.exists():
        if finished_trials(output):
            raise ValueError(f"--output {output} holds trials but no sweep.json; choose another --output")
        return
    if not resume:
        raise ValueError(f"--output {output} already holds a sweep; pass --resume to continue it, or another --output")
    saved = json.loads(saved_path.read_text())
    differ = sorted(key for key in spec.keys() | saved.keys() if spec.get(key) != saved.get(key))
    if differ:
        raise ValueError(
            f"--resume: this sweep differs from the one in {output} in {differ} "
            f"(saved: { {k: saved.get(k) for k in differ} }); resume with the same arguments, or choose another --output"
        )


def _run_trial_in_tune(config: dict[str, Any], trials: dict[str, dict[str, Any]], threads: int) -> None:
    """The Ray Tune trainable: one trial, progress reported per rollout, results reported as the final checkpoint."""
    import torch
    from ray import tune

    trial = trials[config["trial_id"]]
    torch.set_num_threads(threads)
    work = Path(tempfile.mkdtemp(prefix=f"{trial['trial_id']}-"))
    try:
        record = train_and_evaluate(trial, work, report=tune.report)
        final = {"agent_steps": float(record["trained_agent_steps"]), "eval_coverage": record["eval_coverage"]}
        tune.report(final, checkpoint=tune.Checkpoint.from_directory(str(work)))  # persisted before it returns
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _collect(checkpoint: Any, destination: Path) -> None:
    """Copy a finished trial's checkpoint to ``destination``; the rename makes it appear complete or not at all."""
    partial = destination.with_name(f".{destination.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    checkpoint.to_directory(str(partial))
    shutil.rmtree(destination, ignore_errors=True)
    partial.rename(destination)


def _run_tune(trials: list[dict[str, Any]], output: Path, resources: dict[str, float], verbose: int) -> list[str]:
    """Run ``trials`` on the connected Ray cluster; collect each into ``output/trials`` as it completes.

    :return: the ids of the trials that did not finish (failed, or not run after an interruption)
    """
    from ray import tune

    trials_dir = output / "trials"

    class CollectFinished(tune.Callback):
        def on_trial_complete(self, iteration, trials, trial, **info):
            if trial.checkpoint is not None:
                _collect(trial.checkpoint, trials_dir / trial.config["trial_id"])

    # Tune's config holds only the trial id (its console shows it); the trials travel once, through the object store
    trainable = tune.with_parameters(
        _run_trial_in_tune, trials={trial["trial_id"]: trial for trial in trials}, threads=max(1, int(resources["cpu"]))
    )
    tuner = tune.Tuner(
        tune.with_resources(trainable, resources),
        param_space={"trial_id": tune.grid_search([trial["trial_id"] for trial in trials])},
        tune_config=tune.TuneConfig(
            reuse_actors=True,  # a worker keeps its imports (torch, SB3) from one trial to the next
            trial_name_creator=lambda t: t.config["trial_id"],
            trial_dirname_creator=lambda t: t.config["trial_id"],
        ),
        run_config=tune.RunConfig(
            name=time.strftime("sweep-%Y%m%d-%H%M%S"),
            storage_path=str((output / "ray").resolve()),
            callbacks=[CollectFinished()],
            verbose=verbose,
        ),
    )
    for result in tuner.fit():  # after an interruption, trials that never started have no config
        name = (result.config or {}).get("trial_id")
        if name and result.error is None and result.checkpoint is not None and not (trials_dir / name).exists():
            _collect(result.checkpoint, trials_dir / name)
    finished = finished_trials(output)
    return [trial["trial_id"] for trial in trials if trial["trial_id"] not in finished]


def run_sweep(
    preset: str,
    seeds: int,
    variants: Sequence[str] = VARIANTS,
    grid: dict[str, Sequence[Any]] | None = None,
    overrides: dict[str, Any] | None = None,
    eval_sets: Sequence[EvalSet] | None = None,
    extra_eval_sets: Sequence[EvalSet] = (),
    eval_episodes: int | None = None,
    eval_seed: int = EVAL_SEED_BASE,
    deterministic: bool = True,
    address: str | None = None,
    cpus_per_trial: float = 1.0,
    gpus_per_trial: float = 0.0,
    output: str | Path | None = None,
    resume: bool = False,
    verbose: int = 1,
    only: Sequence[str] | None = None,
) -> Path:
    """Train ``seeds`` training seeds of every variant at every grid point on Ray Tune, evaluate each trained model on
    held-out seeds, and write the per-run scores and the across-seed intervals into ``output``.

    :param preset: a preset name (:data:`sb3_latentswarm.presets.PRESETS`): env, algorithm settings and the budget of
        agent-steps, the same for every variant
    :param seeds: number of training seeds, ``0 .. seeds - 1``
    :param variants: from :data:`VARIANTS`: ``proposed`` (LatentSwarmPPO), ``no_comm`` (LatentSwarmPPO trained with
        ``link_mode="none"``), ``independent`` (RecurrentPPO on each UAV's own observation)
    :param grid: ``{SwarmConfig field: values}``; every combination is a grid point, trained and evaluated with it
    :param overrides: ``{SwarmConfig field: value}`` applied to the preset for every trial
    :param eval_sets: the evaluation cells (default: :func:`default_eval_sets`, Table I's conditions and p_f sweep)
    :param extra_eval_sets: cells added to ``eval_sets``, e.g. ``EvalSet("burst10", {"mean_outage_steps": 10})``
    :param eval_episodes: episodes per cell (default: the preset's), env seeds ``eval_seed ..``
    :param deterministic: evaluate with the mean action (``False``: sampled actions)
    :param address: a running Ray cluster (``HOST:PORT``, ``ray://HOST:PORT``, ``auto``); ``None`` starts Ray here
        with every CPU of this machine
    :param cpus_per_trial: CPUs Ray reserves per trial (its torch threads: the integer part, at least 1)
    :param gpus_per_trial: GPUs Ray reserves per trial (a fraction shares one); with 0, trials train on the CPU
    :param output: result folder (default ``runs/sweeps/<preset>``)
    :param resume: continue the sweep in ``output``: finished trials are kept, not retrained
    :param verbose: Ray Tune's console verbosity (0 silent, 1 status table, 2 also trial results)
    :param only: run only these trial ids (e.g. ``proposed-seed2``); the others stay pending for a later ``resume``.
        Lets the cheap trials go first, or splits one sweep over several machines sharing ``output``
    :return: ``output``
    :raises ValueError: on bad arguments or an unreachable ``address``, before anything is trained
    :raises RuntimeError: when trials failed (the finished ones are aggregated; ``resume=True`` reruns the rest)
    """
    from sb3_latentswarm.common.run_record import git_commit
    from sb3_latentswarm.experiments.report import write_report

    commit = git_commit()
    spec = make_spec(
        preset, seeds, variants, grid, overrides, eval_sets, extra_eval_sets, eval_episodes, eval_seed, deterministic
    )
    if not cpus_per_trial > 0:
        raise ValueError(f"--cpus-per-trial must be > 0, got {cpus_per_trial!r}")
    if not gpus_per_trial >= 0:
        raise ValueError(f"--gpus-per-trial must be >= 0, got {gpus_per_trial!r}")
    output = Path(output or Path("runs") / "sweeps" / preset)
    _check_output(output, spec, resume)
    if address is not None:
        check_address(address)
    trials = plan_trials(spec, commit)
    done = finished_trials(output)
    pending = select_trials(trials, done, only)
    print(f"Sweep on preset {preset!r}: {len(trials)} trials, {len(done)} already finished, {len(pending)} to run now")
    failed: list[str] = []
    if pending:
        import ray

        # Ray starts its workers at nice 15, so trials stall behind any other work on the machine (measured: 30 % of a
        # core each, updates 10x slower, next to two busy processes); a sweep's trials are the work. A cluster keeps
        # the niceness its `ray start` gave it.
        os.environ.setdefault("RAY_worker_niceness", "0")
        try:
            context = ray.init(address=address, include_dashboard=False, configure_logging=False, log_to_driver=verbose > 1)
        except (ConnectionError, RuntimeError) as error:
            raise ValueError(f"--address {address}: cannot connect to Ray ({error})") from None
        output.mkdir(parents=True, exist_ok=True)
        (output / "sweep.json").write_text(json.dumps(spec, indent=2))
        try:
            print(f"Ray: {ray.cluster_resources().get('CPU', 0):g} CPUs at {context.address_info.get('address')}")
            resources = {"cpu": cpus_per_trial, "gpu": gpus_per_trial}
            failed = _run_tune(pending, output, resources, verbose)
        finally:
            ray.shutdown()
    write_report(output, commit)
    if failed:
        raise RuntimeError(f"{len(failed)} trial(s) failed: {failed}; rerun with --resume to retry them")
    return output
