"""Time to a trained swarm: learning curves against agent-steps AND against CPU seconds, for a preset's settings.

``train`` one run (one process, one torch thread) and log, beside SB3's ``progress.csv`` columns, the process's CPU
seconds at the end of each update (``time/cpu_seconds``, ``time.process_time``: per-thread CPU time, which other work
on the machine inflates far less than wall time)::

    python examples/time_to_coverage.py train --preset coordination --seed 0 --output runs/ttc/new-s0 \\
        --set batch_size=3840 --set n_epochs=3

``report`` reads several runs, groups them by label (the folder name without its ``-sN`` tail) and prints, per
label, the agent-steps and CPU seconds at which the training coverage (``rollout/coverage``: the mean over the last
``stats_window_size`` finished episodes) first reaches a target, the final coverage, and the ratio to a reference
label; it draws both curves (``--plot``). A run that never reaches the target counts with its whole budget, marked
``>``: the label's mean is then a lower bound, and the ratio says so (``>=`` or ``<=``)::

    python examples/time_to_coverage.py report runs/ttc/*-s? --reference old --target 0.95 --plot curves.png

A run's CPU seconds can also be reconstructed from another run's per-update cost (``--cpu-per-update LABEL=S``, for
runs logged before ``time/cpu_seconds`` existed); the report says which figures are reconstructed.
"""

from __future__ import annotations

import argparse
import csv
import re
import time
from pathlib import Path

import numpy as np


def _number(text: str) -> int | float | str:
    """``--set`` values: an int, else a float, else the text."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _train(args: argparse.Namespace) -> None:
    import torch as th
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure

    from sb3_latentswarm.presets import get_preset

    th.set_num_threads(1)
    overrides = {}
    for item in args.set:
        name, _, value = item.partition("=")
        overrides[name] = _number(value)
    preset = get_preset(args.preset).with_overrides(**overrides)
    output = Path(args.output)
    if (output / "model.zip").exists():
        raise SystemExit(f"{output / 'model.zip'} exists: one run per folder")
    if hasattr(preset, "make_env"):
        env = preset.make_env(args.seed)
        model = preset.make_model(env, seed=args.seed, verbose=0)
    else:  # a package from before Preset.make_env (b250de8 and older), run with PYTHONPATH to rerun old code
        from sb3_latentswarm import LatentSwarmPPO, make_vec_env

        env = make_vec_env(preset.n_envs, config=preset.config, seed=args.seed)
        model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=args.seed, verbose=0, **preset.algo_kwargs)
    model.set_logger(configure(str(output), ["csv"]))

    class CPUSeconds(BaseCallback):
        """Records ``time/cpu_seconds`` (process CPU time since ``learn`` started) with every update's row."""

        def _on_training_start(self) -> None:
            self.start = time.process_time()

        def _on_rollout_end(self) -> None:
            # SB3 dumps row k after rollout k and before its training: the row's coverage was measured by that
            # rollout, so its CPU time is the time at the rollout's end
            self.logger.record("time/cpu_seconds", time.process_time() - self.start)

        def _on_step(self) -> bool:
            return True

    total = args.total_timesteps or preset.total_timesteps
    model.learn(total_timesteps=total, callback=CPUSeconds())
    model.save(output / "model.zip")
    print(f"saved {output / 'model.zip'} after {time.process_time():.0f} CPU s")


def _read(run: Path) -> dict[str, np.ndarray]:
    with open(run / "progress.csv") as handle:
        rows = list(csv.DictReader(handle))

    def column(name: str) -> np.ndarray:
        return np.array([float(row[name]) if row.get(name) not in (None, "") else np.nan for row in rows])

    return {
        "steps": column("time/total_timesteps"),
        "coverage": column("rollout/coverage"),
        "cpu": column("time/cpu_seconds") if rows and "time/cpu_seconds" in rows[0] else np.full(len(rows), np.nan),
    }


