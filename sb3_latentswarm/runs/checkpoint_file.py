"""Reading a training checkpoint under the model-file rules (``docs/security.md``): nothing in the file decides what
runs, where anything is written, or how much is allocated beyond documented limits.

A checkpoint (written by :func:`~sb3_latentswarm.runs.checkpoints.checkpoint_bytes`) is a zip of exactly four entries,
each read in full before anything is used (a damaged byte anywhere fails its CRC):

* ``model.zip``: a model file, read by the model-file loader with its own rules and limits;
* ``state.json``: every key whitelisted and type- and range-checked by :func:`check_state` (integers of at most
  :data:`MAX_INT_DIGITS` digits; the per-swarm random streams restored only as one of the generator kinds of
  :data:`BIT_GENERATORS`, by table, never by a name looked up in NumPy);
* ``arrays.npz``: NumPy arrays of the names :func:`check_array_names` allows, read with ``allow_pickle=False``, numbers
  only;
* ``tensors.pth``: torch tensors of the names it allows, read with ``torch.load(weights_only=True)``.

What depends on the model and the env (shapes, counters, covered-cell counts, observation bounds) is checked when the
run state is restored (:func:`~sb3_latentswarm.runs.checkpoints.restore_run_state`), before anything is changed. Every
error is a :class:`CheckpointError` naming the file.
"""

from __future__ import annotations

import io
import json
import math
import numbers
import os
import re
import stat
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch as th

from sb3_latentswarm.latent_ppo.load_checks import MAX_INT_DIGITS, bounded_int

__all__ = [
    "BIT_GENERATORS",
    "CheckpointContents",
    "CheckpointError",
    "ENTRY_LIMITS",
    "MAX_CHECKPOINT_BYTES",
    "MAX_INT_DIGITS",
    "check_state",
    "compare_settings",
    "describe_differences",
    "newest_valid_checkpoint",
    "read_checkpoint",
    "read_checkpoint_state",
]

CHECKPOINT_FORMAT = 1
"""Version of the checkpoint layout (``state.json``'s ``checkpoint_format``)."""

ENTRY_LIMITS = {"model.zip": 2**30, "state.json": 16 * 2**20, "arrays.npz": 2**28, "tensors.pth": 2**26}
"""The entries of a checkpoint and the largest size read of each, in bytes: the model file 1 GiB (within it, the
model-file limits hold), ``state.json`` 16 MiB, ``arrays.npz`` 256 MiB, ``tensors.pth`` 64 MiB. A ``paper`` run's
checkpoint holds about 120 MB, nearly all of it the model's weights and optimizer state. Entries are stored
uncompressed (as :func:`~sb3_latentswarm.runs.checkpoints.checkpoint_bytes` writes them), so a checkpoint's size on
disk bounds what reading it takes."""

MAX_CHECKPOINT_BYTES = 2**30 + 2**29
"""Largest total size of a checkpoint's entries: 1.5 GiB."""

MAX_SUMMARIES = 100_000
"""Most swarm summaries kept in a checkpoint (the model's statistics window holds at most this many)."""

BIT_GENERATORS: dict[str, type[np.random.BitGenerator]] = {
    "PCG64": np.random.PCG64,
    "PCG64DXSM": np.random.PCG64DXSM,
    "MT19937": np.random.MT19937,
    "Philox": np.random.Philox,
    "SFC64": np.random.SFC64,
}
"""The NumPy generator kinds a checkpoint's per-swarm random streams may have: a fixed table, so the file cannot name a
function to call."""

_ARRAY_NAME = re.compile(r"^(numpy_random_keys|last_episode_starts|last_obs\.\w{1,64}|env\.monitor_episode_(returns|lengths)"
                         r"|env\.core\.[\w.]{1,64})$")
_TENSOR_NAME = re.compile(r"^(torch_rng|cuda_rng_\d{1,3}|latent\.\w{1,64})$")
_STATE_KEYS = {
    "checkpoint_format", "num_timesteps", "n_updates", "total_timesteps", "rng", "env", "swarm_summaries",
    "tensorboard_log", "pending_log", "settings", "extra",
}
_ENV_KEYS = {"backend", "monitor_episode_count", "swarm_rngs", "swarm_seeds", "pending_seed", "seeded"}
_SUMMARY_KEYS = {
    "coverage", "collisions", "steps_to_90", "length", "episode_return", "link_up_rate", "dropout_rate", "truncated",
}
_JSON_DEPTH = 32


