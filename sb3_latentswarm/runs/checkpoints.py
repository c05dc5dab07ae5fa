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

Reading one is strict (:mod:`sb3_latentswarm.runs.checkpoint_file`, :mod:`sb3_latentswarm.runs.restore_checks`):
only these entries, each within its size limit, every value type- and range-checked against the model and the env,
nothing from the file used as a path to write to or a name to call.

The state is captured at the start of a rollout, between two updates: the point where a run holds nothing else.
Resuming from a checkpoint after update ``u`` with ``learn(total - num_timesteps, reset_num_timesteps=False)`` then
gives, on the batched backend in one process, bit-identical parameters after update ``u + k`` to a run that never
stopped (``tests/test_checkpoints.py``). With the SuperSuit backend the env copies cannot be saved: the resumed run
starts new episodes (env seed ``seed + num_timesteps``), and is a continuation, not a replay.

:class:`SwarmCheckpointCallback` writes them every ``save_freq`` agent-steps (atomically, keeping the last ``keep``);
:func:`load_checkpoint` rebuilds the model with its env; :func:`newest_valid_checkpoint` picks the newest checkpoint
that reads whole; :class:`StopOnSignal` turns SIGINT / SIGTERM / SIGHUP into a clean stop at the next step.
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
from stable_baselines3.common.vec_env import VecEnv

from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.runs.checkpoint_file import (
    CHECKPOINT_FORMAT,
    CheckpointContents,
    CheckpointError,
    NamedBytes,
    describe_differences,
    newest_valid_checkpoint,
    read_checkpoint,
    read_checkpoint_state,
)
from sb3_latentswarm.runs.restore_checks import (
    CORE_ARRAYS,
    LINK_STATE,
    OPTIONAL_CORE_ARRAYS,
    READ_ONLY_ARRAYS,
    check_run_state,
    unwrap,
)
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
    "CheckpointContents",
    "checkpoint_bytes",
    "configure_run_logger",
    "default_save_freq",
    "estimate_checkpoint_bytes",
    "latest_checkpoint",
    "list_checkpoints",
    "load_checkpoint",
    "newest_valid_checkpoint",
    "read_checkpoint",
    "read_checkpoint_state",
    "restore_run_state",
    "resume_tensorboard",
]

_NAME = re.compile(r"^checkpoint_(\d+)_steps\.zip$")


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


def _env_state(env: VecEnv) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The plain state of a swarm vec env: VecMonitor's counters and, for the batched backend, the running swarms."""
    from sb3_latentswarm.envs.vec_env import BatchedSwarmVecEnv

    monitor, inner = unwrap(env)
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
        arrays.update({f"core.{name}": np.asarray(getattr(core, name)) for name in CORE_ARRAYS})
        arrays.update(
            {f"core.{name}": getattr(core, name) for name in OPTIONAL_CORE_ARRAYS if getattr(core, name) is not None}
        )
        arrays.update({f"core.{LINK_STATE}{name}": value for name, value in core.link_model.get_state().items()})
    return plain, arrays


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


def restore_run_state(model: Any, checkpoint: str | Path | CheckpointContents) -> bool:
    """Put the run state of ``checkpoint`` (RNGs, last observation, latent state, env) into ``model``.

    ``model`` holds the checkpoint's weights already (see :func:`load_checkpoint`) and its env. Everything is checked
    against the model and the env (:mod:`sb3_latentswarm.runs.restore_checks`) before anything is changed.

    :param checkpoint: a checkpoint's path, or its contents from :func:`read_checkpoint`
    :return: whether the env's running episodes were restored (``False``: another backend; the env is reset with seed
        ``seed + num_timesteps`` when learning continues)
    :raise CheckpointError: naming the file, for anything that does not fit the model, the env or itself
    """
    contents = checkpoint if isinstance(checkpoint, CheckpointContents) else read_checkpoint(checkpoint)
    plan = check_run_state(model, contents)
    state, arrays, tensors = contents.state, contents.arrays, contents.tensors
    monitor, inner = unwrap(model.env) if model.env is not None else (None, None)
    if monitor is not None and "env.monitor_episode_returns" in arrays:
        monitor.episode_returns = arrays["env.monitor_episode_returns"].copy()
        monitor.episode_lengths = arrays["env.monitor_episode_lengths"].copy()
        monitor.episode_count = state["env"]["monitor_episode_count"]
    if plan.restore_episodes:
        core = inner.core  # type: ignore[union-attr]
        core.link_model.set_state(plan.link_state)  # checked: shapes and dtypes fit
        for name in plan.core_arrays:
            value = arrays[f"env.core.{name}"].copy()
            if name in READ_ONLY_ARRAYS:
                value.flags.writeable = False
            setattr(core, name, value)
        core.rngs[:] = plan.generators
        core.seeds = list(state["env"]["swarm_seeds"])
        inner._pending_seed = state["env"]["pending_seed"]  # type: ignore[union-attr]
        inner._seeded = state["env"]["seeded"]  # type: ignore[union-attr]
        model._last_obs = {name[9:]: value.copy() for name, value in arrays.items() if name.startswith("last_obs.")}
        model._last_episode_starts = arrays["last_episode_starts"].copy()
        initial = model.policy.initial_state(len(model._last_episode_starts))  # (fields an older checkpoint lacks)
        model._last_latent_state = LatentState(*(tensors.get(f"latent.{name}", getattr(initial, name)).to(model.device)
                                                 for name in LatentState._fields))
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
    return plan.restore_episodes


