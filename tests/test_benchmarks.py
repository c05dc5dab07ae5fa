"""The speed benchmarks run on CPU at tiny sizes, and their machine-readable output keeps its documented format.

``benchmarks/update_time.py`` is the GPU benchmark (``--device cuda``); here it runs on CPU with the ``smoke`` preset.
The thread guard of :mod:`sb3_latentswarm.utils.threads` is tested here too.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
import sys
import warnings
from pathlib import Path

import pytest
import torch as th

from sb3_latentswarm.utils import threads

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def load_benchmark(name: str):
    spec = importlib.util.spec_from_file_location(f"benchmark_{name}", BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def update_time():
    return load_benchmark("update_time")


@pytest.fixture(scope="module")
def smoke_result(update_time, tmp_path_factory):
    path = tmp_path_factory.mktemp("update_time") / "smoke.json"
    # 3 timed updates: per-update figures are their mean, so a one-off pause of the process (0.1 s of a 0.18 s smoke
    # update failed the split check once in a fresh-clone CI) weighs a third as much
    result = update_time.main(["--device", "cpu", "--preset", "smoke", "--updates", "3", "--json", str(path)])
    return result, json.loads(path.read_text())


def test_update_time_json_has_the_documented_fields(update_time, smoke_result):
    result, written = smoke_result
    assert written == json.loads(json.dumps(result))  # the file holds what main returned
    for field in (
        "preset", "device", "torch", "torch_threads", "load_average", "parameters", "agent_steps_per_update",
        "minibatches_per_update", "seconds", "cpu_seconds", "agent_steps_per_second", "budget_hours", "budget_cpu_hours",
        "host_syncs", "peak_memory_bytes", "peak_memory_kind", "train_logs",
    ):
        assert field in written, field
    assert written["preset"] == "smoke" and written["device"] == "cpu" and written["updates"] == 3
    assert set(written["seconds"]) == set(update_time.RANGES) == set(written["cpu_seconds"])
    # smoke: 2 envs x 20 steps x 3 agents = 120 agent-steps, minibatches of 30, one epoch
    assert written["agent_steps_per_update"] == 120
    assert written["minibatches_per_update"] == 4
    assert written["peak_memory_bytes"] > 2**20
    assert "train/loss" in written["train_logs"]


def test_update_time_split_sums_to_the_total(smoke_result):
    result, _ = smoke_result
    for clock in ("seconds", "cpu_seconds"):
        s = result[clock]
        assert all(s[key] >= 0 for key in ("env", "policy", "backward", "optimizer")), s
        assert s["env"] > 0 and s["policy"] > 0 and s["backward"] > 0 and s["optimizer"] > 0
        # the nested ranges lie inside their parents, timed independently of them
        assert s["env"] + s["policy"] <= s["rollout"] * 1.001
        assert s["backward"] + s["optimizer"] <= s["train"] * 1.001
        # rollout + training are the update, but for SB3's bookkeeping in learn (logging, callbacks)
        assert 0.75 * s["update"] <= s["rollout"] + s["train"] <= s["update"] * 1.001, s


def test_update_time_counts_host_syncs(smoke_result):
    syncs = smoke_result[0]["host_syncs"]
    train, rollout = syncs["train"], syncs["rollout"]
    assert train["minibatches"] == 4
    assert syncs["per_update"] == train["count"] + rollout["count"] == sum(train["by_site"].values()) + sum(
        rollout["by_site"].values())
    # the one sync of a minibatch (the finiteness check of the loss) and a few per update for the logs; not Adam's step
    # counters, which the profiler's aten::_local_scalar_dense counts (one per parameter tensor and minibatch)
    assert train["minibatches"] <= train["count"] <= train["minibatches"] + 12, train["by_site"]
    assert any(count == train["minibatches"] for count in train["by_site"].values()), train["by_site"]
    assert not any("optim" in site for site in train["by_site"])
    assert train["profiler_events"]["aten::_local_scalar_dense"] > train["count"] + 4 * 10
    assert rollout["count"] >= 20  # the smoke preset's 20 steps each hand the actions to the host
    assert train["aten_ops_per_minibatch"] > 100 and rollout["aten_ops_per_step"] > 10


def test_sync_counter_counts_device_reads_not_optimizer_counters():
    syncs = load_benchmark("_syncs")
    weight = th.nn.Parameter(th.ones(3))
    optimizer = th.optim.Adam([weight])
    x = th.arange(-2.0, 3.0)
    with syncs.SyncCounter("cpu") as counter:
        for _ in range(3):
            optimizer.zero_grad()
            (weight * x[:3]).sum().backward()
            optimizer.step()  # Adam reads its host-side step counter (.item()) per parameter and step: no sync
        assert counter.count == 0
        x.sum().item()
        bool(x.max() > 0)
        x.cpu().numpy()  # one transfer
        x[x > 0]  # a boolean mask: the host must learn the result's size
        x.nonzero()
        x[1:3] + x.sum()  # no sync: a slice and an op stay on the device
    assert counter.count == 5, counter.sites
    assert {site.split()[-1] for site in counter.sites} == {"item", "__bool__", "cpu", "__getitem__", "nonzero"}
    with syncs.SyncCounter("cuda") as counter:  # on a GPU run a CPU tensor's value is already on the host
        x.sum().item()
        x.cpu()
    assert counter.count == 0


def test_update_time_leaves_torch_as_it_was(update_time, smoke_result):
    assert th.Tensor.backward is update_time._ORIGINAL_BACKWARD
    assert th.nn.utils.clip_grad_norm_ is update_time._ORIGINAL_CLIP


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--updates", "0"], "--updates and --rounds must be >= 1"),
        (["--warmup", "-1"], "--updates and --rounds must be >= 1"),
        (["--device", "tpu"], "--device"),
        (["--device", "cuda"], "CUDA is not available"),
        (["--rounds", "0"], "(got 1, 0, 1, 0)"),
        (["--compare", "no-such-revision"], "--compare no-such-revision: not a commit"),
    ],
)
def test_update_time_refuses_bad_arguments_before_work(update_time, monkeypatch, capsys, argv, message):
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit) as exit_info:
        update_time.main(["--preset", "smoke", *argv])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_update_time_compare_interleaves_old_and_new_packages(update_time, capsys):
    # HEAD's package exported by git archive (old) against the working tree's (new), one subprocess each
    result = update_time.main(["--preset", "smoke", "--compare", "HEAD", "--rounds", "1", "--warmup", "0"])
    out = capsys.readouterr().out
    assert re.search(r"old HEAD / new per update: process CPU s \d+\.\d\dx, wall s \d+\.\d\dx", out), out
    assert "| old | median |" in out and "| new | median |" in out
    assert [(run["code"], run["round"]) for run in result["runs"]] == [("old", 0), ("new", 0)]
    packages = {run["code"]: Path(run["result"]["package"]) for run in result["runs"]}
    assert packages["new"] == BENCHMARKS.parent / "sb3_latentswarm"
    assert packages["old"].name == "sb3_latentswarm" and packages["old"] != packages["new"]
    for run in result["runs"]:
        assert run["result"]["preset"] == "smoke" and run["result"]["host_syncs"] is None  # children: --no-profile
        assert 0 < run["process_cpu_s"] < run["child_cpu_s"] and run["train_cpu_s"] > 0 and run["rollout_cpu_s"] > 0
    assert set(result["ratios"]) == set(update_time.COMPARED)
    assert result["ratios"]["process_cpu_s"] == pytest.approx(
        result["medians"]["old"]["process_cpu_s"] / result["medians"]["new"]["process_cpu_s"])


def test_compare_helper_reads_the_last_json_line_and_reports_failed_runs(tmp_path):
    compare = load_benchmark("_compare")
    assert compare.last_json_line('table\n{"a": 1}\n\n') == {"a": 1}
    with pytest.raises(ValueError, match="printed nothing"):
        compare.last_json_line("\n")
    with pytest.raises(ValueError, match="last line is not JSON"):
        compare.last_json_line("[1]\nnot json")
    failing = tmp_path / "failing.py"
    failing.write_text("import sys\nsys.exit('boom')\n")
    with pytest.raises(RuntimeError, match="exited 1:\nboom"):
        compare.run_once([sys.executable, str(failing)], tmp_path)
    with pytest.raises(ValueError, match="--rounds must be an int in"):
        compare.alternate(failing, [], "HEAD", 0)


@pytest.mark.parametrize("autocast", [None, "bf16"])
def test_train_throughput_compares_both_algorithms_per_hidden_size(capsys, autocast):
    train_throughput = load_benchmark("train_throughput")
    args = argparse.Namespace(
        hidden=[8, 16], n_envs=1, n_steps=8, chunk_length=4, n_epochs=1, blocks=2, updates_per_block=1, autocast=autocast
    )
    try:
        train_throughput.compare_recurrent_ppo(args)
    finally:
        th.set_num_threads(1)
    out = capsys.readouterr().out
    for hidden in (8, 16):
        assert f"| {hidden} | LatentSwarmPPO |" in out and f"| {hidden} | RecurrentPPO |" in out
        assert f"hidden {hidden}: LatentSwarmPPO / RecurrentPPO = " in out
        assert (f"| {hidden} | LatentSwarmPPO (bf16) |" in out) == (autocast == "bf16")
        assert (f"hidden {hidden}: LatentSwarmPPO (bf16) / RecurrentPPO = " in out) == (autocast == "bf16")
    assert "load average" in out and "kernels)" in out


@pytest.fixture
def fresh_warning(monkeypatch):
    monkeypatch.setattr(threads, "_warned", False)
    yield
    th.set_num_threads(1)


def test_set_torch_threads_refuses_less_than_one():
    with pytest.raises(ValueError, match="threads"):
        threads.set_torch_threads(0)
    with pytest.raises(TypeError, match="threads"):
        threads.set_torch_threads(True)


def test_set_torch_threads_warns_once_past_the_available_cores(fresh_warning):
    cores = threads.available_cores()
    with pytest.warns(RuntimeWarning, match=f"{cores + 1} torch threads.*{cores} core"):
        assert threads.set_torch_threads(cores + 1) == cores + 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        threads.set_torch_threads(cores + 2)  # once per process
        threads.set_torch_threads(1)


def test_set_torch_threads_within_the_cores_is_silent(fresh_warning):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert threads.set_torch_threads(1) == 1
    assert not threads._warned


def test_thread_variable_past_the_cores_warns(fresh_warning, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", str(threads.available_cores() + 3))
    before = th.get_num_threads()
    with pytest.warns(RuntimeWarning, match="OMP_NUM_THREADS="):
        assert threads.apply_default_torch_threads() == before  # the user's variable is kept, only warned about


def test_gpu_check_runs_its_cpu_mode_and_says_what_it_skipped(tmp_path, capsys, monkeypatch):
    gpu_check = load_benchmark("gpu_check")
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)  # CI-safe mode also where a GPU is present
    rows = gpu_check.main(["--preset", "smoke", "--repeats", "2", "--minibatches", "1", "--output", str(tmp_path)])
    out = capsys.readouterr().out
    assert "CPU-only mode (CI-safe): CUDA skipped because" in out
    assert "python benchmarks/gpu_check.py --output runs/gpu_check" in out  # the command to run on a GPU
    by_name = {(row["check"], row["variant"]): row for row in rows}
    assert list(by_name) == [("device tests", "pytest"), *((("train minibatch" if phase == "train" else "rollout step"),
                             variant) for phase, variant in gpu_check.ORDER), ("update (estimate)", "best / eager")]
    assert sorted(gpu_check.ORDER) == sorted((p, v) for p, variants in gpu_check.VARIANTS.items() for v in variants)
    for (_check, variant), row in by_name.items():
        if variant in ("pytest", "loss graph", "step graph"):
            assert row["status"] == "SKIPPED" and row["note"], row
        else:
            assert row["status"] == "ok" and row["device"] == "cpu" and row["preset"] == "smoke", row
    for check in ("train minibatch", "rollout step"):  # eager against itself, with the same samples: exact
        row = by_name[(check, "eager")]
        assert row["max_diff"] == 0.0 and row["ms"] > 0 and row["x_eager"] == 1.0
    table = (tmp_path / "table.md").read_text()
    assert table.count("| SKIPPED |") == 3 and table.count("| ok |") == 3
    assert (tmp_path / "table.csv").read_text().splitlines()[0] == ",".join(gpu_check.COLUMNS)
    written = json.loads((tmp_path / "results.json").read_text())
    assert written["device"] == "cpu" and "CUDA" in written["cuda_skipped"] and len(written["rows"]) == len(rows)


def test_gpu_check_refuses_cuda_without_a_device(capsys, monkeypatch):
    gpu_check = load_benchmark("gpu_check")
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    monkeypatch.setattr(gpu_check.th.version, "cuda", "12.4")
    with pytest.raises(SystemExit):
        gpu_check.main(["--device", "cuda", "--output", "/nonexistent"])
    assert "no CUDA device is visible" in capsys.readouterr().err


def test_allocator_alternates_the_settings_and_reports_medians(monkeypatch, tmp_path):
    allocator = load_benchmark("allocator")
    calls = []

    def fake_child(args, extra):
        calls.append(dict(extra))
        tuned = bool(extra)
        return {"cpu_s": 1.0 if tuned else 1.5, "user_s": 0.9, "sys_s": 0.1 if tuned else 0.6,
                "minor_faults": 10.0 if tuned else 1000.0, "peak_rss_mib": 1030.0 if tuned else 1000.0,
                "end_rss_mib": 900.0}

    monkeypatch.setattr(allocator, "run_child", fake_child)
    summary = allocator.main(["--rounds", "3", "--json", str(tmp_path / "a.json")])
    assert calls == [{}, allocator.TUNED, allocator.TUNED, {}, {}, allocator.TUNED]  # alternating order per round
    assert summary["speedup"] == 1.5 and abs(summary["peak_rss_ratio"] - 1.03) < 1e-9
    assert summary["round_speedups"] == [1.5, 1.5, 1.5]
    assert json.loads((tmp_path / "a.json").read_text())["summary"]["medians"]["tuned"]["minor_faults"] == 10.0


def test_allocator_child_runs_without_the_callers_allocator_variables(monkeypatch):
    allocator = load_benchmark("allocator")
    seen = {}

    def fake_run(command, env, **kwargs):
        seen.update(env)
        return argparse.Namespace(returncode=0, stdout='{"cpu_s": 1}\n', stderr="")

    monkeypatch.setenv("MALLOC_ARENA_MAX", "2")
    monkeypatch.setattr(allocator.subprocess, "run", fake_run)
    args = allocator.build_parser().parse_args([])
    assert allocator.run_child(args, {"MALLOC_TRIM_THRESHOLD_": "5"}) == {"cpu_s": 1}
    assert seen["MALLOC_TRIM_THRESHOLD_"] == "5" and "MALLOC_ARENA_MAX" not in seen and seen["OMP_NUM_THREADS"] == "1"


def test_gpu_check_worker_subprocess_returns_its_row():
    # the path every CUDA row takes (one subprocess per variant), exercised on the CPU
    gpu_check = load_benchmark("gpu_check")
    args = gpu_check.build_parser().parse_args(["--repeats", "1", "--minibatches", "1"])
    row = gpu_check.run_worker("rollout", "eager", args, "smoke", "cpu", timeout=300)
    assert row["status"] == "ok" and row["check"] == "rollout step" and row["max_diff"] == 0.0 and row["ms"] > 0, row
    failed = gpu_check.safe_measure("rollout", "no such variant", args, "smoke", "cpu")  # what a worker prints
    assert failed["status"] == "FAILED" and "unknown rollout variant" in failed["note"]