class CheckpointError(ValueError):
    """A checkpoint is missing, damaged, or does not belong to the run that tries to continue from it."""


class CheckpointContents(NamedTuple):
    """A checkpoint read in full and checked on its own (:func:`read_checkpoint`)."""

    path: Path
    state: dict[str, Any]
    model_file: bytes
    arrays: dict[str, np.ndarray]
    tensors: dict[str, th.Tensor]


class NamedBytes(io.BytesIO):
    """An in-memory entry that prints as ``FILE (entry NAME)``, so the model-file loader's errors name the checkpoint."""

    def __init__(self, data: bytes, name: str):
        super().__init__(data)
        self._label = name

    def __repr__(self) -> str:
        return self._label

    __str__ = __repr__


# ---------------------------------------------------------------------------------------------- the zip
def _entry_bytes(archive: zipfile.ZipFile, name: str, path: Any, what: str = "entry") -> bytes:
    try:
        return archive.read(name)
    except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, ValueError) as error:  # CRC, truncation, encryption
        raise CheckpointError(f"{path}: its {what} {name!r} is damaged ({error}); the file cannot be used") from None
    except NotImplementedError:
        raise CheckpointError(f"{path}: its {what} {name!r} uses a compression this reader does not accept") from None


def check_zip(
    archive: zipfile.ZipFile, path: Any, limits: dict[str, int], total: int, what: str = "entry", stored: bool = False
) -> None:
    """Refuse duplicate entries, entries over their limit in ``limits`` or over ``total`` together, and compressed ones
    (``stored``), naming them."""
    names = [info.filename for info in archive.infolist()]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise CheckpointError(f"{path}: the zip holds the {what} {duplicates} more than once; refused")
    for info in archive.infolist():
        if info.compress_type not in ((zipfile.ZIP_STORED,) if stored else (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED)):
            raise CheckpointError(f"{path}: {what} {info.filename!r} uses a compression this reader does not accept")
        limit = limits.get(info.filename)
        if limit is not None and info.file_size > limit:
            raise CheckpointError(
                f"{path}: its {what} {info.filename!r} is {info.file_size:,} bytes, over the limit of {limit:,}"
            )
    size = sum(info.file_size for info in archive.infolist())
    if size > total:
        raise CheckpointError(f"{path}: its {what}s hold {size:,} bytes together, over the limit of {total:,}")


def _open(path: str | Path) -> zipfile.ZipFile:
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise CheckpointError(f"no checkpoint at {path}") from None
    except OSError as error:
        raise CheckpointError(f"{path}: cannot read the checkpoint ({error.strerror})") from None
    if not stat.S_ISREG(mode):
        raise CheckpointError(f"{path} is not a regular file; a checkpoint is a .zip file")
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as error:
        raise CheckpointError(f"{path} is not a checkpoint (not a readable zip file: {error})") from None
    try:
        check_zip(archive, path, ENTRY_LIMITS, MAX_CHECKPOINT_BYTES, stored=True)
        names = set(archive.namelist())
        if "data" in names and "model.zip" not in names:
            raise CheckpointError(
                f"{path} is a model file, not a checkpoint: load it with LatentSwarmPPO.load (CLI: --warm-start / --model)"
            )
        missing, unknown = sorted(set(ENTRY_LIMITS) - names), sorted(names - set(ENTRY_LIMITS))
        if missing or unknown:
            parts = [f"it lacks {missing}"] if missing else []
            parts += [f"unknown entries {unknown}"] if unknown else []
            raise CheckpointError(f"{path} is not a checkpoint of sb3-latentswarm: {'; '.join(parts)}")
    except BaseException:
        archive.close()
        raise
    return archive


