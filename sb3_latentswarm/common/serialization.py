"""Model files that can be loaded without running code: plain JSON for the attributes, tensors read with
``torch.load(weights_only=True)``.

Stable-Baselines3's zip keeps every attribute it cannot write as JSON (the policy class, the spaces, schedules,
configs) as a cloudpickle blob in its ``data`` entry, and ``BaseAlgorithm.load`` unpickles those blobs: a crafted
``model.zip`` runs whatever code it carries. This module writes the same zip layout (``data``, ``policy.pth``,
``policy.optimizer.pth``, ...) with a ``data`` entry of plain values only, and reads it back without unpickling:

* every attribute the algorithm saves is encoded by :func:`to_plain`: JSON values as they are, and a closed set of
  types as tagged dicts: tuples, deques, NumPy arrays and scalars, gymnasium ``Box``/``Dict`` spaces,
  :class:`~sb3_latentswarm.SwarmConfig`, schedules (constant, SB3's ``LinearSchedule``,
  :class:`~sb3_latentswarm.common.schedules.StepSchedule`), the policy class by its alias in ``policy_aliases``, and
  classes of ``torch.nn`` / ``torch.optim`` by name. Anything else fails at save time with the attribute's name;
* loading decodes only those tags (no import of a module named by the file, no call of a function it names), and
  rebuilds the model through its constructor, so that the constructor's checks apply to the saved values and to the
  overrides given to ``load``. New constructor options of plain types need no change here;
* the attributes of a run in progress (the last observation, the carried recurrent state) and machine-specific
  paths (``tensorboard_log``) are not saved.

A file with a pickled entry (any SB3 file, and this package's files before save format 2) is refused unless the caller
passes ``trust_pickle=True``.
"""

from __future__ import annotations

import collections
import inspect
import io
import json
import pathlib
import warnings
import zipfile
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.save_util import load_from_zip_file, open_path, save_to_zip_file
from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule, LinearSchedule

from sb3_latentswarm.common.schedules import StepSchedule
from sb3_latentswarm.config import SwarmConfig

PLAIN_FORMAT = 1
"""Version of the plain-data encoding, stored as ``data["plain_format"]``."""

RUN_STATE = ("_last_obs", "_last_episode_starts", "_last_original_obs", "_last_lstm_states", "lr_schedule")
"""Attributes of a run in progress, or derived from saved ones: rebuilt on load, never saved."""

MACHINE_SPECIFIC = ("tensorboard_log",)
"""Paths that may name the machine that saved the model: kept when relative (``runs/tb``: a loaded model continues
logging there, as SB3's does), saved as ``None`` when absolute (pass ``tensorboard_log=...`` to ``load``)."""

NOT_CONSTRUCTOR_ARGUMENTS = ("self", "policy", "env", "device", "_init_setup_model")

_PICKLE_MARK = ":serialized:"  # how SB3's data_to_json marks a cloudpickled attribute


class UnsafeModelFileError(ValueError):
    """A model file holds pickled Python objects, which would run code when loaded."""

    def __init__(self, path: Any, pickled: list[str]):
        self.path = path
        self.pickled = pickled
        super().__init__(
            f"{path} stores pickled Python objects ({', '.join(pickled)}); unpickling runs whatever code the file "
            f"carries, so it is refused. Load it with trust_pickle=True (CLI: --trust-pickle) only if you trust where "
            f"the file comes from; then save it again to get a file of plain data."
        )


# ---------------------------------------------------------------------------------------------- encoding
def _schedule_to_plain(schedule: Any) -> dict[str, Any] | None:
    while isinstance(schedule, FloatSchedule):
        schedule = schedule.value_schedule
    if isinstance(schedule, ConstantSchedule):
        return {"__schedule__": "constant", "value": float(schedule.val)}
    if isinstance(schedule, LinearSchedule):
        return {
            "__schedule__": "linear",
            "start": float(schedule.start),
            "end": float(schedule.end),
            "end_fraction": float(schedule.end_fraction),
        }
    if isinstance(schedule, StepSchedule):
        return {
            "__schedule__": "step",
            "initial_value": schedule.initial_value,
            "final_value": schedule.final_value,
            "switch_fraction": schedule.switch_fraction,
        }
    return None


