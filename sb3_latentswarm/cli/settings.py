"""The command line's settings, parsed and validated once, before any env is built or file written.

``--set NAME=VALUE`` pairs become :class:`~sb3_latentswarm.presets.Preset` overrides here (:func:`parse_overrides`,
names checked by :func:`~sb3_latentswarm.presets.check_setting_names`, the one list of valid names); ``train``'s
options are merged with a resumed run's (:func:`train_settings`); ``--device``, ``--output`` and ``--threads`` are
checked by :func:`check_arguments`, which :func:`sb3_latentswarm.cli.main` calls before any command runs.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import sys
from pathlib import Path
from typing import Any

from sb3_latentswarm.presets import Preset, check_setting_names, get_preset, override_targets
from sb3_latentswarm.utils.checks import check_int
from sb3_latentswarm.utils.seeding import training_env_seed


def _literal(raw: str) -> Any:
    """A ``--set`` value as Python reads it (``3`` int, ``2.5`` and ``1e-4`` float, ``True``, ``None``, ``(1, 2)``),
    else the text itself (``full``)."""
    if raw.lower() in ("true", "false"):
        return raw.lower() == "true"
    try:
        return ast.literal_eval(raw)
    except (ValueError, SyntaxError):
        return raw


def parse_overrides(pairs: list[str], option: str = "--set") -> dict[str, Any]:
    """Turn ``["p_fail=0.5", "n_agents=4", "learning_rate=1e-4"]`` into ``{name: value}`` settings.

    Values are read as Python literals and not converted: ``n_agents=2.5`` stays a float, which ``SwarmConfig``
    rejects, as it would in Python. Names are checked by :func:`~sb3_latentswarm.presets.check_setting_names`
    (``SwarmConfig`` fields, ``n_envs``/``eval_episodes``, ``LatentSwarmPPO`` and ``LatentSwarmPolicy`` arguments);
    :meth:`Preset.with_overrides <sb3_latentswarm.presets.Preset.with_overrides>` routes them and validates.

    :param option: the option the pairs come from, for the messages (``--grid``, ``--eval-set NAME``)
    """
    overrides: dict[str, Any] = {}
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"{option} expects NAME=VALUE, got {pair!r}")
        name, raw = pair.split("=", 1)
        if name in overrides:
            raise ValueError(f"{option} {name} given twice ({overrides[name]!r} and {raw!r})")
        overrides[name] = _literal(raw)
    check_setting_names(list(overrides), option)
    return overrides


def check_arguments(args: argparse.Namespace) -> None:
    """Every check of the options that needs no env or model, once, before the command runs: ``--threads`` (then
    applied), ``--device``, ``--output``, and ``--set``, parsed into ``args.overrides`` (a training setting outside
    ``train`` and ``sweep`` is refused).

    :raise ValueError: naming the option and its value
    """
    if args.threads < 0:
        raise ValueError(f"--threads must be >= 0, got {args.threads}")
    if args.threads:
        from sb3_latentswarm.utils.threads import set_torch_threads

        set_torch_threads(args.threads)  # warns once past the available cores
    check_device(args)
    check_output_folder(args)
    args.adapted_env = adapted_env_from_args(args)
    args.overrides = parse_overrides(args.set or [])
    if args.command in ("evaluate", "render"):
        targets = override_targets()
        for name in args.overrides:
            if name in targets["LatentSwarmPPO"] + targets["LatentSwarmPolicy"] + ("n_envs",):
                raise ValueError(f"--set {name}: a training setting, which only `train` uses")


def adapted_env_from_args(args: argparse.Namespace) -> Any:
    """``--env`` with ``--env-kwargs`` as an :class:`~sb3_latentswarm.envs.adapted_env.AdaptedEnv` (``None`` without
    ``--env``), its module imported now: a bad name, JSON or module fails before any work.

    :raise ValueError: naming the option: ``--env-kwargs`` without ``--env``, bad JSON, a name that is neither
        registered nor an entry point, a module that cannot be imported, ``--backend supersuit`` with ``--env``
    """
    name, text = getattr(args, "env", None), getattr(args, "env_kwargs", None)
    if name is None:
        if text is not None:
            raise ValueError("--env-kwargs needs --env (the env they are for)")
        return None
    from sb3_latentswarm.envs.adapted_env import AdaptedEnv, parse_env_kwargs

    env = AdaptedEnv(name, parse_env_kwargs(text))
    if getattr(args, "backend", None) not in (None, "batched"):
        raise ValueError(f"--backend {args.backend} steps the swarm env only; --env {name} runs through the adapter")
    env.env_fn()
    return env


def preset_from_args(args: argparse.Namespace, model: Any = None) -> Preset:
    """The ``--preset`` named, or, without one, the training config saved with ``model`` (else ``demo``), on
    ``--env``'s adapted env if given (:meth:`Preset.with_env <sb3_latentswarm.presets.Preset.with_env>`), with the
    ``--set`` overrides (``args.overrides``, :func:`check_arguments`). A model trained on an adapted env carries no
    config; ``evaluate --env`` without ``--preset`` then takes the link model from the ``config.json`` that ``train``
    wrote beside it."""
    adapted_env = getattr(args, "adapted_env", None)
    saved_links = _saved_adapted_config(args, model) if adapted_env is not None and args.preset is None else None
    if args.preset is not None:
        preset = get_preset(args.preset)
    elif saved_links is not None:
        preset = dataclasses.replace(get_preset("demo"), name="saved", config=saved_links,
                                     description="the link config in config.json beside the model")
        preset = preset.with_env(adapted_env, keep_links=True)
        return preset.with_overrides(**args.overrides) if args.overrides else preset
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
    preset = preset.with_env(adapted_env)
    return preset.with_overrides(**args.overrides) if args.overrides else preset


def _saved_adapted_config(args: argparse.Namespace, model: Any) -> Any:
    """The config ``train --env`` wrote beside ``--model`` (``config.json``: plain data, its link model), for
    ``evaluate --env`` without ``--preset``; ``None`` when there is none.

    :raise ValueError: a ``config.json`` that is not a valid ``SwarmConfig``, naming the file
    """
    path = Path(getattr(args, "model", None) or "").parent / "config.json"
    if model is None or not path.is_file():
        return None
    from sb3_latentswarm.config import SwarmConfig
    from sb3_latentswarm.utils.atomic import read_json

    try:
        return SwarmConfig(**read_json(path))
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: not the config of a run ({error}); pass --preset and --set the link model") from None


RESUME_SETTINGS = ("preset", "set", "seed", "env_seed", "total_timesteps", "backend", "env", "env_kwargs")
"""The ``train`` options a checkpoint stores and ``--resume`` compares (given ones must match, except a larger
``--total-timesteps``, which extends the run's budget; missing ones are taken from the checkpoint; a checkpoint
without ``env_seed``, from before ``--env-seed``, seeded its env copies from ``seed``). ``env`` is a registered name
or an entry point; a stored entry point is run only when ``--env`` names it again (:meth:`AdaptedEnv.from_record
<sb3_latentswarm.envs.adapted_env.AdaptedEnv.from_record>`)."""


def train_settings(
    args: argparse.Namespace, stored: dict[str, Any] | None = None, source: str = "checkpoint"
) -> dict[str, Any]:
    """The run's settings: the options given, else (with ``--resume``) the stored ones, else the defaults.

    :param stored: the settings of the run being resumed (a checkpoint's, or ``train --seeds``'s record)
    :param source: what ``stored`` comes from, for the message
    :raise ValueError: with ``--resume``, for a given option that differs from the stored one, naming both values
    """
    stored = stored or {}
    given = {
        "preset": args.preset,
        "set": sorted(args.set) if args.set else None,
        "seed": args.seed,
        "env_seed": args.env_seed,
        "total_timesteps": args.total_timesteps,
        "backend": args.backend,
        "env": getattr(args, "env", None),
        "env_kwargs": None if getattr(args, "adapted_env", None) is None else dict(args.adapted_env.kwargs),
    }
    if stored:
        if stored.get("env_seed") is None:  # a run from before --env-seed: its env copies were seeded from --seed
            stored = {**stored, "env_seed": stored.get("seed")}

        def same(name: str, value: Any) -> bool:
            if name == "set":  # the same settings in any order
                return parse_overrides(value) == parse_overrides(stored.get(name) or [])
            if name == "total_timesteps" and stored.get(name) is not None:  # a larger budget extends the run
                return value >= stored[name]
            if name == "env_kwargs":
                return value == (stored.get(name) or {})
            return value == stored.get(name)

        differ = [
            f"{name} ({source}: {stored.get(name)!r}, command: {value!r})"
            for name, value in given.items()
            if value is not None and not same(name, value)
        ]
        if differ:
            raise ValueError(
                f"--resume: the run in {args.output} was started with other settings: {'; '.join(differ)}. Resume with "
                f"the run's settings (omit the options to take them from the {source}) or start a new run in another "
                f"--output"
            )
        resumed = {name: stored.get(name) for name in RESUME_SETTINGS}
        if given["total_timesteps"] is not None:
            resumed["total_timesteps"] = given["total_timesteps"]
        return resumed
    defaults = {"preset": "demo", "set": [], "seed": 0, "total_timesteps": None, "backend": "batched", "env": None,
                "env_kwargs": None}
    settings = {name: defaults.get(name) if value is None else value for name, value in given.items()}
    if settings["env_seed"] is None:  # the default: copy c gets --seed + c, as before --env-seed
        settings["env_seed"] = settings["seed"]
    return settings


def checked_training_preset(args: argparse.Namespace, n_seeds: int | None = None) -> Preset:
    """The preset of ``args`` (``--preset``, ``--set``) with its algorithm settings validated, and with ``--evaluate``
    its evaluation episodes held out from the training env copies: before any env is built or file written.

    :param n_seeds: ``None`` for one run (copies ``ENV_SEED .. ENV_SEED + n_envs - 1``, ``ENV_SEED`` defaulting to
        ``--seed``); else the number of seeds of ``train --seeds``, whose seed ``S + i`` trains the copies of
        :func:`~sb3_latentswarm.utils.seeding.training_env_seed` ``(S + i, n_envs)``
    """
    from sb3_latentswarm.latent_ppo.latent_ppo import validate_algorithm_kwargs

    preset = preset_from_args(args)
    check_int("n_envs", preset.n_envs, low=1)  # before any arithmetic with it
    check_int("n_steps", preset.algo_kwargs["n_steps"], low=1)
    validate_algorithm_kwargs(**preset.algo_kwargs)
    if args.evaluate:
        check_int("eval_episodes", preset.eval_episodes, low=1)
        # the evaluation episodes must not replay a training env copy's first episode
        from sb3_latentswarm.evaluation import check_held_out

        if n_seeds is None:
            bases = [args.seed if args.env_seed is None else args.env_seed]
        else:
            bases = [training_env_seed(args.seed + i, preset.n_envs) for i in range(n_seeds)]
        for base in bases:
            check_held_out(eval_seed(args), preset.eval_episodes, base, preset.n_envs)
    return preset


def eval_seed(args: argparse.Namespace) -> int:
    """``--eval-seed``, or the held-out default (:data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, 1,000,000)."""
    return 1_000_000 if args.eval_seed is None else args.eval_seed  # the literal keeps --help free of torch imports


def check_device(args: argparse.Namespace) -> None:
    """``--device``: a torch device string; ``cuda`` without CUDA falls back to the CPU, said on stderr."""
    if not hasattr(args, "device") or args.device == "auto":
        return
    import torch

    try:
        device = torch.device(args.device)
    except RuntimeError:
        raise ValueError(f"--device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {args.device!r}") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        print(f"sb3-latentswarm {args.command}: --device {args.device}: CUDA is not available here; running on the CPU",
              file=sys.stderr)
    elif device.type not in ("cpu", "cuda"):
        raise ValueError(f"--device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {args.device!r}")
    elif device.type == "cuda" and device.index is not None and device.index >= torch.cuda.device_count():
        raise ValueError(f"--device {args.device}: this machine has {torch.cuda.device_count()} CUDA device(s)")


def check_output_folder(args: argparse.Namespace) -> None:
    """``--output`` of train, evaluate and sweep names a folder: an existing file there is an error, before any work."""
    output = getattr(args, "output", None)
    if args.command in ("train", "evaluate", "sweep") and output and Path(output).exists() and not Path(output).is_dir():
        raise ValueError(f"--output {output} is an existing file, not a folder")