# ---------------------------------------------------------------------------------------------- state.json
def parse_json(content: bytes, path: Any, name: str) -> Any:
    """Parse a JSON entry: integers of at most :data:`MAX_INT_DIGITS` digits, nested at most 32 deep."""
    try:
        value = json.loads(content.decode("utf-8"), parse_int=bounded_int)
    except (UnicodeDecodeError, ValueError) as error:
        raise CheckpointError(f"{path}: its {name!r} is not valid JSON ({error})") from None
    except RecursionError:
        raise CheckpointError(f"{path}: its {name!r} is nested too deep") from None
    depth, level = 0, [value]
    while level:
        depth += 1
        if depth > _JSON_DEPTH:
            raise CheckpointError(f"{path}: its {name!r} is nested deeper than {_JSON_DEPTH}")
        children = (item.values() if isinstance(item, dict) else item for item in level if isinstance(item, (dict, list)))
        level = [v for items in children for v in items]
    return value


def _is_int(value: Any, low: int | None = None, high: int | None = None) -> bool:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        return False
    number = int(value)
    return (low is None or number >= low) and (high is None or number <= high)


def _is_finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _expect(ok: bool, path: Any, name: str, must: str, value: Any) -> None:
    if not ok:
        text = repr(value)
        raise CheckpointError(f"{path}: state.json {name} must be {must}, got {text[:80]}{'...' if len(text) > 80 else ''}")


def _check_rng(rng: Any, path: Any) -> None:
    _expect(isinstance(rng, dict) and set(rng) == {"python_random", "numpy_random"}, path, "'rng'",
            "a dict of 'python_random' and 'numpy_random'", rng)
    py = rng["python_random"]
    _expect(isinstance(py, dict) and set(py) == {"version", "internal", "gauss_next"}, path, "rng.python_random",
            "a dict of version, internal, gauss_next", py)
    _expect(py["version"] == 3, path, "rng.python_random.version", "3", py["version"])
    internal = py["internal"]
    _expect(isinstance(internal, list) and len(internal) == 625 and all(_is_int(v, 0, 2**32 - 1) for v in internal[:624])
            and _is_int(internal[624], 1, 624), path, "rng.python_random.internal",
            "625 ints (624 words < 2**32 and a position in [1, 624])", internal)
    _expect(py["gauss_next"] is None or _is_finite(py["gauss_next"]), path, "rng.python_random.gauss_next",
            "None or a finite number", py["gauss_next"])
    npr = rng["numpy_random"]
    _expect(isinstance(npr, dict) and set(npr) == {"name", "pos", "has_gauss", "cached_gaussian"}, path,
            "rng.numpy_random", "a dict of name, pos, has_gauss, cached_gaussian", npr)
    _expect(npr["name"] == "MT19937", path, "rng.numpy_random.name", "'MT19937'", npr["name"])
    _expect(_is_int(npr["pos"], 0, 624), path, "rng.numpy_random.pos", "an int in [0, 624]", npr["pos"])
    _expect(_is_int(npr["has_gauss"], 0, 1), path, "rng.numpy_random.has_gauss", "0 or 1", npr["has_gauss"])
    _expect(_is_finite(npr["cached_gaussian"]), path, "rng.numpy_random.cached_gaussian", "a finite number",
            npr["cached_gaussian"])


def make_generator(state: Any, path: Any, name: str) -> np.random.Generator:
    """A ``numpy.random.Generator`` in the saved ``state`` of one of the kinds of :data:`BIT_GENERATORS`."""
    _expect(isinstance(state, dict) and state.get("bit_generator") in BIT_GENERATORS, path, name,
            f"the state of a NumPy generator of kind {sorted(BIT_GENERATORS)}", state)
    bit_generator = BIT_GENERATORS[state["bit_generator"]]()
    try:
        bit_generator.state = state
    except (TypeError, ValueError, KeyError, OverflowError) as error:
        raise CheckpointError(f"{path}: state.json {name} is not a valid {state['bit_generator']} state ({error})") from None
    return np.random.Generator(bit_generator)


