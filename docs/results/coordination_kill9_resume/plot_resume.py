"""The learning curve of a `coordination` run killed with kill -9 and resumed (train --resume), against a run of
another seed that never stopped: progress.csv (one row per update) and the TensorBoard run folder of the resumed run.

    python docs/results/coordination_kill9_resume/plot_resume.py RESUMED_DIR UNINTERRUPTED_DIR OUTPUT_DIR
"""
import sys
from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure
from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

resumed, other, output = (Path(p) for p in sys.argv[1:4])
KILLED_AT, RESUMED_FROM = int(sys.argv[4]), int(sys.argv[5])
rows = pd.read_csv(resumed / "progress.csv")
steps = rows["time/total_timesteps"].astype(int).tolist()
per_update = steps[0]
assert steps == [per_update * (k + 1) for k in range(len(steps))], "progress.csv is not one row per update"
events = [e for path in sorted((resumed / "tb").rglob("events.out.tfevents.*")) for e in EventFileLoader(str(path)).Load()]
tb_steps = sorted({e.step for e in events for v in e.summary.value if v.tag == "rollout/coverage"})
purges = [e.step for e in events if e.HasField("session_log")]
figure = Figure(figsize=(8, 3.6))
axes = figure.subplots(1, 2)
for ax, column, label in ((axes[0], "rollout/coverage", "coverage (training rollouts)"),
                          (axes[1], "rollout/collisions", "collisions per episode (training rollouts)")):
    base = pd.read_csv(other / "progress.csv")
    ax.plot(base["time/total_timesteps"] / 1e6, base[column], color="0.6", lw=1, label="seed 2, never stopped")
    ax.plot(rows["time/total_timesteps"] / 1e6, rows[column], color="C0", lw=1.2, label="seed 1, killed and resumed")
    ax.axvline(KILLED_AT / 1e6, color="C3", ls="--", lw=1, label=f"kill -9 at {KILLED_AT:,} agent-steps")
    ax.set_xlabel("agent-steps (millions)")
    ax.set_title(label, fontsize=9)
axes[0].legend(fontsize=7, loc="lower right")
figure.suptitle("coordination, squashed-Gaussian actor: kill -9 after 13 updates, then train --resume", fontsize=9)
figure.tight_layout()
output.mkdir(parents=True, exist_ok=True)
figure.savefig(output / "resume_learning_curve.png", dpi=110)
summary = (
    f"progress.csv: {len(rows)} rows, one per update, agent-steps {steps[0]:,} .. {steps[-1]:,} with no gap or repeat\n"
    f"TensorBoard: {len(tb_steps)} distinct steps of rollout/coverage ({tb_steps[0]:,} .. {tb_steps[-1]:,}); "
    f"purge events at steps {purges} (what the killed process logged after its last checkpoint at {RESUMED_FROM:,})\n"
)
(output / "summary.txt").write_text(summary)
print(summary)
