"""The training hot path: host syncs per minibatch, unvalidated Gaussians, ValueNorm without tensor branches, the
GRU equations of the autocast path, and bf16 autocast (validated, saved, and the same in rollouts and replay)."""

import collections
import os
import sys

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import CallbackList
from torch.overrides import TorchFunctionMode

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.latent_ppo.policies import SequenceLinear, gru_cell
from sb3_latentswarm.latent_ppo.recurrence import SequenceGRUCell, gru_update
from sb3_latentswarm.latent_ppo.value_norm import ValueNorm

SMALL = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=7, num_obstacles=5, p_fail=0.5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)
PAPER_SIZED_POLICY = dict(latent_dim=512, predictor_hidden=256, decoder_hidden=256, critic_hidden=256, actor_hidden=64)
SYNC_METHODS = {"item", "__float__", "__bool__", "__int__", "__index__", "tolist", "cpu", "numpy"}


class HostReads(TorchFunctionMode):
    """Counts reads of tensor values by the host outside ``torch.optim`` (Adam's step counters live on the host)."""

    def __init__(self):
        super().__init__()
        self.count = collections.Counter()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        name = getattr(func, "__name__", "")
        if name in SYNC_METHODS:
            filename = sys._getframe(1).f_code.co_filename
            if f"torch{os.sep}optim{os.sep}" not in filename:
                self.count[name] += 1
        return func(*args, **(kwargs or {}))


def collected_model(policy_kwargs=TINY_POLICY, **kwargs):
    params = dict(n_steps=20, chunk_length=5, batch_size=30, n_epochs=2, policy_kwargs=policy_kwargs, seed=0)
    params.update(kwargs)
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(2, config=SMALL, seed=0), **params)
    model.learn(total_timesteps=1, log_interval=None)  # sets up the logger and env, collects one rollout, trains once
    callback = CallbackList([])  # SB3's no-op callback
    callback.init_callback(model)
    model.collect_rollouts(model.env, callback, model.rollout_buffer, model.n_steps)
    return model


def replay_error(model):
    """The largest |log pi| difference between the rollout's stored log-probs and their replay in training."""
    with th.no_grad():
        return max(
            (model.policy.evaluate_sequences(b.observations, b.actions, b.latent_state, b.episode_starts).log_prob
             - b.old_log_prob).abs().max().item()
            for b in model.rollout_buffer.get(model.batch_size)
        )


def test_gru_cell_is_torch_grucell():
    th.manual_seed(0)
    cell = th.nn.GRUCell(20, 16)
    inputs, hidden = th.randn(6, 20, requires_grad=True), th.randn(6, 16, requires_grad=True)
    expected, got = cell(inputs, hidden), gru_cell(inputs, hidden, cell)
    th.testing.assert_close(got, expected, atol=1e-6, rtol=0)
    weights = th.randn(6, 16)
    grads_expected = th.autograd.grad((expected * weights).sum(), [inputs, hidden, *cell.parameters()])
    grads_got = th.autograd.grad((got * weights).sum(), [inputs, hidden, *cell.parameters()])
    for g_expected, g_got in zip(grads_expected, grads_got):
        th.testing.assert_close(g_got, g_expected, atol=1e-6, rtol=0)


def recurrence(weight, bias, added, hidden, deferred, dtype=th.float32):
    """h_{t+1} = tanh(h_t W^T + b + c_t) over T steps, through SequenceLinear; the stacked states, float32."""
    linear = SequenceLinear(weight, bias, dtype, deferred)
    states = []
    for added_t in added.unbind(0):
        hidden = th.tanh(linear(hidden, added_t).float())
        states.append(hidden)
    return th.stack(states)