def _check_env(env: Any, path: Any) -> None:
    _expect(isinstance(env, dict) and set(env) <= _ENV_KEYS, path, "'env'", f"a dict of some of {sorted(_ENV_KEYS)}", env)
    if "backend" in env:
        _expect(isinstance(env["backend"], str) and len(env["backend"]) <= 100, path, "env.backend", "a class name",
                env["backend"])
    if "monitor_episode_count" in env:
        _expect(_is_int(env["monitor_episode_count"], 0), path, "env.monitor_episode_count", "an int >= 0",
                env["monitor_episode_count"])
    batched = {"swarm_rngs", "swarm_seeds", "pending_seed", "seeded"}
    if batched & set(env):
        _expect(batched <= set(env), path, "'env'", f"all of {sorted(batched)} or none", sorted(env))
        rngs, seeds = env["swarm_rngs"], env["swarm_seeds"]
        _expect(isinstance(rngs, list) and 1 <= len(rngs) <= 100_000, path, "env.swarm_rngs", "a list of generator states",
                rngs)
        for k, state in enumerate(rngs):
            make_generator(state, path, f"env.swarm_rngs[{k}]")
        _expect(isinstance(seeds, list) and len(seeds) == len(rngs) and all(s is None or _is_int(s, 0) for s in seeds),
                path, "env.swarm_seeds", f"a list of {len(rngs)} ints >= 0 or None", seeds)
        pending = env["pending_seed"]
        _expect(pending is None or _is_int(pending, 0) or (isinstance(pending, list) and all(_is_int(s, 0) for s in pending)),
                path, "env.pending_seed", "None, an int >= 0 or a list of them", pending)
        _expect(isinstance(env["seeded"], bool), path, "env.seeded", "true or false", env["seeded"])


def _check_summary(summary: Any, path: Any, name: str) -> None:
    _expect(isinstance(summary, dict) and set(summary) <= _SUMMARY_KEYS, path, name,
            f"a dict of some of {sorted(_SUMMARY_KEYS)}", summary)
    checks: dict[str, tuple[Callable[[Any], bool], str]] = {
        "coverage": (lambda v: _is_finite(v) and 0 <= v <= 1, "a number in [0, 1]"),
        "link_up_rate": (lambda v: _is_finite(v) and 0 <= v <= 1, "a number in [0, 1]"),
        "dropout_rate": (lambda v: _is_finite(v) and 0 <= v <= 1, "a number in [0, 1]"),
        "collisions": (lambda v: _is_int(v, 0), "an int >= 0"),
        "length": (lambda v: _is_int(v, 0), "an int >= 0"),
        "steps_to_90": (lambda v: v is None or _is_int(v, 0), "None or an int >= 0"),
        "episode_return": (_is_finite, "a finite number"),
        "truncated": (lambda v: isinstance(v, bool), "true or false"),
    }
    for key, value in summary.items():
        accepts, must = checks[key]
        _expect(accepts(value), path, f"{name}.{key}", must, value)


def _check_pending_log(pending: Any, path: Any) -> None:
    if pending == {}:
        return
    _expect(isinstance(pending, dict) and set(pending) == {"values", "excluded"}, path, "'pending_log'",
            "a dict of 'values' and 'excluded'", pending)
    values, excluded = pending["values"], pending["excluded"]
    _expect(isinstance(values, dict) and len(values) <= 1000, path, "pending_log.values", "a dict of logged numbers", values)
    for key, value in values.items():
        _expect(re.fullmatch(r"train/[\w/.-]{1,100}", key) is not None, path, "a pending_log key", "a 'train/...' name", key)
        _expect(isinstance(value, (int, float)) and not isinstance(value, bool), path, f"pending_log.values[{key!r}]",
                "a number", value)
    _expect(isinstance(excluded, dict) and set(excluded) <= set(values), path, "pending_log.excluded",
            "a dict over the logged keys", excluded)
    for key, value in excluded.items():
        _expect(value is None or (isinstance(value, list) and all(v in ("", "stdout", "log", "json", "csv", "tensorboard")
                                                                   for v in value)),
                path, f"pending_log.excluded[{key!r}]", "None or a list of SB3 output formats", value)


