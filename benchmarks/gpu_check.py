"""GPU readiness in one command: the tests that touch the device, then a preset's training minibatch and rollout step
timed eager and with CUDA graphs (``torch.compile(mode="reduce-overhead")``), each checked against eager first; one
table, also written as Markdown, CSV and JSON under ``--output``.

On a CUDA machine (planned to finish within 10 minutes on one H100/H200-class GPU; ``--budget`` caps it):

    python benchmarks/gpu_check.py --output runs/gpu_check

On a machine without CUDA it runs a CI-safe mode: it says which CUDA parts it skips and why, and times the eager
training minibatch and rollout step on the CPU at a tiny size (``--preset smoke`` unless another is given), so that
the script itself is exercised (``tests/test_benchmarks.py`` runs it so).

Rows:

* ``device tests``: ``pytest -q -m "not slow"`` on :data:`DEVICE_TESTS` in a subprocess. Their models use SB3's
  default ``device="auto"``, i.e. the GPU when there is one (tests that pass ``device="cpu"`` stay on the CPU).
* ``train minibatch``: one training minibatch as ``LatentSwarmPPO.train`` runs it (the joint loss of
  ``_minibatch_losses`` weighted by ``_loss_weights``, backward, gradient clipping, Adam step), on the first
  minibatch of a collected rollout. Variants: ``eager``; ``loss graph``: the loss function under
  ``torch.compile(mode="reduce-overhead")`` (forward and backward captured as CUDA graphs).
* ``rollout step``: one policy step of the rollout (``policy(obs, state, episode_starts, deterministic=True)`` under
  ``no_grad``, the actions copied to the host); variants ``eager`` and ``step graph`` (the step under
  ``torch.compile(mode="reduce-overhead")``).
* ``update (estimate)``: minibatches per update x the training minibatch + ``n_steps`` x the rollout step, eager and
  with the fastest correct variant of each (the env's time is not in it).

Correctness comes first: a compiled variant's loss and gradients (training), or actions, values, log-probabilities
and new latent state (rollout), on the same parameters and inputs, after the CUDA graph is recorded (third call),
must match eager within :data:`TOLERANCE` (relative: loss |a - b| <= tol * max(1, |a|); gradients ||a - b|| <= tol *
||a|| over all parameters together; rollout outputs max |a - b| <= tol * max(1, max |a|)); otherwise the row says
FAILED, the difference and the tolerance, and is not timed. A variant that raises or passes its time limit is FAILED
with the reason. Each variant runs in a subprocess of its own on CUDA (a compilation that hangs costs only its row);
eager and the variant are timed in alternation in that process (median of ``--repeats`` calls, wall seconds with
``torch.cuda.synchronize`` around each; on a CPU this thread's CPU seconds). ``--compile-on-cpu`` runs the compiled
variants on a CPU too (inductor without CUDA graphs), to check their code and their agreement with eager where no
GPU is at hand.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

DEVICE_TESTS = (
    "tests/test_latent_ppo.py",
    "tests/test_latent_ppo_hotpath.py",
    "tests/test_agent.py",
    "tests/test_safe_loading.py",
)
"""Test files whose models run on the default device (SB3's ``auto``: the GPU when there is one)."""
TOLERANCE = {"float32": 1e-3, "bf16": 3e-2}
"""Relative tolerance of a compiled variant against eager, by the preset's precision (see the module docstring)."""
VARIANTS = {
    "train": ("eager", "loss graph"),
    "rollout": ("eager", "step graph"),
}
"""Measured variants of each phase; all but ``eager`` need CUDA."""
ORDER = (("train", "eager"), ("rollout", "eager"), ("rollout", "step graph"), ("train", "loss graph"))
"""The order the rows run in: eager first, then the compiled variants from the quickest compilation to the slowest
(what passes ``--budget`` is SKIPPED)."""
COLUMNS = ("check", "variant", "device", "preset", "status", "ms", "x_eager", "setup_s", "max_diff", "tolerance", "note")
"""Columns of the table (``ms``: median milliseconds per call; ``x_eager``: eager's time / this one's, same process)."""
REPO = Path(__file__).resolve().parents[1]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="auto", help="auto (cuda when available, else the CI-safe CPU mode), cuda, cpu")
    parser.add_argument("--preset", default=None, help="preset measured (default: paper on CUDA, smoke on CPU)")
    parser.add_argument("--output", default="runs/gpu_check", help="folder for table.md, table.csv and results.json")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per variant (median; default 5)")
    parser.add_argument("--minibatches", type=int, default=2, help="rollout size, in the preset's minibatches (default 2)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=float, default=570.0, help="seconds for the whole check (default 570)")
    parser.add_argument("--test-timeout", type=float, default=180.0, help="seconds for the device tests (default 180)")
    parser.add_argument("--variant-timeout", type=float, default=150.0, help="seconds per measured variant (default 150)")
    parser.add_argument("--no-tests", action="store_true", help="skip the device tests")
    parser.add_argument("--in-process", action="store_true", help="measure in this process, not one subprocess per variant")
    parser.add_argument("--compile-on-cpu", action="store_true",
                        help="without CUDA, also run the compiled variants on the CPU (torch.compile without CUDA "
                             "graphs; minutes of compiling): checks their code and correctness, not CUDA graphs")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)  # PHASE:VARIANT, one JSON row on stdout
    return parser