@pytest.mark.parametrize("dtype", [th.float32, th.bfloat16])
def test_sequence_linear_sums_the_weight_gradient_once_per_sequence(dtype):
    generator = th.Generator().manual_seed(0)
    weight = (th.randn(16, 16, generator=generator) / 4).requires_grad_()
    bias = th.randn(16, generator=generator).requires_grad_()
    added = th.randn(7, 5, 16, generator=generator).requires_grad_()  # (T, B, N)
    hidden = th.randn(5, 16, generator=generator).requires_grad_()
    readout = th.randn(7, 5, 16, generator=generator)
    leaves = [weight, bias, added, hidden]
    results = {}
    for deferred in (True, False):
        states = recurrence(weight, bias, added, hidden, deferred, dtype)
        loss = (states * readout).sum()
        first = th.autograd.grad(loss, leaves, retain_graph=True)
        second = th.autograd.grad(loss, leaves)  # a retained graph's second pass: the per-sequence sums start afresh
        for g_first, g_second in zip(first, second):
            assert th.equal(g_first, g_second)
        results[deferred] = states, first
    (states, grads), (expected_states, expected_grads) = results[True], results[False]
    assert th.equal(states, expected_states)  # the same forward GEMMs
    for got, expected in zip(grads, expected_grads):
        if dtype == th.float32:
            th.testing.assert_close(got, expected, atol=1e-5 * float(expected.abs().max()), rtol=0)
        else:  # bf16: the per-step gradients are summed in bf16 by autograd, once in a float32-accumulating GEMM here
            cosine = th.nn.functional.cosine_similarity(got.flatten().double(), expected.flatten().double(), dim=0)
            assert cosine > 0.999
    with th.no_grad():
        assert th.equal(recurrence(weight, bias, added, hidden, True, dtype), expected_states)


def gru_sequence(cell, inputs, added, hidden, fused, dtype=th.float32):
    """A GRU over T steps: one SequenceGRUCell node per step (fused) or gru_cell's autograd ops; stacked states."""
    states = []
    if fused:
        hidden_linear = SequenceLinear(cell.weight_hh, cell.bias_hh, dtype)
        step = SequenceGRUCell(SequenceLinear(cell.weight_ih, None, dtype), hidden_linear)
    for inputs_t, added_t in zip(inputs.unbind(0), added.unbind(0)):
        if fused:
            hidden = step(inputs_t, added_t, hidden)
        else:
            input_gates = th.addmm(added_t.to(dtype), inputs_t.to(dtype), cell.weight_ih.to(dtype).t())
            hidden_gates = th.addmm(cell.bias_hh.to(dtype), hidden.to(dtype), cell.weight_hh.to(dtype).t())
            hidden = gru_update(input_gates, hidden_gates, hidden)
        states.append(hidden)
    return th.stack(states)


@pytest.mark.parametrize("dtype", [th.float32, th.bfloat16])
def test_the_fused_gru_node_has_autograds_gradients(dtype):
    generator = th.Generator().manual_seed(0)
    cell = th.nn.GRUCell(12, 16)
    inputs = th.randn(6, 5, 12, generator=generator).requires_grad_()  # (T, B, K)
    added = th.randn(6, 5, 48, generator=generator).requires_grad_()  # an observed projection with the bias
    hidden = th.randn(5, 16, generator=generator).requires_grad_()
    readout = th.randn(6, 5, 16, generator=generator)
    leaves = [inputs, added, hidden, cell.weight_ih, cell.weight_hh, cell.bias_hh]
    results = {}
    for fused in (True, False):
        states = gru_sequence(cell, inputs, added, hidden, fused, dtype)
        results[fused] = states, th.autograd.grad((states * readout).sum(), leaves)
    (states, grads), (expected_states, expected_grads) = results[True], results[False]
    assert th.equal(states, expected_states)  # gru_update's forward
    for got, expected in zip(grads, expected_grads):
        if dtype == th.float32:
            th.testing.assert_close(got, expected, atol=1e-5 * float(expected.abs().max()), rtol=0)
        else:  # bf16: the weight gradient summed once in a float32-accumulating GEMM instead of per step in bf16
            cosine = th.nn.functional.cosine_similarity(got.flatten().double(), expected.flatten().double(), dim=0)
            assert cosine > 0.999