def _space_to_plain(space: spaces.Space, name: str) -> dict[str, Any]:
    if isinstance(space, spaces.Dict):
        return {"__space__": "Dict", "spaces": {key: _space_to_plain(sub, f"{name}[{key!r}]") for key, sub in space.items()}}
    if isinstance(space, spaces.Box):
        return {
            "__space__": "Box",
            "low": _array_to_plain(space.low),
            "high": _array_to_plain(space.high),
            "shape": list(space.shape),
            "dtype": str(space.dtype),
        }
    raise TypeError(f"{name}: cannot store a {type(space).__name__} space as plain data (Box and Dict only)")


def _array_to_plain(array: np.ndarray) -> dict[str, Any]:
    flat = array.reshape(-1)
    if flat.size and (flat == flat[0]).all():  # a bound shared by every entry: one number
        return {"__ndarray__": flat[0].item(), "dtype": str(array.dtype), "shape": list(array.shape)}
    return {"__ndarray__": array.tolist(), "dtype": str(array.dtype), "shape": list(array.shape)}


def to_plain(value: Any, name: str, algorithm: type | None = None) -> Any:
    """Encode ``value`` (the attribute ``name`` of a model of class ``algorithm``) as JSON-ready plain data.

    :raise TypeError: for a type outside the closed set this module knows, naming the attribute
    """
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return _array_to_plain(value)
    if isinstance(value, th.device):
        return str(value)
    if isinstance(value, SwarmConfig):
        return {"__swarm_config__": value.to_dict()}
    if isinstance(value, spaces.Space):
        return _space_to_plain(value, name)
    if isinstance(value, tuple):
        return {"__tuple__": [to_plain(v, f"{name}[{i}]", algorithm) for i, v in enumerate(value)]}
    if isinstance(value, collections.deque):
        return {"__deque__": [to_plain(v, f"{name}[{i}]", algorithm) for i, v in enumerate(value)], "maxlen": value.maxlen}
    if isinstance(value, list):
        return [to_plain(v, f"{name}[{i}]", algorithm) for i, v in enumerate(value)]
    if isinstance(value, dict):
        if not all(isinstance(key, str) for key in value):
            raise TypeError(f"{name}: only dicts with str keys can be stored as plain data, got keys {list(value)}")
        return {key: to_plain(v, f"{name}[{key!r}]", algorithm) for key, v in value.items()}
    if isinstance(value, type):
        aliases = getattr(algorithm, "policy_aliases", {})
        for alias, policy_class in aliases.items():
            if value is policy_class:
                return {"__policy__": alias}
        if any(getattr(module, value.__name__, None) is value for module in (th.nn, th.optim)):
            return {"__torch_class__": value.__name__}
        raise TypeError(
            f"{name}: the class {value.__module__}.{value.__qualname__} cannot be stored as plain data (policy classes by "
            f"their alias in {algorithm.__name__ if algorithm else 'the algorithm'}.policy_aliases, torch.nn and "
            f"torch.optim classes by name)"
        )
    schedule = _schedule_to_plain(value)
    if schedule is not None:
        return schedule
    raise TypeError(
        f"{name}: a {type(value).__name__} cannot be stored as plain data; schedules must be numbers, "
        f"stable_baselines3.common.utils.LinearSchedule or sb3_latentswarm.common.schedules.StepSchedule"
    )


# ---------------------------------------------------------------------------------------------- decoding
def _torch_class(name: str) -> type:
    for module in (th.nn, th.optim):
        candidate = getattr(module, name, None)
        if isinstance(candidate, type) and (issubclass(candidate, (th.nn.Module, th.optim.Optimizer))):
            return candidate
    raise ValueError(f"unknown torch.nn / torch.optim class {name!r} in a model file")


