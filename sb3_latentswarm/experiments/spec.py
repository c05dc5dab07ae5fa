"""``SweepSpec``: what a sweep trains and how it evaluates, validated once, saved as ``sweep.json`` and read back.

The spec is the one description of a sweep that every module reads (:mod:`.sweep` plans and runs its trials,
:mod:`.trial` trains and evaluates one, :mod:`.report` writes the tables): a frozen dataclass with a docstring per
field, in the manner of CleanRL's ``Args`` and BenchMARL's experiment config. :meth:`SweepSpec.create` fills in the
defaults from the preset and validates every setting the way the objects that will use it do: each grid point's
:class:`~sb3_latentswarm.SwarmConfig`, vec env and ``LatentSwarmPPO`` arguments and policy are built (without
training), so a value ``LatentSwarmPPO`` or ``SwarmConfig`` would refuse fails here, before Ray starts or any folder
is made.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.adapted_env import AdaptedEnv
from sb3_latentswarm.experiments.trial import (
    EVAL_SEED_BASE,
    VARIANTS,
    EvalSet,
    all_conditions,
    default_eval_sets,
    training_env_seed,
    training_settings,
    trial_preset,
    variant_algo_kwargs,
)
from sb3_latentswarm.presets import Preset, check_setting_names, get_preset
from sb3_latentswarm.utils.atomic import check_real_path, json_values, read_json, write_text
from sb3_latentswarm.utils.checks import check_bool, check_int
from sb3_latentswarm.utils.seeding import warm_start_seed

__all__ = [
    "ADAPTED_DEFAULT_VARIANTS",
    "DEFAULT_VARIANTS",
    "EVALUATION_ONLY_SETTINGS",
    "MAX_GRID_POINTS",
    "MAX_TRIAL_ID_LENGTH",
    "SweepSpec",
    "check_training_settings",
    "trial_id",
]

DEFAULT_VARIANTS = ("proposed", "no_comm", "independent")
"""The variants a sweep trains unless told otherwise (the substitute-trained ones are asked for by name)."""
ADAPTED_DEFAULT_VARIANTS = ("proposed", "no_comm", "zero_substitute", "hold_last")
"""The variants a sweep on an adapted env (``--env``) trains unless told otherwise: the independent baseline is
evaluated on the swarm env only."""
EVALUATION_ONLY_SETTINGS = ("eval_episodes",)
"""Settings that change only the evaluation, not the training: refused as ``--grid`` names (two grid points would
train the same model twice)."""
MAX_GRID_POINTS = 1000
"""Most points of a sweep's ``--grid`` (the product of its value counts); a larger grid is refused at once."""

MAX_TRIAL_ID_LENGTH = 80
"""Longest trial id (a folder name under ``trials/`` and in Ray Tune's experiment folder; file systems allow 255 bytes,
Tune adds its own prefix and suffix)."""
_CONFIG_FIELDS = tuple(f.name for f in dataclasses.fields(SwarmConfig) if f.name != "extra")


def _value_text(value: Any) -> str:
    """A grid value as a trial id shows it: strings as they are, anything else as JSON (``0.1``, ``[-5.0, 0.0]``)."""
    return value if isinstance(value, str) else json.dumps(value, sort_keys=True, default=repr)


def trial_id(variant: str, train_seed: int, grid_point: Mapping[str, Any]) -> str:
    """The folder name of a trial: ``proposed-seed0``, ``proposed-seed0-p_fail=0.5``.

    Characters outside ``[A-Za-z0-9_.=-]`` become ``_``. When that changes the text, or it is longer than
    :data:`MAX_TRIAL_ID_LENGTH`, the id keeps a readable head and ends in ``-`` and 10 hex digits of the SHA-1 of the
    exact trial (variant, seed, grid point), so distinct trials never share an id.
    """
    parts = [variant, f"seed{train_seed}", *(f"{name}={_value_text(value)}" for name, value in grid_point.items())]
    text = "-".join(parts)
    readable = re.sub(r"[^A-Za-z0-9_.=-]", "_", text)
    if readable == text and len(readable) <= MAX_TRIAL_ID_LENGTH:
        return readable
    digest = hashlib.sha1(text.encode()).hexdigest()[:10]
    return f"{readable[: MAX_TRIAL_ID_LENGTH - len(digest) - 1]}-{digest}"


