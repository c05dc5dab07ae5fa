"""ONNX export of one UAV's step: the recurrent state as explicit inputs and outputs (TorchRL's way for recurrent
policies), so that the file runs anywhere onnxruntime does, without torch (:class:`~sb3_latentswarm.agent.OnnxSwarmAgent`).

Inputs (batch dim B: one UAV, or several stepped together; float32 unless noted):

=====================  ==================  ===============================================================
``map_state``          (B, d_mu)           mu_{t-1}                                       (Sec. III-A)
``task_state``         (B, d_tau)          tau_{t-1}
``memory_state``       (B, d_rho)          rho_{t-1}
``prev_local_obs``     (B, o_dim)          o_{t-1}
``prev_message``       (B, d)              mbar_{t-1}, the best available message of the previous step
``held_message``       (B, d)              the last message received in the episode (``hold_last``)
``local_obs``          (B, o_dim)          o_t, flattened
``proprio``            (B, e_dim)          e_t (its first three entries are p_t)
``message_mean``       (B, d)              m_t, the mean of the messages received this step (Sec. III-B)
``message_count``      (B,) int64          |N_t^i|; 0: nothing arrived (dropout: the substitute is used)
``noise``              (B, action_dim)     eps ~ N(0, I); zeros give the mean action
=====================  ==================  ===============================================================

Outputs: ``action`` (B, action_dim) inside the action space (``LatentSwarmPolicy.env_actions``), the next state
(``next_map_state``, ..., ``next_held_message``, in the order above), ``message`` (B, d), z_t = [mu_t; tau_t], what
the UAV broadcasts for step t + 1, and ``predicted_message`` (B, d), mhat_t (Sec. III-C). All zeros is the state at an
episode start.

A delay-aware policy (``delay_aware=True``, an extension; ``docs/concepts.md``, "Delayed messages") is exported in
format 2: one more state, ``prev_message_age`` (B, 1), alpha_{t-1} (after ``held_message``; output
``next_prev_message_age``), and one more input, ``message_age`` (B, 1), alpha_t = the mean age of the messages in
``message_mean`` divided by the expiry E (0 when nothing arrived; after ``message_count``). ``message_mean`` then holds
each message as its sender broadcast it (:func:`~sb3_latentswarm.agent.onnx_runtime.onnx_io_names`).

A policy trained on an adapted env (any PettingZoo ``ParallelEnv`` through
:func:`~sb3_latentswarm.envs.make_adapted_vec_env`, ``docs/own_env.md``) is exported in format 3 (format 4 when it is
delay-aware: the age state and input as in format 2). Its ``proprio`` is the own-state function's e_t, (B, e_dim) with
e_dim possibly 0 (then a (B, 0) input), and p_t is not in it: where the env has a position function, one more input,
``position`` (B, position_dims), p_t (after ``proprio``); without positions, no input (the map update reads no
position, as the policy's). The metadata records the layout (``position_key``: ``"position"`` or ``None``, and
``position_dims``: 3 or 0), so :class:`~sb3_latentswarm.agent.OnnxSwarmAgent` checks the observations as
:class:`~sb3_latentswarm.agent.LatentSwarmAgent` does. Files of the swarm env's layout are unchanged (formats 1, 2).
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn

from sb3_latentswarm.agent.agent import agent_spec, policy_of
from sb3_latentswarm.agent.onnx_runtime import FORMATS, onnx_io_names
from sb3_latentswarm.envs.observations import POSITION_KEY, SWARM_LAYOUT
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
from sb3_latentswarm.latent_ppo.recurrence import AgentInputs, Blocks, agent_update, gru_cell, outgoing_message
from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.utils.atomic import write_bytes

__all__ = ["EXPORT_TOLERANCE", "INPUT_NAMES", "METADATA_KEY", "OUTPUT_NAMES", "OPSET", "ExportCheck", "export_onnx"]

STATE_NAMES, INPUT_NAMES, OUTPUT_NAMES = onnx_io_names(False)
"""The names of the paper's exported step (format 1; a delay-aware step: ``onnx_io_names(True)``; an adapted layout's
step: ``onnx_io_names(delay_aware, position=True)`` where it reads positions)."""
assert STATE_NAMES == LatentState._fields[:6]  # (sent_history is not exported: the received messages come as sent)
OPSET = 17
METADATA_KEY = "sb3_latentswarm"
"""The key of the file's metadata (JSON: format, sizes, action bounds, substitute; the layout in formats 3 and 4) read
by the runtime."""
EXPORT_TOLERANCE = 1e-5
"""The largest difference between onnxruntime and the float32 torch step that :func:`export_onnx` accepts."""


class _GraphLinears:
    """:class:`~sb3_latentswarm.latent_ppo.recurrence.EagerLinears` in float32 with the GRU written as two
    ``F.linear`` and its gates (:func:`gru_cell`, equal to ``nn.GRUCell`` to ~1e-7), which every ONNX runtime has."""

    def __init__(self, policy: LatentSwarmPolicy) -> None:
        self.policy = policy

    def gru(self, cell: nn.GRUCell, blocks: Blocks, hidden: th.Tensor) -> th.Tensor:
        return gru_cell(th.cat([block for _, block in blocks], dim=-1), hidden, cell)

    def predictor(self, blocks: Blocks) -> th.Tensor:
        return self.policy.message_predictor(th.cat([block for _, block in blocks], dim=-1))


class AgentStep(nn.Module):
    """The per-UAV step as a module of tensors only (what is exported): :func:`agent_update` in float32, then the
    actor. Inputs and outputs: see the module docstring."""

    def __init__(self, policy: LatentSwarmPolicy) -> None:
        super().__init__()
        self.policy = policy
        self.state_names, self.input_names, self.output_names = _io_names(policy)

    def forward(self, *tensors: th.Tensor) -> tuple[th.Tensor, ...]:
        named = dict(zip(self.input_names, tensors))
        state = _latent_state(tensors[: len(self.state_names)])
        out = agent_update(self.policy, _agent_inputs(self.policy, named), state, _GraphLinears(self.policy))
        action = self.policy.env_actions(self.policy.actions_from_noise(out.state.task_state, named["noise"]))
        exported = [getattr(out.state, name) for name in self.state_names]
        return (action, *exported, outgoing_message(out.state), out.predicted_message)


def _io_names(policy: LatentSwarmPolicy) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
    """``(state, input, output)`` names of ``policy``'s exported step (:func:`onnx_io_names` of its layout)."""
    return onnx_io_names(policy.delay_aware, policy.layout.position_key == POSITION_KEY)