if __name__ == "__main__":  # --help and argument errors answer here, before the imports below load torch
    build_parser().parse_args()

import torch as th  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared helpers, also when loaded by path (tests)


# ---------------------------------------------------------------------------------------------------- measuring
def _sync(device: th.device) -> None:
    if device.type == "cuda":
        th.cuda.synchronize(device)


def _mark_step(variant: str) -> None:
    """A new iteration for CUDA-graph trees: the previous replay's outputs may be overwritten."""
    if variant != "eager" and hasattr(th, "compiler") and hasattr(th.compiler, "cudagraph_mark_step_begin"):
        th.compiler.cudagraph_mark_step_begin()


def _relative(reference: th.Tensor, other: th.Tensor) -> float:
    if reference.numel() == 0:  # a zero-width state field (e.g. the delay-aware inputs of a policy without them)
        return 0.0
    return float((reference.float() - other.float()).abs().max() / max(1.0, float(reference.float().abs().max())))


def _precision(model: Any) -> str:
    return "bf16" if getattr(model, "autocast", None) == "bf16" else "float32"


def _timed(calls: dict[str, Any], repeats: int, device: th.device) -> dict[str, list[float]]:
    """Each callable ``repeats`` times, in alternation; seconds per call: wall seconds on a GPU, this thread's CPU
    seconds on a CPU (a shared CPU's wall clock counts other processes' time slices)."""
    clock = time.perf_counter if device.type == "cuda" else time.thread_time
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            _sync(device)
            start = clock()
            call()
            _sync(device)
            times[name].append(clock() - start)
    return times


def _eager_random() -> None:
    """Compiled code draws the same random numbers as eager (inductor's ``fallback_random``): the entropy estimate of
    a squashed Gaussian samples, and the comparison with eager must see the same samples."""
    import torch._inductor.config as inductor_config

    inductor_config.fallback_random = True


def _train_functions(model: Any, variant: str) -> tuple[Any, Any]:
    """(eager loss function, the variant's loss function) of one minibatch: ``LatentSwarmPPO.train``'s joint loss."""
    try:
        from sb3_latentswarm.latent_ppo.latent_ppo import LOSS_TERMS
    except ImportError:  # another layout
        LOSS_TERMS = tuple(model._loss_weights())  # noqa: N806
    weights = model._loss_weights()
    clip_range = model.clip_range(1.0)
    clip_range_vf = None if model.clip_range_vf is None else model.clip_range_vf(1.0)

    def loss_fn(batch: Any) -> th.Tensor:
        losses = model._minibatch_losses(batch, clip_range, clip_range_vf)
        return sum(weights[term] * losses[term] for term in LOSS_TERMS)

    if variant == "eager":
        return loss_fn, loss_fn
    if variant == "loss graph":
        _eager_random()
        return loss_fn, th.compile(loss_fn, mode="reduce-overhead")
    raise ValueError(f"unknown training variant {variant!r}")


