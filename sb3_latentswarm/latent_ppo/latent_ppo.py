"""``LatentSwarmPPO``: MAPPO-style training of the latent-swarm policy with the joint loss of Sec. III-E.

A subclass of sb3-contrib's ``RecurrentPPO``. What it changes and why (see ``docs/algorithm.md``):

* the recurrent state is a :class:`~sb3_latentswarm.latent_ppo.type_aliases.LatentState` (map, task, memory,
  previous observation and message), not LSTM (h, c) pairs;
* :class:`~sb3_latentswarm.latent_ppo.buffers.SwarmRolloutBuffer` keeps each swarm together and time-aligned in a minibatch,
  replaying contiguous chunks from the stored latent state, because every agent's update reads its peers' states;
* ``train`` minimizes L = -L_CLIP + c1 L_VF + c2 L_map + c3 L_pred - ent_coef * entropy in one gradient step per
  minibatch on all parameters;
* opt-in training options of MAPPO (marlbenchmark/on-policy) that the paper does not specify: value normalization
  (``normalize_value``), a Huber value loss (``value_loss="huber"``) and gradient clipping per parameter group
  (``grad_clip="per_group"``: the critic's gradient norm no longer scales down the actor's and the latent losses').
"""

from __future__ import annotations

import inspect
import io
import os
import pathlib
import warnings
from collections import deque
from typing import Any, ClassVar, TypeVar, cast

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import FloatSchedule, obs_as_tensor, safe_mean
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.observations import LINK_AGE_KEY
from sb3_latentswarm.envs.vec_env import check_vec_normalize
from sb3_latentswarm.latent_ppo.arguments import COMPILE_REMOVED, check_algorithm_values, fitting_chunk_length
from sb3_latentswarm.latent_ppo.buffers import SwarmRolloutBuffer
from sb3_latentswarm.latent_ppo.model_file import UnsafeModelFileError, load_plain, read_data, save_plain
from sb3_latentswarm.latent_ppo.policies import (
    NEW_POLICY_KWARGS,
    LatentSwarmPolicy,
    check_observation_space,
    with_legacy_defaults,
)
from sb3_latentswarm.latent_ppo.schedules import paper_learning_rate
from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.latent_ppo.update import loss_gradient_norms, minibatch_losses, ppo_update, recompute_old_log_probs
from sb3_latentswarm.utils.atomic import atomic_path
from sb3_latentswarm.version import __version__

SelfLatentSwarmPPO = TypeVar("SelfLatentSwarmPPO", bound="LatentSwarmPPO")

SAVE_FORMAT = 2
"""Version of the saved-model layout; bumped when a change would make older files load wrongly. 2: plain data, no
pickle (:mod:`sb3_latentswarm.latent_ppo.model_file`); 1: SB3's pickled attributes, read only with ``trust_pickle``."""

PICKLED_SAVE_FORMATS = (1,)

PAPER_LEARNING_RATE = paper_learning_rate()
"""1e-4 for the first 1000 of 1600 updates, 1e-5 after (Sec. IV)."""

N_AGENT_KEYS = ("link_row", "swarm_proprio", LINK_AGE_KEY)
"""Observation keys whose shape depends on the number of agents; the policy's parameters do not."""

