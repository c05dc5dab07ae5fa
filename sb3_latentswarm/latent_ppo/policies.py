"""``LatentSwarmPolicy``: the map / task / memory latent state of Sec. III, as an SB3 policy.

The latent updates of Sec. III-A/B/C are written once, in :mod:`sb3_latentswarm.latent_ppo.recurrence`; here are the
networks and the heads: the actor pi_xi(a | tau_t), a Gaussian (or opt-in tanh-squashed) with mean and diagonal std
from tau_t (Sec. III-D); the map decoder D_eta(mu_t) -> M_hat_t (Sec. III-A); the critic V_omega(s_t),
s_t = ({e_t^j}, M_hat_t), read from the global part of the observation (Sec. III-D).

The actor side reads only ``local_obs``, ``proprio`` and ``link_row`` (and ``position`` where an adapted env has
one); the critic only the global state: ``swarm_proprio`` and ``global_map`` on the swarm env, ``global_state`` on an
env adapted by :func:`~sb3_latentswarm.envs.make_adapted_vec_env` (the two layouts of
:func:`~sb3_latentswarm.envs.observations.observation_layout`). No parameter depends on the number of agents N, so a
policy trained with N = 3 runs with N = 5.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import Schedule
from torch import nn

from sb3_latentswarm.envs.observations import LINK_AGE_KEY, POSITION_DIMS, as_vec_observation
from sb3_latentswarm.latent_ppo.critic import build_critic, critic_output, mlp
from sb3_latentswarm.latent_ppo.distributions import (  # noqa: F401  (smooth_log_std & co: also importable from here)
    TanhSquashedGaussianDistribution,
    UnvalidatedDiagGaussianDistribution,
    action_entropy,
    inverse_smooth_log_std,
    smooth_log_std,
    unvalidated_normal,
)
from sb3_latentswarm.latent_ppo.policy_checks import (  # noqa: F401  (REQUIRED_KEYS, check_observation_space: public here)
    REQUIRED_KEYS,
    check_delay_aware,
    check_log_std_bounds,
    check_observation_space,
    space_shape,
    unexpected_kwargs_message,
)
from sb3_latentswarm.latent_ppo.recurrence import (  # noqa: F401  (SequenceLinear, gru_cell: also importable from here)
    AgentInputs,
    SequenceLinear,
    StepInputs,
    StepOutput,
    agent_update,
    gru_cell,
    replay_sequence,
    swarm_step,
)
from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.latent_ppo.value_norm import ValueNorm
from sb3_latentswarm.utils.checks import check_choice, check_float, check_int

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


class LatentSwarmPolicy(BasePolicy):
    """Actor-critic policy with per-UAV map, task and memory GRU states and latent message passing.

    :param observation_space: Dict space with keys ``local_obs``, ``proprio``, ``link_row``, ``swarm_proprio``,
        ``global_map`` (as produced by :class:`~sb3_latentswarm.envs.SwarmReconEnv`), or the adapted layout of
        :func:`~sb3_latentswarm.envs.make_adapted_vec_env` (``global_state`` instead of the last two)
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
        action inside the [-1, 1] box, the mean action is tanh(mean), rescaled linearly to the env's box when it is
        not [-1, 1] (:meth:`env_actions`, as SB3's ``unscale_action``; the rollout buffer keeps a in [-1, 1]). Its
        entropy has no closed form: the PPO entropy bonus uses a one-sample estimate (:meth:`action_entropy`). Needs a
        Box action space with finite bounds
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
    :param delay_aware: (extension, opt-in) read the age of the pooled message (needs delayed links, the ``link_age``
        key; under delay every policy pools each arrival as it was sent: docs/concepts.md, "Delayed messages")
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
        delay_aware: bool = False,
        **unused_kwargs: Any,
    ):
        if unused_kwargs:
            # RecurrentPPO passes use_sde; anything else is a typo the user should hear about
            unexpected = set(unused_kwargs) - {"use_sde"}
            if unexpected:
                raise TypeError(unexpected_kwargs_message(unexpected, LatentSwarmPolicy.__init__))
            if unused_kwargs.get("use_sde"):
                raise ValueError("LatentSwarmPolicy does not support use_sde=True")
        self.layout = check_observation_space(observation_space)
        if not isinstance(action_space, spaces.Box):
            raise TypeError(f"LatentSwarmPolicy needs a Box action space, got {action_space}")
        check_choice("log_std_mapping", log_std_mapping, LOG_STD_MAPPINGS)
        check_choice("action_distribution", action_distribution, ACTION_DISTRIBUTIONS)
        squashed = action_distribution == "squashed_gaussian"
        if squashed and not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
            raise ValueError(
                "action_distribution='squashed_gaussian' rescales tanh's [-1, 1] to the action box, which needs finite "
                f"bounds; the action space is {action_space} (use action_distribution='gaussian')"
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
        self.log_std_bounds = check_log_std_bounds(log_std_bounds)
        self.log_std_mapping = log_std_mapping
        self.action_distribution_name = action_distribution
        for name, bound in (("action_low", action_space.low), ("action_high", action_space.high)):  # for env_actions
            self.register_buffer(name, th.as_tensor(bound, dtype=th.float32), persistent=False)  # (the space is saved)
        self.unit_action_box = bool(np.all(action_space.low == -1.0) and np.all(action_space.high == 1.0))
        self.rescale_actions = squashed and not self.unit_action_box  # env_actions rescales rather than clips
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
        self.delay_aware, self.message_expiry, self.layout = check_delay_aware(delay_aware, observation_space, self.layout)

        self.local_obs_dim = int(np.prod(space_shape(observation_space["local_obs"])))
        self.proprio_dim = int(space_shape(observation_space["proprio"])[-1])
        self.map_shape = tuple(space_shape(observation_space[self.layout.referent_key]))  # the referent's shape
        self.n_cells = int(np.prod(self.map_shape))
        self.position_dims = self.layout.position_dims
        self.swarm_critic = "swarm_proprio" in self.layout.critic_keys
        self.action_dim = int(np.prod(action_space.shape))
        o_dim, e_dim, d_mu, d_tau, d_rho, d_msg, age_dim = (
            self.local_obs_dim,
            self.proprio_dim,
            self.map_dim,
            self.task_dim,
            self.memory_dim,
            self.message_dim,
            int(self.delay_aware),  # the age column of the task, memory and predictor inputs (delay-aware)
        )

        # E_phi(mu_{t-1}; o_t, p_t, m^mu_t)
        self.map_encoder = nn.GRUCell(o_dim + self.position_dims + d_mu, d_mu)
        # D_eta(mu_t) -> M_hat_t
        self.map_decoder = mlp([d_mu, decoder_hidden, self.n_cells], nn.ReLU)
        # F_theta(tau_{t-1}; o_t, e_t, mu_{t-1}, mbar_t)
        self.task_encoder = nn.GRUCell(o_dim + e_dim + d_mu + d_msg + age_dim, d_tau)  # (+ alpha_t: delay-aware)
        # G_psi(rho_{t-1}; tau_{t-1}, o_{t-1}, mbar_{t-1})
        self.memory_encoder = nn.GRUCell(d_tau + o_dim + d_msg + age_dim, d_rho)  # (+ alpha_{t-1})
        # P_zeta(rho_t, o_t, e_t) -> mhat_t
        self.message_predictor = mlp([d_rho + o_dim + e_dim + age_dim, predictor_hidden, d_msg])  # (+ alpha_t)
        # pi_xi(a | tau_t): mean and diagonal log std (raw outputs, bounded by bound_log_std)
        self.actor_trunk = nn.Sequential(nn.Linear(d_tau, actor_hidden), nn.Tanh())
        self.action_mean = nn.Linear(actor_hidden, self.action_dim)
        if self.state_dependent_std:
            self.action_log_std = nn.Linear(actor_hidden, self.action_dim)
        else:
            self.log_std = nn.Parameter(th.full((self.action_dim,), self._raw_log_std_init))
        # V_omega(s_t) (latent_ppo/critic.py): s_t = ({e_t^j}_j, M_hat_t) on the swarm env, global_state on an adapted one
        state_dim = self.n_cells if self.swarm_critic else int(np.prod(space_shape(observation_space["global_state"])))
        self.critic_map, self.critic_agents, self.critic_head = build_critic(
            state_dim, e_dim if self.swarm_critic else None, critic_hidden)
        self.value_normalizer = ValueNorm(beta=value_norm_beta) if self.normalize_value else None
        gaussian: type[DiagGaussianDistribution] = (
            TanhSquashedGaussianDistribution if squashed else UnvalidatedDiagGaussianDistribution
        )
        self.action_dist = gaussian(self.action_dim)
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
        assert isinstance(value_head, nn.Linear)  # mlp ends with a Linear layer
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
        data.update({"delay_aware": True} if self.delay_aware else {})  # (absent when off: older versions load the file)
        return data

    @property
    def no_predictor(self) -> bool:
        """The paper's "No predictor" ablation: ``message_substitute == "zero"``."""
        return self.message_substitute == "zero"

    @no_predictor.setter
    def no_predictor(self, value: bool) -> None:
        self.message_substitute = "zero" if value else "predicted"

    @property
    def delayed_links(self) -> bool:
        """Whether the policy was built for delayed links (the ``link_age`` key in its observation space): then every
        arrival is pooled as it was sent (``docs/concepts.md``, "Delayed messages"); ``delay_aware`` adds its age."""
        return LINK_AGE_KEY in self.layout.actor_keys

    @property
    def latent_dims(self) -> tuple[int, ...]:
        """Sizes of the :class:`LatentState` fields, in field order."""
        # sent_history: E messages under delayed links (every policy pools arrivals as sent), zero columns without;
        # prev_message_age: one column for a delay-aware policy, zero otherwise
        delay = (self.message_expiry * self.message_dim if self.delayed_links else 0, int(self.delay_aware))
        return (self.map_dim, self.task_dim, self.memory_dim, self.local_obs_dim, self.message_dim, self.message_dim, *delay)

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
        proprio = obs["proprio"].float()  # (..., B, e_dim)
        return StepInputs(
            keep=(1.0 - episode_starts.float()).unsqueeze(-1),
            local_obs=obs["local_obs"].float().flatten(episode_starts.dim()),
            proprio=proprio,
            position=self.map_position(obs, proprio),
            link_mask=link_mask,
            has_message=(link_row.sum(-1) > 0),
            link_age=obs[LINK_AGE_KEY].float().view_as(link_mask) if self.delayed_links else None,
        )

    def map_position(self, obs: dict[str, th.Tensor], proprio: th.Tensor) -> th.Tensor:
        """p_t for the map update (:attr:`layout`'s ``position_key``): the first 3 entries of e_t (the swarm env), the
        ``position`` key (an adapted env with positions), or 0 columns, (..., B, 3 or 0)."""
        if self.layout.position_key == "proprio":
            return proprio[..., :POSITION_DIMS]
        if self.layout.position_key is None:
            return proprio[..., :0]
        return obs[self.layout.position_key].float()

    def recurrent_step(self, inputs: StepInputs, state: LatentState) -> StepOutput:
        """The latent updates of one step (Sec. III), under the policy's :attr:`autocast`; outputs in float32.

        :param inputs: :meth:`step_inputs` of this step, leading dim B
        :param state: the state carried in from step t-1, (B, ...) per field
        """
        return self._in_latent_precision(swarm_step, self, inputs, state)

    def agent_step(self, inputs: AgentInputs, state: LatentState) -> StepOutput:
        """:func:`~sb3_latentswarm.latent_ppo.recurrence.agent_update` for any batch of agents whose received messages
        are already pooled (one UAV: B = 1), under the policy's :attr:`autocast`; outputs in float32."""
        return self._in_latent_precision(agent_update, self, inputs, state)

    def _in_latent_precision(self, step: Callable[..., StepOutput], *args: Any) -> StepOutput:
        if self.autocast is None:
            return step(*args)
        with self.latent_autocast():
            out = step(*args)
        return StepOutput(
            LatentState(*(field.float() for field in out.state)),
            out.received_message.float(),
            out.predicted_message.float(),
            out.has_message,
            out.sent_message.float(),
        )

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
            eps = noise if isinstance(noise, th.Tensor) else th.as_tensor(noise, device=actions.device)  # (traceable)
            actions = actions + gaussian.stddev * eps
        return th.tanh(actions) if self.squash_output else actions

    def env_actions(self, actions: th.Tensor) -> th.Tensor:
        """The actions the env takes for the actor's ``actions`` (B, action_dim), the one place that maps them to the
        box: clipped (the Gaussian, as SB3's PPO), or for the squashed actor on a box other than [-1, 1]
        (:attr:`rescale_actions`) rescaled, low + (a + 1) (high - low) / 2, as SB3's ``unscale_action``. Returns
        (B, action_dim) in ``actions``' dtype (float32 at least)."""
        low, high = cast(th.Tensor, self.action_low), cast(th.Tensor, self.action_high)  # (registered buffers)
        if self.rescale_actions:
            return low + (actions + 1.0) * (0.5 * (high - low))
        return th.minimum(th.maximum(actions, low), high)

    action_entropy = staticmethod(action_entropy)  # (distributions.action_entropy: the squashed Gaussian's estimate)

    @property
    def critic_parameters(self) -> list[nn.Parameter]:
        """Parameters of V_omega only (they read the global state, nothing else reads them)."""
        modules = (self.critic_map, self.critic_agents, self.critic_head)
        return [p for module in modules if module is not None for p in module.parameters()]

    def predict_values(self, obs: dict[str, th.Tensor]) -> th.Tensor:
        """V_omega(s_t) in return units for every slot, (B, 1) (denormalized when the critic learns normalized values)."""
        values = self.critic_output(obs)
        return values if self.value_normalizer is None else self.value_normalizer.denormalize(values)

    def critic_output(self, obs: dict[str, th.Tensor]) -> th.Tensor:
        """The critic's raw output for every slot, (B, 1); computed once per swarm and broadcast to its agents
        (:func:`~sb3_latentswarm.latent_ppo.critic.critic_output`)."""
        return critic_output(self, obs)

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
            critic_obs = {key: obs[key].flatten(0, 1) for key in self.layout.critic_keys + ("link_row",)}
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
        inputs = self.step_inputs({key: obs[key] for key in self.layout.actor_keys}, episode_starts)
        if self.chunked_replay:
            return self._replay_latent_sequence(inputs, state)
        return self._replay_latent_steps(inputs, state)

    @property
    def chunked_replay(self) -> bool:
        """Whether :meth:`evaluate_sequences` replays with the chunk-batched GEMMs of :meth:`_replay_latent_sequence`
        (under :attr:`autocast`, and on devices other than the CPU) rather than one :meth:`recurrent_step` per step, the
        rollout's own computation (float32 on the CPU).

        Chosen by measurement (``docs/algorithm.md``, "The training replay"): 1.21x on a bf16 ``paper`` minibatch on one
        CPU thread (Intel AMX), 0.86-0.99x in float32 there, 22 % fewer aten ops (what a host-bound GPU step pays for).
        """
        return self.autocast is not None or self.device.type != "cpu"

    def _replay_latent_steps(self, inputs: StepInputs, state: LatentState) -> tuple[th.Tensor, ...]:
        """The latent updates of a training sequence, one :meth:`recurrent_step` per step (the rollout's computation).

        :return: tau_t, mu_t, m_t, mhat_t (T, B, dim each), has_message (T, B)
        """
        return replay_sequence(self, inputs, state, "eager")

    def _replay_latent_sequence(self, inputs: StepInputs, state: LatentState) -> tuple[th.Tensor, ...]:
        """The same updates (:func:`~sb3_latentswarm.latent_ppo.recurrence.agent_update`, written once) with the GEMMs
        arranged for the whole sequence (:class:`~sb3_latentswarm.latent_ppo.recurrence.SequenceLinears`): the
        observation columns of each input projection in one GEMM over all T * B rows, the weight gradients of the
        recurrent columns summed once per sequence. float32 results agree with :meth:`_replay_latent_steps` to about
        1e-6.

        :param inputs: :meth:`step_inputs` of the sequence, leading dims (T, B)
        :param state: the state carried into the first step, (B, ...) per field
        :return: tau_t, mu_t, m_t, mhat_t (T, B, dim each), has_message (T, B)
        """
        return replay_sequence(self, inputs, state, "sequence")

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
        observation, agent_names = as_vec_observation(observation, self.layout.actor_keys, "LatentSwarmPolicy")
        self.set_training_mode(False)
        obs_tensor = {key: th.as_tensor(observation[key], device=self.device) for key in self.layout.actor_keys}
        if obs_tensor["local_obs"].dim() == len(space_shape(self.observation_space["local_obs"])):
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
        actions_np = self.env_actions(actions).cpu().numpy()
        # a LatentState holding numpy arrays (its fields are annotated as tensors)
        new_state = cast("tuple[np.ndarray, ...]", LatentState._make(field.cpu().numpy() for field in step.state))
        if agent_names is not None:
            return dict(zip(agent_names, actions_np)), new_state
        return actions_np, new_state
