"""``build_parser``: every subcommand and option of ``sb3-latentswarm``, with its help (imports nothing heavy, so that
``--help`` answers at once)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from typing import Any

from sb3_latentswarm.presets import PRESETS
from sb3_latentswarm.utils.checks import check_int
from sb3_latentswarm.version import __version__


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



def add_action_mode(parser: argparse.ArgumentParser, when: str) -> None:
    """``--deterministic`` / ``--stochastic``: the action mode, sampled by default (the paper's test-time protocol).

    Both set ``stochastic``; ``--stochastic`` is kept for 0.1 command lines (it is the default now).
    """
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--deterministic", dest="stochastic", action="store_false",
        help=f"act with the policy's mean action when {when} (default: sampled actions, the paper's protocol)",
    )
    mode.add_argument(
        "--stochastic", dest="stochastic", action="store_true",
        help="sample the policy's Gaussian actions (the default; kept for 0.1 command lines)",
    )
    parser.set_defaults(stochastic=True)

def add_env(parser: argparse.ArgumentParser, what: str) -> None:
    """``--env`` / ``--env-kwargs``: an adapted PettingZoo env instead of the swarm env (docs/own_env.md, docs/cli.md)."""
    parser.add_argument(
        "--env", default=None, metavar="NAME",
        help=f"{what} on a PettingZoo ParallelEnv through the adapter instead of the swarm env: a registered name "
        "(mpe2:simple_spread_v3, with its positions and metrics) or your Python entry point package.module:function "
        "returning the env (imported: your code runs; never read from a file). The preset gives the algorithm "
        "settings and budget, --set the link model (link_model=outage by default, p_fail, link_mode, ...)",
    )
    parser.add_argument(
        "--env-kwargs", default=None, metavar="JSON",
        help='keyword arguments of --env as a JSON object, e.g. \'{"N": 3, "num_agent_neighbors": 1}\'',
    )


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
        add_action_mode(p, "evaluating or rendering")

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
    add_env(train, "train")
    train.set_defaults(preset=None, seed=None)

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
    add_env(evaluate, "evaluate (a model trained with train --env)")
    evaluate.add_argument(
        "--output",
        default=None,
        help="folder for the tables and evaluation.json, the record of what they were made from (default: evaluation/ "
        "next to the model; evaluation-HASH/ when that holds another evaluation's tables)",
    )

    render = sub.add_parser("render", help="write an animated GIF (or MP4) of one episode and a trajectory figure")
    add_common(render, None)
    render.add_argument("--model", default=None, help="saved model (default: random actions)")
    add_trust_pickle(render)
    conditions = ("proposed (default), full_comm, no_comm, no_predictor, no_memory, hold_last, ...: "
                  "sb3_latentswarm.evaluation.CONDITION_TABLE")
    render.add_argument("--condition", default="proposed", help=f"test-time communication condition: {conditions}")
    render.add_argument("--output", default="episode.gif", help="file ending in .gif or .mp4 (needs imageio-ffmpeg)")
    render.add_argument("--fps", type=int_at_least(1), default=10, help="frames per second of the animation (default 10)")
    add_env(render, "render (the env's own frames, render_mode='rgb_array'; a model trained with train --env)")

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
    add_action_mode(sweep, "evaluating the trials")
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
    add_env(sweep, "sweep (default variants then: proposed no_comm zero_substitute hold_last)")
    sweep.add_argument("--verbose", type=int, default=1, help="Ray Tune console: 0 silent, 1 status table, 2 trial results")
    sweep.set_defaults(threads=1)
    return parser