def _space_from_plain(value: dict[str, Any]) -> spaces.Space:
    if value["__space__"] == "Dict":
        return spaces.Dict({key: _space_from_plain(sub) for key, sub in value["spaces"].items()})
    if value["__space__"] == "Box":
        dtype = np.dtype(value["dtype"])
        return spaces.Box(_array_from_plain(value["low"]), _array_from_plain(value["high"]), dtype=dtype)
    raise ValueError(f"unknown space {value['__space__']!r} in a model file")


def _array_from_plain(value: dict[str, Any]) -> np.ndarray:
    dtype, shape = np.dtype(value["dtype"]), tuple(value["shape"])
    if not dtype.isbuiltin or dtype.kind not in "biuf":
        raise ValueError(f"unexpected array dtype {dtype} in a model file")
    return np.broadcast_to(np.asarray(value["__ndarray__"], dtype=dtype), shape).copy()


def from_plain(value: Any, algorithm: type | None = None) -> Any:
    """Decode what :func:`to_plain` wrote. Only its tags are read; no module or function named by the file is used."""
    if isinstance(value, list):
        return [from_plain(v, algorithm) for v in value]
    if not isinstance(value, dict):
        return value
    if "__tuple__" in value:
        return tuple(from_plain(v, algorithm) for v in value["__tuple__"])
    if "__deque__" in value:
        return collections.deque((from_plain(v, algorithm) for v in value["__deque__"]), maxlen=value["maxlen"])
    if "__ndarray__" in value:
        return _array_from_plain(value)
    if "__space__" in value:
        return _space_from_plain(value)
    if "__swarm_config__" in value:
        return SwarmConfig(**value["__swarm_config__"])
    if "__policy__" in value:
        aliases = getattr(algorithm, "policy_aliases", {})
        if value["__policy__"] not in aliases:
            raise ValueError(f"unknown policy {value['__policy__']!r} in a model file; the algorithm knows {sorted(aliases)}")
        return aliases[value["__policy__"]]
    if "__torch_class__" in value:
        return _torch_class(value["__torch_class__"])
    if "__schedule__" in value:
        kind = value["__schedule__"]
        if kind == "constant":
            return ConstantSchedule(float(value["value"]))
        if kind == "linear":
            return LinearSchedule(float(value["start"]), float(value["end"]), float(value["end_fraction"]))
        if kind == "step":
            return StepSchedule(value["initial_value"], value["final_value"], value["switch_fraction"])
        raise ValueError(f"unknown schedule {kind!r} in a model file")
    tags = [key for key in value if key.startswith("__") and key.endswith("__")]
    if tags:
        raise ValueError(f"unknown entry {tags[0]!r} in a model file")
    return {key: from_plain(v, algorithm) for key, v in value.items()}


# ---------------------------------------------------------------------------------------------- files
def constructor_arguments(algorithm: type) -> list[str]:
    """The keyword arguments of ``algorithm.__init__`` that a saved model carries (all but policy, env, device)."""
    parameters = inspect.signature(algorithm.__init__).parameters.values()
    return [p.name for p in parameters if p.name not in NOT_CONSTRUCTOR_ARGUMENTS and p.kind is p.POSITIONAL_OR_KEYWORD]


def _pickled_entries(value: Any, name: str = "data") -> list[str]:
    if isinstance(value, dict):
        if _PICKLE_MARK in value:
            return [name]
        return [entry for key, v in value.items() for entry in _pickled_entries(v, key)]
    if isinstance(value, list):
        return [entry for v in value for entry in _pickled_entries(v, name)]
    return []


def read_data(path: str | pathlib.Path | io.BufferedIOBase) -> tuple[dict[str, Any], list[str]]:
    """The raw JSON of a model zip's ``data`` entry (nothing decoded, nothing unpickled) and its pickled entries."""
    file = open_path(path, "r", verbose=0, suffix="zip")
    try:
        with zipfile.ZipFile(file) as archive:
            if "data" not in archive.namelist():
                raise ValueError(f"{path} is not a saved model: its zip has no 'data' entry")
            raw = json.loads(archive.read("data").decode())
    except zipfile.BadZipFile as error:
        raise ValueError(f"{path} is not a saved model (not a zip file)") from error
    finally:
        if isinstance(path, (str, pathlib.Path)):
            file.close()
        else:
            file.seek(0)
    return raw, _pickled_entries(raw)


