"""The record an experiment script writes next to its results: ``run.md`` with command, commit, machine and facts.

The example scripts (``examples/reproduce_table1.py``, ``learning_curve.py``, ``sustained_dropout.py``, ...), the sweep
report and the trial records use it, so that every folder under ``docs/results/`` says the same things about how it
was made. It describes a run of an experiment, hence its place here rather than among the algorithm's building blocks
in ``common/``.
"""

from __future__ import annotations

import platform
import shlex
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import torch as th

from sb3_latentswarm.utils.atomic import write_text


def git_commit() -> str:
    """The short hash of ``HEAD``, marked when tracked files differ from it; ``"unknown"`` outside a git checkout.

    Call it before the script writes anything, so that the record names the code that ran.
    """
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True)
        return out.stdout.strip() + (" (with uncommitted changes)" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def machine_summary(device: th.device | str | None = None) -> str:
    """Processor, OS, torch threads (and device), Python and torch versions, on one line."""
    on = f"device {device}, " if device is not None else ""
    return (
        f"{platform.machine()}, {platform.system()}, {th.get_num_threads()} torch thread(s), {on}"
        f"Python {platform.python_version()}, torch {th.__version__}"
    )


def write_run_record(
    output: Path,
    title: str,
    commit: str,
    facts: Sequence[str],
    body: Sequence[str],
    device: th.device | str | None = None,
) -> str:
    """Write ``output / "run.md"`` (a title, the command line of this process, commit, machine, ``facts`` as bullets,
    then ``body``), print it, and return its text."""
    lines = [
        f"# {title}\n",
        f"- command: `python {shlex.join(sys.argv)}`",
        f"- commit: {commit}",
        f"- machine: {machine_summary(device)}",
        *(f"- {fact}" for fact in facts),
        "",
        *body,
        "",
    ]
    text = "\n".join(lines)
    write_text(output / "run.md", text)  # atomic: a failed write leaves the earlier record
    print(text)
    return text
