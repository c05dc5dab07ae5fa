"""Hostile checkpoints: crafted and damaged checkpoints and faults, each tried and classified (issue 34).

Trains one tiny run (3 updates, a checkpoint after each), then tries every case of :func:`cases` in a fresh folder and
prints one line per case and the outcome counts:

* ``works``: the run continues (or the fault is handled) correctly; an edit that stays in range and consistent works;
* ``clear error``: refused with one line that names the file (or folder) and no library advice
  (``weights_only=False``, ``allow_pickle``);
* ``unclear``: refused with another exception, a message without the file's name, or a failure after loading;
* ``silent wrong``: an edit that must be refused (out of range, inconsistent, another run's settings) is accepted;
* ``data loss``: another checkpoint or the run's files were changed or deleted;
* ``escape``: a file was written outside the case's folder (where the checkpoint pointed), or code from the file ran.

Run: ``nice -n 19 python benchmarks/hostile_checkpoints.py [--out benchmarks/results/hostile_checkpoints.txt]``.
Tests (``tests/test_checkpoint_safety.py``) run a seeded subset of the same table.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import hashlib
import io
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="also write the report to this file")
    parser.add_argument("--only", default=None, help="run only the cases whose name contains this text")
    return parser


if __name__ == "__main__":
    build_parser().parse_args()  # --help answers before torch loads


import numpy as np  # noqa: E402
import torch as th  # noqa: E402

th.set_num_threads(1)

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env  # noqa: E402
from sb3_latentswarm.runs.checkpoint_file import compare_settings  # noqa: E402
from sb3_latentswarm.runs.checkpoints import (  # noqa: E402
    CheckpointError,
    StopOnSignal,
    SwarmCheckpointCallback,
    list_checkpoints,
    load_checkpoint,
    newest_valid_checkpoint,
    resume_tensorboard,
)
from sb3_latentswarm.utils.locks import OutputInUseError, output_lock  # noqa: E402

OUTCOMES = ("works", "clear error", "unclear", "silent wrong", "data loss", "escape")
SMALL = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=30, num_obstacles=5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)
PER_UPDATE = 20 * 6  # n_steps x slots (2 swarms of 3 agents)
ADVICE = ("weights_only", "allow_pickle", "Traceback")
ROOT = Path(__file__).resolve().parents[1]


def make_env(config: SwarmConfig = SMALL) -> Any:
    return make_vec_env(2, config=config, seed=0)


def make_model(env: Any) -> LatentSwarmPPO:
    return LatentSwarmPPO(
        "LatentSwarmPolicy", env, n_steps=20, chunk_length=5, batch_size=30, n_epochs=1, policy_kwargs=TINY_POLICY, seed=0
    )


def train_base(folder: Path) -> list[Path]:
    """A run of 3 updates with a checkpoint after each: ``folder/checkpoint_{120,240,360}_steps.zip``."""
    model = make_model(make_env())
    callback = SwarmCheckpointCallback(PER_UPDATE, folder, keep=5, settings={"preset": "hostile", "p_fail": 0.1})
    model.learn(3 * PER_UPDATE, callback=callback)
    return list_checkpoints(folder)


# ---------------------------------------------------------------------------------------------- crafting
def read_parts(path: Path) -> dict[str, Any]:
    with zipfile.ZipFile(path) as archive:
        raw = {name: archive.read(name) for name in archive.namelist()}
    with np.load(io.BytesIO(raw["arrays.npz"]), allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    tensors = th.load(io.BytesIO(raw["tensors.pth"]), weights_only=True)
    with zipfile.ZipFile(io.BytesIO(raw["model.zip"])) as model_zip:
        model = {name: model_zip.read(name) for name in model_zip.namelist()}
    return {"state": json.loads(raw["state.json"]), "arrays": arrays, "tensors": tensors, "model": model, "raw": raw}


def write_parts(path: Path, parts: dict[str, Any], entries: list[tuple[str, bytes]] | None = None,
                compression: int = zipfile.ZIP_STORED) -> Path:
    """Write a checkpoint from (edited) parts; ``entries`` replaces the entry list (duplicates, extra entries)."""
    if entries is None:
        npz, pth, model_zip = io.BytesIO(), io.BytesIO(), io.BytesIO()
        np.savez(npz, **parts["arrays"])
        th.save(parts["tensors"], pth)
        with zipfile.ZipFile(model_zip, "w") as archive:
            for name, content in parts["model"].items():
                archive.writestr(name, content)
        entries = [
            ("model.zip", model_zip.getvalue()),
            ("state.json", parts["state"] if isinstance(parts["state"], bytes) else json.dumps(parts["state"]).encode()),
            ("arrays.npz", npz.getvalue()),
            ("tensors.pth", pth.getvalue()),
        ]
    with zipfile.ZipFile(path, "w", compression=compression) as archive, warnings_off():
        for name, content in entries:
            archive.writestr(name, content)
    return path


@contextlib.contextmanager
def warnings_off():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def write_file(path: Path, content: bytes) -> Path:
    path.write_bytes(content)
    return path


def model_data(parts: dict[str, Any]) -> dict[str, Any]:
    return json.loads(parts["model"]["data"])


def set_model_data(parts: dict[str, Any], data: dict[str, Any] | bytes) -> None:
    parts["model"]["data"] = data if isinstance(data, bytes) else json.dumps(data).encode()


# ---------------------------------------------------------------------------------------------- the cases
@dataclass(frozen=True)
class Case:
    """One hostile input or fault.

    :param refuse: whether a correct reader must refuse it (``False``: an in-range, consistent edit, or a fault the
        run must survive)
    :param craft: makes the case in ``work`` from the base run's checkpoints; returns the checkpoint to load, or an
        outcome already decided (a fault case classifies itself)
    :param escape: a path that must not exist after the case (where the file tried to make the run write)
    """

    name: str
    group: str
    refuse: bool
    craft: Callable[[Path, list[Path]], Any]
    escape: str | None = None


def edit(fn: Callable[[dict[str, Any]], Any]) -> Callable[[Path, list[Path]], Path]:
    """A case that edits the newest checkpoint's parts with ``fn`` and loads the result."""

    def craft(work: Path, base: list[Path]) -> Path:
        parts = read_parts(base[-1])
        fn(parts)
        return write_parts(work / base[-1].name, parts)

    return craft


