"""The per-step function of Sec. III, written once: message pooling, then the latent updates of any batch of agents.

The batched policy step is :func:`pool_messages` + :func:`agent_update` (:func:`swarm_step`); a single UAV
(:class:`~sb3_latentswarm.agent.LatentSwarmAgent`) averages the messages its radio received and calls
:func:`agent_update` with a batch of 1; the training replay (:func:`replay_sequence`) runs :func:`swarm_step` at every
step of a time-major sequence with other :class:`Linears`: the same equations, with the GEMMs arranged for a whole
sequence (the observation columns of each input projection computed once for all T * B rows, the weight gradients of
the recurrent columns summed once per sequence by :class:`SequenceLinear`).

Per UAV i at step t, in the paper's order:

* message of UAV j: z_{t-1}^j = [mu_{t-1}^j ; tau_{t-1}^j]; aggregate over live in-links (Sec. III-B):
  m_t^i = mean_{j in N_t^i} z_{t-1}^j (zero when N_t^i is empty)
* memory (Sec. III-A): rho_t = G_psi(rho_{t-1}, tau_{t-1}, o_{t-1}, mbar_{t-1})
* predictor (Sec. III-C): mhat_t = P_zeta(rho_t, o_t, e_t); best available message mbar_t = m_t if N_t^i is not
  empty, else the substitute (mhat_t in the paper, see ``MESSAGE_SUBSTITUTES``)
* map (Sec. III-A): mu_t = E_phi(mu_{t-1}, o_t, p_t, m_t^mu) with m_t^mu = 0 when nothing arrived (the asymmetric
  update: the map state never sees a predicted message)
* task (Sec. III-A): tau_t = F_theta(tau_{t-1}, o_t, e_t, mu_{t-1}, mbar_t)

Under delayed links (an extension, opt-in: ``SwarmConfig.message_delay > 0`` or a delayed adapter link model) a
message of j that arrives a_ij steps late is pooled as it was sent, z_{t-1-a_ij}^j (:func:`pool_delayed_messages`),
by every policy. A delay-aware policy (``LatentSwarmPolicy(delay_aware=True)``, opt-in) also reads the pooled
message's age alpha_t = mean_{j in N_t^i} a_ij / E (0 when nothing arrived), one more input of the task update (beside
mbar_t), the memory update (alpha_{t-1}, beside mbar_{t-1}) and the predictor (P_zeta(rho_t, o_t, e_t, alpha_t)).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import torch as th
import torch.nn.functional as F
from torch import nn

from sb3_latentswarm.latent_ppo.type_aliases import LatentState

if TYPE_CHECKING:
    from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

__all__ = [
    "AgentInputs",
    "EagerLinears",
    "Linears",
    "SequenceGRUCell",
    "SequenceLinear",
    "SequenceLinears",
    "StepInputs",
    "StepOutput",
    "agent_update",
    "gru_cell",
    "gru_update",
    "outgoing_message",
    "pool_delayed_messages",
    "pool_messages",
    "replay_sequence",
    "swarm_step",
]

Blocks = Sequence[tuple[str, th.Tensor]]
"""The input of a layer as named column blocks, in the order of the layer's input columns. The names of
:data:`OBSERVED_BLOCKS` are read from the observation (known for a whole sequence in advance); the others depend on
the recurrence."""
OBSERVED_BLOCKS = ("local_obs", "proprio", "position", "prev_local_obs")


class AgentInputs(NamedTuple):
    """What :func:`agent_update` reads at step t, for a batch of B agents (any agents: a swarm's, several swarms', one
    UAV's), after the messages have been pooled."""

    keep: th.Tensor
    """1 - episode_start, (B, 1): the carried state is zeroed where an episode starts."""
    local_obs: th.Tensor
    """o_t, flattened, float32, (B, o_dim)."""
    proprio: th.Tensor
    """e_t, float32, (B, e_dim)."""
    position: th.Tensor
    """p_t, the first entries of e_t, (B, 3)."""
    received_message: th.Tensor
    """m_t, the mean of the messages z_{t-1}^j received over live in-links, zero when none arrived, (B, d_mu + d_tau)."""
    has_message: th.Tensor
    """Whether N_t^i is not empty, (B,) bool."""
    message_age: th.Tensor | None = None
    """Delay-aware policies only: alpha_t, the mean age of the pooled messages divided by the expiry E, in [0, 1], 0
    when nothing arrived, (B, 1); ``None``: the policy does not read ages (the paper)."""


class StepInputs(NamedTuple):
    """What a swarm step reads from the observation, before the recurrence (``LatentSwarmPolicy.step_inputs``).

    Leading dims ``(...)``: ``(B,)`` for one step, ``(T, B)`` for a training sequence (then indexed per step)."""

    keep: th.Tensor
    """1 - episode_start, (..., B, 1)."""
    local_obs: th.Tensor
    """o_t, flattened, float32, (..., B, o_dim)."""
    proprio: th.Tensor
    """e_t, float32, (..., B, e_dim)."""
    position: th.Tensor
    """p_t, the first entries of e_t, (..., B, 3)."""
    link_mask: th.Tensor
    """[..., s, i, j] = 1 iff the link j -> i of swarm s delivered at t, (..., n_swarms, N, N)."""
    has_message: th.Tensor
    """Whether N_t^i is not empty, (..., B) bool."""
    link_age: th.Tensor | None = None
    """Delayed links only: [..., s, i, j] = how many steps late the message of j -> i is (0 where nothing arrived),
    float, (..., n_swarms, N, N); ``None`` without delay."""


class StepOutput(NamedTuple):
    """Everything one latent step produces for a batch of agents (leading dim: slots)."""

    state: LatentState
    """The new state, to carry into the next step."""
    received_message: th.Tensor
    """m_t, the mean of live in-link messages (zeros when none arrived), (B, d_mu + d_tau)."""
    predicted_message: th.Tensor
    """mhat_t = P(rho_t, o_t, e_t), evaluated at every step, (B, d_mu + d_tau)."""
    has_message: th.Tensor
    """Whether N_t^i is not empty, (B,) bool."""
    sent_message: th.Tensor
    """z_{t-1}^i = [mu_{t-1}^i; tau_{t-1}^i], the message this agent broadcast for step t (zero at an episode start),
    (B, d_mu + d_tau)."""


# ---------------------------------------------------------------------------------------------- the equations
def outgoing_message(state: LatentState, keep: th.Tensor | None = None) -> th.Tensor:
    """z^i = [mu^i; tau^i] (Sec. III-B): the message an agent broadcasts from its state, (B, d_mu + d_tau).

    :param state: the state after step t-1 (the message is received at step t)
    :param keep: (B, 1) 1 - episode_start: zero where an episode starts; ``None``: keep everything
    """
    if keep is None:
        return th.cat([state.map_state, state.task_state], dim=-1)
    return th.cat([state.map_state * keep, state.task_state * keep], dim=-1)


def pool_messages(sent_messages: th.Tensor, link_mask: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """Sec. III-B: m_t^i = mean_{j in N_t^i} z_{t-1}^j over the live in-links of every agent, zero when none.

    :param sent_messages: z_{t-1}^j of every agent, (n_swarms, N, d)
    :param link_mask: [s, i, j] = 1.0 iff the link j -> i of swarm s delivered at t, float, (n_swarms, N, N)
    :return: received messages m_t (n_swarms * N, d), agent-minor, and whether anything arrived (n_swarms * N,) bool
    """
    n_swarms, n_agents, dim = sent_messages.shape
    in_degree = link_mask.sum(-1, keepdim=True)  # |N_t^i|, (n_swarms, N, 1)
    received = (th.bmm(link_mask, sent_messages) / in_degree.clamp(min=1.0)).view(n_swarms * n_agents, dim)
    return received, (in_degree > 0).view(n_swarms * n_agents)


def pool_delayed_messages(sent_messages: th.Tensor, link_mask: th.Tensor, link_age: th.Tensor,
                          expiry: int) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Sec. III-B under delay (extension): each arrival pooled as it was sent, m_t^i = mean_{j in N_t^i}
    z_{t-1-a_ij}^j, and its age alpha_t^i = mean_{j in N_t^i} a_ij / E (both zero when nothing arrived).

    :param sent_messages: [s, j, a] = z_{t-1-a}^j, the messages every agent sent, freshest first, (n_swarms, N, E + 1, d)
    :param link_mask: [s, i, j] = 1.0 iff a message of j arrived at i at t, float, (n_swarms, N, N)
    :param link_age: [s, i, j] = its delay a_ij in steps, in [0, E], float, (n_swarms, N, N)
    :param expiry: E, the largest delay (ages are divided by max(E, 1))
    :return: received messages m_t (n_swarms * N, d), whether anything arrived (n_swarms * N,) bool, alpha_t
        (n_swarms * N, 1)
    """
    n_swarms, n_agents, n_ages, dim = sent_messages.shape
    in_degree = link_mask.sum(-1, keepdim=True)  # |N_t^i|, (n_swarms, N, 1)
    weights = link_mask / in_degree.clamp(min=1.0)  # (n_swarms, N, N)
    by_age = F.one_hot(link_age.long(), n_ages).to(weights.dtype) * weights.unsqueeze(-1)  # (n_swarms, N, N, E + 1)
    received = th.einsum("sija,sjad->sid", by_age, sent_messages).reshape(n_swarms * n_agents, dim)
    age = (weights * link_age).sum(-1, keepdim=True) / max(expiry, 1)  # (n_swarms, N, 1)
    return received, (in_degree > 0).view(n_swarms * n_agents), age.view(n_swarms * n_agents, 1)


def _with_age(blocks: Blocks, name: str, age: th.Tensor | None) -> Blocks:
    """``blocks`` with an age column appended (delay-aware policies), unchanged otherwise."""
    return blocks if age is None else (*blocks, (name, age))


def agent_update(policy: LatentSwarmPolicy, inputs: AgentInputs, state: LatentState,
                 linears: Linears | None = None) -> StepOutput:
    """Everything after pooling of Sec. III for a batch of agents: memory, predictor / substitute, the asymmetric map
    update and the task update. No agent reads another's row: any batch of agents gives the same rows.

    :param policy: the networks (and ``message_substitute``, ``no_memory``)
    :param inputs: this step's observation and pooled message
    :param state: the state carried in from step t-1, (B, ...) per field
    :param linears: how the layers' GEMMs are computed (default :class:`EagerLinears`: the rollout's computation)
    """
    linears = EagerLinears(policy) if linears is None else linears
    map_prev, task_prev, memory_prev, local_prev, message_prev, held_prev = (field * inputs.keep for field in state[:6])
    age = inputs.message_age  # alpha_t (delay-aware policies), else None
    prev_age = None if age is None else state.prev_message_age * inputs.keep
    local_obs, proprio, received_message = inputs.local_obs, inputs.proprio, inputs.received_message
    sent_message = th.cat([map_prev, task_prev], dim=-1)  # z_{t-1}^i, (B, d_mu + d_tau)

    # Sec. III-A: rho_t = G_psi(rho_{t-1}, tau_{t-1}, o_{t-1}, mbar_{t-1})   (no_memory: rho zeroed before use)
    if policy.no_memory:
        memory_prev = th.zeros_like(memory_prev)
    memory_state = linears.gru(policy.memory_encoder, _with_age((("task_prev", task_prev), ("prev_local_obs", local_prev),
                                                                ("message_prev", message_prev)), "prev_age", prev_age),
                               memory_prev)
    memory_used = th.zeros_like(memory_state) if policy.no_memory else memory_state

    # Sec. III-C: mhat_t = P_zeta(rho_t, o_t, e_t);  mbar_t = m_t if N_t^i != {} else mhat_t
    predicted_message = linears.predictor(_with_age((("memory", memory_used), ("local_obs", local_obs),
                                                     ("proprio", proprio)), "age", age))
    # (extensions: hold_last / own_message / zero replace mhat_t; see MESSAGE_SUBSTITUTES)
    received_now = inputs.has_message.unsqueeze(-1)
    held_message = th.where(received_now, received_message, held_prev)
    if policy.message_substitute == "predicted":
        substitute = predicted_message
    elif policy.message_substitute == "zero":
        substitute = th.zeros_like(predicted_message)
    elif policy.message_substitute == "hold_last":
        substitute = held_prev
    elif policy.message_substitute == "own_message":
        substitute = sent_message
    else:  # a value of MESSAGE_SUBSTITUTES this update does not know yet: never a silent default
        raise ValueError(f"agent_update: no rule for message_substitute={policy.message_substitute!r}")
    best_message = th.where(received_now, received_message, substitute)

    # Sec. III-A, asymmetric update: mu_t = E_phi(mu_{t-1}, o_t, p_t, m^mu_t), m^mu_t = 0 when nothing arrived
    # (received_message is already zero there, so the predictor never reaches the map state)
    map_message = received_message[:, : policy.map_dim]
    map_state = linears.gru(policy.map_encoder, (("local_obs", local_obs), ("position", inputs.position),
                                                ("map_message", map_message)), map_prev)

    # Sec. III-A: tau_t = F_theta(tau_{t-1}, o_t, e_t, mu_{t-1}, mbar_t)
    task_state = linears.gru(policy.task_encoder, _with_age((("local_obs", local_obs), ("proprio", proprio),
                                                            ("map_prev", map_prev), ("best_message", best_message)),
                                                           "age", age), task_prev)

    new_state = LatentState(map_state, task_state, memory_state, local_obs, best_message, held_message,
                            state.sent_history, state.prev_message_age if age is None else age)
    return StepOutput(new_state, received_message, predicted_message, inputs.has_message, sent_message)


def swarm_step(policy: LatentSwarmPolicy, inputs: StepInputs, state: LatentState,
               linears: Linears | None = None) -> StepOutput:
    """One step of whole swarms: :func:`pool_messages` of the messages z_{t-1} over the step's link mask, then
    :func:`agent_update`.

    :param inputs: one step's :class:`StepInputs`, leading dim B = n_swarms * N (env-major)
    :param state: the state carried in from step t-1, (B, ...) per field
    """
    n_swarms, n_agents = inputs.link_mask.shape[:2]
    sent = outgoing_message(state, inputs.keep).view(n_swarms, n_agents, policy.message_dim)
    if inputs.link_age is None:
        received_message, has_message = pool_messages(sent, inputs.link_mask)
        message_age = None
    else:  # delayed links: z_{t-1-a} of each arrival from the senders' histories [z_{t-1}; z_{t-2}; ...; z_{t-1-E}]
        history = th.cat([sent.flatten(0, 1), state.sent_history * inputs.keep], dim=-1)  # (B, (E + 1) d)
        sent_by_age = history.view(n_swarms, n_agents, -1, policy.message_dim)
        received_message, has_message, message_age = pool_delayed_messages(
            sent_by_age, inputs.link_mask, inputs.link_age, policy.message_expiry)
    agent_inputs = AgentInputs(inputs.keep, inputs.local_obs, inputs.proprio, inputs.position, received_message,
                               has_message, message_age if policy.delay_aware else None)
    out = agent_update(policy, agent_inputs, state, linears)
    if inputs.link_age is None:
        return out
    # the history carried into t + 1: [z_{t-1}; ...; z_{t-E}] (the oldest message drops out)
    new_history = history[:, : state.sent_history.shape[-1]]
    return out._replace(state=out.state._replace(sent_history=new_history))


# ---------------------------------------------------------------------------------------------- how GEMMs are computed
class Linears(Protocol):
    """The layers of :func:`agent_update` applied to named column blocks (:data:`Blocks`)."""

    def gru(self, cell: nn.GRUCell, blocks: Blocks, hidden: th.Tensor) -> th.Tensor:
        """``cell(cat(blocks), hidden)``, float32, (B, hidden_size)."""

    def predictor(self, blocks: Blocks) -> th.Tensor:
        """P_zeta(cat(blocks)), (B, d_mu + d_tau)."""


class EagerLinears:
    """Each layer on the concatenation of its blocks, one GEMM per projection: the rollout's computation (float32:
    ``nn.GRUCell``'s own kernel; under autocast :func:`gru_cell`, whose GEMMs autocast reaches)."""

    def __init__(self, policy: LatentSwarmPolicy) -> None:
        self.policy = policy

    def gru(self, cell: nn.GRUCell, blocks: Blocks, hidden: th.Tensor) -> th.Tensor:
        inputs = th.cat([block for _, block in blocks], dim=-1)
        return cell(inputs, hidden) if self.policy.autocast is None else gru_cell(inputs, hidden, cell)

    def predictor(self, blocks: Blocks) -> th.Tensor:
        return self.policy.message_predictor(th.cat([block for _, block in blocks], dim=-1))


class _SplitLinear(NamedTuple):
    observed: tuple[th.Tensor, ...]  # T x (B, out): the observed columns' projection (with the bias), per step
    recurrent: SequenceLinear | None  # the recurrent columns
    hidden: SequenceLinear | None  # W_hh h + b_hh of a GRU


class SequenceLinears:
    """The layers of :func:`agent_update` over a time-major sequence, step :attr:`t` at a time: each input projection is
    split by input columns into the blocks read from the observation (:data:`OBSERVED_BLOCKS`), projected once for all
    T * B rows at the first call (the bias rides on them), and the blocks that depend on the recurrence, projected per
    step by a :class:`SequenceLinear` (weights cast once to ``dtype``, weight gradient summed once per sequence); each
    GRU step is one :class:`SequenceGRUCell` node (gate arithmetic and its backward fused). The sums of the split
    projections round differently from one GEMM: float32 results agree with :class:`EagerLinears` to about 1e-6.

    :param sequence: the observed blocks of the whole sequence by name, (T, B, width) each
    :param dtype: the GEMMs' dtype (the autocast dtype, or the weights')
    """

    def __init__(self, policy: LatentSwarmPolicy, sequence: dict[str, th.Tensor], dtype: th.dtype) -> None:
        self.policy, self.sequence, self.dtype = policy, sequence, dtype
        self.t = 0
        self._layers: dict[nn.Module, _SplitLinear] = {}

    def _split(self, layer: nn.Module, weight: th.Tensor, bias: th.Tensor | None, blocks: Blocks,
               hidden: tuple[th.Tensor, th.Tensor] | None = None) -> _SplitLinear:
        if layer not in self._layers:
            columns: dict[bool, list[th.Tensor]] = {True: [], False: []}  # observed?: column blocks of the weight
            start = 0
            for name, block in blocks:
                width = block.shape[-1]
                columns[name in OBSERVED_BLOCKS].append(weight[:, start : start + width])
                start += width
            observed_names = [name for name, _ in blocks if name in OBSERVED_BLOCKS]
            observed: tuple[th.Tensor, ...] = ()
            if observed_names:
                observed_inputs = _cat([self.sequence[name] for name in observed_names])  # (T, B, width)
                # unbind: its backward stacks the T gradients once (indexing [t] would zero-fill a (T, B, .) per step)
                observed = F.linear(observed_inputs, _columns(columns[True]), bias).unbind(0)
            recurrent = None
            if columns[False]:
                recurrent = SequenceLinear(_columns(columns[False]), None if observed else bias, self.dtype)
            hidden_linear = None if hidden is None else SequenceLinear(*hidden, self.dtype)
            self._layers[layer] = _SplitLinear(observed, recurrent, hidden_linear)
        return self._layers[layer]

    @staticmethod
    def _recurrent_inputs(blocks: Blocks) -> th.Tensor:
        return _cat([block for name, block in blocks if name not in OBSERVED_BLOCKS])

    def _project(self, split: _SplitLinear, blocks: Blocks) -> th.Tensor:
        added = split.observed[self.t] if split.observed else None
        if split.recurrent is None:
            assert added is not None  # a layer has at least one block
            return added
        return split.recurrent(self._recurrent_inputs(blocks), added)

    def gru(self, cell: nn.GRUCell, blocks: Blocks, hidden: th.Tensor) -> th.Tensor:
        split = self._split(cell, cell.weight_ih, cell.bias_ih, blocks, (cell.weight_hh, cell.bias_hh))
        assert split.hidden is not None
        added = split.observed[self.t] if split.observed else None
        if split.recurrent is None:  # every input column observed: only W_hh h is per step
            assert added is not None
            return gru_update(added, split.hidden(hidden), hidden)
        return SequenceGRUCell(split.recurrent, split.hidden)(self._recurrent_inputs(blocks), added, hidden)

    def predictor(self, blocks: Blocks) -> th.Tensor:
        first, activation, last = self.policy.message_predictor  # Linear, Tanh, Linear
        assert isinstance(first, nn.Linear) and isinstance(last, nn.Linear)
        split = self._split(first, first.weight, first.bias, blocks)
        if last not in self._layers:  # reads the hidden layer, which depends on the recurrence
            self._layers[last] = _SplitLinear((), SequenceLinear(last.weight, last.bias, self.dtype), None)
        output = self._layers[last].recurrent
        assert output is not None
        return output(activation(self._project(split, blocks)))


def _columns(blocks: list[th.Tensor]) -> th.Tensor:
    return blocks[0] if len(blocks) == 1 else th.cat(blocks, dim=1)


def _cat(blocks: list[th.Tensor]) -> th.Tensor:
    return blocks[0] if len(blocks) == 1 else th.cat(blocks, dim=-1)  # (a single block is not copied)


def replay_sequence(policy: LatentSwarmPolicy, inputs: StepInputs, state: LatentState,
                    linears: str = "eager") -> tuple[th.Tensor, ...]:
    """The latent updates of time-major sequences of whole swarms: :func:`swarm_step` at every step (in the caller's
    autocast region).

    :param inputs: :class:`StepInputs` of the sequence, leading dims (T, B)
    :param state: the state carried into the first step, (B, ...) per field
    :param linears: ``"eager"``: the policy's ``recurrent_step`` per step (the rollout's computation);
        ``"sequence"``: :class:`SequenceLinears`
    :return: tau_t, mu_t, m_t, mhat_t (T, B, dim each, float32) and has_message (T, B)
    """
    if linears == "sequence":
        weight_dtype = policy.map_encoder.weight_ih.dtype
        dtype = weight_dtype if policy.autocast is None else th.get_autocast_dtype(policy.device.type)
        # o_{t-1}: the stored one before the first step, zeroed at episode starts as the carried state is
        prev_local_obs = th.cat([state.prev_local_obs.unsqueeze(0), inputs.local_obs[:-1]]) * inputs.keep
        sequence = {"local_obs": inputs.local_obs, "proprio": inputs.proprio, "position": inputs.position,
                    "prev_local_obs": prev_local_obs}
        sequence_linears = SequenceLinears(policy, sequence, dtype)
    outputs: list[list[th.Tensor]] = [[], [], [], [], []]
    # one unbind per field instead of an indexing op per field and step (views either way); an absent field stays None
    n_steps = inputs.keep.shape[0]
    per_step = [(None,) * n_steps if field is None else field.unbind(0) for field in inputs]
    for t, step_fields in enumerate(zip(*per_step)):
        step_inputs = StepInputs._make(step_fields)
        if linears == "sequence":
            sequence_linears.t = t
            step = swarm_step(policy, step_inputs, state, sequence_linears)
        else:
            step = policy.recurrent_step(step_inputs, state)
        state = step.state
        for output, value in zip(outputs, (state.task_state, state.map_state, step.received_message,
                                           step.predicted_message, step.has_message)):
            output.append(value)
    task_states, map_states, received, predicted, has_message = (th.stack(output) for output in outputs)
    return task_states, map_states, received.float(), predicted.float(), has_message


# ---------------------------------------------------------------------------------------------- GRU and GEMM kernels
def gru_cell(inputs: th.Tensor, hidden: th.Tensor, cell: nn.GRUCell) -> th.Tensor:
    """``torch.nn.GRUCell``'s equations with its parameters, its two GEMMs written as ``F.linear`` so that autocast runs
    them in bfloat16 (``GRUCell``'s own op is not autocast on CPU); the gates are computed in float32:

    r = sigmoid(W_ir x + b_ir + W_hr h + b_hr), z = sigmoid(W_iz x + b_iz + W_hz h + b_hz),
    n = tanh(W_in x + b_in + r * (W_hn h + b_hn)), h' = (1 - z) * n + z * h = (h - n) * z + n.

    :param inputs: x, (B, input_size)
    :param hidden: h, (B, hidden_size), float32
    :param cell: the ``GRUCell`` whose ``weight_ih``, ``bias_ih``, ``weight_hh``, ``bias_hh`` are used
    :return: h', (B, hidden_size), float32 (the dtype of ``hidden``)
    """
    return gru_update(F.linear(inputs, cell.weight_ih, cell.bias_ih), F.linear(hidden, cell.weight_hh, cell.bias_hh), hidden)


def gru_update(input_gates: th.Tensor, hidden_gates: th.Tensor, hidden: th.Tensor) -> th.Tensor:
    """The gates and new state of ``torch.nn.GRUCell`` from its two projections (:func:`gru_cell`), in float32.

    :param input_gates: W_ih x + b_ih, (B, 3 hidden_size), gates in the order r, z, n (float32 or bfloat16)
    :param hidden_gates: W_hh h + b_hh, (B, 3 hidden_size)
    :param hidden: h, (B, hidden_size), float32
    :return: h', (B, hidden_size), float32
    """
    return _gru_gates(input_gates, hidden_gates, hidden)[0]


def _gru_gates(input_gates: th.Tensor, hidden_gates: th.Tensor,
               hidden: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
    """:func:`gru_update` and what its backward reads: h', [r, z] (B, 2 hidden_size), n, W_hn h + b_hn and h - n."""
    size = hidden.shape[-1]
    input_gates, hidden_gates = input_gates.float(), hidden_gates.float()
    # r and z in one op (element-wise, so the same numbers as GRUCell's two where the rows are whole SIMD vectors)
    reset_update = th.sigmoid(input_gates[:, : 2 * size] + hidden_gates[:, : 2 * size])
    hidden_n = hidden_gates[:, 2 * size :]
    new = th.tanh(input_gates[:, 2 * size :] + reset_update[:, :size] * hidden_n)
    kept = hidden - new
    return kept * reset_update[:, size:] + new, reset_update, new, hidden_n, kept


class SequenceGRUCell:
    """One step of a GRU cell (:func:`gru_update` of its two projections) as one autograd node, in a recurrence whose
    projections are :class:`SequenceLinear`: the forward pass is :func:`gru_update`'s, the backward pass computes the
    gates' gradients in a few fused element-wise ops (instead of autograd's one node per op) and hands each projection's
    (gradient, input) pair to its :class:`SequenceLinear`, which sums the weight gradient once per sequence.

    :param input_linear: W_ih (or its recurrent columns) and b_ih (or None when an observed projection carries it)
    :param hidden_linear: W_hh and b_hh
    """

    def __init__(self, input_linear: SequenceLinear, hidden_linear: SequenceLinear) -> None:
        self.input_linear, self.hidden_linear = input_linear, hidden_linear

    def __call__(self, inputs: th.Tensor, added: th.Tensor | None, hidden: th.Tensor) -> th.Tensor:
        """h' for x_t ``inputs`` (B, K), c_t ``added`` (B, 3 hidden_size) or None and h ``hidden`` (B, hidden_size)."""
        if not (self.input_linear.tracked and self.hidden_linear.tracked):
            return gru_update(self.input_linear(inputs, added), self.hidden_linear(hidden), hidden)
        return _SequenceGRUStep.apply(inputs, added, hidden, self.input_linear.token, self.hidden_linear.token, self)


class SequenceLinear:
    """y_t = x_t W^T + b (+ c_t) applied at every step t of a recurrence, with the weight gradient computed once per
    sequence: sum_t g_t^T x_t as one GEMM over all T * B rows after the backward pass through time, as cuDNN's RNNs do,
    instead of one small GEMM and one accumulation of a full-size gradient per step. The input gradients g_t W stay per
    step (they are the recurrence). Under autocast the weight and bias are cast once to the autocast dtype (the GEMMs
    then run in it; the summed weight gradient is rounded once to it, not per step).

    Without gradients (``torch.no_grad`` or a weight that does not require them) it is the plain GEMM. A backward pass
    must reach the weight (``loss.backward()``, or ``torch.autograd.grad`` with respect to the parameters); one that
    asks only for other tensors' gradients would leave its per-step pairs behind for the next pass of a retained graph.

    :param weight: W, (N, K), a parameter or a differentiable view of one (a slice of a GRU's W_ih)
    :param bias: b, (N,), or None
    :param dtype: the GEMMs' dtype (the autocast dtype, or the weight's)
    :param deferred: sum the weight gradient once per sequence; ``False``: autograd's per-step weight gradients
    """

    def __init__(self, weight: th.Tensor, bias: th.Tensor | None, dtype: th.dtype, deferred: bool = True):
        self.dtype = dtype
        self.pairs: list[tuple[th.Tensor, th.Tensor]] = []  # (g_t, x_t), filled by the backward pass
        requires_grad = weight.requires_grad or (bias is not None and bias.requires_grad)
        self.tracked = deferred and th.is_grad_enabled() and requires_grad
        # cast once (differentiably when not tracked: autograd then sums the per-step weight gradients itself)
        self.weight = (weight.detach() if self.tracked else weight).to(dtype)
        self.bias = None if bias is None else (bias.detach() if self.tracked else bias).to(dtype)
        # a scalar whose backward node runs after every step's (it feeds all of them): the weight gradient is summed there
        self.token = _SequenceWeightGradient.apply(self, weight, bias) if self.tracked else None

    def __call__(self, inputs: th.Tensor, added: th.Tensor | None = None) -> th.Tensor:
        """x_t W^T + b + c_t for one step: ``inputs`` x_t (B, K), ``added`` c_t (B, N) or None; (B, N) in ``dtype``."""
        if not self.tracked:
            return _affine(inputs.to(self.dtype), self.weight, self.bias, added)
        return _SequenceLinearStep.apply(inputs, added, self.token, self)


def _affine(inputs: th.Tensor, weight: th.Tensor, bias: th.Tensor | None, added: th.Tensor | None) -> th.Tensor:
    if added is not None:
        return th.addmm(added.to(inputs.dtype) if bias is None else added.to(inputs.dtype) + bias, inputs, weight.t())
    return th.mm(inputs, weight.t()) if bias is None else th.addmm(bias, inputs, weight.t())


class _SequenceLinearStep(th.autograd.Function):
    @staticmethod
    def forward(ctx: Any, inputs: th.Tensor, added: th.Tensor | None, token: th.Tensor, linear: SequenceLinear) -> th.Tensor:
        cast = inputs.to(linear.dtype)
        ctx.save_for_backward(cast)
        ctx.linear, ctx.input_dtype = linear, inputs.dtype
        ctx.added_dtype = None if added is None else added.dtype
        return _affine(cast, linear.weight, linear.bias, added)

    @staticmethod
    def backward(ctx: Any, grad: th.Tensor) -> tuple[th.Tensor | None, ...]:
        (cast,) = ctx.saved_tensors
        linear: SequenceLinear = ctx.linear
        grad = grad.to(linear.dtype)
        linear.pairs.append((grad, cast))
        grad_inputs = th.mm(grad, linear.weight).to(ctx.input_dtype) if ctx.needs_input_grad[0] else None
        grad_added = grad.to(ctx.added_dtype) if ctx.added_dtype is not None and ctx.needs_input_grad[1] else None
        return grad_inputs, grad_added, th.zeros((), dtype=th.float32, device=grad.device), None


class _SequenceWeightGradient(th.autograd.Function):
    @staticmethod
    def forward(ctx: Any, linear: SequenceLinear, weight: th.Tensor, bias: th.Tensor | None) -> th.Tensor:
        ctx.linear = linear
        ctx.weight_dtype = weight.dtype
        ctx.has_bias = bias is not None
        return th.zeros((), dtype=th.float32, device=weight.device)

    @staticmethod
    def backward(ctx: Any, _: th.Tensor) -> tuple[th.Tensor | None, ...]:
        linear: SequenceLinear = ctx.linear
        if not linear.pairs:
            return None, None, None
        grads = th.cat([g for g, _ in linear.pairs])  # (T * B, N), steps in any order, rows matched with the inputs
        inputs = th.cat([x for _, x in linear.pairs])  # (T * B, K)
        linear.pairs = []  # (a retained graph's next backward pass fills them again)
        grad_weight = th.mm(grads.t(), inputs).to(ctx.weight_dtype) if ctx.needs_input_grad[1] else None
        grad_bias = grads.sum(0, dtype=th.float32).to(ctx.weight_dtype) if ctx.has_bias and ctx.needs_input_grad[2] else None
        return None, grad_weight, grad_bias


class _SequenceGRUStep(th.autograd.Function):
    @staticmethod
    def forward(ctx: Any, inputs: th.Tensor, added: th.Tensor | None, hidden: th.Tensor, input_token: th.Tensor,
                hidden_token: th.Tensor, cell: SequenceGRUCell) -> th.Tensor:
        input_linear, hidden_linear = cell.input_linear, cell.hidden_linear
        cast_inputs, cast_hidden = inputs.to(input_linear.dtype), hidden.to(hidden_linear.dtype)
        new_hidden, reset_update, new, hidden_n, kept = _gru_gates(
            _affine(cast_inputs, input_linear.weight, input_linear.bias, added),
            _affine(cast_hidden, hidden_linear.weight, hidden_linear.bias, None), hidden)
        ctx.save_for_backward(cast_inputs, cast_hidden, reset_update, new, hidden_n, kept)
        ctx.cell, ctx.input_dtype, ctx.hidden_dtype = cell, inputs.dtype, hidden.dtype
        ctx.added_dtype = None if added is None else added.dtype
        return new_hidden

    @staticmethod
    def backward(ctx: Any, grad: th.Tensor) -> tuple[th.Tensor | None, ...]:
        cast_inputs, cast_hidden, reset_update, new, hidden_n, kept = ctx.saved_tensors
        cell: SequenceGRUCell = ctx.cell
        input_linear, hidden_linear = cell.input_linear, cell.hidden_linear
        size = new.shape[-1]
        reset, update = reset_update[:, :size], reset_update[:, size:]
        grad = grad.float()
        # h' = (h - n) z + n;  n = tanh(a_n + r h_n);  [r, z] = sigmoid(a_rz + h_rz)
        grad_kept = grad * update
        grad_new = th.ops.aten.tanh_backward(grad - grad_kept, new)
        grad_reset_update = th.ops.aten.sigmoid_backward(th.cat([grad_new * hidden_n, grad * kept], dim=1), reset_update)
        grad_input_gates = th.cat([grad_reset_update, grad_new], dim=1).to(input_linear.dtype)  # (B, 3 hidden_size)
        grad_hidden_gates = th.cat([grad_reset_update, grad_new * reset], dim=1).to(hidden_linear.dtype)
        input_linear.pairs.append((grad_input_gates, cast_inputs))
        hidden_linear.pairs.append((grad_hidden_gates, cast_hidden))
        grad_inputs = th.mm(grad_input_gates, input_linear.weight).to(ctx.input_dtype) if ctx.needs_input_grad[0] else None
        grad_added = None
        if ctx.added_dtype is not None and ctx.needs_input_grad[1]:
            grad_added = grad_input_gates.to(ctx.added_dtype)
        grad_hidden = None
        if ctx.needs_input_grad[2]:
            grad_hidden = grad_kept + th.mm(grad_hidden_gates, hidden_linear.weight).to(ctx.hidden_dtype)
        zero = th.zeros((), dtype=th.float32, device=grad.device)
        return grad_inputs, grad_added, grad_hidden, zero, zero, None