def check_training_settings(preset: Preset, where: str, variants: Sequence[str] = VARIANTS) -> None:
    """Build what a trial builds from ``preset`` (its vec env, ``LatentSwarmPPO``'s argument checks and the policy with
    its optimizer, with each variant's own policy arguments), without training, so every setting is checked by the
    code that uses it. The ``independent`` learner takes its PPO settings from the same arguments
    (:meth:`~sb3_latentswarm.presets.Preset.independent_ppo_kwargs`), so they are checked here too.

    :param where: names the settings in the message (``"--set {...}, --grid point {'p_fail': 0.1}"``)
    :raises ValueError, TypeError: with the setting's own message, prefixed by ``where``
    """
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    variants = [v for v in variants if v != "independent"] or ["proposed"]
    try:
        env = preset.make_env(0)
        try:
            for variant in variants:
                algo_kwargs = variant_algo_kwargs(variant, preset.algo_kwargs)
                model = LatentSwarmPPO("LatentSwarmPolicy", env, device="cpu", _init_setup_model=False, **algo_kwargs)
                model._setup_lr_schedule()  # the policy's optimizer takes the schedule's first value
                model.policy_class(model.observation_space, model.action_space, model.lr_schedule, **model.policy_kwargs)
        finally:
            env.close()
    except AssertionError as error:  # SB3's PPO checks some arguments with assert
        raise ValueError(f"{where}: {error}") from None
    except (TypeError, ValueError) as error:
        raise type(error)(f"{where}: {error}") from None



def _added_later_at_default(recorded: Mapping[str, Any], key: str, value: Any) -> bool:
    """True when ``recorded`` (an earlier ``trial.json``'s ``train_config``) lacks the ``SwarmConfig`` field ``key``,
    added after that trial ran, and this sweep keeps it at its default: an opt-in field's default is the behaviour
    the earlier code had (the house rule for extensions), so the earlier trial trained the same way."""
    if key in recorded:
        return False
    defaults = {f.name: f.default for f in dataclasses.fields(SwarmConfig)}
    return key in defaults and json_values(defaults[key]) == value