def _report(args: argparse.Namespace) -> None:
    cpu_per_update = dict(item.split("=") for item in args.cpu_per_update)
    missing = [run for run in args.runs if not (Path(run) / "progress.csv").is_file()]
    if missing:
        raise SystemExit(f"no progress.csv in: {', '.join(missing)} (give the run folders of `train --output`)")
    if args.plot and not Path(args.plot).resolve().parent.is_dir():
        raise SystemExit(f"--plot {args.plot}: the folder {Path(args.plot).resolve().parent} does not exist")
    groups: dict[str, list[tuple[str, dict[str, np.ndarray]]]] = {}
    for run in map(Path, args.runs):
        label = re.sub(r"-s\d+$", "", run.name)
        groups.setdefault(label, []).append((run.name, _read(run)))
    if args.reference not in groups:
        raise SystemExit(f"--reference {args.reference!r} is none of the labels found: {', '.join(groups)} "
                         "(a run folder's name without its -sN tail)")
    summary = {}
    print(f"target: training coverage >= {args.target}")
    print("| label | run | updates | agent-steps to target | CPU s to target | final coverage | CPU s per update |")
    print("|---|---|---|---|---|---|---|")
    for label, runs in groups.items():
        hits_steps, hits_cpu, censored = [], [], 0
        for name, data in runs:
            cpu, reconstructed = data["cpu"], False
            if np.isnan(cpu).all() and label in cpu_per_update:
                cpu = float(cpu_per_update[label]) * np.arange(1, len(cpu) + 1)
                reconstructed = True
            per_update = float(np.nanmedian(np.diff(cpu))) if np.isfinite(cpu).sum() > 2 else np.nan
            reached = np.flatnonzero(data["coverage"] >= args.target)
            # a run that never reaches the target counts with its whole budget: a lower bound on its time to target
            index, mark = (reached[0], "") if len(reached) else (len(cpu) - 1, "> ")
            censored += not len(reached)
            step, seconds = data["steps"][index], cpu[index]
            hits_steps.append(step)
            hits_cpu.append(seconds)
            mark_cpu = " (reconstructed)" if reconstructed else ""
            print(f"| {label} | {name} | {len(cpu)} | {mark}{step:,.0f} | {mark}{seconds:,.0f}{mark_cpu} | "
                  f"{data['coverage'][-1]:.4f} | {per_update:.2f} |")
        summary[label] = (np.mean(hits_steps), np.mean(hits_cpu), censored)
    ref_steps, ref_cpu, ref_censored = summary[args.reference]
    for label, (steps, seconds, censored) in summary.items():
        # censored runs make a mean a lower bound: the reference's raises the ratio, the label's lowers it; with
        # both censored the ratio of two lower bounds says nothing
        both = censored and ref_censored and label != args.reference
        bound = ">= " if ref_censored and not censored else "<= " if censored and not ref_censored else ""
        ratios = f"{args.reference} / {label}: " + (
            "n/a, both have runs that never reached it" if both
            else f"{bound}{ref_steps / steps:.2f}x agent-steps, {bound}{ref_cpu / seconds:.2f}x CPU s"
        )
        note = f"; {censored} run(s) never reached it: the means are lower bounds" if censored else ""
        print(f"{label}: mean agent-steps to target {'>= ' if censored else ''}{steps:,.0f}, "
              f"CPU s {'>= ' if censored else ''}{seconds:,.0f} ({ratios}{note})")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for (label, runs), color in zip(groups.items(), colors):
            for index, (_name, data) in enumerate(runs):
                cpu = data["cpu"]
                if np.isnan(cpu).all() and label in cpu_per_update:
                    cpu = float(cpu_per_update[label]) * np.arange(1, len(cpu) + 1)
                kwargs = dict(color=color, alpha=0.8, label=label if index == 0 else None)
                axes[0].plot(data["steps"] / 1e6, data["coverage"], **kwargs)
                axes[1].plot(cpu, data["coverage"], **kwargs)
        for axis in axes:
            axis.axhline(args.target, color="grey", lw=0.8, ls="--")
            axis.grid(alpha=0.3)
        axes[0].set_xlabel("agent-steps (millions)")
        axes[1].set_xlabel("CPU seconds (one thread)")
        axes[0].set_ylabel("training coverage (last 100 episodes)")
        axes[0].legend()
        figure.suptitle(args.title)
        figure.tight_layout()
        from sb3_latentswarm.utils.atomic import atomic_path

        with atomic_path(args.plot) as tmp:
            figure.savefig(tmp, dpi=110, format="png")
        print(f"wrote {args.plot}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    train = sub.add_parser("train", help="train one run and log time/cpu_seconds")
    train.add_argument("--preset", default="coordination")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--output", required=True)
    train.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    train.add_argument("--total-timesteps", type=int, default=None)
    report = sub.add_parser("report", help="time to a coverage target, per label")
    report.add_argument("runs", nargs="+")
    report.add_argument("--target", type=float, default=0.95)
    report.add_argument("--reference", default="old")
    report.add_argument("--cpu-per-update", action="append", default=[], metavar="LABEL=SECONDS")
    report.add_argument("--plot", default=None)
    report.add_argument("--title", default="coordination: training coverage")
    args = parser.parse_args()
    _train(args) if args.command == "train" else _report(args)


if __name__ == "__main__":
    main()