def _export_format(policy: LatentSwarmPolicy) -> int:
    """The export format of ``policy``'s file (:data:`~sb3_latentswarm.agent.onnx_runtime.FORMATS`): 1 or 2 on the
    swarm env's layout, 3 or 4 on an adapted env's (2 and 4: delay-aware)."""
    return FORMATS[_adapted(policy), policy.delay_aware]


def _adapted(policy: LatentSwarmPolicy) -> bool:
    """Whether ``policy`` was trained on an adapted env (p_t not read from ``proprio``: formats 3 and 4)."""
    return policy.layout.position_key != SWARM_LAYOUT.position_key


def _agent_inputs(policy: LatentSwarmPolicy, named: dict[str, th.Tensor]) -> AgentInputs:
    """:class:`AgentInputs` of one exported step's inputs (by name; ``message_age`` present for a delay-aware step,
    ``position`` for an adapted layout with positions). p_t is the policy's own ``map_position``: the first entries of
    ``proprio`` (the swarm env), the input ``position``, or 0 columns."""
    proprio, message_mean = named["proprio"], named["message_mean"]
    has_message = named["message_count"] > 0
    return AgentInputs(
        keep=th.ones_like(message_mean[:, :1]),  # (not proprio's: it may have 0 columns on an adapted env)
        local_obs=named["local_obs"],
        proprio=proprio,
        position=policy.map_position(named, proprio),
        received_message=th.where(has_message.unsqueeze(-1), message_mean, th.zeros_like(message_mean)),
        has_message=has_message,
        message_age=named.get("message_age"),
    )


def _latent_state(tensors: Sequence[th.Tensor]) -> LatentState:
    """The exported state fields (6, or 7 with ``prev_message_age``), completed with zero-column fields: the sent
    history is not exported (a UAV receives each message as its sender broadcast it), nor is the age without delay."""
    empty = tensors[0][:, :0]
    age = tensors[6] if len(tensors) > 6 else empty
    return LatentState._make((*tensors[:6], empty, age))


@dataclass(frozen=True)
class ExportCheck:
    """What :func:`export_onnx` checked before writing the file."""

    path: str
    max_abs_error: float
    """The largest difference between onnxruntime and the float32 torch step, over every output of the check's steps
    (each step fed the same inputs), below :data:`EXPORT_TOLERANCE`."""
    tolerance: float
    autocast_max_abs_error: float | None
    """For a model that runs under bf16 autocast: the largest difference of the exported float32 step's action from
    the model's own (bf16) step over the same steps (bf16 rounding, ~1e-2); ``None`` for a float32 model."""
    n_steps: int
    size_bytes: int


