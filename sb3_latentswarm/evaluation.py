"""Evaluation harness: the five test-time conditions of Sec. IV, the metrics of Table I, and the paper's numbers.

Conditions (Sec. IV, "To assess each proposed component's contribution, we compare five conditions"):

================  =========================================================================================
``proposed``      the complete framework; links drawn from the A2A channel of Eq. (1) with failure prob. p_f
``full_comm``     every directed link forced up at every step (``link_mode="full"``): coordination upper bound
``no_comm``       every link forced down (``link_mode="none"``): lower bound, every step is a dropout
``no_predictor``  channel links; the predicted message mhat_t is replaced by a zero vector during dropout
``no_memory``     channel links; the memory state rho_t is zeroed before it is used in any update
================  =========================================================================================

More conditions, extensions (:data:`EXTRA_CONDITIONS`, not in Table I and not in the default set of
:func:`evaluate_conditions`; pass them in ``conditions``):

======================  ===================================================================================
``full_comm_in_range``  every link up whose 3D length is within the channel's usable range, every longer link
                        down (``link_mode="full_in_range"``, range :func:`~sb3_latentswarm.channel.usable_link_range`,
                        set by ``SwarmConfig.link_range_probability``): Full comm without delivering messages from
                        peers so far away that the trained policy never received one (with distance-limited links
                        "a message arrived" is also a proximity cue)
``hold_last``           channel links; during dropout the last message actually received in the episode (zero
                        before the first) replaces mhat_t: the baseline a predictor must beat
``own_message``         channel links; during dropout the agent's own message z_{t-1}^i replaces mhat_t
======================  ===================================================================================

The conditions that do not name a substitute keep the policy's own ``message_substitute`` (the predictor for a
model trained as the paper does; zeros for a ``zero_substitute`` learner, the held message for a ``hold_last`` one).

Execution is decentralized: every UAV acts from its own ``local_obs``, ``proprio`` and the messages that reached it
(``link_row``); the global keys of the observation are read only for the ``map_error`` diagnostic. Episodes run in
``n_envs`` :class:`~sb3_latentswarm.envs.SwarmReconEnv` copies stepped in lockstep, with one batched policy call per
step for the agents of all copies; a copy that finishes starts the next pending episode.

Reproducibility: episode ``k`` resets its env with seed ``seed + k`` (obstacles, start positions, actuation noise,
sensor flips, links), and with ``deterministic=False`` draws its action noise from its own generator seeded from
``seed + k``, so every row depends on its own seed only, not on ``n_envs`` or on the other episodes. The same
``seed`` across conditions and p_f values gives common random numbers: the same maps and start positions.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import pandas as pd
import torch as th
from tqdm.auto import tqdm

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.swarm_recon import ACTOR_OBS_KEYS, SwarmReconEnv
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

__all__ = [
    "CONDITIONS",
    "CONDITION_LABELS",
    "EPISODE_COLUMNS",
    "EXTRA_CONDITIONS",
    "PAPER_P_FAILS",
    "PAPER_TABLE1_CONDITIONS",
    "PAPER_TABLE1_P_FAIL",
    "condition_config",
    "evaluate",
    "evaluate_conditions",
    "evaluate_p_fail_sweep",
    "policy_switches",
    "side_by_side",
    "summarize",
    "to_markdown",
]

CONDITIONS = ("proposed", "full_comm", "no_comm", "no_predictor", "no_memory")
"""The five test-time conditions of Sec. IV (Table I, and the default of :func:`evaluate_conditions`)."""
EXTRA_CONDITIONS = ("full_comm_in_range", "hold_last", "own_message")
"""Conditions beyond the paper (see the module docstring); accepted wherever a condition is."""
CONDITION_LABELS = {
    "full_comm": "Full comm (UB)",
    "full_comm_in_range": "Full comm in range",
    "proposed": "Proposed (full)",
    "no_memory": "No memory",
    "no_comm": "No comm (LB)",
    "no_predictor": "No predictor",
    "hold_last": "Hold last message",
    "own_message": "Own message",
}
"""Row labels of Table I."""
PAPER_P_FAILS = (0.0, 0.05, 0.15, 0.3, 0.5)
"""The link failure probabilities of the robustness sweep (Table I, right)."""

_LINK_MODES = {
    "proposed": "channel",
    "full_comm": "full",
    "full_comm_in_range": "full_in_range",
    "no_comm": "none",
    "no_predictor": "channel",
    "no_memory": "channel",
    "hold_last": "channel",
    "own_message": "channel",
}
# (message_substitute, no_memory) of the latent-swarm policy under each condition; None keeps the policy's own
# substitute (see LatentSwarmPolicy.message_substitute)
_SWITCHES: dict[str, tuple[str | None, bool]] = {
    "proposed": (None, False),
    "full_comm": (None, False),
    "full_comm_in_range": (None, False),
    "no_comm": (None, False),
    "no_predictor": ("zero", False),
    "no_memory": (None, True),
    "hold_last": ("hold_last", False),
    "own_message": ("own_message", False),
}

EPISODE_COLUMNS = (
    "episode",
    "seed",
    "condition",
    "p_fail",
    "coverage",
    "collisions",
    "steps_to_90",
    "episode_return",
    "episode_length",
    "link_up_rate",
    "dropout_rate",
    "map_error",
    "pred_error_dropout",
)
"""Columns of the per-episode DataFrame of :func:`evaluate`, in order."""

# Names of the formatted columns of :func:`summarize` (Table I's headers).
COVERAGE_COLUMN = "Coverage (%)"
COLLISIONS_COLUMN = "Collisions"
STEPS_COLUMN = "Steps to 90%"
# Per-episode columns whose mean is also reported by summarize.
_EXTRA_MEANS = ("episode_return", "episode_length", "link_up_rate", "dropout_rate", "map_error", "pred_error_dropout")


# ---------------------------------------------------------------------------------------------- conditions
def _check_condition(condition: str) -> None:
    if condition not in CONDITIONS + EXTRA_CONDITIONS:
        raise ValueError(f"Unknown condition {condition!r}; allowed conditions: {list(CONDITIONS + EXTRA_CONDITIONS)}")


def _check_p_fail(p_fail: float) -> float:
    if isinstance(p_fail, bool) or not isinstance(p_fail, (int, float, np.number)) or not 0.0 <= float(p_fail) <= 1.0:
        raise ValueError(f"p_fail must be a probability in [0, 1], got {p_fail!r}")
    return float(p_fail)


def condition_config(config: SwarmConfig, condition: str, p_fail: float) -> SwarmConfig:
    """The env configuration of ``condition``: its link mode (Sec. IV) and the link failure probability ``p_fail``."""
    _check_condition(condition)
    return config.replace(link_mode=_LINK_MODES[condition], p_fail=_check_p_fail(p_fail))


@contextlib.contextmanager
def policy_switches(policy: LatentSwarmPolicy, condition: str) -> Iterator[LatentSwarmPolicy]:
    """Set the ablation switches of ``condition`` on ``policy`` (and eval mode); restore them on exit.

    Every condition sets ``no_memory``, so ``proposed`` also turns off a memory ablation left on by the caller; the
    substitute is set only by the conditions that name one (``no_predictor``, ``hold_last``, ``own_message``).
    """
    _check_condition(condition)
    saved = (policy.message_substitute, policy.no_memory, policy.training)
    substitute, policy.no_memory = _SWITCHES[condition]
    if substitute is not None:
        policy.message_substitute = substitute
    policy.set_training_mode(False)
    try:
        yield policy
    finally:
        policy.message_substitute, policy.no_memory = saved[0], saved[1]
        policy.set_training_mode(saved[2])


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
    """Fail early, with both shapes in the message, when the model was built for another grid or sensor."""
    fw = config.footprint_width
    if policy is not None:
        if tuple(policy.map_shape) != (config.grid_height, config.grid_width) or policy.local_obs_dim != fw * fw:
            raise ValueError(
                f"The policy was built for a {policy.map_shape[1]}x{policy.map_shape[0]} grid and local_obs of "
                f"{policy.local_obs_dim} cells, but the evaluation config has a {config.grid_width}x{config.grid_height} "
                f"grid and sensor_range={config.sensor_range} ({fw * fw} cells); pass the training config"
            )
        return
    own = getattr(model, "config", None)
    if isinstance(own, SwarmConfig):
        fields = ("grid_width", "grid_height", "sensor_range", "cell_size", "v_max", "vz_max", "dt")
        differ = {f: (getattr(own, f), getattr(config, f)) for f in fields if getattr(own, f) != getattr(config, f)}
        if differ:
            raise ValueError(f"{type(model).__name__} was built for another geometry than the evaluation config: {differ}")


# ---------------------------------------------------------------------------------------------- actors
class _LatentActor:
    """Runs a :class:`LatentSwarmPolicy` on all slots of all copies with one ``latent_step`` per env step.

    Besides the actions it returns, per slot, the two diagnostics of the step (NaN where they do not apply).
    """

    def __init__(self, policy: LatentSwarmPolicy, n_slots: int, n_agents: int) -> None:
        self.policy = policy
        self.n_agents = n_agents
        self.state = policy.initial_state(n_slots)

    def act(
        self, obs: dict[str, np.ndarray], episode_starts: np.ndarray, noise: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        policy, n = self.policy, self.n_agents
        device = policy.device
        with th.no_grad():
            tensors = {key: th.as_tensor(obs[key], device=device) for key in ACTOR_OBS_KEYS}
            starts = th.as_tensor(episode_starts, dtype=th.float32, device=device)
            step = policy.latent_step(tensors, self.state, starts)
            sent = step.sent_message  # z_{t-1}^j = [mu_{t-1}^j; tau_{t-1}^j], zero at an episode start, (B, d_msg)
            self.state = step.state
            # the mean action, or a sample with eps from the episode's own generator
            actions = policy.actions_from_noise(step.state.task_state, noise)

            # map_error: per-cell squared error of D(mu_t^i) against M_hat_t (the target of Eq. (3))
            target = th.as_tensor(obs["global_map"], device=device).float().flatten(1)
            map_error = ((policy.decode_map(step.state.map_state) - target) ** 2).mean(-1)

            # pred_error: the substitute used during dropout (mbar_t there: mhat_t, zeros, the held or the own
            # message) against the message a full link set would have delivered, the mean of z_{t-1}^j over j != i
            if n > 1:
                per_swarm = sent.view(-1, n, sent.shape[-1])
                full_message = ((per_swarm.sum(1, keepdim=True) - per_swarm) / (n - 1)).view_as(sent)
                substitute = step.state.prev_message
                pred_error = ((substitute - full_message) ** 2).mean(-1)
                pred_error = th.where(step.has_message, th.full_like(pred_error, math.nan), pred_error)
            else:
                pred_error = th.full_like(map_error, math.nan)
        return (
            np.clip(actions.cpu().numpy(), -1.0, 1.0),
            map_error.cpu().numpy().astype(np.float64),
            pred_error.cpu().numpy().astype(np.float64),
        )


class _PredictActor:
    """Runs any model with an SB3-style recurrent ``predict(obs, state, episode_start, deterministic)``.

    It receives only the actor keys (decentralized execution) and gives no diagnostics.
    """

    def __init__(self, model: Any, deterministic: bool) -> None:
        self.model = model
        self.deterministic = deterministic
        self.state: Any = None

    def act(
        self, obs: dict[str, np.ndarray], episode_starts: np.ndarray, noise: np.ndarray | None
    ) -> tuple[np.ndarray, None, None]:
        actor_obs = {key: obs[key] for key in ACTOR_OBS_KEYS}
        actions, self.state = self.model.predict(
            actor_obs, state=self.state, episode_start=episode_starts, deterministic=self.deterministic
        )
        return np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0), None, None


# ---------------------------------------------------------------------------------------------- rollouts
_NOISE_STREAM = 0x5EED  # separates the action-noise stream of episode seed s from the env's stream of s


@dataclasses.dataclass
class _EpisodeLog:
    """Diagnostics accumulated over the agent-steps of one episode."""

    map_error_sum: float = 0.0
    map_error_count: int = 0
    pred_error_sum: float = 0.0
    pred_error_count: int = 0


def _run_episodes(
    actor: _LatentActor | _PredictActor,
    config: SwarmConfig,
    n_episodes: int,
    seed: int,
    n_envs: int,
    stochastic_noise: bool,
    action_dim: int,
    progress: tqdm | None = None,
) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Run ``n_episodes`` episodes in ``n_envs`` lockstep copies; return one row per episode and the coverage curves.

    ``progress``, if given, advances by one per finished episode.
    """
    n = config.n_agents
    envs = [SwarmReconEnv(config) for _ in range(n_envs)]
    agents = envs[0].possible_agents
    n_slots = n_envs * n
    spaces = envs[0].observation_space(agents[0])
    batch = {key: np.zeros((n_slots, *spaces[key].shape), dtype=spaces[key].dtype) for key in (*ACTOR_OBS_KEYS, "global_map")}
    episode_starts = np.zeros(n_slots, dtype=np.float32)
    episode_of = np.full(n_envs, -1)  # episode running in each copy, -1 idle
    steps = np.zeros(n_envs, dtype=np.int64)
    noise_rngs: list[np.random.Generator | None] = [None] * n_envs
    logs = [_EpisodeLog() for _ in range(n_episodes)]
    rows: list[dict[str, Any]] = [{} for _ in range(n_episodes)]
    curves = np.full((n_episodes, config.max_steps + 1), np.nan)
    next_episode = 0

    def write(copy: int, obs: dict[str, dict[str, np.ndarray]]) -> None:
        slots = slice(copy * n, (copy + 1) * n)
        for key, array in batch.items():
            array[slots] = [obs[agent][key] for agent in agents]

    def start(copy: int) -> None:
        nonlocal next_episode
        k = next_episode
        next_episode += 1
        obs, _ = envs[copy].reset(seed=seed + k)
        write(copy, obs)
        episode_of[copy] = k
        steps[copy] = 0
        episode_starts[copy * n : (copy + 1) * n] = 1.0
        if stochastic_noise:
            noise_rngs[copy] = np.random.default_rng([seed + k, _NOISE_STREAM])
        curves[k, 0] = 100.0 * envs[copy].coverage

    for copy in range(min(n_envs, n_episodes)):
        start(copy)
    while (episode_of >= 0).any():
        live = np.flatnonzero(episode_of >= 0)
        noise = None
        if stochastic_noise:
            noise = np.zeros((n_slots, action_dim), dtype=np.float32)
            for copy in live:
                noise[copy * n : (copy + 1) * n] = noise_rngs[copy].standard_normal((n, action_dim))
        # idle copies stay in the batch with their last observation (their actions are dropped), so the actor's
        # state keeps one row per slot whatever its layout
        actions, map_error, pred_error = actor.act(batch, episode_starts, noise)
        episode_starts[:] = 0.0
        for copy in live:
            k = int(episode_of[copy])
            slots = slice(copy * n, (copy + 1) * n)
            if map_error is not None:
                log = logs[k]
                log.map_error_sum += float(map_error[slots].sum())
                log.map_error_count += n
                dropped = pred_error[slots][~np.isnan(pred_error[slots])]
                log.pred_error_sum += float(dropped.sum())
                log.pred_error_count += dropped.size
            obs, _, terminations, truncations, infos = envs[copy].step(
                {agent: actions[copy * n + i] for i, agent in enumerate(agents)}
            )
            steps[copy] += 1
            curves[k, steps[copy]] = 100.0 * envs[copy].coverage
            if terminations[agents[0]] or truncations[agents[0]]:
                curves[k, steps[copy] + 1 :] = curves[k, steps[copy]]
                rows[k] = _episode_row(k, seed, infos[agents[0]]["swarm_summary"], logs[k], map_error is not None)
                episode_of[copy] = -1
                if progress is not None:
                    progress.update()
                if next_episode < n_episodes:
                    start(copy)
            else:
                write(copy, obs)
    return rows, curves


