"""Issue 35's "show it first" check on MPE2 simple_spread: does communication matter in this setting?

The same learner (LatentSwarmPPO through the adapter) is trained with every link up (``outage`` links at p_f = 0) and
without links (``link_mode="none"``: no message ever arrives), a few seeds each, then evaluated on held-out episodes
(seeds 10_000 + k, sampled actions). The check passes when the learner with links is ahead by >= 10 % of the return
range (the best condition's mean return minus the untrained policy's). Regenerates
``docs/results/simple_spread_comm_check/`` (``per_run/*.json``, ``results.csv`` and ``run.md``):

    nice -n 19 python examples/simple_spread_comm_check.py --conditions links --seeds 0 1 2 &
    nice -n 19 python examples/simple_spread_comm_check.py --conditions no_links --seeds 0 1 2 &
    wait; python examples/simple_spread_comm_check.py --report-only

The longer budget (``longer_budget/``): ``--timesteps 200000 --seeds 3`` (then 4 5) with
``--output docs/results/simple_spread_comm_check/longer_budget``. MAPPO's MPE settings at 3M agent-steps
(``budget_3m/``): ``--timesteps 3000000 --seeds 0 --n-envs 32 --n-epochs 10 --learning-rate 7e-4``; the harder setting
(``n5_one_landmark/``): the same with ``--n-agents 5 --neighbors 1``. The report describes the setting each folder's
runs recorded.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

CONDITIONS: dict[str, dict[str, Any]] = {
    "links": dict(link_model="outage", p_fail=0.0),
    "no_links": dict(link_mode="none"),
}
"""The two learners' link models, as ``LinkSpec`` fields."""


@dataclasses.dataclass
class Args:
    conditions: list[str] = dataclasses.field(default_factory=lambda: list(CONDITIONS))
    """Which learners to train (keys of :data:`CONDITIONS`)."""
    seeds: list[int] = dataclasses.field(default_factory=lambda: [0, 1, 2])
    """Training seeds."""
    timesteps: int = 90_000
    """Agent-steps of training per run."""
    n_agents: int = 3
    """N (agents and landmarks)."""
    neighbors: int = 1
    """``num_agent_neighbors`` = ``num_landmark_neighbors``: how many other agents and landmarks an agent sees."""
    max_cycles: int = 25
    """Episode length."""
    n_envs: int = 8
    """Env copies."""
    n_epochs: int = 4
    """PPO epochs per rollout."""
    learning_rate: float = 3e-4
    """Adam's learning rate."""
    eval_episodes: int = 32
    """Held-out evaluation episodes per run."""
    output: str = "docs/results/simple_spread_comm_check"
    """Where ``per_run/``, ``results.csv`` and ``run.md`` go."""
    report_only: bool = False
    """Only aggregate the runs already in ``output/per_run``."""


def env_factory(args: Args, condition: str):
    from mpe2 import simple_spread_v3

    from sb3_latentswarm.envs import LinkSpec, make_adapted_vec_env  # here, so that --help answers without torch
    from sb3_latentswarm.envs.mpe import mpe_positions, simple_spread_metrics

    def make_env():
        return simple_spread_v3.parallel_env(N=args.n_agents, continuous_actions=True, max_cycles=args.max_cycles,
                                             num_agent_neighbors=args.neighbors, num_landmark_neighbors=args.neighbors)

    def make(n_envs: int, seed: int):
        return make_adapted_vec_env(make_env, n_envs, link_model=LinkSpec(**CONDITIONS[condition]), position_fn=mpe_positions,
                                    metrics_fn=simple_spread_metrics, seed=seed)

    return make


def train_and_evaluate(args: Args, condition: str, seed: int) -> dict:
    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.evaluation.adapted import evaluate_adapted

    make = env_factory(args, condition)
    env = make(args.n_envs, seed)
    steps = 2 * args.max_cycles
    model = LatentSwarmPPO(
        "LatentSwarmPolicy", env, n_steps=steps, chunk_length=args.max_cycles,
        batch_size=steps * args.n_envs * args.n_agents // 2, n_epochs=args.n_epochs, learning_rate=args.learning_rate,
        normalize_value=True,
        policy_kwargs=dict(latent_dim=32, predictor_hidden=64, decoder_hidden=64, critic_hidden=64, actor_hidden=32,
                           log_std_init=-0.5),
        seed=seed,
    )
    untrained = evaluate_adapted(model, make, n_episodes=args.eval_episodes, seed=10_000)
    start = time.process_time()
    model.learn(args.timesteps)
    trained = evaluate_adapted(model, make, n_episodes=args.eval_episodes, seed=10_000)
    return {"condition": condition, "seed": seed, "timesteps": args.timesteps, "cpu_s": time.process_time() - start,
            "setting": dataclasses.asdict(args) | {"conditions": None, "seeds": None},
            "untrained": untrained, "trained": trained}