def check_save_format(data: dict[str, Any] | None, path: Any, formats: tuple[int, ...] = (SAVE_FORMAT,)) -> None:
    """Raise a clear ``ValueError`` when ``data`` (a saved model's attributes) is not a loadable LatentSwarmPPO file.

    :param formats: the save formats the caller reads (:data:`SAVE_FORMAT` for plain files, :data:`PICKLED_SAVE_FORMATS`
        for pickled files read with ``trust_pickle``)
    """
    if not data or "save_format" not in data:
        raise ValueError(f"{path} was not saved by LatentSwarmPPO (no save_format); load it with the class that saved it")
    saved_format, saved_by = data["save_format"], data.get("saved_by_version", "unknown")
    if isinstance(saved_format, bool) or not isinstance(saved_format, int):
        kind = type(saved_format).__name__
        raise ValueError(f"{path}: data entry 'save_format' must be an int, got {kind} ({saved_format!r})")
    if not isinstance(saved_by, str):
        raise ValueError(f"{path}: data entry 'saved_by_version' must be a str, got {type(saved_by).__name__}")
    if saved_format in formats:
        return
    if saved_format == SAVE_FORMAT:  # a pickled file that claims the plain format: no version of the package wrote it
        raise ValueError(
            f"{path} holds pickled entries but declares save format {SAVE_FORMAT}, whose files are plain data: it was "
            f"not written by sb3-latentswarm's save; refused"
        )
    newer = "a newer" if saved_format > SAVE_FORMAT else "an older"
    if saved_format in PICKLED_SAVE_FORMATS:
        raise ValueError(
            f"{path} was saved by {newer} sb3-latentswarm ({saved_by}, save format {saved_format}, pickled attributes); "
            f"load it with trust_pickle=True (only if you trust the file) and save it again"
        )
    raise ValueError(
        f"{path} was saved by {newer} sb3-latentswarm ({saved_by}, save format {saved_format}); this is "
        f"sb3-latentswarm {__version__} (save format {SAVE_FORMAT}). Install sb3-latentswarm=={saved_by} to load it."
    )


