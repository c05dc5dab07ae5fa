"""One place for argument checks: each raises a clear ``TypeError``/``ValueError`` naming the field and its range.

Every public entry point (``SwarmConfig``, ``LatentSwarmPPO``, ``evaluate``, the callbacks, the vec envs, the sweep
spec, the CLI) validates through these functions, so a bad value gets the same message wherever it enters, and before
any work starts or any file is written.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Collection
from typing import Any

import numpy as np

__all__ = ["check_int", "check_float", "check_choice", "check_bool"]


def check_int(name: str, value: Any, low: int | None = None, high: int | None = None) -> int:
    """Return ``value`` as a Python int, or raise.

    :param name: the field's name as the user wrote it (``"n_steps"``, ``"SwarmConfig.n_agents"``).
    :param value: an int or a NumPy integer; ``bool`` is refused.
    :param low: smallest allowed value (inclusive), or None.
    :param high: largest allowed value (inclusive), or None.
    :raises TypeError: ``value`` is not an integer (or is a bool).
    :raises ValueError: ``value`` is outside ``[low, high]``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an int, got {type(value).__name__} ({value!r})")
    value = int(value)
    if (low is not None and value < low) or (high is not None and value > high):
        raise ValueError(f"{name} must be an int in {_interval(low, high, False, False)}, got {value}")
    return value


def check_float(
    name: str,
    value: Any,
    low: float = -math.inf,
    high: float = math.inf,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """Return ``value`` as a finite Python float, or raise.

    :param name: the field's name as the user wrote it.
    :param value: an int, float or NumPy number; ``bool`` and strings are refused.
    :param low: lower bound; ``low_open`` makes it exclusive.
    :param high: upper bound; ``high_open`` makes it exclusive.
    :raises TypeError: ``value`` is not a real number.
    :raises ValueError: ``value`` is NaN, infinite or outside the interval.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} ({value!r})")
    value = float(value)
    bad_low = value <= low if low_open else value < low
    bad_high = value >= high if high_open else value > high
    if not math.isfinite(value) or bad_low or bad_high:
        raise ValueError(f"{name} must be a finite number in {_interval(low, high, low_open, high_open)}, got {value}")
    return value


def check_bool(name: str, value: Any) -> bool:
    """Return ``value`` if it is a bool (or NumPy bool), else raise ``TypeError``."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {type(value).__name__} ({value!r})")
    return bool(value)


def check_choice(name: str, value: Any, choices: Collection[Any]) -> Any:
    """Return ``value`` if it is one of ``choices``, else raise ``ValueError`` listing them."""
    try:
        ok = value in choices
    except TypeError:
        ok = False
    if not ok:
        listed = ", ".join(repr(c) for c in choices)
        raise ValueError(f"{name} must be one of {listed}; got {value!r}")
    return value


def _interval(low: float | None, high: float | None, low_open: bool, high_open: bool) -> str:
    low = -math.inf if low is None else low
    high = math.inf if high is None else high
    left = "(" if low_open or low == -math.inf else "["
    right = ")" if high_open or high == math.inf else "]"
    return f"{left}{low}, {high}{right}"