def check_state(state: Any, path: Any) -> dict[str, Any]:
    """Check a checkpoint's ``state.json`` on its own: only the keys it may hold, each of its type and range.

    :raise CheckpointError: naming the file and the key
    """
    _expect(isinstance(state, dict), path, "", "a JSON object", state)
    if state.get("checkpoint_format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{path} has checkpoint format {state.get('checkpoint_format')!r}; this version reads {CHECKPOINT_FORMAT}"
        )
    missing, unknown = sorted(_STATE_KEYS - set(state)), sorted(set(state) - _STATE_KEYS)
    if missing or unknown:
        parts = [f"lacks {missing}"] if missing else []
        parts += [f"holds unknown keys {unknown}"] if unknown else []
        raise CheckpointError(f"{path}: state.json {'; '.join(parts)}")
    for name in ("num_timesteps", "n_updates", "total_timesteps"):
        _expect(_is_int(state[name], 0), path, f"'{name}'", "an int >= 0", state[name])
    _check_rng(state["rng"], path)
    _check_env(state["env"], path)
    summaries = state["swarm_summaries"]
    _expect(isinstance(summaries, list) and len(summaries) <= MAX_SUMMARIES, path, "'swarm_summaries'",
            f"a list of at most {MAX_SUMMARIES} summaries", summaries)
    for k, summary in enumerate(summaries):
        _check_summary(summary, path, f"swarm_summaries[{k}]")
    # kept for the record only: a checkpoint never chooses where a resumed run writes
    log = state["tensorboard_log"]
    _expect(log is None or (isinstance(log, str) and len(log) <= 4096), path, "'tensorboard_log'", "None or a path", log)
    _check_pending_log(state["pending_log"], path)
    for name in ("settings", "extra"):
        _expect(isinstance(state[name], dict), path, f"'{name}'", "a JSON object", state[name])
    return state


def read_checkpoint_state(path: str | Path) -> dict[str, Any]:
    """The checked ``state.json`` of a checkpoint (``num_timesteps``, ``settings``, ``extra``, ...), nothing else read.

    :raise CheckpointError: for a missing, damaged or crafted file, naming it
    """
    with _open(path) as archive:
        content = _entry_bytes(archive, "state.json", path)
    return check_state(parse_json(content, path, "state.json"), path)


# ---------------------------------------------------------------------------------------------- arrays and tensors
def _read_arrays(data: bytes, path: Any) -> dict[str, np.ndarray]:
    try:
        inner = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, ValueError) as error:
        raise CheckpointError(f"{path}: its entry 'arrays.npz' is not a NumPy archive ({error})") from None
    with inner:
        names = inner.namelist()
        check_zip(inner, path, {}, ENTRY_LIMITS["arrays.npz"], what="array")
        for name in names:
            if not name.endswith(".npy") or not _ARRAY_NAME.match(name[:-4]):
                raise CheckpointError(f"{path}: arrays.npz holds an unknown array {name!r}; refused")
        arrays = {}
        for name in names:
            try:
                array = np.load(io.BytesIO(_entry_bytes(inner, name, path, "array")), allow_pickle=False)
            except (ValueError, OSError, EOFError) as error:  # numpy's text advises allow_pickle: not for this file
                kind = "an object array (pickled objects)" if "pickle" in str(error) else f"not a NumPy array ({error})"
                raise CheckpointError(f"{path}: arrays.npz entry {name[:-4]!r} is {kind}; refused") from None
            if not isinstance(array, np.ndarray) or array.dtype.kind not in "biuf" or not array.dtype.isbuiltin:
                raise CheckpointError(f"{path}: arrays.npz entry {name[:-4]!r} must hold numbers, got dtype {array.dtype}")
            arrays[name[:-4]] = array
    return arrays


def _read_tensors(data: bytes, path: Any) -> dict[str, th.Tensor]:
    try:
        check_zip(zipfile.ZipFile(io.BytesIO(data)), path, {}, ENTRY_LIMITS["tensors.pth"], what="tensor record")
        tensors = th.load(io.BytesIO(data), weights_only=True, map_location="cpu")
    except CheckpointError:
        raise
    except Exception as error:  # noqa: BLE001 - torch's own text suggests weights_only=False, which must not be followed
        raise CheckpointError(
            f"{path}: its entry 'tensors.pth' cannot be read as plain tensors ({type(error).__name__}); the file is "
            f"damaged or crafted. It is refused."
        ) from None
    if not isinstance(tensors, dict):
        raise CheckpointError(f"{path}: tensors.pth must hold a dict of tensors, got {type(tensors).__name__}")
    for name, tensor in tensors.items():
        if not isinstance(name, str) or not _TENSOR_NAME.match(name):
            raise CheckpointError(f"{path}: tensors.pth holds an unknown entry {name!r}; refused")
        if not isinstance(tensor, th.Tensor):
            raise CheckpointError(f"{path}: tensors.pth entry {name!r} must be a tensor, got {type(tensor).__name__}")
        if tensor.is_floating_point() and not bool(th.isfinite(tensor).all()):
            raise CheckpointError(f"{path}: tensors.pth entry {name!r} holds NaN or infinite values")
    if "torch_rng" not in tensors:
        raise CheckpointError(f"{path}: tensors.pth has no 'torch_rng'")
    return tensors


