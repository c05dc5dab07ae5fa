"""The number of torch CPU threads this package runs with, chosen in this one place.

Measured with ``benchmarks/threads.py`` (the README's training snippet) on this project's shared 2-core machine at a
load average of 10.6: one thread trained at 154 agent-steps/s, two at 12 (0.08x), because the second thread waits for
a core that other processes hold. The issue that asked for this measured two threads faster by a small factor when the
second core was free. One thread is therefore the default: never far from the best, never an order of magnitude
slower, and the same arithmetic on every machine (results do not depend on the core count).
"""

from __future__ import annotations

import os

import torch as th

DEFAULT_TORCH_THREADS = 1
"""Intra-op threads of torch after ``import sb3_latentswarm``, unless the environment chose (below)."""

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""Environment variables that mean the user chose a thread count: the package then leaves torch as it is."""


def apply_default_torch_threads() -> int:
    """Set torch to :data:`DEFAULT_TORCH_THREADS` threads unless one of :data:`THREAD_VARIABLES` is set.

    :func:`apply_default_torch_threads_once` calls it when the package first loads its torch-using code;
    ``torch.set_num_threads(n)`` after that overrides it.

    :return: the number of threads torch now uses
    """
    if not any(os.environ.get(name) for name in THREAD_VARIABLES):
        th.set_num_threads(DEFAULT_TORCH_THREADS)
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