def measure_train(model: Any, variant: str, repeats: int) -> dict[str, Any]:
    """Loss and gradients of ``variant`` against eager on the same parameters, then both timed (with Adam steps)."""
    policy, device = model.policy, model.device
    batch = next(iter(model.rollout_buffer.get(model.batch_size)))
    policy.set_training_mode(True)
    eager, compiled = _train_functions(model, variant)
    parameters = [p for p in policy.parameters() if p.requires_grad]

    def gradients(fn: Any) -> tuple[th.Tensor, list[th.Tensor]]:
        _mark_step(variant)
        policy.optimizer.zero_grad(set_to_none=True)
        th.manual_seed(0)  # the entropy of a squashed Gaussian is estimated from samples: the same samples each call
        loss = fn(batch)
        loss.backward()
        return loss.detach().clone(), [th.zeros_like(p) if p.grad is None else p.grad.detach().clone() for p in parameters]

    reference_loss, reference_grads = gradients(eager)
    start = time.perf_counter()
    for _ in range(3):  # compile, record the CUDA graph, replay it
        loss, grads = gradients(compiled)
    setup_s = time.perf_counter() - start
    tol = TOLERANCE[_precision(model)]
    loss_diff = float((loss - reference_loss).abs()) / max(1.0, float(reference_loss.abs()))
    # over all parameters together: a tensor with a tiny gradient would make a per-tensor ratio noisy under bf16
    grad_error = sum(float((g.float() - r.float()).norm()) ** 2 for g, r in zip(grads, reference_grads)) ** 0.5
    grad_norm = sum(float(r.float().norm()) ** 2 for r in reference_grads) ** 0.5
    grad_diff = grad_error / grad_norm if grad_norm > 0 else grad_error
    max_diff = max(loss_diff, grad_diff)
    row = {"max_diff": max_diff, "tolerance": tol, "setup_s": setup_s,
           "note": f"loss {float(reference_loss):.6g}: rel. diff {loss_diff:.1e}, gradients {grad_diff:.1e}"}
    if not (max_diff <= tol):  # also a NaN
        return {**row, "status": "FAILED", "note": f"differs from eager beyond the tolerance ({row['note']})"}

    def step(fn: Any, mark: str) -> None:
        _mark_step(mark)
        policy.optimizer.zero_grad(set_to_none=True)
        fn(batch).backward()
        th.nn.utils.clip_grad_norm_(parameters, model.max_grad_norm)
        policy.optimizer.step()

    calls = {"variant": lambda: step(compiled, variant)}
    if variant != "eager":
        calls["eager"] = lambda: step(eager, "eager")
    times = _timed(calls, repeats, device)
    return {**row, "status": "ok", "seconds": times["variant"], "eager_seconds": times.get("eager", times["variant"])}