def validate_algorithm_kwargs(**kwargs: Any) -> dict[str, Any]:
    """Check ``LatentSwarmPPO`` keyword arguments without building anything; return them unchanged.

    The one validation of the algorithm's settings: the constructor, :meth:`LatentSwarmPPO.load` (saved values and
    overrides) and the sweep spec call it, so a bad value fails with the same message before any work starts. Only
    the arguments given are checked; ``policy_kwargs``' entries are checked by the policy. Ranges: ``learning_rate``
    in (0, 1], ``clip_range`` in (0, 1] (each value of a schedule, too), ``clip_range_vf`` and ``target_kl`` None or
    > 0, ``gamma`` and ``gae_lambda`` in [0, 1], the loss weights >= 0, ``max_grad_norm`` and ``huber_delta`` > 0.

    :raise TypeError: for an argument that is not one of the constructor's, or of the wrong type
    :raise ValueError: for a value outside its range, naming the argument and the range
    """
    known = set(inspect.signature(LatentSwarmPPO.__init__).parameters) - {"self", "policy", "env", "device"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise TypeError(f"unknown LatentSwarmPPO argument(s) {unknown}; valid: {', '.join(sorted(known))}")
    check_algorithm_values(kwargs)
    return kwargs


def _env_config(env: VecEnv) -> SwarmConfig | None:
    config = getattr(env, "config", None)
    return config if isinstance(config, SwarmConfig) else None


class LatentSwarmPPO(RecurrentPPO):
    """Latent semantic state estimation for UAV swarms (Karakasis and Saad), trained as MAPPO with auxiliary losses.

    Defaults are the paper's (Sec. IV) where it gives them: ``n_steps=600``, ``gamma=0.99``, ``gae_lambda=0.95``,
    ``clip_range=0.2``, ``ent_coef=0.01``, ``vf_coef=0.5`` (c1), ``map_coef=5`` (c2), ``pred_coef=5`` (c3), and a
    learning rate of 1e-4 for the first 1000 of 1600 updates and 1e-5 after (:func:`paper_learning_rate`).

    :param policy: ``"LatentSwarmPolicy"`` or :class:`LatentSwarmPolicy` (or a subclass); any other name (SB3's
        ``"MultiInputPolicy"``, ...) raises ``ValueError``, any other class ``TypeError``
    :param env: a swarm VecEnv from :func:`sb3_latentswarm.make_vec_env` (it must expose ``n_agents``)
    :param learning_rate: learning rate or schedule of ``progress_remaining``
    :param n_steps: steps per vec-env slot per rollout (paper: 600)
    :param batch_size: agent-steps per minibatch, rounded down to whole (swarm, chunk) sequences of
        ``n_agents * chunk_length`` agent-steps
    :param n_epochs: passes over the rollout per update (the paper does not say; MAPPO uses 5 to 15)
    :param gamma: discount factor gamma
    :param gae_lambda: GAE lambda
    :param clip_range: PPO clipping epsilon
    :param clip_range_vf: optional value clipping (``None``: off)
    :param normalize_advantage: normalize advantages per minibatch
    :param ent_coef: entropy coefficient
    :param vf_coef: c1, weight of the value loss L_VF
    :param map_coef: c2, weight of the map-reconstruction loss L_map
    :param pred_coef: c3, weight of the message-prediction loss L_pred
    :param chunk_length: steps per training sequence (MAPPO's data chunk); when it does not divide ``n_steps``, the
        largest divisor of ``n_steps`` below it is used, with a warning
    :param max_grad_norm: gradient clipping norm
    :param grad_clip: ``"global"``: one norm over all parameters (SB3's); ``"per_group"``: the critic V_omega and the
        rest (actor, latent encoders, decoder, predictor) are clipped to ``max_grad_norm`` separately, as MAPPO's
        separate actor and critic optimizers do
    :param normalize_value: train the critic on normalized returns (MAPPO's ValueNorm; its statistics are part of the
        policy's state and saved with it). Sets the policy's ``normalize_value``
    :param value_loss: ``"mse"`` (the paper's L_VF) or ``"huber"`` (MAPPO's, with ``huber_delta``)
    :param huber_delta: the Huber loss's threshold, in the critic's units (normalized when ``normalize_value``)
    :param log_grad_norms: log the gradient norm of each weighted loss term (``train/grad_norm_<term>``) on the first
        minibatch of every update (costs one extra backward pass per term and update)
    :param compile_latent_step: removed after 0.2.0 (``True`` raises ``ValueError``): ``torch.compile`` of the latent step
        never paid back its compilation within a ``coordination`` run (``docs/algorithm.md``)
    :param autocast: ``None`` (float32, the default) or ``"bf16"``: the latent forward pass (GRUs, message predictor,
        map decoder, critic trunk) runs under bfloat16 autocast, in rollouts, training and ``predict`` alike; the latent
        state, the action heads, log-probabilities, the PPO ratio, ValueNorm and the losses stay float32 (see
        :attr:`LatentSwarmPolicy.autocast`). Faster only for large latent sizes on CPUs with bf16 matrix units
        (``benchmarks/minibatch_ops.py`` measures it). bf16 GEMMs round differently for different batch shapes, so the
        rollout's log-probabilities (one step of all slots) and the training replay's (chunks of minibatch rows) differ
        by about 1e-4; with ``"bf16"`` each update therefore first recomputes the old log-probabilities with the training
        forward pass itself (:meth:`recompute_old_log_probs`), and the PPO ratio compares like with like
    :param target_kl: optional KL early stopping
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: TensorBoard log folder
    :param policy_kwargs: keyword arguments of :class:`LatentSwarmPolicy` (e.g. ``latent_dim``)
    :param verbose: 0, 1 or 2
    :param seed: seed of torch, numpy and the env copies
    :param device: ``"auto"``, ``"cpu"`` or ``"cuda"``
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"LatentSwarmPolicy": LatentSwarmPolicy}
    policy: LatentSwarmPolicy  # type: ignore[assignment]  # narrowed: _setup_model builds only this policy
    rollout_buffer: SwarmRolloutBuffer

    def __init__(
        self,
        policy: str | type[LatentSwarmPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = PAPER_LEARNING_RATE,
        n_steps: int = 600,
        batch_size: int = 4500,
        n_epochs: int = 5,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        clip_range: float | Schedule = 0.2,
        clip_range_vf: float | Schedule | None = None,
        normalize_advantage: bool = True,
        ent_coef: float = 0.01,
        vf_coef: float = 0.5,
        map_coef: float = 5.0,
        pred_coef: float = 5.0,
        chunk_length: int = 25,
        max_grad_norm: float = 0.5,
        grad_clip: str = "global",
        normalize_value: bool = False,
        value_loss: str = "mse",
        huber_delta: float = 10.0,
        log_grad_norms: bool = False,
        compile_latent_step: bool = False,
        autocast: str | None = None,
        target_kl: float | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ):
        if not isinstance(policy, str) and not (isinstance(policy, type) and issubclass(policy, LatentSwarmPolicy)):
            raise TypeError(f"policy must be 'LatentSwarmPolicy' or a subclass of LatentSwarmPolicy, got {policy!r}")
        arguments = {name: value for name, value in locals().items() if name not in ("self", "policy", "env", "device")}
        validate_algorithm_kwargs(**{name: value for name, value in arguments.items() if not name.startswith("__")})
        chunk_length = fitting_chunk_length(n_steps, chunk_length)
        policy_kwargs = dict(policy_kwargs or {})
        if "normalize_value" in policy_kwargs and bool(policy_kwargs["normalize_value"]) != bool(normalize_value):
            raise ValueError(
                f"normalize_value={normalize_value} contradicts policy_kwargs['normalize_value']="
                f"{policy_kwargs['normalize_value']}; set it once, on LatentSwarmPPO"
            )
        policy_kwargs["normalize_value"] = bool(normalize_value)
        # recorded in the model file, so that a later change of a default cannot change how a saved model acts
        policy_kwargs = {**NEW_POLICY_KWARGS, **policy_kwargs}
        super().__init__(
            policy,  # type: ignore[arg-type]  # RecurrentPPO types it as its LSTM policy; ours replaces it
            env,
            learning_rate=learning_rate,
            n_steps=n_steps,
            batch_size=batch_size,
            n_epochs=n_epochs,
            gamma=gamma,
            gae_lambda=gae_lambda,
            clip_range=clip_range,
            clip_range_vf=clip_range_vf,
            normalize_advantage=normalize_advantage,
            ent_coef=ent_coef,
            vf_coef=vf_coef,
            max_grad_norm=max_grad_norm,
            target_kl=target_kl,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.map_coef = map_coef
        self.pred_coef = pred_coef
        self.chunk_length = chunk_length
        self.grad_clip = grad_clip
        self.normalize_value = bool(normalize_value)
        self.value_loss = value_loss
        self.huber_delta = huber_delta
        self.log_grad_norms = log_grad_norms
        self.autocast = autocast
        self.n_agents: int | None = None
        self.save_format = SAVE_FORMAT
        self.saved_by_version = __version__
        self.swarm_config: SwarmConfig | None = None
        """The env config of training (saved with the model; the evaluation's default)."""
        if self.env is not None:
            self.n_agents = self._check_swarm_env(self.env)
            self._check_batch_size()
        if _init_setup_model:
            self._setup_model()

    def _get_policy_from_name(self, policy_name: str) -> type[BasePolicy]:
        """SB3's look-up of ``policy_aliases``, with an error that names the one policy this algorithm supports.

        :raise ValueError: for any other name, e.g. SB3's ``"MultiInputPolicy"`` or sb3-contrib's
            ``"MultiInputLstmPolicy"`` (they have no latent state, no messages and no predictor)
        """
        if policy_name not in self.policy_aliases:
            raise ValueError(
                f"LatentSwarmPPO has no policy {policy_name!r}: the only one it supports is 'LatentSwarmPolicy' "
                "(the latent-state policy of Sec. III; its options go in policy_kwargs)"
            )
        return self.policy_aliases[policy_name]

    # ------------------------------------------------------------------ environment checks
    @staticmethod
    def _check_swarm_env(env: VecEnv) -> int:
        """Validate a swarm VecEnv and return its number of agents per swarm."""
        check_vec_normalize(env)
        check_observation_space(env.observation_space)
        try:
            n_agents = int(env.get_attr("n_agents", indices=0)[0]) if not hasattr(env, "n_agents") else int(env.n_agents)
        except (AttributeError, IndexError) as error:
            raise ValueError(
                "LatentSwarmPPO needs a swarm VecEnv exposing `n_agents` (slots are env-major, agent-minor); "
                "build it with sb3_latentswarm.make_vec_env"
            ) from error
        if env.num_envs % n_agents != 0:
            raise ValueError(f"The VecEnv has {env.num_envs} slots, not a multiple of n_agents={n_agents}")
        link_shape = cast(spaces.Dict, env.observation_space)["link_row"].shape  # a Dict: checked above
        link_dim = link_shape[-1] if link_shape else None
        if link_dim != n_agents:
            raise ValueError(f"observation 'link_row' has length {link_dim} but the env reports n_agents={n_agents}")
        return n_agents

    def _check_batch_size(self) -> None:
        """A minibatch must hold at least one whole (swarm, chunk) sequence of ``n_agents * chunk_length`` agent-steps."""
        assert self.n_agents is not None
        sequence = self.n_agents * self.chunk_length
        if self.batch_size is None or self.batch_size < sequence:
            raise ValueError(
                f"batch_size must hold at least one whole swarm sequence (n_agents * chunk_length = {sequence} "
                f"agent-steps), got batch_size={self.batch_size}"
            )

    # ------------------------------------------------------------------ setup
    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        if self.env is not None:
            self.n_agents = self._check_swarm_env(self.env)
            self.observation_space = self.env.observation_space
            self.swarm_config = _env_config(self.env)
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs
        )
        self.policy = self.policy.to(self.device)
        if not isinstance(self.policy, LatentSwarmPolicy):
            raise ValueError("LatentSwarmPPO needs a LatentSwarmPolicy")
        self.policy.autocast = self.autocast
        self.__dict__.pop("compile_latent_step", None)  # the saved flag of a file from 0.2.0 or earlier (see load)
        self._setup_rollout_state()
        self.clip_range = FloatSchedule(self.clip_range)
        if self.clip_range_vf is not None:
            if isinstance(self.clip_range_vf, (float, int)) and self.clip_range_vf <= 0:
                raise ValueError(f"clip_range_vf must be positive (None deactivates it), got {self.clip_range_vf}")
            self.clip_range_vf = FloatSchedule(self.clip_range_vf)

    def _setup_rollout_state(self) -> None:
        """(Re)build the buffer, the carried latent state and the swarm statistics for the current env size.

        Without an env (a model loaded for ``predict``) nothing is allocated: the rollout buffer of ``n_steps * n_envs``
        agent-steps is built only when there is an env to train on (:meth:`set_env`).
        """
        self._swarm_summaries: deque[dict[str, Any]] = deque(maxlen=self._stats_window_size)
        self._last_latent_state: LatentState | None = None
        if self.env is None or self.n_agents is None:
            return
        self._last_latent_state = self.policy.initial_state(self.n_envs)
        self.rollout_buffer = SwarmRolloutBuffer(
            self.n_steps,
            self.observation_space,  # type: ignore[arg-type]
            self.action_space,
            latent_dims=self.policy.latent_dims,
            n_agents=self.n_agents,
            chunk_length=self.chunk_length,
            device=self.device,
            gamma=self.gamma,
            gae_lambda=self.gae_lambda,
            n_envs=self.n_envs,
            swarm_keys=self.policy.layout.state_keys,  # the global state s_t, equal within a swarm: stored once per swarm
        )

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """Set a new swarm VecEnv. Unlike SB3, the number of agents and of env copies may differ from training's."""
        env = self._wrap_env(env, self.verbose)
        n_agents = self._check_swarm_env(env)
        observation_space = cast(spaces.Dict, env.observation_space)  # checked by _check_swarm_env
        for key, space in cast(spaces.Dict, self.observation_space).spaces.items():
            if key not in observation_space.spaces:
                hint = (" (the model was trained with delayed links, which give 'link_age': give the new env "
                        "message_delay > 0)" if key == LINK_AGE_KEY else "")
                raise ValueError(f"Observation '{key}' of training ({space}) is missing from the new env{hint}; only "
                                 f"the number of agents may change")
            if key not in N_AGENT_KEYS and observation_space[key].shape != space.shape:
                raise ValueError(
                    f"Observation '{key}' of the new env differs from training's ({space}); only the number of agents "
                    f"may change"
                )
        if env.action_space != self.action_space:
            raise ValueError(f"Action space mismatch: {env.action_space} != {self.action_space}")
        self._vec_normalize_env = unwrap_vec_normalize(env)
        if force_reset:
            self._last_obs = None
        self.n_agents = n_agents
        self.swarm_config = _env_config(env)
        self.n_envs = env.num_envs
        self.env = env
        self.observation_space = observation_space
        self.policy.observation_space = observation_space
        self._setup_rollout_state()

    @classmethod
    def load(
        cls,
        path,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        trust_pickle: bool = False,
        **kwargs,
    ) -> LatentSwarmPPO:
        """Load a model; ``env`` may have another number of agents or env copies than the training env.

        Loading runs no code from the file: the attributes are plain JSON and the tensors are read with
        ``torch.load(weights_only=True)`` (see :mod:`sb3_latentswarm.latent_ppo.model_file`). ``kwargs`` replace saved
        constructor arguments and pass the constructor's checks. Files of another save format fail with a
        ``ValueError`` naming both versions instead of loading wrongly.

        :param trust_pickle: also read files whose attributes are pickled (SB3's format, and this package's files
            before save format 2). Unpickling runs whatever code the file carries: only for files you trust.
        :param custom_objects: SB3's replacements for pickled attributes (with ``trust_pickle`` only)
        :raise UnsafeModelFileError: (a ``ValueError``) for a pickled file without ``trust_pickle=True``
        """
        raw, pickled = read_data(path)
        if pickled and not trust_pickle:
            raise UnsafeModelFileError(path, pickled)
        if pickled:
            data, _, _ = load_from_zip_file(path, device="cpu", custom_objects=custom_objects, load_data=True)
            check_save_format(data, path, PICKLED_SAVE_FORMATS)
            assert data is not None  # check_save_format raises for a file without data
            # files from before an actor option existed were built with its old value (LEGACY_POLICY_KWARGS)
            custom_objects = {"policy_kwargs": with_legacy_defaults(data.get("policy_kwargs")), **(custom_objects or {})}
            trusted = super().load(path, env=None, device=device, custom_objects=custom_objects)
            path = io.BytesIO()  # from here on the same path as a plain file, so that kwargs meet the same checks
            trusted.save(path)
            raw, _ = read_data(path)
        check_save_format(raw, path)
        raw = {**raw, "policy_kwargs": with_legacy_defaults(raw.get("policy_kwargs"))}
        if raw.get("compile_latent_step"):  # saved by 0.2.0 or earlier with the flag on
            warnings.warn(f"{path}: {COMPILE_REMOVED.split(':')[0]}; the saved flag is ignored, the model runs eagerly",
                          DeprecationWarning, stacklevel=2)
            raw["compile_latent_step"] = False
        n_envs = getattr(env, "num_envs", 1) if env is not None else None  # its rollout buffer counts in the budget
        model = load_plain(cls, path, raw, device=device, print_system_info=print_system_info, n_envs_to_train=n_envs,
                           **kwargs)
        model._check_batch_size()
        if env is not None:
            model.set_env(env, force_reset=force_reset)
        return model

    def _check_loaded(self, path: Any) -> None:
        """The saved spaces and swarm size must agree with each other (a file could declare any of them)."""
        try:
            check_observation_space(self.observation_space)
        except (TypeError, ValueError, KeyError) as error:
            raise ValueError(f"{path}: data entry 'observation_space' is not a swarm observation space: {error}") from None
        if self.n_agents is None:
            raise ValueError(f"{path}: the data entry has no 'n_agents'")
        link_dim = self.observation_space["link_row"].shape[-1]  # type: ignore[index]
        if link_dim != self.n_agents:
            raise ValueError(
                f"{path}: data entry 'n_agents' is {self.n_agents} but the observation 'link_row' has length {link_dim}"
            )
        if self.n_envs % self.n_agents != 0:
            raise ValueError(f"{path}: data entry 'n_envs' ({self.n_envs}) is not a multiple of n_agents ({self.n_agents})")
        if self.swarm_config is not None and self.swarm_config.n_agents != self.n_agents:
            raise ValueError(
                f"{path}: data entry 'swarm_config' has n_agents={self.swarm_config.n_agents}, 'n_agents' is {self.n_agents}"
            )

    def save(self, path, exclude=None, include=None, include_optimizer: bool = True) -> None:
        """Save the model as plain data and tensors (no pickle): see :mod:`sb3_latentswarm.latent_ppo.model_file`.

        The file holds no path of this machine (an absolute ``tensorboard_log`` is not kept; a relative one is) and no
        state of a rollout in progress (a checkpoint holds that:
        :func:`sb3_latentswarm.runs.checkpoints.load_checkpoint`). A path is written atomically:
        to a temporary file in the same folder, then renamed, so a failed save (full disk, size limit, Ctrl-C) leaves
        the earlier file intact. A missing suffix becomes ``.zip``, as in SB3.

        :param include_optimizer: ``False`` leaves out the optimizer state (Adam's moments, about two thirds of the
            file): enough to evaluate, predict, export or warm-start, and :meth:`load` reads it; :meth:`learn` on such a
            model starts a fresh optimizer and warns once. Keep the default for a run you mean to continue exactly.
        """
        self.save_format = SAVE_FORMAT
        self.saved_by_version = __version__
        if not isinstance(path, (str, os.PathLike)):  # a file object: SB3 writes into it
            save_plain(self, path, exclude=exclude, include=include, include_optimizer=include_optimizer)
            return
        path = pathlib.Path(path)
        if path.suffix == "":  # SB3's open_path adds ".zip"
            path = path.with_suffix(".zip")
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:  # a failed save leaves the earlier file as it was
            save_plain(self, tmp, exclude=exclude, include=include, include_optimizer=include_optimizer)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_last_latent_state", "_swarm_summaries"]

    # ------------------------------------------------------------------ rollouts
    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
    ) -> bool:
        """Collect ``n_rollout_steps`` per slot with the current policy, carrying the latent state across calls."""
        assert isinstance(rollout_buffer, SwarmRolloutBuffer), "LatentSwarmPPO needs a SwarmRolloutBuffer"
        assert self._last_obs is not None, "No previous observation was provided"
        assert self.n_agents is not None
        self.policy.set_training_mode(False)
        n_steps = 0
        rollout_buffer.reset()
        callback.on_rollout_start()
        latent_state = self._last_latent_state
        assert latent_state is not None, "No latent state: set an env first"
        link_up_sum, in_link_count, dropout_sum, in_box_sum = 0.0, 0.0, 0.0, 0.0

        while n_steps < n_rollout_steps:
            assert self._last_obs is not None
            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)
                episode_starts = th.as_tensor(self._last_episode_starts, dtype=th.float32, device=self.device)
                actions, values, log_probs, new_latent_state = self.policy(obs_tensor, latent_state, episode_starts)
            # what the env takes (clipped, or the squashed actor's a rescaled to the box); the buffer keeps the actor's
            clipped_actions = self.policy.env_actions(actions).cpu().numpy()
            actions = actions.cpu().numpy()
            in_box_sum += 1.0 if self.policy.rescale_actions else float((clipped_actions == actions).mean())

            # link statistics of the observation the agents just acted on (vectorized over slots)
            link_row = self._last_obs["link_row"]
            link_up_sum += float(link_row.sum())
            in_link_count += link_row.shape[0] * (self.n_agents - 1)
            dropout_sum += float((link_row.sum(axis=-1) == 0).mean())

            new_obs, rewards, dones, infos = env.step(clipped_actions)
            self.num_timesteps += env.num_envs
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            self._update_swarm_summaries(infos, dones)
            n_steps += 1
            rewards = rewards + self.gamma * self._truncation_values(infos, dones)
            rollout_buffer.add(
                self._last_obs,  # type: ignore[arg-type]
                actions,
                rewards,
                self._last_episode_starts,  # type: ignore[arg-type]
                values,
                log_probs,
                latent_state=latent_state,
            )
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones
            latent_state = new_latent_state

        self._last_latent_state = latent_state
        with th.no_grad():
            values = self.policy.predict_values(obs_as_tensor(new_obs, self.device))  # type: ignore[arg-type]
        rollout_buffer.compute_returns_and_advantage(last_values=values, dones=dones)

        self.logger.record("rollout/link_up_rate", link_up_sum / in_link_count if in_link_count else float("nan"))
        self.logger.record("rollout/dropout_rate", dropout_sum / n_steps)
        self.logger.record("rollout/actions_in_box", in_box_sum / n_steps)
        if self._swarm_summaries:
            self.logger.record("rollout/coverage", safe_mean([s["coverage"] for s in self._swarm_summaries]))
            self.logger.record("rollout/collisions", safe_mean([s["collisions"] for s in self._swarm_summaries]))
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def _truncation_values(self, infos: list[dict[str, Any]], dones: np.ndarray) -> np.ndarray:
        """V(s_T) of swarms cut off by the horizon (``TimeLimit.truncated``), 0 elsewhere (SB3's timeout bootstrap).

        Truncation ends all agents of a swarm together, so the terminal observations form whole swarms and the
        centralized critic evaluates them in one batch.
        """
        bootstrap = np.zeros(len(dones), dtype=np.float32)
        slots = [i for i in np.flatnonzero(dones) if infos[i].get("TimeLimit.truncated", False)]
        slots = [i for i in slots if infos[i].get("terminal_observation") is not None]
        if not slots:
            return bootstrap
        keys = self.observation_space.spaces  # type: ignore[attr-defined]
        terminal = {key: np.stack([infos[i]["terminal_observation"][key] for i in slots]) for key in keys}
        with th.no_grad():
            values = self.policy.predict_values({key: th.as_tensor(obs, device=self.device) for key, obs in terminal.items()})
        bootstrap[slots] = values.cpu().numpy().flatten()
        return bootstrap

    def _update_swarm_summaries(self, infos: list[dict[str, Any]], dones: np.ndarray) -> None:
        """Keep the end-of-episode summary of each finished swarm (read from its first agent's slot)."""
        assert self.n_agents is not None
        first_slots = np.flatnonzero(dones[:: self.n_agents]) * self.n_agents
        for slot in first_slots:
            summary = infos[slot].get("swarm_summary")
            if summary is not None:
                self._swarm_summaries.append(summary)

    # ------------------------------------------------------------------ training: latent_ppo/update.py
    def _minibatch_losses(self, rollout_data: Any, clip_range: float, clip_range_vf: float | None) -> dict[str, th.Tensor]:
        """The unweighted terms of the joint loss on one minibatch, plus the log probability ratio."""
        return minibatch_losses(self, rollout_data, clip_range, clip_range_vf)

    def _loss_weights(self) -> dict[str, float]:
        # Eq. (2): L = -L_CLIP + c1 L_VF + c2 L_map + c3 L_pred (and SB3's entropy bonus)
        return {"policy": 1.0, "value": self.vf_coef, "entropy": self.ent_coef, "map": self.map_coef, "pred": self.pred_coef}

    def _parameter_groups(self) -> list[list[th.nn.Parameter]]:
        """The groups whose gradients are clipped separately (one group with ``grad_clip="global"``)."""
        if self.grad_clip == "global":
            return [list(self.policy.parameters())]
        critic_ids = {id(p) for p in self.policy.critic_parameters}
        rest = [p for p in self.policy.parameters() if id(p) not in critic_ids]
        return [rest, list(self.policy.critic_parameters)]

    def loss_gradient_norms(self, losses: dict[str, th.Tensor]) -> dict[str, float]:
        """L2 norm, over all parameters, of the gradient of each weighted loss term (before any clipping)."""
        return loss_gradient_norms(self, losses)

    def recompute_old_log_probs(self) -> None:
        """Replace the rollout's log pi_old(a_t) by the training forward pass's
        (:func:`~sb3_latentswarm.latent_ppo.update.recompute_old_log_probs`)."""
        recompute_old_log_probs(self)

    def train(self) -> None:
        """One update on the rollout: the joint loss of Sec. III-E, one gradient step per minibatch
        (:func:`~sb3_latentswarm.latent_ppo.update.ppo_update`)."""
        ppo_update(self)

    def learn(
        self: SelfLatentSwarmPPO,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "LatentSwarmPPO",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfLatentSwarmPPO:
        """Train for ``total_timesteps`` agent-steps (SB3's ``learn``).

        With ``reset_num_timesteps=False`` (after :meth:`load` or
        :func:`~sb3_latentswarm.runs.checkpoints.load_checkpoint`), ``total_timesteps`` are
        the steps still to run: the schedules continue from ``num_timesteps`` and TensorBoard logging continues in the
        model's last run folder. Pass a :class:`~sb3_latentswarm.runs.checkpoints.SwarmCheckpointCallback` as ``callback``
        to write checkpoints a run can resume from exactly (``docs/long_runs.md``).
        """
        if self.env is None:
            raise ValueError("LatentSwarmPPO.learn needs an env: pass one to the constructor, load(..., env=...) or set_env")
        if getattr(self, "_fresh_optimizer", False):  # set by load for a file saved with include_optimizer=False
            warnings.warn(
                "this model was loaded from a weight-only file (saved with include_optimizer=False): the optimizer "
                "starts fresh (Adam's moments at zero), so training does not continue the saved run exactly",
                stacklevel=2,
            )
            self._fresh_optimizer = False
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    @property
    def last_latent_state(self) -> LatentState | None:
        """The latent state carried between rollouts (one row per vec-env slot); ``None`` without an env."""
        return self._last_latent_state