def _episode_row(k: int, seed: int, summary: dict[str, Any], log: _EpisodeLog, has_diagnostics: bool) -> dict[str, Any]:
    steps_to_90 = summary["steps_to_90"]
    map_error = log.map_error_sum / log.map_error_count if has_diagnostics and log.map_error_count else math.nan
    pred_error = log.pred_error_sum / log.pred_error_count if has_diagnostics and log.pred_error_count else math.nan
    return {
        "episode": k,
        "seed": seed + k,
        "coverage": 100.0 * summary["coverage"],
        "collisions": int(summary["collisions"]),
        "steps_to_90": math.nan if steps_to_90 is None else float(steps_to_90),
        "episode_return": float(summary["episode_return"]),
        "episode_length": int(summary["length"]),
        "link_up_rate": float(summary["link_up_rate"]),
        "dropout_rate": float(summary["dropout_rate"]),
        "map_error": map_error,
        "pred_error_dropout": pred_error,
    }


# ---------------------------------------------------------------------------------------------- public API
def evaluate(
    model: Any,
    condition: str = "proposed",
    p_fail: float | None = None,
    n_episodes: int = 10,
    seed: int = 0,
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
    :param condition: one of :data:`CONDITIONS` or :data:`EXTRA_CONDITIONS`
    :param p_fail: p_f, the link failure probability of the channel; ``None`` (default) keeps the config's (the
        paper's 0.3 in ``SwarmConfig()`` and the presets)
    :param n_episodes: number of episodes (paper: 10 Monte Carlo runs)
    :param seed: episode ``k`` uses env seed ``seed + k`` (and, if stochastic, action-noise seed ``seed + k``)
    :param config: the env configuration; default: the model's training config if it carries one (``model.env``'s
        ``config``, or ``model.config``), else ``SwarmConfig()``. Its ``link_mode`` and ``p_fail`` are replaced by
        the condition's.
    :param deterministic: act with the mean action (``False``: sample the Gaussian policy)
    :param n_envs: env copies stepped in lockstep (default: ``min(n_episodes, 64)``)
    :param return_curves: also return the coverage curves
    :param progress_bar: show a progress bar of finished episodes (tqdm, on stderr)
    :return: the per-episode DataFrame (columns :data:`EPISODE_COLUMNS`: ``coverage`` is the final coverage in %,
        ``steps_to_90`` is NaN when 90 % was never reached, ``map_error`` is the mean over agent-steps of the per-cell
        squared error between D(mu_t^i) and M_hat_t, ``pred_error_dropout`` the mean over dropout agent-steps of the
        per-element squared error between the substitute message (mhat_t^i, or 0 under ``no_predictor``) and the mean
        of z_{t-1}^j over all peers j != i, NaN without dropout or with N = 1); with ``return_curves`` also an array
        (n_episodes, max_steps + 1) of coverage in % after each step (column 0: after reset), padded with the final
        value after the episode ends.
    """
    _check_condition(condition)
    model = _resolve_model(model)
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, (int, np.integer)) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an int >= 1, got {n_episodes!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an int >= 0, got {seed!r}")
    if n_envs is None:
        n_envs = min(int(n_episodes), 64)
    if isinstance(n_envs, bool) or not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
        raise ValueError(f"n_envs must be None or an int >= 1, got {n_envs!r}")
    if config is None:
        config = _model_config(model) or SwarmConfig()
    elif not isinstance(config, SwarmConfig):
        raise TypeError(f"config must be a SwarmConfig or None, got {type(config).__name__}")
    config = condition_config(config, condition, config.p_fail if p_fail is None else p_fail)
    policy = _latent_policy(model)
    _check_geometry(model, policy, config)
    n_envs = min(int(n_envs), int(n_episodes))

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
        if any(_SWITCHES[condition]):
            raise ValueError(
                f"Condition {condition!r} switches off a component of the latent-swarm policy; "
                f"{type(model).__name__} has none (use 'proposed', 'full_comm', 'full_comm_in_range' or 'no_comm')"
            )
        actor: _LatentActor | _PredictActor = _PredictActor(model, deterministic)
        rows, curves = _run_episodes(actor, config, int(n_episodes), int(seed), n_envs, False, 0, progress)
    else:
        with policy_switches(policy, condition):
            actor = _LatentActor(policy, n_envs * config.n_agents, config.n_agents)
            action_dim = int(np.prod(policy.action_space.shape))
            rows, curves = _run_episodes(
                actor, config, int(n_episodes), int(seed), n_envs, not deterministic, action_dim, progress
            )
    if progress is not None:
        progress.close()

    df = pd.DataFrame(rows)
    df.insert(2, "condition", condition)
    df.insert(3, "p_fail", config.p_fail)
    df = df[list(EPISODE_COLUMNS)]
    return (df, curves) if return_curves else df


def evaluate_conditions(
    model: Any,
    conditions: Sequence[str] = CONDITIONS,
    p_fail: float | None = None,
    n_episodes: int = 10,
    seed: int = 0,
    config: SwarmConfig | None = None,
    return_curves: bool = False,
    **kwargs: Any,
) -> pd.DataFrame | tuple[pd.DataFrame, dict[str, np.ndarray]]:
    """:func:`evaluate` under each condition (Table I, left), with the same seeds (same maps and starts).

    :param kwargs: further :func:`evaluate` arguments (``deterministic``, ``n_envs``, ``progress_bar``)
    :return: the concatenated per-episode DataFrame; with ``return_curves`` also ``{condition: curves}``
    """
    for condition in conditions:
        _check_condition(condition)
    model = _resolve_model(model)
    frames, curves = [], {}
    for condition in conditions:
        df, curves[condition] = evaluate(model, condition, p_fail, n_episodes, seed, config, return_curves=True, **kwargs)
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    return (df, curves) if return_curves else df


def evaluate_p_fail_sweep(
    model: Any,
    p_fails: Sequence[float] = PAPER_P_FAILS,
    n_episodes: int = 10,
    seed: int = 0,
    config: SwarmConfig | None = None,
    condition: str = "proposed",
    return_curves: bool = False,
    **kwargs: Any,
) -> pd.DataFrame | tuple[pd.DataFrame, dict[float, np.ndarray]]:
    """:func:`evaluate` at each link failure probability (Table I, right), with the same seeds.

    :param kwargs: further :func:`evaluate` arguments (``deterministic``, ``n_envs``, ``progress_bar``)
    :return: the concatenated per-episode DataFrame; with ``return_curves`` also ``{p_fail: curves}``
    """
    p_fails = [_check_p_fail(p) for p in p_fails]
    model = _resolve_model(model)
    frames, curves = [], {}
    for p in p_fails:
        df, curves[p] = evaluate(model, condition, p, n_episodes, seed, config, return_curves=True, **kwargs)
        frames.append(df)
    df = pd.concat(frames, ignore_index=True)
    return (df, curves) if return_curves else df


# ---------------------------------------------------------------------------------------------- tables
def _mean_std(values: np.ndarray, ddof: int) -> tuple[float, float]:
    if values.size == 0:
        return math.nan, math.nan
    std = float(np.std(values, ddof=ddof)) if values.size > ddof else math.nan
    return float(np.mean(values)), std


def _format_mean_std(mean: float, std: float, decimals: int) -> str:
    if math.isnan(mean):
        return "N/A"
    if math.isnan(std):
        return f"{mean:.{decimals}f}"
    return f"{mean:.{decimals}f} ± {std:.{decimals}f}"


def summarize(df: pd.DataFrame, by: str | Sequence[str] = "condition", ddof: int = 1, decimals: int = 2) -> pd.DataFrame:
    """Table I's format: per group, mean ± std of coverage and collisions, and steps to 90 % over the runs that got there.

    :param df: per-episode rows from :func:`evaluate` (columns ``coverage``, ``collisions``, ``steps_to_90``)
    :param by: the grouping column(s), e.g. ``"condition"`` or ``"p_fail"``; groups keep their order of appearance
    :param ddof: delta degrees of freedom of the std (1: the sample std; the paper does not say which)
    :param decimals: decimals of the formatted strings (the paper: 2)
    :return: one row per group: the group column(s); ``"Coverage (%)"``, ``"Collisions"`` and ``"Steps to 90%"``
        as strings (``"692.71 ± 189.04 (7/10)"``: 7 of 10 runs reached 90 %, mean ± std over those 7; ``"N/A"`` when
        none did; the std is left out when it is undefined); ``n_runs``, ``n_reached`` and numeric
        ``{coverage,collisions,steps_to_90}_{mean,std}``; and the means of the other per-episode metrics present
        (NaN-ignoring for the diagnostics). ``attrs["display_columns"]`` names the columns :func:`to_markdown` shows.
    """
    keys = [by] if isinstance(by, str) else list(by)
    missing = [c for c in (*keys, "coverage", "collisions", "steps_to_90") if c not in df.columns]
    if missing:
        raise ValueError(f"summarize needs the column(s) {missing}; the DataFrame has {list(df.columns)}")
    rows = []
    for group, runs in df.groupby(keys, sort=False):
        group = group if isinstance(group, tuple) else (group,)
        coverage_mean, coverage_std = _mean_std(runs["coverage"].to_numpy(float), ddof)
        collisions_mean, collisions_std = _mean_std(runs["collisions"].to_numpy(float), ddof)
        steps = runs["steps_to_90"].to_numpy(float)
        reached = steps[~np.isnan(steps)]
        steps_mean, steps_std = _mean_std(reached, ddof)
        steps_text = (
            "N/A"
            if reached.size == 0
            else f"{_format_mean_std(steps_mean, steps_std, decimals)} ({reached.size}/{steps.size})"
        )
        row: dict[str, Any] = dict(zip(keys, group))
        row.update(
            {
                COVERAGE_COLUMN: _format_mean_std(coverage_mean, coverage_std, decimals),
                COLLISIONS_COLUMN: _format_mean_std(collisions_mean, collisions_std, decimals),
                STEPS_COLUMN: steps_text,
                "n_runs": int(steps.size),
                "n_reached": int(reached.size),
                "coverage_mean": coverage_mean,
                "coverage_std": coverage_std,
                "collisions_mean": collisions_mean,
                "collisions_std": collisions_std,
                "steps_to_90_mean": steps_mean,
                "steps_to_90_std": steps_std,
            }
        )
        for column in _EXTRA_MEANS:
            if column in runs.columns:
                values = runs[column].to_numpy(float)
                row[f"{column}_mean"] = float(np.nanmean(values)) if (~np.isnan(values)).any() else math.nan
        rows.append(row)
    summary = pd.DataFrame(rows)
    summary.attrs["display_columns"] = [*keys, COVERAGE_COLUMN, COLLISIONS_COLUMN, STEPS_COLUMN]
    return summary


def _paper_table(rows: list[tuple], key: str) -> pd.DataFrame:
    """Build a paper table: numeric columns plus the strings as printed in the paper."""
    records = []
    for key_value, cov_mean, cov_std, coll_mean, coll_std, steps_mean, steps_std in rows:
        record: dict[str, Any] = {key: key_value}
        if key == "condition":
            record["label"] = CONDITION_LABELS[key_value]
        record[COVERAGE_COLUMN] = _format_mean_std(cov_mean, cov_std, 2)
        if key == "condition":
            record[COLLISIONS_COLUMN] = _format_mean_std(coll_mean, coll_std, 2)
        record[STEPS_COLUMN] = (
            "N/A" if math.isnan(steps_mean) else _format_mean_std(steps_mean, steps_std, 2 if key == "condition" else 0)
        )
        record.update(
            coverage_mean=cov_mean,
            coverage_std=cov_std,
            collisions_mean=coll_mean,
            collisions_std=coll_std,
            steps_to_90_mean=steps_mean,
            steps_to_90_std=steps_std,
        )
        records.append(record)
    return pd.DataFrame(records)


_NAN = math.nan
PAPER_TABLE1_CONDITIONS = _paper_table(
    [
        ("full_comm", 92.40, 2.64, 10.30, 12.54, 732.71, 90.58),
        ("proposed", 90.98, 2.92, 8.70, 8.49, 692.71, 189.04),
        ("no_memory", 81.90, 5.51, 41.50, 24.08, _NAN, _NAN),
        ("no_comm", 83.44, 4.80, 31.90, 21.85, _NAN, _NAN),
        ("no_predictor", 70.30, 3.61, 54.90, 26.12, _NAN, _NAN),
    ],
    key="condition",
)
"""Table I (left) of the paper, p_f = 0.3, 10 Monte Carlo runs; "N/A": no run reached 90 % coverage."""

PAPER_TABLE1_P_FAIL = _paper_table(
    [
        (0.00, 91.66, 2.33, _NAN, _NAN, 665.0, _NAN),
        (0.05, 92.59, 2.04, _NAN, _NAN, 593.0, _NAN),
        (0.15, 91.36, 2.00, _NAN, _NAN, 758.0, _NAN),
        (0.30, 90.89, 2.18, _NAN, _NAN, 651.0, _NAN),
        (0.50, 90.96, 2.17, _NAN, _NAN, 677.0, _NAN),
    ],
    key="p_fail",
)
"""Table I (right) of the paper: the proposed model under a sweep of p_f (steps to 90 % without a std)."""


def side_by_side(summary: pd.DataFrame, paper: pd.DataFrame | None = None) -> pd.DataFrame:
    """Our formatted columns next to the paper's, matched on the paper table's key (``condition`` or ``p_fail``).

    :param summary: the output of :func:`summarize` grouped by ``condition`` or by ``p_fail``
    :param paper: :data:`PAPER_TABLE1_CONDITIONS` or :data:`PAPER_TABLE1_P_FAIL` (default: by the summary's key)
    :return: key column, then for each formatted column of the paper table ``"<column>"`` (ours) and
        ``"<column> (paper)"``; rows in the summary's order, "-" where the paper has no such row
    """
    if paper is None:
        paper = PAPER_TABLE1_CONDITIONS if "condition" in summary.columns else PAPER_TABLE1_P_FAIL
    key = "condition" if "condition" in paper.columns else "p_fail"
    if key not in summary.columns:
        raise ValueError(f"The summary has no {key!r} column to match the paper table on; columns: {list(summary.columns)}")
    text_columns = [c for c in (COVERAGE_COLUMN, COLLISIONS_COLUMN, STEPS_COLUMN) if c in paper.columns]
    paper_rows = {(round(float(v), 6) if key == "p_fail" else v): i for i, v in enumerate(paper[key])}
    records = []
    for _, row in summary.iterrows():
        value = row[key]
        match = paper_rows.get(round(float(value), 6) if key == "p_fail" else value)
        record: dict[str, Any] = {key: value}
        if key == "condition":
            record["label"] = CONDITION_LABELS.get(value, value)
        for column in text_columns:
            record[column] = row[column]
            record[f"{column} (paper)"] = "-" if match is None else paper[column].iloc[match]
        records.append(record)
    return pd.DataFrame(records)


def to_markdown(df: pd.DataFrame, columns: Sequence[str] | None = None, decimals: int = 2) -> str:
    """A GitHub markdown table of ``df`` (no ``tabulate`` needed); floats with ``decimals`` decimals, NaN as "N/A".

    :param columns: the columns to show, in order; default: ``df.attrs["display_columns"]`` if set and all present
        (a :func:`summarize` output shows its group columns and Table I's three formatted columns), else all
    """
    if columns is None:
        display = list(df.attrs.get("display_columns", ()))
        # attrs survive some pandas operations that select columns: then show what was selected
        columns = display if display and set(display) <= set(df.columns) else list(df.columns)
    columns = list(columns)
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"Unknown column(s) {missing}; the DataFrame has {list(df.columns)}")

    def cell(value: Any) -> str:
        if isinstance(value, (float, np.floating)):
            return "N/A" if math.isnan(value) else f"{value:.{decimals}f}"
        return str(value).replace("|", "\\|")

    body = [[cell(v) for v in row] for row in df[columns].itertuples(index=False, name=None)]
    header = [str(c).replace("|", "\\|") for c in columns]
    widths = [max(len(header[i]), *(len(r[i]) for r in body)) if body else len(header[i]) for i in range(len(columns))]
    lines = [
        "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths)) + " |",
        "|" + "|".join("-" * (w + 2) for w in widths) + "|",
    ]
    lines += ["| " + " | ".join(v.ljust(w) for v, w in zip(r, widths)) + " |" for r in body]
    return "\n".join(lines)