def export_onnx(model: Any, path: str | os.PathLike[str], n_check_steps: int = 16, seed: int = 0) -> ExportCheck:
    """Export one UAV's step of ``model`` to an ONNX file (float32, opset 17, a dynamic batch dim).

    Before writing, the exported graph is run with onnxruntime on ``n_check_steps`` steps of a synthetic episode
    (observations drawn from the observation space, messages from the agent's own states, dropouts included) and
    compared with the torch step: the file is written (atomically: a temporary file, then ``os.replace``) only if every
    output agrees within :data:`EXPORT_TOLERANCE`. A model trained under bf16 autocast is exported in float32 (an ONNX
    CPU runtime has no bf16 ``MatMul``); its difference from the model's own bf16 step is reported in the result.

    :param model: a :class:`~sb3_latentswarm.LatentSwarmPPO` or its policy
    :param path: the ``.onnx`` file to write
    :param n_check_steps: steps of the check (>= 1)
    :param seed: seed of the check's inputs
    :return: the :class:`ExportCheck`
    :raise ImportError: without ``onnx`` and ``onnxruntime`` (``pip install "sb3-latentswarm[deploy]"``)
    :raise RuntimeError: when onnxruntime and torch disagree beyond the tolerance (nothing is written)
    :raise ValueError: for ``n_check_steps`` < 1
    :raise FileNotFoundError: when ``path``'s folder does not exist (before any work)

    A delay-aware policy (``delay_aware=True``) is exported in format 2, with its age input; a policy trained on an
    adapted env in format 3 (4 when delay-aware), with its layout's inputs (the module docstring).
    """
    import onnx
    import onnxruntime as ort

    policy = policy_of(model)
    spec = agent_spec(policy)
    if int(n_check_steps) < 1:
        raise ValueError(f"n_check_steps must be >= 1, got {n_check_steps}")
    if not os.path.isdir(os.path.dirname(os.path.abspath(path))):  # before the export's work, not after it
        raise FileNotFoundError(f"cannot write {os.fspath(path)!r}: its folder does not exist")
    module = AgentStep(policy).to("cpu").eval()
    was_device = policy.device
    policy.to("cpu")
    try:
        check_inputs = _check_episode(policy, int(n_check_steps), seed)
        buffer = io.BytesIO()
        input_names, output_names = module.input_names, module.output_names
        dynamic = {name: {0: "batch"} for name in (*input_names, *output_names)}
        with th.no_grad(), warnings.catch_warnings():
            # the TorchScript exporter on purpose: the dynamo one fixes the batch size where Python computes with it
            warnings.simplefilter("ignore", DeprecationWarning)
            th.onnx.export(module, tuple(th.as_tensor(x) for x in check_inputs[0]), buffer,  # type: ignore[arg-type]  # a file object works
                           input_names=list(input_names),
                           output_names=list(output_names), dynamic_axes=dynamic, opset_version=OPSET, dynamo=False)
        graph = onnx.load_from_string(buffer.getvalue())
        metadata = {
            "format": _export_format(policy), "state_dims": _state_dims(policy),
            "local_obs_shape": list(spec.local_obs_shape),
            "proprio_dim": spec.proprio_dim, "message_dim": spec.message_dim, "action_dim": spec.action_dim,
            "action_low": list(spec.action_low), "action_high": list(spec.action_high),
            "message_substitute": policy.message_substitute, "no_memory": policy.no_memory,
            "trained_autocast": policy.autocast,
        }
        if _adapted(policy):  # (formats 3 and 4: the adapted layout)
            metadata.update(position_key=spec.position_key, position_dims=spec.position_dims)
        if policy.delay_aware:
            metadata.update(delay_aware=True, message_expiry=policy.message_expiry)
        onnx.helper.set_model_props(graph, {METADATA_KEY: json.dumps(metadata)})
        data = graph.SerializeToString()
        session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
        error, autocast_error = 0.0, None if policy.autocast is None else 0.0
        for inputs in check_inputs:
            with th.no_grad():
                expected = [t.numpy() for t in module(*(th.as_tensor(x) for x in inputs))]
            got = session.run(list(output_names), dict(zip(input_names, inputs)))
            error = max(error, *(float(np.abs(g - e).max()) for g, e in zip(got, expected)))
            if autocast_error is not None:
                autocast_error = max(autocast_error, float(np.abs(got[0] - _own_step_action(policy, inputs)).max()))
        if not error <= EXPORT_TOLERANCE:  # (NaN fails too)
            raise RuntimeError(f"onnxruntime differs from torch by {error:.3g} > {EXPORT_TOLERANCE:g}; nothing written")
    finally:
        policy.to(was_device)
    write_bytes(path, data)
    return ExportCheck(os.fspath(path), error, EXPORT_TOLERANCE, autocast_error, int(n_check_steps), len(data))