def state_edit(*keys: Any, value: Any = None, delete: bool = False) -> Callable[[Path, list[Path]], Path]:
    def fn(parts: dict[str, Any]) -> None:
        target = parts["state"]
        for key in keys[:-1]:
            target = target[key]
        if delete:
            del target[keys[-1]]
        else:
            target[keys[-1]] = value

    return edit(fn)


def array_edit(name: str, change: Callable[[np.ndarray], Any]) -> Callable[[Path, list[Path]], Path]:
    def fn(parts: dict[str, Any]) -> None:
        result = change(parts["arrays"][name].copy())
        if result is None:
            del parts["arrays"][name]
        else:
            parts["arrays"][name] = result

    return edit(fn)


def setitem(array: np.ndarray, index: Any, value: Any) -> np.ndarray:
    array[index] = value
    return array


def tensor_edit(name: str, value: Any) -> Callable[[Path, list[Path]], Path]:
    def fn(parts: dict[str, Any]) -> None:
        if value is None:
            del parts["tensors"][name]
        else:
            parts["tensors"][name] = value

    return edit(fn)


def model_edit(change: Callable[[dict[str, Any]], Any]) -> Callable[[Path, list[Path]], Path]:
    def fn(parts: dict[str, Any]) -> None:
        data = model_data(parts)
        result = change(data)
        set_model_data(parts, result if isinstance(result, bytes) else data)

    return edit(fn)


def both_counters(value: int) -> Callable[[Path, list[Path]], Path]:
    """num_timesteps changed consistently in state.json and model.zip."""

    def fn(parts: dict[str, Any]) -> None:
        parts["state"]["num_timesteps"] = value
        data = model_data(parts)
        data["num_timesteps"] = value
        set_model_data(parts, data)

    return edit(fn)