def measure_rollout(model: Any, variant: str, repeats: int) -> dict[str, Any]:
    """One rollout step of ``variant`` against eager on the same inputs, then both timed."""
    from stable_baselines3.common.utils import obs_as_tensor

    policy, device = model.policy, model.device
    policy.set_training_mode(False)
    obs = obs_as_tensor(model._last_obs, device)
    state = model._last_latent_state
    starts = th.as_tensor(model._last_episode_starts, dtype=th.float32, device=device)

    def policy_step(obs: Any, state: Any, starts: th.Tensor) -> Any:
        return policy(obs, state, starts, deterministic=True)

    if variant not in VARIANTS["rollout"]:
        raise ValueError(f"unknown rollout variant {variant!r}")
    if variant != "eager":
        _eager_random()
    compiled = policy_step if variant == "eager" else th.compile(policy_step, mode="reduce-overhead")

    def outputs(fn: Any, mark: str) -> list[th.Tensor]:
        _mark_step(mark)
        th.manual_seed(0)
        with th.no_grad():
            actions, values, log_probs, new_state = fn(obs, state, starts)
        return [t.detach().clone() for t in (actions, values, log_probs, *new_state)]

    reference = outputs(policy_step, "eager")
    start = time.perf_counter()
    for _ in range(3):
        result = outputs(compiled, variant)
    setup_s = time.perf_counter() - start
    tol = TOLERANCE[_precision(model)]
    diff = max(_relative(r, o) for r, o in zip(reference, result))
    row = {"max_diff": diff, "tolerance": tol, "setup_s": setup_s,
           "note": "actions, values, log-probabilities, latent state; actions copied to the host"}
    if not (diff <= tol):
        return {**row, "status": "FAILED", "note": f"differs from eager beyond the tolerance (max rel. diff {diff:.1e})"}

    def step(fn: Any, mark: str) -> None:
        _mark_step(mark)
        with th.no_grad():
            actions = fn(obs, state, starts)[0]
        actions.cpu()  # as collect_rollouts does: one sync per step

    calls = {"variant": lambda: step(compiled, variant)}
    if variant != "eager":
        calls["eager"] = lambda: step(policy_step, "eager")
    times = _timed(calls, repeats, device)
    return {**row, "status": "ok", "seconds": times["variant"], "eager_seconds": times.get("eager", times["variant"])}


def measure(phase: str, variant: str, preset: str, device: str, repeats: int, minibatches: int, seed: int) -> dict[str, Any]:
    """One row: build the preset's model with a collected rollout on ``device``, then measure ``phase``/``variant``."""
    from minibatch_ops import build

    th.manual_seed(seed)
    start = time.perf_counter()
    model = build(preset, minibatches, seed=seed, device=device)
    build_s = time.perf_counter() - start
    measured = (measure_train if phase == "train" else measure_rollout)(model, variant, repeats)
    row = {"check": f"{phase} minibatch" if phase == "train" else "rollout step", "variant": variant,
           "device": str(model.device), "preset": preset, **measured, "build_s": build_s,
           "precision": _precision(model), "n_steps": model.n_steps, "n_epochs": model.n_epochs,
           "minibatches_per_update": None}
    if "seconds" in measured:
        row["ms"] = 1e3 * statistics.median(measured["seconds"])
        row["x_eager"] = statistics.median(measured["eager_seconds"]) / statistics.median(measured["seconds"])
        row["eager_ms"] = 1e3 * statistics.median(measured["eager_seconds"])
    return row


# ---------------------------------------------------------------------------------------------------- orchestration
def cuda_skip_reason() -> str | None:
    """Why CUDA cannot be used here, or ``None`` when it can."""
    if th.version.cuda is None:
        return f"this torch build has no CUDA (torch {th.__version__})"
    if not th.cuda.is_available():
        return f"no CUDA device is visible (torch {th.__version__}, CUDA {th.version.cuda})"
    return None


def run_tests(tests: tuple[str, ...], timeout: float) -> dict[str, Any]:
    command = [sys.executable, "-m", "pytest", "-q", "-m", "not slow", "-p", "no:cacheprovider", *tests]
    start = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"status": "FAILED", "note": f"did not finish within {timeout:.0f} s", "setup_s": timeout}
    seconds = time.perf_counter() - start
    lines = [line for line in done.stdout.strip().splitlines() if line.strip()]
    summary = lines[-1].strip("= ") if lines else done.stderr.strip()[-200:]
    status = "ok" if done.returncode == 0 else "FAILED"
    failed = [line for line in lines if line.startswith("FAILED")][:3]
    return {"status": status, "note": "; ".join([summary, *failed]), "setup_s": seconds}


