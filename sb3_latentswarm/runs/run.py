"""The one run path (rl-baselines3-zoo's ``ExperimentManager`` role): new | resume | warm start -> learn with
checkpoints and signal handling -> save (atomically) -> evaluate.

``sb3-latentswarm train`` (:mod:`sb3_latentswarm.cli.train`), each seed of ``train --seeds`` (which runs that command
once per seed, :mod:`sb3_latentswarm.runs.train_seeds`) and every sweep trial
(:func:`sb3_latentswarm.experiments.trial.train_and_evaluate`) train through :class:`Run`::

    with Run(output) as run:            # the output folder is held for the whole run
        stored = run.state              # the checkpoint find_start chose (None: a new run), for the caller to compare
        spec = RunSpec(preset, output, seed=0, resume=True, ...)
        result = run.train(spec, hooks)  # hooks: extra callbacks, what a checkpoint keeps, printing, evaluation

What differs between callers is data (:class:`RunSpec`) or a hook (:class:`RunHooks`), never a second copy of the
steps. :meth:`Run.__enter__` takes the output folder's lock (:func:`~sb3_latentswarm.utils.locks.output_lock`) for the
whole run, and :func:`find_start` chooses the newest valid checkpoint to continue.
"""

from __future__ import annotations

import contextlib
import io
import signal
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_latentswarm.baselines.independent import IndependentRecurrentPPO, independent_ppo
from sb3_latentswarm.latent_ppo import LatentSwarmPPO
from sb3_latentswarm.runs.checkpoints import (
    CheckpointError,
    StopOnSignal,
    SwarmCheckpointCallback,
    TrainingInterrupted,
    configure_run_logger,
    default_save_freq,
    estimate_checkpoint_bytes,
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    newest_valid_checkpoint,
    read_checkpoint_state,
)
from sb3_latentswarm.utils.atomic import atomic_path, probe_writable, write_json
from sb3_latentswarm.utils.checks import check_int
from sb3_latentswarm.utils.locks import output_lock

if TYPE_CHECKING:
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_latentswarm.presets import Preset

__all__ = [
    "CHECKPOINTS",
    "LEARNERS",
    "CheckpointWriteError",
    "Run",
    "RunHooks",
    "RunResult",
    "RunSpec",
    "RunStopped",
    "find_start",
    "required_room",
]

CHECKPOINTS = "checkpoints"
"""Subfolder of a run's output folder holding its checkpoints (:mod:`sb3_latentswarm.runs.checkpoints`)."""

LEARNERS = ("latent_swarm_ppo", "independent_ppo")
"""What a run can train: :class:`~sb3_latentswarm.latent_ppo.LatentSwarmPPO` (checkpoints, exact resume), or the
``independent`` baseline's sb3-contrib ``RecurrentPPO`` (:mod:`sb3_latentswarm.baselines.independent`: no checkpoints,
a rerun starts again)."""


