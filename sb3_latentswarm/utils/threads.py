"""The number of torch CPU threads this package runs with, chosen in this one place.

Measured with ``benchmarks/threads.py`` (the README's training snippet) on this project's shared 2-core machine at a
load average of 5.3 (2026-12-02): one thread trained at 349 agent-steps/s, two at 20 (0.06x), because the second
thread waits for a core that other processes hold. The issue that asked for this measured two threads faster by a
small factor when the second core was free. One thread is therefore the default: never far from the best, never an
order of magnitude slower, and the same arithmetic on every machine (results do not depend on the core count).

Measured again for issue 21 (``docs/benchmarks.md``): a ``coordination`` update took 144 s with two threads against
2.7 s with one on the loaded 2-core machine (0.02x): OpenMP threads spin-wait for a core that another process holds.
Parallelism on such a machine comes from processes of one thread each (``sb3-latentswarm sweep`` asks Ray for one CPU
per trial and sets one thread in each). :func:`set_torch_threads` and the environment variables below warn once when
they ask for more threads than the process may run on (``os.sched_getaffinity``).
"""

from __future__ import annotations

import os
import warnings

import torch as th

from sb3_latentswarm.utils.checks import check_int

DEFAULT_TORCH_THREADS = 1
"""Intra-op threads of torch after ``import sb3_latentswarm``, unless the environment chose (below)."""

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""Environment variables that mean the user chose a thread count: the package then leaves torch as it is."""


def available_cores() -> int:
    """The number of cores this process may run on (``os.sched_getaffinity``; ``os.cpu_count`` where it is missing)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


_warned = False


def warn_if_oversubscribed(threads: int, source: str) -> bool:
    """Warn (once per process) when ``threads`` torch threads exceed :func:`available_cores`.

    :param threads: the number of intra-op threads asked for
    :param source: what asked, for the message (``"set_torch_threads(4)"``, ``"OMP_NUM_THREADS=4"``)
    :return: whether ``threads`` exceeds the available cores
    """
    global _warned
    cores = available_cores()
    if threads <= cores:
        return False
    if not _warned:
        _warned = True
        warnings.warn(
            f"{source} asks for {threads} torch threads, but this process may run on {cores} core(s): threads that "
            "wait for a core spin, and a loaded 2-core machine ran a coordination update 50x slower with 2 threads "
            "than with 1. Use one thread per process and run several processes (sb3-latentswarm sweep) instead.",
            RuntimeWarning,
            stacklevel=3,
        )
    return True


def set_torch_threads(threads: int) -> int:
    """``torch.set_num_threads(threads)``, warning once when that is more than the available cores.

    :param threads: intra-op threads, >= 1
    :return: the number of threads torch now uses
    :raises ValueError: ``threads`` < 1
    :raises TypeError: ``threads`` is not an int
    """
    check_int("threads", threads, low=1)
    warn_if_oversubscribed(threads, f"set_torch_threads({threads})")
    th.set_num_threads(threads)
    return th.get_num_threads()


def _requested_threads() -> tuple[str, int] | None:
    """The first of :data:`THREAD_VARIABLES` that is set to a positive integer, with its value."""
    for name in THREAD_VARIABLES:
        value = os.environ.get(name, "").strip()
        if value.isdigit() and int(value) > 0:
            return name, int(value)
    return None


def apply_default_torch_threads() -> int:
    """Set torch to :data:`DEFAULT_TORCH_THREADS` threads unless one of :data:`THREAD_VARIABLES` is set.

    :func:`apply_default_torch_threads_once` calls it when the package first loads its torch-using code;
    ``torch.set_num_threads(n)`` after that overrides it. A variable that asks for more threads than
    :func:`available_cores` gets a warning (:func:`warn_if_oversubscribed`); torch keeps the count it asked for.

    :return: the number of threads torch now uses
    """
    if not any(os.environ.get(name) for name in THREAD_VARIABLES):
        th.set_num_threads(DEFAULT_TORCH_THREADS)
    else:
        requested = _requested_threads()
        if requested is not None:
            warn_if_oversubscribed(requested[1], f"{requested[0]}={requested[1]}")
    return th.get_num_threads()


_applied = False


def apply_default_torch_threads_once() -> None:
    """:func:`apply_default_torch_threads` the first time it is called in a process, nothing afterwards.

    Called by ``import sb3_latentswarm`` when torch is already loaded, else by the subpackages that load torch
    (``latent_ppo``, ``envs``, ``baselines``), so that a later ``torch.set_num_threads(n)`` of the user's is kept.
    """
    global _applied
    if not _applied:
        _applied = True
        apply_default_torch_threads()