def load_checkpoint(path: str | Path, env: VecEnv, device: th.device | str = "auto", **kwargs: Any) -> Any:
    """Rebuild the :class:`~sb3_latentswarm.latent_ppo.LatentSwarmPPO` of checkpoint ``path`` on ``env``, ready to continue.

    Continue with ``model.learn(total - model.num_timesteps, reset_num_timesteps=False)`` (SB3's convention: the
    remaining agent-steps), which keeps the schedule progress. The file never chooses where the run writes: pass
    ``tensorboard_log`` to continue TensorBoard logging (default: none).

    :param env: the env of the run (same config, backend and number of copies); an env of another config is refused,
        naming each field that differs
    :param kwargs: passed to :meth:`LatentSwarmPPO.load` (e.g. ``tensorboard_log``)
    :raise CheckpointError: for a missing, damaged or crafted file, or an env that does not fit it, naming the file
    """
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO
    from sb3_latentswarm.latent_ppo.load_checks import check_load_budget

    contents = read_checkpoint(path)
    kwargs.setdefault("tensorboard_log", None)
    label = f"{path} (entry model.zip)"
    try:
        model = LatentSwarmPPO.load(NamedBytes(contents.model_file, label), device=device, **kwargs)
    except (TypeError, ValueError) as error:
        if isinstance(error, TypeError) and label not in str(error):
            raise  # a wrong keyword of the caller
        raise CheckpointError(str(error) if label in str(error) else f"{label}: {error}") from None
    saved_config, config = model.swarm_config, getattr(env, "config", None)
    if saved_config is not None and config is not None and saved_config != config:
        differ = describe_differences(saved_config.to_dict(), config.to_dict())
        raise CheckpointError(f"{path} belongs to a run on another env config: {'; '.join(differ)}")
    try:
        check_load_budget(model, label, n_envs=env.num_envs)
        model.set_env(env)
    except ValueError as error:
        raise CheckpointError(str(error) if str(path) in str(error) else f"{path}: {error}") from None
    restore_run_state(model, contents)
    return model


def resume_tensorboard(
    output: str | Path, given: str | None, stored: dict[str, Any], tb_log_name: str
) -> tuple[str | None, str | None, str | None]:
    """Where a resumed run logs TensorBoard: never where the checkpoint alone says.

    The folder is ``given`` (``--tensorboard``) or, without it, the run's stored folder only when it lies inside
    ``output`` (symlinks resolved); the run folder is the stored one only when it is ``FOLDER/<tb_log_name>_<n>``,
    else the next new run in the folder.

    :param stored: the checkpoint's ``settings`` (its ``tensorboard`` and ``tensorboard_run``)
    :return: ``(folder, run folder, note)``: ``note`` is a line to print when the stored folder was not used
    """
    from stable_baselines3.common.utils import get_latest_run_id

    note = None
    folder = given
    saved_folder, saved_run = stored.get("tensorboard"), stored.get("tensorboard_run")
    if folder is None and isinstance(saved_folder, str):
        if Path(saved_folder).resolve().is_relative_to(Path(output).resolve()):
            folder = saved_folder
        else:
            note = (f"TensorBoard: the checkpoint names the folder {saved_folder!r} outside {output}; it is not used. "
                    f"Pass --tensorboard again to continue logging there")
    if folder is None:
        return None, None, note
    pattern = re.compile(rf"^{re.escape(tb_log_name)}_\d{{1,9}}$")
    if isinstance(saved_run, str) and Path(saved_run).parent == Path(folder) and pattern.match(Path(saved_run).name):
        return folder, saved_run, note
    return folder, str(Path(folder) / f"{tb_log_name}_{get_latest_run_id(folder, tb_log_name) + 1}"), note


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
    """The checkpoints in ``folder``, oldest first (by their agent-step count); symlinks are not checkpoints."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    regular = (p for p in folder.iterdir() if not p.is_symlink() and p.is_file())
    found = [(int(m.group(1)), p) for p in regular if (m := _NAME.match(p.name))]
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
    """Context manager: the first SIGINT / SIGTERM / SIGHUP (a closed terminal) sets :attr:`signum` (training stops
    cleanly at its next step, see :class:`SwarmCheckpointCallback`); a second one raises ``KeyboardInterrupt`` at once.

    Handlers are installed only in the main thread (Python's rule); elsewhere this does nothing.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

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
