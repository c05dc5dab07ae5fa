"""``LatentSwarmPolicy``: the map / task / memory latent state of Sec. III, as an SB3 policy.

Per UAV i at step t, in the paper's order (all agents of all swarms at once, grouped by swarm with reshapes):

* message of UAV j: z_{t-1}^j = [mu_{t-1}^j ; tau_{t-1}^j]; aggregate over live in-links (Sec. III-B):
  m_t^i = mean_{j in N_t^i} z_{t-1}^j, split into m^mu and m^tau
* memory (Sec. III-A): rho_t = G_psi(rho_{t-1}, tau_{t-1}, o_{t-1}, mbar_{t-1})
* predictor (Sec. III-C): mhat_t = P_zeta(rho_t, o_t, e_t); best available message mbar_t = m_t if N_t^i is not
  empty, else mhat_t
* map (Sec. III-A): mu_t = E_phi(mu_{t-1}, o_t, p_t, m_t^mu) with m_t^mu = 0 when nothing arrived (the asymmetric
  update: the map state never sees a predicted message); decoder D_eta(mu_t) reconstructs M_hat_t
* task (Sec. III-A): tau_t = F_theta(tau_{t-1}, o_t, e_t, mu_{t-1}, mbar_t)
* actor (Sec. III-D): Gaussian pi_xi(a | tau_t) with mean and diagonal std from tau_t (``action_distribution``:
  the paper's Gaussian, or opt-in its tanh-squashed version whose actions stay in the [-1, 1] box)
* critic (Sec. III-D): V_omega(s_t), s_t = ({e_t^j}, M_hat_t) read from the global part of the observation

The actor side reads only ``local_obs``, ``proprio`` and ``link_row``; the critic only ``swarm_proprio`` and
``global_map``. No parameter depends on the number of agents N, so a policy trained with N = 3 runs with N = 5.
"""

from __future__ import annotations

import contextlib
import inspect
import math
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution, SquashedDiagGaussianDistribution, TanhBijector
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import Schedule
from torch import nn
from torch.distributions import Normal

from sb3_latentswarm.envs.observations import (
    ACTOR_OBS_KEYS,
    POSITION_DIMS,
    PROPRIO_POSITION,
    STATE_OBS_KEYS,
    as_vec_observation,
)
from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.latent_ppo.value_norm import ValueNorm
from sb3_latentswarm.utils.checks import check_choice, check_float, check_int
from sb3_latentswarm.utils.threads import apply_default_torch_threads_once

apply_default_torch_threads_once()  # the package's torch thread default (utils/threads.py), once per process

REQUIRED_KEYS = ACTOR_OBS_KEYS + STATE_OBS_KEYS
"""The first three entries of the proprioceptive state e_t are the (normalized) position p_t."""

ACTION_DISTRIBUTIONS = ("gaussian", "squashed_gaussian")
"""Values of ``action_distribution``: the paper's diagonal Gaussian, or the same Gaussian followed by tanh."""
LOG_STD_MAPPINGS = ("tanh", "clamp")
"""Values of ``log_std_mapping``: how the std head's raw output is bounded to ``log_std_bounds``."""
NEW_POLICY_KWARGS: dict[str, Any] = {"log_std_mapping": "tanh", "action_distribution": "gaussian"}
"""The defaults a new model is built with; ``LatentSwarmPPO`` writes them into its ``policy_kwargs`` so that its file
records them."""
LEGACY_POLICY_KWARGS: dict[str, Any] = {"log_std_mapping": "clamp", "action_distribution": "gaussian"}
"""What a model file saved before these keyword arguments existed was built with: it loads with these values and acts
exactly as before."""


AUTOCAST_MODES = (None, "bf16")
"""Values of ``autocast``: ``None`` (float32 everywhere, the default) or ``"bf16"`` (bfloat16 autocast of the latent
forward pass: GRUs, message predictor, map decoder, critic trunk)."""