@pytest.mark.parametrize("autocast", [None, "bf16"])
def test_replayed_log_probs_match_the_rollout_under_the_same_autocast(autocast):
    model = collected_model(autocast=autocast)
    assert model.policy.autocast == autocast
    if autocast is not None:  # bf16 rounds the rollout's steps and the replay's chunks differently: train() recomputes
        assert 1e-5 < replay_error(model) < 1e-2
        model.recompute_old_log_probs()
    assert replay_error(model) < 1e-5
    if autocast is not None:  # the rollout did run in bf16: a float32 replay of the same data differs
        model.policy.autocast = None
        assert replay_error(model) > 1e-5


def sequence_inputs(model):
    batch = next(model.rollout_buffer.get(model.batch_size))
    obs = {key: batch.observations[key] for key in ("local_obs", "proprio", "link_row")}
    return model.policy.step_inputs(obs, batch.episode_starts), batch.latent_state


@pytest.mark.parametrize("substitute", ["predicted", "zero", "hold_last", "own_message"])
@pytest.mark.parametrize("no_memory", [False, True])
def test_chunked_replay_matches_the_per_step_replay(substitute, no_memory):
    model = collected_model(policy_kwargs={**TINY_POLICY, "message_substitute": substitute, "no_memory": no_memory})
    policy = model.policy
    inputs, initial_state = sequence_inputs(model)
    assert (inputs.keep[1:] == 0).any() and not inputs.has_message.all()  # episode starts and dropouts inside chunks
    chunked = policy._replay_latent_sequence(inputs, initial_state)  # the recurrence-free GEMMs over the whole chunk
    per_step = policy._replay_latent_steps(inputs, initial_state)  # recurrent_step, as in rollouts
    parameters = list(policy.parameters())
    gradients = []
    for outputs in (chunked, per_step):
        weighted = sum((output * th.randn(output.shape, generator=th.Generator().manual_seed(i))).sum()
                       for i, output in enumerate(outputs[:4]))
        gradients.append(th.autograd.grad(weighted, parameters, allow_unused=True))
    assert th.equal(chunked[4], per_step[4])
    for got, expected in zip(chunked[:4], per_step[:4]):
        assert got.shape == expected.shape
        th.testing.assert_close(got, expected, atol=1e-6, rtol=0)
    reached = 0
    for got, expected in zip(*gradients):
        assert (got is None) == (expected is None)
        if expected is not None:
            reached += 1
            th.testing.assert_close(got, expected, atol=1e-5 * float(expected.abs().max()), rtol=0)
    assert reached > 10


def test_the_chunked_replay_runs_under_autocast_and_the_rollouts_computation_in_float32_on_the_cpu():
    policy = collected_model(n_epochs=1).policy
    assert not policy.chunked_replay
    policy.autocast = "bf16"
    assert policy.chunked_replay


@pytest.mark.parametrize("autocast", [None, "bf16"])
def test_only_bf16_training_recomputes_the_old_log_probs(autocast, monkeypatch):
    model = collected_model(autocast=autocast, n_epochs=1)
    calls = []
    recompute = LatentSwarmPPO.recompute_old_log_probs
    monkeypatch.setattr(LatentSwarmPPO, "recompute_old_log_probs", lambda self: (calls.append(self), recompute(self)))
    rollout = model.rollout_buffer.log_probs.copy()
    model.train()
    assert calls == ([] if autocast is None else [model])
    trained_on = model.rollout_buffer._torch_cache["log_probs"].reshape(rollout.shape).numpy()
    np.testing.assert_array_equal(model.rollout_buffer.log_probs, rollout)  # the rollout's own record stays
    if autocast is None:
        np.testing.assert_array_equal(trained_on, rollout)
    else:
        assert 1e-5 < np.abs(trained_on - rollout).max() < 1e-2


def test_recomputed_bf16_log_probs_are_reproduced_by_any_minibatch_of_the_rollout():
    model = collected_model(autocast="bf16", batch_size=45)  # 8 sequences of 15 agent-steps: minibatches of 3, 3, 2
    model.recompute_old_log_probs()
    for _ in range(3):  # get() shuffles the sequences into other minibatches each time
        assert replay_error(model) < 1e-5


def test_replayed_log_probs_match_the_rollout_at_the_paper_latent_size():
    model = collected_model(policy_kwargs=PAPER_SIZED_POLICY, n_epochs=1)
    assert model.policy.latent_dim == 512
    assert replay_error(model) < 1e-5


