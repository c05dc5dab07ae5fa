"""What the message predictor and the memory do when every link is down (a test the paper does not run).

Under the paper's ``no_predictor`` and ``no_memory`` ablations at p_f = 0.3, only the agent-steps in dropout change.
Here every link fails (p_f = 1, the same as the ``no_comm`` condition), so every step of every UAV uses the
substitute message: the prediction (``proposed``), a zero vector (``no_predictor``), or the prediction made with the
memory zeroed (``no_memory``). Both ways of acting, mean and sampled, on the same episode seeds. Writes
``sustained_dropout.csv`` (per episode), ``sustained_dropout.md`` and ``run.md`` into ``--output``.

    python examples/sustained_dropout.py --model docs/results/fast_1800_updates/model.zip --preset fast \\
        --output docs/results/archive/fast_1800_updates_sustained_dropout

(that model left the tree after commit 206f0d5: ``git checkout 206f0d5 -- docs/results/fast_1800_updates/model.zip``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from sb3_latentswarm.presets import PRESETS, get_preset

SUBSTITUTES = {"proposed": "prediction", "no_predictor": "zero vector", "no_memory": "prediction, memory zeroed"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", required=True, help="saved LatentSwarmPPO")
    parser.add_argument("--preset", default="fast", choices=sorted(PRESETS), help="the preset the model trained on")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="episode k uses env (and action-noise) seed seed + k")
    parser.add_argument("--output", required=True, help="result folder")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: the package default, one)")
    args = parser.parse_args()  # before the imports: --help and bad arguments answer without loading torch
    import pandas as pd
    import torch as th

    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.evaluation import evaluate, summarize, to_markdown
    from sb3_latentswarm.experiments.run_record import git_commit, write_run_record

    if not Path(args.model).exists():
        parser.error(f"--model: no file at {args.model}")
    if args.threads:
        th.set_num_threads(args.threads)
    commit = git_commit()  # the code that runs, before anything is written
    config = get_preset(args.preset).config
    model = LatentSwarmPPO.load(args.model, device="cpu")
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    frames = []
    for actions, deterministic in (("mean", True), ("sampled", False)):
        for condition, substitute in SUBSTITUTES.items():
            frame = evaluate(
                model,
                condition,
                p_fail=1.0,
                n_episodes=args.episodes,
                seed=args.seed,
                config=config,
                deterministic=deterministic,
            )
            frames.append(frame.assign(actions=actions, substitute=substitute))
    episodes = pd.concat(frames, ignore_index=True)
    episodes.to_csv(output / "sustained_dropout.csv", index=False)
    table = to_markdown(summarize(episodes, by=["actions", "substitute"]))
    (output / "sustained_dropout.md").write_text(table + "\n")
    facts = [
        f"model: `{args.model}` ({model.num_timesteps:,} agent-steps of training)",
        f"evaluation: p_f = 1 (no message ever arrives), {args.episodes} episodes per row, env seeds "
        f"{args.seed}..{args.seed + args.episodes - 1}; the substitute message is what every UAV uses at every step",
        f"wall time: {time.perf_counter() - start:.0f} s",
    ]
    write_run_record(output, f"Sustained dropout: preset `{args.preset}`", commit, facts, [table])


if __name__ == "__main__":
    main()
