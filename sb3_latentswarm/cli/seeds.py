"""``sb3-latentswarm train --seeds K``: plan the seeds, check everything once, run each seed's single-seed ``train``
in a process of its own (:mod:`sb3_latentswarm.runs.train_seeds`) and report."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sb3_latentswarm.cli import resume_command
from sb3_latentswarm.cli.evaluate import EVALUATION_TABLES
from sb3_latentswarm.cli.settings import checked_training_preset, parse_overrides, train_settings
from sb3_latentswarm.envs.adapted_env import AdaptedEnv
from sb3_latentswarm.runs.run import find_start, required_room
from sb3_latentswarm.runs.train_seeds import SEEDS_RECORD, SeedRun, run_seed_processes, seed_folder, seed_state
from sb3_latentswarm.utils import threads as torch_threads
from sb3_latentswarm.utils.atomic import probe_writable, read_json, write_json
from sb3_latentswarm.utils.seeding import training_env_seed
from sb3_latentswarm.version import __version__


def command_train_seeds(args: argparse.Namespace, output: Path) -> int:
    """``train --seeds K [--jobs J]``: seeds ``S .. S+K-1`` in ``OUTPUT/seed{S+i}/``, each by the single-seed
    ``train`` in a single-thread process of its own (:mod:`sb3_latentswarm.runs.train_seeds`), at most J at a time.

    Every argument, the preset's settings (by building the env and model of seed S) and the folders are checked
    before any process starts or any file is written. ``--resume`` (or the same command with ``--resume``) skips the
    finished seeds, continues the unfinished ones from their checkpoints and starts the others.

    :return: 0; 1 when a seed failed; 128 + the signal's number when stopped by SIGINT / SIGTERM / SIGHUP
    """
    record_path = output / SEEDS_RECORD
    record: dict[str, Any] | None = None
    if record_path.exists():
        try:
            record = read_json(record_path)
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
    settings = train_settings(args, (record or {}).get("settings"), source=SEEDS_RECORD)
    args.adapted_env = AdaptedEnv.from_record(settings, args.adapted_env, str(record_path))
    args.env = settings["env"]
    recorded_total = ((record or {}).get("settings") or {}).get("total_timesteps")
    if recorded_total is not None and settings["total_timesteps"] != recorded_total:
        raise ValueError(
            f"--resume --total-timesteps {settings['total_timesteps']}: the seeds of {args.output} were started with "
            f"{recorded_total}; a --seeds run keeps its budget (finished seeds are skipped). Extend one seed with "
            f"train --resume --output {args.output}/seedN --total-timesteps {settings['total_timesteps']}"
        )
    del settings["env_seed"]  # each seed's own (training_env_seed), recorded in env_seeds below
    args.preset, args.set, args.seed, args.backend = settings["preset"], settings["set"], settings["seed"], settings["backend"]
    args.overrides = parse_overrides(args.set)  # a resumed run's are its record's
    n_seeds = args.seeds or int((record or {}).get("seeds", 1))
    given = {name: getattr(args, name) for name in SEED_OPTIONS}
    options = {name: stored.get(name, value) if value is None or value is False else value for name, value in given.items()}
    args.evaluate, args.eval_seed = options["evaluate"], options["eval_seed"]
    preset = checked_training_preset(args, n_seeds=n_seeds)  # --evaluate: held out from every seed's env copies
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
    cores = torch_threads.available_cores()  # looked up at call time (tests patch it)
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
    print(f"If stopped, resume with: {resume_command(output)}")  # now: kill -9 of this command prints nothing at its end
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
            + f". Resume every unfinished seed with:\n  {resume_command(output)}",
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
            f"seeds with:\n  {resume_command(output)}",
            file=sys.stderr,
        )
        return 1
    return 0


SEED_OPTIONS = ("evaluate", "eval_seed", "stochastic", "tensorboard", "save_freq", "keep_checkpoints")
"""``train --seeds`` options stored in its record and passed to every seed's process; ``--resume`` takes the stored
value of each one not given again (the settings of :data:`RESUME_SETTINGS` must match, as for one seed)."""


def _seed_argv(
    args: argparse.Namespace, settings: dict[str, Any], options: dict[str, Any], seed: int, resume: bool, n_envs: int
):
    """The ``sb3-latentswarm`` arguments that train (or, with ``resume``, continue) one seed of ``train --seeds``:
    model seed ``seed``, env copies from :func:`~sb3_latentswarm.utils.seeding.training_env_seed` ``(seed, n_envs)``
    (a resumed seed takes both from its checkpoint)."""
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
    if settings.get("env") is not None:  # also on resume: a seed's checkpoint never imports an entry point by itself
        argv += ["--env", settings["env"], "--env-kwargs", json.dumps(settings.get("env_kwargs") or {})]
    for name, value in given.items():
        if value is not None:
            argv += [f"--{name.replace('_', '-')}", str(value)]
    if args.threads:
        argv += ["--threads", str(args.threads)]
    if options["evaluate"]:
        argv.append("--evaluate")
    if options["eval_seed"] is not None:
        argv += ["--eval-seed", str(options["eval_seed"])]
    argv.append("--stochastic" if options["stochastic"] else "--deterministic")
    return tuple(argv)


def _last_line(path: Path, limit: int = 300) -> str:
    """The last non-empty line of a text file (at most ``limit`` characters), ``""`` where there is none."""
    try:
        lines = [line.strip() for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return lines[-1][:limit] if lines else ""
