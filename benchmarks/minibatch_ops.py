"""Cost of one ``LatentSwarmPPO`` training minibatch (forward + backward + optimizer step) of a preset's model.

A rollout of exactly ``--minibatches`` of the preset's minibatches is collected once (the preset's env, latent size,
chunk length and minibatch size; fewer env copies and a shorter rollout so that it fits), then ``model.train()`` runs
with one epoch, i.e. ``--minibatches`` minibatches per call. Per minibatch (the call's total divided by the number of
minibatches, so the once-per-update work of ``train`` is shared out):

* ``aten ops``: aten operators dispatched, forward and backward and optimizer (a ``TorchDispatchMode`` counter);
* ``syncs``: host syncs with the GPU's semantics (``benchmarks/_syncs.py``): reads of a tensor's value by the host
  (``.item()``, ``float()``, ``bool()``, ``int()``, ``.tolist()``, ``.cpu()``, ``.numpy()``) and data-dependent
  shapes, each a device synchronization on a GPU. ``--sites`` lists where they happen. Reads inside ``torch.optim``
  are not counted: Adam's step counters live on the host (``capturable=False``), reading them is no device sync;
* ``CPU s``: per-thread CPU seconds (``time.thread_time``) of the training call, median over ``--repeats`` calls;
* ``recomp``: of these, the recomputation of the old log-probabilities that ``train`` does first under autocast
  (``LatentSwarmPPO.recompute_old_log_probs``, timed alone): once per update, i.e. shared by ``n_epochs`` epochs of
  minibatches in training, where this benchmark runs one epoch;
* ``replay``: the largest difference between the log-probabilities recomputed by ``evaluate_sequences`` for the
  rollout's actions and the old log-probabilities ``train`` uses (PPO's ratio is exactly 1 before the first step when
  it is 0): the rollout's own, or under autocast those ``LatentSwarmPPO.recompute_old_log_probs`` put in their place;
  ``rollout``: the same against the rollout's own log-probabilities.

Variants (``--autocast none bf16``; without ``--autocast`` the preset's own setting) are built in the same process
and timed in alternation. ``--compare REV`` measures
the package of git revision ``REV`` (exported to a temporary folder with ``git archive``) against the working tree,
alternating one subprocess each per ``--rounds`` round, and prints the old/new ratio.

    python benchmarks/minibatch_ops.py --preset coordination --autocast none bf16
    python benchmarks/minibatch_ops.py --preset paper --autocast none bf16 --repeats 3
    python benchmarks/minibatch_ops.py --preset paper --compare main --rounds 2 --repeats 2
"""

from __future__ import annotations

import argparse
import collections
import inspect
import json
import math
import pathlib
import statistics
import sys
import time
from typing import Any

from sb3_latentswarm.presets import PRESETS, get_preset


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="coordination", choices=sorted(PRESETS))
    parser.add_argument("--autocast", nargs="+", default=["preset"], choices=["preset", "none", "bf16"],
                        help="variants: the preset's setting (default), float32, bf16")
    parser.add_argument("--minibatches", type=int, default=2, help="minibatches per train() call (one epoch)")
    parser.add_argument("--repeats", type=int, default=3, help="timed train() calls per variant (median)")
    parser.add_argument("--compare", metavar="REV", help="git revision whose package is measured against the work tree")
    parser.add_argument("--rounds", type=int, default=2, help="with --compare: alternating old/new subprocess rounds")
    parser.add_argument("--sites", action="store_true", help="list the host syncs by call site")
    parser.add_argument("--json", action="store_true", help="print the rows as one JSON line (used by --compare)")
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import torch as th  # noqa: E402
from torch.utils._python_dispatch import TorchDispatchMode  # noqa: E402

from sb3_latentswarm import LatentSwarmPPO, make_vec_env  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))  # the shared helper, also when loaded by path (tests)
from _compare import alternate  # noqa: E402
from _syncs import SyncCounter  # noqa: E402

PRESET = "preset"
"""The ``--autocast`` variant that keeps the preset's own setting."""


