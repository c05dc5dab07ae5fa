"""Sweeps on a real multi-node Ray cluster (``ray.cluster_utils.Cluster``), shared storage as a ``file://`` URI, and
a cluster started by ``ray start`` with token authentication (Ray >= 2.60). The commands are those of
``docs/sweeps.md``, "Running on a cluster"."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import pytest
import ray

from sb3_latentswarm.cli import main

ROOT = Path(__file__).resolve().parents[1]
RAY_BIN = Path(sys.executable).with_name("ray")


@pytest.mark.slow
def test_two_node_sweep_with_file_storage(tmp_path, capsys, monkeypatch):
    from ray.cluster_utils import Cluster

    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the nodes' workers import this checkout
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        output, storage = tmp_path / "sweep", tmp_path / "shared-storage"
        # a driver with another Ray version than the cluster's: one line that says so (Ray's own check, made to fail)
        with monkeypatch.context() as patch:
            version = ray._private.utils.compute_version_info()
            patch.setattr(ray._private.utils, "compute_version_info", lambda: ("2.59.0", version[1]))
            with pytest.raises(SystemExit) as error:
                main(["sweep", "--preset", "smoke", "--seeds", "1", "--address", cluster.address,
                      "--output", str(tmp_path / "mismatch"), "--verbose", "0"])
        assert error.value.code == 2
        err = capsys.readouterr().err
        started = f"version: Version mismatch: The cluster was started with: Ray: {ray.__version__}"
        assert f"--address {cluster.address}: {started}" in err
        assert "This process on" in err and "Ray: 2.59.0" in err and len(err.strip().splitlines()) == 1
        # two trials of one CPU each on two nodes of one CPU: they run at the same time, one on each node
        argv = ["sweep", "--preset", "smoke", "--seeds", "2", "--variant", "proposed", "--grid", "p_fail=0.3",
                "--eval-episodes", "2", "--address", cluster.address, "--storage", f"file://{storage}",
                "--output", str(output), "--verbose", "0"]
        assert main(argv) == 0
        printed = capsys.readouterr().out
        assert "2 trials, 0 already finished, 2 to run now" in printed and "Ray: 2 CPUs" in printed

        records = [json.loads((output / "trials" / name / "trial.json").read_text())
                   for name in ("proposed-seed0-p_fail=0.3", "proposed-seed1-p_fail=0.3")]
        node_ids = {node.node_id for node in cluster.list_all_nodes()}
        assert {r["ray_node_id"] for r in records} == node_ids  # each trial names the node it ran on: both nodes
        assert all(r["node"] == socket.gethostname() for r in records)
        run_md = (output / "run.md").read_text()
        assert all(f"(Ray node {r['ray_node_id']})" in run_md for r in records)
        scores = pd.read_csv(output / "scores.csv")
        assert set(scores["grid.p_fail"]) == {0.3} and scores.groupby("eval_set")["train_seed"].nunique().eq(2).all()
        assert any(storage.glob("sweep-*/proposed-seed0-p_fail=0.3"))  # Tune wrote its experiment to the storage URI
        assert not (output / "ray").exists()
        assert not (output / "running").exists()  # finished trials leave no work folder behind

        # resume from another machine attached to the same cluster: only the named trial runs
        shutil.rmtree(output / "trials" / "proposed-seed1-p_fail=0.3")
        assert main([*argv, "--resume", "--only", "proposed-seed1-p_fail=0.3"]) == 0
        assert "2 trials, 1 already finished, 1 to run now" in capsys.readouterr().out
        assert (output / "trials" / "proposed-seed1-p_fail=0.3" / "trial.json").exists()
    finally:
        ray.shutdown()
        cluster.shutdown()


def test_an_unwritable_storage_uri_fails_before_ray_starts(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(SystemExit) as error:
        main(["sweep", "--preset", "smoke", "--seeds", "1", "--output", str(tmp_path / "sweep"),
              "--storage", f"file://{blocker}/storage"])
    assert error.value.code == 2
    err = capsys.readouterr().err
    assert f"--storage file://{blocker}/storage: cannot write there" in err and len(err.strip().splitlines()) == 1


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _clean_env(home: str, **extra: str) -> dict[str, str]:
    """This process's environment without Ray's token variables, with its own HOME (so no ~/.ray/auth_token)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_AUTH", "RAY_ADDRESS"))}
    return {**env, "HOME": home, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", **extra}


@pytest.mark.slow
def test_a_token_cluster_says_the_token_is_missing_or_wrong_and_joins_with_it(tmp_path):
    # Ray 2.60's `ray start` enables token authentication when it finds a token; a client without one gets
    # "Authentication token is missing or incorrect" deep in a log and a ConnectionError naming the node IP
    token = "0123456789abcdef0123456789abcdef"
    port = _free_port()
    home = tempfile.mkdtemp(prefix="rayhome-", dir="/tmp")  # short: Ray's socket paths live under its temp dir
    head = subprocess.Popen(
        [str(RAY_BIN), "start", "--head", "--port", str(port), "--num-cpus", "1", "--include-dashboard=false",
         "--temp-dir", f"{home}/ray", "--block"],
        env=_clean_env(home, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token),
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 90
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline and head.poll() is None, "ray start --head did not come up"
                time.sleep(0.5)
        address = f"127.0.0.1:{port}"

        sweep = [sys.executable, "-m", "sb3_latentswarm.cli", "sweep", "--preset", "smoke", "--seeds", "1",
                 "--output", str(tmp_path / "sweep"), "--address", address]
        missing = subprocess.run(sweep, env=_clean_env(home), capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert missing.returncode == 2
        assert missing.stderr.strip().splitlines() == [
            f"sb3-latentswarm sweep: error: --address {address}: token: the cluster asks for a Ray auth token and none "
            "is set here; copy the head's token (`ray get-auth-token` there) into RAY_AUTH_TOKEN or ~/.ray/auth_token "
            "here, or restart the cluster with RAY_AUTH_MODE=disabled on a private network"
        ]
        assert not (tmp_path / "sweep").exists()

        connect = ("import ray; from sb3_latentswarm.experiments import check_cluster; "
                   f"check_cluster({address!r}); ray.init(address={address!r}); print(ray.cluster_resources()['CPU'])")
        wrong = subprocess.run([sys.executable, "-c", connect], env=_clean_env(home, RAY_AUTH_TOKEN="f" * 32),
                               capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert wrong.returncode == 1 and "token: the cluster refuses this machine's Ray auth token" in wrong.stderr
        right = subprocess.run([sys.executable, "-c", connect], env=_clean_env(home, RAY_AUTH_TOKEN=token),
                               capture_output=True, text=True, timeout=300, cwd=ROOT)
        assert right.returncode == 0, right.stderr[-2000:]
        assert right.stdout.strip().splitlines()[-1] == "1.0"  # joined in token mode, without RAY_AUTH_MODE set
    finally:
        os.killpg(head.pid, signal.SIGKILL)  # the head and the processes it started (its own session)
        head.wait()
        shutil.rmtree(home, ignore_errors=True)