class Payload:
    """Unpickling this writes a marker file: what a hostile pickle would do."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self) -> Any:
        return exec, (f"open({self.marker!r}, 'w').write('pwned')",)


def pickled_array(work: Path, base: list[Path]) -> Path:
    parts = read_parts(base[-1])
    npz = io.BytesIO()
    with zipfile.ZipFile(npz, "w") as archive:
        for name, array in parts["arrays"].items():
            if name == "last_episode_starts":
                continue
            buffer = io.BytesIO()
            np.save(buffer, array)
            archive.writestr(f"{name}.npy", buffer.getvalue())
        buffer = io.BytesIO()
        np.save(buffer, np.array([Payload(str(work.parent / "escape_marker"))], dtype=object), allow_pickle=True)
        archive.writestr("last_episode_starts.npy", buffer.getvalue())
    raw = dict(parts["raw"])
    raw["arrays.npz"] = npz.getvalue()
    return write_parts(work / base[-1].name, parts, entries=list(raw.items()))


def pickled_tensors(work: Path, base: list[Path]) -> Path:
    parts = read_parts(base[-1])
    raw = dict(parts["raw"])
    pth = io.BytesIO()
    th.save({"torch_rng": Payload(str(work.parent / "escape_marker"))}, pth)
    raw["tensors.pth"] = pth.getvalue()
    return write_parts(work / base[-1].name, parts, entries=list(raw.items()))


def raw_entries(change: Callable[[dict[str, bytes]], list[tuple[str, bytes]]], compression: int = zipfile.ZIP_STORED):
    def craft(work: Path, base: list[Path]) -> Path:
        parts = read_parts(base[-1])
        return write_parts(work / base[-1].name, parts, entries=change(dict(parts["raw"])), compression=compression)

    return craft


def raw_state(text: bytes) -> Callable[[Path, list[Path]], Path]:
    return raw_entries(lambda raw: [(n, text if n == "state.json" else c) for n, c in raw.items()])


def bytes_damage(offset_fraction: float, flip: bool = True) -> Callable[[Path, list[Path]], Any]:
    """Flip one byte of (or truncate) the newest checkpoint; the resume must pick the older one or read it unchanged."""

    def craft(work: Path, base: list[Path]) -> Any:
        for path in base:
            shutil.copy(path, work / path.name)
        newest = work / base[-1].name
        data = bytearray(newest.read_bytes())
        position = int(offset_fraction * (len(data) - 1))
        if flip:
            data[position] ^= 0xFF
        else:
            del data[position:]
        newest.write_bytes(bytes(data))
        return ("resume", work)

    return craft


def cases() -> list[Case]:
    """The table: crafted state, arrays, tensors, zip structure, model file; damage; faults."""
    found: list[Case] = []

    def add(name: str, group: str, refuse: bool, craft: Callable[[Path, list[Path]], Any], escape: str | None = None):
        found.append(Case(name, group, refuse, craft, escape))

    # state.json: counters
    for value in (-1, -120, 10**30, 1.5, "360", None, True, [360]):
        add(f"num_timesteps={value!r}", "state", True, state_edit("num_timesteps", value=value))
    for value in (-1, 99, "3", None):
        add(f"n_updates={value!r}", "state", True, state_edit("n_updates", value=value))
    for value in (-5, 1.0, None):
        add(f"total_timesteps={value!r}", "state", True, state_edit("total_timesteps", value=value))
    add("num_timesteps in state and model both 600 (consistent)", "state", False, both_counters(600))
    add("num_timesteps in state and model both -1", "state", True, both_counters(-1))
    add("5000-digit num_timesteps", "state", True, raw_state(b'{"num_timesteps": ' + b"9" * 5000 + b"}"))
    for key in ("checkpoint_format", "num_timesteps", "n_updates", "total_timesteps", "rng", "env", "swarm_summaries",
                "tensorboard_log", "pending_log", "settings", "extra"):
        add(f"state.json without {key}", "state", True, state_edit(key, delete=True))
    add("state.json with an unknown key", "state", True, state_edit("__class__", value="os.system"))
    add("checkpoint_format 2", "state", True, state_edit("checkpoint_format", value=2))
    add("state.json not JSON", "state", True, raw_state(b"{not json"))
    add("state.json a list", "state", True, raw_state(b"[1, 2]"))
    add("state.json deeply nested", "state", True, raw_state(b"[" * 100_000 + b"]" * 100_000))
    add("state.json not UTF-8", "state", True, raw_state(b"\xff\xfe{}"))
    add("state.json with NaN counters", "state", True, raw_state(b'{"num_timesteps": NaN}'))
    # state.json: random streams
    for name in ("exec", "Generator", "RandomState", "__import__", "default_rng", "bit_generator"):
        add(f"bit_generator {name!r}", "rng", True, state_edit("env", "swarm_rngs", 0, "bit_generator", value=name))
    add("bit_generator MT19937 with a PCG64 state", "rng", True,
        state_edit("env", "swarm_rngs", 0, "bit_generator", value="MT19937"))
    add("PCG64 state a string", "rng", True, state_edit("env", "swarm_rngs", 0, "state", value="x"))
    add("PCG64 state 2**200", "rng", True, state_edit("env", "swarm_rngs", 0, "state", "state", value=2**200))
    add("PCG64 state another valid value", "rng", False, state_edit("env", "swarm_rngs", 0, "state", "state", value=12345))
    add("python_random version 2", "rng", True, state_edit("rng", "python_random", "version", value=2))
    add("python_random internal short", "rng", True, state_edit("rng", "python_random", "internal", value=[1, 2]))
    add("python_random position 625", "rng", True, state_edit("rng", "python_random", "internal", 624, value=625))
    add("python_random gauss_next NaN", "rng", True, raw_entries(lambda raw: [
        (n, c.replace(b'"gauss_next": null', b'"gauss_next": NaN') if n == "state.json" else c) for n, c in raw.items()]))
    add("numpy_random name PCG64", "rng", True, state_edit("rng", "numpy_random", "name", value="PCG64"))
    add("numpy_random pos 10**6", "rng", True, state_edit("rng", "numpy_random", "pos", value=10**6))
    add("numpy_random pos 5 (in range)", "rng", False, state_edit("rng", "numpy_random", "pos", value=5))
    add("numpy keys of 10 words", "rng", True, array_edit("numpy_random_keys", lambda a: a[:10]))
    # state.json: env
    add("swarm_rngs one swarm short", "env", True, state_edit("env", "swarm_rngs", value=[]))
    add("swarm_seeds a string", "env", True, state_edit("env", "swarm_seeds", value="0,1"))
    add("swarm_seeds negative", "env", True, state_edit("env", "swarm_seeds", value=[-1, 1]))
    add("swarm_seeds other values (in range)", "env", False, state_edit("env", "swarm_seeds", value=[7, 8]))
    add("pending_seed -3", "env", True, state_edit("env", "pending_seed", value=-3))
    add("seeded 'yes'", "env", True, state_edit("env", "seeded", value="yes"))
    add("monitor_episode_count -1", "env", True, state_edit("env", "monitor_episode_count", value=-1))
    add("env backend another class", "env", False, state_edit("env", "backend", value="DummyVecEnv"))
    add("env unknown key", "env", True, state_edit("env", "python", value="import os"))
    # state.json: summaries, log, paths, settings
    for value in (-1.17, 1.5, "0.5", None):
        add(f"summary coverage {value!r}", "summaries", True, state_edit("swarm_summaries", 0, "coverage", value=value))
    add("summary coverage 0.5 (in range)", "summaries", False, state_edit("swarm_summaries", 0, "coverage", value=0.5))
    add("summary collisions -4", "summaries", True, state_edit("swarm_summaries", 0, "collisions", value=-4))
    add("summary unknown key", "summaries", True, state_edit("swarm_summaries", 0, "__reduce__", value=1))
    add("200,000 summaries", "summaries", True, state_edit("swarm_summaries", value=[{"coverage": 0.5}] * 200_000))
    add("pending_log key outside train/", "log", True, state_edit("pending_log", "values", "time/total_timesteps", value=1.0))
    add("pending_log value a string", "log", True, state_edit("pending_log", "values", "train/loss", value="x"))
    add("pending_log excluded format 'shell'", "log", True,
        state_edit("pending_log", "excluded", "train/loss", value=["shell"]))
    for where in ("../../escape_tb", "ABS"):
        add(f"tensorboard_log {where}", "paths", False,
            lambda work, base, where=where: state_edit(
                "tensorboard_log", value=str(work.parent / "escape_tb") if where == "ABS" else where)(work, base),
            escape="escape_tb")
    add("settings.tensorboard outside the run folder, no --tensorboard", "paths", False,
        lambda work, base: ("tensorboard", work, None, str(work.parent / "escape_tb"), str(work.parent / "escape_tb" / "x_1")))
    add("settings.tensorboard_run ../../escape_tb with --tensorboard", "paths", False,
        lambda work, base: ("tensorboard", work, str(work / "tb"), str(work / "tb"),
                            str(work / "tb" / ".." / ".." / "escape_tb")))
    add("settings.tensorboard_run of another name with --tensorboard", "paths", False,
        lambda work, base: ("tensorboard", work, str(work / "tb"), str(work / "tb"), str(work / "tb" / "evil_1")))
    add("settings.tensorboard inside the run folder (continues there)", "paths", False,
        lambda work, base: ("tensorboard", work, None, str(work / "tb"), str(work / "tb" / "latentswarm_hostile_1")))
    add("settings p_fail edited (compared with the run's)", "settings", True,
        lambda work, base: ("settings", {"preset": "hostile", "p_fail": 0.9}, {"preset": "hostile", "p_fail": 0.1}))
    add("settings unchanged (compared with the run's)", "settings", False,
        lambda work, base: ("settings", {"preset": "hostile", "p_fail": 0.1}, {"preset": "hostile", "p_fail": 0.1}))
    add("settings a list", "settings", True, state_edit("settings", value=[1]))
    add("extra a string", "settings", True, state_edit("extra", value="x"))
    # arrays.npz: the batched core and the observations
    core = "env.core."
    array_cases: list[tuple[str, str, Callable[[np.ndarray], Any], bool]] = [
        ("footprint 10**6", "footprint", lambda a: setitem(a, (0, 0, 0), 10**6), True),
        ("footprint -1", "footprint", lambda a: setitem(a, (0, 0, 0), -1), True),
        ("n_covered -117", "n_covered", lambda a: setitem(a, 0, -117), True),
        ("n_covered + 1 (inconsistent with the map)", "n_covered", lambda a: a + 1, True),
        ("n_covered 10**6", "n_covered", lambda a: setitem(a, 0, 10**6), True),
        ("t -1", "t", lambda a: setitem(a, 0, -1), True),
        ("t 10**6", "t", lambda a: setitem(a, 0, 10**6), True),
        ("collisions -1", "collisions", lambda a: setitem(a, 0, -1), True),
        ("steps_to_90 -5", "steps_to_90", lambda a: setitem(a, 0, -5), True),
        ("_truth 7", "_truth", lambda a: setitem(a, (0, 20), 7), True),
        ("_map -9", "_map", lambda a: setitem(a, (0, 20), -9), True),
        ("kinematics NaN", "kinematics", lambda a: setitem(a, (0, 0, 0), np.nan), True),
        ("kinematics +1e-3 (in range)", "kinematics", lambda a: a + 1e-3, False),
        ("episode_return inf", "episode_return", lambda a: setitem(a, 0, np.inf), True),
        ("_reward_terms NaN", "_reward_terms", lambda a: setitem(a, (0, 0), np.nan), True),
        ("_in_link_sum -1", "_in_link_sum", lambda a: setitem(a, (0, 0), -1), True),
        ("_in_link_sum 10**6", "_in_link_sum", lambda a: setitem(a, (0, 0), 10**6), True),
        ("_n_dropouts -1", "_n_dropouts", lambda a: setitem(a, (0, 0), -1), True),
        ("_n_link_draws -1", "_n_link_draws", lambda a: setitem(a, 0, -1), True),
        ("global_map 100", "global_map", lambda a: setitem(a, (0, 0, 0), 100), True),
        ("link_rows 2.0", "link_rows", lambda a: setitem(a, (0, 0, 0), 2.0), True),
        ("_truth shape (1, 196)", "_truth", lambda a: a[:1], True),
        ("_truth as float64", "_truth", lambda a: a.astype(np.float64), True),
        ("_covered missing", "_covered", lambda a: None, True),
        ("dropout flipped (in range)", "dropout", lambda a: ~a, False),
    ]
    for label, name, change, refuse in array_cases:
        add(f"core {label}", "arrays", refuse, array_edit(core + name, change))
    obs_cases: list[tuple[str, str, Callable[[np.ndarray], Any], bool]] = [
        ("last_obs.proprio NaN", "last_obs.proprio", lambda a: setitem(a, (0, 0), np.nan), True),
        ("last_obs.proprio 1e9 (its space is unbounded)", "last_obs.proprio", lambda a: setitem(a, (0, 0), 1e9), False),
        ("last_obs.link_row 3.0 (outside the space)", "last_obs.link_row", lambda a: setitem(a, (0, 0), 3.0), True),
        ("last_obs.local_obs 9", "last_obs.local_obs", lambda a: setitem(a, (0, 0), 9), True),
        ("last_obs.global_map wrong shape", "last_obs.global_map", lambda a: a[:, :5], True),
        ("last_obs.link_row missing", "last_obs.link_row", lambda a: None, True),
        ("last_obs.proprio as float64", "last_obs.proprio", lambda a: a.astype(np.float64), True),
        ("last_episode_starts 7", "last_episode_starts", lambda a: a.astype(np.int64) + 7, True),
        ("last_episode_starts short", "last_episode_starts", lambda a: a[:2], True),
        ("monitor lengths -3", "env.monitor_episode_lengths", lambda a: setitem(a, 0, -3), True),
        ("monitor lengths differ from the swarms' steps", "env.monitor_episode_lengths", lambda a: a + 1, True),
        ("monitor returns NaN", "env.monitor_episode_returns", lambda a: setitem(a, 0, np.nan), True),
        ("monitor returns +1 (in range)", "env.monitor_episode_returns", lambda a: a + 1, False),
        ("monitor returns short", "env.monitor_episode_returns", lambda a: a[:3], True),
        ("numpy keys as strings", "numpy_random_keys", lambda a: a.astype(str), True),
        ("numpy keys complex", "numpy_random_keys", lambda a: a.astype(np.complex64), True),
    ]
    for label, name, change, refuse in obs_cases:
        add(label, "arrays", refuse, array_edit(name, change))
    add("a link model state the env's links do not have", "arrays", True,
        edit(lambda parts: parts["arrays"].update({"env.core.link_model.xi_state": np.zeros((2, 3, 3), np.int8)})))
    add("an old checkpoint's _xi_state beside links without memory (ignored)", "arrays", False,
        edit(lambda parts: parts["arrays"].update({"env.core._xi_state": np.full((2, 3, 3), -1, np.int8)})))
    add("arrays.npz with an unknown array", "arrays", True,
        edit(lambda parts: parts["arrays"].update({"os.system": np.zeros(3)})))
    add("arrays.npz with a pickled object array", "arrays", True, pickled_array)
    add("arrays.npz not a zip", "arrays", True,
        raw_entries(lambda raw: [(n, b"junk" if n == "arrays.npz" else c) for n, c in raw.items()]))
    # tensors.pth
    add("tensors.pth with a pickled payload", "tensors", True, pickled_tensors)
    add("tensors.pth not a torch file", "tensors", True,
        raw_entries(lambda raw: [(n, b"junk" if n == "tensors.pth" else c) for n, c in raw.items()]))
    add("torch_rng of 10 bytes", "tensors", True, tensor_edit("torch_rng", th.zeros(10, dtype=th.uint8)))
    add("torch_rng missing", "tensors", True, tensor_edit("torch_rng", None))
    add("latent.map_state NaN", "tensors", True, tensor_edit("latent.map_state", th.full((6, 8), float("nan"))))
    add("latent.map_state wrong shape", "tensors", True, tensor_edit("latent.map_state", th.zeros(6, 9)))
    add("latent.map_state float64", "tensors", True, tensor_edit("latent.map_state", th.zeros(6, 8, dtype=th.float64)))
    add("latent.map_state zeros (in range)", "tensors", False, tensor_edit("latent.map_state", th.zeros(6, 8)))
    add("latent.task_state missing", "tensors", True, tensor_edit("latent.task_state", None))
    add("tensors.pth unknown entry", "tensors", True, tensor_edit("__builtins__", th.zeros(1)))
    # zip structure
    add("duplicate state.json (second names a TensorBoard folder)", "zip", True, raw_entries(lambda raw: [
        *raw.items(), ("state.json", raw["state.json"].replace(b'"tensorboard_log": null', b'"tensorboard_log": "../esc"'))]))
    add("an extra entry", "zip", True, raw_entries(lambda raw: [*raw.items(), ("run.sh", b"rm -rf /")]))
    for name in ("model.zip", "state.json", "arrays.npz", "tensors.pth"):
        add(f"without {name}", "zip", True, raw_entries(lambda raw, name=name: [(n, c) for n, c in raw.items() if n != name]))
    add("entries deflated (a zip bomb's shape)", "zip", True, raw_entries(lambda raw: list(raw.items()), zipfile.ZIP_DEFLATED))
    add("state.json of 17 MiB", "zip", True,
        raw_entries(lambda raw: [(n, c[:-1] + b" " * (17 * 2**20) + b"}" if n == "state.json" else c)
                                 for n, c in raw.items()]))
    add("empty file", "zip", True, lambda work, base: write_file(work / base[-1].name, b""))
    add("a model file in place of a checkpoint", "zip", True,
        lambda work, base: write_file(work / base[-1].name, read_parts(base[-1])["raw"]["model.zip"]))
    add("a directory named like a checkpoint", "zip", True,
        lambda work, base: (work / base[-1].name).mkdir() or work / base[-1].name)
    add("a FIFO named like a checkpoint", "zip", True,
        lambda work, base: os.mkfifo(work / base[-1].name) or work / base[-1].name)
    add("no such file", "zip", True, lambda work, base: work / "checkpoint_999_steps.zip")
    # the model file inside
    add("model widths 4096", "model", True, model_edit(lambda d: d["policy_kwargs"].update(
        {k: 4096 for k in ("latent_dim", "predictor_hidden", "decoder_hidden", "critic_hidden", "actor_hidden")})))
    add("model n_steps 2,000,000 (rollout buffer)", "model", True, model_edit(lambda d: d.update(n_steps=2_000_000)))
    add("model 5000-digit integer", "model", True,
        model_edit(lambda d: json.dumps(d).replace('"n_epochs": 1', '"n_epochs": ' + "9" * 5000).encode()))
    add("model num_timesteps differs from state.json", "model", True, model_edit(lambda d: d.update(num_timesteps=240)))
    add("model _n_updates differs from state.json", "model", True, model_edit(lambda d: d.update(_n_updates=1)))
    add("model pickled entry", "model", True,
        model_edit(lambda d: d.update(swarm_config={":type:": "x", ":serialized:": "gAR9lC4="})))
    add("model grid differs from its observation space", "model", True,
        model_edit(lambda d: d["swarm_config"]["__swarm_config__"].update(grid_width=12)))
    add("model p_fail edited (env of another config)", "model", True,
        model_edit(lambda d: d["swarm_config"]["__swarm_config__"].update(p_fail=0.9)))
    add("model learning_rate NaN", "model", True, model_edit(lambda d: d.update(learning_rate=float("nan"))))
    add("model tensorboard_log ../../escape_tb", "model", True,
        model_edit(lambda d: d.update(tensorboard_log="../../escape_tb")), escape="escape_tb")
    add("model weights damaged", "model", True, edit(lambda parts: parts["model"].update({"policy.pth": b"junk"})))
    add("model gamma 0.98 (in range)", "model", False, model_edit(lambda d: d.update(gamma=0.98)))
    # damage to the newest checkpoint: the resume must use the older ones
    rng = random.Random(34)
    for _ in range(40):
        fraction = rng.random()
        add(f"newest: byte at {fraction:.3f} flipped", "damage", False, bytes_damage(fraction))
    for fraction in (0.0, 0.1, 0.5, 0.9, 0.999):
        add(f"newest: truncated at {fraction:.3f}", "damage", False, bytes_damage(fraction, flip=False))
    # faults
    add("all checkpoints damaged", "fault", True, fault_all_damaged)
    add("a second writer into a held folder", "fault", True, fault_second_writer)
    add("a writer after a holder killed with kill -9", "fault", False, fault_dead_holder)
    add("temporaries of a killed write removed at the next start", "fault", False, fault_stale_temporaries)
    add("a write that fails leaves the earlier checkpoints", "fault", False, fault_failed_write)
    add("SIGHUP during training writes a checkpoint and stops", "fault", False, fault_sighup)
    add("a symlinked checkpoint is not a checkpoint", "fault", False, fault_symlink)
    add("a checkpoint passed to LatentSwarmPPO.load", "fault", True, fault_checkpoint_as_model)
    add("an env of another config", "fault", True, fault_other_env)
    add("two concurrent train runs into one folder", "fault", True, fault_concurrent_runs)
    # the same through the command line's run path (train --resume)
    add("train --resume with a bit-flipped newest checkpoint", "cli", False, cli_flipped_newest)
    add("train --resume, checkpoints name a TensorBoard folder outside --output", "cli", False, cli_tensorboard_outside)
    add("train --resume, checkpoints' settings edited to p_fail=0.9", "cli", True, cli_settings_edited)
    add("train --resume, every checkpoint damaged", "cli", True, cli_all_damaged)
    return found


# ---------------------------------------------------------------------------------------------- faults
def fault_all_damaged(work: Path, base: list[Path]) -> tuple[str, str]:
    for path in base:
        (work / path.name).write_bytes(path.read_bytes()[:100])
    try:
        newest_valid_checkpoint(list_checkpoints(work), report=None)
    except CheckpointError as error:
        return classify_error(error, work / base[-1].name)
    return "silent wrong", "a damaged checkpoint was chosen"


HOLD = ("import sys; from sb3_latentswarm.utils.locks import output_lock\n"
        "with output_lock(sys.argv[1]):\n    print('held', flush=True); sys.stdin.read()")


def _holder(folder: Path) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], env={**os.environ, "PYTHONPATH": str(ROOT)},
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    return holder


def fault_second_writer(work: Path, base: list[Path]) -> tuple[str, str]:
    holder = _holder(work)
    try:
        with output_lock(work):
            return "silent wrong", "a second writer got the folder"
    except OutputInUseError as error:
        ok = str(work) in str(error) and f"pid {holder.pid}" in str(error)
        return ("clear error" if ok else "unclear"), str(error)
    finally:
        holder.kill()
        holder.wait()


def fault_dead_holder(work: Path, base: list[Path]) -> tuple[str, str]:
    holder = _holder(work)
    holder.kill()
    holder.wait()
    try:
        with output_lock(work):
            pass
    except OutputInUseError as error:
        return "unclear", f"a dead holder blocks: {error}"
    return ("works" if not (work / ".lock").exists() else "unclear"), "taken after kill -9; lock file removed at the end"


def fault_stale_temporaries(work: Path, base: list[Path]) -> tuple[str, str]:
    names = (".checkpoint_360_steps.a1b2c3d4.tmp.zip", ".model.zz99yy88.tmp.zip", ".write-probe.k3j4l5m6")
    leftovers = [work / name for name in names]
    for path in leftovers:
        path.write_bytes(b"partial")
    (work / "keep.txt").write_text("mine")
    with output_lock(work):
        pass
    left = [p.name for p in leftovers if p.exists()]
    if not (work / "keep.txt").exists():
        return "data loss", "a file of the user was removed"
    return ("works", "removed") if not left else ("unclear", f"left {left}")


def fault_failed_write(work: Path, base: list[Path]) -> tuple[str, str]:
    for path in base:
        shutil.copy(path, work / path.name)
    before = {p.name: digest(p) for p in work.iterdir()}
    from sb3_latentswarm.utils import atomic

    def failing(tmp_path: Path, data: bytes) -> None:
        raise OSError(28, "No space left on device")

    try:
        with atomic.atomic_path(work / "checkpoint_480_steps.zip") as tmp:
            tmp.write_bytes(b"half a checkpoint")
            failing(tmp, b"")
    except OSError:
        pass
    after = {p.name: digest(p) for p in work.iterdir()}
    return ("works", "earlier checkpoints intact, no partial file") if after == before else ("data loss", f"{after}")


def fault_sighup(work: Path, base: list[Path]) -> tuple[str, str]:
    model = make_model(make_env())

    class HangUp(SwarmCheckpointCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == PER_UPDATE + 60:
                os.kill(os.getpid(), signal.SIGHUP)
            return super()._on_step()

    with StopOnSignal() as stop:
        callback = HangUp(PER_UPDATE * 10, work, stop=stop)
        model.learn(5 * PER_UPDATE, callback=callback)
    written = list_checkpoints(work)
    ok = stop.signum == signal.SIGHUP and callback.stopped and written and written[-1].name == "checkpoint_120_steps.zip"
    return ("works", f"stopped by SIGHUP, checkpoint {written[-1].name}") if ok else ("data loss", f"{written}")


def fault_symlink(work: Path, base: list[Path]) -> tuple[str, str]:
    shutil.copy(base[0], work / base[0].name)
    (work / "checkpoint_999_steps.zip").symlink_to(base[-1])
    chosen, _ = newest_valid_checkpoint(list_checkpoints(work), report=None)
    return ("works", "the link is ignored") if chosen.name == base[0].name else ("silent wrong", f"chose {chosen}")


def fault_checkpoint_as_model(work: Path, base: list[Path]) -> tuple[str, str]:
    try:
        LatentSwarmPPO.load(base[-1])
    except ValueError as error:
        ok = str(base[-1]) in str(error) and "load_checkpoint" in str(error)
        return ("clear error" if ok else "unclear"), str(error)
    return "silent wrong", "loaded as a model"


def fault_other_env(work: Path, base: list[Path]) -> tuple[str, str]:
    try:
        load_checkpoint(base[-1], env=make_env(SMALL.replace(p_fail=0.9)), device="cpu")
    except CheckpointError as error:
        ok = "p_fail" in str(error)
        return classify_error(error, base[-1]) if ok else ("unclear", str(error))
    return "silent wrong", "continued on another env"


TRAIN = ("import sys; from pathlib import Path\n"
         "sys.path.insert(0, {bench!r}); import hostile_checkpoints as h\n"
         "from sb3_latentswarm.utils.locks import output_lock\n"
         "folder = Path(sys.argv[1])\n"
         "with output_lock(folder):\n"
         "    print('training', flush=True)\n"
         "    if sys.argv[2:] == ['wait']: sys.stdin.readline()\n"
         "    h.train_base(folder)\n")


def fault_concurrent_runs(work: Path, base: list[Path]) -> tuple[str, str]:
    """Two processes train into one folder: one refused with one clear line, the other's checkpoints intact."""
    code = TRAIN.format(bench=str(Path(__file__).parent))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    first = subprocess.Popen([sys.executable, "-c", code, str(work), "wait"], env=env, stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    assert first.stdout is not None and first.stdin is not None and first.stdout.readline().strip() == "training"
    second = subprocess.run([sys.executable, "-c", code, str(work)], env=env, capture_output=True, text=True)
    first.stdin.write("go\n")  # the first trains only after the second tried: the two overlap for certain
    first.stdin.flush()
    first.wait()
    refused = second.returncode != 0 and f"{work} is in use by another run (pid {first.pid}" in second.stderr
    names = [p.name for p in list_checkpoints(work)]
    intact = first.returncode == 0 and names == [p.name for p in base] and all(
        read_parts(work / name)["state"]["num_timesteps"] == int(name.split("_")[1]) for name in names)
    if not intact:
        return "data loss", f"first rc {first.returncode}, checkpoints {names}"
    last = (second.stderr.strip().splitlines() or ["(nothing on stderr)"])[-1]
    return ("clear error" if refused else "unclear"), f"second: rc {second.returncode}, {last}"


def _cli(argv: list[str]) -> tuple[int, str, str]:
    from sb3_latentswarm.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exit_:
            code = int(exit_.code or 0)
    return code, out.getvalue(), err.getvalue()


def _cli_run(work: Path) -> Path:
    """A ``train`` run of the smoke preset with a checkpoint after each of its 3 updates."""
    run = work / "run"
    code, _, err = _cli(["train", "--preset", "smoke", "--output", str(run), "--total-timesteps", "360", "--save-freq",
                         "120", "--keep-checkpoints", "5", "--no-progress", "--tensorboard", str(run / "tb")])
    assert code == 0, err
    return run


def _resume(run: Path) -> tuple[int, str, str]:
    return _cli(["train", "--resume", "--output", str(run), "--total-timesteps", "480", "--no-progress"])


def cli_flipped_newest(work: Path, base: list[Path]) -> tuple[str, str]:
    run = _cli_run(work)
    newest = list_checkpoints(run / "checkpoints")[-1]
    data = bytearray(newest.read_bytes())
    data[len(data) // 2] ^= 0xFF
    newest.write_bytes(bytes(data))
    code, out, err = _resume(run)
    if code != 0:
        return "unclear", f"rc {code}: {err.strip()[-200:]}"
    said = [line for line in out.splitlines() if line.startswith("Skipping damaged")]
    ok = said and "resuming from the older" in said[0] and (run / "model.zip").is_file()
    return ("works", said[0][:200]) if ok else ("silent wrong", "resumed without saying so")


def _edit_all(run: Path, change: Callable[[dict[str, Any]], None]) -> None:
    for path in list_checkpoints(run / "checkpoints"):
        parts = read_parts(path)
        change(parts["state"])
        write_parts(path, parts)


def cli_tensorboard_outside(work: Path, base: list[Path]) -> tuple[str, str]:
    run = _cli_run(work)
    outside = work.parent / "escape_tb"
    _edit_all(run, lambda state: state["settings"].update(tensorboard=str(outside), tensorboard_run=str(outside / "x_1")))
    code, out, err = _resume(run)
    if code != 0:
        return "unclear", f"rc {code}: {err.strip()[-200:]}"
    note = [line for line in out.splitlines() if line.startswith("TensorBoard:")]
    return ("works", note[0][:160]) if note else ("unclear", "resumed without saying where TensorBoard logs")


def cli_settings_edited(work: Path, base: list[Path]) -> tuple[str, str]:
    run = _cli_run(work)

    def edit_set(state: dict[str, Any]) -> None:
        state["settings"]["set"] = [*(state["settings"].get("set") or []), "p_fail=0.9"]

    _edit_all(run, edit_set)
    code, out, err = _resume(run)
    if code == 0:
        return "silent wrong", "continued on the edited env"
    clear = code == 2 and "p_fail" in err and str(run) in err and len(err.strip().splitlines()) == 1
    return ("clear error" if clear else "unclear"), err.strip()[:300]


def cli_all_damaged(work: Path, base: list[Path]) -> tuple[str, str]:
    run = _cli_run(work)
    for path in list_checkpoints(run / "checkpoints"):
        path.write_bytes(path.read_bytes()[:300])
    code, out, err = _resume(run)
    clear = code == 2 and "no valid checkpoint" in err and len(err.strip().splitlines()) == 1
    return ("clear error" if clear else "unclear"), err.strip()[:300]


# ---------------------------------------------------------------------------------------------- trying a case
def tree(folder: Path, skip: Path) -> set[str]:
    """Every path under ``folder`` except those under ``skip`` (relative names)."""
    found = set()
    for current, folders, files in os.walk(folder):
        if Path(current) == skip:
            folders[:] = []
            continue
        found.update(str(Path(current, name).relative_to(folder)) for name in folders + files)
    found.discard(str(skip.relative_to(folder)))
    return found


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "dir"


def classify_error(error: BaseException, path: Path | str) -> tuple[str, str]:
    text = str(error)
    one_line = "\n" not in text.strip()
    clear = isinstance(error, ValueError) and str(path) in text and one_line and not any(a in text for a in ADVICE)
    return ("clear error" if clear else "unclear"), f"{type(error).__name__}: {text[:300]}"


def continue_run(path: Path, work: Path) -> tuple[str, str]:
    """Load the checkpoint and train one more update in ``work`` (cwd); an error after loading is unclear."""
    try:
        model = load_checkpoint(path, env=make_env(), device="cpu")
    except (CheckpointError, ValueError, TypeError) as error:
        return classify_error(error, path)
    except Exception as error:  # noqa: BLE001 - anything else is what the benchmark counts as unclear
        return "unclear", f"{type(error).__name__}: {str(error)[:300]}"
    try:
        model.learn(PER_UPDATE, reset_num_timesteps=False)
        summaries = list(model._swarm_summaries)
        if any(not 0 <= s.get("coverage", 0) <= 1 for s in summaries) or model.num_timesteps < 0:
            return "silent wrong", "a summary or counter out of range after training"
    except Exception as error:  # noqa: BLE001
        return "unclear", f"loaded, then {type(error).__name__}: {str(error)[:300]}"
    return "loaded", f"continued to {model.num_timesteps} agent-steps"


def resume_from(work: Path, base: list[Path]) -> tuple[str, str]:
    """Choose the newest valid checkpoint in ``work`` and continue it; compare with the undamaged one."""
    lines: list[str] = []
    try:
        chosen, _ = newest_valid_checkpoint(list_checkpoints(work), report=lines.append)
    except CheckpointError as error:
        return "unclear", f"no checkpoint chosen although older ones are valid: {error}"
    outcome, detail = continue_run(chosen, work)
    if outcome != "loaded":
        return outcome, detail
    if chosen.name == base[-1].name and digest(chosen) != digest(base[-1]):
        # the damaged file read as valid: the damage must have been in bytes that carry no data (zip metadata)
        same = read_parts(chosen)["raw"] == read_parts(base[-1])["raw"]
        return ("works", "damage in zip metadata only; data identical") if same else ("silent wrong", "damaged data read")
    note = f"; said: {lines[0][:160]}" if lines else ""
    return "works", f"resumed from {chosen.name}{note}"


def run_case(case: Case, base: list[Path], root: Path, index: int) -> tuple[str, str]:
    """Try ``case`` in a fresh folder under ``root``; return (outcome, detail)."""
    work = root / "cases" / f"{index:04d}"
    work.mkdir(parents=True)
    before = {p.name: digest(p) for p in base}
    outside = tree(root.parent, skip=work)
    cwd = os.getcwd()
    os.chdir(work)  # relative paths of a crafted file resolve here, inside the case's folder tree
    try:
        crafted = case.craft(work, base)
        if isinstance(crafted, tuple) and crafted[0] == "resume":
            outcome, detail = resume_from(work, base)
        elif isinstance(crafted, tuple) and crafted[0] == "tensorboard":
            _, output, given, saved_folder, saved_run = crafted
            stored = {"tensorboard": saved_folder, "tensorboard_run": saved_run}
            folder, run, note = resume_tensorboard(output, given, stored, "latentswarm_hostile")
            if run is not None:
                Path(run).mkdir(parents=True, exist_ok=True)  # what the run's logger would create
            outcome, detail = "works", f"TensorBoard run {run}" + (f" ({note[:80]})" if note else "")
        elif isinstance(crafted, tuple) and crafted[0] == "settings":
            _, stored, current = crafted
            try:
                compare_settings(stored, current, work / base[-1].name)
                outcome, detail = "loaded", "same settings"
            except CheckpointError as error:
                outcome, detail = classify_error(error, work / base[-1].name)
        elif isinstance(crafted, tuple):
            outcome, detail = crafted
        else:
            outcome, detail = continue_run(crafted, work)
    except Exception as error:  # noqa: BLE001 - a case that breaks the harness is reported, not hidden
        outcome, detail = "unclear", f"harness: {type(error).__name__}: {error}"
    finally:
        os.chdir(cwd)
    if outcome == "loaded":
        outcome = "silent wrong" if case.refuse else "works"
    elif outcome == "clear error" and not case.refuse:
        outcome = "unclear"  # a valid input refused
    if {p.name: digest(p) for p in base} != before:
        outcome, detail = "data loss", "the base run's checkpoints changed"
    escaped = sorted(tree(root.parent, skip=work) - outside)
    if escaped:
        outcome, detail = "escape", f"written outside the case's folder: {escaped[:3]}"
        for name in escaped:
            path = root.parent / name
            shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)
    return outcome, detail


def main(argv: list[str] | None = None) -> dict[str, int]:
    args = build_parser().parse_args(argv)
    started = time.time()
    with tempfile.TemporaryDirectory(prefix="hostile-") as tmp:
        root = Path(tmp) / "sandbox"
        base = train_base(root / "base")
        table = [case for case in cases() if args.only is None or args.only in case.name]
        counts: collections.Counter[str] = collections.Counter()
        lines = []
        for index, case in enumerate(table):
            outcome, detail = run_case(case, base, root, index)
            counts[outcome] += 1
            lines.append(f"{outcome:12s} | {case.group:9s} | {case.name} | {detail}")
            print(lines[-1], flush=True)
    summary = [
        f"{len(table)} cases in {time.time() - started:.0f} s: "
        + ", ".join(f"{name} {counts.get(name, 0)}" for name in OUTCOMES),
    ]
    print("\n".join(summary))
    if args.out:
        header = [f"# hostile_checkpoints.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", ""]
        Path(args.out).write_text("\n".join([*header, *lines, "", *summary, ""]))
    return {name: counts.get(name, 0) for name in OUTCOMES}


if __name__ == "__main__":
    main()