class OpCounter(TorchDispatchMode):
    """Counts the aten operators dispatched while active (forward, autograd's backward and the optimizer)."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: collections.Counter[str] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # noqa: ANN001 - torch's protocol
        self.ops[str(func.overloadpacket)] += 1
        return func(*args, **(kwargs or {}))


def build(
    preset_name: str, minibatches: int, autocast: str | None = PRESET, seed: int = 0, device: str = "cpu"
) -> LatentSwarmPPO:
    """A model of the preset with a collected rollout of ``minibatches`` minibatches, ready for ``train()``.

    :param autocast: ``LatentSwarmPPO``'s ``autocast``, or :data:`PRESET` for the preset's own setting
    :param device: the torch device of the model (``benchmarks/gpu_check.py`` builds on ``cuda``)
    """
    from stable_baselines3.common.logger import configure

    preset = get_preset(preset_name)
    kwargs: dict[str, Any] = dict(preset.algo_kwargs)
    n_agents, chunk = preset.config.n_agents, kwargs["chunk_length"]
    sequences = max(1, kwargs["batch_size"] // (n_agents * chunk)) * minibatches
    n_envs = max(d for d in range(1, min(8, sequences) + 1) if sequences % d == 0)
    kwargs.update(n_steps=sequences // n_envs * chunk, n_epochs=1, target_kl=None)
    if autocast != PRESET:  # (older packages, measured by --compare, have no autocast argument)
        kwargs["autocast"] = autocast
    env = make_vec_env(n_envs, config=preset.config, seed=seed)
    model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=seed, device=device, **kwargs)
    model.set_logger(configure(None, []))
    _, callback = model._setup_learn(model.n_steps * model.n_envs, callback=None)
    callback.on_training_start(locals(), globals())
    model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=model.n_steps)
    model.rollout_error = replay_error(model)
    if recomputes(model):
        model.recompute_old_log_probs()  # what train() does first under autocast
    model.replay_error = replay_error(model)
    model.train()  # warm-up: moves the rollout to tensors once, allocates the optimizer's state
    return model


def recomputes(model: LatentSwarmPPO) -> bool:
    """Whether ``train()`` first recomputes the old log-probabilities (under autocast; older packages never do)."""
    return getattr(model, "autocast", None) is not None and hasattr(model, "recompute_old_log_probs")


def replay_error(model: LatentSwarmPPO) -> float:
    """The largest |replayed - stored| log-probability over the rollout's minibatches (each shuffled by ``get``)."""
    with th.no_grad():
        return max(
            float((model.policy.evaluate_sequences(b.observations, b.actions, b.latent_state, b.episode_starts).log_prob
                   - b.old_log_prob).abs().max())
            for b in model.rollout_buffer.get(model.batch_size)
        )


def measure(preset_name: str, autocasts: list[str | None], minibatches: int, repeats: int) -> list[dict[str, Any]]:
    """Ops, syncs and CPU seconds per minibatch for each autocast variant, timed in alternation."""
    models = {name: build(preset_name, minibatches, name) for name in autocasts}
    rows = {}
    for name, model in models.items():
        with OpCounter() as ops:
            model.train()
        with SyncCounter(model.device) as syncs:
            model.train()
        rows[name] = {"ops": ops.ops, "syncs": syncs.sites, "cpu": [], "recompute": []}
    for _ in range(repeats):
        for name, model in models.items():
            start = time.thread_time()
            model.train()
            rows[name]["cpu"].append(time.thread_time() - start)
            if recomputes(model):  # train()'s first step, timed alone
                start = time.thread_time()
                model.recompute_old_log_probs()
                rows[name]["recompute"].append(time.thread_time() - start)
    model = next(iter(models.values()))
    result: list[dict[str, Any]] = []
    for name, row in rows.items():
        result.append(
            {
                "preset": preset_name,
                "latent_dim": model.policy.latent_dim,
                "batch_size": model.batch_size,
                "autocast": getattr(models[name], "autocast", None) or "none",  # the preset's own when not asked
                "ops": sum(row["ops"].values()) / minibatches,
                "syncs": sum(row["syncs"].values()) / minibatches,
                "cpu_s": statistics.median(row["cpu"]) / minibatches,
                "recompute_s": statistics.median(row["recompute"]) / minibatches if row["recompute"] else 0.0,
                "replay": models[name].replay_error,
                "rollout": models[name].rollout_error,
                "sync_sites": dict(row["syncs"]),
                "top_ops": dict(row["ops"].most_common(8)),
            }
        )
    return result


