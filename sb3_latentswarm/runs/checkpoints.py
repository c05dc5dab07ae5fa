"""Training checkpoints that continue a run exactly: SB3's ``CheckpointCallback`` habit, with the whole run state.

A checkpoint is one zip file, ``checkpoint_<num_timesteps>_steps.zip`` (SB3's ``rl_model_<n>_steps.zip`` naming),
of plain data only (no pickle, see ``docs/security.md``):

* ``model.zip``: the model as :meth:`LatentSwarmPPO.save <sb3_latentswarm.latent_ppo.LatentSwarmPPO.save>` writes it:
  weights, optimizer state, ValueNorm statistics (policy buffers), ``num_timesteps``, ``_n_updates``, the schedule
  progress ``_current_progress_remaining`` and ``_total_timesteps``, the episode-statistics window ``ep_info_buffer``;
* ``state.json``: the Python and NumPy RNG states (NumPy's global stream shuffles the rollout buffer), the last
  swarm summaries, the vec env's plain state (VecMonitor counters, per-swarm ``numpy.random.Generator`` states of the
  batched core, its pending seed), the caller's run settings (what ``train --resume`` compares) and ``extra`` (plain
  data a caller keeps with the run, e.g. a sweep trial's progress rows);
* ``arrays.npz`` (read with ``allow_pickle=False``): the last observation, the last episode starts, the batched core's
  state arrays and its link model's state (:meth:`~sb3_latentswarm.links.LinkModel.get_state`: the Gilbert-Elliott
  chains, messages in flight), so every running episode continues where it stopped;
* ``tensors.pth`` (read with ``torch.load(weights_only=True)``): the carried latent state and the torch RNG states.

The state is captured at the start of a rollout, between two updates: the point where a run holds nothing else.
Resuming from a checkpoint after update ``u`` with ``learn(total - num_timesteps, reset_num_timesteps=False)`` then
gives, on the batched backend in one process, bit-identical parameters after update ``u + k`` to a run that never
stopped (``tests/test_checkpoints.py``). With the SuperSuit backend the env copies cannot be saved: the resumed run
starts new episodes (env seed ``seed + num_timesteps``), and is a continuation, not a replay.

:class:`SwarmCheckpointCallback` writes them every ``save_freq`` agent-steps (atomically, keeping the last ``keep``);
:func:`load_checkpoint` (also
:func:`load_checkpoint`) rebuilds the model
with its env; :class:`StopOnSignal` turns SIGINT / SIGTERM into a clean stop at the next step.
"""

from __future__ import annotations

import csv
import io
import json
import random
import re
import signal
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import CSVOutputFormat, HumanOutputFormat, Logger, TensorBoardOutputFormat
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.utils.atomic import write_bytes, write_text
from sb3_latentswarm.utils.checks import check_int
from sb3_latentswarm.utils.signals import SignalHandlers

__all__ = [
    "CHECKPOINT_FORMAT",
    "CheckpointError",
    "StopOnSignal",
    "SwarmCheckpointCallback",
    "TrainingInterrupted",
    "ResumableCSVOutputFormat",
    "ResumableTensorBoardOutputFormat",
    "checkpoint_bytes",
    "configure_run_logger",
    "default_save_freq",
    "estimate_checkpoint_bytes",
    "latest_checkpoint",
    "list_checkpoints",
    "load_checkpoint",
    "read_checkpoint_state",
    "restore_run_state",
]

CHECKPOINT_FORMAT = 1
"""Version of the checkpoint layout (``state.json``'s ``checkpoint_format``)."""

_NAME = re.compile(r"^checkpoint_(\d+)_steps\.zip$")

