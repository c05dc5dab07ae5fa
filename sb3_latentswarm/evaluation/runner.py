"""The episode runner on the batched core, and the public entry points :func:`evaluate`, :func:`evaluate_conditions`
and :func:`evaluate_p_fail_sweep`.

Episodes run in one :class:`~sb3_latentswarm.envs.batched_core.SwarmBatch` of ``n_envs`` swarms (the stepping path of
training), with one batched policy call per step for the agents of all swarms; a swarm that finishes starts the next
pending episode inside the same batch.

Reproducibility: episode ``k`` resets its swarm with seed ``seed + k`` (obstacles, start positions, actuation noise,
sensor flips, links: the swarm's own generator), and with ``deterministic=False`` draws its action noise from its own
generator seeded from ``seed + k``, so every row depends on its own seed only, not on ``n_envs`` or on the other
episodes. The same ``seed`` across conditions and p_f values gives common random numbers: the same maps and start
positions. The default ``seed`` is :data:`HELD_OUT_SEED` (1,000,000): training seeds its env copies ``seed + c`` with
small seeds (``sb3-latentswarm train --seed S``: S .. S + n_envs - 1; the sweep: ``train_seed * n_envs + c``), so
the default evaluation episodes are never the first episodes of a training env copy
(:func:`check_held_out` says so for a given training run).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from typing import Any, Literal, overload

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.batched_core import LINK_AGE_KEY, SwarmBatch
from sb3_latentswarm.evaluation.actors import LatentActor, PredictActor
from sb3_latentswarm.evaluation.conditions import (
    CONDITIONS,
    check_condition,
    check_p_fail,
    condition_config,
    policy_switches,
)
from sb3_latentswarm.evaluation.diagnostics import EPISODE_COLUMNS, EpisodeDiagnostics
from sb3_latentswarm.evaluation.paper import PAPER_P_FAILS
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
from sb3_latentswarm.utils.checks import check_bool, check_int
from sb3_latentswarm.utils.seeding import action_noise_rng

__all__ = [
    "EPISODE_COLUMNS",
    "HELD_OUT_SEED",
    "check_held_out",
    "evaluate",
    "evaluate_conditions",
    "evaluate_p_fail_sweep",
    "seed_range",
]

HELD_OUT_SEED = 1_000_000
"""Default first episode seed of every evaluation: held out from the env seeds of training (see the module docstring)."""

def seed_range(seed: int, n_episodes: int) -> str:
    """The episode seeds ``seed .. seed + n_episodes - 1`` as printed beside every table (``"seeds 1000000-1000009"``)."""
    return f"seed {seed}" if n_episodes == 1 else f"seeds {seed}-{seed + n_episodes - 1}"


def check_held_out(eval_seed: int, n_episodes: int, train_seed: int, n_envs: int) -> None:
    """Raise ``ValueError`` if the evaluation seeds ``eval_seed .. eval_seed + n_episodes - 1`` meet the seeds of the
    training env copies ``train_seed .. train_seed + n_envs - 1`` (each copy's first episode uses its seed)."""
    eval_seed, n_episodes = check_int("eval_seed", eval_seed, 0), check_int("n_episodes", n_episodes, 1)
    train_seed, n_envs = check_int("train_seed", train_seed, 0), check_int("n_envs", n_envs, 1)
    if eval_seed < train_seed + n_envs and train_seed < eval_seed + n_episodes:
        raise ValueError(
            f"The evaluation episode {seed_range(eval_seed, n_episodes)} overlap the training env copies' seeds "
            f"{train_seed}-{train_seed + n_envs - 1}: the evaluation would replay training episodes; use an evaluation "
            f"seed >= {train_seed + n_envs} (default {HELD_OUT_SEED})"
        )


# ---------------------------------------------------------------------------------------------- models

def _resolve_model(model: Any) -> Any:
    """A path is a saved :class:`~sb3_latentswarm.LatentSwarmPPO`, loaded safely (a pickled file is refused)."""
    if not isinstance(model, (str, os.PathLike)):
        return model
    from sb3_latentswarm.latent_ppo import LatentSwarmPPO

    if not (os.path.isfile(model) or os.path.isfile(f"{os.fspath(model)}.zip")):  # SB3's save adds .zip
        raise ValueError(f"model: no file at {model}")
    return LatentSwarmPPO.load(model, device="cpu")


def _latent_policy(model: Any) -> LatentSwarmPolicy | None:
    policy = getattr(model, "policy", model)
    return policy if isinstance(policy, LatentSwarmPolicy) else None


def _model_config(model: Any) -> SwarmConfig | None:
    """The training configuration of ``model`` if it carries one (its own ``config`` or its env's)."""
    for name in ("swarm_config", "config"):  # LatentSwarmPPO saves its training env's config as swarm_config
        config = getattr(model, name, None)
        if isinstance(config, SwarmConfig):
            return config
    env = getattr(model, "env", None)
    if env is None:
        return None
    with contextlib.suppress(Exception):  # any VecEnv: the attribute may be missing or not forwarded
        config = getattr(env, "config", None)
        if isinstance(config, SwarmConfig):
            return config
        config = env.get_attr("config", indices=[0])[0]
        if isinstance(config, SwarmConfig):
            return config
    return None


def _check_geometry(model: Any, policy: LatentSwarmPolicy | None, config: SwarmConfig) -> None:
    """Fail early, with both shapes in the message, when the model was built for another grid or sensor, or reads
    message ages (``delay_aware``) that a config without delay does not give."""
    fw = config.footprint_width
    if policy is not None:
        if tuple(policy.map_shape) != (config.grid_height, config.grid_width) or policy.local_obs_dim != fw * fw:
            raise ValueError(
                f"The policy was built for a {policy.map_shape[1]}x{policy.map_shape[0]} grid and local_obs of "
                f"{policy.local_obs_dim} cells, but the evaluation config has a {config.grid_width}x{config.grid_height} "
                f"grid and sensor_range={config.sensor_range} ({fw * fw} cells); pass the training config"
            )
        if getattr(policy, "delay_aware", False) and config.message_delay == 0:
            raise ValueError(
                "The policy is delay-aware (delay_aware=True: it reads each message's age, the link_age observation), "
                "but the evaluation config has message_delay=0, which gives no ages; evaluate it with delayed links, "
                "message_delay in [1, 1000] (e.g. its training config's, --set message_delay=K on the command line)"
            )
        return
    own = getattr(model, "config", None)
    if isinstance(own, SwarmConfig):
        fields = ("grid_width", "grid_height", "sensor_range", "cell_size", "v_max", "vz_max", "dt")
        differ = {f: (getattr(own, f), getattr(config, f)) for f in fields if getattr(own, f) != getattr(config, f)}
        if differ:
            raise ValueError(f"{type(model).__name__} was built for another geometry than the evaluation config: {differ}")




# ---------------------------------------------------------------------------------------------- rollouts
def _run_episodes(
    actor: LatentActor | PredictActor,
    config: SwarmConfig,
    n_episodes: int,
    seed: int,
    n_envs: int,
    stochastic_noise: bool,
    action_dim: int,
    progress: tqdm | None = None,
) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Run ``n_episodes`` episodes in one batch of ``n_envs`` swarms; return one row per episode and the coverage curves.

    ``progress``, if given, advances by one per finished episode.
    """
    n = config.n_agents
    core = SwarmBatch(config, n_envs)
    n_slots = n_envs * n
    episode_starts = np.zeros(n_slots, dtype=np.float32)
    episode_of = np.full(n_envs, -1)  # episode running in each swarm, -1 idle
    noise_rngs: list[np.random.Generator | None] = [None] * n_envs
    diagnostics = EpisodeDiagnostics(n_episodes, n_slots)
    rows: list[dict[str, Any]] = [{} for _ in range(n_episodes)]
    curves = np.full((n_episodes, config.max_steps + 1), np.nan)
    next_episode = 0

    def start(swarms: np.ndarray) -> None:
        """Start the next pending episodes in ``swarms`` (as many as are pending)."""
        nonlocal next_episode
        swarms = swarms[: n_episodes - next_episode]
        if swarms.size == 0:
            return
        episodes = np.arange(next_episode, next_episode + swarms.size)
        next_episode += swarms.size
        core.reset(swarms, seeds=[seed + int(k) for k in episodes])
        episode_of[swarms] = episodes
        episode_starts.reshape(n_envs, n)[swarms] = 1.0
        if stochastic_noise:
            for swarm, k in zip(swarms.tolist(), episodes.tolist()):
                noise_rngs[swarm] = action_noise_rng(seed + k)
        curves[episodes, 0] = 100.0 * core.coverage[swarms]

    start(np.arange(n_envs))
    while (episode_of >= 0).any():
        live = np.flatnonzero(episode_of >= 0)
        noise: np.ndarray | None = None
        if stochastic_noise:
            swarm_noise = np.zeros((n_envs, n, action_dim), dtype=np.float32)
            for swarm in live.tolist():
                rng = noise_rngs[swarm]
                assert rng is not None  # created when the swarm's episode started
                swarm_noise[swarm] = rng.standard_normal((n, action_dim))
            noise = swarm_noise.reshape(n_slots, action_dim)
        # idle swarms stay in the batch (their actions move nothing that is recorded), so the actor's state keeps
        # one row per slot
        link_rows = core.link_rows.reshape(n_slots, n)
        obs = {
            "local_obs": core.local_obs.reshape(n_slots, -1).copy(),  # writable copies: torch warns on read-only arrays
            "proprio": core.proprio.reshape(n_slots, -1).copy(),
            "link_row": link_rows.copy(),
            "global_map": core.global_map.copy(),  # (n_envs, H, W): read by the map_error diagnostic only
        }
        if core.link_ages is not None:  # delayed links: what a delay-aware policy reads beside link_row
            obs[LINK_AGE_KEY] = core.link_ages.reshape(n_slots, n).copy()
        actions, map_error, pred_error = actor.act(obs, episode_starts, noise)
        diagnostics.record(np.repeat(episode_of, n), episode_starts > 0, link_rows.sum(-1) == 0, map_error, pred_error)
        episode_starts[:] = 0.0
        _, terminated, truncated = core.step(core.check_actions(actions.reshape(n_envs, n, -1)))
        coverage = 100.0 * core.coverage
        steps = core.t[live]
        curves[episode_of[live], steps] = coverage[live]
        finished = live[(terminated | truncated)[live]]
        for swarm in finished.tolist():
            k = int(episode_of[swarm])
            curves[k, core.t[swarm] + 1 :] = coverage[swarm]
            rows[k] = _episode_row(k, seed, core.swarm_summary(swarm), diagnostics.row(k))
            episode_of[swarm] = -1
            if progress is not None:
                progress.update()
        start(finished)
    return rows, curves


def _episode_row(k: int, seed: int, summary: dict[str, Any], diagnostics: dict[str, float]) -> dict[str, Any]:
    steps_to_90 = summary["steps_to_90"]
    return {
        "episode": k,
        "seed": seed + k,
        "coverage": 100.0 * summary["coverage"],
        "collisions": int(summary["collisions"]),
        "steps_to_90": np.nan if steps_to_90 is None else float(steps_to_90),
        "episode_return": float(summary["episode_return"]),
        "episode_length": int(summary["length"]),
        "link_up_rate": float(summary["link_up_rate"]),
        "dropout_rate": float(summary["dropout_rate"]),
        **diagnostics,
    }


# ---------------------------------------------------------------------------------------------- public API
# The return type follows ``return_curves`` (typeshed's habit for flag-dependent returns).
@overload
def evaluate(model: Any, condition: str = ..., p_fail: float | None = ..., n_episodes: int = ..., seed: int = ...,
             config: SwarmConfig | None = ..., deterministic: bool = ..., n_envs: int | None = ...,
             return_curves: Literal[False] = ..., progress_bar: bool = ...) -> pd.DataFrame: ...
@overload
def evaluate(model: Any, condition: str = ..., p_fail: float | None = ..., n_episodes: int = ..., seed: int = ...,
             config: SwarmConfig | None = ..., deterministic: bool = ..., n_envs: int | None = ..., *,
             return_curves: Literal[True], progress_bar: bool = ...) -> tuple[pd.DataFrame, np.ndarray]: ...
@overload
def evaluate(model: Any, condition: str = ..., p_fail: float | None = ..., n_episodes: int = ..., seed: int = ...,
             config: SwarmConfig | None = ..., deterministic: bool = ..., n_envs: int | None = ..., *,
             return_curves: bool, progress_bar: bool = ...) -> pd.DataFrame | tuple[pd.DataFrame, np.ndarray]: ...
def evaluate(
    model: Any,
    condition: str = "proposed",
    p_fail: float | None = None,
    n_episodes: int = 10,
    seed: int = HELD_OUT_SEED,
    config: SwarmConfig | None = None,
    deterministic: bool = True,
    n_envs: int | None = None,
    return_curves: bool = False,
    progress_bar: bool = False,
) -> pd.DataFrame | tuple[pd.DataFrame, np.ndarray]:
    """Evaluate ``model`` under one condition of Sec. IV; one row per episode (Monte Carlo run).

    :param model: a :class:`~sb3_latentswarm.LatentSwarmPPO`, a :class:`~sb3_latentswarm.LatentSwarmPolicy`, or any
        object with a recurrent ``predict(obs, state, episode_start, deterministic)`` over env-major slots (e.g. the
        planners of :mod:`sb3_latentswarm.baselines`, which get no policy diagnostics: NaN); or the path of a saved
        LatentSwarmPPO, loaded with :meth:`~sb3_latentswarm.LatentSwarmPPO.load` (which refuses pickled files)
    :param condition: a name of :data:`~sb3_latentswarm.evaluation.CONDITION_TABLE` (:data:`CONDITIONS` or
        :data:`EXTRA_CONDITIONS`)
    :param p_fail: p_f, the link failure probability of the channel; ``None`` (default) keeps the config's (the
        paper's 0.3 in ``SwarmConfig()`` and the presets)
    :param n_episodes: number of episodes (paper: 10 Monte Carlo runs)
    :param seed: episode ``k`` uses env seed ``seed + k`` (and, if stochastic, action-noise seed ``seed + k``);
        default :data:`HELD_OUT_SEED`, disjoint from the env seeds of training
    :param config: the env configuration; default: the model's training config if it carries one (``model.env``'s
        ``config``, or ``model.config``), else ``SwarmConfig()``. Its ``link_mode`` and ``p_fail`` are replaced by
        the condition's.
    :param deterministic: act with the mean action (SB3's default); ``False`` samples the Gaussian policy, the
        protocol of the paper (Sec. III-D: commands are sampled at execution)
    :param n_envs: swarms stepped together in one batch (default: ``min(n_episodes, 64)``)
    :param return_curves: also return the coverage curves
    :param progress_bar: show a progress bar of finished episodes (tqdm, on stderr)
    :return: the per-episode DataFrame (columns :data:`EPISODE_COLUMNS`: ``coverage`` is the final coverage in %,
        ``steps_to_90`` is NaN when 90 % was never reached, ``map_error`` is the mean over agent-steps of the per-cell
        squared error between D(mu_t^i) and M_hat_t, ``pred_error_dropout`` the mean over dropout agent-steps of the
        per-element squared error between the substitute message (mhat_t^i, or 0 under ``no_predictor``) and the mean
        of z_{t-1}^j over all peers j != i, NaN without dropout or with N = 1; the dropout diagnostics
        ``dropout_share``, ``dropout_run_mean`` and ``pred_error_depth_*`` of
        :mod:`sb3_latentswarm.evaluation.diagnostics`); with ``return_curves`` also an array
        (n_episodes, max_steps + 1) of coverage in % after each step (column 0: after reset), padded with the final
        value after the episode ends.
    """
    spec = check_condition(condition)
    n_episodes = check_int("n_episodes", n_episodes, 1)
    seed = check_int("seed", seed, 0)
    n_envs = min(n_episodes, 64) if n_envs is None else check_int("n_envs", n_envs, 1)
    check_bool("deterministic", deterministic)
    model = _resolve_model(model)
    if config is None:
        config = _model_config(model) or SwarmConfig()
    elif not isinstance(config, SwarmConfig):
        raise TypeError(f"config must be a SwarmConfig or None, got {type(config).__name__}")
    config = condition_config(config, condition, config.p_fail if p_fail is None else p_fail)
    policy = _latent_policy(model)
    _check_geometry(model, policy, config)
    n_envs = min(n_envs, n_episodes)

    description = f"{condition}, p_f={config.p_fail:g}"
    progress = None
    if progress_bar:  # episodes take seconds each: refresh at every one (mininterval=0), so the count is always shown
        progress = tqdm(total=int(n_episodes), desc=description, unit="episode", leave=False, mininterval=0)
    if policy is None:
        if not callable(getattr(model, "predict", None)):
            raise TypeError(
                "model must be a LatentSwarmPPO, a LatentSwarmPolicy or have a recurrent predict(), "
                f"got {type(model).__name__}"
            )
        if spec.switches_policy:
            raise ValueError(
                f"Condition {condition!r} switches off a component of the latent-swarm policy; "
                f"{type(model).__name__} has none (use 'proposed', 'full_comm', 'full_comm_in_range' or 'no_comm')"
            )
        actor: LatentActor | PredictActor = PredictActor(model, deterministic)
        rows, curves = _run_episodes(actor, config, n_episodes, seed, n_envs, False, 0, progress)
    else:
        with policy_switches(policy, condition):
            actor = LatentActor(policy, n_envs * config.n_agents, config.n_agents)
            action_dim = int(policy.action_dim)
            rows, curves = _run_episodes(actor, config, n_episodes, seed, n_envs, not deterministic, action_dim, progress)
    if progress is not None:
        progress.close()

    df = pd.DataFrame(rows)
    df.insert(2, "condition", condition)
    df.insert(3, "p_fail", config.p_fail)
    df = df[list(EPISODE_COLUMNS)]
    return (df, curves) if return_curves else df


@overload
def evaluate_conditions(model: Any, conditions: Sequence[str] = ..., p_fail: float | None = ..., n_episodes: int = ...,
                        seed: int = ..., config: SwarmConfig | None = ..., return_curves: Literal[False] = ...,
                        **kwargs: Any) -> pd.DataFrame: ...
@overload
def evaluate_conditions(model: Any, conditions: Sequence[str] = ..., p_fail: float | None = ..., n_episodes: int = ...,
                        seed: int = ..., config: SwarmConfig | None = ..., *, return_curves: Literal[True],
                        **kwargs: Any) -> tuple[pd.DataFrame, dict[str, np.ndarray]]: ...
@overload
def evaluate_conditions(model: Any, conditions: Sequence[str] = ..., p_fail: float | None = ..., n_episodes: int = ...,
                        seed: int = ..., config: SwarmConfig | None = ..., *, return_curves: bool,
                        **kwargs: Any) -> pd.DataFrame | tuple[pd.DataFrame, dict[str, np.ndarray]]: ...
def evaluate_conditions(
    model: Any,
    conditions: Sequence[str] = CONDITIONS,
    p_fail: float | None = None,
    n_episodes: int = 10,
    seed: int = HELD_OUT_SEED,
    config: SwarmConfig | None = None,
    return_curves: bool = False,
    **kwargs: Any,
) -> pd.DataFrame | tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """:func:`evaluate` under each condition (Table I, left), with the same seeds (same maps and starts).

    :param kwargs: further :func:`evaluate` arguments (``deterministic``, ``n_envs``, ``progress_bar``)
    :return: the concatenated per-episode DataFrame; with ``return_curves`` also ``{condition: curves}``
    """
    for condition in conditions:
        check_condition(condition)
    cells = [(condition, condition, p_fail) for condition in conditions]
    return _evaluate_cells(model, cells, n_episodes, seed, config, return_curves, kwargs)


@overload
def evaluate_p_fail_sweep(model: Any, p_fails: Sequence[float] = ..., n_episodes: int = ..., seed: int = ...,
                          config: SwarmConfig | None = ..., condition: str = ..., return_curves: Literal[False] = ...,
                          **kwargs: Any) -> pd.DataFrame: ...
@overload
def evaluate_p_fail_sweep(model: Any, p_fails: Sequence[float] = ..., n_episodes: int = ..., seed: int = ...,
                          config: SwarmConfig | None = ..., condition: str = ..., *, return_curves: Literal[True],
                          **kwargs: Any) -> tuple[pd.DataFrame, dict[float, np.ndarray]]: ...
@overload
def evaluate_p_fail_sweep(model: Any, p_fails: Sequence[float] = ..., n_episodes: int = ..., seed: int = ...,
                          config: SwarmConfig | None = ..., condition: str = ..., *, return_curves: bool,
                          **kwargs: Any) -> pd.DataFrame | tuple[pd.DataFrame, dict[float, np.ndarray]]: ...
def evaluate_p_fail_sweep(
    model: Any,
    p_fails: Sequence[float] = PAPER_P_FAILS,
    n_episodes: int = 10,
    seed: int = HELD_OUT_SEED,
    config: SwarmConfig | None = None,
    condition: str = "proposed",
    return_curves: bool = False,
    **kwargs: Any,
) -> pd.DataFrame | tuple[pd.DataFrame, dict[float, np.ndarray]]:
    """:func:`evaluate` at each link failure probability (Table I, right), with the same seeds.

    :param kwargs: further :func:`evaluate` arguments (``deterministic``, ``n_envs``, ``progress_bar``)
    :return: the concatenated per-episode DataFrame; with ``return_curves`` also ``{p_fail: curves}``
    """
    cells = [(p, condition, p) for p in (check_p_fail(p) for p in p_fails)]
    return _evaluate_cells(model, cells, n_episodes, seed, config, return_curves, kwargs)


def _evaluate_cells(
    model: Any,
    cells: Sequence[tuple[Any, str, float | None]],
    n_episodes: int,
    seed: int,
    config: SwarmConfig | None,
    return_curves: bool,
    kwargs: dict[str, Any],
) -> pd.DataFrame | tuple[pd.DataFrame, dict[Any, np.ndarray]]:
    """:func:`evaluate` in each ``(key, condition, p_fail)`` cell on the same seeds: the rows concatenated, and with
    ``return_curves`` also ``{key: curves}``."""
    model = _resolve_model(model)
    frames, curves = [], {}
    for key, condition, p_fail in cells:
        df, curves[key] = evaluate(model, condition, p_fail, n_episodes, seed, config, return_curves=True, **kwargs)
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    return (df, curves) if return_curves else df


