"""``sb3-latentswarm train``: one run (:class:`~sb3_latentswarm.runs.run.Run`) from the command line's settings, or
``--seeds K`` of them (:mod:`sb3_latentswarm.cli.seeds`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from sb3_latentswarm.callbacks import RolloutProgressBarCallback, whole_rollouts
from sb3_latentswarm.cli import resume_command
from sb3_latentswarm.cli.evaluate import EVALUATION_TABLES, evaluate_and_print
from sb3_latentswarm.cli.seeds import command_train_seeds
from sb3_latentswarm.cli.settings import checked_training_preset, parse_overrides, train_settings
from sb3_latentswarm.envs.adapted_env import AdaptedEnv
from sb3_latentswarm.presets import Preset
from sb3_latentswarm.runs.checkpoints import default_save_freq, resume_tensorboard
from sb3_latentswarm.runs.run import CheckpointWriteError, Run, RunHooks, RunResult, RunSpec, RunStopped
from sb3_latentswarm.runs.train_seeds import SEEDS_RECORD
from sb3_latentswarm.utils.locks import output_lock


def command_train(args: argparse.Namespace) -> int:
    """``train``: validate every setting, probe the output folder, train with checkpoints, save ``model.zip``: one
    :class:`~sb3_latentswarm.runs.run.Run`.

    ``--resume`` continues the newest checkpoint in ``--output``; SIGINT / SIGTERM write a checkpoint and exit with
    128 + the signal number (see ``docs/long_runs.md``). ``--seeds K`` > 1 (or an ``--output`` holding a
    ``seeds.json``) runs this command once per seed, in processes of their own
    (:func:`~sb3_latentswarm.cli.seeds.command_train_seeds`).
    """
    output = Path(args.output or f"runs/{args.preset or 'demo'}")
    args.output = str(output)
    if output.exists() and not output.is_dir():
        raise ValueError(f"--output {output} is an existing file, not a folder")
    if (args.seeds or 1) > 1 or (output / SEEDS_RECORD).exists():
        with output_lock(output):  # the seeds' parent folder, held while the seeds train (each seed holds its own)
            return command_train_seeds(args, output)
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
        settings = train_settings(args, stored)
        # a checkpoint may name a registered env; an entry point runs only when --env names it again (docs/security.md)
        args.adapted_env = AdaptedEnv.from_record(settings, args.adapted_env, f"the checkpoint {run.start}")
        args.env = settings["env"]
        args.preset, args.set, args.seed = settings["preset"], settings["set"], settings["seed"]
        args.backend, args.env_seed = settings["backend"], settings["env_seed"]
        args.overrides = parse_overrides(args.set)  # a resumed run's are its checkpoint's
        preset = checked_training_preset(args)
        total = settings["total_timesteps"] = settings["total_timesteps"] or preset.total_timesteps
        if args.save_freq is None:  # the run's own frequency on --resume (not compared: it changes no result)
            args.save_freq = stored.get("save_freq", default_save_freq(total, preset.agent_steps_per_update))
        if args.keep_checkpoints is None:
            args.keep_checkpoints = stored.get("keep_checkpoints", 3)
        # the checkpoint never decides where the run writes: its folder only inside --output, else --tensorboard's
        tensorboard, tensorboard_run, note = resume_tensorboard(output, args.tensorboard, stored, f"latentswarm_{preset.name}")
        if note:
            print(note)
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
            run.train(spec, _TrainCommandHooks(args, preset, stored))
        except CheckpointWriteError as error:
            print(
                f"sb3-latentswarm train: error: {error}; free some space and resume with:\n  {resume_command(output)}",
                file=sys.stderr,
            )
            return 1
        except RunStopped as stopped:
            if stopped.saved:
                print(f"Stopped by {stopped.name} after the last update", file=sys.stderr)
            else:
                print(
                    f"\nStopped by {stopped.name or 'a second signal'} after {stopped.seconds:.0f} s; checkpoint "
                    f"{stopped.checkpoint} (the rollout in progress is not kept). Resume with:\n  {resume_command(output)}",
                    file=sys.stderr,
                )
            return stopped.exit_code
    return 0


def actor_line(policy: Any) -> str:
    """The banner's line on the actor: its distribution, and what the env gets of its actions
    (:meth:`~sb3_latentswarm.LatentSwarmPolicy.env_actions`)."""
    low, high = policy.action_space.low, policy.action_space.high
    uniform = low.min() == low.max() and high.min() == high.max()
    box = f"[{low.min():g}, {high.min():g}]" if uniform else f"[{low.tolist()}, {high.tolist()}]"
    if not policy.squash_output:
        hint = ""
        if not policy.unit_action_box:
            hint = " (--set action_distribution=squashed_gaussian: the squashed actor, rescaled to the box)"
        return f"Actor: Gaussian, sampled actions clipped to the action box {box}{hint}"
    if policy.rescale_actions:
        return f"Actor: tanh-squashed Gaussian, actions rescaled from [-1, 1] to the action box {box}"
    return f"Actor: tanh-squashed Gaussian, actions inside the action box {box}"


class _TrainCommandHooks(RunHooks):
    """What ``train`` says while its run goes, its progress bar and its ``--evaluate``."""

    def __init__(self, args: argparse.Namespace, preset: Preset, stored: dict[str, Any]):
        self.args, self.preset, self.stored = args, preset, stored

    def callbacks(self) -> list[Any]:
        return [RolloutProgressBarCallback()] if not self.args.no_progress and sys.stderr.isatty() else []

    def started(self, run: Run) -> None:
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
            if preset.env is not None:
                overrides += f" on {preset.env.name} {json.dumps(dict(preset.env.kwargs))}"
            print(
                f"Training preset '{preset.name}'{overrides} for {end:,} agent-steps{rounded}: {preset.n_envs} swarms of "
                f"{preset.config.n_agents}, n_steps {model.n_steps}, {end // per_rollout} updates, seed {args.seed} "
                f"({copies})"
            )
            rate = model.learning_rate
            rate_text = f"{rate:g}" if isinstance(rate, (int, float)) else repr(rate)
            epochs = f"{model.n_epochs} epoch{'s' if model.n_epochs != 1 else ''}"
            print(f"PPO: learning rate {rate_text}, minibatch {model.batch_size:,} agent-steps, {epochs}")
            print(actor_line(model.policy))
        print(f"Checkpoints every {args.save_freq:,} agent-steps in {run.checkpoint_dir} (keeping {args.keep_checkpoints})")
        # now: a run killed by kill -9 prints nothing at its end
        print(f"If stopped, resume with: {resume_command(run.output)}")

    def saved(self, run: Run, result: RunResult) -> None:
        print(f"Trained in {result.train_seconds:.0f} s; saved {result.model_path}")

    def evaluate(self, run: Run, result: RunResult) -> None:
        if self.args.evaluate:
            evaluate_and_print(
                result.model, self.preset, self.args, run.output, p_fail_sweep=False, baselines=True,
                model_path=result.model_path,
            )
