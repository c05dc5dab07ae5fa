"""``sb3-latentswarm sweep``: seeds x variants (x a grid) on Ray Tune (:mod:`sb3_latentswarm.experiments`)."""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from typing import Any

from sb3_latentswarm.cli import program_name
from sb3_latentswarm.cli.settings import parse_overrides


def command_sweep(args: argparse.Namespace) -> int:
    """``sweep``: the sweep spec from the options (checked whole before Ray starts), then the trials on Ray Tune.

    :return: 0; 1 when trials failed (the finished ones are aggregated, ``--resume`` retries the others); 128 + the
        signal's number when SIGINT / SIGTERM / SIGHUP stopped it (Ray Tune stopped cleanly; the resume command printed)
    """
    from sb3_latentswarm.experiments import SweepSpec, run_sweep
    from sb3_latentswarm.experiments.spec import ADAPTED_DEFAULT_VARIANTS, DEFAULT_VARIANTS
    from sb3_latentswarm.experiments.sweep import SweepStopped

    spec = SweepSpec.create(
        args.preset,
        args.seeds,
        variants=args.variant or (DEFAULT_VARIANTS if args.adapted_env is None else ADAPTED_DEFAULT_VARIANTS),
        grid=_parse_grid(args.grid or []),
        overrides=args.overrides,  # --set, parsed by check_arguments
        extra_eval_sets=[_parse_eval_set(text) for text in args.eval_set or []],
        eval_episodes=args.eval_episodes,
        **({} if args.eval_seed is None else {"eval_seed": args.eval_seed}),
        deterministic=not args.stochastic,
        total_timesteps=args.total_timesteps,
        warm_start=args.warm_start,
        env=args.adapted_env,
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
    except SweepStopped as stopped:  # SIGINT / SIGTERM / SIGHUP: Ray stopped cleanly, the finished trials are kept
        argv = [arg for arg in args.argv if arg != "--resume"]
        print(
            f"\nsb3-latentswarm sweep: stopped by {stopped.name}; finished trials are kept in {stopped.output}. Resume "
            f"with:\n  {shlex.join([program_name(), *argv, '--resume'])}",
            file=sys.stderr,
        )
        return stopped.exit_code
    except RuntimeError as error:  # failed trials: the finished ones are reported, --resume retries the rest
        print(f"sb3-latentswarm sweep: {error}", file=sys.stderr)
        return 1
    return 0


def _parse_grid(pairs: list[str]) -> dict[str, Sequence[Any]]:
    """``["p_fail=0.1,0.3"]`` -> ``{"p_fail": [0.1, 0.3]}`` (values typed like ``--set``'s)."""
    grid: dict[str, Sequence[Any]] = {}
    for pair in pairs:
        name, _, raw = pair.partition("=")
        if not raw:
            raise ValueError(f"--grid expects FIELD=V1,V2,..., got {pair!r}")
        if name in grid:
            raise ValueError(f"--grid {name} given twice; give all its values once: --grid {name}=V1,V2,...")
        grid[name] = [parse_overrides([f"{name}={value}"], "--grid")[name] for value in raw.split(",")]
    return grid


def _parse_eval_set(text: str):
    """``"burst10=outage_model=gilbert_elliott,mean_outage_steps=10,conditions=proposed+no_predictor"`` -> EvalSet."""
    from sb3_latentswarm.experiments import EvalSet

    name, _, raw = text.partition("=")
    if not name or not raw:
        raise ValueError(f"--eval-set expects NAME=FIELD=VALUE[,FIELD=VALUE...][,conditions=C1+C2], got {text!r}")
    pairs = raw.split(",")
    conditions = [pair.partition("=")[2] for pair in pairs if pair.startswith("conditions=")]
    overrides = parse_overrides([pair for pair in pairs if not pair.startswith("conditions=")], f"--eval-set {name}")
    return EvalSet(name, overrides, tuple(conditions[-1].split("+")) if conditions else None)
