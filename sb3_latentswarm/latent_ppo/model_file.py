"""Model files that can be loaded without running code: plain JSON for the attributes, tensors read with
``torch.load(weights_only=True)``.

Stable-Baselines3's zip keeps every attribute it cannot write as JSON (the policy class, the spaces, schedules,
configs) as a cloudpickle blob in its ``data`` entry, and ``BaseAlgorithm.load`` unpickles those blobs: a crafted
``model.zip`` runs whatever code it carries. This module writes the same zip layout (``data``, ``policy.pth``,
``policy.optimizer.pth``, ...) with a ``data`` entry of plain values only, and reads it back without unpickling:

* every attribute the algorithm saves is encoded by :func:`to_plain`: JSON values as they are, and a closed set of
  types as tagged dicts: tuples, deques, NumPy arrays and scalars, gymnasium ``Box``/``Dict`` spaces,
  :class:`~sb3_latentswarm.SwarmConfig`, schedules (constant, SB3's ``LinearSchedule``,
  :class:`~sb3_latentswarm.latent_ppo.schedules.StepSchedule`), the policy class by its alias in ``policy_aliases``, and
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
import math
import numbers
import os
import pathlib
import stat
import warnings
import zipfile
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.save_util import load_from_zip_file, open_path, recursive_getattr, save_to_zip_file
from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule, LinearSchedule

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.latent_ppo.load_checks import bounded_int, check_config_matches_space, check_load_budget
from sb3_latentswarm.latent_ppo.schedules import StepSchedule

PLAIN_FORMAT = 1
"""Version of the plain-data encoding, stored as ``data["plain_format"]``."""

RUN_STATE = ("_last_obs", "_last_episode_starts", "_last_original_obs", "_last_lstm_states", "lr_schedule")
"""Attributes of a run in progress, or derived from saved ones: rebuilt on load, never saved."""

MACHINE_SPECIFIC = ("tensorboard_log",)
"""Paths that may name the machine that saved the model: kept when relative (``runs/tb``: a loaded model continues
logging there, as SB3's does), saved as ``None`` when absolute (pass ``tensorboard_log=...`` to ``load``)."""

NOT_CONSTRUCTOR_ARGUMENTS = ("self", "policy", "env", "device", "_init_setup_model")

_PICKLE_MARK = ":serialized:"  # how SB3's data_to_json marks a cloudpickled attribute

# ---------------------------------------------------------------------------------------------- limits
MAX_DATA_BYTES = 8 * 2**20
"""Largest ``data`` entry read (8 MiB; the files this package writes hold about 20 kB)."""

MAX_DEPTH = 32
"""Deepest nesting of lists and dicts in the ``data`` entry (this package's files nest 7 deep)."""

MAX_ARRAY_ELEMENTS = 2**20
"""Most elements of one stored array or ``Box`` space (a 1024 x 1024 map; the paper's is 50 x 50)."""

MAX_SPACE_KEYS = 64
"""Most keys of a stored ``Dict`` space."""

MAX_POLICY_WIDTH = 4096
"""Largest integer in ``policy_kwargs`` (layer widths, latent sizes), so a file cannot declare a network of GiBs."""

MAX_TENSOR_ENTRY_BYTES = 2**30
"""Largest tensor entry (``policy.pth``, ``policy.optimizer.pth``, ``pytorch_variables.pth``) read: 1 GiB."""

TENSOR_ENTRIES = ("policy.pth", "policy.optimizer.pth", "pytorch_variables.pth")


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
        f"stable_baselines3.common.utils.LinearSchedule or sb3_latentswarm.latent_ppo.schedules.StepSchedule"
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
        if not isinstance(value["spaces"], dict) or len(value["spaces"]) > MAX_SPACE_KEYS:
            raise ValueError(f"a Dict space must map at most {MAX_SPACE_KEYS} names to spaces")
        return spaces.Dict({key: _space_from_plain(sub) for key, sub in value["spaces"].items()})
    if value["__space__"] == "Box":
        dtype = np.dtype(value["dtype"])
        low, high = _array_from_plain(value["low"]), _array_from_plain(value["high"])
        if "shape" in value and tuple(value["shape"]) != low.shape:
            raise ValueError(f"a Box space's shape {value['shape']} differs from its bounds' shape {list(low.shape)}")
        return spaces.Box(low, high, dtype=dtype)
    raise ValueError(f"unknown space {value['__space__']!r}")


def _array_from_plain(value: dict[str, Any]) -> np.ndarray:
    dtype, shape = np.dtype(value["dtype"]), value["shape"]
    if not dtype.isbuiltin or dtype.kind not in "biuf":
        raise ValueError(f"unexpected array dtype {dtype}")
    if not isinstance(shape, list) or len(shape) > 8 or not all(_is_int(n) and n >= 0 for n in shape):
        raise ValueError(f"an array shape must be a list of at most 8 ints >= 0, got {shape!r}")
    if math.prod(shape) > MAX_ARRAY_ELEMENTS:
        raise ValueError(
            f"an array or space of shape {tuple(shape)} has {math.prod(shape):,} elements, more than the limit of "
            f"{MAX_ARRAY_ELEMENTS:,} (sb3_latentswarm.latent_ppo.model_file.MAX_ARRAY_ELEMENTS)"
        )
    values = np.asarray(value["__ndarray__"], dtype=dtype)
    if values.dtype.kind == "f" and np.isnan(values).any():
        raise ValueError("an array holds NaN")
    return np.broadcast_to(values, tuple(shape)).copy()


def _schedule_value(value: dict[str, Any], key: str) -> float:
    number = value[key]
    if not _is_number(number):
        raise ValueError(f"schedule {key} must be a finite number, got {number!r}")
    return float(number)


def from_plain(value: Any, algorithm: type | None = None) -> Any:
    """Decode what :func:`to_plain` wrote. Only its tags are read; no module or function named by the file is used."""
    if isinstance(value, list):
        return [from_plain(v, algorithm) for v in value]
    if not isinstance(value, dict):
        return value
    if "__tuple__" in value:
        return tuple(from_plain(v, algorithm) for v in value["__tuple__"])
    if "__deque__" in value:
        maxlen = value["maxlen"]
        if maxlen is not None and not (_is_int(maxlen) and 0 <= maxlen <= 100_000):
            raise ValueError(f"a deque's maxlen must be None or an int in [0, 100000], got {maxlen!r}")
        return collections.deque((from_plain(v, algorithm) for v in value["__deque__"]), maxlen=maxlen)
    if "__ndarray__" in value:
        return _array_from_plain(value)
    if "__space__" in value:
        return _space_from_plain(value)
    if "__swarm_config__" in value:
        fields = value["__swarm_config__"]
        if not isinstance(fields, dict):
            raise ValueError("a SwarmConfig must be stored as a dict of its fields")
        return SwarmConfig(**fields)
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
            return ConstantSchedule(_schedule_value(value, "value"))
        if kind == "linear":
            ends = (_schedule_value(value, key) for key in ("start", "end", "end_fraction"))
            return LinearSchedule(*ends)
        if kind == "step":
            return StepSchedule(*(_schedule_value(value, key) for key in ("initial_value", "final_value", "switch_fraction")))
        raise ValueError(f"unknown schedule {kind!r} in a model file")
    tags = [key for key in value if key.startswith("__") and key.endswith("__")]
    if tags:
        raise ValueError(f"unknown entry {tags[0]!r} in a model file")
    return {key: from_plain(v, algorithm) for key, v in value.items()}


# ---------------------------------------------------------------------------------------------- what a file may hold
def _is_int(value: Any) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _is_schedule(value: Any) -> bool:
    return _is_number(value) or isinstance(value, (ConstantSchedule, LinearSchedule, StepSchedule))


def _is_deque_of_dicts(value: Any) -> bool:
    return isinstance(value, collections.deque) and all(isinstance(v, dict) for v in value)


def _is_relative_path(value: Any) -> bool:
    if not isinstance(value, str) or not 0 < len(value) <= 255 or "\0" in value:
        return False
    path = pathlib.PurePath(value)
    return not path.is_absolute() and ".." not in path.parts


def _is_space(value: Any) -> bool:
    return isinstance(value, (spaces.Dict, spaces.Box))


STATE_ATTRIBUTES: dict[str, tuple[str, Any]] = {
    "policy_class": ("a policy alias ({\"__policy__\": NAME})", lambda v: isinstance(v, type)),
    "verbose": ("an int in [0, 2]", lambda v: _is_int(v) and 0 <= v <= 2),
    "policy_kwargs": ("a dict", lambda v: isinstance(v, dict)),
    "num_timesteps": ("an int >= 0", lambda v: _is_int(v) and v >= 0),
    "_total_timesteps": ("an int >= 0", lambda v: _is_int(v) and v >= 0),
    "_num_timesteps_at_start": ("an int >= 0", lambda v: _is_int(v) and v >= 0),
    "seed": ("None or an int", lambda v: v is None or _is_int(v)),
    "action_noise": ("None", lambda v: v is None),
    "start_time": ("a finite number", _is_number),
    "learning_rate": ("a finite number or a schedule", _is_schedule),
    "tensorboard_log": (
        "None or a relative path without '..' (at most 255 characters)",
        lambda v: v is None or _is_relative_path(v),
    ),
    "_episode_num": ("an int >= 0", lambda v: _is_int(v) and v >= 0),
    "use_sde": ("False", lambda v: v is False),
    "sde_sample_freq": ("an int", _is_int),
    "_current_progress_remaining": ("a finite number", _is_number),
    "_stats_window_size": ("an int in [1, 100000]", lambda v: _is_int(v) and 1 <= v <= 100_000),
    "ep_info_buffer": ("None or a deque of dicts", lambda v: v is None or _is_deque_of_dicts(v)),
    "ep_success_buffer": ("None or a deque", lambda v: v is None or isinstance(v, collections.deque)),
    "_n_updates": ("an int >= 0", lambda v: _is_int(v) and v >= 0),
    "n_steps": ("an int >= 1", lambda v: _is_int(v) and v >= 1),
    "gamma": ("a finite number", _is_number),
    "gae_lambda": ("a finite number", _is_number),
    "ent_coef": ("a finite number", _is_number),
    "vf_coef": ("a finite number", _is_number),
    "max_grad_norm": ("a finite number", _is_number),
    "rollout_buffer_class": ("None", lambda v: v is None),
    "rollout_buffer_kwargs": ("an empty dict", lambda v: v == {}),
    "batch_size": ("an int >= 1", lambda v: _is_int(v) and v >= 1),
    "n_epochs": ("an int >= 1", lambda v: _is_int(v) and v >= 1),
    "clip_range": ("a finite number or a schedule", _is_schedule),
    "clip_range_vf": ("None, a finite number or a schedule", lambda v: v is None or _is_schedule(v)),
    "normalize_advantage": ("True or False", lambda v: isinstance(v, bool)),
    "target_kl": ("None or a finite number", lambda v: v is None or _is_number(v)),
    "observation_space": ("a Box or Dict space", _is_space),
    "action_space": ("a Box space", lambda v: isinstance(v, spaces.Box)),
    "n_envs": ("an int >= 1", lambda v: _is_int(v) and v >= 1),
    # LatentSwarmPPO's own state
    "n_agents": ("an int >= 1", lambda v: _is_int(v) and v >= 1),
    "save_format": ("an int", _is_int),
    "saved_by_version": ("a str", lambda v: isinstance(v, str)),
    "swarm_config": ("None or a SwarmConfig", lambda v: v is None or isinstance(v, SwarmConfig)),
}
"""Every attribute that :func:`save_plain` writes for the algorithms of this package, with the type it must have once
decoded. Constructor arguments not listed here are accepted under their own name and checked by the constructor."""


def saved_attributes(algorithm: type) -> set[str]:
    """The attribute names :func:`save_plain` writes and :func:`load_plain` accepts: :data:`STATE_ATTRIBUTES` and the
    constructor arguments of ``algorithm``."""
    return set(STATE_ATTRIBUTES) | set(constructor_arguments(algorithm))


def check_attributes(algorithm: type, data: dict[str, Any], path: Any) -> None:
    """Refuse an attribute :func:`save_plain` does not write, or one of the wrong type, naming it.

    Allowed: the keys of :data:`STATE_ATTRIBUTES` (with their types) and the constructor arguments of ``algorithm``
    (validated by the constructor when the model is rebuilt).

    :raise ValueError: naming the file and the entry
    """
    allowed = saved_attributes(algorithm)
    for name, value in data.items():
        expected = STATE_ATTRIBUTES.get(name)
        if expected is None:
            if name in allowed:
                continue
            raise ValueError(
                f"{path}: data entry {name!r} is not an attribute that a saved {algorithm.__name__} holds; refused "
                f"(a model file may hold only the attributes its save writes)"
            )
        description, accepts = expected
        if not accepts(value):
            raise ValueError(f"{path}: data entry {name!r} must be {description}, got {_describe(value)}")
    if "policy_class" not in data:
        raise ValueError(f"{path}: the data entry has no 'policy_class'; this is not a complete saved model")
    aliases = getattr(algorithm, "policy_aliases", {})
    if not any(data["policy_class"] is policy for policy in aliases.values()):
        raise ValueError(f"{path}: data entry 'policy_class' must be one of {algorithm.__name__}'s policies {sorted(aliases)}")
    if "policy_kwargs" in data:
        _check_policy_kwargs(data["policy_kwargs"], path)


def _check_policy_kwargs(value: Any, path: Any, name: str = "policy_kwargs") -> None:
    if isinstance(value, dict):
        for key, v in value.items():
            _check_policy_kwargs(v, path, f"{name}[{key!r}]")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _check_policy_kwargs(v, path, f"{name}[{i}]")
    elif _is_int(value) and abs(value) > MAX_POLICY_WIDTH:
        raise ValueError(
            f"{path}: data entry {name} must be at most {MAX_POLICY_WIDTH} (the limit on network sizes), got {value}"
        )
    elif isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{path}: data entry {name} must be finite, got {value}")


def _describe(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} ({text[:80]}{'...' if len(text) > 80 else ''})"


def check_weights(module: th.nn.Module, params: object, entry: str, path: Any) -> None:
    """Compare the tensors read from ``entry`` with ``module``'s state dict: same names, dtypes and shapes, all finite.

    :raise ValueError: naming the file, the entry and the tensor
    """
    if not isinstance(params, dict):
        raise ValueError(f"{path}: {entry} must hold a dict of tensors, got {type(params).__name__}")
    expected = module.state_dict()
    missing, unexpected = sorted(set(expected) - set(params)), sorted(set(params) - set(expected))
    if missing or unexpected:
        raise ValueError(
            f"{path}: {entry} does not match the policy the file declares: missing tensors {missing[:5]}, unexpected "
            f"tensors {unexpected[:5]}"
        )
    for name, tensor in params.items():
        want = expected[name]
        if not isinstance(tensor, th.Tensor):
            raise ValueError(f"{path}: {entry}[{name!r}] must be a tensor, got {type(tensor).__name__}")
        if tensor.dtype != want.dtype or tensor.shape != want.shape:
            raise ValueError(
                f"{path}: {entry}[{name!r}] must be a {want.dtype} tensor of shape {tuple(want.shape)}, got "
                f"{tensor.dtype} of shape {tuple(tensor.shape)}"
            )
        if tensor.is_floating_point() and not bool(th.isfinite(tensor).all()):
            raise ValueError(f"{path}: {entry}[{name!r}] holds NaN or infinite values")


def _check_optimizer_state(state: Any, path: Any) -> None:
    if not isinstance(state, dict) or not isinstance(state.get("state", {}), dict):
        raise ValueError(f"{path}: policy.optimizer.pth must hold an optimizer state dict")
    for key, entry in state.get("state", {}).items():
        for name, tensor in (entry.items() if isinstance(entry, dict) else ()):
            if isinstance(tensor, th.Tensor) and tensor.is_floating_point() and not bool(th.isfinite(tensor).all()):
                raise ValueError(f"{path}: policy.optimizer.pth state {key}[{name!r}] holds NaN or infinite values")


# ---------------------------------------------------------------------------------------------- files
def constructor_arguments(algorithm: type) -> list[str]:
    """The keyword arguments of ``algorithm.__init__`` that a saved model carries (all but policy, env, device)."""
    parameters = inspect.signature(algorithm).parameters.values()
    return [p.name for p in parameters if p.name not in NOT_CONSTRUCTOR_ARGUMENTS and p.kind is p.POSITIONAL_OR_KEYWORD]


def _pickled_entries(value: Any, name: str = "data") -> list[str]:
    if isinstance(value, dict):
        if _PICKLE_MARK in value:
            return [name]
        return [entry for key, v in value.items() for entry in _pickled_entries(v, key)]
    if isinstance(value, list):
        return [entry for v in value for entry in _pickled_entries(v, name)]
    return []


def _json_depth(value: Any) -> int:
    """Nesting depth of decoded JSON, without recursion."""
    depth, level = 0, [value]
    while level:
        depth += 1
        children = (item.values() if isinstance(item, dict) else item for item in level if isinstance(item, (dict, list)))
        level = [value for items in children for value in items]
        if depth > MAX_DEPTH:
            break
    return depth


def check_model_path(path: Any) -> None:
    """Refuse, without opening it, a path that is not a regular file (a directory, a FIFO, a device): ``ValueError``."""
    if not isinstance(path, (str, os.PathLike)):
        return
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ValueError(f"{path}: no such model file") from None
    except OSError as error:
        raise ValueError(f"{path}: cannot read the model file ({error.strerror})") from None
    if stat.S_ISDIR(mode):
        raise ValueError(f"{path} is a directory, not a model file (.zip)")
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path} is not a regular file (a FIFO, socket or device?); a model file is a .zip file")