@dataclass(frozen=True)
class RunSpec:
    """One training run: everything :meth:`Run.train` needs, checked before any file is written."""

    preset: Preset
    """Env config, number of env copies, algorithm settings and default budget of the run (already validated, e.g.
    by the CLI's settings); a sweep variant passes its own (links down for ``no_comm``, its message substitute)."""
    output: Path
    """The run's folder: ``model.zip``, ``checkpoints/``, and with :attr:`run_files` ``config.json`` and
    ``progress.csv``."""
    seed: int = 0
    """Seed of a new model; a warm-started model is reseeded with it (a continuation draws new random numbers)."""
    env_seed: int | None = None
    """Seed of the first env copy, copy ``c`` gets ``env_seed + c`` (default: :attr:`seed`)."""
    total_timesteps: int | None = None
    """Training budget in agent-steps, counted from the run's start (default: the preset's)."""
    learner: str = "latent_swarm_ppo"
    """One of :data:`LEARNERS`."""
    backend: str = "batched"
    """Vec env backend (:func:`~sb3_latentswarm.envs.make_vec_env`)."""
    device: str = "auto"
    """Torch device, as SB3 takes it."""
    resume: bool = False
    """Continue the checkpoint :func:`find_start` chose; without it, a folder holding checkpoints is refused."""
    warm_start: Path | None = None
    """A model file to continue training (weights, optimizer, agent-step count) instead of a new model."""
    save_freq: int | None = None
    """Agent-steps between checkpoints (default: about 5 % of the budget in whole updates; 0: only at the end and when
    stopped)."""
    keep_checkpoints: int = 3
    """How many of the newest checkpoints are kept."""
    settings: Mapping[str, Any] = field(default_factory=dict)
    """Plain data stored in every checkpoint: what a caller compares before it resumes (``train``'s options, a sweep
    trial's identity)."""
    tensorboard: str | None = None
    """TensorBoard log folder of the model (SB3's ``tensorboard_log``)."""
    tensorboard_run: str | None = None
    """The exact TensorBoard run folder the run logger writes into (``tensorboard/<name>_<k>``), kept on resume."""
    run_files: bool = True
    """Write ``progress.csv`` (SB3's logger, and TensorBoard) while training and ``config.json`` beside the model. A
    sweep trial writes its own ``progress.csv`` and ``trial.json`` instead."""
    verbose: int = 0
    """SB3's verbosity (1: the training table every update and a line per checkpoint)."""

    @property
    def budget(self) -> int:
        return self.preset.total_timesteps if self.total_timesteps is None else self.total_timesteps

    @property
    def first_env_seed(self) -> int:
        return self.seed if self.env_seed is None else self.env_seed

    @property
    def checkpoint_freq(self) -> int:
        """:attr:`save_freq`, or the default for the budget."""

        default = default_save_freq(self.budget, self.preset.agent_steps_per_update)
        return default if self.save_freq is None else self.save_freq

    @property
    def checkpoints(self) -> bool:
        """Whether the run writes checkpoints (only LatentSwarmPPO's state is saved whole)."""
        return self.learner == "latent_swarm_ppo"

    def check(self) -> None:
        """:raise ValueError: for a learner, budget, checkpoint setting or TensorBoard run that cannot be used."""
        if self.learner not in LEARNERS:
            raise ValueError(f"learner must be one of {LEARNERS}, got {self.learner!r}")
        check_int("total_timesteps", self.budget, low=1)
        check_int("keep_checkpoints", self.keep_checkpoints, low=1)
        if self.save_freq is not None:
            check_int("save_freq", self.save_freq, low=0)
        if not self.checkpoints and (self.resume or self.tensorboard is not None):
            raise ValueError(f"learner {self.learner!r} has no checkpoints to resume and no TensorBoard run")


@dataclass(frozen=True)
class RunResult:
    """A finished run: its saved model and what it took."""

    model: Any
    """The trained model (for ``independent_ppo``, the :class:`~sb3_latentswarm.baselines.IndependentRecurrentPPO`
    the evaluation harness takes)."""
    model_path: Path
    trained_steps: int
    """Agent-steps trained, since the run's start (a resumed run counts its earlier part)."""
    resumed_from: int | None
    """Agent-steps of the checkpoint the run continued, ``None`` for a new or warm-started run."""
    train_seconds: float
    """Wall-clock seconds of this process's training (not the earlier part of a resumed run)."""
    device: Any


class RunStopped(TrainingInterrupted):
    """A signal stopped the run; a checkpoint holds everything trained before it (a ``KeyboardInterrupt``, so code
    that handles Ctrl-C handles it).

    :param signum: the first signal's number (``None``: stopped by a second signal or a ``KeyboardInterrupt``)
    :param checkpoint: the newest checkpoint, from which ``resume`` continues
    :param seconds: wall-clock seconds trained before the stop
    :param saved: the signal came during the last update: ``model.zip`` is complete, only the evaluation was skipped
    """

    def __init__(self, signum: int | None, checkpoint: Path | None, seconds: float, saved: bool = False):
        super().__init__(signum, checkpoint)
        self.seconds, self.saved = seconds, saved
        self.name = signal.Signals(signum).name if signum else ""

    @property
    def exit_code(self) -> int:
        """The shell's status of a process ended by the signal: 128 + its number (130 for a second Ctrl-C)."""
        return 128 + int(self.signum) if self.signum else 130


class CheckpointWriteError(OSError):
    """A checkpoint could not be written (full disk, size limit); the earlier checkpoints are intact."""


class RunHooks:
    """What a caller adds to :meth:`Run.train`, in SB3's callback habit; each method does nothing by default."""

    def callbacks(self) -> Sequence[BaseCallback]:
        """SB3 callbacks learning runs with, besides the checkpoints (progress bars, Tune reports)."""
        return ()

    def extra_state(self) -> dict[str, Any]:
        """Plain data kept with every checkpoint (``state.json``'s ``extra``), read back as ``run.state["extra"]``."""
        return {}

    def started(self, run: Run) -> None:
        """The model is built and the folder checked: called once before training (e.g. to say what will run)."""

    def saved(self, run: Run, result: RunResult) -> None:
        """``model.zip`` is written."""

    def evaluate(self, run: Run, result: RunResult) -> None:
        """Evaluate the saved model (skipped when a signal came during training)."""


