"""Old against new code, interleaved: one benchmark script run on a git revision's package and on the working tree.

The benchmarks' ``--compare REV --rounds R`` use this module. ``REV``'s ``sb3_latentswarm`` is exported with
``git archive`` into a temporary folder; each round then runs the benchmark command once under
``PYTHONPATH=<old package>`` and once under ``PYTHONPATH=<working tree>``, old first, in fresh subprocesses with one
torch/OpenMP thread (``OMP_NUM_THREADS=MKL_NUM_THREADS=1``), so that the machine's load falls on both alike. The
script itself is always the working tree's, so it must tolerate an old package (missing arguments or modules).

Each run must print its result as one JSON value on the last line of its standard output; :func:`alternate` parses
it and adds the child's process CPU seconds (user + sys, from ``resource.getrusage(RUSAGE_CHILDREN)``) and wall
seconds of the whole subprocess.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
"""The working tree: its ``sb3_latentswarm`` is the new code."""
PACKAGE = "sb3_latentswarm"
ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
CODES = ("old", "new")


@dataclass(frozen=True)
class Run:
    """One subprocess of :func:`alternate`."""

    code: str
    """``"old"`` (the revision's package) or ``"new"`` (the working tree's)."""
    round: int
    """0-based round index."""
    result: Any
    """The JSON value on the last line of the run's standard output."""
    child_cpu_s: float
    """User + sys CPU seconds of the whole subprocess (imports and setup included)."""
    wall_s: float
    """Wall seconds of the whole subprocess."""


def check_revision(rev: str) -> str:
    """The full commit hash of ``rev`` in this repository.

    :raise ValueError: ``rev`` is not a commit here, or this is not a git checkout
    """
    try:
        out = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
                             capture_output=True, text=True, check=False)
    except FileNotFoundError as error:
        raise ValueError(f"--compare {rev}: git is not installed ({error})") from error
    if out.returncode != 0:
        raise ValueError(f"--compare {rev}: not a commit of the git checkout {REPO}")
    return out.stdout.strip()


def export_package(rev: str, dest: str | os.PathLike[str]) -> Path:
    """Write revision ``rev``'s ``sb3_latentswarm`` folder into ``dest`` (``git archive | tar -x``); return ``dest``."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, PACKAGE], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return Path(dest)


def last_json_line(stdout: str) -> Any:
    """The JSON value on the last non-empty line of ``stdout``.

    :raise ValueError: there is no output, or its last line is not JSON
    """
    lines = [line for line in stdout.splitlines() if line.strip()]
    if not lines:
        raise ValueError("the benchmark run printed nothing (expected a JSON line last)")
    try:
        return json.loads(lines[-1])
    except json.JSONDecodeError as error:
        raise ValueError(f"the benchmark run's last line is not JSON: {lines[-1][:200]!r}") from error


def run_once(command: Sequence[str], root: str | os.PathLike[str]) -> tuple[Any, float, float]:
    """Run ``command`` with ``PYTHONPATH=root`` and one thread, in ``root``: (last JSON line, child CPU s, wall s).

    :raise RuntimeError: the command failed (its stderr's tail in the message)
    """
    env = {**os.environ, "PYTHONPATH": str(root), **ONE_THREAD}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(list(command), env=env, cwd=str(root), capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} (PYTHONPATH={root}) exited {done.returncode}:\n{done.stderr[-3000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return last_json_line(done.stdout), cpu, wall


def alternate(
    script: str | os.PathLike[str],
    arguments: Sequence[str],
    rev: str,
    rounds: int,
    on_run: Callable[[Run], None] | None = None,
) -> dict[str, list[Run]]:
    """``python script *arguments`` on ``rev``'s package and on the working tree's, alternating, ``rounds`` rounds
    (old first in even rounds, new first in odd ones).

    :param script: the benchmark script (run by this interpreter, ``sys.executable``)
    :param arguments: its arguments; they must make it print one JSON line last
    :param rev: a git revision of this repository (the old code)
    :param rounds: old/new pairs, >= 1
    :param on_run: called after each run (e.g. to print progress, so that a long comparison shows partial results)
    :return: ``{"old": [Run, ...], "new": [Run, ...]}``, one run per round each
    :raise ValueError: ``rounds`` < 1 or ``rev`` not a commit (before any run); TypeError: ``rounds`` not an int
    :raise RuntimeError: a run failed
    """
    # imported here: the benchmark scripts import this module in their old-package runs too, which may predate it
    from sb3_latentswarm.utils.checks import check_int

    check_int("--rounds", rounds, low=1)
    check_revision(rev)
    command = [sys.executable, str(Path(script).resolve()), *arguments]
    runs: dict[str, list[Run]] = {code: [] for code in CODES}
    with tempfile.TemporaryDirectory(prefix="sb3ls-compare-") as old_root:
        export_package(rev, old_root)
        for index in range(rounds):
            pairs = list(zip(CODES, (old_root, str(REPO))))
            # old first in even rounds, new first in odd ones: a load that rises or falls over the run hits both alike
            for code, root in pairs if index % 2 == 0 else pairs[::-1]:
                result, cpu, wall = run_once(command, root)
                run = Run(code, index, result, cpu, wall)
                runs[code].append(run)
                if on_run is not None:
                    on_run(run)
    return runs
