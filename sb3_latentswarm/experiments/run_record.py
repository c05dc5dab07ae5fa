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
    """What code runs: this package's version and, when it is imported from a git checkout, that checkout's short
    commit (marked when tracked files differ from it), e.g. ``"0.1.0, commit 1a2b3c4"``.

    The checkout is the one holding this package (``sb3_latentswarm/..``), never the current folder's repository: a run
    started elsewhere, or inside another git repository, still records the code that ran. An installed copy (a wheel
    in site-packages) records its version only. Call it before the script writes anything.
    """
    from sb3_latentswarm.version import __version__

    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists() or not (root / "sb3_latentswarm").is_dir():
        return f"{__version__} (not a git checkout)"
    try:
        git = ["git", "-C", str(root)]
        out = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
        dirty = subprocess.run([*git, "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True)
        changed = " (with uncommitted changes)" if dirty.stdout.strip() else ""
        return f"{__version__}, commit {out.stdout.strip()}{changed}"
    except (OSError, subprocess.CalledProcessError):
        return f"{__version__}, commit unknown"


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
