"""``run_sweep``: training seeds x variants x grid points as Ray Tune trials, then the across-seed tables.

Layout of ``output`` (default ``runs/sweeps/<preset>/``)::

    sweep.json                 the :class:`~.spec.SweepSpec` (preset, variants, seeds, grid, overrides, evaluation cells)
    .lock                      held (:func:`~sb3_latentswarm.utils.locks.output_lock`) by the sweep running here
    trials/<trial_id>/         one finished trial: model.zip, trial.json (config, commit, machine, Ray node),
                               episodes.csv (one row per evaluation episode), progress.csv (one row per rollout)
    running/<trial_id>/        a trial in progress: its mid-trial checkpoints, continued by ``resume=True``
    ray/                       Ray Tune's experiment folders (``storage`` moves them elsewhere)
    episodes.csv, scores.csv   all trials' episodes; one row per trial and evaluation cell (the runs' scores)
    aggregate.csv, aggregate.md, *.png, run.md    the across-seed intervals (see :mod:`.report`)

A trial is finished when ``trials/<trial_id>/`` holds its complete results: they are copied there, whole, from the
checkpoint the trial reports to Tune when it is done. ``resume=True`` runs only the trials that are not finished.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_latentswarm.experiments.report import TRIAL_FILES, finished_trials
from sb3_latentswarm.experiments.spec import SweepSpec, trial_id
from sb3_latentswarm.experiments.trial import train_and_evaluate
from sb3_latentswarm.utils.atomic import read_json, write_json
from sb3_latentswarm.utils.checks import check_float
from sb3_latentswarm.utils.locks import output_lock
from sb3_latentswarm.utils.signals import SignalHandlers

__all__ = ["SweepStopped", "check_cluster", "check_storage", "plan_trials", "run_sweep", "select_trials"]


class SweepStopped(KeyboardInterrupt):
    """A sweep stopped by SIGINT / SIGTERM / SIGHUP after Ray Tune ended its trials cleanly.

    :param signum: the signal's number
    :param output: the sweep's folder (``--resume`` continues it)
    """

    def __init__(self, signum: int, output: Path):
        self.signum = signum
        self.output = output
        super().__init__(f"sweep stopped by {self.name}; resume it with --resume")

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """128 + the signal's number (130 for SIGINT, 143 for SIGTERM), as the shell reports a process it ended."""
        return 128 + self.signum