def test_train_reads_the_device_once_per_minibatch():
    model = collected_model(n_epochs=3)
    n_minibatches = 3 * len(list(model.rollout_buffer.get(model.batch_size)))
    with HostReads() as reads:
        model.train()
    # one finiteness check per minibatch; per epoch one read of the statistics; per update a few for the logs
    per_update = 3 * 2 + 6
    assert sum(reads.count.values()) <= n_minibatches + per_update, reads.count
    assert n_minibatches >= 12  # the bound above would fail with the former ~17 reads per minibatch


def test_gaussians_are_built_without_argument_validation():
    # whatever earlier code in this process chose (torch._dynamo, used by the compile tests, switches it off globally)
    global_default = th.distributions.Distribution._validate_args
    for distribution in ("gaussian", "squashed_gaussian"):
        model = collected_model(policy_kwargs={**TINY_POLICY, "action_distribution": distribution}, n_epochs=1)
        policy = model.policy
        dist = policy.action_distribution(th.zeros(4, policy.task_dim))
        assert dist.distribution._validate_args is False
        assert th.distributions.Distribution._validate_args is global_default  # the global default is left alone
        assert th.distributions.Normal(0.0, 1.0, validate_args=None)._validate_args is global_default
        with HostReads() as reads:
            dist.log_prob(th.zeros(4, policy.action_dim))
        assert sum(reads.count.values()) == 0


def test_value_norm_reads_no_tensor_on_the_host():
    norm = ValueNorm(beta=0.9)
    values = th.linspace(-3.0, 5.0, 11)
    with HostReads() as reads:
        mean, var = norm.mean_var()
        assert th.equal(norm.normalize(values), values)  # before any update: mean 0, variance 1
        norm.update(values * 10.0)
        round_trip = norm.denormalize(norm.normalize(values))
    assert sum(reads.count.values()) == 0
    assert (mean.item(), var.item()) == (0.0, 1.0)
    th.testing.assert_close(round_trip, values)
    th.testing.assert_close(norm.mean_var()[0], (values * 10.0).mean())


def test_autocast_is_validated_saved_and_loaded(tmp_path):
    with pytest.raises(ValueError, match=r"autocast \(None: float32\) must be one of None, 'bf16'; got 'fp16'"):
        LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(2, config=SMALL, seed=0), autocast="fp16")
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(2, config=SMALL, seed=0), n_steps=20, chunk_length=5,
                           batch_size=30, policy_kwargs=TINY_POLICY, autocast="bf16", seed=0)
    model.save(tmp_path / "bf16.zip")
    loaded = LatentSwarmPPO.load(tmp_path / "bf16.zip", device="cpu")
    assert loaded.autocast == "bf16" and loaded.policy.autocast == "bf16"
    assert LatentSwarmPPO.load(tmp_path / "bf16.zip", device="cpu", autocast=None).policy.autocast is None
    obs = {key: np.asarray(value) for key, value in model.env.reset().items()}
    actions, _ = loaded.policy.predict(obs, deterministic=True)
    expected, _ = model.policy.predict(obs, deterministic=True)
    np.testing.assert_array_equal(actions, expected)
    with pytest.raises(ValueError, match="autocast must be one of"):
        model.policy.autocast = "float16"


def test_minibatch_benchmark_counts_ops_and_syncs_on_smoke():
    import importlib.util
    import pathlib

    path = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / "minibatch_ops.py"
    spec = importlib.util.spec_from_file_location("minibatch_ops", path)
    benchmark = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(benchmark)
    rows = benchmark.measure("smoke", [None, "bf16"], minibatches=2, repeats=1)
    assert [row["autocast"] for row in rows] == ["none", "bf16"]
    for row in rows:
        assert row["ops"] > 100 and row["cpu_s"] > 0 and row["replay"] < 1e-5
        # one finiteness read per minibatch, the per-epoch and per-update reads shared out over the 2 minibatches
        assert 1 <= row["syncs"] <= 8, row["sync_sites"]
