"""One trial of a sweep: train one (variant, training seed, grid point), save the model, evaluate it on held-out seeds.

This module needs no Ray: :func:`train_and_evaluate` takes a ``report`` function, which the Ray Tune trainable of
:mod:`sb3_latentswarm.experiments.sweep` sets to ``ray.tune.report``.

Seeds. Training seed ``k`` seeds the algorithm with ``k`` and the env copies with ``k * n_envs + c`` (``c`` the copy
index), so the copies of different training seeds never share a reset seed. Evaluation episode ``e`` uses env seed
``eval_seed + e`` (default :data:`EVAL_SEED_BASE` = 1,000,000), disjoint from every training seed, and the same for
every trial and cell: the variants are compared on the same maps and start positions (common random numbers).
"""

from __future__ import annotations

import math
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from stable_baselines3.common.callbacks import BaseCallback

import sb3_latentswarm.evaluation as evaluation
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.presets import Preset, get_preset
from sb3_latentswarm.runs.run import RunHooks
from sb3_latentswarm.utils.atomic import atomic_path, json_values, read_json, write_json
from sb3_latentswarm.utils.seeding import training_env_seed, warm_start_seed

if TYPE_CHECKING:
    from sb3_latentswarm.envs.adapted_env import AdaptedEnv

VARIANTS = ("proposed", "no_comm", "zero_substitute", "hold_last", "independent")
"""The learners a sweep trains: LatentSwarmPPO (``proposed``), the same trained without links (``no_comm``), the same
trained with zeros (``zero_substitute``) or the last received message (``hold_last``) in place of the predicted message
during dropout (so that its policy learns to read that substitute: the fair "no predictor" learners), and independent
RecurrentPPO."""
TRAINING_SUBSTITUTES = {"zero_substitute": "zero", "hold_last": "hold_last"}
"""``LatentSwarmPolicy.message_substitute`` of the variants trained with another substitute than the predictor."""
EVAL_SEED_BASE = evaluation.HELD_OUT_SEED
"""First env seed of the evaluation episodes (training env seeds stay below it)."""
PROGRESS_COLUMNS = ("agent_steps", "episode_reward", "coverage", "collisions")
"""The columns of a trial's ``progress.csv`` rows (:class:`TuneProgress`), besides the trial's labels."""
SCORE_METRICS = ("coverage", "collisions", "steps_to_90", "reached_90")
"""Per-run scores of an evaluation cell on the swarm env: means over its episodes (``steps_to_90`` over the episodes
that reached 90 % coverage, NaN if none did; ``reached_90`` is the percentage that did). On an adapted env the scores
are the env's own metrics (:func:`score_metrics`)."""


def score_metrics(episodes: pd.DataFrame) -> tuple[str, ...]:
    """The per-run scores of ``episodes``: :data:`SCORE_METRICS` on the swarm env; on an adapted env (rows of
    :func:`~sb3_latentswarm.evaluation.adapted.evaluate_adapted_conditions`) the mean episode ``return`` and every
    ``final_<name>`` / ``sum_<name>`` metric of the env (simple_spread: ``final_landmarks_covered``,
    ``sum_collisions``, ...)."""
    if "coverage" in episodes.columns:
        return SCORE_METRICS
    return ("return", *(c for c in episodes.columns if c.startswith(("final_", "sum_"))))