class _StopTune(SignalHandlers):
    """While Ray Tune runs: the first SIGINT / SIGTERM / SIGHUP asks Tune to stop (through its own SIGUSR1 handler:
    trials are stopped, the experiment state saved, ``fit`` returns); a second one stops at once. Without this, SIGTERM
    ends the driver in a Ray abort dump."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self) -> None:
        super().__init__()
        self.signum: int | None = None
        self._tune_sigint: str | None = None

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signum is not None or signal.getsignal(signal.SIGUSR1) in (signal.SIG_DFL, signal.SIG_IGN, None):
            raise KeyboardInterrupt  # a second signal, or Tune has not started: stop now
        self.signum = signum
        os.kill(os.getpid(), signal.SIGUSR1)

    def __enter__(self) -> _StopTune:
        self._tune_sigint = os.environ.get("TUNE_DISABLE_SIGINT_HANDLER")
        os.environ["TUNE_DISABLE_SIGINT_HANDLER"] = "1"  # SIGINT stays ours; Tune keeps its SIGUSR1 handler
        return super().__enter__()

    def __exit__(self, *exc: Any) -> None:
        super().__exit__(*exc)
        if self._tune_sigint is None:
            os.environ.pop("TUNE_DISABLE_SIGINT_HANDLER", None)
        else:
            os.environ["TUNE_DISABLE_SIGINT_HANDLER"] = self._tune_sigint


def plan_trials(spec: SweepSpec, commit: str) -> list[dict[str, Any]]:
    """Every (variant, training seed, grid point) of ``spec``, as the trial dicts :func:`train_and_evaluate` takes."""
    return [
        {
            "trial_id": trial_id(variant, seed, point),
            "variant": variant,
            "train_seed": seed,
            "grid_point": point,
            "spec": spec,
            "commit": commit,
        }
        # seed-major: an interrupted sweep has every variant at its first seeds, not all seeds of the first variant
        for point in spec.grid_points()
        for seed in spec.seeds
        for variant in spec.variants
    ]


def select_trials(trials: list[dict[str, Any]], done: set[str], only: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """The trials still to run, in plan order: not finished, and among ``only`` when it is given."""
    if only is not None:
        ids = [trial["trial_id"] for trial in trials]
        unknown = [trial_id for trial_id in only if trial_id not in ids]
        if unknown or not only:
            raise ValueError(f"--only: unknown trial id(s) {unknown or list(only)}; this sweep's trials are {ids}")
    return [t for t in trials if t["trial_id"] not in done and (only is None or t["trial_id"] in only)]


# ---------------------------------------------------------------------------------------------- the sweep folder
def _check_output(output: Path, spec: SweepSpec, resume: bool) -> None:
    """Refuse a folder that holds another sweep, or this one without ``resume``."""
    saved_path = output / "sweep.json"
    if not saved_path.exists():
        if (output / "trials").is_dir() and any((output / "trials").iterdir()):
            raise ValueError(f"--output {output} holds trials but no sweep.json; choose another --output")
        return
    if not resume:
        raise ValueError(f"--output {output} already holds a sweep; pass --resume to continue it, or another --output")
    saved = read_json(saved_path)
    asked = json.loads(json.dumps(spec.to_dict()))
    differ = sorted(key for key in asked.keys() | saved.keys() if asked.get(key) != saved.get(key))
    if differ:
        raise ValueError(
            f"--resume: this sweep differs from the one in {output} in {differ} "
            f"(saved: { {k: saved.get(k) for k in differ} }); resume with the same arguments, or choose another --output"
        )


def _plan(
    output: Path, spec: SweepSpec, resume: bool, commit: str, only: Sequence[str] | None
) -> tuple[list[dict[str, Any]], set[str], list[dict[str, Any]]]:
    """Check ``output`` (read only) and return (all trials, the finished ids, the trials to run now)."""
    _check_output(output, spec, resume)
    trials = plan_trials(spec, commit)
    done = set(finished_trials(output, spec)) if (output / "sweep.json").exists() else set()
    return trials, done, select_trials(trials, done, only)


# ---------------------------------------------------------------------------------------------- the cluster
def _auth_metadata() -> tuple[tuple[str, str], ...] | None:
    """The gRPC header carrying this machine's Ray token (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or
    ``~/.ray/auth_token``, as Ray reads them), or ``None`` when there is none."""
    try:
        from ray._raylet import AuthenticationTokenLoader  # type: ignore[attr-defined]
    except ImportError:  # a Ray before token authentication (2.5x): it has no tokens
        return None
    loader = AuthenticationTokenLoader.instance()
    if not loader.has_token(ignore_auth_mode=True):
        return None
    return tuple(loader.get_token_for_http_header().items())


def check_cluster(address: str) -> None:
    """Fail fast, in one line, when the Ray cluster at ``address`` cannot be used from here, saying which of the
    address or the token is wrong (a Ray version mismatch is reported by :func:`run_sweep` when it connects).

    ``address`` is ``HOST:PORT`` (the head's GCS port, 6379 by default), ``ray://HOST:PORT`` (Ray Client, checked for
    an answer only) or ``auto``. Ray >= 2.60 clusters started with ``ray start`` ask for a token when the head found
    one (``ray get-auth-token --generate``, or one ``ray.init()`` left in ``~/.ray/auth_token``). A cluster that asks
    for one, when this machine holds a token it accepts, is joined in token mode (``RAY_AUTH_MODE=token``, what
    ``ray start`` sets on the head), unless ``RAY_AUTH_MODE`` is set already.

    :raises ValueError: ``--address ...: <what is wrong>; <what to do>``
    """
    if address == "auto":
        return  # ray.init finds the local cluster or raises ConnectionError at once
    client = address.startswith("ray://")
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--address must be HOST:PORT, ray://HOST:PORT or auto, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=5.0).close()
    except OSError as error:
        raise ValueError(f"--address {address}: address: no Ray cluster answers there ({error})") from None
    if client:
        return
    import grpc
    from ray.core.generated import gcs_service_pb2, gcs_service_pb2_grpc

    def ask(metadata: tuple[tuple[str, str], ...]) -> grpc.StatusCode:
        with grpc.insecure_channel(f"{host}:{port}") as channel:
            try:
                stub = gcs_service_pb2_grpc.NodeInfoGcsServiceStub(channel)
                stub.GetClusterId(gcs_service_pb2.GetClusterIdRequest(), timeout=10.0, metadata=metadata)  # type: ignore[attr-defined]
            except grpc.RpcError as error:
                return error.code()
        return grpc.StatusCode.OK

    status = ask(())
    if status == grpc.StatusCode.OK:
        return
    if status != grpc.StatusCode.UNAUTHENTICATED:
        raise ValueError(f"--address {address}: address: this is not a Ray head's GCS port (gRPC {status.name})")
    metadata = _auth_metadata()
    remedy = (
        "copy the head's token (`ray get-auth-token` there) into RAY_AUTH_TOKEN or ~/.ray/auth_token here, "
        "or restart the cluster with RAY_AUTH_MODE=disabled on a private network"
    )
    if metadata is None:
        raise ValueError(f"--address {address}: token: the cluster asks for a Ray auth token and none is set here; {remedy}")
    if ask(metadata) != grpc.StatusCode.OK:
        raise ValueError(f"--address {address}: token: the cluster refuses this machine's Ray auth token; {remedy}")
    mode = os.environ.get("RAY_AUTH_MODE")
    if mode is None:
        from ray._private.authentication.authentication_token_setup import _enable_token_auth
        from ray._raylet import AuthenticationTokenLoader  # type: ignore[attr-defined]

        _enable_token_auth()  # RAY_AUTH_MODE=token for this process and its children, as `ray start` does
        AuthenticationTokenLoader.instance().reset_cache()
    elif mode.lower() != "token":
        raise ValueError(f"--address {address}: token: the cluster asks for a token but RAY_AUTH_MODE={mode}; unset it")


def _connect(address: str | None, verbose: int) -> Any:
    """``ray.init`` with a one-line error for a version mismatch or a refused connection."""
    import ray

    try:
        return ray.init(address=address, include_dashboard=False, configure_logging=False, log_to_driver=verbose > 1)
    except (ConnectionError, RuntimeError) as error:
        ray.shutdown()  # a failed connection leaves a half-made worker behind
        text = " ".join(str(error).split()) or type(error).__name__  # Ray's messages span several lines
        if "version mismatch" in text.lower():
            raise ValueError(
                f"--address {address}: version: {text}; use the cluster's Ray and Python versions on this machine"
            ) from None
        raise ValueError(f"--address {address}: cannot connect to Ray ({text})") from None


def check_storage(storage: str | None, output: Path) -> str:
    """The ``storage_path`` of Ray Tune: ``storage`` (a URI such as ``s3://bucket/sweeps``, ``gs://...``,
    ``file:///shared/sweeps``, or a path every node shares), or ``output/ray`` by default.

    A small probe file is written there and removed, so a URI that cannot be opened fails before any trial starts.

    :raises ValueError: ``--storage URI: cannot write there (...)``
    """
    if storage is None:
        return str((output / "ray").resolve())
    import pyarrow.fs

    try:
        filesystem, path = pyarrow.fs.FileSystem.from_uri(storage if "://" in storage else str(Path(storage).resolve()))
        probe = f"{path.rstrip('/')}/.sb3-latentswarm-probe-{os.getpid()}"
        filesystem.create_dir(path, recursive=True)
        with filesystem.open_output_stream(probe) as stream:
            stream.write(b"probe")
        filesystem.delete_file(probe)
    except (OSError, ValueError, ImportError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise ValueError(f"--storage {storage}: cannot write there ({first_line})") from None
    return storage if "://" in storage else str(Path(storage).resolve())


# ---------------------------------------------------------------------------------------------- the trials on Tune
def _run_trial_in_tune(config: dict[str, Any], trials: dict[str, dict[str, Any]], threads: int, running: str) -> None:
    """The Ray Tune trainable: one trial, progress reported per rollout, results reported as the final checkpoint.

    The trial works in ``running/<trial_id>/`` of the sweep folder, where :func:`train_and_evaluate` keeps its
    mid-trial checkpoints: a rerun into the same folder continues from the newest one, so a resumed sweep continues
    an interrupted trial. A node that does not see the sweep folder (no shared file system) works in a temporary
    folder, and an interrupted trial there starts again. Only the results (:data:`~.report.TRIAL_FILES`) travel
    back to the driver, as the trial's Tune checkpoint.
    """
    import ray
    import torch
    from ray import tune

    trial = trials[config["trial_id"]]
    torch.set_num_threads(threads)
    shared = Path(running).parent.is_dir()  # the sweep folder exists here: this machine, or a shared file system
    work = Path(running) / trial["trial_id"] if shared else Path(tempfile.mkdtemp(prefix=f"{trial['trial_id']}-"))
    work.mkdir(parents=True, exist_ok=True)
    record = train_and_evaluate(trial, work, report=tune.report)
    # the node that ran it, for run.md (trial.py records the host name as "node")
    record = {**record, "ray_node_id": ray.get_runtime_context().get_node_id()}
    write_json(work / "trial.json", record)
    final = {"agent_steps": float(record["trained_agent_steps"]), "eval_return": record["eval_return"]}
    if record["eval_coverage"] is not None:
        final["eval_coverage"] = record["eval_coverage"]
    results = Path(tempfile.mkdtemp(prefix=f"{trial['trial_id']}-results-"))
    try:
        for name in TRIAL_FILES:
            shutil.copy2(work / name, results / name)
        tune.report(final, checkpoint=tune.Checkpoint.from_directory(str(results)))  # persisted before it returns
    finally:
        shutil.rmtree(results, ignore_errors=True)
        if not shared:
            shutil.rmtree(work, ignore_errors=True)


def _collect(checkpoint: Any, destination: Path) -> None:
    """Copy a finished trial's checkpoint to ``destination``; the rename makes it appear complete or not at all."""
    partial = destination.with_name(f".{destination.name}.partial")
    shutil.rmtree(partial, ignore_errors=True)
    checkpoint.to_directory(str(partial))
    shutil.rmtree(destination, ignore_errors=True)
    partial.rename(destination)
    shutil.rmtree(destination.parent.parent / "running" / destination.name, ignore_errors=True)


def _run_tune(
    trials: list[dict[str, Any]], output: Path, storage_path: str, resources: dict[str, float], verbose: int
) -> None:
    """Run ``trials`` on the connected Ray cluster; collect each into ``output/trials`` as it completes."""
    from ray import tune

    trials_dir = output / "trials"

    class CollectFinished(tune.Callback):
        def on_trial_complete(self, iteration, trials, trial, **info):
            if trial.checkpoint is not None:
                _collect(trial.checkpoint, trials_dir / trial.config["trial_id"])

    # Tune's config holds only the trial id (its console shows it); the trials travel once, through the object store
    trainable = tune.with_parameters(
        _run_trial_in_tune,
        trials={trial["trial_id"]: trial for trial in trials},
        threads=max(1, int(resources["cpu"])),
        running=str((output / "running").resolve()),
    )
    tuner = tune.Tuner(
        tune.with_resources(trainable, resources),
        param_space={"trial_id": tune.grid_search([trial["trial_id"] for trial in trials])},
        tune_config=tune.TuneConfig(
            reuse_actors=True,  # a worker keeps its imports (torch, SB3) from one trial to the next
            trial_name_creator=lambda t: t.config["trial_id"],
            trial_dirname_creator=lambda t: t.config["trial_id"],
        ),
        run_config=tune.RunConfig(
            name=time.strftime("sweep-%Y%m%d-%H%M%S"),
            storage_path=storage_path,
            callbacks=[CollectFinished()],
            verbose=verbose,
        ),
    )
    results = tuner.fit()
    for result in (results[i] for i in range(len(results))):  # trials that never started have no config
        name = (result.config or {}).get("trial_id")
        if name and result.error is None and result.checkpoint is not None and not (trials_dir / name).exists():
            _collect(result.checkpoint, trials_dir / name)


def run_sweep(
    spec: SweepSpec,
    *,
    address: str | None = None,
    storage: str | None = None,
    cpus_per_trial: float = 1.0,
    gpus_per_trial: float = 0.0,
    output: str | Path | None = None,
    resume: bool = False,
    verbose: int = 1,
    only: Sequence[str] | None = None,
) -> Path:
    """Train every trial of ``spec`` (training seeds x variants x grid points) on Ray Tune, evaluate each trained model
    on held-out seeds, and write the per-run scores and the across-seed intervals into ``output``.

    :param spec: the sweep, from :meth:`SweepSpec.create <sb3_latentswarm.experiments.SweepSpec.create>`
    :param address: a running Ray cluster (``HOST:PORT``, ``ray://HOST:PORT``, ``auto``); ``None`` uses
        ``RAY_ADDRESS`` or starts Ray here with every CPU of this machine. See :func:`check_cluster` for tokens
    :param storage: Ray Tune's ``storage_path`` (:func:`check_storage`): a URI (``s3://``, ``gs://``, ``file://``) or
        a path every node can write; default ``output/ray``, enough on one machine
    :param cpus_per_trial: CPUs Ray reserves per trial (its torch threads: the integer part, at least 1)
    :param gpus_per_trial: GPUs Ray reserves per trial (a fraction shares one); with 0, trials train on the CPU
    :param output: result folder (default ``runs/sweeps/<preset>``), locked while the sweep runs
        (:func:`~sb3_latentswarm.utils.locks.output_lock`)
    :param resume: continue the sweep in ``output``: finished trials are kept, interrupted ones continue from their
        last checkpoint in ``running/``
    :param verbose: Ray Tune's console verbosity (0 silent, 1 status table, 2 also trial results)
    :param only: run only these trial ids (e.g. ``proposed-seed2``); the others stay pending for a later ``resume``
    :return: ``output``
    :raises ValueError: on bad arguments, a folder in use or holding another sweep, a damaged or stray trial folder, an
        unreachable cluster or storage, before anything is trained
    :raises RuntimeError: when trials failed (the finished ones are aggregated; ``resume=True`` reruns the rest)
    """
    from sb3_latentswarm.experiments.report import write_report
    from sb3_latentswarm.experiments.run_record import git_commit

    if not isinstance(spec, SweepSpec):
        raise TypeError(f"spec must be a SweepSpec (SweepSpec.create(...)), got {type(spec).__name__}")
    check_float("--cpus-per-trial", cpus_per_trial, low=0.0, low_open=True)
    check_float("--gpus-per-trial", gpus_per_trial, low=0.0)
    commit = git_commit()
    output = Path(output or Path("runs") / "sweeps" / spec.preset)
    if output.exists() and not output.is_dir():
        raise ValueError(f"--output {output} is a file, not a folder")
    _plan(output, spec, resume, commit, only)  # every check that reads the folder, before it is created or locked
    if address is not None:
        check_cluster(address)
    storage_path = check_storage(storage, output)
    with output_lock(output):
        trials, done, pending = _plan(output, spec, resume, commit, only)  # again: another sweep may have ended
        print(
            f"Sweep on preset {spec.preset!r}: {len(trials)} trials, {len(done)} already finished, {len(pending)} to run now"
        )
        if pending:
            import ray

            # Ray starts its workers at nice 15, so trials stall behind any other work on the machine (measured: 30 % of
            # a core each, updates 10x slower, next to two busy processes); a sweep's trials are the work. A cluster
            # keeps the niceness its `ray start` gave it.
            os.environ.setdefault("RAY_worker_niceness", "0")
            context = _connect(address, verbose)
            spec.save(output / "sweep.json")
            try:
                print(f"Ray: {ray.cluster_resources().get('CPU', 0):g} CPUs at {context.address_info.get('address')}")
                with _StopTune() as stop:
                    _run_tune(pending, output, storage_path, {"cpu": cpus_per_trial, "gpu": gpus_per_trial}, verbose)
            finally:
                ray.shutdown()
            if stop.signum is not None:  # Ray stopped cleanly; the finished trials are in trials/, the others resume
                raise SweepStopped(stop.signum, output)
        finished = finished_trials(output, spec)
        with contextlib.suppress(OSError):  # the work folder of running trials, once none is left there
            (output / "running").rmdir()
        write_report(output, commit)
    failed = [trial["trial_id"] for trial in pending if trial["trial_id"] not in finished]
    if failed:
        raise RuntimeError(f"{len(failed)} trial(s) failed: {failed}; rerun with --resume to retry them")
    return output