def read_checkpoint(path: str | Path) -> CheckpointContents:
    """Read a whole checkpoint and check it on its own (structure, types, ranges; every byte through its CRC).

    Cheap next to a load (no model is built): what :func:`newest_valid_checkpoint` uses to tell a damaged file.

    :raise CheckpointError: naming the file and what is wrong
    """
    with _open(path) as archive:
        entries = {name: _entry_bytes(archive, name, path) for name in ENTRY_LIMITS}
    state = check_state(parse_json(entries["state.json"], path, "state.json"), path)
    arrays = _read_arrays(entries["arrays.npz"], path)
    tensors = _read_tensors(entries["tensors.pth"], path)
    keys = arrays.get("numpy_random_keys")
    if keys is None or keys.shape != (624,) or keys.dtype != np.uint32:
        raise CheckpointError(f"{path}: arrays.npz 'numpy_random_keys' must be 624 uint32 words")
    if tensors["torch_rng"].dtype != th.uint8 or tensors["torch_rng"].shape != th.get_rng_state().shape:
        raise CheckpointError(f"{path}: tensors.pth 'torch_rng' is not a torch generator state")
    try:
        with zipfile.ZipFile(io.BytesIO(entries["model.zip"])) as model_zip:
            check_zip(model_zip, f"{path} (entry model.zip)", {}, ENTRY_LIMITS["model.zip"])
            for name in model_zip.namelist():
                _entry_bytes(model_zip, name, f"{path} (entry model.zip)")
    except zipfile.BadZipFile as error:
        raise CheckpointError(f"{path}: its entry 'model.zip' is not a zip file ({error})") from None
    return CheckpointContents(Path(path), state, entries["model.zip"], arrays, tensors)


# ---------------------------------------------------------------------------------------------- choosing and comparing
def newest_valid_checkpoint(
    checkpoints: list[Path], report: Callable[[str], None] | None = print
) -> tuple[Path, CheckpointContents]:
    """The newest of ``checkpoints`` (oldest first) that reads as a whole; a damaged newer one is skipped with one line
    to ``report`` naming it, the reason and the checkpoint used instead.

    :raise CheckpointError: when none is valid, naming each file and why
    """
    skipped: list[tuple[Path, str]] = []
    for path in reversed(checkpoints):
        try:
            contents = read_checkpoint(path)
        except CheckpointError as error:
            skipped.append((path, str(error)))
            continue
        if skipped and report is not None:
            names = ", ".join(p.name for p, _ in skipped)
            report(f"Skipping damaged checkpoint(s) {names} ({skipped[0][1]}); resuming from the older {path}")
        return path, contents
    if not skipped:
        raise CheckpointError("no checkpoint to resume from")
    raise CheckpointError("no valid checkpoint: " + "; ".join(reason for _, reason in skipped))


def describe_differences(stored: dict[str, Any], current: dict[str, Any], names: Any = None) -> list[str]:
    """``name: checkpoint X, this run Y`` for each of ``names`` (default: every key of either) that differs."""
    keys = sorted(set(stored) | set(current)) if names is None else list(names)
    return [f"{key}: checkpoint {stored.get(key)!r}, this run {current.get(key)!r}" for key in keys
            if stored.get(key) != current.get(key)]


def compare_settings(stored: dict[str, Any], current: dict[str, Any], path: Any, names: Any = None) -> None:
    """Refuse to continue the run of checkpoint ``path`` with other settings, naming every one that differs."""
    differ = describe_differences(stored, current, names)
    if differ:
        raise CheckpointError(f"{path} belongs to a run with other settings: {'; '.join(differ)}")
