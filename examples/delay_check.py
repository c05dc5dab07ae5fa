"""Issue 35's delay setting against the loss-only channel at the same delivery rate, on ``coordination``.

Two learners of the ``coordination`` preset (300 updates, its PPO options, its channel: the A2A link of Eq. (1) with
Bernoulli outages at p_f 0.3):

- ``loss_only``: the preset as it is; its trained models are ``docs/results/coordination_time_to_coverage/
  models_2026-12-04/new-s*.zip`` (seeds 0-5, the preset's current options);
- ``delay2``: the same channel, and every message it delivers arrives 2 steps late (``message_delay=2``, fixed,
  ``message_expiry=4``: nothing expires, so the delivery rate is the loss-only channel's), learned by the delay-aware
  policy (``delay_aware=true``: messages pooled as they were sent, their age an input; docs/concepts.md), trained by

      sb3-latentswarm train --preset coordination --set message_delay=2 message_expiry=4 delay_aware=true \\
          --seed S --output runs/delay_check/delay2-seedS

- ``blind``: the delayed channel of ``delay2``, learned by the policy without the age input (``delay_aware`` off:
  messages still pooled as they were sent, their age unknown to it; docs/concepts.md), trained by

      sb3-latentswarm train --preset coordination --set message_delay=2 message_expiry=4 \\
          --seed S --output runs/delay_check/blind-seedS

Each model is evaluated on 100 held-out episodes (env seeds 1,000,000 ..., sampled actions, the paper's protocol) in
the conditions ``proposed``, ``no_predictor`` and ``no_comm``: the ``delay2`` models under their delayed channel, the
``loss_only`` models under the loss-only channel and, as a third row, under the delayed channel they never trained on
(built without delay, they have no sent history and pool the senders' current messages). Writes ``results.csv`` (one
row per model, channel and condition) and ``summary.md`` into ``--output``; rows of the learners not evaluated in this
call (``--learners``) are kept from the existing ``results.csv``, so a learner can be added later::

    python examples/delay_check.py --delay-runs runs/delay_check --seeds 0 1 2
    python examples/delay_check.py --learners blind --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOSS_ONLY_MODELS = ROOT / "docs" / "results" / "coordination_time_to_coverage" / "models_2026-12-04"
DELAY = {"message_delay": 2, "message_delay_model": "fixed", "message_expiry": 4}
"""The delayed channel: every delivered message 2 steps late, none expires (same delivery rate as without delay)."""
CONDITIONS = ("proposed", "no_predictor", "no_comm")
LEARNERS = ("delay2", "blind", "loss_only")
"""The learners in the order of the summary: the delay-aware one, the age-blind one (both trained under the delayed
channel; run folders ``{learner}-seedS``), the loss-only one (the committed models)."""
EVAL_SEED, EVAL_EPISODES = 1_000_000, 100


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--delay-runs", type=Path, default=Path("runs/delay_check"),
                        help="folder holding delay2-seedS/model.zip and blind-seedS/model.zip (default runs/delay_check)")
    parser.add_argument("--learners", nargs="+", choices=LEARNERS, default=list(LEARNERS),
                        help="learners to evaluate (default all); the others' rows are kept from results.csv")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds (default 0 1 2)")
    parser.add_argument("--episodes", type=int, default=EVAL_EPISODES, help="held-out episodes per cell (default 100)")
    parser.add_argument("--output", type=Path, default=ROOT / "docs" / "results" / "coordination_delay_check",
                        help="where results.csv and run.md go")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    return args


def markdown_table(frame) -> str:
    """``frame`` as a markdown table, floats with 2 decimals."""
    cells = [[f"{v:.2f}" if isinstance(v, float) else str(v) for v in row] for row in frame.itertuples(index=False)]
    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * len(frame.columns)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in cells]) + "\n"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    models = {(learner, s): (LOSS_ONLY_MODELS / f"new-s{s}.zip" if learner == "loss_only"
                             else args.delay_runs / f"{learner}-seed{s}" / "model.zip")
              for learner in args.learners for s in args.seeds}
    missing = [str(path) for path in models.values() if not path.is_file()]
    if missing:
        raise SystemExit(f"missing model files: {missing}")

    import pandas as pd  # here, so that --help answers without pandas or torch

    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.evaluation import evaluate
    from sb3_latentswarm.utils.atomic import atomic_path

    rows = []
    for (learner, seed), path in sorted(models.items()):
        model = LatentSwarmPPO.load(path, device="cpu")
        base = model.swarm_config.replace(message_delay=0)
        delayed = base.replace(**DELAY)
        channels = {"delay2": delayed} if learner != "loss_only" else {"loss_only": base, "delay2": delayed}
        for channel, config in channels.items():
            for condition in CONDITIONS:
                start = time.process_time()
                df = evaluate(model, condition, n_episodes=args.episodes, seed=EVAL_SEED, config=config, deterministic=False)
                rows.append(dict(learner=learner, train_seed=seed, channel=channel, condition=condition,
                                 coverage=df["coverage"].mean(), collisions=df["collisions"].mean(),
                                 link_up_rate=df["link_up_rate"].mean(), episodes=len(df)))
                print(f"{learner} seed {seed} under {channel}, {condition}: coverage {rows[-1]['coverage']:.2f} % "
                      f"({time.process_time() - start:.0f} CPU-s)", flush=True)
    results = pd.DataFrame(rows)
    previous = args.output / "results.csv"
    if previous.is_file():  # keep the rows of the learners not evaluated now
        kept = pd.read_csv(previous)
        results = pd.concat([kept[~kept["learner"].isin(args.learners)], results], ignore_index=True)
    order = {learner: i for i, learner in enumerate(LEARNERS)}
    results = results.sort_values(["learner", "train_seed"], key=lambda c: c.map(order) if c.name == "learner" else c,
                                  kind="stable").reset_index(drop=True)
    args.output.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.output / "results.csv") as tmp:
        results.to_csv(tmp, index=False)
    summary = (results.groupby(["learner", "channel", "condition"], sort=False)
               .agg(seeds=("train_seed", "size"), coverage=("coverage", "mean"), coverage_min=("coverage", "min"),
                    coverage_max=("coverage", "max"), collisions=("collisions", "mean"),
                    link_up_rate=("link_up_rate", "mean")).reset_index())
    with atomic_path(args.output / "summary.md") as tmp:
        tmp.write_text(markdown_table(summary))
    print(summary.to_string(index=False))
    print(json.dumps({"learners": args.learners, "seeds": args.seeds, "episodes": args.episodes}))


if __name__ == "__main__":
    main()
