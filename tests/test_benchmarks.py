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
    result = update_time.main(["--device", "cpu", "--preset", "smoke", "--updates", "1", "--json", str(path)])
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
    assert written["preset"] == "smoke" and written["device"] == "cpu" and written["updates"] == 1
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
    assert train["by_op"].get("aten::_local_scalar_dense", 0) >= 4  # at least one loss .item() per minibatch
    assert syncs["per_update"] == train["count"] + rollout["count"]
    assert train["aten_ops_per_minibatch"] > 100 and rollout["aten_ops_per_step"] > 10


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
