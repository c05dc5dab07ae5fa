"""Held-out coverage of the time-to-coverage models: the `proposed` condition at the `coordination` channel, 100
episodes from seed 1,000,000 (never a training episode), sampled actions (the paper's protocol) and mean actions on
the same episodes; the protocol of ../actor_choice/ (whose squashed models are the old settings' seeds 0-2).

    python docs/results/coordination_time_to_coverage/held_out.py LABEL=MODEL ... > held_out.md
"""
import sys

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.evaluation import HELD_OUT_SEED, evaluate
from sb3_latentswarm.presets import get_preset

config = get_preset("coordination").config
print("| model | coverage % sampled | coverage % mean | collisions sampled | collisions mean |")
print("|---|---|---|---|---|")
for label, path in (arg.split("=", 1) for arg in sys.argv[1:]):
    model = LatentSwarmPPO.load(path, device="cpu")
    cells = [evaluate(model, "proposed", n_episodes=100, seed=HELD_OUT_SEED, config=config, deterministic=d)
             for d in (False, True)]
    print(f"| {label} | {cells[0]['coverage'].mean():.2f} | {cells[1]['coverage'].mean():.2f} | "
          f"{cells[0]['collisions'].mean():.2f} | {cells[1]['collisions'].mean():.2f} |", flush=True)