@dataclass(frozen=True)
class SweepSpec:
    """A sweep: training seeds x variants x grid points, and the evaluation cells every trained model meets.

    Build it with :meth:`create` (defaults from the preset, every setting validated); ``sweep.json`` holds
    :meth:`to_dict`, and :meth:`load` reads it back.
    """

    preset: str
    """Name of the preset (:data:`sb3_latentswarm.presets.PRESETS`): env, algorithm settings and the budget of
    agent-steps, the same for every variant."""
    variants: tuple[str, ...]
    """The learners to train, from :data:`~.trial.VARIANTS` (``proposed``, ``no_comm``, ``independent``)."""
    seeds: tuple[int, ...]
    """Training seeds ``0 .. K - 1``: seed ``k`` seeds the algorithm with ``k`` and env copy ``c`` with
    ``k * n_envs + c``."""
    grid: dict[str, tuple[Any, ...]] = field(default_factory=dict)
    """Training settings to cross (``--grid``): name -> distinct values; every combination is a grid point."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """Settings changed for every trial (``--set``), any name ``train --set`` takes."""
    eval_sets: tuple[EvalSet, ...] = ()
    """The evaluation cells (``table1``, ``p_fail=...``, the ``--eval-set`` ones), in table order."""
    eval_episodes: int = 10
    """Evaluation episodes per cell and trial (``--eval-episodes``)."""
    eval_seed: int = EVAL_SEED_BASE
    """Env seed of the first evaluation episode; episode ``e`` uses ``eval_seed + e`` (held out from training)."""
    deterministic: bool = True
    """Evaluate with the mean action (``True``) or sampled actions (``--stochastic``)."""
    total_timesteps: int | None = None
    """Training budget of every trial in agent-steps (``--total-timesteps``); ``None``: the preset's."""
    env: AdaptedEnv | None = None
    """The adapted env every trial trains and is evaluated on (``--env``, ``--env-kwargs``); ``None``: the swarm env.
    ``sweep.json`` stores its name and keyword arguments; an entry point read back from it is never imported
    (:meth:`AdaptedEnv.from_dict <sb3_latentswarm.envs.adapted_env.AdaptedEnv.from_dict>`): ``--resume`` names it
    again."""
    warm_start: str | None = None
    """Folder of an earlier sweep (``--warm-start``): each trial continues that sweep's finished model of the same id
    (its weights, optimizer state and agent-step count; SB3's ``load`` + ``learn(reset_num_timesteps=False)``) up to
    :attr:`total_timesteps`, instead of starting from scratch. The earlier sweep must have the same preset and grid, and
    each of its trials must have trained with the settings this sweep's trial resolves to (``trial.json``'s
    ``train_config``, ``algo_kwargs`` and ``n_envs``, so that ``--set`` can restore values a preset has changed since;
    the evaluation may differ); its progress rows open the trial's ``progress.csv``. ``None``: every
    trial starts from a new model."""

    @classmethod
    def create(
        cls,
        preset: str,
        seeds: int,
        *,
        variants: Sequence[str] = DEFAULT_VARIANTS,
        grid: Mapping[str, Sequence[Any]] | None = None,
        overrides: Mapping[str, Any] | None = None,
        eval_sets: Sequence[EvalSet] | None = None,
        extra_eval_sets: Sequence[EvalSet] = (),
        eval_episodes: int | None = None,
        eval_seed: int = EVAL_SEED_BASE,
        deterministic: bool = True,
        total_timesteps: int | None = None,
        warm_start: str | Path | None = None,
        env: AdaptedEnv | None = None,
    ) -> SweepSpec:
        """Validate a sweep's arguments and return its spec; nothing is trained, no file is written.

        :param seeds: number of training seeds K (seeds ``0 .. K - 1``)
        :param eval_sets: the evaluation cells (default: :func:`~.trial.default_eval_sets` of the preset)
        :param extra_eval_sets: cells added after ``eval_sets``
        :param eval_episodes: default ``overrides["eval_episodes"]``, else the preset's
        :param total_timesteps: the budget of every trial in agent-steps, >= 1 (default: the preset's)
        :param warm_start: an earlier sweep's folder whose finished models the trials continue (see :attr:`warm_start`)
        :param env: an adapted env to run on (see :attr:`env`); its learners are LatentSwarmPPO variants only
        :raises ValueError, TypeError: for an unknown name, a grid of more than :data:`MAX_GRID_POINTS` points, a repeated
            or duplicate grid value, an evaluation-only grid
            name, a setting that ``SwarmConfig``, the vec env, ``LatentSwarmPPO`` or its policy refuses, or a
            ``warm_start`` folder that does not hold this sweep's finished trials at a smaller budget
        """
        get_preset(preset)  # an unknown name fails here
        check_int("--seeds", seeds, low=1)
        variants = tuple(dict.fromkeys(variants))
        unknown = [v for v in variants if v not in VARIANTS]
        if unknown or not variants:
            raise ValueError(f"--variant: unknown variant(s) {unknown or list(variants)}; choose from {list(VARIANTS)}")
        if env is not None and "independent" in variants:
            raise ValueError(
                "--variant independent: the independent RecurrentPPO baseline is evaluated on the swarm env only; with "
                f"--env choose from {[v for v in VARIANTS if v != 'independent']}"
            )
        grid_values: dict[str, tuple[Any, ...]] = {name: tuple(values) for name, values in (grid or {}).items()}
        overrides = dict(overrides or {})
        check_setting_names(list(grid_values), "--grid")
        check_setting_names(list(overrides), "--set")
        n_points = math.prod(len(values) for values in grid_values.values())
        if n_points > MAX_GRID_POINTS:
            sizes = " x ".join(f"{len(values)} {name}" for name, values in grid_values.items())
            raise ValueError(f"--grid has {n_points:,} points ({sizes}), more than the limit of {MAX_GRID_POINTS:,}; "
                             f"split it into several sweeps")
        for name, values in grid_values.items():
            if name in EVALUATION_ONLY_SETTINGS:
                raise ValueError(
                    f"--grid {name}: changes the evaluation only, so its grid points would train the same model; "
                    f"use --{name.replace('_', '-')} or --set {name}=N"
                )
            if name in overrides:
                raise ValueError(f"--grid {name} is also given in --set; give it in one of them")
            if not values:
                raise ValueError(f"--grid {name}: no values")
            repeated = [v for i, v in enumerate(values) if v in values[:i]]  # 0.1 and 0.10, 1 and 1.0 are one value
            if repeated:
                raise ValueError(f"--grid {name}: the values {list(values)} repeat {repeated}; give each value once")
        base = trial_preset(preset, overrides, {}, env)
        if eval_episodes is None:
            eval_episodes = base.eval_episodes
        check_int("--eval-episodes", eval_episodes, low=1)
        check_int("eval_seed", eval_seed, low=0)
        check_bool("deterministic", deterministic)
        if total_timesteps is not None:
            check_int("--total-timesteps", total_timesteps, low=1)
        if warm_start is not None:
            if not isinstance(warm_start, (str, Path)):
                raise TypeError(f"--warm-start must be a folder path, got {type(warm_start).__name__}")
            warm_start = str(Path(warm_start).resolve())  # Ray's workers run elsewhere
        eval_sets = (*(default_eval_sets(base) if eval_sets is None else eval_sets), *extra_eval_sets)
        spec = cls(
            preset=preset,
            variants=variants,
            seeds=tuple(range(seeds)),
            grid=grid_values,
            overrides=overrides,
            eval_sets=eval_sets,
            eval_episodes=eval_episodes,
            eval_seed=eval_seed,
            deterministic=deterministic,
            total_timesteps=total_timesteps,
            warm_start=warm_start,
            env=env,
        )
        if spec.warm_start is not None:
            spec.check_warm_start()
        spec.validate()
        return spec

    def grid_points(self) -> list[dict[str, Any]]:
        """Every combination of the grid's values, in ``--grid`` order (``[{}]`` without a grid)."""
        return [dict(zip(self.grid, values)) for values in itertools.product(*self.grid.values())]

    def trial_presets(self) -> list[Preset]:
        """The preset of every grid point (the ``--set`` overrides, then the point), in :meth:`grid_points` order."""
        return [self.point_preset(point) for point in self.grid_points()]

    def point_preset(self, grid_point: Mapping[str, Any]) -> Preset:
        """The preset a grid point's trials train and evaluate with: the named preset, the ``--set`` overrides, the
        point, and :attr:`total_timesteps` as the budget of every variant (the ``independent`` baseline's too)."""
        preset = trial_preset(self.preset, self.overrides, dict(grid_point), self.env)
        if self.total_timesteps is None:
            return preset
        return dataclasses.replace(preset, total_timesteps=self.total_timesteps, baseline_timesteps=self.total_timesteps)

    @property
    def warm_start_depth(self) -> int:
        """0 for a sweep that trains from scratch; 1 + the depth of :attr:`warm_start`'s sweep for one that continues
        it (the continuation's seed offset, :func:`~sb3_latentswarm.utils.seeding.warm_start_seed`)."""
        if self.warm_start is None:
            return 0
        return 1 + SweepSpec.load(Path(self.warm_start) / "sweep.json").warm_start_depth

    def check_warm_start(self) -> None:
        """Check that :attr:`warm_start` holds a sweep this one can continue: same preset and grid, every trial of this
        sweep finished there (``trial.json``, ``model.zip``, ``progress.csv``) with the settings it resolves to here
        (:func:`~sb3_latentswarm.experiments.trial.training_settings` against its ``trial.json``), each at fewer
        agent-steps than this sweep's budget.

        :raises ValueError: naming what differs or what is missing
        """
        folder = Path(str(self.warm_start))
        if not (folder / "sweep.json").is_file():
            raise ValueError(f"--warm-start {folder}: no sweep.json there; give the folder of a finished sweep")
        earlier = SweepSpec.load(folder / "sweep.json")
        names = ("preset", "grid", "env")

        def plain(spec: SweepSpec, name: str) -> Any:
            value = getattr(spec, name)
            return json_values(value.to_dict() if name == "env" and value is not None else value)

        differ = [name for name in names if plain(self, name) != plain(earlier, name)]
        if differ:
            sides = "; ".join(
                f"{name}: {plain(earlier, name)} there, {plain(self, name)} here"
                for name in differ
            )
            raise ValueError(
                f"--warm-start {folder}: that sweep trained with other settings ({sides}); a continued trial must train "
                "the same way (only --total-timesteps and the evaluation may change)"
            )
        missing, too_long, settings_differ = [], {}, {}
        for point, preset in zip(self.grid_points(), self.trial_presets()):
            for seed in self.seeds:
                for variant in self.variants:
                    name = trial_id(variant, seed, point)
                    trial_dir = folder / "trials" / name
                    for part in (trial_dir, *(trial_dir / f for f in ("trial.json", "model.zip", "progress.csv"))):
                        if part.is_symlink():
                            check_real_path(part, folder, "--warm-start trial's file or folder")
                    if not all((trial_dir / f).is_file() for f in ("trial.json", "model.zip", "progress.csv")):
                        missing.append(name)
                        continue
                    record = read_json(trial_dir / "trial.json")
                    # the settings it trained with, as recorded, not as the preset reads today: a preset's defaults
                    # may have changed since (then --set gives the earlier values back)
                    now = training_settings(variant, preset)
                    changed = {
                        key: (record.get(part, {}).get(key), value)
                        for part in ("train_config", "algo_kwargs")
                        for key, value in now[part].items()
                        if record.get(part, {}).get(key) != value
                        and not (part == "train_config" and _added_later_at_default(record.get(part, {}), key, value))
                    }
                    if record.get("n_envs") != now["n_envs"]:
                        changed["n_envs"] = (record.get("n_envs"), now["n_envs"])
                    if changed:
                        settings_differ[name] = changed
                        continue
                    steps = int(record["trained_agent_steps"])
                    if steps >= preset.total_timesteps:
                        too_long[name] = (steps, preset.total_timesteps)
        if missing:
            raise ValueError(
                f"--warm-start {folder}: these trials are not finished there: {missing} (each needs trial.json, "
                "model.zip and progress.csv; a committed results folder may hold its trials without their models: "
                "docs/results/README.md names the commit that has them, to bring back with git checkout COMMIT -- "
                "FOLDER/trials)"
            )
        if settings_differ:
            first = next(iter(settings_differ.values()))
            fix = " ".join(f"{key}={there}" for key, (there, _) in first.items() if key != "policy_kwargs")
            raise ValueError(
                f"--warm-start {folder}: its trials trained with other settings than this sweep's (there, here): "
                f"{settings_differ}; a continued trial must train the same way (only --total-timesteps and the "
                f"evaluation may change): pass the earlier values with --set (for example --set {fix})"
            )
        if too_long:
            raise ValueError(
                f"--warm-start {folder}: trials already trained as many agent-steps as this sweep's budget, or more "
                f"(trained, budget): {too_long}; give a larger --total-timesteps"
            )

    @property
    def n_trials(self) -> int:
        """Variants x training seeds x grid points."""
        return len(self.variants) * len(self.seeds) * len(self.grid_points())

    def validate(self) -> None:
        """Check every trial's settings and evaluation cell the way training and evaluation will (see the module)."""
        names = [s.name for s in self.eval_sets]
        if len(set(names)) != len(names):
            raise ValueError(f"evaluation set names must be unique, got {names}")
        for eval_set in self.eval_sets:
            unknown = [name for name in eval_set.overrides if name not in _CONFIG_FIELDS]
            if unknown:
                raise ValueError(
                    f"--eval-set {eval_set.name}: unknown SwarmConfig field(s) {unknown}; "
                    f"fields: {', '.join(sorted(_CONFIG_FIELDS))}"
                )
            for condition in eval_set.conditions or ():
                if condition not in all_conditions():
                    raise ValueError(
                        f"--eval-set {eval_set.name}: unknown condition {condition!r}; allowed: {list(all_conditions())}"
                    )
        presets = self.trial_presets()
        for point, point_preset in zip(self.grid_points(), presets):
            where = f"--set {self.overrides}" if not point else f"--set {self.overrides}, --grid point {point}"
            check_training_settings(point_preset, where, self.variants)
            for eval_set in self.eval_sets:
                point_preset.config.replace(**eval_set.overrides)
        largest_training_seed = warm_start_seed(
            training_env_seed(len(self.seeds), max(p.n_envs for p in presets)), self.warm_start_depth
        )
        if self.eval_seed < largest_training_seed:
            raise ValueError(
                f"--eval-seed {self.eval_seed} overlaps the training env seeds (up to {largest_training_seed - 1}); "
                f"give --eval-seed {largest_training_seed} or larger"
            )
        ids = [trial_id(v, s, p) for p in self.grid_points() for s in self.seeds for v in self.variants]
        if len(set(ids)) != len(ids):  # a safeguard: trial_id hashes whatever it cannot show
            raise ValueError(f"two trials of this sweep have the same id: {sorted({i for i in ids if ids.count(i) > 1})}")

    def to_dict(self) -> dict[str, Any]:
        """The JSON form of ``sweep.json`` (lists for tuples, the evaluation cells as dicts)."""
        return {
            "preset": self.preset,
            "variants": list(self.variants),
            "seeds": list(self.seeds),
            "grid": {name: list(values) for name, values in self.grid.items()},
            "overrides": dict(self.overrides),
            "eval_sets": [s.to_dict() for s in self.eval_sets],
            "eval_episodes": self.eval_episodes,
            "eval_seed": self.eval_seed,
            "deterministic": self.deterministic,
            "total_timesteps": self.total_timesteps,
            "warm_start": self.warm_start,
            **({} if self.env is None else self.env.to_dict()),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SweepSpec:
        """The spec of :meth:`to_dict`'s output (JSON lists become tuples again); not re-validated. Keys added after a
        spec was written (``total_timesteps``, ``warm_start``, ``env``) take their defaults; an entry point ``env`` is read
        as data only (:meth:`AdaptedEnv.from_dict <sb3_latentswarm.envs.adapted_env.AdaptedEnv.from_dict>`)."""
        expected = {f.name for f in dataclasses.fields(cls)} | {"env_kwargs"}
        required = expected - {"total_timesteps", "warm_start", "env", "env_kwargs"}
        if not required <= set(data) <= expected:
            raise ValueError(f"a sweep spec has the keys {sorted(expected)}, got {sorted(data)}")
        return cls(
            preset=data["preset"],
            variants=tuple(data["variants"]),
            seeds=tuple(data["seeds"]),
            grid={name: tuple(_as_tuples(v) for v in values) for name, values in data["grid"].items()},
            overrides={name: _as_tuples(value) for name, value in data["overrides"].items()},
            eval_sets=tuple(EvalSet.from_dict(s) for s in data["eval_sets"]),
            eval_episodes=data["eval_episodes"],
            eval_seed=data["eval_seed"],
            deterministic=data["deterministic"],
            total_timesteps=data.get("total_timesteps"),
            warm_start=data.get("warm_start"),
            env=None if data.get("env") is None else AdaptedEnv.from_dict(data),
        )

    def save(self, path: str | Path) -> None:
        """Write :meth:`to_dict` as JSON (atomically)."""
        write_text(path, json.dumps(self.to_dict(), indent=2))

    @classmethod
    def load(cls, path: str | Path) -> SweepSpec:
        """Read a spec written by :meth:`save`.

        :raises ValueError: naming the file when it is not a sweep spec
        """
        try:
            return cls.from_dict(read_json(path))
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{path} is not a sweep spec ({error})") from None


def _as_tuples(value: Any) -> Any:
    """JSON lists back to the tuples the spec held (``log_std_bounds=(-5, 0)`` is written as a list)."""
    return tuple(_as_tuples(v) for v in value) if isinstance(value, list) else value
