"""What a checkpoint's run state must satisfy to be put into a model and its env: every shape, counter and range
checked against the model, the env and the env's config, before anything is changed.

:func:`check_run_state` is called by :func:`~sb3_latentswarm.runs.checkpoints.restore_run_state`; a failure is a
:class:`~sb3_latentswarm.runs.checkpoint_file.CheckpointError` naming the file and the value.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from sb3_latentswarm.latent_ppo.type_aliases import LatentState
from sb3_latentswarm.runs.checkpoint_file import CheckpointContents, CheckpointError, make_generator

__all__ = [
    "CORE_ARRAYS", "LINK_STATE", "OPTIONAL_CORE_ARRAYS", "READ_ONLY_ARRAYS", "RestorePlan", "check_run_state", "unwrap"
]

CORE_ARRAYS = (
    "_truth", "_map", "_covered", "kinematics", "_links", "footprint", "t", "n_covered", "collisions",
    "episode_return", "steps_to_90", "_in_link_sum", "_n_dropouts", "_n_link_draws", "_reward_terms", "dropout",
    "local_obs", "proprio", "link_rows", "global_map",
)
"""Attributes of the batched core (:class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`) that change while it runs;
the others are constants of the config. Arrays go to ``arrays.npz``, the random streams to ``state.json``."""
OPTIONAL_CORE_ARRAYS = ("_link_ages", "link_ages")
"""Core arrays that exist only with some configs (``None`` otherwise): the message ages under delay."""
READ_ONLY_ARRAYS = ("local_obs", "proprio", "link_rows", "global_map", "link_ages")
LINK_STATE = "link_model."
"""Prefix of the link model's state arrays in ``arrays.npz`` (:meth:`~sb3_latentswarm.links.LinkModel.get_state`)."""


class RestorePlan(NamedTuple):
    """What :func:`check_run_state` found: whether the episodes can be restored, the swarms' generators, the core
    arrays to set (optional ones included) and the link model's state."""

    restore_episodes: bool
    generators: list[np.random.Generator]
    core_arrays: tuple[str, ...] = ()
    link_state: dict[str, np.ndarray] | None = None


def unwrap(env: VecEnv) -> tuple[VecMonitor | None, VecEnv]:
    """The ``VecMonitor`` around ``env`` (or ``None``) and the innermost vec env."""
    monitor = None
    while hasattr(env, "venv"):
        if isinstance(env, VecMonitor):
            monitor = env
        env = env.venv
    return monitor, env


def _fail(path: Any, text: str) -> CheckpointError:
    return CheckpointError(f"{path}: {text}")


def _in_range(array: np.ndarray, low: float, high: float) -> bool:
    return bool(array.size == 0 or (np.isfinite(array).all() and array.min() >= low and array.max() <= high))


def _check_counters(model: Any, contents: CheckpointContents) -> None:
    state, path = contents.state, contents.path
    for name, attribute in (("num_timesteps", "num_timesteps"), ("n_updates", "_n_updates"),
                            ("total_timesteps", "_total_timesteps")):
        if int(state[name]) != int(getattr(model, attribute)):
            raise _fail(path, f"state.json {name} is {state[name]} but its model.zip says {getattr(model, attribute)}: "
                              f"the two parts of the checkpoint disagree")


def _check_observations(model: Any, contents: CheckpointContents) -> None:
    arrays, path, n_envs = contents.arrays, contents.path, model.n_envs
    space = model.observation_space
    stored = {name[9:] for name in arrays if name.startswith("last_obs.")}
    if stored != set(space.spaces):
        raise _fail(path, f"arrays.npz holds the observations {sorted(stored)}, the model observes {sorted(space.spaces)}")
    for key, sub in space.spaces.items():
        value = arrays[f"last_obs.{key}"]
        if value.shape != (n_envs, *sub.shape) or value.dtype != sub.dtype:
            raise _fail(path, f"arrays.npz last_obs.{key} is {value.dtype} {value.shape}, the env's is "
                              f"{sub.dtype} {(n_envs, *sub.shape)}")
        if not np.isfinite(value).all():
            raise _fail(path, f"arrays.npz last_obs.{key} holds NaN or infinite observations")
        if not (np.all(value >= sub.low) and np.all(value <= sub.high)):
            raise _fail(path, f"arrays.npz last_obs.{key} holds observations outside the observation space "
                              f"[{sub.low.min()}, {sub.high.max()}]")
    starts = arrays.get("last_episode_starts")
    if starts is None or starts.shape != (n_envs,) or not np.isin(starts, (0, 1)).all():
        raise _fail(path, f"arrays.npz last_episode_starts must be {n_envs} values of 0 or 1")
    initial = model.policy.initial_state(n_envs)
    for name in LatentState._fields:
        tensor, want = contents.tensors.get(f"latent.{name}"), getattr(initial, name)
        if tensor is None and want.numel() == 0:  # a field without columns (delay-aware only) of an older checkpoint
            continue
        if not isinstance(tensor, th.Tensor) or tensor.shape != want.shape or tensor.dtype != want.dtype:
            got = "nothing" if tensor is None else f"{tensor.dtype} {tuple(tensor.shape)}"
            raise _fail(path, f"tensors.pth latent.{name} must be {want.dtype} {tuple(want.shape)}, got {got}")


def _check_monitor(monitor: VecMonitor | None, contents: CheckpointContents, n_envs: int) -> None:
    arrays, path = contents.arrays, contents.path
    if monitor is None or "env.monitor_episode_returns" not in arrays:
        return
    returns, lengths = arrays["env.monitor_episode_returns"], arrays.get("env.monitor_episode_lengths")
    if returns.shape != monitor.episode_returns.shape or lengths is None or lengths.shape != monitor.episode_lengths.shape:
        raise _fail(path, f"the checkpoint's env has {returns.shape[0] if returns.ndim else 0} slots, this env {n_envs}")
    if not np.isfinite(returns).all() or lengths.dtype.kind not in "iu" or (lengths < 0).any():
        raise _fail(path, "arrays.npz env.monitor_episode_* hold non-finite returns or negative lengths")
    if "monitor_episode_count" not in contents.state["env"]:
        raise _fail(path, "state.json env lacks monitor_episode_count")


def _link_state(core: Any, contents: CheckpointContents) -> dict[str, np.ndarray]:
    """The link model's saved state, checked against the env's link model (keys, shapes, dtypes, ranges).

    Checkpoints written before the link models existed keep the Gilbert-Elliott chains as ``core._xi_state``.
    """
    arrays, path, prefix = contents.arrays, contents.path, f"env.core.{LINK_STATE}"
    state = {name[len(prefix):]: value for name, value in arrays.items() if name.startswith(prefix)}
    own = core.link_model.get_state()
    if not state and "env.core._xi_state" in arrays and "xi_state" in own:
        state = {"xi_state": arrays["env.core._xi_state"]}
    if set(state) != set(own):
        raise _fail(path, f"the checkpoint's link model state has {sorted(state)}, this env's {sorted(own)}: the env "
                          f"config differs from the checkpoint's")
    expiry = getattr(core.link_model, "expiry", 0)
    for name, current in own.items():
        value = state[name]
        if value.shape != current.shape or value.dtype != current.dtype:
            raise _fail(path, f"arrays.npz link model state {name!r} is {value.dtype} {value.shape}, this env's "
                              f"{current.dtype} {current.shape}: the env config differs from the checkpoint's")
        high = 1 if name.endswith("xi_state") else expiry if name.endswith("in_flight") else np.inf
        if not _in_range(value, -1, high):
            raise _fail(path, f"arrays.npz link model state {name!r} holds values outside [-1, {high}]")
    return state


def _check_core(inner: Any, contents: CheckpointContents) -> tuple[list[np.random.Generator], tuple[str, ...]]:
    """Shapes, dtypes and ranges of the batched core's saved arrays; the swarms' generators and the arrays to set."""
    core, arrays, env_state, path = inner.core, contents.arrays, contents.state["env"], contents.path
    if len(env_state["swarm_rngs"]) != core.n_swarms:
        raise _fail(path, f"the checkpoint's env has {len(env_state['swarm_rngs'])} swarms, this env {core.n_swarms}")
    optional = tuple(name for name in OPTIONAL_CORE_ARRAYS if getattr(core, name) is not None)
    saved = {}
    for name in (*CORE_ARRAYS, *optional):
        value, current = arrays.get(f"env.core.{name}"), getattr(core, name)
        if value is None or value.shape != current.shape or value.dtype != current.dtype:
            got = "nothing" if value is None else f"{value.shape} {value.dtype}"
            raise _fail(path, f"the checkpoint's env state {name} has shape {got}, this env's {current.shape} "
                              f"{current.dtype}: the env config differs from the checkpoint's")
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            raise _fail(path, f"arrays.npz env.core.{name} holds NaN or infinite values")
        saved[name] = value
    config, n_agents = inner.config, core.n_agents
    t, draws = saved["t"], saved["_n_link_draws"]
    ranges = {  # name: (low, high) of every element
        "_truth": (-1, 1), "_map": (-1, 1), "local_obs": (-1, 1), "global_map": (-1, 1),
        "footprint": (0, core._pad_size - 1), "t": (0, config.max_steps), "n_covered": (0, core._n_cells),
        "collisions": (0, np.inf), "_n_link_draws": (0, config.max_steps + 1), "link_rows": (0, 1),
    }
    for name, (low, high) in ranges.items():
        if not _in_range(saved[name], low, high):
            raise _fail(path, f"arrays.npz env.core.{name} holds values outside [{low}, {high}]")
    covered = saved["_covered"].reshape(core.n_swarms, -1)[:, core._inside_flat].sum(axis=1)
    if not np.array_equal(covered, saved["n_covered"]):
        raise _fail(path, f"arrays.npz env.core.n_covered {saved['n_covered'].tolist()} differs from the covered cells "
                          f"of its map {covered.tolist()}")
    if ((saved["steps_to_90"] < -1) | (saved["steps_to_90"] > t)).any():
        raise _fail(path, "arrays.npz env.core.steps_to_90 must be -1 or a step of the episode so far")
    if ((saved["_in_link_sum"] < 0) | (saved["_in_link_sum"] > draws[:, None] * max(n_agents - 1, 1))).any():
        raise _fail(path, "arrays.npz env.core._in_link_sum is outside [0, link draws x peers]")
    if ((saved["_n_dropouts"] < 0) | (saved["_n_dropouts"] > draws[:, None])).any():
        raise _fail(path, "arrays.npz env.core._n_dropouts is outside [0, link draws]")
    lengths = contents.arrays.get("env.monitor_episode_lengths")
    per_slot = np.repeat(t, n_agents)
    if lengths is not None and lengths.shape == per_slot.shape and not np.array_equal(lengths, per_slot):
        raise _fail(path, f"arrays.npz env.monitor_episode_lengths {lengths.tolist()} differ from the swarms' steps "
                          f"{t.tolist()}")
    for name in optional:  # message ages under delay
        if not _in_range(saved[name], 0, getattr(core.link_model, "expiry", np.inf)):
            raise _fail(path, f"arrays.npz env.core.{name} holds ages outside [0, the link model's expiry]")
    generators = [make_generator(state, path, f"env.swarm_rngs[{k}]") for k, state in enumerate(env_state["swarm_rngs"])]
    return generators, (*CORE_ARRAYS, *optional)


def check_run_state(model: Any, contents: CheckpointContents) -> RestorePlan:
    """Check the run state of ``contents`` against ``model`` (built from the checkpoint's model.zip) and its env.

    :raise CheckpointError: naming the file and the first value that does not fit
    """
    from sb3_latentswarm.envs.vec_env import BatchedSwarmVecEnv

    _check_counters(model, contents)
    if model.env is None:
        return RestorePlan(False, [])
    monitor, inner = unwrap(model.env)
    _check_monitor(monitor, contents, model.n_envs)
    state_env = contents.state["env"]
    if not isinstance(inner, BatchedSwarmVecEnv) or state_env.get("backend") != type(inner).__name__:
        return RestorePlan(False, [])
    if "swarm_rngs" not in state_env:
        raise _fail(contents.path, "state.json env lacks the swarms' random streams")
    generators, core_arrays = _check_core(inner, contents)
    link_state = _link_state(inner.core, contents)
    _check_observations(model, contents)
    return RestorePlan(True, generators, core_arrays, link_state)
