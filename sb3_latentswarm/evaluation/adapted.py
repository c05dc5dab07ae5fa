"""Episodes of a model on an adapted env (:func:`~sb3_latentswarm.envs.make_adapted_vec_env`), reported in the env's
own metrics: the mean agent return per episode, and whatever the env's ``metrics_fn`` measures (for MPE2
``simple_spread``, :func:`~sb3_latentswarm.envs.mpe.simple_spread_metrics`: ``final_landmarks_covered`` and
``sum_collisions``).

:func:`evaluate_adapted_conditions` runs the test-time conditions of :mod:`~sb3_latentswarm.evaluation.conditions` on
an :class:`~sb3_latentswarm.envs.adapted_env.AdaptedEnv` the way :func:`~sb3_latentswarm.evaluation.evaluate_conditions`
runs them on the swarm env: each condition sets the link mode of the evaluation env (``full_comm``: every link up,
``no_comm``: every link down, the others: the config's link model at ``p_fail``) and the policy's switches
(``no_predictor``: zeros in place of the predicted message, ``hold_last``, ``no_memory``, ...), with the same episode
seeds in every condition. Its rows carry the message diagnostics the swarm env's rows carry (the map error against
the env's referent, the substitute error and the dropout statistics of
:mod:`~sb3_latentswarm.evaluation.diagnostics`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import pandas as pd
import torch as th
from stable_baselines3.common.vec_env import VecEnv

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.evaluation.actors import LatentActor
from sb3_latentswarm.evaluation.conditions import CONDITIONS, check_condition, condition_config, policy_switches
from sb3_latentswarm.evaluation.diagnostics import DEPTH_COLUMNS, EpisodeDiagnostics
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
from sb3_latentswarm.utils.checks import check_bool, check_int

if TYPE_CHECKING:
    from sb3_latentswarm.envs.adapted_env import AdaptedEnv

__all__ = [
    "ADAPTED_COLUMNS",
    "SUMMARY_SKIPS",
    "adapted_episodes",
    "evaluate_adapted",
    "evaluate_adapted_conditions",
    "summarize_adapted",
]

ADAPTED_COLUMNS = ("episode", "seed", "condition", "p_fail", "return", "length")
"""The first columns of :func:`evaluate_adapted_conditions`' rows; the env's ``final_<name>`` / ``sum_<name>`` metrics
follow, then the message diagnostics of the swarm env's rows (``map_error``: D_eta's squared error against the
referent; ``pred_error_dropout``; :data:`~sb3_latentswarm.evaluation.DIAGNOSTIC_COLUMNS`)."""
SUMMARY_SKIPS = ("dropout_run_mean", *DEPTH_COLUMNS)
"""Per-episode columns :func:`summarize_adapted` leaves out of its table (they stay in the per-episode rows)."""


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


def evaluate_adapted_conditions(
    model: Any,
    env: AdaptedEnv,
    config: SwarmConfig,
    conditions: Sequence[str] = CONDITIONS,
    p_fail: float | None = None,
    n_episodes: int = 10,
    seed: int = 1_000_000,
    deterministic: bool = False,
) -> pd.DataFrame:
    """The model on the adapted env ``env`` under each test-time condition, on the same episode seeds; one row per
    episode (:data:`ADAPTED_COLUMNS`, then the env's own metrics, e.g. ``final_landmarks_covered`` and
    ``sum_collisions`` for simple_spread). Episode ``k`` is the first episode of env copy ``k``, reset with seed
    ``seed + k``: every row depends on its seed (and, with sampled actions, on the torch generator seeded with
    ``seed``), the same in every condition.

    :param model: a :class:`~sb3_latentswarm.LatentSwarmPPO` trained on an env of this kind
    :param env: the env, by name (``--env``)
    :param config: its link fields (``link_model``, ``p_fail``, ...; ``Preset.with_env``); each condition replaces
        ``link_mode`` (and ``p_fail``)
    :param conditions: names of :data:`~sb3_latentswarm.evaluation.CONDITION_TABLE`
    :param p_fail: p_f of the link model; ``None`` keeps ``config.p_fail``
    :param seed: episode ``k`` resets with ``seed + k`` (held out from training by default); the sampled actions
        draw from a torch generator seeded with it
    :param deterministic: mean actions instead of sampled ones (default: sampled, the paper's protocol)
    :raise ValueError: an unknown condition, a bad count or p_f; a model without a latent-swarm policy under a
        condition that switches one off
    """
    names = [check_condition(name).name for name in conditions]
    check_int("n_episodes", n_episodes, low=1)
    check_int("seed", seed, low=0)
    check_bool("deterministic", deterministic)
    policy = getattr(model, "policy", None)
    if not isinstance(policy, LatentSwarmPolicy):
        raise TypeError(f"model must be a LatentSwarmPPO, got {type(model).__name__}")
    frames = []
    for name in names:
        cell = condition_config(config, name, config.p_fail if p_fail is None else p_fail)

        def make_env(copies: int, first_seed: int, cell: SwarmConfig = cell) -> VecEnv:
            return env.make_vec_env(copies, cell, first_seed, monitor=False)

        with policy_switches(policy, name):
            episodes = _first_episodes(model, make_env(n_episodes, seed), deterministic, seed)
        frame = pd.DataFrame(episodes)
        frame.insert(0, "episode", np.arange(n_episodes))
        frame.insert(1, "seed", seed + np.arange(n_episodes))
        frame.insert(2, "condition", name)
        frame.insert(3, "p_fail", cell.p_fail)
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def _first_episodes(model: Any, env: VecEnv, deterministic: bool, seed: int) -> list[dict[str, float]]:
    """The ``episode_metrics`` of the first episode of every copy of ``env``, in copy order, each with the message
    diagnostics of :mod:`~sb3_latentswarm.evaluation.diagnostics` (``map_error``, ``pred_error_dropout``,
    ``dropout_share``, ...: the swarm env's columns). The copies that finish early run on until the last one has
    finished; their later episodes are not kept.

    The actions come from ``model.predict``; the diagnostics from a :class:`~sb3_latentswarm.evaluation.actors.
    LatentActor` stepped beside it on the same observations with mean actions. Its latent state is the policy's (the
    latent updates read observations and links, never the sampled action), and it draws no random numbers, so the
    episodes and the sampled actions are what ``predict`` alone gives.
    """
    n_agents = int(env.get_attr("n_agents", indices=0)[0])
    n_copies = env.num_envs // n_agents
    episodes: list[dict[str, float] | None] = [None] * n_copies
    policy = model.policy
    shadow = LatentActor(policy, env.num_envs, n_agents)
    diagnostics = EpisodeDiagnostics(n_copies, env.num_envs)
    episode_of_slot = np.repeat(np.arange(n_copies), n_agents)  # copy c plays episode c until its first one ends
    with th.random.fork_rng():
        th.manual_seed(seed)
        obs = cast(dict[str, np.ndarray], env.reset())  # an adapted env's observations are a Dict
        state = None
        starts = np.ones(env.num_envs, dtype=bool)
        while any(episode is None for episode in episodes):
            referent = obs[policy.layout.referent_key][::n_agents]  # the same in every slot of a copy: one per copy
            actor_obs = {key: obs[key] for key in policy.layout.actor_keys} | {policy.layout.referent_key: referent}
            _, map_error, pred_error = shadow.act(actor_obs, starts.astype(np.float32), None)
            dropout = obs["link_row"].sum(-1) == 0
            diagnostics.record(episode_of_slot, starts, dropout, map_error, pred_error)
            actions, state = model.predict(obs, state=state, episode_start=starts, deterministic=deterministic)
            step_obs, _, starts, infos = env.step(actions)
            obs = cast(dict[str, np.ndarray], step_obs)
            for copy in np.flatnonzero(starts[::n_agents]):
                if episodes[copy] is None:
                    episodes[copy] = dict(infos[copy * n_agents]["episode_metrics"]) | diagnostics.row(int(copy))
                    episode_of_slot[copy * n_agents : (copy + 1) * n_agents] = -1
    env.close()
    return [episode for episode in episodes if episode is not None]


def summarize_adapted(df: pd.DataFrame, by: str = "condition", decimals: int = 3) -> pd.DataFrame:
    """Per group, the mean and the standard deviation (across episodes, ``ddof=1``) of every metric column of
    :func:`evaluate_adapted_conditions` but :data:`SUMMARY_SKIPS`; one row per group in the order of first appearance
    (a diagnostic with no value in a group, e.g. ``pred_error_dropout`` with every link up, reads ``nan``).

    :raise ValueError: ``by`` is not a column
    """
    if by not in df.columns:
        raise ValueError(f"summarize_adapted: no column {by!r}; the DataFrame has {list(df.columns)}")
    labels = ("episode", "seed", "condition", "p_fail", "eval_set", by, *SUMMARY_SKIPS)
    metrics = [c for c in df.columns if c not in labels]
    rows = []
    for group, runs in df.groupby(by, sort=False):
        row: dict[str, Any] = {by: group, "episodes": len(runs)}
        for metric in metrics:
            std = runs[metric].std(ddof=1) if len(runs) > 1 else float("nan")
            row[metric] = f"{runs[metric].mean():.{decimals}f} ± {std:.{decimals}f}"
        rows.append(row)
    return pd.DataFrame(rows)
