"""``sb3-latentswarm train --seeds K [--jobs J]``: K training seeds of one run, each in its own single-thread process.

Seed ``S + i`` is trained by the single-seed command, ``python -m sb3_latentswarm.cli train --seed S+i --env-seed
(S+i)*n_envs --output OUTPUT/seedS+i ...`` (env copy ``c`` seeded ``(S+i) * n_envs + c``, the rule of ``sweep``,
:func:`~sb3_latentswarm.utils.seeding.training_env_seed`: no two seeds share an env copy), in a process of its own
with one torch thread (``OMP_NUM_THREADS=1``, ``MKL_NUM_THREADS=1``), at most J processes at a time: there is one
implementation of training, and every seed folder holds exactly what a single ``train`` writes (``model.zip``,
``config.json``, ``progress.csv``, ``checkpoints/``, the tables of ``--evaluate``), plus ``train.log``, the
process's output.

Why processes and not threads: these recurrent networks are small, a training step is many short kernels, and a
second OpenMP thread spin-waits for a core that another process holds. On this project's 2-core machine under load,
a ``coordination`` update took 144 s with two torch threads against 2.7 s with one (0.02x), and the README's model
trained at 0.06x of one thread's speed with two (:mod:`sb3_latentswarm.utils.threads`). Independent seeds need no
communication, so one single-thread process per core is the fastest way to use several cores, the way CleanRL's
``benchmark.py`` (``--num-seeds``, ``--workers``) and Ray Tune's ``with_resources({"cpu": 1})`` pack runs.

This module runs the processes (:func:`run_seed_processes`: start, wait, forward signals, collect exit codes and CPU
seconds) and reads a seed folder's state (:func:`seed_state`) and result (:func:`last_coverage`); the ``train``
subcommand (:mod:`sb3_latentswarm.cli`) validates the arguments, plans the seeds and prints the results.
"""

from __future__ import annotations

import csv
import math
import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sb3_latentswarm.utils.signals import SignalHandlers

SEEDS_RECORD = "seeds.json"
"""Written into ``train --seeds``'s ``--output``: the run's settings, the number of seeds and each seed's result;
what ``--resume`` compares and continues."""

TRAIN_LOG = "train.log"
"""Each seed folder's log: the standard output and error of its ``train`` process (appended to on resume)."""

FORWARDED_SIGNALS: dict[int, int] = {
    signal.SIGINT: signal.SIGINT,
    signal.SIGTERM: signal.SIGTERM,
    signal.SIGHUP: signal.SIGTERM,
}
"""Signal the parent receives -> signal it sends to every running seed (``train`` checkpoints on SIGINT / SIGTERM;
a closed terminal's SIGHUP becomes a SIGTERM)."""


def seed_folder(output: str | Path, seed: int) -> Path:
    """``OUTPUT/seed{seed}``: the folder of one training seed."""
    return Path(output) / f"seed{seed}"


def seed_state(folder: str | Path, evaluate: bool = False) -> str:
    """What ``train --seeds`` does with a seed folder.

    :param folder: the seed's folder
    :param evaluate: whether the run evaluates its model (``--evaluate``): a seed is finished only with its tables
    :return: ``"finished"`` (``model.zip``, and with ``evaluate`` the ``conditions`` table: skipped), ``"unfinished"``
        (checkpoints: continued with ``train --resume``), or ``"new"`` (trained from the start)
    """
    from sb3_latentswarm.runs.checkpoints import list_checkpoints

    folder = Path(folder)
    if (folder / "model.zip").is_file() and (not evaluate or (folder / "conditions.csv").is_file()):
        return "finished"
    return "unfinished" if list_checkpoints(folder / "checkpoints") else "new"


def last_coverage(folder: str | Path) -> float | None:
    """The last ``rollout/coverage`` in ``folder/progress.csv`` (the mean final coverage of the swarm episodes that
    ended in the last update), or ``None`` where there is none."""
    path = Path(folder) / "progress.csv"
    if not path.is_file():
        return None
    value = None
    with path.open(newline="") as handle:
        for row in csv.DictReader(handle):
            text = (row.get("rollout/coverage") or "").strip()
            if text:
                value = float(text)
    return value if value is not None and math.isfinite(value) else None


@dataclass(frozen=True)
class SeedRun:
    """One seed's ``train`` process.

    :param seed: the training seed (``--seed``)
    :param folder: its ``--output`` (``OUTPUT/seed{seed}``)
    :param argv: the ``sb3-latentswarm`` arguments (``("train", "--seed", "3", ...)``)
    :param resume: whether ``argv`` continues the seed's checkpoint (``train --resume``)
    """

    seed: int
    folder: Path
    argv: tuple[str, ...]
    resume: bool = False

    @property
    def log(self) -> Path:
        return self.folder / TRAIN_LOG

    @property
    def command(self) -> list[str]:
        """The process's command line: this Python, ``-m sb3_latentswarm.cli``, then :attr:`argv`."""
        return [sys.executable, "-m", "sb3_latentswarm.cli", *self.argv]


@dataclass(frozen=True)
class SeedResult:
    """How one seed's process ended.

    :param seed: the training seed
    :param folder: its folder
    :param status: ``"trained"`` (exit 0), ``"failed"`` (another exit code), ``"stopped"`` (ended after a signal was
        forwarded to it: it wrote a checkpoint) or ``"not started"`` (a signal came first)
    :param exit_code: the process's exit status (``-N``: killed by signal N), ``None`` when not started
    :param wall_seconds: seconds from start to exit
    :param cpu_seconds: user + system CPU seconds of the process (``os.wait4``), ``None`` where not measured
    :param coverage: :func:`last_coverage` of the folder after the process ended
    """

    seed: int
    folder: Path
    status: str
    exit_code: int | None = None
    wall_seconds: float | None = None
    cpu_seconds: float | None = None
    coverage: float | None = None

    @property
    def log(self) -> Path:
        return self.folder / TRAIN_LOG

    def as_record(self) -> dict[str, Any]:
        """Plain data for :data:`SEEDS_RECORD`."""
        return {
            "status": self.status,
            "exit_code": self.exit_code,
            "wall_seconds": self.wall_seconds,
            "cpu_seconds": self.cpu_seconds,
            "coverage": self.coverage,
            "log": str(self.log),
        }