def print_table(rows: list[dict[str, Any]], label: str = "", sites: bool = False) -> None:
    header = ("code", 8), ("preset", 13), ("d", 4), ("batch", 6), ("autocast", 8), ("aten ops", 9), ("syncs", 6), ("CPU s", 7)
    print(" ".join(f"{name:>{width}}" for name, width in (*header, ("recomp", 7), ("replay", 8), ("rollout", 8))))
    for row in rows:
        print(
            f"{label or row.get('code', 'new'):>8} {row['preset']:>13} {row['latent_dim']:>4} {row['batch_size']:>6} "
            f"{row['autocast']:>8} {row['ops']:>9.0f} {row['syncs']:>6.1f} {row['cpu_s']:>7.3f}"
            f" {row.get('recompute_s', 0.0):>7.3f} {row['replay']:>8.1e} "
            f"{row.get('rollout', math.nan):>8.1e}"
        )
        if sites:
            for site, count in sorted(row["sync_sites"].items(), key=lambda item: -item[1]):
                print(f"{'':>12} {count:>4} x {site}")


def compare(args: argparse.Namespace) -> None:
    """Old (``args.compare``) and new (working tree) code in alternating subprocesses; the ratio of CPU s."""
    arguments = ["--preset", args.preset, "--json", "--minibatches", str(args.minibatches), "--repeats", str(args.repeats)]
    runs = alternate(__file__, arguments, args.compare, args.rounds)
    results = {code: [run.result[0] for run in code_runs] for code, code_runs in runs.items()}
    rows = []
    for code, runs in results.items():
        row = dict(runs[0], code=code, cpu_s=statistics.median(r["cpu_s"] for r in runs),
                   recompute_s=statistics.median(r.get("recompute_s", 0.0) for r in runs))
        rows.append(row)
    print_table(rows, sites=args.sites)
    old, new = rows[0]["cpu_s"], rows[1]["cpu_s"]
    print(f"old {args.compare} / new CPU s per minibatch: {old / new:.2f}x ({args.rounds} alternating rounds)")
    if rows[0]["recompute_s"] or rows[1]["recompute_s"]:  # once per update: shared by the preset's epochs in training
        default_epochs = inspect.signature(LatentSwarmPPO.__init__).parameters["n_epochs"].default
        n_epochs = get_preset(args.preset).algo_kwargs.get("n_epochs", default_epochs)
        old_epoch, new_epoch = (row["cpu_s"] - row["recompute_s"] * (1 - 1 / n_epochs) for row in rows)
        print(f"with the recomputation shared by the preset's {n_epochs} epochs: {old_epoch / new_epoch:.2f}x")


def main() -> None:
    parser = build_parser()
    args = parser.parse_args()
    th.set_num_threads(1)
    if args.compare:
        compare(args)
        return
    autocasts = [{"preset": PRESET, "none": None}.get(name, name) for name in args.autocast]
    rows = measure(args.preset, autocasts, args.minibatches, args.repeats)
    if args.json:
        print(json.dumps(rows))
        return
    print(f"torch {th.__version__}, 1 thread; per minibatch: ops and syncs counted, CPU s the median of {args.repeats}")
    print_table(rows, sites=args.sites)
    if len(rows) > 1 and all(math.isfinite(r["cpu_s"]) for r in rows):
        print(f"{rows[0]['autocast']} / {rows[1]['autocast']} CPU s: {rows[0]['cpu_s'] / rows[1]['cpu_s']:.2f}x")


if __name__ == "__main__":
    main()