def find_start(output: str | Path) -> Path | None:
    """The checkpoint a run in ``output`` continues from: the newest in ``output/checkpoints/`` that reads whole
    (:func:`~sb3_latentswarm.runs.checkpoints.newest_valid_checkpoint`: a damaged newer one is skipped with one line
    saying so), ``None`` for none.

    :raise CheckpointError: when the folder holds checkpoints and none is valid, naming each and why
    """
    found = list_checkpoints(Path(output) / CHECKPOINTS)
    return newest_valid_checkpoint(found)[0] if found else None


def required_room(model: Any) -> int:
    """Bytes a run's output folder must have free before training: the one free-space rule.

    A checkpointing run writes a new checkpoint before it deletes the oldest: twice a checkpoint's size. Another
    learner writes its model file once: its size and 1 MiB (``model.zip`` is written to a temporary name first).
    """

    if isinstance(model, LatentSwarmPPO):
        return 2 * estimate_checkpoint_bytes(model)
    buffer = io.BytesIO()
    model.save(buffer)
    return len(buffer.getvalue()) + (1 << 20)


class Run:
    """One run in an output folder, held from ``with Run(output) as run:`` to the end of the block.

    Entering chooses the checkpoint the run would continue (:attr:`start`, by :func:`find_start`); :attr:`state` reads
    it. :meth:`train` then builds the env and the model (new, resumed from :attr:`start`, or warm-started), checks the
    folder has room (:func:`required_room`), learns with checkpoints and clean stops on SIGINT / SIGTERM, saves
    ``model.zip`` atomically and evaluates.

    :param output: the run's folder (need not exist yet: nothing is written before :meth:`train` has built the model)
    """

    def __init__(self, output: str | Path):
        self.output = Path(output)
        self.start: Path | None = None
        """The checkpoint :func:`find_start` chose on entering, ``None`` when the folder holds none."""
        self.env: Any = None
        self.model: Any = None
        """The algorithm being trained (set by :meth:`train`)."""
        self.resumed_from: int | None = None
        """Agent-steps of :attr:`start` when :meth:`train` resumed it."""
        self.budget = 0
        self._state: dict[str, Any] | None = None

    def __enter__(self) -> Run:
        self._lock = contextlib.ExitStack()  # the output folder is held for the whole run: a second writer is refused
        self._lock.enter_context(output_lock(self.output))
        try:
            self.start = find_start(self.output)
        except BaseException:
            self._lock.close()
            raise
        return self

    def __exit__(self, *exc_info: Any) -> None:
        if self.env is not None:
            self.env.close()
        self._lock.close()

    @property
    def checkpoint_dir(self) -> Path:
        return self.output / CHECKPOINTS

    @property
    def state(self) -> dict[str, Any] | None:
        """The run state stored in :attr:`start` (``settings``, ``num_timesteps``, ``extra``, ...), ``None`` without
        one; read once."""
        if self.start is None:
            return None
        if self._state is None:
            self._state = read_checkpoint_state(self.start)
        return self._state

    @property
    def remaining(self) -> int:
        """Agent-steps left to train (after :meth:`train` built the model)."""
        return self.budget - int(self.model.num_timesteps)

    def train(self, spec: RunSpec, hooks: RunHooks | None = None) -> RunResult:
        """new | resume | warm start -> learn with checkpoints -> save -> evaluate.

        :raise CheckpointError: for checkpoints in the folder without ``spec.resume``
        :raise RunStopped: when SIGINT / SIGTERM stopped training (after writing a checkpoint)
        :raise CheckpointWriteError: when a checkpoint could not be written
        """
        hooks = hooks or RunHooks()
        spec.check()
        if Path(spec.output) != self.output:
            raise ValueError(f"the spec's output {spec.output} is not the run's folder {self.output}")
        if self.start is not None and not spec.resume:
            raise CheckpointError(
                f"{self.checkpoint_dir} holds checkpoints (newest {self.start.name}): resume that run or use another folder"
            )
        self.budget = spec.budget
        self._build(spec)
        probe_writable(spec.output, room_bytes=required_room(self.model))
        if spec.tensorboard_run is not None:
            probe_writable(spec.tensorboard_run)
        if spec.run_files:
            self.model.set_logger(configure_run_logger(spec.output, spec.verbose, spec.tensorboard_run, self.resumed_from))
        hooks.started(self)
        start = time.perf_counter()
        stop = self._learn(spec, hooks)
        seconds = time.perf_counter() - start
        result = self._save(spec, seconds)
        hooks.saved(self, result)
        if stop is not None:  # the signal came during the last update: the model is complete, the evaluation skipped
            raise RunStopped(stop, None, seconds, saved=True)
        hooks.evaluate(self, result)
        return result

    # ------------------------------------------------------------------------------------------ the steps
    def _build(self, spec: RunSpec) -> None:
        """The env and the model: resumed from :attr:`start`, warm-started from ``spec.warm_start``, or new."""
        self.env = spec.preset.make_env(spec.first_env_seed, backend=spec.backend)
        if spec.learner == "independent_ppo":
            self.model = independent_ppo(
                self.env, seed=spec.seed, device=spec.device, continue_from=spec.warm_start,
                **spec.preset.independent_ppo_kwargs(),
            )
        elif self.start is not None:
            self.model = load_checkpoint(self.start, env=self.env, device=spec.device, tensorboard_log=spec.tensorboard)
            self.model.verbose = spec.verbose
            self.resumed_from = int(self.model.num_timesteps)
        elif spec.warm_start is not None:
            self.model = LatentSwarmPPO.load(spec.warm_start, env=self.env, device=spec.device)
            self.model.set_random_seed(spec.seed)
        else:
            self.model = spec.preset.make_model(
                self.env, seed=spec.seed, device=spec.device, verbose=spec.verbose, tensorboard_log=spec.tensorboard
            )
        if spec.warm_start is not None and self.model.num_timesteps >= self.budget:
            raise ValueError(
                f"warm start {spec.warm_start} has trained {self.model.num_timesteps:,} agent-steps, not fewer than the "
                f"run's budget of {self.budget:,}"
            )

    def _learn(self, spec: RunSpec, hooks: RunHooks) -> int | None:
        """Train the remaining budget; a checkpoint every ``save_freq``, at the end and on a signal (a learner without
        checkpoints keeps Python's signal handling).

        :return: the signal that came during the last update (``None``: none)
        """
        callbacks = list(hooks.callbacks())
        start = time.perf_counter()
        with contextlib.ExitStack() as scope:
            stop, checkpoints = None, None
            if spec.checkpoints:
                stop = scope.enter_context(StopOnSignal())
                checkpoints = SwarmCheckpointCallback(
                    spec.checkpoint_freq,
                    self.checkpoint_dir,
                    keep=spec.keep_checkpoints,
                    settings=dict(spec.settings),
                    extra_state=hooks.extra_state,
                    stop=stop,
                    verbose=spec.verbose,
                )
                callbacks.append(checkpoints)
            try:
                if self.remaining > 0:
                    self.model.learn(
                        total_timesteps=self.remaining,
                        callback=callbacks,
                        tb_log_name=f"latentswarm_{spec.preset.name}",
                        reset_num_timesteps=self.start is None and spec.warm_start is None,
                    )
            except KeyboardInterrupt:  # a second signal: no clean stop, the last captured state is still written
                if checkpoints is None:
                    raise
                checkpoints.stopped = True
                checkpoints.write()
            except OSError as error:  # a checkpoint could not be written: the earlier ones are intact
                raise CheckpointWriteError(
                    f"could not write a checkpoint: {error}. The earlier checkpoints in {self.checkpoint_dir} are intact"
                ) from error
            finally:
                if spec.run_files:
                    self.model.logger.close()
        if stop is not None and checkpoints is not None and checkpoints.stopped:
            where = checkpoints.last_path or latest_checkpoint(self.checkpoint_dir)
            raise RunStopped(stop.signum, where, time.perf_counter() - start)
        return None if stop is None else stop.signum

    def _save(self, spec: RunSpec, seconds: float) -> RunResult:
        """``model.zip`` (and with ``run_files`` ``config.json``), each written atomically."""
        trained = self.model
        if spec.learner == "independent_ppo":
            trained = IndependentRecurrentPPO(self.model)
        path = spec.output / "model.zip"
        spec.output.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            trained.save(tmp)
        if spec.run_files:
            write_json(spec.output / "config.json", spec.preset.config.to_dict())
        return RunResult(trained, path, int(self.model.num_timesteps), self.resumed_from, seconds, self.model.device)
