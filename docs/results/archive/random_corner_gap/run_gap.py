"""The scripted coordination gap with the launch corner drawn per episode (see run.md); run from the repository root."""
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
from coordination_gap import coverage_table, to_markdown

from sb3_latentswarm.presets import get_preset

base = get_preset("coordination").config
for n_agents, region in ((5, "random_corner"), (3, "random_corner"), (5, "corner")):
    config = base.replace(n_agents=n_agents, start_region=region)
    t = time.process_time()
    table = coverage_table(config, [40, 60, 80], 20, 10_000)
    print(f"N={n_agents} start_region={region} (20 episodes per cell, seeds 10000+, {time.process_time()-t:.0f} s CPU)")
    print(to_markdown(table, [40, 60, 80]), flush=True)
