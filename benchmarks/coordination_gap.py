"""How much a scenario rewards coordination: coverage of coordinated planners against message-free heuristics.

Regenerates the scripted-gap table of ``docs/env.md`` ("A scenario that needs coordination"). Every planner of
:data:`~sb3_latentswarm.baselines.COORDINATED_PLANNERS` and :data:`~sb3_latentswarm.baselines.MESSAGE_FREE_PLANNERS`
runs ``--episodes`` episodes of the preset's env (its channel, p_f and start region) on held-out seeds (``--seed``
onwards, far from the training seeds 0 to n_envs - 1) at each horizon T of ``--horizons``; ``initial_energy`` follows
T so that b_0 / kappa = T, as in the presets. The frontier explorer also runs without links (``no_comm``): then it is
message-free too. The last rows give the gap, best coordinated minus best message-free, in coverage points.
``--set FIELD=VALUE`` replaces ``SwarmConfig`` fields of the preset (as ``sb3-latentswarm --set`` does), so a candidate
scenario can be measured before it becomes a preset; ``--output`` also writes the table (markdown, atomically).

    python benchmarks/coordination_gap.py --preset coordination --horizons 60 80 100 120 --episodes 50
    python benchmarks/coordination_gap.py --preset random_corner --horizons 40 48 60 --episodes 100 \\
        --output docs/results/random_corner_preset_gap/gap.md
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from sb3_latentswarm.cli import parse_overrides
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.presets import PRESETS, get_preset, override_targets
from sb3_latentswarm.utils.atomic import write_text


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="coordination", choices=sorted(PRESETS))
    parser.add_argument("--horizons", type=int, nargs="+", default=[60, 80, 100, 120])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=10_000, help="first held-out episode seed")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="replace a SwarmConfig field of the preset (repeatable), e.g. --set n_agents=5")
    parser.add_argument("--output", default=None, help="also write the header and table to this markdown file")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import pandas as pd  # noqa: E402

from sb3_latentswarm.baselines import COORDINATED_PLANNERS, MESSAGE_FREE_PLANNERS  # noqa: E402
from sb3_latentswarm.evaluation import evaluate  # noqa: E402


@dataclass(frozen=True)
class Entry:
    """One row of the table: a planner, the condition it runs under, and whether its UAVs coordinate."""

    label: str
    planner: str
    condition: str
    coordinated: bool


ENTRIES = (
    *(Entry(f"{name} (coordinated)", name, "proposed", True) for name in COORDINATED_PLANNERS),
    Entry("frontier, no links (message-free)", "frontier", "no_comm", False),
    *(Entry(f"{name} (message-free)", name, "proposed", False) for name in MESSAGE_FREE_PLANNERS),
)


def coverage_table(config: SwarmConfig, horizons: list[int], episodes: int, seed: int) -> pd.DataFrame:
    """Mean and std of the final coverage (%) of every entry at every horizon: columns ``(T, "mean" | "std")``."""
    planners = {**COORDINATED_PLANNERS, **MESSAGE_FREE_PLANNERS}
    records = []
    for horizon in horizons:
        env_config = config.replace(max_steps=horizon, initial_energy=horizon * config.energy_decay)
        for entry in ENTRIES:
            df = evaluate(planners[entry.planner](env_config), entry.condition, None, episodes, seed, env_config)
            records.append((entry.label, horizon, df["coverage"].mean(), df["coverage"].std(ddof=1)))
    table = pd.DataFrame(records, columns=["planner", "T", "mean", "std"])
    return table.pivot(index="planner", columns="T", values=["mean", "std"]).loc[[e.label for e in ENTRIES]]


def to_markdown(table: pd.DataFrame, horizons: list[int]) -> str:
    """The table with ``mean ± std`` cells and the two best-of rows and the gap."""
    coordinated = [e.label for e in ENTRIES if e.coordinated]
    message_free = [e.label for e in ENTRIES if not e.coordinated]
    lines = ["| planner | " + " | ".join(f"T = {t}" for t in horizons) + " |", "|---|" + "---|" * len(horizons)]
    for label in table.index:
        cells = [f"{table.loc[label, ('mean', t)]:.1f} ± {table.loc[label, ('std', t)]:.1f}" for t in horizons]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    best_coordinated = table.loc[coordinated, "mean"].max()
    best_free = table.loc[message_free, "mean"].max()
    lines.append("| best coordinated | " + " | ".join(f"{best_coordinated[t]:.1f}" for t in horizons) + " |")
    lines.append("| best message-free | " + " | ".join(f"{best_free[t]:.1f}" for t in horizons) + " |")
    gap = best_coordinated - best_free
    lines.append("| **gap (points)** | " + " | ".join(f"**{gap[t]:.1f}**" for t in horizons) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    if args.episodes < 2:
        parser.error(f"--episodes must be >= 2 (the table shows a std), got {args.episodes}")
    if min(args.horizons) < 1:
        parser.error(f"--horizons must be >= 1, got {args.horizons}")
    try:
        overrides = parse_overrides(args.set)
        fields = set(override_targets()["SwarmConfig"])
        not_env = sorted(set(overrides) - fields)
        if not_env:
            raise ValueError(f"--set {not_env}: not SwarmConfig fields (this benchmark runs planners, no learner)")
        preset = get_preset(args.preset).with_overrides(**overrides)
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    c = preset.config
    channel = c.outage_model + (f" (mean outage {c.mean_outage_steps:g} steps)" if c.outage_model == "gilbert_elliott" else "")
    header = (
        f"preset {preset.name}{' with ' + ', '.join(args.set) if args.set else ''}: {c.grid_width}x{c.grid_height} cells "
        f"of {c.cell_size:g} m, N={c.n_agents}, v_max={c.v_max:g} m/s, start_region={c.start_region!r} "
        f"({c.start_region_size:g} m), p_fail={c.p_fail:g}, outage_model={channel}; {args.episodes} episodes per cell, "
        f"seeds {args.seed}+; coverage in % (mean ± std)"
    )
    table = to_markdown(coverage_table(c, args.horizons, args.episodes, args.seed), args.horizons)
    print(header)
    print(table)
    if args.output is not None:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        write_text(Path(args.output), f"{header}\n\n{table}\n")


if __name__ == "__main__":
    main()
