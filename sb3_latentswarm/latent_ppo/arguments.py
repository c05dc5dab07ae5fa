"""The ranges of :class:`~sb3_latentswarm.latent_ppo.LatentSwarmPPO`'s settings and the one check of their values.

:func:`~sb3_latentswarm.latent_ppo.validate_algorithm_kwargs` checks the argument names against the constructor's,
then calls :func:`check_algorithm_values`; the constructor, ``load`` and the sweep spec all go through it.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Any

from sb3_latentswarm.latent_ppo.policies import AUTOCAST_MODES
from sb3_latentswarm.utils.checks import check_bool, check_choice, check_float, check_int

__all__ = [
    "CLIP_RANGE_RANGE",
    "COMPILE_REMOVED",
    "GRAD_CLIP_MODES",
    "LEARNING_RATE_RANGE",
    "VALUE_LOSSES",
    "check_algorithm_values",
    "check_schedule",
    "fitting_chunk_length",
]

COMPILE_REMOVED = (
    "compile_latent_step=True was removed after 0.2.0: torch.compile of the latent step saved 3 % of a `coordination` update "
    "(2.01 -> 1.95 CPU s) after 29 CPU s of this thread and 284 s wall of compiling, so it never paid back within "
    "the preset's 300 updates (docs/algorithm.md, 'Compiled latent step (removed)'); drop the argument"
)
"""The error for ``compile_latent_step=True`` (the argument stays, ``False`` only, so that old calls get this message)."""

VALUE_LOSSES = ("mse", "huber")
GRAD_CLIP_MODES = ("global", "per_group")
LEARNING_RATE_RANGE = (0.0, 1.0)
"""Learning rates (and every value of a learning-rate schedule) must lie in (0, 1]."""
CLIP_RANGE_RANGE = (0.0, 1.0)
"""PPO's epsilon (and every value of its schedule) must lie in (0, 1]."""


def check_schedule(name: str, value: Any, low: float, high: float = math.inf) -> None:
    """A number in (low, high], or a schedule whose values at progress_remaining 1, 0.5 and 0 are in [low, high] and
    whose start value (progress_remaining 1) is above ``low`` (a schedule may decay to ``low``, as SB3's linear ones do)."""
    if not callable(value):
        check_float(name, value, low, high, low_open=True)
        return
    for progress in (1.0, 0.5, 0.0):
        try:
            current = value(progress)
        except Exception as error:  # noqa: BLE001 - a user's schedule; report which argument fails
            raise ValueError(f"{name}: the schedule fails at progress_remaining={progress}: {error}") from error
        check_float(f"{name} (its value at progress_remaining={progress})", current, low, high, low_open=progress == 1.0)


def check_algorithm_values(kwargs: dict[str, Any]) -> None:
    """Check the values of ``LatentSwarmPPO`` keyword arguments (only those given; ``policy_kwargs``' entries are the
    policy's to check). Ranges: ``learning_rate`` in (0, 1], ``clip_range`` in (0, 1] (each value of a schedule, too),
    ``clip_range_vf`` and ``target_kl`` None or > 0, ``gamma`` and ``gae_lambda`` in [0, 1], the loss weights >= 0,
    ``max_grad_norm`` and ``huber_delta`` > 0.

    :raise TypeError: for a value of the wrong type
    :raise ValueError: for a value outside its range, naming the argument and the range
    """
    for name in ("n_steps", "batch_size", "n_epochs", "chunk_length", "stats_window_size"):
        if name in kwargs:
            check_int(name, kwargs[name], low=1)
    for name in ("ent_coef", "vf_coef", "map_coef", "pred_coef"):
        if name in kwargs:
            check_float(name, kwargs[name], low=0.0)
    for name in ("gamma", "gae_lambda"):
        if name in kwargs:
            check_float(name, kwargs[name], low=0.0, high=1.0)
    for name in ("max_grad_norm", "huber_delta"):
        if name in kwargs:
            check_float(name, kwargs[name], low=0.0, low_open=True)
    if "learning_rate" in kwargs:
        check_schedule("learning_rate", kwargs["learning_rate"], *LEARNING_RATE_RANGE)
    if "clip_range" in kwargs:
        check_schedule("clip_range", kwargs["clip_range"], *CLIP_RANGE_RANGE)
    if kwargs.get("clip_range_vf") is not None:
        check_schedule("clip_range_vf (None deactivates it)", kwargs["clip_range_vf"], 0.0)
    if kwargs.get("target_kl") is not None:
        check_float("target_kl (None deactivates it)", kwargs["target_kl"], low=0.0, low_open=True)
    for name in ("normalize_advantage", "normalize_value", "log_grad_norms", "compile_latent_step", "_init_setup_model"):
        if name in kwargs:
            check_bool(name, kwargs[name])
    if kwargs.get("compile_latent_step"):
        raise ValueError(COMPILE_REMOVED)
    if "grad_clip" in kwargs:
        check_choice("grad_clip", kwargs["grad_clip"], GRAD_CLIP_MODES)
    if "value_loss" in kwargs:
        check_choice("value_loss", kwargs["value_loss"], VALUE_LOSSES)
    if "autocast" in kwargs:
        check_choice("autocast (None: float32)", kwargs["autocast"], AUTOCAST_MODES)
    if "verbose" in kwargs:
        check_int("verbose", kwargs["verbose"], low=0, high=2)
    if kwargs.get("seed") is not None:
        check_int("seed", kwargs["seed"], low=0)
    if kwargs.get("policy_kwargs") is not None and not isinstance(kwargs["policy_kwargs"], dict):
        raise TypeError(f"policy_kwargs must be a dict or None, got {type(kwargs['policy_kwargs']).__name__}")
    if kwargs.get("tensorboard_log") is not None and not isinstance(kwargs["tensorboard_log"], (str, os.PathLike)):
        raise TypeError(f"tensorboard_log must be a path or None, got {type(kwargs['tensorboard_log']).__name__}")


def fitting_chunk_length(n_steps: int, chunk_length: int) -> int:
    """``chunk_length``, or, when it does not divide ``n_steps``, the largest divisor of ``n_steps`` below it.

    Every training sequence then has the same length (no padding), and a rollout of any length trains.
    """
    if n_steps % chunk_length == 0:
        return chunk_length
    fitting = max(d for d in range(1, min(chunk_length, n_steps) + 1) if n_steps % d == 0)
    warnings.warn(
        f"chunk_length={chunk_length} does not divide n_steps={n_steps}: training sequences of {fitting} steps are used "
        f"(pass a chunk_length that divides n_steps to choose another)",
        stacklevel=3,
    )
    return fitting