def read_data(path: str | pathlib.Path | io.BufferedIOBase) -> tuple[dict[str, Any], list[str]]:
    """The raw JSON of a model zip's ``data`` entry (nothing decoded, nothing unpickled) and its pickled entries.

    :raise ValueError: naming the file, for a path that is not a regular file, a file that is not a zip with a
        ``data`` entry, a ``data`` entry over :data:`MAX_DATA_BYTES`, nested deeper than :data:`MAX_DEPTH`, or not JSON
    """
    if isinstance(path, (str, os.PathLike)) and not os.path.lexists(path) and os.path.lexists(f"{path}.zip"):
        path = f"{path}.zip"  # SB3's convention: "model" names model.zip
    check_model_path(path)
    file = open_path(path, "r", verbose=0, suffix="zip")
    try:
        with zipfile.ZipFile(file) as archive:
            names = archive.namelist()
            if "data" not in names and {"model.zip", "state.json"} <= set(names):
                raise ValueError(
                    f"{path} is a training checkpoint, not a model file: continue it with "
                    f"sb3_latentswarm.runs.checkpoints.load_checkpoint(path, env) (CLI: train --resume), or use the "
                    f"model.zip its run saved"
                )
            if "data" not in names:
                raise ValueError(f"{path} is not a saved model: its zip has no 'data' entry")
            if len(set(names)) != len(names):
                raise ValueError(f"{path}: its zip holds an entry more than once; refused")
            size = archive.getinfo("data").file_size
            if size > MAX_DATA_BYTES:
                raise ValueError(
                    f"{path}: its 'data' entry is {size:,} bytes, more than the limit of {MAX_DATA_BYTES:,} "
                    f"(sb3_latentswarm.latent_ppo.model_file.MAX_DATA_BYTES)"
                )
            for name in TENSOR_ENTRIES:
                if name in archive.namelist() and archive.getinfo(name).file_size > MAX_TENSOR_ENTRY_BYTES:
                    raise ValueError(f"{path}: its {name!r} entry is over the limit of {MAX_TENSOR_ENTRY_BYTES:,} bytes")
            content = archive.read("data")
    except (zipfile.BadZipFile, EOFError, NotImplementedError) as error:
        raise ValueError(f"{path} is not a saved model (not a readable zip file: {error})") from None
    finally:
        if isinstance(path, (str, pathlib.Path)):
            file.close()
        else:
            file.seek(0)
    try:
        raw = json.loads(content.decode(), parse_int=bounded_int)
    except (UnicodeDecodeError, ValueError) as error:  # also an integer too long for Python to convert
        raise ValueError(f"{path}: its 'data' entry is not valid JSON ({error})") from None
    except RecursionError:
        raise ValueError(f"{path}: its 'data' entry is nested deeper than the limit of {MAX_DEPTH}") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: its 'data' entry must be a JSON object, got {type(raw).__name__}")
    if _json_depth(raw) > MAX_DEPTH:
        raise ValueError(f"{path}: its 'data' entry is nested deeper than the limit of {MAX_DEPTH}")
    return raw, _pickled_entries(raw)