def save_plain(model: Any, path: str | pathlib.Path | io.BufferedIOBase, exclude=None, include=None) -> None:
    """Save ``model`` (an SB3 algorithm) in SB3's zip layout with a plain-data ``data`` entry.

    What SB3's ``save`` would store, less :data:`RUN_STATE`; :data:`MACHINE_SPECIFIC` attributes are stored as ``None``
    when they are absolute paths.
    A schedule given as a plain function cannot be stored: it is saved as its current value, with a warning.
    """
    algorithm = type(model)
    excluded = set(exclude or ()).union(model._excluded_save_params(), RUN_STATE)
    excluded -= set(include or ())
    state_dicts, torch_variables = model._get_torch_save_params()
    excluded |= {name.split(".")[0] for name in state_dicts + torch_variables}
    data: dict[str, Any] = {"plain_format": PLAIN_FORMAT}
    for name, value in model.__dict__.items():
        if name in excluded:
            continue
        if name in MACHINE_SPECIFIC:
            value = None if value is None or pathlib.Path(value).is_absolute() else str(value)
        elif callable(value) and not isinstance(value, type) and _schedule_to_plain(value) is None:
            current = float(value(model._current_progress_remaining))
            warnings.warn(
                f"{name} is a function, which a model file of plain data cannot hold: saved as its current value "
                f"{current:g}. Use a number, LinearSchedule or StepSchedule to save the schedule itself.",
                stacklevel=3,
            )
            value = current
        data[name] = to_plain(value, name, algorithm)
    params = {name: model.get_parameters()[name] for name in state_dicts}
    variables = {name: getattr(model, name) for name in torch_variables}
    save_to_zip_file(path, data=data, params=params, pytorch_variables=variables)


def load_plain(
    algorithm: type,
    path: Any,
    raw: dict[str, Any],
    device: th.device | str = "auto",
    print_system_info: bool = False,
    **kwargs: Any,
) -> Any:
    """Rebuild a model of class ``algorithm`` saved by :func:`save_plain`, without an env.

    The saved constructor arguments, with ``kwargs`` in place of any of them, go through ``algorithm(...)`` so that
    its checks apply; the other saved attributes are then restored and the tensors read with ``weights_only=True``.

    :param raw: the file's ``data`` entry as read by :func:`read_data` (free of pickles)
    :raise TypeError: for a keyword that is not a constructor argument, listing those that are
    """
    if raw.get("plain_format") != PLAIN_FORMAT:
        raise ValueError(f"{path}: unknown plain-data format {raw.get('plain_format')!r} (this version reads {PLAIN_FORMAT})")
    data = {name: from_plain(value, algorithm) for name, value in raw.items() if name != "plain_format"}
    arguments = constructor_arguments(algorithm)
    unknown = sorted(set(kwargs) - set(arguments))
    if unknown:
        raise TypeError(f"{algorithm.__name__}.load got unknown keyword argument(s) {unknown}; valid: {', '.join(arguments)}")
    # the saved value of each argument: its attribute of the same name, or SB3's private one (stats_window_size)
    saved = {name: data.get(name, data.get(f"_{name}")) for name in arguments if name in data or f"_{name}" in data}
    saved.pop("verbose", None)  # build quietly; the saved verbosity comes back with the other attributes
    model = algorithm(
        policy=data.pop("policy_class"), env=None, device=device, _init_setup_model=False, **{**saved, **kwargs}
    )
    overridden = set(kwargs) | {f"_{name}" for name in kwargs}
    model.__dict__.update({name: value for name, value in data.items() if name not in overridden})
    model._setup_model()
    # the tensors: torch.load(weights_only=True), which reads tensors and plain containers only
    _, params, variables = load_from_zip_file(path, load_data=False, device=device, print_system_info=print_system_info)
    model.set_parameters(params, exact_match=True, device=device)
    for name, value in (variables or {}).items():
        if value is not None:
            getattr(model, name).data = value.data
    return model
