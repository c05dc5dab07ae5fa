"""Moved to :mod:`sb3_latentswarm.utils.threads`: the thread default is process plumbing, not an algorithm building block.

This path was documented in 0.1.0, so it still imports, with a ``DeprecationWarning``; it will be removed in 0.3.
"""

import warnings

from sb3_latentswarm.utils.threads import (
    DEFAULT_TORCH_THREADS,
    THREAD_VARIABLES,
    apply_default_torch_threads,
    apply_default_torch_threads_once,
    set_torch_threads,
)

warnings.warn(
    "sb3_latentswarm.common.threads moved to sb3_latentswarm.utils.threads; the old path will be removed in 0.3",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["DEFAULT_TORCH_THREADS", "THREAD_VARIABLES", "apply_default_torch_threads", "apply_default_torch_threads_once",
           "set_torch_threads"]
