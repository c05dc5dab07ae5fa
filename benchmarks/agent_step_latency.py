"""Latency of one UAV's step (docs/deploy.md, "Latency"): the exported ONNX step in onnxruntime
(:class:`~sb3_latentswarm.agent.OnnxSwarmAgent`) and the torch agent (:class:`~sb3_latentswarm.agent.LatentSwarmAgent`),
median and 99th percentile of the wall time over ``--steps`` steps of one thread and the median of the thread's CPU time
(the better estimate on a loaded machine), with the bytes of the message each UAV sends.

Models: a saved ``LatentSwarmPPO`` (``--model``, default the weight-only copy of the committed ``coordination``
model) and an untrained policy of the ``paper`` preset's size (d_mu = d_tau = d_rho = 512; trained under bf16
autocast, exported in float32).
Inputs are a fixed observation and two received messages (the step's cost does not depend on their values).

    python benchmarks/agent_step_latency.py
    python benchmarks/agent_step_latency.py --steps 1000 --model tests/data/models/coordination-proposed-seed0.zip
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFAULT_MODEL = "tests/data/models/coordination-proposed-seed0.zip"


@dataclass(frozen=True)
class Args:
    model: str = DEFAULT_MODEL
    """A saved LatentSwarmPPO."""
    steps: int = 1000
    """Timed steps per agent (after 50 warm-up steps)."""


def time_agent(agent, steps: int) -> tuple[float, float, float]:
    """Median and 99th percentile of one step's wall time and median of its thread CPU time, in microseconds."""
    agent.reset(seed=0)
    obs = {"local_obs": np.zeros(agent.spec.local_obs_shape, dtype=np.float32),
           "proprio": np.full(agent.spec.proprio_dim, 0.5, dtype=np.float32)}
    wall, cpu = [], []
    for i in range(50 + steps):
        received = np.stack([agent.message(), agent.message()])
        start, start_cpu = time.perf_counter(), time.thread_time()
        agent.step(obs, received)
        if i >= 50:
            wall.append(time.perf_counter() - start)
            cpu.append(time.thread_time() - start_cpu)
    wall_us, cpu_us = 1e6 * np.asarray(wall), 1e6 * np.asarray(cpu)
    return float(np.median(wall_us)), float(np.percentile(wall_us, 99)), float(np.median(cpu_us))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=Args.model)
    parser.add_argument("--steps", type=int, default=Args.steps)
    args = Args(**vars(parser.parse_args()))

    import torch as th

    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.agent import LatentSwarmAgent, OnnxSwarmAgent, export_onnx
    from sb3_latentswarm.envs import make_vec_env
    from sb3_latentswarm.presets import get_preset

    th.set_num_threads(1)
    paper = get_preset("paper")
    models = {
        Path(args.model).parent.name or args.model: LatentSwarmPPO.load(args.model, device="cpu"),
        "paper-sized (untrained)": LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=paper.config, seed=0),
                                                  policy_kwargs=paper.algo_kwargs["policy_kwargs"], device="cpu",
                                                  autocast=paper.algo_kwargs.get("autocast")),
    }
    print(f"load average before: {os.getloadavg()[0]:.1f}")
    print("| model | d | message bytes (float32 / float16) | ONNX file | ONNX step: wall median (p99), thread CPU median "
          "| torch agent step: wall median (p99), thread CPU median |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name, model in models.items():
            path = Path(folder) / "uav.onnx"
            check = export_onnx(model, path)
            onnx = time_agent(OnnxSwarmAgent(path), args.steps)
            torch_agent = time_agent(LatentSwarmAgent(model), args.steps)
            d = model.policy.message_dim
            print(f"| {name} | {d} | {4 * d} / {2 * d} | {check.size_bytes / 1e6:.2f} MB "
                  f"| {onnx[0]:.0f} us ({onnx[1]:.0f}), {onnx[2]:.0f} us | {torch_agent[0]:.0f} us ({torch_agent[1]:.0f}), "
                  f"{torch_agent[2]:.0f} us |")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