def child_environment(threads: int = 1) -> dict[str, str]:
    """This process's environment with ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` set to ``threads`` and unbuffered
    output (the log shows each line as it is written)."""
    return {
        **os.environ,
        "OMP_NUM_THREADS": str(threads),
        "MKL_NUM_THREADS": str(threads),
        "PYTHONUNBUFFERED": "1",
    }


class _Signals(SignalHandlers):
    """Context manager recording SIGINT / SIGTERM / SIGHUP (main thread only) instead of acting on them."""

    SIGNALS = tuple(FORWARDED_SIGNALS)

    def __enter__(self) -> _Signals:
        return super().__enter__()


@dataclass
class _Running:
    run: SeedRun
    process: subprocess.Popen
    start: float
    signalled: bool = False


def _reap(running: _Running) -> tuple[int, float | None] | None:
    """The exit code and CPU seconds of a process that has ended, else ``None`` (without blocking)."""
    if hasattr(os, "wait4"):
        pid, status, usage = os.wait4(running.process.pid, os.WNOHANG)
        if pid == 0:
            return None
        running.process.returncode = os.waitstatus_to_exitcode(status)
        return running.process.returncode, usage.ru_utime + usage.ru_stime
    code = running.process.poll()
    return None if code is None else (code, None)


def run_seed_processes(
    runs: Sequence[SeedRun],
    jobs: int,
    threads: int = 1,
    on_start: Callable[[SeedRun], None] | None = None,
    on_finish: Callable[[SeedResult], None] | None = None,
    poll_seconds: float = 0.2,
) -> tuple[list[SeedResult], int | None]:
    """Run every seed's ``train`` process, at most ``jobs`` at a time, in the order given.

    Each process writes its output to :attr:`SeedRun.log` (appended, after a line with its command), runs in a
    session of its own (so that a terminal's Ctrl-C reaches it once, from here) with ``threads`` OpenMP / MKL
    threads. A SIGINT, SIGTERM or SIGHUP received here is forwarded to every running process
    (:data:`FORWARDED_SIGNALS`: each writes a checkpoint and exits), the seeds not yet started are not started, and
    the function returns once every process has ended. A second signal is forwarded too (``train`` then stops at once,
    still writing its last captured state). If this function itself fails, the running processes get SIGTERM and
    are waited for.

    :param runs: the processes to run (:class:`SeedRun`)
    :param jobs: the most processes at a time, >= 1
    :param threads: torch threads of each process (``OMP_NUM_THREADS``), >= 1
    :param on_start: called with each run as its process starts
    :param on_finish: called with each result as its process ends (and for each seed a signal kept from starting)
    :param poll_seconds: how often the processes are checked
    :return: the results in ``runs``' order, and the first signal received (``None`` if none)
    :raises ValueError: ``jobs`` or ``threads`` < 1
    :raises TypeError: ``jobs`` or ``threads`` not an int
    """
    from sb3_latentswarm.utils.checks import check_float, check_int

    check_int("jobs", jobs, low=1)
    check_int("threads", threads, low=1)
    check_float("poll_seconds", poll_seconds, low=0.0, low_open=True)
    pending = list(runs)
    running: list[_Running] = []
    results: dict[int, SeedResult] = {}
    forwarded = 0
    env = child_environment(threads)

    def finish(result: SeedResult) -> None:
        results[result.seed] = result
        if on_finish is not None:
            on_finish(result)

    with _Signals() as signals:
        try:
            while pending or running:
                if forwarded < len(signals.received):  # forward each new signal once to every running process
                    for signum in signals.received[forwarded:]:
                        for job in running:
                            job.process.send_signal(FORWARDED_SIGNALS[signum])
                            job.signalled = True
                    forwarded = len(signals.received)
                    for run in pending:
                        finish(SeedResult(run.seed, run.folder, "not started"))
                    pending.clear()
                while pending and len(running) < jobs:
                    run = pending.pop(0)
                    run.folder.mkdir(parents=True, exist_ok=True)
                    with run.log.open("a") as log:
                        log.write(f"$ sb3-latentswarm {shlex.join(run.argv)}\n")
                        log.flush()
                        process = subprocess.Popen(
                            run.command, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
                        )
                    running.append(_Running(run, process, time.perf_counter()))
                    if on_start is not None:
                        on_start(run)
                time.sleep(poll_seconds)
                for job in list(running):
                    ended = _reap(job)
                    if ended is None:
                        continue
                    running.remove(job)
                    code, cpu = ended
                    status = "trained" if code == 0 else "stopped" if job.signalled else "failed"
                    wall = time.perf_counter() - job.start
                    finish(SeedResult(job.run.seed, job.run.folder, status, code, wall, cpu, last_coverage(job.run.folder)))
        finally:
            for job in running:  # only on an error here: never leave a seed training without its parent
                job.process.send_signal(signal.SIGTERM)
            for job in running:
                job.process.wait()
    order = {run.seed: k for k, run in enumerate(runs)}
    first_signal = signals.received[0] if signals.received else None
    return sorted(results.values(), key=lambda result: order[result.seed]), first_signal