#: Attributes of the batched core (:class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`) that change while it runs;
#: the others are constants of the config. Arrays go to ``arrays.npz``, the random streams to ``state.json``.
_CORE_ARRAYS = (
    "_truth", "_map", "_covered", "kinematics", "_links", "footprint", "t", "n_covered", "collisions",
    "episode_return", "steps_to_90", "_in_link_sum", "_n_dropouts", "_n_link_draws", "_reward_terms", "dropout",
    "local_obs", "proprio", "link_rows", "global_map",
)
#: Core arrays that exist only with some configs (``None`` otherwise): the message ages under delay.
_OPTIONAL_CORE_ARRAYS = ("_link_ages", "link_ages")
_READ_ONLY_ARRAYS = ("local_obs", "proprio", "link_rows", "global_map", "link_ages")
#: Prefix of the link model's state arrays in ``arrays.npz`` (:meth:`~sb3_latentswarm.links.LinkModel.get_state`).
_LINK_STATE = "link_model."


class CheckpointError(ValueError):
    """A checkpoint is missing, damaged, or does not belong to the run that tries to continue from it."""


def default_save_freq(total_timesteps: int, steps_per_update: int, fraction: float = 0.05) -> int:
    """Agent-steps between checkpoints: about ``fraction`` of the budget, rounded to whole updates (at least one).

    :param total_timesteps: the training budget in agent-steps
    :param steps_per_update: agent-steps per update, ``n_steps * n_envs * n_agents``
    """
    updates = max(1, -(-total_timesteps // steps_per_update))
    return max(1, round(updates * fraction)) * steps_per_update


# ---------------------------------------------------------------------------------------------- the run state
def _rng_states() -> tuple[dict[str, Any], dict[str, np.ndarray], dict[str, th.Tensor]]:
    version, internal, gauss = random.getstate()
    name, keys, pos, has_gauss, cached = np.random.get_state(legacy=True)
    plain = {
        "python_random": {"version": version, "internal": list(internal), "gauss_next": gauss},
        "numpy_random": {"name": name, "pos": int(pos), "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
    }
    tensors = {"torch_rng": th.get_rng_state()}
    if th.cuda.is_available() and th.cuda.is_initialized():
        tensors.update({f"cuda_rng_{i}": state for i, state in enumerate(th.cuda.get_rng_state_all())})
    return plain, {"numpy_random_keys": np.asarray(keys, dtype=np.uint32)}, tensors


def _set_rng_states(plain: dict[str, Any], arrays: dict[str, np.ndarray], tensors: dict[str, th.Tensor]) -> None:
    py = plain["python_random"]
    random.setstate((py["version"], tuple(py["internal"]), py["gauss_next"]))
    npr = plain["numpy_random"]
    np.random.set_state((npr["name"], arrays["numpy_random_keys"], npr["pos"], npr["has_gauss"], npr["cached_gaussian"]))
    th.set_rng_state(tensors["torch_rng"])
    cuda = [tensors[name] for name in sorted(k for k in tensors if k.startswith("cuda_rng_"))]
    if cuda and th.cuda.is_available():
        th.cuda.set_rng_state_all(cuda)


def _unwrap(env: VecEnv) -> tuple[VecMonitor | None, VecEnv]:
    monitor = None
    while hasattr(env, "venv"):
        if isinstance(env, VecMonitor):
            monitor = env
        env = env.venv
    return monitor, env


def _env_state(env: VecEnv) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The plain state of a swarm vec env: VecMonitor's counters and, for the batched backend, the running swarms."""
    from sb3_latentswarm.envs.vec_env import BatchedSwarmVecEnv

    monitor, inner = _unwrap(env)
    plain: dict[str, Any] = {"backend": type(inner).__name__}
    arrays: dict[str, np.ndarray] = {}
    if monitor is not None:
        plain["monitor_episode_count"] = int(monitor.episode_count)
        arrays["monitor_episode_returns"] = np.asarray(monitor.episode_returns)
        arrays["monitor_episode_lengths"] = np.asarray(monitor.episode_lengths)
    if isinstance(inner, BatchedSwarmVecEnv):
        core = inner.core
        rngs = [rng for rng in core.rngs if rng is not None]
        if len(rngs) < len(core.rngs):
            raise CheckpointError("the batched env has not been reset yet: there is no run state to save")
        plain["swarm_rngs"] = [rng.bit_generator.state for rng in rngs]  # PCG64: plain dicts of ints
        plain["swarm_seeds"] = list(core.seeds)
        plain["pending_seed"] = inner._pending_seed
        plain["seeded"] = bool(inner._seeded)
        arrays.update({f"core.{name}": np.asarray(getattr(core, name)) for name in _CORE_ARRAYS})
        arrays.update(
            {f"core.{name}": getattr(core, name) for name in _OPTIONAL_CORE_ARRAYS if getattr(core, name) is not None}
        )
        arrays.update({f"core.{_LINK_STATE}{name}": value for name, value in core.link_model.get_state().items()})
    return plain, arrays


def _set_env_state(env: VecEnv, plain: dict[str, Any], arrays: dict[str, np.ndarray]) -> bool:
    """Restore what :func:`_env_state` saved; ``False`` when the episodes could not be restored (another backend)."""
    from sb3_latentswarm.envs.vec_env import BatchedSwarmVecEnv

    monitor, inner = _unwrap(env)
    if monitor is not None and "monitor_episode_returns" in arrays:
        if arrays["monitor_episode_returns"].shape != monitor.episode_returns.shape:
            raise CheckpointError(
                f"the checkpoint's env has {arrays['monitor_episode_returns'].shape[0]} slots, this env {env.num_envs}"
            )
        monitor.episode_returns = arrays["monitor_episode_returns"].copy()
        monitor.episode_lengths = arrays["monitor_episode_lengths"].copy()
        monitor.episode_count = plain["monitor_episode_count"]
    if not isinstance(inner, BatchedSwarmVecEnv) or plain.get("backend") != type(inner).__name__:
        return False
    core = inner.core
    if len(plain["swarm_rngs"]) != core.n_swarms:
        raise CheckpointError(f"the checkpoint's env has {len(plain['swarm_rngs'])} swarms, this env {core.n_swarms}")
    optional = [name for name in _OPTIONAL_CORE_ARRAYS if getattr(core, name) is not None]
    if any(f"core.{name}" not in arrays for name in optional):
        raise CheckpointError(
            f"the checkpoint's env has no {optional}: the env config differs from the checkpoint's (message delay)"
        )
    _set_link_state(core.link_model, arrays)
    for name in (*_CORE_ARRAYS, *optional):
        saved, current = arrays[f"core.{name}"], getattr(core, name)
        if saved.shape != current.shape or saved.dtype != current.dtype:
            raise CheckpointError(
                f"the checkpoint's env state {name} has shape {saved.shape} {saved.dtype}, this env's "
                f"{current.shape} {current.dtype}: the env config differs from the checkpoint's"
            )
        value = saved.copy()
        if name in _READ_ONLY_ARRAYS:
            value.flags.writeable = False
        setattr(core, name, value)
    for k, state in enumerate(plain["swarm_rngs"]):
        rng = np.random.Generator(getattr(np.random, state["bit_generator"])())
        rng.bit_generator.state = state
        core.rngs[k] = rng
    core.seeds = list(plain["swarm_seeds"])
    inner._pending_seed = plain["pending_seed"]
    inner._seeded = plain["seeded"]
    return True


def _set_link_state(link_model: Any, arrays: dict[str, np.ndarray]) -> None:
    """Restore the link model's state from the core arrays of a checkpoint (``core.link_model.<name>``).

    Checkpoints written before the link models existed keep the Gilbert-Elliott chains as ``core._xi_state``.
    """
    prefix = f"core.{_LINK_STATE}"
    state = {name[len(prefix) :]: value for name, value in arrays.items() if name.startswith(prefix)}
    if not state and "core._xi_state" in arrays and "xi_state" in link_model.get_state():
        state = {"xi_state": arrays["core._xi_state"]}
    try:
        link_model.set_state(state)
    except ValueError as error:
        raise CheckpointError(f"{error}: the env config differs from the checkpoint's") from None


def checkpoint_bytes(model: Any, settings: dict[str, Any] | None = None, extra: dict[str, Any] | None = None) -> bytes:
    """The checkpoint of ``model`` (a :class:`~sb3_latentswarm.latent_ppo.LatentSwarmPPO` between two updates) as zip bytes.

    :param settings: plain data describing the run (compared by ``train --resume``)
    :param extra: plain data the caller keeps with the run
    :raise CheckpointError: when the model has no run in progress (``learn`` not started)
    """
    if model._last_obs is None:
        raise CheckpointError("the model has no run in progress to checkpoint (call learn first)")
    model_file = io.BytesIO()
    model.save(model_file)
    rng_plain, rng_arrays, tensors = _rng_states()
    env_plain, env_arrays = _env_state(model.env) if model.env is not None else ({}, {})
    arrays = {**rng_arrays, **{f"env.{k}": v for k, v in env_arrays.items()}}
    arrays.update({f"last_obs.{key}": np.asarray(value) for key, value in model._last_obs.items()})
    arrays["last_episode_starts"] = np.asarray(model._last_episode_starts)
    latent = model._last_latent_state
    tensors.update({f"latent.{name}": getattr(latent, name).detach().cpu().clone() for name in LatentState._fields})
    state = {
        "checkpoint_format": CHECKPOINT_FORMAT,
        "num_timesteps": int(model.num_timesteps),
        "n_updates": int(model._n_updates),
        "total_timesteps": int(model._total_timesteps),
        "rng": rng_plain,
        "env": env_plain,
        "swarm_summaries": list(model._swarm_summaries),
        "tensorboard_log": model.tensorboard_log,
        "pending_log": _pending_log(model),
        "settings": settings or {},
        "extra": extra or {},
    }
    npz, pth, out = io.BytesIO(), io.BytesIO(), io.BytesIO()
    np.savez(npz, allow_pickle=False, **arrays)
    th.save(tensors, pth)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as archive:
        archive.writestr("model.zip", model_file.getvalue())
        archive.writestr("state.json", json.dumps(state, indent=1, default=_plain_default))
        archive.writestr("arrays.npz", npz.getvalue())
        archive.writestr("tensors.pth", pth.getvalue())
    return out.getvalue()


def _pending_log(model: Any) -> dict[str, Any]:
    """The values recorded since the last dump (the ``train/`` keys of the last update), kept so that the resumed
    run's first dump has them too."""
    logger = getattr(model, "_logger", None)
    if logger is None:
        return {}
    values = {k: float(v) for k, v in logger.name_to_value.items() if isinstance(v, (int, float, np.number))}
    excluded = {k: list(v) if v else None for k, v in logger.name_to_excluded.items() if k in values}
    return {"values": values, "excluded": excluded}


def _plain_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"a checkpoint holds plain data only, got a {type(value).__name__}")


def _open(path: str | Path) -> zipfile.ZipFile:
    try:
        archive = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise CheckpointError(f"no checkpoint at {path}") from None
    except zipfile.BadZipFile:
        raise CheckpointError(f"{path} is not a checkpoint (not a zip file)") from None
    missing = {"model.zip", "state.json", "arrays.npz", "tensors.pth"} - set(archive.namelist())
    if missing:
        archive.close()
        raise CheckpointError(f"{path} is not a checkpoint of sb3-latentswarm: it lacks {sorted(missing)}")
    return archive


def read_checkpoint_state(path: str | Path) -> dict[str, Any]:
    """The ``state.json`` of a checkpoint (``num_timesteps``, ``settings``, ``extra``, ...), nothing else loaded."""
    with _open(path) as archive:
        state = json.loads(archive.read("state.json"))
    if state.get("checkpoint_format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{path} has checkpoint format {state.get('checkpoint_format')!r}; this version reads {CHECKPOINT_FORMAT}"
        )
    return state


def restore_run_state(model: Any, path: str | Path) -> bool:
    """Put the run state of checkpoint ``path`` (RNGs, last observation, latent state, env) into ``model``.

    ``model`` holds the checkpoint's weights already (see :func:`load_checkpoint`) and its env.

    :return: whether the env's running episodes were restored (``False``: another backend; the env is reset with seed
        ``seed + num_timesteps`` when learning continues)
    """
    state = read_checkpoint_state(path)
    with _open(path) as archive:
        with np.load(io.BytesIO(archive.read("arrays.npz")), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
        tensors = th.load(io.BytesIO(archive.read("tensors.pth")), weights_only=True, map_location="cpu")
    env_arrays = {name[4:]: value for name, value in arrays.items() if name.startswith("env.")}
    restored = _set_env_state(model.env, state["env"], env_arrays) if model.env is not None else False
    if restored:
        model._last_obs = {name[9:]: value.copy() for name, value in arrays.items() if name.startswith("last_obs.")}
        model._last_episode_starts = arrays["last_episode_starts"].copy()
        saved = LatentState(*(tensors[f"latent.{name}"] for name in LatentState._fields))
        if saved.map_state.shape[0] != model.n_envs:
            raise CheckpointError(f"the checkpoint carries {saved.map_state.shape[0]} slots, the env has {model.n_envs}")
        model._last_latent_state = LatentState(*(t.to(model.device) for t in saved))
    else:  # new episodes from a seed that depends on where the run stopped
        base = model.seed if model.seed is not None else 0
        model.env.seed(base + int(state["num_timesteps"]))
        model._last_obs = None
    model._swarm_summaries.extend(state["swarm_summaries"])
    if model.ep_info_buffer:  # VecMonitor's types (the model file keeps Python numbers): logged means match exactly
        for info in model.ep_info_buffer:
            info["r"], info["l"] = np.float32(info["r"]), np.int32(info["l"])
    model._pending_log_values = state.get("pending_log") or {}  # recorded again by SwarmCheckpointCallback
    _set_rng_states(state["rng"], arrays, tensors)
    return restored


def load_checkpoint(path: str | Path, env: VecEnv, device: th.device | str = "auto", **kwargs: Any) -> Any:
    """Rebuild the :class:`~sb3_latentswarm.latent_ppo.LatentSwarmPPO` of checkpoint ``path`` on ``env``, ready to continue.

    Continue with ``model.learn(total - model.num_timesteps, reset_num_timesteps=False)`` (SB3's convention: the
    remaining agent-steps), which keeps the schedule progress and continues TensorBoard in the same run folder.

    :param env: the env of the run (same config, backend and number of copies)
    :param kwargs: passed to :meth:`LatentSwarmPPO.load` (e.g. ``tensorboard_log``; default: the run's)
    :raise CheckpointError: for a missing or damaged file, or an env that does not fit it
    """
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    state = read_checkpoint_state(path)
    with _open(path) as archive:
        model_file = io.BytesIO(archive.read("model.zip"))
    kwargs.setdefault("tensorboard_log", state.get("tensorboard_log"))
    model = LatentSwarmPPO.load(model_file, env=env, device=device, **kwargs)
    restore_run_state(model, path)
    return model


# ---------------------------------------------------------------------------------------------- logging
class ResumableCSVOutputFormat(CSVOutputFormat):
    """SB3's ``progress.csv`` writer that continues an existing file.

    :param resume_step: ``None``: start a new file; else keep the complete rows up to this ``time/total_timesteps``
        (those logged after the checkpoint are dropped: the resumed run logs them again; a row cut off by a kill is
        dropped too) and append
    """

    def __init__(self, filename: str | Path, resume_step: int | None = None):
        path = Path(filename)
        if resume_step is None or not path.exists() or path.stat().st_size == 0:
            super().__init__(str(path))
            return
        lines = path.read_text().splitlines(keepends=True)
        header = next(csv.reader(lines[:1]))
        column = header.index("time/total_timesteps") if "time/total_timesteps" in header else None
        kept = [lines[0]]
        for line in lines[1:]:
            row = next(csv.reader([line]), [])
            if not line.endswith("\n") or len(row) != len(header):  # a row cut off by a kill -9
                continue
            if column is None or (row[column] and float(row[column]) <= resume_step):
                kept.append(line)
        write_text(path, "".join(kept))
        self.file = open(path, "r+")  # noqa: SIM115 - SB3's writer keeps the file open
        self.file.seek(0, 2)
        self.keys = header
        self.separator = ","
        self.quotechar = '"'


class ResumableTensorBoardOutputFormat(TensorBoardOutputFormat):
    """SB3's TensorBoard writer with ``purge_step``: a resumed run hides the events the stopped run logged after its
    checkpoint, so the curve continues without a doubled stretch."""

    def __init__(self, folder: str | Path, purge_step: int | None = None):
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(log_dir=str(folder), purge_step=purge_step)
        self._is_closed = False


def configure_run_logger(
    folder: str | Path, verbose: int = 0, tensorboard_run: str | Path | None = None, resume_step: int | None = None
) -> Logger:
    """An SB3 logger writing ``folder/progress.csv`` (and stdout when ``verbose``, TensorBoard into the exact run
    folder ``tensorboard_run``), continuing both after the checkpoint at ``resume_step`` agent-steps."""
    Path(folder).mkdir(parents=True, exist_ok=True)
    formats: list[Any] = [ResumableCSVOutputFormat(Path(folder) / "progress.csv", resume_step)]
    if verbose >= 1:
        formats.append(HumanOutputFormat(sys.stdout))
    if tensorboard_run is not None:
        purge = None if resume_step is None else resume_step + 1
        formats.append(ResumableTensorBoardOutputFormat(tensorboard_run, purge))
    return Logger(folder=str(folder), output_formats=formats)


def estimate_checkpoint_bytes(model: Any) -> int:
    """An upper estimate of a checkpoint's size (what ``train`` checks the output folder has room for)."""
    model_file = io.BytesIO()
    model.save(model_file)
    per_slot = sum(int(np.prod(space.shape)) * space.dtype.itemsize for space in model.observation_space.spaces.values())
    latent = sum(model.policy.latent_dims)
    return len(model_file.getvalue()) + 3 * per_slot * model.n_envs + 8 * latent * model.n_envs + (1 << 20)


# ---------------------------------------------------------------------------------------------- files
def list_checkpoints(folder: str | Path) -> list[Path]:
    """The checkpoints in ``folder``, oldest first (by their agent-step count)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _NAME.match(p.name)) and p.is_file()]
    return [p for _, p in sorted(found)]


def latest_checkpoint(folder: str | Path) -> Path | None:
    """The newest checkpoint in ``folder``, or ``None``."""
    found = list_checkpoints(folder)
    return found[-1] if found else None


class TrainingInterrupted(KeyboardInterrupt):
    """Training was stopped by a signal after writing a checkpoint (raised by callers that cannot return a status,
    e.g. a sweep trial). A ``KeyboardInterrupt``, so code that handles Ctrl-C handles it too.

    :param signum: the signal's number
    :param checkpoint: the checkpoint written, from which a rerun continues
    """

    def __init__(self, signum: int | None, checkpoint: Path | None):
        self.signum = signum
        self.checkpoint = checkpoint
        name = signal.Signals(signum).name if signum else "a signal"
        super().__init__(f"training stopped by {name}; checkpoint {checkpoint}")


class StopOnSignal(SignalHandlers):
    """Context manager: the first SIGINT / SIGTERM sets :attr:`signum` (training stops cleanly at its next step, see
    :class:`SwarmCheckpointCallback`); a second one raises ``KeyboardInterrupt`` at once.

    Handlers are installed only in the main thread (Python's rule); elsewhere this does nothing.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        super().__init__()
        self.signum: int | None = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum

    @property
    def exit_code(self) -> int:
        """The shell's status of a process ended by the signal: 128 + its number (130 for SIGINT, 143 for SIGTERM)."""
        return 128 + int(self.signum or 0)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum else ""

    def __enter__(self) -> StopOnSignal:
        return super().__enter__()


class SwarmCheckpointCallback(BaseCallback):
    """Write a checkpoint every ``save_freq`` agent-steps, at the end of training, and when training is stopped.

    Unlike SB3's ``CheckpointCallback`` (which saves the model only, counting vec-env steps), a checkpoint here holds
    the whole run (see :mod:`sb3_latentswarm.runs.checkpoints`), counts agent-steps (SB3's ``num_timesteps``), is written
    atomically (:mod:`sb3_latentswarm.utils.atomic`: a failed write leaves the earlier checkpoints intact) and only
    the last ``keep`` are kept.

    The run state is captured at the start of every rollout (between two updates). When ``stop`` reports a signal,
    the rollout in progress is abandoned (``_on_step`` returns ``False``, so SB3's ``learn`` returns normally) and the
    state captured at its start is written: nothing of that update is kept, nothing is lost before it. The same holds
    when another callback ends training inside a rollout.

    :param save_freq: agent-steps between checkpoints (0: only at the end and when stopped); a checkpoint is written
        at the first rollout start at or past each multiple
    :param save_path: folder of the checkpoints (created when the first one is written)
    :param keep: how many of the newest checkpoints to keep (older ones are deleted after a new one is written)
    :param settings: plain data describing the run, stored in every checkpoint
    :param extra_state: called when a checkpoint is captured; its plain-data result is stored as ``extra``
    :param stop: a :class:`StopOnSignal` (or anything with a ``signum`` attribute) checked at every step
    :param verbose: 1 prints a line per checkpoint
    """

    def __init__(
        self,
        save_freq: int,
        save_path: str | Path,
        keep: int = 3,
        settings: dict[str, Any] | None = None,
        extra_state: Callable[[], dict[str, Any]] | None = None,
        stop: Any = None,
        verbose: int = 0,
    ):
        super().__init__(verbose)
        check_int("save_freq", save_freq, low=0)
        check_int("keep", keep, low=1)
        self.save_freq = int(save_freq)
        self.save_path = Path(save_path)
        self.keep = int(keep)
        self.settings = settings or {}
        self.extra_state = extra_state
        self.stop = stop
        self.last_path: Path | None = None
        """The newest checkpoint written."""
        self.stopped = False
        """Whether training was stopped by a signal."""
        self._snapshot: tuple[int, bytes] | None = None
        self._in_rollout = False
        self._written_at: int | None = None
        self._next_save = 0

    def _init_callback(self) -> None:
        # what load_checkpoint left on the model, recorded once: taken off the model here
        pending = vars(self.model).pop("_pending_log_values", None) or {}
        for key, value in pending.get("values", {}).items():
            excluded = pending.get("excluded", {}).get(key)
            self.logger.record(key, value, exclude=tuple(excluded) if excluded else None)
        self._next_save = self._following(self.num_timesteps)
        latest = latest_checkpoint(self.save_path)
        self._written_at = int(_NAME.match(latest.name).group(1)) if latest else None  # type: ignore[union-attr]

    def _following(self, steps: int) -> int:
        return (steps // self.save_freq + 1) * self.save_freq if self.save_freq else -1

    def _capture(self) -> None:
        extra = self.extra_state() if self.extra_state is not None else None
        self._snapshot = (int(self.model.num_timesteps), checkpoint_bytes(self.model, self.settings, extra))

    def _on_rollout_start(self) -> None:
        self._in_rollout = True
        self._capture()
        steps = self.model.num_timesteps
        if self.save_freq and steps >= self._next_save and steps > 0:
            self.write()
            self._next_save = self._following(steps)

    def _on_step(self) -> bool:
        if self.stop is not None and self.stop.signum is not None:
            self.stopped = True
            return False
        return True

    def _on_rollout_end(self) -> None:
        self._in_rollout = False

    def _on_training_end(self) -> None:
        # a rollout cut short (by a signal or another callback) is abandoned: the state at its start is written;
        # after a finished update, the final state is captured first
        if not self._in_rollout and (self._snapshot is None or self.model.num_timesteps > self._snapshot[0]):
            self._capture()
        self.write()

    def write(self) -> Path | None:
        """Write the last captured state (if not written yet) and delete checkpoints beyond ``keep``."""
        if self._snapshot is None:
            return self.last_path
        steps, data = self._snapshot
        if self._written_at == steps and self.last_path is not None:
            return self.last_path
        self.save_path.mkdir(parents=True, exist_ok=True)
        path = self.save_path / f"checkpoint_{steps}_steps.zip"
        write_bytes(path, data)
        self.last_path, self._written_at = path, steps
        for old in list_checkpoints(self.save_path)[: -self.keep]:
            old.unlink(missing_ok=True)
        if self.verbose >= 1:
            print(f"Checkpoint at {steps:,} agent-steps: {path}")
        return path
