"""How much a scenario rewards coordination: coverage of coordinated planners against message-free heuristics.

Regenerates the scripted-gap table of ``docs/env.md`` ("A scenario that needs coordination"). Every planner of
:data:`~sb3_latentswarm.baselines.COORDINATED_PLANNERS` and :data:`~sb3_latentswarm.baselines.MESSAGE_FREE_PLANNERS`
runs ``--episodes`` episodes of the preset's env (its channel, p_f and start region) on held-out seeds (``--seed``
onwards, far from the training seeds 0 to n_envs - 1) at each horizon T of ``--horizons``; ``initial_energy`` follows
T so that b_0 / kappa = T, as in the presets. The frontier explorer also runs without links (``no_comm``): then it is
message-free too. The last rows give the gap, best coordinated minus best message-free, in coverage points.

    python benchmarks/coordination_gap.py --preset coordination --horizons 60 80 100 120 --episodes 50
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pandas as pd

from sb3_latentswarm.baselines import COORDINATED_PLANNERS, MESSAGE_FREE_PLANNERS
from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.presets import PRESETS, get_preset


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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="coordination", choices=sorted(PRESETS))
    parser.add_argument("--horizons", type=int, nargs="+", default=[60, 80, 100, 120])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=10_000, help="first held-out episode seed")
    args = parser.parse_args()
    preset = get_preset(args.preset)
    table = coverage_table(preset.config, args.horizons, args.episodes, args.seed)
    c = preset.config
    print(
        f"preset {preset.name}: {c.grid_width}x{c.grid_height} cells of {c.cell_size:g} m, N={c.n_agents}, "
        f"v_max={c.v_max:g} m/s, start_region={c.start_region!r} ({c.start_region_size:g} m), p_fail={c.p_fail:g}, "
        f"outage_model={c.outage_model!r}; {args.episodes} episodes per cell, seeds {args.seed}+; coverage in % (mean ± std)"
    )
    print(to_markdown(table, args.horizons))


if __name__ == "__main__":
    main()