@dataclass(frozen=True)
class EvalSet:
    """A named evaluation cell family: env config overrides, evaluated under some test-time conditions.

    :param name: the ``eval_set`` column of the output tables
    :param overrides: :class:`~sb3_latentswarm.SwarmConfig` fields replaced in the trial's env config (``p_fail``
        included; a condition still sets its own ``link_mode``)
    :param conditions: the conditions of :mod:`sb3_latentswarm.evaluation` to run; ``None``: every condition it
        knows, :func:`all_conditions` (read when the trial runs, so new conditions join automatically)
    """

    name: str
    overrides: dict[str, Any] = field(default_factory=dict)
    conditions: tuple[str, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "overrides": dict(self.overrides), "conditions": self.conditions and list(self.conditions)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EvalSet:
        conditions = data.get("conditions")
        return cls(data["name"], dict(data.get("overrides") or {}), tuple(conditions) if conditions else None)


def all_conditions() -> tuple[str, ...]:
    """Every test-time condition: Table I's five, then the extensions of :mod:`sb3_latentswarm.evaluation`."""
    return evaluation.CONDITIONS + evaluation.EXTRA_CONDITIONS


def default_conditions(config: SwarmConfig) -> tuple[str, ...]:
    """The conditions of a cell that names none: :func:`all_conditions`, without ``full_comm_in_range`` where the
    link model has no range (``link_model="outage"``: every link is "in range", so the row would repeat
    ``full_comm``'s)."""
    if config.link_model == "outage":
        return tuple(name for name in all_conditions() if name != "full_comm_in_range")
    return all_conditions()


def default_eval_sets(preset: Preset) -> list[EvalSet]:
    """Table I: every condition (:func:`all_conditions`) at the preset's p_f (``table1``), and the proposed condition at
    each p_f of the preset's sweep (``p_fail=0``, ``p_fail=0.05``, ...)."""
    return [EvalSet("table1")] + [EvalSet(f"p_fail={p:g}", {"p_fail": p}, ("proposed",)) for p in preset.p_fails]


def trial_preset(
    preset_name: str, overrides: dict[str, Any], grid_point: dict[str, Any], env: AdaptedEnv | None = None
) -> Preset:
    """The preset of a trial: the named preset on the sweep's adapted env (``--env``, if any), with the sweep's
    ``--set`` overrides, then its grid point."""
    return get_preset(preset_name).with_env(env).with_overrides(**{**overrides, **grid_point})


def grid_labels(grid_point: dict[str, Any]) -> dict[str, Any]:
    """The grid point as table columns, ``grid.<name>``: apart from the evaluation's own columns (``p_fail`` is also
    the p_f of an evaluation cell)."""
    return {f"grid.{name}": value for name, value in grid_point.items()}


def conditions_for(variant: str, conditions: Sequence[str]) -> list[str]:
    """The conditions a variant can be evaluated under: the independent learner has no predictor or memory to switch
    off, so it runs only the conditions that change the links alone."""
    if variant != "independent":
        return list(conditions)
    return [c for c in conditions if not evaluation.CONDITION_TABLE[c].switches_policy]


def variant_algo_kwargs(variant: str, algo_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``LatentSwarmPPO`` keyword arguments of ``variant``: the preset's, with the variant's training substitute."""
    if variant not in TRAINING_SUBSTITUTES:
        return dict(algo_kwargs)
    policy_kwargs = {**algo_kwargs.get("policy_kwargs", {}), "message_substitute": TRAINING_SUBSTITUTES[variant]}
    return {**algo_kwargs, "policy_kwargs": policy_kwargs}


def training_config(variant: str, preset: Preset) -> SwarmConfig:
    """The env a variant trains on: the preset's, with every link down for ``no_comm`` (which is evaluated on the same
    env as the others)."""
    return preset.config.replace(link_mode="none") if variant == "no_comm" else preset.config


def training_settings(variant: str, preset: Preset) -> dict[str, Any]:
    """What decides how a trial trains, as ``trial.json`` records it: ``train_config`` (``SwarmConfig.to_dict``),
    ``algo_kwargs`` (of ``LatentSwarmPPO``, or of the ``independent`` baseline's ``RecurrentPPO``) and ``n_envs``.
    JSON types (lists, not tuples), so that a record read back compares equal."""
    if variant == "independent":
        algo_kwargs = preset.independent_ppo_kwargs()
    else:
        algo_kwargs = variant_algo_kwargs(variant, preset.algo_kwargs)
    config = training_config(variant, preset).to_dict()
    return json_values({"train_config": config, "algo_kwargs": algo_kwargs, "n_envs": preset.n_envs})


class TuneProgress(BaseCallback):
    """Reports training progress after every rollout: agent-steps, mean episode return, coverage and collisions of
    the episodes finished since the last report (coverage in %, NaN when none finished).

    :param report: called with the metrics dict (``ray.tune.report`` in a sweep)
    """

    def __init__(self, report: Callable[[dict[str, float]], None] | None = None, swarm_metrics: bool = True):
        super().__init__()
        self.report = report
        self.swarm_metrics = swarm_metrics
        """Whether ``report`` gets coverage and collisions (the swarm env's); an adapted env has neither, so its rows
        keep them as NaN and the report (Ray Tune's status table) leaves them out."""
        self.rows: list[dict[str, float]] = []
        self._summaries: list[dict[str, Any]] = []

    def _on_step(self) -> bool:
        # every slot of a finished swarm carries its summary: a swarm counts once per agent, the same weight for all
        self._summaries.extend(info["swarm_summary"] for info in self.locals["infos"] if "swarm_summary" in info)
        return True

    def _on_rollout_end(self) -> None:
        returns = [info["r"] for info in self.model.ep_info_buffer or ()]
        row = {
            "agent_steps": float(self.num_timesteps),
            "episode_reward": float(np.mean(returns)) if returns else math.nan,
            "coverage": 100.0 * float(np.mean([s["coverage"] for s in self._summaries])) if self._summaries else math.nan,
            "collisions": float(np.mean([s["collisions"] for s in self._summaries])) if self._summaries else math.nan,
        }
        self._summaries.clear()
        self.rows.append(row)
        if self.report is not None:
            self.report(row if self.swarm_metrics else {k: row[k] for k in ("agent_steps", "episode_reward")})


def evaluate_sets(
    model: Any,
    variant: str,
    config: SwarmConfig,
    eval_sets: Sequence[EvalSet],
    n_episodes: int,
    eval_seed: int = EVAL_SEED_BASE,
    deterministic: bool = True,
    env: AdaptedEnv | None = None,
) -> pd.DataFrame:
    """Per-episode rows (:data:`~sb3_latentswarm.evaluation.EPISODE_COLUMNS` plus ``eval_set``) of ``model`` in every
    cell of ``eval_sets``, all on the env seeds ``eval_seed .. eval_seed + n_episodes - 1``; on the adapted env ``env``
    the rows of :func:`~sb3_latentswarm.evaluation.adapted.evaluate_adapted_conditions` (the env's own metrics)."""
    frames = []
    for eval_set in eval_sets:
        cell_config = config.replace(**eval_set.overrides)
        conditions = conditions_for(variant, eval_set.conditions or default_conditions(cell_config))
        if not conditions:
            continue
        if env is not None:
            from sb3_latentswarm.evaluation.adapted import evaluate_adapted_conditions

            frame = evaluate_adapted_conditions(model, env, cell_config, conditions,
                                                n_episodes=n_episodes, seed=eval_seed, deterministic=deterministic)
            frames.append(frame.assign(eval_set=eval_set.name))
            continue
        frame = evaluation.evaluate_conditions(
            model,
            conditions=conditions,
            p_fail=None,  # the cell's config carries p_f (the trial's, or the set's override)
            n_episodes=n_episodes,
            seed=eval_seed,
            config=cell_config,
            deterministic=deterministic,
        )
        frames.append(frame.assign(eval_set=eval_set.name))
    return pd.concat(frames, ignore_index=True)


def run_scores(episodes: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """One row per group ``by`` (a run in a cell) with its :func:`score_metrics`, means over the group's episodes, and
    ``episodes``, their number."""
    grouped = episodes.groupby(list(by), sort=False, dropna=False)
    if "coverage" not in episodes.columns:  # an adapted env: its own metrics
        metrics = {name: (name, "mean") for name in score_metrics(episodes)}
        return grouped.agg(**metrics, episodes=("return", "size")).reset_index()
    scores = grouped.agg(
        coverage=("coverage", "mean"),
        collisions=("collisions", "mean"),
        steps_to_90=("steps_to_90", "mean"),  # pandas skips NaN: the mean over the episodes that reached 90 %
        reached_90=("steps_to_90", lambda steps: 100.0 * steps.notna().mean()),
        episodes=("coverage", "size"),
    )
    return scores.reset_index()


def finished_trial_dirs(output: Path) -> list[Path]:
    """The complete trial folders of the sweep in ``output``: ``trials/<trial_id>/`` with its ``trial.json`` (not the
    hidden ``.<trial_id>.partial`` folders of an interrupted copy)."""
    paths = (output / "trials").glob("*/trial.json")
    return sorted(path.parent for path in paths if not path.parent.name.startswith("."))


def _trial_identity(trial: dict[str, Any]) -> dict[str, Any]:
    """What a trial's checkpoint must match to be continued: its id, variant, seed, grid point and the sweep spec."""
    keys = ("trial_id", "variant", "train_seed", "grid_point", "spec")
    identity = {key: trial[key] for key in keys[:-1]} | {"spec": trial["spec"].to_dict()}
    return json_values(identity)


def _warm_start_record(sweep: str, earlier_dir: Path, progress: TuneProgress) -> dict[str, Any]:
    """Start ``progress`` with the earlier trial's rows (``earlier_dir``, a trial of the sweep folder ``sweep``);
    return ``trial.json``'s ``warm_start`` entry."""
    earlier = read_json(earlier_dir / "trial.json")
    rows = pd.read_csv(earlier_dir / "progress.csv")
    progress.rows = rows[[c for c in PROGRESS_COLUMNS if c in rows.columns]].to_dict("records")
    return {
        "sweep": sweep,
        "agent_steps": int(earlier["trained_agent_steps"]),
        "train_seconds": earlier.get("train_seconds"),
        "commit": earlier.get("commit"),
    }


class _TrialHooks(RunHooks):
    """A trial's part of the run: Tune progress (kept in every checkpoint with the warm-start record) and the
    evaluation cells, written as ``episodes.csv``."""

    def __init__(self, progress: TuneProgress, warm_started: dict[str, Any] | None, evaluate: Callable[[Any], pd.DataFrame]):
        self.progress, self.warm_started, self._evaluate = progress, warm_started, evaluate
        self.episodes: pd.DataFrame | None = None
        self.eval_seconds = 0.0

    def callbacks(self) -> list[BaseCallback]:
        return [self.progress]

    def extra_state(self) -> dict[str, Any]:
        return {"progress_rows": self.progress.rows, "warm_start": self.warm_started}

    def evaluate(self, run: Any, result: Any) -> None:
        start = time.perf_counter()
        self.episodes = self._evaluate(result.model)
        self.eval_seconds = time.perf_counter() - start


def train_and_evaluate(
    trial: dict[str, Any],
    output: Path,
    report: Callable[[dict[str, float]], None] | None = None,
    device: str = "auto",
    resume: bool = True,
    save_freq: int | None = None,
    keep_checkpoints: int = 2,
) -> dict[str, Any]:
    """Train the trial's variant, save ``model.zip``, evaluate it, and write its raw results into ``output``: one
    :class:`~sb3_latentswarm.runs.run.Run`, as ``sb3-latentswarm train`` is.

    LatentSwarmPPO variants (all but ``independent``) write checkpoints into ``output/checkpoints/`` while they
    train; with ``resume`` (the default) a rerun into the same ``output`` continues from the newest one, exactly where
    it stopped (same parameters as an uninterrupted trial, see :mod:`sb3_latentswarm.runs.checkpoints`). The
    ``independent`` RecurrentPPO baseline has no checkpoints and restarts from zero. SIGINT / SIGTERM (in the main
    thread) write a checkpoint and raise :class:`~sb3_latentswarm.runs.run.RunStopped`.

    :param trial: ``trial_id``, ``variant``, ``train_seed``, ``grid_point``, the sweep's
        :class:`~sb3_latentswarm.experiments.spec.SweepSpec` ``spec`` and ``commit``; see
        :func:`sb3_latentswarm.experiments.sweep.plan_trials`
    :param output: the trial's work folder (keep it across reruns to resume)
    :param report: called with the progress metrics after every rollout
    :param resume: continue from the newest checkpoint in ``output`` (``False``: an existing one is an error)
    :param save_freq: agent-steps between checkpoints (default: about 5 % of the budget, whole updates; 0: only when
        stopped and at the end)
    :param keep_checkpoints: how many checkpoints to keep
    :return: the trial record (also written as ``trial.json``); ``episodes.csv`` holds one row per evaluation
        episode, ``progress.csv`` one row per rollout
    :raise sb3_latentswarm.runs.checkpoints.CheckpointError: for a checkpoint of another trial in ``output``, or any
        checkpoint when ``resume`` is ``False``
    """
    import dataclasses

    from sb3_latentswarm.experiments.run_record import machine_summary
    from sb3_latentswarm.runs.checkpoints import CheckpointError
    from sb3_latentswarm.runs.run import Run, RunSpec

    spec = trial["spec"]
    variant, train_seed, grid_point = trial["variant"], int(trial["train_seed"]), dict(trial["grid_point"])
    preset = spec.point_preset(grid_point)
    depth = spec.warm_start_depth  # a continued trial draws new episodes and random numbers (warm_start_seed)
    env_seed = warm_start_seed(training_env_seed(train_seed, preset.n_envs), depth)
    train_preset = dataclasses.replace(
        preset, config=training_config(variant, preset), algo_kwargs=variant_algo_kwargs(variant, preset.algo_kwargs)
    )
    progress = TuneProgress(report, swarm_metrics=spec.env is None)
    output = Path(output)
    identity = _trial_identity(trial)
    earlier_dir = Path(spec.warm_start) / "trials" / trial["trial_id"] if spec.warm_start is not None else None
    with Run(output) as run:
        warm_started: dict[str, Any] | None = None  # the earlier sweep's trial this one continues (spec.warm_start)
        if run.start is not None and resume:
            stored = run.state or {}
            if stored["settings"] != identity:
                differ = sorted(k for k in identity if stored["settings"].get(k) != identity[k])
                raise CheckpointError(
                    f"{run.start} is a checkpoint of another trial (it differs in {differ}); use another folder"
                )
            progress.rows = list(stored["extra"].get("progress_rows", []))
            warm_started = stored["extra"].get("warm_start")
        elif earlier_dir is not None:
            warm_started = _warm_start_record(spec.warm_start, earlier_dir, progress)

        def evaluate(model: Any) -> pd.DataFrame:
            return evaluate_sets(
                model, variant, preset.config, spec.eval_sets, spec.eval_episodes, spec.eval_seed, spec.deterministic,
                env=preset.env,
            )

        hooks = _TrialHooks(progress, warm_started, evaluate)
        result = run.train(
            RunSpec(
                train_preset,
                output,
                seed=warm_start_seed(train_seed, depth),  # train_seed for a new model (depth 0)
                env_seed=env_seed,
                learner="independent_ppo" if variant == "independent" else "latent_swarm_ppo",
                device=device,
                resume=resume and variant != "independent",
                warm_start=None if earlier_dir is None else earlier_dir / "model.zip",
                save_freq=save_freq,
                keep_checkpoints=keep_checkpoints,
                settings=identity,
                run_files=False,
            ),
            hooks,
        )
    episodes = hooks.episodes
    assert episodes is not None
    labels = {"trial_id": trial["trial_id"], "variant": variant, "train_seed": train_seed, **grid_labels(grid_point)}
    episodes = episodes.assign(**labels)
    with atomic_path(output / "episodes.csv") as tmp:
        episodes.to_csv(tmp, index=False)
    with atomic_path(output / "progress.csv") as tmp:
        pd.DataFrame(progress.rows).assign(**labels).to_csv(tmp, index=False)

    record = {
        **labels,
        "grid_point": grid_point,
        "preset": spec.preset,
        "commit": trial["commit"],
        "machine": machine_summary(result.device),
        "node": platform.node(),
        **training_settings(variant, preset),  # train_config, algo_kwargs, n_envs
        "eval_config": preset.config.to_dict(),
        "training_env_seeds": [env_seed, env_seed + preset.n_envs - 1],
        "eval_env_seeds": [spec.eval_seed, spec.eval_seed + spec.eval_episodes - 1],
        "budget_agent_steps": preset.total_timesteps,
        "trained_agent_steps": result.trained_steps,
        "resumed_from_agent_steps": result.resumed_from,
        "warm_start": warm_started,
        "train_seconds": result.train_seconds,
        "eval_seconds": hooks.eval_seconds,
        "eval_sets": [s.to_dict() for s in spec.eval_sets],
        "deterministic": spec.deterministic,
        # the first cell's proposed-condition means, for Tune's console (an adapted env: its return)
        "eval_coverage": float(episodes["coverage"].iloc[: spec.eval_episodes].mean()) if preset.env is None else None,
        "eval_return": float(episodes["episode_return" if preset.env is None else "return"].iloc[: spec.eval_episodes]
                             .mean()),
        "env": None if preset.env is None else preset.env.to_dict(),
    }
    write_json(output / "trial.json", json_values(record))
    return record


__all__ = [
    "EVAL_SEED_BASE",
    "all_conditions",
    "SCORE_METRICS",
    "VARIANTS",
    "EvalSet",
    "PROGRESS_COLUMNS",
    "TRAINING_SUBSTITUTES",
    "TuneProgress",
    "conditions_for",
    "default_eval_sets",
    "evaluate_sets",
    "finished_trial_dirs",
    "grid_labels",
    "run_scores",
    "score_metrics",
    "train_and_evaluate",
    "trial_preset",
    "training_env_seed",
    "training_config",
    "training_settings",
    "variant_algo_kwargs",
]
