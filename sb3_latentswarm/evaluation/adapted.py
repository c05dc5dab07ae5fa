"""Episodes of a model on an adapted env (:func:`~sb3_latentswarm.envs.make_adapted_vec_env`), reported in the env's
own metrics: the mean agent return per episode, and whatever the env's ``metrics_fn`` measures (for MPE2
``simple_spread``, :func:`~sb3_latentswarm.envs.mpe.simple_spread_metrics`: ``final_landmarks_covered`` and
``sum_collisions``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecEnv

from sb3_latentswarm.utils.checks import check_int

__all__ = ["adapted_episodes", "evaluate_adapted"]


def adapted_episodes(
    model: Any,
    make_env: Callable[[int, int], VecEnv],
    n_episodes: int,
    seed: int = 10_000,
    deterministic: bool = False,
    n_envs: int | None = None,
) -> list[dict[str, float]]:
    """Run ``n_episodes`` episodes and return each one's ``episode_metrics`` (``return``, ``length``, ``final_<name>``,
    ``sum_<name>``), in the order they finished (by step, then by copy).

    :param model: anything with a recurrent ``predict(obs, state, episode_start, deterministic)`` (``LatentSwarmPPO``)
    :param make_env: ``(n_envs, seed) -> VecEnv`` building the adapted env (copy ``c`` starts from ``seed + c``)
    :param n_episodes: episodes to collect
    :param seed: the episode seed of the first copy; the sampled actions draw from a torch generator seeded with it
        (the global torch random state is restored afterwards)
    :param deterministic: the mean action instead of sampled ones
    :param n_envs: copies stepped together (default ``min(n_episodes, 8)``)
    """
    check_int("n_episodes", n_episodes, low=1)
    n_envs = min(n_episodes, 8) if n_envs is None else n_envs
    env = make_env(n_envs, seed)
    n_agents = int(env.get_attr("n_agents", indices=0)[0])
    episodes: list[dict[str, float]] = []
    with th.random.fork_rng():
        th.manual_seed(seed)
        obs = env.reset()
        state = None
        starts = np.ones(env.num_envs, dtype=bool)
        while len(episodes) < n_episodes:
            actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=deterministic)
            obs, _, dones, infos = env.step(actions)
            starts = dones
            for slot in np.flatnonzero(dones[::n_agents]) * n_agents:
                episodes.append(dict(infos[slot]["episode_metrics"]))
    env.close()
    return episodes[:n_episodes]


def evaluate_adapted(
    model: Any,
    make_env: Callable[[int, int], VecEnv],
    n_episodes: int = 10,
    seed: int = 10_000,
    deterministic: bool = False,
    n_envs: int | None = None,
) -> dict[str, float]:
    """The mean of every episode metric of :func:`adapted_episodes` over ``n_episodes`` held-out episodes, plus
    ``return_std`` (across episodes)."""
    episodes = adapted_episodes(model, make_env, n_episodes, seed, deterministic, n_envs)
    results = {key: float(np.mean([episode[key] for episode in episodes])) for key in episodes[0]}
    results["return_std"] = float(np.std([episode["return"] for episode in episodes]))
    return results
