"""The ``sb3-latentswarm`` command: ``train``, ``evaluate``, ``render`` and ``sweep``.

    sb3-latentswarm train --preset demo --evaluate          # the README's main job
    sb3-latentswarm train --preset coordination --seeds 3   # seeds 0, 1, 2: one single-thread process each
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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from sb3_latentswarm.presets import PRESETS, Preset, get_preset, override_targets, unknown_settings_message
from sb3_latentswarm.utils.checks import check_int
from sb3_latentswarm.utils.seeding import training_env_seed
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
    valid = {name for names in override_targets().values() for name in names}
    overrides: dict[str, Any] = {}
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"--set expects NAME=VALUE, got {pair!r}")
        name, raw = pair.split("=", 1)
        if name not in valid:
            raise ValueError(f"--set: {unknown_settings_message([name])}")
        if name in overrides:
            raise ValueError(f"--set {name} given twice ({overrides[name]!r} and {raw!r})")
        overrides[name] = _literal(raw)
    return overrides


def int_at_least(low: int) -> Callable[[str], int]:
    """An argparse ``type`` that reads an integer >= ``low`` (``int_at_least(1)`` for counts, ``int_at_least(0)``
    where 0 means "never"), checked by :func:`~sb3_latentswarm.utils.checks.check_int`.

    :return: the parser, which raises ``argparse.ArgumentTypeError`` (argparse prefixes the option's name)
    """

    def parse(text: str) -> int:
        try:
            return check_int("the value", int(text), low=low)
        except ValueError:  # not an integer (int), or one below low (check_int)
            raise argparse.ArgumentTypeError(f"expected an int >= {low}, got {text!r}") from None

    parse.__name__ = f"int_at_least_{low}"
    return parse


class _ListSettings(argparse.Action):
    """``--list-settings``: print :func:`~sb3_latentswarm.presets.format_settings` and exit, as ``--help`` does."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string=None):
        from sb3_latentswarm.presets import format_settings

        print(format_settings())
        parser.exit()


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


RESUME_SETTINGS = ("preset", "set", "seed", "env_seed", "total_timesteps", "backend")
"""The ``train`` options a checkpoint stores and ``--resume`` compares (given ones must match, except a larger
``--total-timesteps``, which extends the run's budget; missing ones are taken from the checkpoint; a checkpoint
without ``env_seed``, from before ``--env-seed``, seeded its env copies from ``seed``)."""


def _train_settings(
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
    }
    if stored:
        if stored.get("env_seed") is None:  # a run from before --env-seed: its env copies were seeded from --seed
            stored = {**stored, "env_seed": stored.get("seed")}

        def same(name: str, value: Any) -> bool:
            if name == "set":  # the same settings in any order
                return parse_overrides(value) == parse_overrides(stored.get(name) or [])
            if name == "total_timesteps" and stored.get(name) is not None:  # a larger budget extends the run
                return value >= stored[name]
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
    defaults = {"preset": "demo", "set": [], "seed": 0, "total_timesteps": None, "backend": "batched"}
    settings = {name: defaults.get(name) if value is None else value for name, value in given.items()}
    if settings["env_seed"] is None:  # the default: copy c gets --seed + c, as before --env-seed
        settings["env_seed"] = settings["seed"]
    return settings


def _program_name() -> str:
    """The name the user ran this command by: ``basename(sys.argv[0])`` when that is one of the package's console
    scripts (``sb3-latentswarm``), else ``sb3-latentswarm`` (``python -m sb3_latentswarm.cli``, a test runner)."""
    import os
    from importlib.metadata import entry_points

    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    for suffix in ("-script.py", ".exe"):  # the launchers pip writes on Windows
        name = name.removesuffix(suffix)
    try:
        scripts = {ep.name for ep in entry_points(group="console_scripts") if ep.value.startswith(f"{__name__}:")}
    except Exception:  # broken package metadata must not stop a run from printing how to resume it
        scripts = set()
    return name if name in scripts else "sb3-latentswarm"


def _resume_command(output: Path) -> str:
    """``sb3-latentswarm train --resume --output OUTPUT``, by the name the user ran (:func:`_program_name`)."""
    import shlex

    return f"{_program_name()} train --resume --output {shlex.quote(str(output))}"


def _checked_training_preset(args: argparse.Namespace, n_seeds: int | None = None) -> Preset:
    """The preset of ``args`` (``--preset``, ``--set``) with its algorithm settings validated, and with ``--evaluate``
    its evaluation episodes held out from the training env copies: before any env is built or file written.

    :param n_seeds: ``None`` for one run (copies ``ENV_SEED .. ENV_SEED + n_envs - 1``, ``ENV_SEED`` defaulting to
        ``--seed``); else the number of seeds of ``train --seeds``, whose seed ``S + i`` trains the copies of
        :func:`~sb3_latentswarm.utils.seeding.training_env_seed` ``(S + i, n_envs)``
    """
    from sb3_latentswarm.latent_ppo.latent_ppo import validate_algorithm_kwargs

    preset = _preset_from_args(args, training=True)
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
            check_held_out(_eval_seed(args), preset.eval_episodes, base, preset.n_envs)
    return preset


def command_train(args: argparse.Namespace) -> int:
    """``train``: validate every setting, probe the output folder, train with checkpoints, save ``model.zip``: one
    :class:`~sb3_latentswarm.runs.run.Run`.

    ``--resume`` continues the newest checkpoint in ``--output``; SIGINT / SIGTERM write a checkpoint and exit with
    128 + the signal number (see ``docs/long_runs.md``). ``--seeds K`` > 1 (or an ``--output`` holding a
    ``seeds.json``) runs this command once per seed, in processes of their own (:func:`_command_train_seeds`).
    """
    from sb3_latentswarm.runs.checkpoints import default_save_freq
    from sb3_latentswarm.runs.run import CheckpointWriteError, Run, RunSpec, RunStopped
    from sb3_latentswarm.runs.train_seeds import SEEDS_RECORD

    output = Path(args.output or f"runs/{args.preset or 'demo'}")
    args.output = str(output)
    if output.exists() and not output.is_dir():
        raise ValueError(f"--output {output} is an existing file, not a folder")
    if (args.seeds or 1) > 1 or (output / SEEDS_RECORD).exists():
        return _command_train_seeds(args, output)
    with Run(output) as run:
        if args.resume and run.start is None:
            raise ValueError(f"--resume: no checkpoint in {run.checkpoint_dir}; train without --resume to start a run there")
        if not args.resume and run.start is not None:
            raise ValueError(
                f"--output {output} holds the checkpoints of an earlier run (newest: {run.start}); continue it with "
                f"--resume, or pass another --output"
            )
        if run.start is None and any((output / f"{name}.csv").exists() for name in EVALUATION_TABLES):
            raise ValueError(
                f"--output {output} holds the evaluation tables of an earlier model; a new model there would sit beside "
                f"them. Pass another --output"
            )
        stored: dict[str, Any] = (run.state or {}).get("settings") or {}
        settings = _train_settings(args, stored)
        args.preset, args.set, args.seed = settings["preset"], settings["set"], settings["seed"]
        args.backend, args.env_seed = settings["backend"], settings["env_seed"]
        preset = _checked_training_preset(args)
        total = settings["total_timesteps"] = settings["total_timesteps"] or preset.total_timesteps
        if args.save_freq is None:  # the run's own frequency on --resume (not compared: it changes no result)
            args.save_freq = stored.get("save_freq", default_save_freq(total, preset.agent_steps_per_update))
        if args.keep_checkpoints is None:
            args.keep_checkpoints = stored.get("keep_checkpoints", 3)
        tensorboard = args.tensorboard if args.tensorboard is not None else stored.get("tensorboard")
        tensorboard_run = stored.get("tensorboard_run")
        if tensorboard is not None and tensorboard_run is None:
            from stable_baselines3.common.utils import get_latest_run_id

            name = f"latentswarm_{preset.name}"
            tensorboard_run = str(Path(tensorboard) / f"{name}_{get_latest_run_id(tensorboard, name) + 1}")
        spec = RunSpec(
            preset,
            output,
            seed=args.seed,
            env_seed=args.env_seed,
            total_timesteps=total,
            backend=args.backend,
            device=args.device,
            resume=args.resume,
            save_freq=args.save_freq,
            keep_checkpoints=args.keep_checkpoints,
            settings={
                **settings,
                "tensorboard": tensorboard,
                "tensorboard_run": tensorboard_run,
                "save_freq": args.save_freq,
                "keep_checkpoints": args.keep_checkpoints,
            },
            tensorboard=tensorboard,
            tensorboard_run=tensorboard_run,
            verbose=args.verbose,
        )
        try:
            run.train(spec, _TrainCommandHooks(args, preset, stored))  # type: ignore[arg-type]  # a RunHooks
        except CheckpointWriteError as error:
            print(
                f"sb3-latentswarm train: error: {error}; free some space and resume with:\n  {_resume_command(output)}",
                file=sys.stderr,
            )
            return 1
        except RunStopped as stopped:
            if stopped.saved:
                print(f"Stopped by {stopped.name} after the last update", file=sys.stderr)
            else:
                print(
                    f"\nStopped by {stopped.name or 'a second signal'} after {stopped.seconds:.0f} s; checkpoint "
                    f"{stopped.checkpoint} (the rollout in progress is not kept). Resume with:\n  {_resume_command(output)}",
                    file=sys.stderr,
                )
            return stopped.exit_code
    return 0


class _TrainCommandHooks:
    """What ``train`` says while its run goes (:class:`~sb3_latentswarm.runs.run.RunHooks`), its progress bar and its
    ``--evaluate``."""

    def __init__(self, args: argparse.Namespace, preset: Preset, stored: dict[str, Any]):
        self.args, self.preset, self.stored = args, preset, stored

    def callbacks(self) -> list[Any]:
        from sb3_latentswarm.callbacks import RolloutProgressBarCallback

        return [RolloutProgressBarCallback()] if not self.args.no_progress and sys.stderr.isatty() else []

    def extra_state(self) -> dict[str, Any]:
        return {}

    def started(self, run: Any) -> None:
        from sb3_latentswarm.callbacks import whole_rollouts

        args, preset, model, total, remaining = self.args, self.preset, run.model, run.budget, run.remaining
        per_rollout = model.n_steps * run.env.num_envs
        # learn() collects whole rollouts: the run ends at the budget rounded up to them (the progress bar's total)
        end = model.num_timesteps + (whole_rollouts(remaining, per_rollout) if remaining > 0 else 0)
        rounded = f" ({total:,} rounded up to whole rollouts of {per_rollout:,})" if end != total else ""
        copies = f"env copies {args.env_seed}..{args.env_seed + preset.n_envs - 1}"
        if run.resumed_from is not None:
            at = f"{model.num_timesteps:,} of {end:,} agent-steps{rounded}"
            print(f"Resuming {run.start} at {at}, seed {args.seed} ({copies})")
            earlier = self.stored.get("total_timesteps")
            if earlier is not None and total > earlier:
                print(f"The run's budget grows from {earlier:,} to {total:,} agent-steps (--total-timesteps)")
            if remaining <= 0:
                print(
                    f"The run has trained its {total:,} agent-steps: nothing to train (give --total-timesteps N, N > "
                    f"{model.num_timesteps:,}, to train on); model.zip is written again from the newest checkpoint"
                )
        else:
            overrides = f" with {' '.join(args.set)}" if args.set else ""
            print(
                f"Training preset '{preset.name}'{overrides} for {end:,} agent-steps{rounded}: {preset.n_envs} swarms of "
                f"{preset.config.n_agents}, n_steps {model.n_steps}, {end // per_rollout} updates, seed {args.seed} "
                f"({copies})"
            )
            rate = model.learning_rate
            rate_text = f"{rate:g}" if isinstance(rate, (int, float)) else repr(rate)
            epochs = f"{model.n_epochs} epoch{'s' if model.n_epochs != 1 else ''}"
            print(f"PPO: learning rate {rate_text}, minibatch {model.batch_size:,} agent-steps, {epochs}")
        print(f"Checkpoints every {args.save_freq:,} agent-steps in {run.checkpoint_dir} (keeping {args.keep_checkpoints})")
        # now: a run killed by kill -9 prints nothing at its end
        print(f"If stopped, resume with: {_resume_command(run.output)}")

    def saved(self, run: Any, result: Any) -> None:
        print(f"Trained in {result.train_seconds:.0f} s; saved {result.model_path}")

    def evaluate(self, run: Any, result: Any) -> None:
        if self.args.evaluate:
            _evaluate_and_print(
                result.model, self.preset, self.args, run.output, p_fail_sweep=False, baselines=True,
                model_path=result.model_path,
            )


SEED_OPTIONS = ("evaluate", "eval_seed", "stochastic", "tensorboard", "save_freq", "keep_checkpoints")
"""``train --seeds`` options stored in its record and passed to every seed's process; ``--resume`` takes the stored
value of each one not given again (the settings of :data:`RESUME_SETTINGS` must match, as for one seed)."""


def _seed_argv(
    args: argparse.Namespace, settings: dict[str, Any], options: dict[str, Any], seed: int, resume: bool, n_envs: int
):
    """The ``sb3-latentswarm`` arguments that train (or, with ``resume``, continue) one seed of ``train --seeds``:
    model seed ``seed``, env copies from :func:`~sb3_latentswarm.utils.seeding.training_env_seed` ``(seed, n_envs)``
    (a resumed seed takes both from its checkpoint)."""
    from sb3_latentswarm.runs.train_seeds import seed_folder

    folder = seed_folder(args.output, seed)
    argv = ["train", "--output", str(folder), "--no-progress", "--device", args.device, "--verbose", str(args.verbose)]
    if resume:  # the settings, TensorBoard run, save_freq and keep_checkpoints are the seed checkpoint's
        argv.insert(1, "--resume")
        given = {"save_freq": args.save_freq, "keep_checkpoints": args.keep_checkpoints}
    else:
        argv += ["--preset", settings["preset"], "--seed", str(seed), "--env-seed", str(training_env_seed(seed, n_envs))]
        argv += ["--total-timesteps", str(settings["total_timesteps"])]
        argv += ["--backend", settings["backend"]]
        for pair in settings["set"] or []:
            argv += ["--set", pair]
        given = {name: options[name] for name in ("save_freq", "keep_checkpoints")}
        if options["tensorboard"] is not None:
            argv += ["--tensorboard", str(Path(options["tensorboard"]) / f"seed{seed}")]
    for name, value in given.items():
        if value is not None:
            argv += [f"--{name.replace('_', '-')}", str(value)]
    if args.threads:
        argv += ["--threads", str(args.threads)]
    if options["evaluate"]:
        argv.append("--evaluate")
    if options["eval_seed"] is not None:
        argv += ["--eval-seed", str(options["eval_seed"])]
    if options["stochastic"]:
        argv.append("--stochastic")
    return tuple(argv)


def _last_line(path: Path, limit: int = 300) -> str:
    """The last non-empty line of a text file (at most ``limit`` characters), ``""`` where there is none."""
    try:
        lines = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return lines[-1][:limit] if lines else ""


def _command_train_seeds(args: argparse.Namespace, output: Path) -> int:
    """``train --seeds K [--jobs J]``: seeds ``S .. S+K-1`` in ``OUTPUT/seed{S+i}/``, each by the single-seed
    ``train`` in a single-thread process of its own (:mod:`sb3_latentswarm.runs.train_seeds`), at most J at a time.

    Every argument, the preset's settings (by building the env and model of seed S) and the folders are checked
    before any process starts or any file is written. ``--resume`` (or the same command with ``--resume``) skips the
    finished seeds, continues the unfinished ones from their checkpoints and starts the others.

    :return: 0; 1 when a seed failed; 128 + the signal's number when stopped by SIGINT / SIGTERM / SIGHUP
    """
    from sb3_latentswarm.runs.run import find_start, required_room
    from sb3_latentswarm.runs.train_seeds import SEEDS_RECORD, SeedRun, run_seed_processes, seed_folder, seed_state
    from sb3_latentswarm.utils.atomic import probe_writable, write_json
    from sb3_latentswarm.utils.threads import available_cores

    record_path = output / SEEDS_RECORD
    record: dict[str, Any] | None = None
    if record_path.exists():
        try:
            record = json.loads(record_path.read_text())
            if not isinstance(record, dict) or not isinstance(record.get("settings"), dict):
                raise ValueError("not a seeds record")
        except (OSError, ValueError) as error:  # JSONDecodeError is a ValueError
            raise ValueError(f"--output {output}: {record_path} is not a readable record of train --seeds ({error})") from None
        if not args.resume:
            raise ValueError(
                f"--output {output} holds the seeds of an earlier run ({record_path}); continue them with --resume, or "
                f"pass another --output"
            )
    elif args.resume:
        raise ValueError(f"--resume --seeds: no run of train --seeds in {output} (no {SEEDS_RECORD}); train without --resume")
    elif find_start(output) is not None or (output / "model.zip").exists():
        raise ValueError(
            f"--output {output} holds a single-seed run (model.zip or checkpoints/); train --seeds needs a folder of its "
            f"own: pass another --output"
        )
    if args.env_seed is not None:
        raise ValueError(
            f"--env-seed {args.env_seed} with --seeds: each seed S+i trains its own env copies, (S+i) * n_envs + c "
            f"(disjoint across seeds, as in sweep); --env-seed is for a single run"
        )
    stored = (record or {}).get("options") or {}
    settings = _train_settings(args, (record or {}).get("settings"), source=SEEDS_RECORD)
    recorded_total = ((record or {}).get("settings") or {}).get("total_timesteps")
    if recorded_total is not None and settings["total_timesteps"] != recorded_total:
        raise ValueError(
            f"--resume --total-timesteps {settings['total_timesteps']}: the seeds of {args.output} were started with "
            f"{recorded_total}; a --seeds run keeps its budget (finished seeds are skipped). Extend one seed with "
            f"train --resume --output {args.output}/seedN --total-timesteps {settings['total_timesteps']}"
        )
    del settings["env_seed"]  # each seed's own (training_env_seed), recorded in env_seeds below
    args.preset, args.set, args.seed, args.backend = settings["preset"], settings["set"], settings["seed"], settings["backend"]
    n_seeds = args.seeds or int((record or {}).get("seeds", 1))
    given = {name: getattr(args, name) for name in SEED_OPTIONS}
    options = {name: stored.get(name, value) if value is None or value is False else value for name, value in given.items()}
    args.evaluate, args.eval_seed = options["evaluate"], options["eval_seed"]
    preset = _checked_training_preset(args, n_seeds=n_seeds)  # --evaluate: held out from every seed's env copies
    settings["total_timesteps"] = settings["total_timesteps"] or preset.total_timesteps
    seeds = range(settings["seed"], settings["seed"] + n_seeds)
    env_seeds = {seed: training_env_seed(seed, preset.n_envs) for seed in seeds}

    states = {seed: seed_state(seed_folder(output, seed), bool(options["evaluate"])) for seed in seeds}
    if record is None:  # a new run: no seed folder may hold an earlier run's files
        for seed in seeds:
            folder = seed_folder(output, seed)
            if states[seed] != "new" or any((folder / f"{name}.csv").exists() for name in EVALUATION_TABLES):
                raise ValueError(f"--output {output}: {folder} holds an earlier run; pass another --output")
    to_run = [seed for seed in seeds if states[seed] != "finished"]
    cores = available_cores()
    threads = args.threads or 1
    jobs = min(args.jobs or cores, max(len(to_run), 1))
    if jobs * threads > cores:
        print(
            f"sb3-latentswarm train: warning: --jobs {jobs} runs {jobs * threads} torch thread(s) at once, but this "
            f"process may run on {cores} core(s): processes that wait for a core are slower in all, and two threads on "
            f"a loaded 2-core machine ran a coordination update 50x slower than one (docs/benchmarks.md)",
            file=sys.stderr,
        )
    room = 0
    if to_run:  # build seed S's env and model once: every setting is checked, and a checkpoint's size known
        env = preset.make_env(env_seeds[seeds.start], backend=args.backend)
        try:
            model = preset.make_model(env, seed=settings["seed"], device=args.device, verbose=0)
            room = required_room(model) * len(to_run)
            del model
        finally:
            env.close()
    probe_writable(output, room_bytes=room)
    if options["tensorboard"] is not None:
        probe_writable(options["tensorboard"])

    record = {
        "settings": settings,
        "seeds": max(n_seeds, int((record or {}).get("seeds", 0))),
        # first and last env copy seed of each seed started here (k * n_envs + c, as in sweep; a resumed seed keeps
        # its checkpoint's): no two seeds share an env stream
        "env_seeds": {
            **(record or {}).get("env_seeds", {}),
            **{str(seed): [base, base + preset.n_envs - 1] for seed, base in env_seeds.items() if states[seed] == "new"},
        },
        "options": {name: stored.get(name, options[name]) if record else options[name] for name in SEED_OPTIONS},
        "results": (record or {}).get("results", {}),
        "version": __version__,
    }
    write_json(record_path, record)
    overrides = f" with {' '.join(settings['set'])}" if settings["set"] else ""
    each = "one torch thread each" if threads == 1 else f"{threads} torch threads each"
    skipped = [seed for seed in seeds if states[seed] == "finished"]
    print(
        f"Training {n_seeds} seeds ({seeds.start}..{seeds.stop - 1}) of preset '{preset.name}'{overrides}, "
        f"{settings['total_timesteps']:,} agent-steps each, {jobs} at a time ({each}), in "
        f"{output}/seed*/" + (f"; {len(skipped)} already trained" if skipped else "")
    )
    print(
        f"Seed k trains env copies k * {preset.n_envs} .. k * {preset.n_envs} + {preset.n_envs - 1} (none shared between "
        f"seeds)"
    )
    print(f"If stopped, resume with: {_resume_command(output)}")  # now: kill -9 of this command prints nothing at its end
    for seed in skipped:
        print(f"seed {seed}: already trained, skipped ({seed_folder(output, seed) / 'model.zip'})")
    runs = [
        SeedRun(
            seed,
            seed_folder(output, seed),
            _seed_argv(args, settings, options, seed, states[seed] == "unfinished", preset.n_envs),
            resume=states[seed] == "unfinished",
        )
        for seed in to_run
    ]

    def started(run: SeedRun) -> None:
        how = "continuing from its newest checkpoint" if run.resume else "started"
        print(f"seed {run.seed}: {how} (log {run.log})", flush=True)

    def finished(result) -> None:
        record["results"][str(result.seed)] = result.as_record()
        write_json(record_path, record)
        if result.status == "not started":
            return
        cpu = f", {result.cpu_seconds:.0f} s CPU" if result.cpu_seconds is not None else ""
        took = f"{result.wall_seconds:.0f} s{cpu}"
        if result.status == "trained":
            coverage = f", last rollout coverage {100 * result.coverage:.1f} %" if result.coverage is not None else ""
            print(f"seed {result.seed}: trained in {took}{coverage} ({result.folder / 'model.zip'})", flush=True)
        else:
            print(f"seed {result.seed}: {result.status} (exit code {result.exit_code}) after {took}; log {result.log}",
                  flush=True)

    results, signum = run_seed_processes(runs, jobs, threads, on_start=started, on_finish=finished)
    trained = [result for result in results if result.status == "trained"]
    failed = [result for result in results if result.status == "failed"]
    coverages = [result.coverage for result in trained if result.coverage is not None]
    summary = f"\n{len(trained)} seed(s) trained, {len(skipped)} skipped (already trained), {len(failed)} failed"
    if signum is not None:
        summary += f", {len(results) - len(trained) - len(failed)} stopped or not started"
    if coverages:
        summary += (
            f"; last rollout coverage of the trained ones: mean {100 * sum(coverages) / len(coverages):.1f} % "
            f"(min {100 * min(coverages):.1f}, max {100 * max(coverages):.1f})"
        )
    print(summary)
    if signum is not None:
        import signal

        stopped = [str(result.seed) for result in results if result.status == "stopped"]
        waiting = [str(result.seed) for result in results if result.status == "not started"]
        print(
            f"\nStopped by {signal.Signals(signum).name}: seed(s) {', '.join(stopped) or 'none'} wrote a checkpoint"
            + (f", seed(s) {', '.join(waiting)} not started" if waiting else "")
            + f". Resume every unfinished seed with:\n  {_resume_command(output)}",
            file=sys.stderr,
        )
        return 128 + int(signum)
    if failed:
        lines = "\n".join(
            f"  seed {result.seed}: exit code {result.exit_code}, log {result.log}: {_last_line(result.log)}"
            for result in failed
        )
        print(
            f"sb3-latentswarm train: {len(failed)} seed(s) failed:\n{lines}\nFix the cause and rerun the unfinished "
            f"seeds with:\n  {_resume_command(output)}",
            file=sys.stderr,
        )
        return 1
    return 0


def _evaluate_and_print(
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
    from sb3_latentswarm.evaluation import (
        CONDITIONS,
        evaluate,
        evaluate_conditions,
        evaluate_p_fail_sweep,
        seed_range,
        summarize,
        to_markdown,
    )
    from sb3_latentswarm.utils.atomic import atomic_path, write_json, write_text

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

    config, episodes, seed = preset.config, preset.eval_episodes, _eval_seed(args)
    seeds = seed_range(seed, episodes)
    progress_bar = sys.stderr.isatty() and not args.no_progress
    policy_kwargs: dict[str, Any] = dict(
        n_episodes=episodes, seed=seed, config=config, deterministic=not args.stochastic, progress_bar=progress_bar
    )
    frames = [evaluate_conditions(model, conditions=CONDITIONS, p_fail=config.p_fail, **policy_kwargs)]
    if baselines:
        from sb3_latentswarm.baselines import FrontierPlanner, LawnmowerPlanner, RandomPlanner

        for label, planner in (
            ("random", RandomPlanner(config, seed=args.seed)),
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
    summary = summarize(table, by="condition")
    finished("conditions", table, to_markdown(summary))
    actions = "sampled" if args.stochastic else "mean"
    title = f"Conditions (p_f = {config.p_fail}, {episodes} episodes each, episode {seeds}, {actions} actions)"
    _print_table(title, to_markdown(summary))
    if p_fail_sweep:
        sweep = evaluate_p_fail_sweep(model, p_fails=preset.p_fails, **policy_kwargs)
        sweep_summary = summarize(sweep, by="p_fail")
        finished("p_fail_sweep", sweep, to_markdown(sweep_summary))
        _print_table(f"p_f sweep (proposed, episode {seeds}, {actions} actions)", to_markdown(sweep_summary))
    print(f"\nTables written to {output}/")


def _eval_seed(args: argparse.Namespace) -> int:
    """``--eval-seed``, or the held-out default (:data:`~sb3_latentswarm.evaluation.HELD_OUT_SEED`, 1,000,000)."""
    return 1_000_000 if args.eval_seed is None else args.eval_seed  # the literal keeps --help free of torch imports


def _load_model(args: argparse.Namespace):
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    if not Path(args.model).exists():
        raise ValueError(f"--model: no file at {args.model}")
    if not Path(args.model).is_file():
        raise ValueError(f"--model {args.model} is not a regular file (a directory or a FIFO?); pass a model .zip")
    return LatentSwarmPPO.load(args.model, device=args.device, trust_pickle=args.trust_pickle)


EVALUATION_RECORD = "evaluation.json"
"""Written beside every evaluation's tables: what they were made from (model file hash, config, conditions, p_f values,
episodes and seeds, actions) and which tables are complete."""

EVALUATION_TABLES = ("conditions", "p_fail_sweep")
"""The tables an evaluation writes (``NAME.csv`` and ``NAME.md``)."""

RECORD_IDENTITY = ("model_sha256", "config", "episodes", "env_seeds", "actions")
"""What every table of one evaluation folder shares; each table adds its own inputs (``requested``)."""


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
    from sb3_latentswarm.evaluation import CONDITIONS
    from sb3_latentswarm.version import __version__

    model_path = model_path if model_path is not None else args.model
    p_fail_sweep = bool(getattr(args, "p_fail_sweep", False)) if p_fail_sweep is None else p_fail_sweep
    baselines = (not getattr(args, "no_baselines", False)) if baselines is None else baselines
    episodes = preset.eval_episodes
    conditions = list(CONDITIONS) + (["random", "lawnmower", "frontier"] if baselines else [])
    requested: dict[str, Any] = {"conditions": {"conditions": conditions, "p_fail": preset.config.p_fail}}
    if p_fail_sweep:
        requested["p_fail_sweep"] = {"conditions": ["proposed"], "p_fails": list(preset.p_fails)}
    return {
        "model": str(model_path),
        "model_sha256": file_sha256(model_path),
        "preset": preset.name,
        "config": preset.config.to_dict(),
        "episodes": episodes,
        "seed": args.seed,
        "env_seeds": [_eval_seed(args), _eval_seed(args) + episodes - 1],
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
        recorded = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        return f"its {path} cannot be read as JSON ({error}); remove it or pass another --output"
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
    kept = json.loads(path.read_text()).get("tables", {}) if path.exists() else {}
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


def command_evaluate(args: argparse.Namespace) -> int:
    from sb3_latentswarm.utils.atomic import probe_writable

    model = _load_model(args)
    preset = _preset_from_args(args, model)
    if args.episodes:
        preset = dataclasses.replace(preset, eval_episodes=args.episodes)
    record = _evaluation_record(preset, args)
    output = _evaluation_folder(args, record)
    probe_writable(output, room_bytes=1 << 20)
    _evaluate_and_print(model, preset, args, output, p_fail_sweep=args.p_fail_sweep, baselines=not args.no_baselines)
    return 0


def command_render(args: argparse.Namespace) -> int:
    from sb3_latentswarm.rendering import check_model_fits, render_episode

    model = _load_model(args) if args.model else None
    preset = _preset_from_args(args, model)
    check_model_fits(model, preset.config)
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
        if name in grid:
            raise ValueError(f"--grid {name} given twice; give all its values once: --grid {name}=V1,V2,...")
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
    from sb3_latentswarm.experiments import SweepSpec, run_sweep
    from sb3_latentswarm.experiments.spec import DEFAULT_VARIANTS

    spec = SweepSpec.create(
        args.preset,
        args.seeds,
        variants=args.variant or DEFAULT_VARIANTS,
        grid=_parse_grid(args.grid or []),
        overrides=parse_overrides(args.set or []),
        extra_eval_sets=[_parse_eval_set(text) for text in args.eval_set or []],
        eval_episodes=args.eval_episodes,
        **({} if args.eval_seed is None else {"eval_seed": args.eval_seed}),
        deterministic=not args.stochastic,
        total_timesteps=args.total_timesteps,
        warm_start=args.warm_start,
    )
    try:
        run_sweep(
            spec,
            address=args.address,
            storage=args.storage,
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
            "latent_dim=32); values are Python literals, validated as in Python; --list-settings lists the names",
        )
        p.add_argument("--list-settings", action=_ListSettings, help="print every --set name, by where it goes, and exit")
        p.add_argument(
            "--seed",
            type=int,
            default=0,
            help="random seed (default 0): for train, the model's seed and the env copies' (copy k gets SEED + k, or "
            "ENV_SEED + k with --env-seed); for render, the episode's env seed; for evaluate, the random baseline's "
            "seed (the episodes' seeds are --eval-seed's)",
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
            "recurrent nets on a loaded CPU; see sb3_latentswarm.utils.threads)",
        )
        p.add_argument("--no-progress", action="store_true", help="no progress bars (shown on a terminal otherwise)")
        p.add_argument(
            "--stochastic",
            action="store_true",
            help="sample the policy's Gaussian actions when evaluating or rendering (default: its mean action)",
        )

    def add_eval_seed(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--eval-seed",
            type=int,
            default=None,
            help="first evaluation episode seed, episode k uses eval_seed + k (default 1000000: held out from the "
            "training env seeds, which start at --env-seed, by default --seed)",
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
    train.add_argument(
        "--total-timesteps", type=int_at_least(1), default=None,
        help="override the preset's budget (agent-steps); with --resume, a larger one extends the run's budget"
    )
    train.add_argument(
        "--output",
        default=None,
        help="folder of the run: model.zip, progress.csv, checkpoints/, tables (default runs/PRESET); one run per folder",
    )
    train.add_argument(
        "--save-freq",
        type=int_at_least(0),
        default=None,
        metavar="AGENT_STEPS",
        help="agent-steps between checkpoints in OUTPUT/checkpoints/ (default: about 5 %% of the budget, in whole "
        "updates; with --resume, the run's; 0: only at the end and when stopped). A checkpoint is also written on "
        "SIGINT / SIGTERM",
    )
    train.add_argument(
        "--keep-checkpoints",
        type=int_at_least(1),
        default=None,
        metavar="K",
        help="keep the newest K checkpoints (default 3; with --resume, the run's)",
    )
    train.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --output from its newest checkpoint (settings not given are the checkpoint's; given "
        "ones must match)",
    )
    train.add_argument("--evaluate", action="store_true", help="evaluate all conditions and baselines afterwards")
    add_eval_seed(train)
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
        default=None,
        choices=("batched", "supersuit"),
        help="vec env backend: 'batched' (default, fast) or 'supersuit' (PettingZoo env via SuperSuit); same episodes",
    )
    train.add_argument(
        "--env-seed",
        type=int_at_least(0),
        default=None,
        metavar="ENV_SEED",
        help="seed of the first env copy, copy k gets ENV_SEED + k (default: --seed; with --resume, the run's). "
        "--seeds sets it for each seed",
    )
    train.add_argument(
        "--seeds",
        type=int_at_least(1),
        default=None,
        metavar="K",
        help="train seeds SEED .. SEED+K-1, each by this command in a single-thread process of its own, into "
        "OUTPUT/seedN/ (default 1: one seed, into OUTPUT itself); seed N's env copies get N * n_envs + k, as in sweep, "
        "so no two seeds share an env stream (--seed alone would give seed N copies N + k, shared with seed N+1); rerun "
        "with --resume to continue the unfinished ones",
    )
    train.add_argument(
        "--jobs",
        type=int_at_least(1),
        default=None,
        metavar="J",
        help="with --seeds: processes at a time (default: the cores this process may run on, at most K; more warns)",
    )
    train.set_defaults(func=command_train, preset=None, seed=None)

    evaluate = sub.add_parser("evaluate", help="evaluate a saved model on the five conditions of Table I")
    add_common(evaluate, None)
    evaluate.add_argument("--model", required=True, help="a LatentSwarmPPO model.zip (e.g. runs/demo/model.zip)")
    add_trust_pickle(evaluate)
    evaluate.add_argument(
        "--episodes", "--eval-episodes", dest="episodes", type=int_at_least(1), default=None,
        help="episodes per row (default: the preset's; --eval-episodes is the same option, as in sweep)",
    )
    add_eval_seed(evaluate)
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
    conditions = "proposed (default), full_comm, no_comm, no_predictor, no_memory, ...: sb3_latentswarm.evaluation.CONDITIONS"
    render.add_argument("--condition", default="proposed", help=f"test-time communication condition: {conditions}")
    render.add_argument("--output", default="episode.gif", help="file ending in .gif or .mp4 (needs imageio-ffmpeg)")
    render.add_argument("--fps", type=int_at_least(1), default=10, help="frames per second of the animation (default 10)")
    render.set_defaults(func=command_render)

    sweep = sub.add_parser("sweep", help="train seeds x variants (x a grid) on Ray Tune; across-seed intervals (extra sweep)")
    sweep.add_argument("--preset", required=True, choices=sorted(PRESETS), help="env, algorithm settings and budget")
    sweep.add_argument("--list-settings", action=_ListSettings, help="print every --set / --grid name, by target, and exit")
    sweep.add_argument("--seeds", type=int, required=True, help="training seeds 0 .. K-1 per variant and grid point")
    sweep.add_argument(
        "--variant",
        nargs="+",
        choices=("proposed", "no_comm", "zero_substitute", "hold_last", "independent"),
        help="learners to train (default: proposed no_comm independent); no_comm is LatentSwarmPPO trained with every "
        "link down, zero_substitute / hold_last are LatentSwarmPPO trained with zeros / the last received message in "
        "place of the predicted message during dropout",
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
    sweep.add_argument(
        "--total-timesteps", type=int_at_least(1), default=None, metavar="AGENT_STEPS",
        help="training budget of every trial (default: the preset's)",
    )
    sweep.add_argument(
        "--warm-start", default=None, metavar="SWEEP_DIR",
        help="continue the finished models of the sweep in SWEEP_DIR (same preset, grid and trained settings) up to "
        "--total-timesteps, instead of training from scratch; the trials' progress.csv start with that sweep's rows",
    )
    sweep.add_argument(
        "--eval-episodes", "--episodes", dest="eval_episodes", type=int_at_least(1), default=None,
        help="episodes per cell (default: the preset's; --episodes is the same option, as in evaluate)",
    )
    sweep.add_argument(
        "--eval-seed", type=int_at_least(0), default=None,
        help="first evaluation episode seed, episode k uses eval_seed + k (default 1000000: above every training env "
        "seed; a continuation of a continuation (--warm-start twice) seeds its env copies from 1000000 on and needs a "
        "larger one)",
    )
    sweep.add_argument("--stochastic", action="store_true", help="evaluate with sampled actions (default: the mean action)")
    sweep.add_argument("--address", default=None, help="Ray cluster to attach to (default: start Ray on this machine)")
    sweep.add_argument(
        "--storage", default=None, metavar="URI",
        help="Ray Tune storage for the trials' results: s3://, gs://, file:// or a path every node shares "
        "(default: OUTPUT/ray)",
    )
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


USER_ERRORS = (ValueError, TypeError, RuntimeError, OSError, ArithmeticError, MemoryError)
"""What a user's input can raise (bad settings, files, devices, torch's own checks): reported in one line, exit 2."""


def _check_device(args: argparse.Namespace) -> None:
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


def _check_output_folder(args: argparse.Namespace) -> None:
    """``--output`` of train, evaluate and sweep names a folder: an existing file there is an error, before any work."""
    output = getattr(args, "output", None)
    if args.command in ("train", "evaluate", "sweep") and output and Path(output).exists() and not Path(output).is_dir():
        raise ValueError(f"--output {output} is an existing file, not a folder")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.threads < 0:
        parser.exit(2, f"sb3-latentswarm {args.command}: error: --threads must be >= 0, got {args.threads}\n")
    if args.threads:
        from sb3_latentswarm.utils.threads import set_torch_threads

        set_torch_threads(args.threads)  # warns once past the available cores
    try:
        _check_device(args)
        _check_output_folder(args)
        return args.func(args)
    except USER_ERRORS as error:
        kind = "" if isinstance(error, (ValueError, TypeError)) else f"{type(error).__name__}: "
        message = " ".join(str(error).split())  # one line, whatever the library wrote
        parser.exit(2, f"sb3-latentswarm {args.command}: error: {kind}{message}\n")
    except KeyboardInterrupt:  # Ctrl-C outside training: the files finished so far are complete (atomic writes)
        print(f"\nsb3-latentswarm {args.command}: interrupted; the files it finished are kept", file=sys.stderr)
        return 130
    return 1


if __name__ == "__main__":
    sys.exit(main())