def _state_dims(policy: LatentSwarmPolicy) -> list[int]:
    """The sizes of the exported state fields (:func:`onnx_io_names`' state names)."""
    dims = dict(zip(LatentState._fields, policy.latent_dims))
    return [dims[name] for name in _io_names(policy)[0]]


def _check_episode(policy: LatentSwarmPolicy, n_steps: int, seed: int) -> list[tuple[np.ndarray, ...]]:
    """The inputs of ``n_steps`` steps of 3 UAVs (batch 3) stepped by the float32 export module, in the order of its
    input names: observations from the observation space (the position too, where the layout has the key), messages
    the UAVs' own (every link up every third step, none every fourth), and for a delay-aware policy ages drawn in
    [0, 1] (0 where nothing arrived)."""
    rng = np.random.default_rng(seed)
    local_space, proprio_space = (cast(spaces.Box, policy.observation_space[key]) for key in ("local_obs", "proprio"))
    n = 3
    local_shape = local_space.shape
    module = AgentStep(policy).eval()
    position_space = cast(spaces.Box, policy.observation_space[POSITION_KEY]) if POSITION_KEY in module.input_names else None
    state = [np.zeros((n, dim), dtype=np.float32) for dim in _state_dims(policy)]
    n_states = len(state)
    message = np.zeros((n, policy.message_dim), dtype=np.float32)
    steps = []
    for t in range(n_steps):
        local_obs = rng.uniform(_finite(local_space.low), _finite(local_space.high), (n, *local_shape))
        if np.issubdtype(local_space.dtype, np.integer):
            local_obs = np.round(local_obs)
        local_obs = local_obs.reshape(n, -1).astype(np.float32)
        proprio = rng.uniform(_finite(proprio_space.low), _finite(proprio_space.high), (n, policy.proprio_dim))
        proprio = proprio.astype(np.float32)
        links = rng.random((n, n)) < 0.5
        links |= t % 3 == 0
        links &= t % 4 != 3
        np.fill_diagonal(links, False)
        count = links.sum(1)
        mean = (links.astype(np.float32) @ message) / np.maximum(count, 1)[:, None].astype(np.float32)
        noise = rng.standard_normal((n, policy.action_dim)).astype(np.float32) * (t % 2)
        age = (rng.random((n, 1)) * (count[:, None] > 0)).astype(np.float32)
        named = dict(zip(module.state_names, state), local_obs=local_obs, proprio=proprio,
                     message_mean=mean.astype(np.float32), message_count=count.astype(np.int64), message_age=age,
                     noise=noise)
        if position_space is not None:
            position = rng.uniform(_finite(position_space.low), _finite(position_space.high), (n, *position_space.shape))
            named["position"] = position.astype(np.float32)
        inputs = tuple(named[name] for name in module.input_names)
        steps.append(inputs)
        with th.no_grad():
            out = [t.numpy() for t in module(*(th.as_tensor(x) for x in inputs))]
        state, message = out[1 : 1 + n_states], out[1 + n_states]
        assert all(math.isfinite(float(np.abs(x).max())) for x in out)
    return steps


def _finite(bound: np.ndarray) -> np.ndarray:
    """A space's bound with the infinite entries replaced by +-1 (the scale of normalized observations)."""
    return np.clip(np.asarray(bound, dtype=np.float64), -1.0, 1.0)


def _own_step_action(policy: LatentSwarmPolicy, inputs: tuple[np.ndarray, ...]) -> np.ndarray:
    """The action of the policy's own step (under its autocast) for one step's export inputs."""
    state_names, input_names, _ = _io_names(policy)
    named = {name: th.as_tensor(x) for name, x in zip(input_names, inputs)}
    state = _latent_state([named[name] for name in state_names])
    with th.no_grad():
        out = policy.agent_step(_agent_inputs(policy, named), state)
        action = policy.env_actions(policy.actions_from_noise(out.state.task_state, named["noise"]))
    return action.numpy()
