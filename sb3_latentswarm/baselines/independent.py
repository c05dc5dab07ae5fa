"""Independent recurrent PPO: sb3-contrib's ``RecurrentPPO`` on the same swarm VecEnv, without messages.

Each UAV is a separate slot with a shared LSTM policy that sees only its own observation (the sensor patch ``local_obs``
and the proprioceptive state ``proprio``): no links, no global state, no critic privileges. This is the learned
"every UAV for itself" row of the comparison; the paper does not report it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_latentswarm.envs.observations import as_vec_observation
from sb3_latentswarm.latent_ppo.model_file import UnsafeModelFileError, load_plain, read_data, save_plain

INDEPENDENT_KEYS = ("local_obs", "proprio")


class OwnObservationVecEnv(VecEnvWrapper):
    """Keep only each agent's own observation keys (drops ``link_row``, ``swarm_proprio`` and ``global_map``)."""

    def __init__(self, venv: VecEnv, keys: tuple[str, ...] = INDEPENDENT_KEYS):
        missing = [key for key in keys if key not in venv.observation_space.spaces]  # type: ignore[attr-defined]
        if missing:
            raise ValueError(f"The VecEnv lacks the observation key(s) {missing}")
        self.keys = keys
        space = spaces.Dict({key: venv.observation_space[key] for key in keys})  # type: ignore[index]
        super().__init__(venv, observation_space=space)

    def _filter(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {key: obs[key] for key in self.keys}

    def reset(self):
        return self._filter(self.venv.reset())

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        for info in infos:
            if "terminal_observation" in info:
                info["terminal_observation"] = self._filter(info["terminal_observation"])
        return self._filter(obs), rewards, dones, infos


class IndependentRecurrentPPO:
    """A trained ``RecurrentPPO`` with the ``predict`` of the evaluation harness (it drops the other keys itself).

    :param model: a ``RecurrentPPO`` trained on :class:`OwnObservationVecEnv`
    """

    def __init__(self, model: RecurrentPPO):
        self.model = model

    def predict(self, observation: dict[str, Any], state=None, episode_start=None, deterministic: bool = True):
        own, agent_names = as_vec_observation(observation, INDEPENDENT_KEYS, "IndependentRecurrentPPO")
        actions, state = self.model.predict(own, state, episode_start, deterministic)
        return (dict(zip(agent_names, actions)) if agent_names is not None else actions), state

    def save(self, path: str | Path, include_optimizer: bool = True) -> None:
        """Save the wrapped ``RecurrentPPO`` in SB3's zip layout with plain data and no pickle (as LatentSwarmPPO).

        :param include_optimizer: ``False`` writes a weight-only file (no Adam state), enough to evaluate
        """
        save_plain(self.model, path, include_optimizer=include_optimizer)

    @classmethod
    def load(cls, path: str | Path, device: str = "auto", trust_pickle: bool = False) -> IndependentRecurrentPPO:
        """Load a ``RecurrentPPO`` saved by :meth:`save` (or trained on :class:`OwnObservationVecEnv` elsewhere).

        :param trust_pickle: also read SB3's own files, whose pickled attributes run code when loaded: only for
            files you trust (see :mod:`sb3_latentswarm.latent_ppo.model_file`)
        """
        if not Path(path).exists():
            raise ValueError(f"IndependentRecurrentPPO.load: no file at {path}")
        raw, pickled = read_data(path)
        if not pickled:
            return cls(load_plain(RecurrentPPO, path, raw, device=device))
        if not trust_pickle:
            raise UnsafeModelFileError(path, pickled)
        return cls(RecurrentPPO.load(path, device=device))


def independent_ppo(
    vec_env: VecEnv,
    seed: int = 0,
    hidden: int = 64,
    n_steps: int = 128,
    batch_size: int = 512,
    continue_from: str | Path | None = None,
    **kwargs: Any,
) -> RecurrentPPO:
    """sb3-contrib ``RecurrentPPO("MultiInputLstmPolicy")`` on each UAV's own observation, ready to ``learn``.

    :param vec_env: a swarm VecEnv from :func:`sb3_latentswarm.make_vec_env`
    :param hidden: LSTM hidden size and MLP width
    :param kwargs: other ``RecurrentPPO`` arguments; ``policy_kwargs`` are added to the LSTM sizes above
        (:meth:`Preset.independent_ppo_kwargs <sb3_latentswarm.presets.Preset.independent_ppo_kwargs>` gives a
        preset's PPO settings)
    :param continue_from: a model saved by :meth:`IndependentRecurrentPPO.save` to continue (weights, optimizer
        state, agent-step count; SB3's ``load`` then ``learn(reset_num_timesteps=False)``) instead of a new model;
        ``seed`` then reseeds its random numbers, and the other arguments are the saved ones
    """
    if continue_from is not None:
        model = IndependentRecurrentPPO.load(continue_from, device=kwargs.get("device", "auto")).model
        model.set_env(OwnObservationVecEnv(vec_env))
        model.set_random_seed(seed)
        return model
    policy_kwargs = dict(lstm_hidden_size=hidden, net_arch=[hidden], **kwargs.pop("policy_kwargs", {}))
    settings: dict[str, Any] = dict(n_steps=n_steps, batch_size=batch_size, ent_coef=0.01, seed=seed)
    return RecurrentPPO(
        "MultiInputLstmPolicy", OwnObservationVecEnv(vec_env), **{**settings, **kwargs}, policy_kwargs=policy_kwargs
    )


def train_independent_ppo(
    vec_env: VecEnv,
    total_timesteps: int,
    seed: int = 0,
    callback: MaybeCallback = None,
    continue_from: str | Path | None = None,
    **kwargs: Any,
) -> IndependentRecurrentPPO:
    """Train :func:`independent_ppo` (new, or ``continue_from``'s model) up to ``total_timesteps`` agent-steps.

    :param total_timesteps: budget in agent-steps
    :param callback: SB3 callback(s) of ``learn`` (e.g. progress reports)
    :param kwargs: the other arguments of :func:`independent_ppo` (``hidden``, ``n_steps``, RecurrentPPO's)
    :raise ValueError: for a ``continue_from`` model that has already trained ``total_timesteps`` or more
    """
    model = independent_ppo(vec_env, seed=seed, continue_from=continue_from, **kwargs)
    if continue_from is not None and model.num_timesteps >= total_timesteps:
        raise ValueError(
            f"continue_from {continue_from} has trained {model.num_timesteps:,} agent-steps, not fewer than "
            f"total_timesteps={total_timesteps:,}"
        )
    model.learn(
        total_timesteps=total_timesteps - model.num_timesteps, callback=callback, reset_num_timesteps=continue_from is None
    )
    return IndependentRecurrentPPO(model)
