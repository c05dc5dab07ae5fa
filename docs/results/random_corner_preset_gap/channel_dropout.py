"""How often a UAV of the random_corner preset is cut off under candidate channels (see run.md); run from the repository
root. The frontier explorer (coordinated, map sharing over live links), 100 episodes per channel, seeds 10000+, T = 48."""
from sb3_latentswarm.baselines import COORDINATED_PLANNERS
from sb3_latentswarm.evaluation import evaluate
from sb3_latentswarm.presets import get_preset

base = get_preset("random_corner").config
print("| p_f | outages | coverage (%) | dropout share | mean dropout run (steps) | link-up rate |")
print("|---|---|---|---|---|---|")
for p_fail, mean_outage in ((0.3, 1), (0.3, 10), (0.3, 25), (0.5, 25), (0.6, 25), (0.5, 50)):
    if mean_outage == 1:
        config = base.replace(p_fail=p_fail, outage_model="bernoulli")
    else:
        config = base.replace(p_fail=p_fail, outage_model="gilbert_elliott", mean_outage_steps=mean_outage)
    df = evaluate(COORDINATED_PLANNERS["frontier"](config), "proposed", None, 100, 10_000, config)
    m = df[["coverage", "dropout_share", "dropout_run_mean", "link_up_rate"]].mean()
    outages = "Bernoulli" if mean_outage == 1 else f"Gilbert-Elliott, mean {mean_outage}"
    print(f"| {p_fail} | {outages} | {m['coverage']:.1f} | {m['dropout_share']:.3f} | {m['dropout_run_mean']:.2f} | "
          f"{m['link_up_rate']:.3f} |")
