"""Actor choice on `coordination`: the std at its bounds, whole action vectors in the box, coverage and collisions
with mean and with sampled actions, on 100 held-out episodes (seeds 1,000,000+), for each model given."""
import json
import sys

import numpy as np

from sb3_latentswarm import LatentSwarmPPO
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.presets import get_preset

EPISODES, SEED = int(sys.argv[1]), 1_000_000
config = get_preset("coordination").config
rows = []
for label, path in (arg.split("=", 1) for arg in sys.argv[2:]):
    model = LatentSwarmPPO.load(path, device="cpu")
    policy = model.policy
    lo, hi = policy.log_std_bounds
    record = {"log_std": [], "raw_mean": []}
    original = policy.action_distribution

    def recording(task_state, original=original):
        dist = original(task_state)
        record["log_std"].append(dist.distribution.scale.log().detach().cpu().numpy().ravel())
        record["raw_mean"].append(dist.distribution.loc.detach().cpu().numpy().reshape(-1, dist.distribution.loc.shape[-1]))
        return dist

    policy.action_distribution = recording
    row = {"model": label, "actor": f"{getattr(policy, 'action_distribution_name', 'gaussian')}/"
           f"{getattr(policy, 'log_std_mapping', 'clamp')}"}
    for mode, deterministic in (("sampled", False), ("mean", True)):
        record["log_std"].clear()
        record["raw_mean"].clear()
        df = evaluate(model, "proposed", n_episodes=EPISODES, seed=SEED, config=config, deterministic=deterministic)
        row[f"coverage_{mode}"] = float(df["coverage"].mean())
        row[f"collisions_{mode}"] = float(df["collisions"].mean())
        if mode == "sampled":
            log_std = np.concatenate(record["log_std"])
            row["std_at_upper_bound"] = float(np.mean(log_std >= hi - 0.01))
            row["std_at_lower_bound"] = float(np.mean(log_std <= lo + 0.01))
            mean = np.concatenate(record["raw_mean"])
            squashed = row["actor"].startswith("squashed")
            inside = np.abs(np.tanh(mean) if squashed else mean) <= 1.0
            row["mean_action_vectors_in_box"] = float(np.all(inside, axis=-1).mean())
            row["mean_action_elements_in_box"] = float(inside.mean())
    row["mean_over_sampled_collisions"] = row["collisions_mean"] / max(row["collisions_sampled"], 1e-9)
    rows.append(row)
    print(json.dumps(row), flush=True)
