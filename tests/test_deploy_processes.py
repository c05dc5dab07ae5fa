"""UAVs as processes (sb3_latentswarm.agent.processes): three UAV processes on 127.0.0.1 fly the in-process episode
exactly, a late reply is lost and the UAV answers again, a killed UAV leaves a finished episode with its dropout
recorded, a taken port is a clear error."""

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_agent import CONFIG, tiny_model

from sb3_latentswarm.agent.wire import HOST, PortInUseError
from sb3_latentswarm.evaluation import HELD_OUT_SEED, evaluate

pytest.importorskip("onnxruntime")

from sb3_latentswarm.agent import OnnxSwarmAgent, export_onnx  # noqa: E402
from sb3_latentswarm.agent.processes import InProcessSwarm, ProcessSwarm, Simulator  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEADLINE = 20.0  # generous: a loaded CI machine must not miss a deadline in the equality test


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture(scope="module")
def onnx_path(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("deploy") / "uav.onnx"
    export_onnx(model, path, n_check_steps=2)
    return str(path)


def in_process(onnx_path):
    return Simulator(InProcessSwarm([OnnxSwarmAgent(onnx_path) for _ in range(CONFIG.n_agents)]), CONFIG)


def test_three_processes_fly_the_in_process_episode(model, onnx_path):
    seeds = [(HELD_OUT_SEED + 7, False), (HELD_OUT_SEED + 8, True)]
    reference = in_process(onnx_path)
    with ProcessSwarm(onnx_path, CONFIG.n_agents) as swarm:
        simulator = Simulator(swarm, CONFIG, deadline=DEADLINE)
        records = [simulator.fly(seed, deterministic) for seed, deterministic in seeds]
        assert all(code is None for code in swarm.exit_codes.values())
    assert all(code == 0 for code in swarm.exit_codes.values())  # STOP: each process exited on its own
    for (seed, deterministic), record in zip(seeds, records):
        expected = reference.fly(seed, deterministic)
        assert not record.missed.any() and record.summary["lost"] == {}
        np.testing.assert_array_equal(record.actions, expected.actions)  # bit for bit
        np.testing.assert_array_equal(record.delivered, expected.delivered)
        assert record.summary == {**expected.summary, "relay_dropout_rate": record.summary["relay_dropout_rate"]}
        assert record.summary["relay_dropout_rate"] == expected.summary["relay_dropout_rate"]
        assert record.summary["length"] == CONFIG.max_steps and record.summary["dropout_rate"] > 0
        assert (record.compute_s > 0).all() and (record.round_trip_s >= record.compute_s).all()
        # and the batched evaluation of the same episode (torch, batch N: actions within 1e-5)
        row = evaluate(model, "proposed", n_episodes=1, seed=seed, deterministic=deterministic, n_envs=1).iloc[0]
        assert row["coverage"] == pytest.approx(100.0 * record.summary["coverage"], abs=1e-9)
        assert row["collisions"] == record.summary["collisions"]


def test_a_killed_uav_is_recorded_and_the_episode_finishes(onnx_path):
    uav, step = 1, 5
    with ProcessSwarm(onnx_path, CONFIG.n_agents) as swarm:
        simulator = Simulator(swarm, CONFIG, deadline=2.0, lost_after=2)
        record = simulator.fly(HELD_OUT_SEED + 7, kill_at=(uav, step))
        assert swarm.exit_codes[uav] == -9
    summary = record.summary
    assert summary["length"] == CONFIG.max_steps  # the others kept flying to the end
    assert summary["killed"] == {uav: step} and summary["lost"] == {uav: step}
    assert summary["deadline_misses"] == {0: 0, 1: CONFIG.max_steps - step, 2: 0}
    assert record.missed[step:, uav].all() and not record.missed[:step].any()
    np.testing.assert_array_equal(record.actions[step:, uav], 0.0)  # hovering
    # its peers see its messages stop: from the step after the kill nothing of it is relayed, links up or not
    assert record.links[step + 1 :, :, uav].any() and not record.delivered[step + 1 :, :, uav].any()
    assert summary["relay_dropout_rate"] > summary["dropout_rate"]


def test_a_taken_port_is_a_clear_error(onnx_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind((HOST, 0))
        port = taken.getsockname()[1]
        with pytest.raises(PortInUseError, match=f"UDP port {port} on 127.0.0.1 is taken"):
            ProcessSwarm(onnx_path, CONFIG.n_agents, port=port)
        with pytest.raises(RuntimeError, match=f"UAV 0's process exited with status 2 .*UDP port {port} .* is taken"):
            ProcessSwarm(onnx_path, CONFIG.n_agents, uav_port=port)


def test_the_example_has_a_help():
    result = subprocess.run([sys.executable, str(ROOT / "examples" / "deploy_processes.py"), "--help"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "--kill-uav" in result.stdout and "--deadline" in result.stdout


@pytest.mark.slow
def test_the_example_flies_a_saved_model_and_loses_a_uav(model, tmp_path):
    model.save(tmp_path / "model.zip")
    command = [sys.executable, str(ROOT / "examples" / "deploy_processes.py"), "--model", str(tmp_path / "model.zip"),
               "--episodes", "2", "--kill-uav", "2", "--kill-step", "3", "--deadline", "2", "--lost-after", "1",
               "--out", str(tmp_path / "out")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    table = (tmp_path / "out" / "episodes.csv").read_text().splitlines()
    assert len(table) == 3 and table[1].endswith(",12,{2: 3}") and table[2].endswith(",15,{2: 0}")  # lost from the start
    assert (tmp_path / "out" / "uav.onnx").is_file() and "simulator step exchange" in result.stdout


def test_a_late_reply_is_lost_and_the_uav_answers_again(onnx_path):
    from sb3_latentswarm.agent.processes import StepInput
    from sb3_latentswarm.envs.batched_core import SwarmBatch

    core = SwarmBatch(CONFIG, 1)
    core.reset(seeds=[HELD_OUT_SEED])
    everyone = {0, 1, 2}
    with ProcessSwarm(onnx_path, CONFIG.n_agents) as swarm:
        nothing = np.zeros((0, swarm.spec.message_dim), np.float32)
        inputs = [StepInput(core.local_obs[0, i], core.proprio[0, i], [], nothing) for i in everyone]
        assert set(swarm.reset(0, HELD_OUT_SEED, True, everyone, DEADLINE)) == everyone
        pid = swarm.procs[1].pid
        os.kill(pid, signal.SIGSTOP)  # UAV 1 stalls past the deadline
        try:
            late = swarm.step(0, 0, inputs, everyone, deadline=0.5)
        finally:
            os.kill(pid, signal.SIGCONT)
        assert set(late) == {0, 2}
        # its reply to step 0 arrives now and is dropped as stale; its reply to step 1 counts
        replies = swarm.step(0, 1, inputs, everyone, DEADLINE)
        assert set(replies) == everyone
    node = in_process(onnx_path).swarm.nodes[1]  # UAV 1 stepped twice (the late step counts in its own state)
    node.reset(HELD_OUT_SEED, 3, True)
    for t in (0, 1):
        action, message, _ = node.step(t, inputs[1].local_obs, inputs[1].proprio, nothing)
    np.testing.assert_array_equal(replies[1].action, action)
    np.testing.assert_array_equal(replies[1].message, message)