def optimizer_entries(model: Any) -> set[str]:
    """The names among ``model``'s saved state dicts that are optimizers (``policy.optimizer``): a weight-only file
    leaves them out."""
    state_dicts, _ = model._get_torch_save_params()
    return {name for name in state_dicts if isinstance(recursive_getattr(model, name), th.optim.Optimizer)}


def save_plain(
    model: Any, path: str | pathlib.Path | io.BufferedIOBase, exclude=None, include=None, include_optimizer: bool = True
) -> None:
    """Save ``model`` (an SB3 algorithm) in SB3's zip layout with a plain-data ``data`` entry.

    What SB3's ``save`` would store, less :data:`RUN_STATE`, restricted to :func:`saved_attributes` (other attributes
    set on the model are not saved); :data:`MACHINE_SPECIFIC` attributes are stored as ``None`` when they are absolute
    paths.
    A schedule given as a plain function cannot be stored: it is saved as its current value, with a warning.

    :param include_optimizer: ``False`` writes a weight-only file: no optimizer state (Adam's two moments, about two
        thirds of a model file), which evaluation never reads; training after loading it starts a fresh optimizer
    """
    algorithm = type(model)
    excluded = set(exclude or ()).union(model._excluded_save_params(), RUN_STATE)
    excluded -= set(include or ())
    state_dicts, torch_variables = model._get_torch_save_params()
    excluded |= {name.split(".")[0] for name in state_dicts + torch_variables}
    saved = saved_attributes(algorithm)
    data: dict[str, Any] = {"plain_format": PLAIN_FORMAT}
    for name, value in model.__dict__.items():
        if name in excluded or name not in saved:
            continue
        if name in MACHINE_SPECIFIC:
            value = None if value is None or pathlib.Path(value).is_absolute() else str(value)
        elif callable(value) and not isinstance(value, type) and _schedule_to_plain(value) is None:
            current, which = float(value(model._current_progress_remaining)), "current"
            if not current > 0:  # a schedule that decayed to 0 (end of training): a constant 0 would not load
                current, which = float(value(1.0)), "initial"
            warnings.warn(
                f"{name} is a function, which a model file of plain data cannot hold: saved as its {which} value "
                f"{current:g}. Use a number, LinearSchedule or StepSchedule to save the schedule itself.",
                stacklevel=3,
            )
            value = current
        data[name] = to_plain(value, name, algorithm)
    if not include_optimizer:
        state_dicts = [name for name in state_dicts if name not in optimizer_entries(model)]
    params = {name: model.get_parameters()[name] for name in state_dicts}
    variables = {name: getattr(model, name) for name in torch_variables}
    save_to_zip_file(path, data=data, params=params, pytorch_variables=variables)