def with_legacy_defaults(policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """The saved ``policy_kwargs`` of a model file, completed with :data:`LEGACY_POLICY_KWARGS` where a key is missing."""
    return {**LEGACY_POLICY_KWARGS, **(policy_kwargs or {})}


def smooth_log_std(raw: th.Tensor, low: float, high: float) -> th.Tensor:
    """log std = low + (high - low) * (tanh(raw) + 1) / 2, CleanRL's SAC bound: smooth, non-zero slope everywhere.

    Computed as ``high - (high - low) * sigmoid(-2 raw)`` for raw >= 0 and ``low + (high - low) * sigmoid(2 raw)``
    below (the same function, since (tanh(x) + 1) / 2 = sigmoid(2x)): ``tanh(raw)`` rounds to exactly +-1 in float32
    once abs(raw) > 9, and its gradient with it, while these forms keep a non-zero gradient up to abs(raw) of about 40
    (where it reaches float32's smallest normal number).

    :param raw: the std head's output, any shape
    :return: the log std, same shape, strictly inside (low, high) for abs(raw) < 9
    """
    span = high - low
    return th.where(raw >= 0, high - span * th.sigmoid(-2.0 * raw), low + span * th.sigmoid(2.0 * raw))


def inverse_smooth_log_std(log_std: float, low: float, high: float) -> float:
    """The raw output that :func:`smooth_log_std` maps to ``log_std`` (which must lie strictly inside (low, high))."""
    return math.atanh(2.0 * (log_std - low) / (high - low) - 1.0)


def unvalidated_normal(mean_actions: th.Tensor, log_std: th.Tensor) -> Normal:
    """SB3's diagonal Gaussian N(mean, exp(log_std)^2), built without ``torch.distributions``' argument validation.

    Validation reads ``bool()`` of tensors (a host sync per check, several per minibatch); the arguments here are
    finite by construction (a linear head and a bounded log std). Per distribution rather than
    ``Distribution.set_default_validate_args(False)``, which would switch it off for the user's code too.
    """
    action_std = th.ones_like(mean_actions) * log_std.exp()
    return Normal(mean_actions, action_std, validate_args=False)


class UnvalidatedDiagGaussianDistribution(DiagGaussianDistribution):
    """SB3's :class:`~stable_baselines3.common.distributions.DiagGaussianDistribution` without argument validation
    (:func:`unvalidated_normal`): the same numbers, no host syncs."""

    def proba_distribution(self, mean_actions: th.Tensor, log_std: th.Tensor) -> UnvalidatedDiagGaussianDistribution:
        self.distribution = unvalidated_normal(mean_actions, log_std)
        return self


class TanhSquashedGaussianDistribution(SquashedDiagGaussianDistribution):
    """SB3's :class:`~stable_baselines3.common.distributions.SquashedDiagGaussianDistribution` (a = tanh(u),
    u ~ N(mean, std^2)) with the exact change of variables in :meth:`log_prob`.

    SB3 subtracts ``log(1 - a^2 + 1e-6)``: the 1e-6 shifts the log-probability of a saturated action by up to 1.6
    nats per dimension, and it flattens the sampled entropy estimate once abs(u) passes about 7, so that estimate stops
    pulling the actor back from saturation. Here log(da/du) = log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)),
    exact and finite for every u. ``entropy()`` stays ``None`` (no closed form): see
    :meth:`LatentSwarmPolicy.action_entropy`. Built without argument validation (:func:`unvalidated_normal`).
    """

    def proba_distribution(self, mean_actions: th.Tensor, log_std: th.Tensor) -> TanhSquashedGaussianDistribution:
        self.distribution = unvalidated_normal(mean_actions, log_std)
        return self

    def log_prob(self, actions: th.Tensor, gaussian_actions: th.Tensor | None = None) -> th.Tensor:
        """log pi(a) = log N(u; mean, std^2) - sum_k log(1 - tanh(u_k)^2), (B,).

        :param actions: squashed actions a in [-1, 1], (B, action_dim)
        :param gaussian_actions: u with a = tanh(u), when known; otherwise u = atanh(a), with a clipped to
            [-1 + eps, 1 - eps] (float eps) as SB3 does, so that a saturated a = +-1 has a finite log-probability
        """
        if gaussian_actions is None:
            gaussian_actions = TanhBijector.inverse(actions)
        log_prob = DiagGaussianDistribution.log_prob(self, gaussian_actions)
        log_det = 2.0 * (math.log(2.0) - gaussian_actions - F.softplus(-2.0 * gaussian_actions))
        return log_prob - log_det.sum(dim=-1)


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


MESSAGE_SUBSTITUTES = ("predicted", "zero", "hold_last", "own_message")
"""What replaces the aggregated message m_t at a step with no live in-link (dropout), ``mbar_t = m_t if N_t^i != {}``
else the substitute:

===============  ===========================================================================================
``predicted``    mhat_t = P_zeta(rho_t, o_t, e_t), the memory-conditioned predictor (Sec. III-C; the paper)
``zero``         a zero vector (the paper's "No predictor" ablation)
``hold_last``    the last message actually received in the episode, zero before the first (extension)
``own_message``  the agent's own message z_{t-1}^i (extension)
===============  ===========================================================================================
"""


class StepInputs(NamedTuple):
    """What a latent step reads from the observation, before the recurrence (:meth:`LatentSwarmPolicy.step_inputs`).

    Leading dims ``(...)``: ``(B,)`` for one step, ``(T, B)`` for a training sequence (then indexed per step)."""

    keep: th.Tensor
    """1 - episode_start, (..., B, 1): the carried state is zeroed where an episode starts."""
    local_obs: th.Tensor
    """o_t, flattened, float32, (..., B, o_dim)."""
    proprio: th.Tensor
    """e_t, float32, (..., B, e_dim)."""
    position: th.Tensor
    """p_t, the first entries of e_t, (..., B, 3)."""
    link_mask: th.Tensor
    """[..., s, i, j] = 1 iff the link j -> i of swarm s delivered at t, (..., n_swarms, N, N)."""
    in_degree: th.Tensor
    """The in-degree ``max(len(N_t^i), 1)``, at least 1 (the divisor of the message mean), (..., n_swarms, N, 1)."""
    has_message: th.Tensor
    """Whether N_t^i is not empty, (..., B) bool."""


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
    input_r, input_z, input_n = input_gates.float().chunk(3, dim=-1)
    hidden_r, hidden_z, hidden_n = hidden_gates.float().chunk(3, dim=-1)
    reset = th.sigmoid(input_r + hidden_r)
    update = th.sigmoid(input_z + hidden_z)
    new = th.tanh(input_n + reset * hidden_n)
    return (hidden - new) * update + new


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


class SequenceEvaluation(NamedTuple):
    """Outputs of :meth:`LatentSwarmPolicy.evaluate_sequences`, time-major ``(T, B, ...)``."""

    values: th.Tensor
    """The critic's raw output: normalized values when the policy normalizes values, returns otherwise."""
    log_prob: th.Tensor
    entropy: th.Tensor
    map_reconstruction: th.Tensor
    """D_eta(mu_t), (T, B, grid_height * grid_width)."""
    received_message: th.Tensor
    predicted_message: th.Tensor
    has_message: th.Tensor


def _mlp(sizes: list[int], activation: type[nn.Module] = nn.Tanh) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(activation())
    return nn.Sequential(*layers)


class LatentSwarmPolicy(BasePolicy):
    """Actor-critic policy with per-UAV map, task and memory GRU states and latent message passing.

    :param observation_space: Dict space with keys ``local_obs``, ``proprio``, ``link_row``, ``swarm_proprio``,
        ``global_map`` (as produced by :class:`~sb3_latentswarm.envs.SwarmReconEnv`)
    :param action_space: Box action space
    :param lr_schedule: learning rate schedule
    :param latent_dim: default size of every latent state (paper: d_mu = d_tau = d_rho = 512)
    :param map_dim: d_mu, size of the map state (default ``latent_dim``)
    :param task_dim: d_tau, size of the task state (default ``latent_dim``)
    :param memory_dim: d_rho, size of the memory state (default ``latent_dim``)
    :param predictor_hidden: hidden width of the message predictor P_zeta
    :param decoder_hidden: hidden width of the map decoder D_eta
    :param critic_hidden: hidden width of the centralized critic V_omega
    :param actor_hidden: hidden width of the actor head on tau_t
    :param log_std_init: initial log std of the Gaussian actor (the std head's bias, or the state-independent
        parameter, is set so that the mapped log std equals it)
    :param log_std_bounds: the range of the log std (``(-5, 2)`` by default; ``(-5, 0)`` keeps the std at most 1, half
        the width of the [-1, 1] action box, so most sampled actions land inside it)
    :param log_std_mapping: how the std head's raw output x is bounded: ``"tanh"`` (new models):
        log std = lo + (hi - lo) (tanh(x) + 1) / 2 as CleanRL's SAC (:func:`smooth_log_std`), non-zero gradient at every
        x; ``"clamp"``: clamp(x, lo, hi), zero gradient outside the bounds (models saved before this option existed
        load with it, see :data:`LEGACY_POLICY_KWARGS`). ``log_std_init`` must lie strictly inside the bounds for
        ``"tanh"``
    :param action_distribution: ``"gaussian"``: the paper's diagonal Gaussian (actions outside the box are clipped by
        the env); ``"squashed_gaussian"``: a = tanh(u), u Gaussian (:class:`TanhSquashedGaussianDistribution`), every
        action inside the [-1, 1] box, the mean action is tanh(mean). Its entropy has no closed form: the PPO entropy
        bonus uses a one-sample estimate (:meth:`action_entropy`). Needs a Box action space bounded by [-1, 1]
    :param state_dependent_std: ``True``: the log std is a linear head on tau_t like the mean (the paper's pi(a | tau));
        ``False``: one learned log std per action dimension, as SB3's default Gaussian policy
    :param normalize_value: the critic learns normalized returns (MAPPO's ValueNorm); :meth:`predict_values` returns
        them denormalized, in return units
    :param value_norm_beta: weight of the old statistics in each (per-update) ValueNorm update
    :param ortho_init: orthogonal initialization of the linear layers (as SB3's ActorCriticPolicy)
    :param optimizer_class: optimizer (default Adam)
    :param optimizer_kwargs: optimizer keyword arguments (default ``eps=1e-5`` as SB3's PPO)
    :param message_substitute: what replaces m_t during dropout, one of :data:`MESSAGE_SUBSTITUTES` (default
        ``"predicted"``, the paper's predictor); training with ``"zero"`` or ``"hold_last"`` gives the fair
        "no predictor" learners of the sweep's ``zero_substitute`` / ``hold_last`` variants
    :param no_predictor: the paper's ablation, the same as ``message_substitute="zero"`` (kept for old files and
        callers: reading it says whether the substitute is ``"zero"``, setting it switches between ``"zero"`` and
        ``"predicted"``)
    :param no_memory: ablation: rho is zeroed before every use
    """

    # narrowed from BasePolicy's Space: __init__ accepts only these
    observation_space: spaces.Dict
    action_space: spaces.Box

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        latent_dim: int = 512,
        map_dim: int | None = None,
        task_dim: int | None = None,
        memory_dim: int | None = None,
        predictor_hidden: int = 256,
        decoder_hidden: int = 256,
        critic_hidden: int = 256,
        actor_hidden: int = 64,
        log_std_init: float = 0.0,
        log_std_bounds: tuple[float, float] = (-5.0, 2.0),
        log_std_mapping: str = NEW_POLICY_KWARGS["log_std_mapping"],
        action_distribution: str = NEW_POLICY_KWARGS["action_distribution"],
        state_dependent_std: bool = True,
        normalize_value: bool = False,
        value_norm_beta: float = 0.995,
        ortho_init: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        no_predictor: bool = False,
        no_memory: bool = False,
        message_substitute: str = "predicted",
        **unused_kwargs: Any,
    ):
        if unused_kwargs:
            # RecurrentPPO passes use_sde; anything else is a typo the user should hear about
            unexpected = set(unused_kwargs) - {"use_sde"}
            if unexpected:
                raise TypeError(_unexpected_kwargs_message(unexpected))
            if unused_kwargs.get("use_sde"):
                raise ValueError("LatentSwarmPolicy does not support use_sde=True")
        check_observation_space(observation_space)
        if not isinstance(action_space, spaces.Box):
            raise TypeError(f"LatentSwarmPolicy needs a Box action space, got {action_space}")
        check_choice("log_std_mapping", log_std_mapping, LOG_STD_MAPPINGS)
        check_choice("action_distribution", action_distribution, ACTION_DISTRIBUTIONS)
        squashed = action_distribution == "squashed_gaussian"
        if squashed and not (np.all(action_space.low == -1.0) and np.all(action_space.high == 1.0)):
            raise ValueError(
                f"action_distribution='squashed_gaussian' produces actions in [-1, 1]; the action space is {action_space}"
            )
        if optimizer_kwargs is None:
            optimizer_kwargs = {"eps": 1e-5}
        super().__init__(
            observation_space,
            action_space,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            normalize_images=False,
            squash_output=squashed,
        )
        sizes = {"latent_dim": latent_dim, "map_dim": map_dim, "task_dim": task_dim, "memory_dim": memory_dim,
                 "predictor_hidden": predictor_hidden, "decoder_hidden": decoder_hidden, "critic_hidden": critic_hidden,
                 "actor_hidden": actor_hidden}
        for name, value in sizes.items():  # network widths: ints >= 1; map/task/memory_dim None means latent_dim
            if value is not None or name not in ("map_dim", "task_dim", "memory_dim"):
                check_int(name, value, low=1)
        self.latent_dim = latent_dim
        self.map_dim = map_dim or latent_dim
        self.task_dim = task_dim or latent_dim
        self.memory_dim = memory_dim or latent_dim
        self.message_dim = self.map_dim + self.task_dim
        self.predictor_hidden = predictor_hidden
        self.decoder_hidden = decoder_hidden
        self.critic_hidden = critic_hidden
        self.actor_hidden = actor_hidden
        self.log_std_init = log_std_init
        self.log_std_bounds = _check_log_std_bounds(log_std_bounds)
        self.log_std_mapping = log_std_mapping
        self.action_distribution_name = action_distribution
        low, high = self.log_std_bounds
        if log_std_mapping == "tanh":
            check_float(f"log_std_init (log_std_mapping='tanh', log_std_bounds {self.log_std_bounds})", log_std_init,
                        low, high, low_open=True, high_open=True)
            self._raw_log_std_init = inverse_smooth_log_std(float(log_std_init), low, high)
        else:
            if not low <= log_std_init <= high:
                raise ValueError(f"log_std_init must lie in log_std_bounds {self.log_std_bounds}, got {log_std_init}")
            self._raw_log_std_init = float(log_std_init)
        self.state_dependent_std = bool(state_dependent_std)
        self.normalize_value = bool(normalize_value)
        self.value_norm_beta = value_norm_beta
        self.ortho_init = ortho_init
        self.message_substitute = check_choice("message_substitute", message_substitute, MESSAGE_SUBSTITUTES)
        if no_predictor:
            if message_substitute not in ("predicted", "zero"):
                raise ValueError(f"no_predictor=True contradicts message_substitute={message_substitute!r}")
            self.message_substitute = "zero"
        self.no_memory = no_memory

        self.local_obs_dim = int(np.prod(_space_shape(observation_space["local_obs"])))
        self.proprio_dim = int(_space_shape(observation_space["proprio"])[-1])
        self.map_shape = tuple(_space_shape(observation_space["global_map"]))
        self.n_cells = int(np.prod(self.map_shape))
        self.action_dim = int(np.prod(action_space.shape))
        o_dim, e_dim, d_mu, d_tau, d_rho, d_msg = (
            self.local_obs_dim,
            self.proprio_dim,
            self.map_dim,
            self.task_dim,
            self.memory_dim,
            self.message_dim,
        )

        # E_phi(mu_{t-1}; o_t, p_t, m^mu_t)
        self.map_encoder = nn.GRUCell(o_dim + POSITION_DIMS + d_mu, d_mu)
        # D_eta(mu_t) -> M_hat_t
        self.map_decoder = _mlp([d_mu, decoder_hidden, self.n_cells], nn.ReLU)
        # F_theta(tau_{t-1}; o_t, e_t, mu_{t-1}, mbar_t)
        self.task_encoder = nn.GRUCell(o_dim + e_dim + d_mu + d_msg, d_tau)
        # G_psi(rho_{t-1}; tau_{t-1}, o_{t-1}, mbar_{t-1})
        self.memory_encoder = nn.GRUCell(d_tau + o_dim + d_msg, d_rho)
        # P_zeta(rho_t, o_t, e_t) -> mhat_t
        self.message_predictor = _mlp([d_rho + o_dim + e_dim, predictor_hidden, d_msg])
        # pi_xi(a | tau_t): mean and diagonal log std (raw outputs, bounded by bound_log_std)
        self.actor_trunk = nn.Sequential(nn.Linear(d_tau, actor_hidden), nn.Tanh())
        self.action_mean = nn.Linear(actor_hidden, self.action_dim)
        if self.state_dependent_std:
            self.action_log_std = nn.Linear(actor_hidden, self.action_dim)
        else:
            self.log_std = nn.Parameter(th.full((self.action_dim,), self._raw_log_std_init))
        # V_omega(s_t), s_t = ({e_t^j}_j, M_hat_t): map encoder + mean-pooled proprio encoder, N-independent
        self.critic_map = nn.Sequential(nn.Linear(self.n_cells, critic_hidden), nn.ReLU())
        self.critic_agents = nn.Sequential(nn.Linear(e_dim, critic_hidden // 4), nn.ReLU())
        self.critic_head = _mlp([critic_hidden + critic_hidden // 4, critic_hidden, 1], nn.ReLU)
        self.value_normalizer = ValueNorm(beta=value_norm_beta) if self.normalize_value else None
        gaussian: type[DiagGaussianDistribution] = (
            TanhSquashedGaussianDistribution if squashed else UnvalidatedDiagGaussianDistribution
        )
        self.action_dist = gaussian(self.action_dim)
        self._compiled_latent_step: Callable[..., StepOutput] | None = None
        self.autocast = None

        if ortho_init:
            self._init_weights()
        self.optimizer = self.optimizer_class(  # type: ignore[call-arg]  # torch types Optimizer(params, defaults); Adam & co take lr
            self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )

    # ------------------------------------------------------------------ construction helpers
    def _init_weights(self) -> None:
        for module in self.modules():
            if isinstance(module, nn.Linear):
                nn.init.orthogonal_(module.weight, gain=np.sqrt(2))
                nn.init.zeros_(module.bias)
        nn.init.orthogonal_(self.action_mean.weight, gain=0.01)
        if self.state_dependent_std:
            nn.init.orthogonal_(self.action_log_std.weight, gain=0.01)
            nn.init.constant_(self.action_log_std.bias, self._raw_log_std_init)
        value_head = self.critic_head[-1]
        assert isinstance(value_head, nn.Linear)  # _mlp ends with a Linear layer
        nn.init.orthogonal_(value_head.weight, gain=1.0)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            latent_dim=self.latent_dim,
            map_dim=self.map_dim,
            task_dim=self.task_dim,
            memory_dim=self.memory_dim,
            predictor_hidden=self.predictor_hidden,
            decoder_hidden=self.decoder_hidden,
            critic_hidden=self.critic_hidden,
            actor_hidden=self.actor_hidden,
            log_std_init=self.log_std_init,
            log_std_bounds=self.log_std_bounds,
            log_std_mapping=self.log_std_mapping,
            action_distribution=self.action_distribution_name,
            state_dependent_std=self.state_dependent_std,
            normalize_value=self.normalize_value,
            value_norm_beta=self.value_norm_beta,
            ortho_init=self.ortho_init,
            lr_schedule=self._dummy_schedule,
            no_memory=self.no_memory,
            message_substitute=self.message_substitute,
        )
        return data

    @property
    def no_predictor(self) -> bool:
        """The paper's "No predictor" ablation: ``message_substitute == "zero"``."""
        return self.message_substitute == "zero"

    @no_predictor.setter
    def no_predictor(self, value: bool) -> None:
        self.message_substitute = "zero" if value else "predicted"

    @property
    def latent_dims(self) -> tuple[int, ...]:
        """Sizes of the :class:`LatentState` fields, in field order."""
        return (self.map_dim, self.task_dim, self.memory_dim, self.local_obs_dim, self.message_dim, self.message_dim)

    def initial_state(self, n_slots: int) -> LatentState:
        """All-zero latent state for ``n_slots`` agents (the state at an episode start)."""
        return LatentState(*(th.zeros(n_slots, dim, device=self.device) for dim in self.latent_dims))

    # ------------------------------------------------------------------ the latent step (Sec. III)
    def latent_step(self, obs: dict[str, th.Tensor], state: LatentState, episode_starts: th.Tensor) -> StepOutput:
        """One step of every latent update for a batch of whole swarms (:meth:`step_inputs`, then
        :meth:`recurrent_step`).

        :param obs: actor observation tensors of step t with leading dim B = n_swarms * n_agents (env-major)
        :param state: the state carried in from step t-1
        :param episode_starts: (B,) 1.0 where obs is the first of an episode: the state is reset to zero there
        :raise ValueError: when B is not a whole number of swarms
        """
        return self.recurrent_step(self.step_inputs(obs, episode_starts), state)

    def step_inputs(self, obs: dict[str, th.Tensor], episode_starts: th.Tensor) -> StepInputs:
        """What the latent step reads from the observation and the episode starts: the conversions and link
        statistics that do not depend on the recurrence. Any leading dims: one step (B,) in rollouts, a whole training
        sequence (T, B) at once in :meth:`evaluate_sequences` (element-wise, so the numbers are the same).

        :param obs: actor observation tensors, (..., B, ...)
        :param episode_starts: (..., B)
        :raise ValueError: when B is not a whole number of swarms
        """
        link_row = obs["link_row"].float()  # (..., B, N)
        n_agents, batch = link_row.shape[-1], link_row.shape[-2]
        if batch % n_agents != 0:
            raise ValueError(f"The batch of {batch} slots is not a whole number of swarms of {n_agents} agents")
        # [..., s, i, j] = 1 iff j -> i delivered at t
        link_mask = link_row.view(*link_row.shape[:-2], batch // n_agents, n_agents, n_agents)
        in_degree = link_mask.sum(-1, keepdim=True)  # |N_t^i|, (..., n_swarms, N, 1)
        proprio = obs["proprio"].float()  # (..., B, e_dim)
        return StepInputs(
            keep=(1.0 - episode_starts.float()).unsqueeze(-1),
            local_obs=obs["local_obs"].float().flatten(episode_starts.dim()),
            proprio=proprio,
            position=proprio[..., PROPRIO_POSITION],
            link_mask=link_mask,
            in_degree=in_degree.clamp(min=1.0),
            has_message=(in_degree > 0).view(link_row.shape[:-1]),
        )

    def recurrent_step(self, inputs: StepInputs, state: LatentState) -> StepOutput:
        """The latent updates of one step (Sec. III), under the policy's :attr:`autocast` (compiled after
        :meth:`compile_latent_step`); outputs in float32.

        :param inputs: :meth:`step_inputs` of this step, leading dim B
        :param state: the state carried in from step t-1, (B, ...) per field
        """
        step = self._eager_recurrent_step if self._compiled_latent_step is None else self._compiled_latent_step
        if self.autocast is None:
            return step(inputs, state)
        with self.latent_autocast():
            out = step(inputs, state)
        return StepOutput(
            LatentState(*(field.float() for field in out.state)),
            out.received_message.float(),
            out.predicted_message.float(),
            out.has_message,
            out.sent_message.float(),
        )

    def compile_latent_step(self, **compile_kwargs: Any) -> None:
        """Run the latent updates of :meth:`recurrent_step` through ``torch.compile`` from now on (rollouts and
        training).

        Compilation is lazy: the first call with each new batch size and grad mode compiles (tens of seconds per
        graph on a CPU with the default inductor backend), later calls reuse the graph.

        :param compile_kwargs: keyword arguments of ``torch.compile`` (e.g. ``backend``, ``mode``)
        """
        self._compiled_latent_step = th.compile(self._eager_recurrent_step, **compile_kwargs)

    @property
    def autocast(self) -> str | None:
        """``None`` (float32) or ``"bf16"``: bfloat16 autocast of the latent forward pass (GRU and predictor GEMMs, map
        decoder, critic trunk); the latent state, the action heads, log-probabilities and values stay float32.

        :raise ValueError: when set to a value not in :data:`AUTOCAST_MODES`
        """
        return self._autocast

    @autocast.setter
    def autocast(self, value: str | None) -> None:
        self._autocast = check_choice("autocast", value, AUTOCAST_MODES)

    def latent_autocast(self) -> contextlib.AbstractContextManager[Any]:
        """The autocast context of the latent forward pass: bfloat16 with ``autocast="bf16"``, nothing otherwise."""
        if self.autocast is None:
            return contextlib.nullcontext()
        return th.autocast(self.device.type, dtype=th.bfloat16)

    def _gru(self, cell: nn.GRUCell, inputs: th.Tensor, hidden: th.Tensor) -> th.Tensor:
        # GRUCell's own kernel is not autocast on CPU: under autocast its equations go through gru_cell's F.linear
        return cell(inputs, hidden) if self.autocast is None else gru_cell(inputs, hidden, cell)

    def _eager_recurrent_step(self, inputs: StepInputs, state: LatentState) -> StepOutput:
        map_prev, task_prev, memory_prev, local_prev, message_prev, held_prev = (field * inputs.keep for field in state)
        local_obs, proprio, has_message = inputs.local_obs, inputs.proprio, inputs.has_message  # (B, o_dim), (B, e_dim), (B,)
        n_swarms, n_agents = inputs.link_mask.shape[:2]
        batch = n_swarms * n_agents

        # Sec. III-B: z_{t-1}^j = [mu_{t-1}^j; tau_{t-1}^j],  m_t^i = mean_{j in N_t^i} z_{t-1}^j
        sent_message = th.cat([map_prev, task_prev], dim=-1)  # z_{t-1}^i, (B, d_msg)
        messages = sent_message.view(n_swarms, n_agents, self.message_dim)
        received_message = (th.bmm(inputs.link_mask, messages) / inputs.in_degree).view(batch, self.message_dim)

        # Sec. III-A: rho_t = G_psi(rho_{t-1}, tau_{t-1}, o_{t-1}, mbar_{t-1})   (no_memory: rho zeroed before use)
        if self.no_memory:
            memory_prev = th.zeros_like(memory_prev)
        memory_state = self._gru(self.memory_encoder, th.cat([task_prev, local_prev, message_prev], dim=-1), memory_prev)
        memory_used = th.zeros_like(memory_state) if self.no_memory else memory_state

        # Sec. III-C: mhat_t = P_zeta(rho_t, o_t, e_t);  mbar_t = m_t if N_t^i != {} else mhat_t
        predicted_message = self.message_predictor(th.cat([memory_used, local_obs, proprio], dim=-1))
        # (extensions: hold_last / own_message / zero replace mhat_t; see MESSAGE_SUBSTITUTES)
        received_now = has_message.unsqueeze(-1)
        held_message = th.where(received_now, received_message, held_prev)
        if self.message_substitute == "predicted":
            substitute = predicted_message
        elif self.message_substitute == "zero":
            substitute = th.zeros_like(predicted_message)
        elif self.message_substitute == "hold_last":
            substitute = held_prev
        else:  # own_message
            substitute = sent_message
        best_message = th.where(received_now, received_message, substitute)

        # Sec. III-A, asymmetric update: mu_t = E_phi(mu_{t-1}, o_t, p_t, m^mu_t), m^mu_t = 0 when nothing arrived
        # (received_message is already zero there, so the predictor never reaches the map state)
        map_message = received_message[:, : self.map_dim]
        map_state = self._gru(self.map_encoder, th.cat([local_obs, inputs.position, map_message], dim=-1), map_prev)

        # Sec. III-A: tau_t = F_theta(tau_{t-1}, o_t, e_t, mu_{t-1}, mbar_t)
        task_state = self._gru(self.task_encoder, th.cat([local_obs, proprio, map_prev, best_message], dim=-1), task_prev)

        new_state = LatentState(map_state, task_state, memory_state, local_obs, best_message, held_message)
        return StepOutput(new_state, received_message, predicted_message, has_message, sent_message)

    # ------------------------------------------------------------------ heads
    def bound_log_std(self, raw: th.Tensor) -> th.Tensor:
        """The log std for a raw std output (``log_std_mapping``), inside ``log_std_bounds``; same shape."""
        if self.log_std_mapping == "clamp":
            return raw.clamp(*self.log_std_bounds)
        return smooth_log_std(raw, *self.log_std_bounds)

    def action_distribution(self, task_state: th.Tensor) -> DiagGaussianDistribution:
        """pi_xi(a | tau_t) (Sec. III-D): Gaussian with state-dependent mean and diagonal std, tanh-squashed when
        ``action_distribution="squashed_gaussian"`` (then a :class:`TanhSquashedGaussianDistribution`).

        :param task_state: tau_t, (B, d_tau)
        :return: SB3 distribution over (B, action_dim) actions; ``.distribution`` is the Gaussian before squashing
        """
        hidden = self.actor_trunk(task_state)
        mean_actions = self.action_mean(hidden)
        if self.state_dependent_std:
            log_std = self.action_log_std(hidden)
        else:
            log_std = self.log_std.expand_as(mean_actions)
        return self.action_dist.proba_distribution(mean_actions, self.bound_log_std(log_std))

    def actions_from_noise(self, task_state: th.Tensor, noise: th.Tensor | np.ndarray | None = None) -> th.Tensor:
        """Actions of pi_xi(a | tau_t) for given standard-normal noise: the one place that turns the actor's outputs
        into actions outside SB3's sampling (evaluation draws the noise from its own per-episode generators).

        :param task_state: tau_t, (B, d_tau)
        :param noise: eps ~ N(0, I), (B, action_dim); ``None``: the mean action
        :return: (B, action_dim): mean + std * eps (mean when ``noise`` is None), passed through tanh for the squashed
            Gaussian; in the noise's dtype when it is wider than float32
        """
        gaussian = self.action_distribution(task_state).distribution
        actions = gaussian.mean
        if noise is not None:
            actions = actions + gaussian.stddev * th.as_tensor(noise, device=actions.device)
        return th.tanh(actions) if self.squash_output else actions

    @staticmethod
    def action_entropy(distribution: DiagGaussianDistribution) -> th.Tensor:
        """The entropy of each row of ``distribution``, (B,): exact for the Gaussian; for the squashed Gaussian, which
        has no closed form, the one-sample estimate -log pi(tanh(u)) with a reparameterized u ~ N(mean, std^2), as
        SB3's SAC does. Its gradient is an unbiased estimate of the entropy's gradient (SB3's PPO instead uses
        -log pi of the stored action, whose expected gradient is zero at the rollout's policy)."""
        entropy = distribution.entropy()
        if entropy is not None:
            return entropy
        # only the squashed Gaussian has no closed-form entropy; its log_prob takes the pre-squash actions too
        assert isinstance(distribution, SquashedDiagGaussianDistribution)
        gaussian_actions = distribution.distribution.rsample()
        return -distribution.log_prob(th.tanh(gaussian_actions), gaussian_actions)

    @property
    def critic_parameters(self) -> list[nn.Parameter]:
        """Parameters of V_omega only (they read the global state, nothing else reads them)."""
        return [p for module in (self.critic_map, self.critic_agents, self.critic_head) for p in module.parameters()]

    def predict_values(self, obs: dict[str, th.Tensor]) -> th.Tensor:
        """V_omega(s_t) in return units for every slot, (B, 1) (denormalized when the critic learns normalized values)."""
        values = self.critic_output(obs)
        return values if self.value_normalizer is None else self.value_normalizer.denormalize(values)

    def critic_output(self, obs: dict[str, th.Tensor]) -> th.Tensor:
        """The critic's raw output for every slot, (B, 1); computed once per swarm and broadcast to its agents."""
        swarm_proprio = obs["swarm_proprio"]  # (B, N, e_dim)
        n_agents = swarm_proprio.shape[-2]
        batch_shape = swarm_proprio.shape[:-2]
        # each swarm's global state (repeated for its agents) is selected before the float conversion
        flat_proprio = swarm_proprio.reshape(-1, n_agents, n_agents, self.proprio_dim)[:, 0].float()  # (n_swarms, N, e_dim)
        flat_map = obs["global_map"].reshape(-1, n_agents, self.n_cells)[:, 0].float()  # (n_swarms, n_cells)
        with self.latent_autocast():
            features = th.cat([self.critic_map(flat_map), self.critic_agents(flat_proprio).mean(dim=1)], dim=-1)
            values = self.critic_head(features).float()  # (n_swarms, 1)
        return values.repeat_interleave(n_agents, dim=0).reshape(*batch_shape, 1)

    def decode_map(self, map_state: th.Tensor) -> th.Tensor:
        """D_eta(mu_t): the reconstruction of M_hat_t, flattened row-major, float32 (computed under :attr:`autocast`).

        :param map_state: mu_t, (..., d_mu)
        :return: (..., grid_height * grid_width)
        """
        with self.latent_autocast():
            return self.map_decoder(map_state).float()

    # ------------------------------------------------------------------ SB3 entry points
    def forward(
        self,
        obs: dict[str, th.Tensor],
        latent_state: LatentState,
        episode_starts: th.Tensor,
        deterministic: bool = False,
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor, LatentState]:
        """One rollout step: actions, values, log-probabilities and the new latent state."""
        step = self.latent_step(obs, latent_state, episode_starts)
        distribution = self.action_distribution(step.state.task_state)
        actions = distribution.get_actions(deterministic=deterministic)
        # from the action itself, as the replay in evaluate_sequences computes it from the stored one (for the squashed
        # Gaussian u = atanh(a), not the sampled u: atanh(tanh(u)) differs from u by up to 1e-3 in float32 near |a| = 1)
        log_prob = distribution.log_prob(actions)
        values = self.predict_values(obs)
        return actions, values, log_prob, step.state

    def evaluate_sequences(
        self,
        obs: dict[str, th.Tensor],
        actions: th.Tensor,
        initial_state: LatentState,
        episode_starts: th.Tensor,
    ) -> SequenceEvaluation:
        """Replay time-major sequences of whole swarms from their stored initial state (for ``train``).

        :param obs: tensors of shape (T, B, ...)
        :param actions: (T, B, action_dim)
        :param initial_state: state carried into the first step, (B, ...)
        :param episode_starts: (T, B)
        """
        n_steps = actions.shape[0]
        # one autocast region for the sequence (with autocast="bf16"): each weight is cast to bf16 once, not per step
        with self.latent_autocast():
            task_state, map_state, received, predicted, has_message = self._replay_latent(obs, initial_state, episode_starts)
            critic_obs = {key: obs[key].flatten(0, 1) for key in STATE_OBS_KEYS}
            values = self.critic_output(critic_obs).view(n_steps, -1)
            map_reconstruction = self.decode_map(map_state)
        # the action heads and log-probabilities in float32
        distribution = self.action_distribution(task_state.flatten(0, 1))
        flat_actions = actions.flatten(0, 1)
        log_prob = distribution.log_prob(flat_actions).view(n_steps, -1)
        entropy = self.action_entropy(distribution).view(n_steps, -1)
        return SequenceEvaluation(
            values=values,
            log_prob=log_prob,
            entropy=entropy,
            map_reconstruction=map_reconstruction,
            received_message=received,
            predicted_message=predicted,
            has_message=has_message,
        )

    def sequence_log_prob(
        self, obs: dict[str, th.Tensor], actions: th.Tensor, initial_state: LatentState, episode_starts: th.Tensor
    ) -> th.Tensor:
        """log pi(a_t | tau_t) of time-major sequences, (T, B): the ``log_prob`` of :meth:`evaluate_sequences` (the same
        numbers), without the critic, the map decoder and the entropy (which samples for the squashed Gaussian)."""
        with self.latent_autocast():
            task_state = self._replay_latent(obs, initial_state, episode_starts)[0]
        return self.action_distribution(task_state.flatten(0, 1)).log_prob(actions.flatten(0, 1)).view(actions.shape[0], -1)

    def _replay_latent(
        self, obs: dict[str, th.Tensor], state: LatentState, episode_starts: th.Tensor
    ) -> tuple[th.Tensor, ...]:
        """tau_t, mu_t, m_t, mhat_t (T, B, dim each) and has_message (T, B) of time-major sequences (in the caller's
        autocast region)."""
        # what does not depend on the recurrence is prepared for all T steps at once
        inputs = self.step_inputs({key: obs[key] for key in ACTOR_OBS_KEYS}, episode_starts)
        if self.chunked_replay:
            return self._replay_latent_sequence(inputs, state)
        return self._replay_latent_steps(inputs, state)

    @property
    def chunked_replay(self) -> bool:
        """Whether :meth:`evaluate_sequences` replays with the chunk-batched GEMMs of :meth:`_replay_latent_sequence`
        (under :attr:`autocast`, and on devices other than the CPU) rather than one :meth:`recurrent_step` per step, the
        rollout's own computation (float32 on the CPU, and after :meth:`compile_latent_step`).

        Chosen by measurement (``docs/algorithm.md``, "The training replay"): on one CPU thread the batched replay makes
        a bf16 ``paper`` minibatch 1.21x faster, but a float32 one is GEMM-bound (0.99x) and a float32 d = 64 one is
        bound by per-op overhead in Python (0.86x), though it dispatches 22 % fewer aten ops, which is what a
        host-bound GPU step pays for.
        """
        return self._compiled_latent_step is None and (self.autocast is not None or self.device.type != "cpu")

    def _replay_latent_steps(self, inputs: StepInputs, state: LatentState) -> tuple[th.Tensor, ...]:
        """The latent updates of a training sequence, one :meth:`recurrent_step` per step (the rollout's computation).

        :return: tau_t, mu_t, m_t, mhat_t (T, B, dim each), has_message (T, B)
        """
        outputs: list[list[th.Tensor]] = [[], [], [], [], []]
        for t in range(inputs.keep.shape[0]):
            step = self.recurrent_step(StepInputs._make(field[t] for field in inputs), state)
            state = step.state
            for output, value in zip(outputs, (state.task_state, state.map_state, step.received_message,
                                               step.predicted_message, step.has_message)):
                output.append(value)
        return tuple(th.stack(output) for output in outputs)

    def _replay_latent_sequence(self, inputs: StepInputs, state: LatentState) -> tuple[th.Tensor, ...]:
        """The latent updates of a training sequence with the recurrence-free arithmetic batched over the chunk.

        The same equations as :meth:`recurrent_step` (``nn.GRUCell``'s r, z, n gates with b_ih and b_hh), arranged for
        time-major sequences: each GRU's input projection W_ih x is split by input columns into the part that reads the
        observations (o_t, e_t, p_t and the previous step's o_{t-1}), computed as one GEMM over all T * B rows before
        the loop, and the part that reads the recurrent state (messages, mu_{t-1}, tau_{t-1}, mbar_{t-1}), computed
        per step; likewise the first layer of the predictor P_zeta. When the substitute is not the predictor, mhat_t
        does not feed the recurrence and is computed after the loop for all rows at once. The sums of the split
        projections round differently from the rollout's one GEMM: float32 results agree with
        :meth:`_replay_latent_steps` to about 1e-6.

        :param inputs: :meth:`step_inputs` of the sequence, leading dims (T, B)
        :param state: the state carried into the first step, (B, ...) per field
        :return: tau_t, mu_t, m_t, mhat_t (T, B, dim each), has_message (T, B)
        """
        o_dim, e_dim, d_mu, d_tau, d_rho = self.local_obs_dim, self.proprio_dim, self.map_dim, self.task_dim, self.memory_dim
        n_steps, (n_swarms, n_agents) = inputs.keep.shape[0], inputs.link_mask.shape[1:3]
        batch = n_swarms * n_agents
        local_obs, proprio, keep = inputs.local_obs, inputs.proprio, inputs.keep  # (T, B, o_dim), (T, B, e_dim), (T, B, 1)
        map_cell, task_cell, memory_cell = self.map_encoder, self.task_encoder, self.memory_encoder
        predictor_in, predictor_out = cast(nn.Linear, self.message_predictor[0]), cast(nn.Linear, self.message_predictor[2])
        use_predictor = self.message_substitute == "predicted"

        # recurrence-free input projections, one GEMM each over T * B rows: the input columns of each W_ih (and of
        # P_zeta's first layer) that read o_t, p_t, e_t, o_{t-1}; the bias b_ih rides on them. Split into per-step views
        # by unbind, whose backward stacks the T gradients once (indexing [t] would zero-fill a (T, B, .) gradient per step)
        observed = th.cat([local_obs, proprio], dim=-1)  # (T, B, o_dim + e_dim)
        map_x = F.linear(th.cat([local_obs, inputs.position], dim=-1), map_cell.weight_ih[:, : o_dim + POSITION_DIMS],
                         map_cell.bias_ih).unbind(0)  # T x (B, 3 d_mu)
        task_x = F.linear(observed, task_cell.weight_ih[:, : o_dim + e_dim], task_cell.bias_ih).unbind(0)  # T x (B, 3 d_tau)
        # o_{t-1}: the stored one before the first step, zeroed at episode starts as the carried state is
        local_prev = th.cat([state.prev_local_obs.unsqueeze(0), local_obs[:-1]]) * keep
        memory_x = F.linear(local_prev, memory_cell.weight_ih[:, d_tau : d_tau + o_dim], memory_cell.bias_ih).unbind(0)
        if use_predictor:
            predictor_x = F.linear(observed, predictor_in.weight[:, d_rho:], predictor_in.bias).unbind(0)  # T x (B, hidden)
        # the GEMMs inside the recurrence: the columns of W_ih that read the recurrent state, and W_hh; each weight is
        # cast once to the autocast dtype and its gradient summed once over the sequence (SequenceLinear)
        dtype = th.get_autocast_dtype(self.device.type) if self.autocast is not None else map_cell.weight_ih.dtype
        map_in = SequenceLinear(map_cell.weight_ih[:, o_dim + POSITION_DIMS :], None, dtype)  # reads m^mu_t
        task_in = SequenceLinear(task_cell.weight_ih[:, o_dim + e_dim :], None, dtype)  # reads [mu_{t-1}; mbar_t]
        memory_columns = th.cat([memory_cell.weight_ih[:, :d_tau], memory_cell.weight_ih[:, d_tau + o_dim :]], dim=1)
        memory_in = SequenceLinear(memory_columns, None, dtype)  # reads [tau_{t-1}; mbar_{t-1}]
        map_hidden, task_hidden, memory_hidden = (SequenceLinear(cell.weight_hh, cell.bias_hh, dtype)
                                                  for cell in (map_cell, task_cell, memory_cell))
        if use_predictor:
            predictor_memory = SequenceLinear(predictor_in.weight[:, :d_rho], None, dtype)  # reads rho_t
            predictor_output = SequenceLinear(predictor_out.weight, predictor_out.bias, dtype)

        map_state, task_state, memory_state, message, held = state.map_state, state.task_state, state.memory_state, \
            state.prev_message, state.held_message
        outputs: list[list[th.Tensor]] = [[], [], [], [], []]
        for t in range(n_steps):
            keep_t = keep[t]
            map_prev, task_prev, memory_prev, message_prev, held_prev = (
                field * keep_t for field in (map_state, task_state, memory_state, message, held)
            )
            # Sec. III-B: z_{t-1}^j = [mu_{t-1}^j; tau_{t-1}^j],  m_t^i = mean_{j in N_t^i} z_{t-1}^j
            sent_message = th.cat([map_prev, task_prev], dim=-1)  # (B, d_msg)
            messages = sent_message.view(n_swarms, n_agents, self.message_dim)
            received_message = (th.bmm(inputs.link_mask[t], messages) / inputs.in_degree[t]).view(batch, self.message_dim)
            # Sec. III-A: rho_t = G_psi(rho_{t-1}, tau_{t-1}, o_{t-1}, mbar_{t-1})   (no_memory: rho zeroed before use)
            if self.no_memory:
                memory_prev = th.zeros_like(memory_prev)
            memory_gates = memory_in(th.cat([task_prev, message_prev], dim=-1), memory_x[t])
            memory_state = gru_update(memory_gates, memory_hidden(memory_prev), memory_prev)
            # Sec. III-C: mhat_t = P_zeta(rho_t, o_t, e_t);  mbar_t = m_t if N_t^i != {} else the substitute
            received_now = inputs.has_message[t].unsqueeze(-1)
            if use_predictor:
                hidden = predictor_x[t] if self.no_memory else predictor_memory(memory_state, predictor_x[t])
                substitute = predictor_output(th.tanh(hidden))
                outputs[3].append(substitute)
            else:
                outputs[3].append(memory_state)
                if self.message_substitute == "zero":
                    substitute = th.zeros_like(received_message)
                elif self.message_substitute == "hold_last":
                    substitute = held_prev
                else:  # own_message
                    substitute = sent_message
            held = th.where(received_now, received_message, held_prev).float()
            message = th.where(received_now, received_message, substitute).float()
            # Sec. III-A, asymmetric update: mu_t = E_phi(mu_{t-1}, o_t, p_t, m^mu_t), m^mu_t = 0 when nothing arrived
            map_state = gru_update(map_in(received_message[:, :d_mu], map_x[t]), map_hidden(map_prev), map_prev)
            # Sec. III-A: tau_t = F_theta(tau_{t-1}, o_t, e_t, mu_{t-1}, mbar_t)
            task_gates = task_in(th.cat([map_prev, message], dim=-1), task_x[t])
            task_state = gru_update(task_gates, task_hidden(task_prev), task_prev)
            for output, value in zip(outputs, (task_state, map_state, received_message)):
                output.append(value)
            outputs[4].append(inputs.has_message[t])
        task_states, map_states, received, predicted, has_message = (th.stack(output) for output in outputs)
        if not use_predictor:  # mhat_t did not feed the recurrence: all T * B rows at once (rho_t zeroed under no_memory)
            memory_used = th.zeros_like(predicted) if self.no_memory else predicted
            predicted = self.message_predictor(th.cat([memory_used, observed], dim=-1))
        return task_states, map_states, received.float(), predicted.float(), has_message


    def _predict(self, observation: dict[str, th.Tensor], deterministic: bool = False) -> th.Tensor:  # type: ignore[override]
        raise RuntimeError("LatentSwarmPolicy is recurrent: call predict(obs, state, episode_start, deterministic)")

    def predict(  # type: ignore[override]
        self,
        observation: dict[str, np.ndarray] | dict[str, dict[str, np.ndarray]],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray | dict[str, np.ndarray], tuple[np.ndarray, ...]]:
        """Actions for whole swarms, as sb3-contrib's recurrent ``predict``.

        :param observation: either a vec-env observation (dict of arrays whose leading dim is a whole number of
            swarms, slots env-major) or a PettingZoo observation ``{agent: {key: array}}`` of one swarm, in which case
            the actions come back as ``{agent: action}``
        :param state: the state returned by the previous call (``None`` at the start: zeros)
        :param episode_start: (n_slots,) 1 where a new episode starts (``None``: no resets)
        :param deterministic: use the mean action
        :return: actions (clipped to the action space) and the new state, a :class:`LatentState` of numpy arrays
        """
        observation, agent_names = as_vec_observation(observation, ACTOR_OBS_KEYS, "LatentSwarmPolicy")
        self.set_training_mode(False)
        obs_tensor = {key: th.as_tensor(observation[key], device=self.device) for key in ACTOR_OBS_KEYS}
        if obs_tensor["local_obs"].dim() == len(_space_shape(self.observation_space["local_obs"])):
            raise ValueError("predict needs a batch of whole swarms (leading slot dimension), got a single observation")
        n_slots = obs_tensor["local_obs"].shape[0]
        if state is None:
            latent = self.initial_state(n_slots)
        else:
            latent = LatentState(*(th.as_tensor(np.asarray(s), dtype=th.float32, device=self.device) for s in state))
            if latent.map_state.shape[0] != n_slots:
                raise ValueError(f"state has {latent.map_state.shape[0]} slots but the observation has {n_slots}")
        starts = th.zeros(n_slots, device=self.device) if episode_start is None else th.as_tensor(
            np.asarray(episode_start, dtype=np.float32), device=self.device
        )
        with th.no_grad():
            step = self.latent_step(obs_tensor, latent, starts)
            actions = self.action_distribution(step.state.task_state).get_actions(deterministic=deterministic)
        actions_np = np.clip(actions.cpu().numpy(), self.action_space.low, self.action_space.high)
        # a LatentState holding numpy arrays (its fields are annotated as tensors)
        new_state = cast("tuple[np.ndarray, ...]", LatentState._make(field.cpu().numpy() for field in step.state))
        if agent_names is not None:
            return dict(zip(agent_names, actions_np)), new_state
        return actions_np, new_state


SB3_POLICY_KWARGS = {
    "net_arch": "predictor_hidden, decoder_hidden, critic_hidden, actor_hidden (one width each)",
    "lstm_hidden_size": "latent_dim (d_mu = d_tau = d_rho), or map_dim, task_dim, memory_dim",
    "n_lstm_layers": "none: the latent state is one GRU cell per part (Sec. III-B)",
    "shared_lstm": "none: the critic reads the global state, not the latent state",
    "enable_critic_lstm": "none: the critic reads the global state, not the latent state",
    "activation_fn": "none: the MLPs use tanh",
    "features_extractor_class": "none: the encoders are fixed by the observation keys",
}
"""SB3 / sb3-contrib ``policy_kwargs`` names and what ``LatentSwarmPolicy`` takes instead, for the error message."""


def _unexpected_kwargs_message(unexpected: set[str]) -> str:
    """``TypeError`` text for unknown ``policy_kwargs``: the valid names, and what to use instead of SB3's names."""
    internal = {"self", "observation_space", "action_space", "lr_schedule", "unused_kwargs"}
    valid = [name for name in inspect.signature(LatentSwarmPolicy.__init__).parameters if name not in internal]
    hints = "".join(f"; {name} -> {SB3_POLICY_KWARGS[name]}" for name in sorted(unexpected) if name in SB3_POLICY_KWARGS)
    return (
        f"LatentSwarmPolicy got unexpected keyword argument(s) {sorted(unexpected)}{hints}. "
        f"Valid policy_kwargs are: {', '.join(valid)}"
    )


def _check_log_std_bounds(bounds: Any) -> tuple[float, float]:
    try:
        low, high = (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise TypeError(f"log_std_bounds must be a pair of numbers (low, high), got {bounds!r}") from None
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        raise ValueError(f"log_std_bounds must be finite with low < high, got {bounds!r}")
    return low, high


def _space_shape(space: spaces.Space) -> tuple[int, ...]:
    """``space.shape``, which gymnasium types as optional (None for spaces without a fixed shape)."""
    if space.shape is None:
        raise ValueError(f"LatentSwarmPolicy needs observation spaces with a fixed shape, got {space}")
    return space.shape


def check_observation_space(observation_space: spaces.Space) -> None:
    """Raise a clear error when the observation space lacks what the latent-swarm policy reads."""
    if not isinstance(observation_space, spaces.Dict):
        raise TypeError(
            f"LatentSwarmPolicy needs a Dict observation space with keys {list(REQUIRED_KEYS)} "
            f"(use sb3_latentswarm.make_vec_env), got {type(observation_space).__name__}"
        )
    missing = [key for key in REQUIRED_KEYS if key not in observation_space.spaces]
    if missing:
        raise ValueError(
            f"The observation space lacks the key(s) {missing} needed by LatentSwarmPolicy "
            f"(has {list(observation_space.spaces)}); use sb3_latentswarm.make_vec_env"
        )