def run_worker(phase: str, variant: str, args: argparse.Namespace, preset: str, device: str, timeout: float) -> dict[str, Any]:
    """:func:`measure` in a fresh subprocess (its compilation and CUDA graphs die with it); the row or a FAILED row."""
    command = [sys.executable, __file__, "--worker", f"{phase}:{variant}", "--preset", preset, "--device", device,
               "--repeats", str(args.repeats), "--minibatches", str(args.minibatches), "--seed", str(args.seed)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False, env=env)
    except subprocess.TimeoutExpired:
        return {"status": "FAILED", "note": f"did not finish within {timeout:.0f} s (compilation included)"}
    lines = done.stdout.strip().splitlines()
    try:
        return json.loads(lines[-1])
    except (IndexError, json.JSONDecodeError):
        error = done.stderr.strip().splitlines()
        return {"status": "FAILED", "note": f"exit {done.returncode}: {error[-1] if error else 'no output'}"}


def safe_measure(phase: str, variant: str, args: argparse.Namespace, preset: str, device: str) -> dict[str, Any]:
    try:
        return measure(phase, variant, preset, device, args.repeats, args.minibatches, args.seed)
    except Exception as error:  # noqa: BLE001 - a row reports any failure
        return {"status": "FAILED", "note": f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"}


def estimate(rows: list[dict[str, Any]], preset_name: str, device: str) -> dict[str, Any]:
    """The update estimate: minibatches per update x training minibatch + n_steps x rollout step, eager and best."""
    from sb3_latentswarm.presets import get_preset

    preset = get_preset(preset_name)
    kwargs = preset.algo_kwargs
    n_agents = preset.config.n_agents
    n_steps = kwargs.get("n_steps", 2048)
    per_update = n_steps * preset.n_envs * n_agents
    n_epochs = kwargs.get("n_epochs", 10)
    minibatches = n_epochs * -(-per_update // kwargs.get("batch_size", 64))

    def best(check: str, eager: bool) -> float | None:
        times = [r["eager_ms"] if eager else r["ms"] for r in rows if r["check"] == check and r["status"] == "ok"
                 and "ms" in r]
        return min(times) if times else None

    figures = {}
    for name, eager in (("eager", True), ("best", False)):
        train, rollout = best("train minibatch", eager), best("rollout step", eager)
        figures[name] = None if train is None or rollout is None else (minibatches * train + n_steps * rollout) / 1e3
    row: dict[str, Any] = {"check": "update (estimate)", "variant": "best / eager", "device": device,
                           "preset": preset_name}
    if figures["eager"] is None or figures["best"] is None:
        return {**row, "status": "SKIPPED", "note": "needs an ok training minibatch and rollout step"}
    hours = preset.updates * figures["best"] / 3600 if preset.updates else float("nan")
    return {**row, "status": "ok", "ms": 1e3 * figures["best"], "x_eager": figures["eager"] / figures["best"],
            "note": f"{minibatches} minibatches + {n_steps} steps per update, env excluded: eager "
                    f"{figures['eager']:.2f} s, best {figures['best']:.2f} s; {preset.updates} updates ~ {hours:.2f} h"}


def _fmt(value: Any, column: str = "") -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        if column in ("max_diff", "tolerance"):
            return f"{value:.1e}"
        if column == "x_eager":
            return f"{value:.2f}"
        return f"{value:,.1f}" if abs(value) >= 100 else f"{value:.3g}"
    return str(value)


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for row in rows:
        lines.append("| " + " | ".join(_fmt(row.get(column), column).replace("|", "/") for column in COLUMNS) + " |")
    return "\n".join(lines)


def write_outputs(folder: Path, rows: list[dict[str, Any]], header: dict[str, Any]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "table.md").write_text("\n".join(header["lines"]) + "\n\n" + table(rows) + "\n")
    with open(folder / "table.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    public = [{k: v for k, v in row.items() if k not in ("seconds", "eager_seconds")} for row in rows]
    (folder / "results.json").write_text(json.dumps({**header, "rows": public}, indent=1) + "\n")


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.minibatches < 1 or args.budget <= 0:
        parser.error("--repeats and --minibatches must be >= 1 and --budget > 0")
    th.set_num_threads(1)
    if args.worker:
        phase, variant = args.worker.split(":", 1)
        row = safe_measure(phase, variant, args, args.preset, args.device)
        print(json.dumps({k: v for k, v in row.items()}))
        return [row]

    start = time.perf_counter()
    reason = cuda_skip_reason()
    if args.device == "auto":
        device = "cpu" if reason else "cuda"
    else:
        device = args.device
    if device.startswith("cuda") and reason:
        parser.error(f"--device {device}: {reason}")
    cuda = device.startswith("cuda")
    preset = args.preset or ("paper" if cuda else "smoke")
    lines = [f"gpu_check: torch {th.__version__}, Python {platform.python_version()}, device {device}"
             + (f" ({th.cuda.get_device_name(device)})" if cuda else f" ({platform.processor() or 'cpu'})")
             + f", preset {preset}, {args.repeats} timed calls per variant"]
    if not cuda:
        lines.append(f"CPU-only mode (CI-safe): CUDA skipped because {reason or 'the CPU was asked for'}. Skipped: the "
                     f"device tests (on the CPU they are part of the normal test suite) and the CUDA-graph variants "
                     f"(torch.compile mode='reduce-overhead' records CUDA graphs: it needs a CUDA device). Timed: "
                     f"eager on the CPU, preset {preset}. On a GPU machine run: python benchmarks/gpu_check.py "
                     f"--output runs/gpu_check")
    for line in lines:
        print(line, flush=True)

    def left() -> float:
        return args.budget - (time.perf_counter() - start)

    rows: list[dict[str, Any]] = []
    tests_row = {"check": "device tests", "variant": "pytest", "device": device, "preset": ""}
    if not cuda:
        rows.append({**tests_row, "status": "SKIPPED", "note": "no CUDA: these tests run on the CPU in the normal suite"})
    elif args.no_tests:
        rows.append({**tests_row, "status": "SKIPPED", "note": "--no-tests"})
    else:
        rows.append({**tests_row, **run_tests(DEVICE_TESTS, min(args.test_timeout, max(left() - 300, 1)))})
    print(f"{rows[-1]['check']}: {rows[-1]['status']} {rows[-1].get('note', '')}", flush=True)
    for phase, variant in ORDER:
        base = {"check": "train minibatch" if phase == "train" else "rollout step", "variant": variant,
                "device": device, "preset": preset}
        if variant != "eager" and not cuda and not args.compile_on_cpu:
            row = {**base, "status": "SKIPPED", "note": "needs CUDA (CUDA graphs)"}
        elif left() < 10:
            row = {**base, "status": "SKIPPED", "note": f"the --budget of {args.budget:.0f} s is spent"}
        elif cuda and not args.in_process:
            row = {**base, **run_worker(phase, variant, args, preset, device, min(args.variant_timeout, left()))}
        else:
            row = {**base, **safe_measure(phase, variant, args, preset, device)}
        rows.append(row)
        print(f"{row['check']}, {variant}: {row['status']} {_fmt(row.get('ms'))} ms {row.get('note', '')}", flush=True)
    rows.append(estimate(rows, preset, device))
    lines.append(f"total {time.perf_counter() - start:.0f} s; tolerance: relative, see benchmarks/gpu_check.py")
    print()
    print(table(rows))
    print(lines[-1])
    header = {"lines": lines, "device": device, "preset": preset, "torch": th.__version__,
              "cuda_skipped": None if cuda else reason}
    write_outputs(Path(args.output), rows, header)
    print(f"written: {Path(args.output) / 'table.md'}, table.csv, results.json")
    return rows


if __name__ == "__main__":
    main()