def _setting(args: Args, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The setting the runs were trained in: their recorded ``setting`` (older runs have none: then ``args``)."""
    recorded = [{k: v for k, v in r["setting"].items() if k not in ("conditions", "seeds", "output", "report_only")}
                for r in runs if "setting" in r]
    if recorded and any(other != recorded[0] for other in recorded):
        raise ValueError(f"{args.output}/per_run holds runs of different settings: {recorded}")
    return recorded[0] if recorded else dataclasses.asdict(args)


def report(args: Args) -> str:
    """Writes ``results.csv`` and ``run.md`` from ``per_run/*.json`` (the setting as the runs recorded it)."""
    from sb3_latentswarm.utils.atomic import atomic_path

    runs_dir = Path(args.output) / "per_run"
    runs = [json.loads(p.read_text()) for p in sorted(runs_dir.glob("*.json"))]
    if not runs:
        raise ValueError(f"{runs_dir} holds no runs: train some first (without --report-only)")
    setting = _setting(args, runs)
    rows = [{"condition": r["condition"], "seed": r["seed"], "timesteps": r["timesteps"], "cpu_s": round(r["cpu_s"]),
             "return": r["trained"]["return"],
             "landmarks_covered": r["trained"]["sum_landmarks_covered"] / r["trained"]["length"],
             "final_landmarks_covered": r["trained"].get("final_landmarks_covered", float("nan")),
             "collisions": r["trained"]["sum_collisions"], "untrained_return": r["untrained"]["return"]} for r in runs]
    header = list(rows[0])
    csv = "\n".join([",".join(header)] + [",".join(str(row[k]) for k in header) for row in rows]) + "\n"
    with atomic_path(Path(args.output) / "results.csv") as path:
        path.write_text(csv)
    means = {}
    lines = ["| learner | seeds | return (mean +- sd over seeds) | landmarks covered (mean over steps) "
             "| landmarks covered at the end | collisions per episode |",
             "|---|---|---|---|---|---|"]
    for condition in CONDITIONS:
        mine = [row for row in rows if row["condition"] == condition]
        if not mine:
            continue
        ret = np.array([row["return"] for row in mine])
        means[condition] = ret.mean()
        covered = np.mean([row["landmarks_covered"] for row in mine])
        final = np.mean([row["final_landmarks_covered"] for row in mine])
        collisions = np.mean([row["collisions"] for row in mine])
        lines.append(f"| {condition} | {len(mine)} | {ret.mean():.2f} +- {ret.std():.2f} | {covered:.3f} | {final:.3f} "
                     f"| {collisions:.2f} |")
    untrained = float(np.mean([row["untrained_return"] for row in rows]))
    lines.append(f"| untrained policy | {len(rows)} | {untrained:.2f} | | | |")
    text = ["# simple_spread communication check (issue 35, \"show it first\")\n",
            f"MPE2 `simple_spread_v3`, N = {setting['n_agents']}, continuous actions, `num_agent_neighbors` = "
            f"`num_landmark_neighbors` = {setting['neighbors']}, {setting['max_cycles']} steps per episode. Each "
            f"learner: LatentSwarmPPO through `make_adapted_vec_env`, {rows[0]['timesteps']:,} agent-steps, "
            f"{setting['n_envs']} env copies, {setting['n_epochs']} epochs, learning rate {setting['learning_rate']:g}, "
            f"one CPU thread; evaluated on {setting['eval_episodes']} held-out episodes (seeds 10,000 + k) with "
            "sampled actions. Return: the mean agent return of an episode.\n", "\n".join(lines) + "\n"]
    if len(means) == 2:
        best = max(means.values())
        span = best - untrained
        gap = means["links"] - means["no_links"]
        share = gap / span if span > 0 else float("nan")
        verdict = "passes" if share >= 0.10 else "misses"
        direction = " (the learner without links is ahead)" if share <= -0.10 else ""
        text.append(f"Return range (best learner - untrained): {span:.2f}. links - no_links: {gap:+.2f}, "
                    f"{100 * share:+.1f} % of the range: the check **{verdict}** the bar (links ahead by >= 10 % of "
                    f"the range){direction}.\n")
    text.append("Command: `python examples/simple_spread_comm_check.py` (see its docstring); per-run JSON in `per_run/`.\n")
    notes = Path(args.output) / "notes.md"  # the hand-written reading of the numbers, kept across regenerations
    if notes.exists():
        text.append(notes.read_text())
    body = "\n".join(text)
    with atomic_path(Path(args.output) / "run.md") as path:
        path.write_text(body)
    return body


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    for field in dataclasses.fields(Args):
        if field.name in ("conditions", "seeds"):
            continue
        if field.type == "bool":
            parser.add_argument(f"--{field.name.replace('_', '-')}", action="store_true")
        else:
            parser.add_argument(f"--{field.name.replace('_', '-')}", type=type(field.default), default=field.default)
    args = Args(**vars(parser.parse_args(argv)))
    runs_dir = Path(args.output) / "per_run"
    runs_dir.mkdir(parents=True, exist_ok=True)
    if not args.report_only:
        for condition in args.conditions:
            for seed in args.seeds:
                result = train_and_evaluate(args, condition, seed)
                path = runs_dir / f"{condition}_seed{seed}.json"
                path.write_text(json.dumps(result, indent=1) + "\n")
                print(f"{condition} seed {seed}: return {result['trained']['return']:.2f} "
                      f"(untrained {result['untrained']['return']:.2f}), {result['cpu_s']:.0f} s CPU", flush=True)
    if os.environ.get("SKIP_REPORT") != "1":
        print(report(args))


if __name__ == "__main__":
    main()
