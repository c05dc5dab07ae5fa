"""Usage: python docs/results/coordination_sampled_actions/sampled_eval.py docs/results/coordination_sampled_actions

Sampled vs mean actions of the coordination sweep's models on the same 100 held-out episodes (training channel)."""

import json
import sys

import pandas as pd

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.baselines.independent import IndependentRecurrentPPO
from sb3_latentswarm.evaluation import evaluate, to_markdown
from sb3_latentswarm.experiments.trial import trial_preset

sweep = "docs/results/coordination"
spec = json.load(open(f"{sweep}/sweep.json"))
config = trial_preset(spec["preset"], spec["overrides"], {}).config
rows = []
for variant, condition in (("independent", "proposed"), ("no_comm", "no_comm")):
    for seed in range(3):
        path = f"{sweep}/trials/{variant}-seed{seed}/model.zip"
        learner = IndependentRecurrentPPO if variant == "independent" else LatentSwarmPPO
        model = learner.load(path, device="cpu")
        for deterministic in (True, False):
            df = evaluate(model, condition, None, 100, spec["eval_seed"], config, deterministic=deterministic)
            rows.append(
                {
                    "variant": variant,
                    "train_seed": seed,
                    "actions": "mean" if deterministic else "sampled",
                    "coverage": df["coverage"].mean(),
                    "collisions": df["collisions"].mean(),
                    "reached_90": 100 * df["steps_to_90"].notna().mean(),
                }
            )
            print(rows[-1], flush=True)
out = pd.DataFrame(rows)
out.to_csv(sys.argv[1] + "/sampled_actions.csv", index=False)
summary = out.groupby(["variant", "actions"], as_index=False)[["coverage", "collisions", "reached_90"]].mean()
open(sys.argv[1] + "/sampled_actions.md", "w").write(
    to_markdown(out) + "\n\nMeans over the 3 seeds:\n\n" + to_markdown(summary) + "\n"
)
print(summary)