def load_plain(
    algorithm: type,
    path: Any,
    raw: dict[str, Any],
    device: th.device | str = "auto",
    print_system_info: bool = False,
    n_envs_to_train: int | None = None,
    **kwargs: Any,
) -> Any:
    """Rebuild a model of class ``algorithm`` saved by :func:`save_plain`, without an env.

    The saved constructor arguments, with ``kwargs`` in place of any of them, go through ``algorithm(...)`` so that
    its checks apply; the other saved attributes are then restored and the tensors read with ``weights_only=True``.
    A weight-only file (saved with ``include_optimizer=False``) loads with a fresh optimizer, and the model's
    ``_fresh_optimizer`` is then ``True`` (``LatentSwarmPPO.learn`` warns of it once).

    :param raw: the file's ``data`` entry as read by :func:`read_data` (free of pickles)
    :param n_envs_to_train: the slots of the env the model will train on, if any: its rollout buffer counts in the
        memory budget (:func:`~sb3_latentswarm.latent_ppo.load_checks.check_load_budget`)
    :raise TypeError: for a keyword that is not a constructor argument, listing those that are
    """
    if raw.get("plain_format") != PLAIN_FORMAT:
        raise ValueError(f"{path}: unknown plain-data format {raw.get('plain_format')!r} (this version reads {PLAIN_FORMAT})")
    data = {}
    for name, value in raw.items():
        if name == "plain_format":
            continue
        try:
            data[name] = from_plain(value, algorithm)
        except (KeyError, TypeError, ValueError, OverflowError) as error:
            detail = f"missing field {error}" if isinstance(error, KeyError) else str(error)
            raise ValueError(f"{path}: data entry {name!r} cannot be read: {detail}") from None
    check_attributes(algorithm, data, path)
    check_config_matches_space(data.get("swarm_config"), data.get("observation_space"), path)
    arguments = constructor_arguments(algorithm)
    unknown = sorted(set(kwargs) - set(arguments))
    if unknown:
        raise TypeError(f"{algorithm.__name__}.load got unknown keyword argument(s) {unknown}; valid: {', '.join(arguments)}")
    # the saved value of each argument: its attribute of the same name, or SB3's private one (stats_window_size)
    saved = {name: data.get(name, data.get(f"_{name}")) for name in arguments if name in data or f"_{name}" in data}
    saved.pop("verbose", None)  # build quietly; the saved verbosity comes back with the other attributes
    try:
        model = algorithm(
            policy=data.pop("policy_class"), env=None, device=device, _init_setup_model=False, **{**saved, **kwargs}
        )
    except (TypeError, ValueError) as error:
        raise type(error)(f"{path}: {error}") from None
    overridden = set(kwargs) | {f"_{name}" for name in kwargs}
    model.__dict__.update({name: value for name, value in data.items() if name not in overridden})
    if hasattr(model, "_check_loaded"):  # the algorithm's checks of saved values that depend on each other
        model._check_loaded(path)
    check_load_budget(model, path, n_envs_to_train)  # before anything the file declares is allocated
    try:
        model._setup_model()
    except (TypeError, ValueError, RuntimeError) as error:
        raise ValueError(f"{path}: the model the file declares cannot be built: {error}") from None
    # the tensors: torch.load(weights_only=True), which reads tensors and plain containers only
    try:
        _, params, variables = load_from_zip_file(path, load_data=False, device=device, print_system_info=print_system_info)
    except Exception as error:  # noqa: BLE001 - torch's own text suggests weights_only=False, which must not be followed
        raise ValueError(
            f"{path}: its tensor entries ({', '.join(TENSOR_ENTRIES)}) cannot be read as plain tensors "
            f"({type(error).__name__}); the file is damaged or not a model file. It is refused."
        ) from None
    params = params or {}
    if "policy" not in params:
        raise ValueError(f"{path}: the file has no policy weights (policy.pth)")
    check_weights(model.policy, params["policy"], "policy.pth", path)
    for name in set(params) - {"policy"}:
        if name == "policy.optimizer":
            _check_optimizer_state(params[name], path)
    # only the optimizer state may be absent (a weight-only file); the policy's tensors were matched name by name above
    absent = set(model._get_torch_save_params()[0]) - set(params)
    if absent - optimizer_entries(model):
        raise ValueError(f"{path}: the file has no {', '.join(sorted(absent))} entry")
    try:
        model.set_parameters(params, exact_match=not absent, device=device)
    except (KeyError, RuntimeError, ValueError) as error:
        raise ValueError(f"{path}: its tensors do not fit the model it declares ({error})") from None
    model._fresh_optimizer = bool(absent)
    for name, value in (variables or {}).items():
        if value is not None:
            current = getattr(model, name, None)
            if not isinstance(current, th.Tensor) or not isinstance(value, th.Tensor) or value.shape != current.shape:
                raise ValueError(f"{path}: pytorch_variables.pth entry {name!r} does not fit the model")
            if value.is_floating_point() and not bool(th.isfinite(value).all()):
                raise ValueError(f"{path}: pytorch_variables.pth entry {name!r} holds NaN or infinite values")
            current.data = value.data
    return model
