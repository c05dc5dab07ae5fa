"""UAVs as processes: the simulator in this process, each UAV in its own, exchanging datagrams over UDP on 127.0.0.1.

Regenerates the table "UAVs as processes" of ``docs/deploy.md``. Loads a saved ``LatentSwarmPPO`` (default: the
committed ``coordination`` model that ``examples/demo.py`` evaluates), exports its per-UAV step to ONNX under
``--out``, starts one process per UAV (each loads the ONNX file on its own, or with ``--runtime torch`` the saved
model), and flies ``--episodes`` held-out episodes: each step the simulator draws the links with the env's link model,
relays only the messages those links deliver, and waits ``--deadline`` seconds for every UAV's action and message; a
late reply is lost (the UAV hovers that step, its peers hear nothing from it). ``--kill-uav I --kill-step T`` kills
UAV I's process before step T of the first episode: the others fly on and the summary names the lost UAV.
Then ``evaluate`` flies the same seeds in one batched process with the same action mode, for comparison, and the
table (CSV + markdown) and the latencies (each UAV's ONNX step, the simulator's round trip) go to ``--out``.

    python examples/deploy_processes.py                                  # 5 held-out episodes, sampled actions
    python examples/deploy_processes.py --episodes 1 --kill-uav 1 --kill-step 20
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "docs" / "results" / "coordination_round2" / "trials" / "proposed-seed0" / "model.zip"


def option(default, help: str):  # noqa: A002 - argparse's name
    """A field of :class:`Args` with the help text that ``--help`` shows."""
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class Args:
    model: str = option(str(MODEL), "a saved LatentSwarmPPO (default: the committed coordination model)")
    episodes: int = option(5, "held-out episodes")
    seed: int = option(1_000_000, "episode k uses env seed (and action-noise seed) seed + k")
    deterministic: bool = option(False, "mean actions (default: sampled, the paper's protocol)")
    runtime: str = option("onnx", "what each UAV process loads: 'onnx' (the exported file, no torch) or 'torch'")
    deadline: float = option(1.0, "seconds a step waits for the UAVs' replies (the control step dt is 1 s)")
    lost_after: int = option(3, "deadline misses in a row after which a UAV is lost (not waited for)")
    port: int = option(0, "the simulator's UDP port on 127.0.0.1 (0: a free one)")
    uav_port: int = option(0, "UAV i binds uav_port + i (0: free ones)")
    kill_uav: int = option(-1, "kill this UAV's process during the first episode (-1: none)")
    kill_step: int = option(10, "... before this step")
    out: str = option(str(ROOT / "runs" / "deploy_processes"), "folder of the ONNX file and the tables")


def parse_args() -> Args:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for spec in dataclasses.fields(Args):
        name = "--" + spec.name.replace("_", "-")
        if spec.type == "bool":
            parser.add_argument(name, action="store_true", help=spec.metadata["help"])
        else:
            kind = {"int": int, "float": float}.get(str(spec.type), str)
            parser.add_argument(name, type=kind, default=spec.default, help=f"{spec.metadata['help']} (default: %(default)s)")
    args = Args(**vars(parser.parse_args()))
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.runtime not in ("onnx", "torch"):
        parser.error(f"--runtime must be 'onnx' or 'torch', got {args.runtime!r}")
    if not Path(args.model).is_file():
        parser.error(f"--model: no file at {args.model}")
    return args


def milliseconds(values: np.ndarray) -> str:
    """``median (p99)`` of seconds, in ms, NaN (missed steps) left out."""
    values = values[np.isfinite(values)] * 1e3
    return f"{np.median(values):.2f} ms ({np.percentile(values, 99):.2f} ms)" if values.size else "n/a"


def main() -> None:
    args = parse_args()  # before the imports: --help answers without loading torch
    import pandas as pd

    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.agent import export_onnx
    from sb3_latentswarm.agent.processes import ProcessSwarm, Simulator
    from sb3_latentswarm.evaluation import evaluate, to_markdown
    from sb3_latentswarm.evaluation.conditions import condition_config

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = LatentSwarmPPO.load(args.model, device="cpu")
    config = condition_config(model.swarm_config, "proposed", model.swarm_config.p_fail)
    uav_model = args.model
    if args.runtime == "onnx":
        uav_model = str(out / "uav.onnx")
        check = export_onnx(model, uav_model)
        print(f"exported {uav_model} ({check.size_bytes / 1e6:.2f} MB, onnxruntime vs torch {check.max_abs_error:.1e})")
    seeds = [args.seed + k for k in range(args.episodes)]
    mode = "mean" if args.deterministic else "sampled"
    print(f"{config.n_agents} UAV processes ({args.runtime}), "
          f"{args.episodes} episode{'s' if args.episodes > 1 else ''}, seeds {seeds[0]}..{seeds[-1]}, "
          f"{mode} actions, deadline {args.deadline:g} s")
    with ProcessSwarm(uav_model, config.n_agents, port=args.port, uav_port=args.uav_port) as swarm:
        print(f"simulator on 127.0.0.1:{swarm.port}, UAVs on {[address[1] for address in swarm.addresses if address]}")
        simulator = Simulator(swarm, config, deadline=args.deadline, lost_after=args.lost_after)
        records = []
        for k, seed in enumerate(seeds):
            kill = (args.kill_uav, args.kill_step) if k == 0 and args.kill_uav >= 0 else None
            records.append(simulator.fly(seed, args.deterministic, kill_at=kill))
            print(f"episode {seed}: {json.dumps({key: records[-1].summary[key] for key in ('coverage', 'collisions', 'deadline_misses', 'lost', 'killed')})}")  # noqa: E501
    batched = evaluate(model, "proposed", n_episodes=args.episodes, seed=args.seed, deterministic=args.deterministic)

    table = pd.DataFrame({
        "seed": seeds,
        "coverage (processes) %": [100.0 * r.summary["coverage"] for r in records],
        "coverage (evaluate) %": batched["coverage"].to_numpy(),
        "collisions (processes)": [r.summary["collisions"] for r in records],
        "collisions (evaluate)": batched["collisions"].to_numpy(),
        "deadline misses": [sum(r.summary["deadline_misses"].values()) for r in records],
        "lost UAVs {uav: step}": [str(r.summary["lost"]) for r in records],
    })
    compute = np.concatenate([r.compute_s.ravel() for r in records])
    round_trip = np.concatenate([r.round_trip_s.ravel() for r in records])
    step = np.concatenate([r.step_s for r in records])
    latency = pd.DataFrame({
        "what": [f"one UAV's {args.runtime} step (in its process)", "UAV round trip (datagram out, reply in)",
                 f"simulator step exchange ({config.n_agents} UAVs)"],
        "median (p99)": [milliseconds(compute), milliseconds(round_trip), milliseconds(step)],
        "samples": [int(np.isfinite(compute).sum()), int(np.isfinite(round_trip).sum()), step.size],
    })
    table.to_csv(out / "episodes.csv", index=False)
    latency.to_csv(out / "latency.csv", index=False)
    text = f"{to_markdown(table)}\n\n{to_markdown(latency)}\n"
    (out / "deploy_processes.md").write_text(text)
    print(f"\n{text}\nwritten to {out}")


if __name__ == "__main__":
    main()
