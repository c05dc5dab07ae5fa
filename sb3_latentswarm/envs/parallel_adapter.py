"""The adapter: any PettingZoo ``ParallelEnv`` with homogeneous agents and ``Box`` spaces as the SB3 VecEnv that
``LatentSwarmPPO`` trains on, with a link model (:mod:`sb3_latentswarm.links`) between its agents.

``make_adapted_vec_env(env_fn, n_envs, link_model=...)`` steps ``n_envs`` copies of the env in this process and adds
what the latent policy reads (the adapted layout of :func:`~sb3_latentswarm.envs.observations.observation_layout`):

==================  ===========================  ===========================================================
key                 shape per slot               from
==================  ===========================  ===========================================================
``local_obs``       the agent's observation      the env (float32)
``proprio``         (e,), e may be 0              ``own_state_fn(env)`` (N, e); default none, e = 0
``link_row``        (N,)                          the link model: ``[j] = 1`` iff the message of ``j`` reached
                                                  this agent at this step
``link_age``        (N,), only with delay         the link model: how many steps late that message is (0 where
                                                  nothing arrived), in [0, E] (``docs/concepts.md``, "Delayed messages")
``position``        (3,), only with positions     ``position_fn(env)`` (N, 2) or (N, 3), 2D padded with z = 0
``global_state``    (S,)                          ``state_fn(env)``; default ``env.state()``
``referent``        (R,), only when given         ``referent_fn(env)``; default: D_eta reconstructs the global state
==================  ===========================  ===========================================================

Slots are **env-major, agent-minor** (SuperSuit's order): slot ``k`` is agent ``k % N`` (``possible_agents`` order) of
copy ``k // N``. A copy's episode ends when every agent is terminated or truncated; then all its slots are done
together (``terminal_observation``, ``TimeLimit.truncated`` when nothing terminated, and ``episode_metrics``) and the
copy resets. Copy ``c`` is reset with ``seed + c`` at the first reset after :meth:`AdaptedVecEnv.seed` (or creation),
and its links draw from their own generator seeded by ``(seed, c)``.

The user functions (``position_fn``, ``own_state_fn``, ``state_fn``, ``referent_fn``, ``metrics_fn``) are called
after every reset and step, also after the last step of an episode, when ``env.agents`` may already be empty (the
final state gives V(s_T) for the truncation bootstrap): read the env's world, not ``env.agents``.

What it refuses, before any training (:func:`check_parallel_env` and a probe episode step on a separate copy):
agents with different spaces, a non-``Box`` observation or action space (a ``Discrete`` action space names the
continuous alternative), a position function of the wrong shape, a global state or referent that changes shape, a
link model that needs positions without ``position_fn``, a delayed link model without an ``expiry`` (the bound of
``link_age``), and agents that leave the env before the others.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.observations import GLOBAL_STATE_KEY, LINK_AGE_KEY, POSITION_DIMS, POSITION_KEY, REFERENT_KEY
from sb3_latentswarm.links import ALL, FixedLinks, LinkModel, LinkStep, make_link_model
from sb3_latentswarm.utils.checks import check_int

__all__ = ["AdaptedVecEnv", "LinkSpec", "check_parallel_env", "make_adapted_vec_env"]

EnvFunction = Callable[[Any], Any]
"""A function of the env copy (a PettingZoo ``ParallelEnv``) returning an array."""


@dataclass(frozen=True)
class LinkSpec:
    """A link model of :mod:`sb3_latentswarm.links` by its ``SwarmConfig`` fields, built for any number of copies and
    agents: ``LinkSpec(link_model="outage", p_fail=0.3)`` (Bernoulli), ``LinkSpec(link_model="outage",
    outage_model="gilbert_elliott", p_fail=0.6, mean_outage_steps=40)``, ``LinkSpec(link_model="distance",
    link_range=0.5, p_fail=0.0)`` (``link_range`` in the units of ``position_fn``), ``LinkSpec(link_mode="none")`` (no
    messages) or ``LinkSpec(link_mode="full")``; any of them with delay: ``LinkSpec(link_model="outage", p_fail=0.3,
    message_delay=2, message_delay_model="geometric", message_expiry=6)`` (the observation then has ``link_age``).

    :param fields: ``SwarmConfig`` fields (``link_model``, ``link_mode``, ``p_fail``, ``outage_model``,
        ``mean_outage_steps``, ``link_range``, the channel parameters of Eq. (1) for ``"a2a"``)
    """

    fields: dict[str, Any] = field(default_factory=dict)

    def __init__(self, **fields: Any) -> None:
        if "n_agents" in fields:
            raise ValueError("LinkSpec takes the link fields only; the adapter sets n_agents from the env")
        fields.setdefault("link_mode", "channel")
        unknown = sorted(set(fields) - {f.name for f in dataclasses.fields(SwarmConfig)})
        if unknown:
            raise TypeError(f"LinkSpec got unknown field(s) {unknown}: it takes SwarmConfig's link fields (link_model, "
                            "link_mode, p_fail, outage_model, mean_outage_steps, link_range, message_delay, ...)")
        SwarmConfig(**fields)  # validated now, not at the first step
        object.__setattr__(self, "fields", dict(fields))

    def __call__(self, n_swarms: int, n_agents: int) -> LinkModel:
        return make_link_model(SwarmConfig(n_agents=n_agents, **self.fields), n_swarms)


def _box(space: Any, what: str, agent: str) -> spaces.Box:
    if isinstance(space, spaces.Box):
        return space
    hint = ""
    if what == "action" and isinstance(space, (spaces.Discrete, spaces.MultiDiscrete)):
        hint = (" LatentSwarmPolicy's actor is a Gaussian over a Box: use the env's continuous actions (MPE2: "
                "parallel_env(..., continuous_actions=True))")
    raise TypeError(f"The adapter needs Box {what} spaces; agent {agent!r} has {space}.{hint}")


def check_parallel_env(env: Any) -> tuple[list[str], spaces.Box, spaces.Box]:
    """Check that ``env`` is a ``ParallelEnv`` whose agents share one ``Box`` observation and one ``Box`` action space.

    :return: (``possible_agents``, the observation space, the action space)
    :raises TypeError: not a ParallelEnv, or a non-``Box`` space
    :raises ValueError: no agents, agents with different spaces, or an action space with an infinite bound
    """
    for name in ("possible_agents", "observation_space", "action_space", "reset", "step"):
        if not hasattr(env, name):
            raise TypeError(f"The adapter needs a PettingZoo ParallelEnv; {type(env).__name__} has no {name!r}")
    agents = list(env.possible_agents)
    if not agents:
        raise ValueError("The env has no possible_agents")
    observation_space = _box(env.observation_space(agents[0]), "observation", agents[0])
    action_space = _box(env.action_space(agents[0]), "action", agents[0])
    if not (np.all(np.isfinite(action_space.low)) and np.all(np.isfinite(action_space.high))):
        raise ValueError(
            f"The adapter needs an action Box with finite bounds (SB3's PPO does; the Gaussian actor's actions are "
            f"clipped to the box, the squashed actor's rescaled to it); agent {agents[0]!r} has {action_space}"
        )
    for agent in agents[1:]:
        for what, space, first in (("observation", env.observation_space(agent), observation_space),
                                   ("action", env.action_space(agent), action_space)):
            _box(space, what, agent)
            if space != first:
                raise ValueError(
                    f"The adapter needs homogeneous agents (one policy for all): agent {agent!r} has {what} space {space}, "
                    f"{agents[0]!r} has {first}"
                )
    return agents, observation_space, action_space


class AdaptedVecEnv(VecEnv):
    """``n_envs`` copies of a ``ParallelEnv`` as an SB3 VecEnv of ``n_envs * N`` slots (see the module docstring);
    build it with :func:`make_adapted_vec_env`.

    :ivar n_agents: N, agents per copy
    :ivar n_swarms: the number of copies
    :ivar link_model: the :class:`~sb3_latentswarm.links.LinkModel` of all copies
    """

    def __init__(
        self,
        env_fn: Callable[[], Any],
        n_envs: int,
        link_model: LinkModel | Callable[[int, int], LinkModel] | None = None,
        position_fn: EnvFunction | None = None,
        own_state_fn: EnvFunction | None = None,
        state_fn: EnvFunction | None = None,
        referent_fn: EnvFunction | None = None,
        metrics_fn: Callable[[Any], dict[str, float]] | None = None,
        seed: int | None = None,
    ) -> None:
        check_int("n_envs", n_envs, low=1)
        probe = env_fn()
        agents, agent_obs_space, action_space = check_parallel_env(probe)
        self.agents = agents
        self.n_agents = len(agents)
        self.n_swarms = int(n_envs)
        self.link_model = self._build_link_model(link_model, position_fn)
        self.position_fn, self.own_state_fn, self.referent_fn = position_fn, own_state_fn, referent_fn
        self.metrics_fn = metrics_fn
        self.state_fn = state_fn if state_fn is not None else _env_state
        self._shapes: dict[str, tuple[int, ...]] = {}
        self._probe(probe, action_space)
        self.envs = [env_fn() for _ in range(n_envs)]
        for env in self.envs:
            if list(env.possible_agents) != agents:
                raise ValueError(f"env_fn made copies with different agents: {list(env.possible_agents)} != {agents}")
        self.render_mode = getattr(self.envs[0], "render_mode", None)

        low, high = agent_obs_space.low.astype(np.float32), agent_obs_space.high.astype(np.float32)
        box: dict[str, spaces.Space] = {"local_obs": spaces.Box(low, high, dtype=np.float32),
                                        "proprio": _real_box(self._shapes["proprio"]),
                                        "link_row": spaces.Box(0.0, 1.0, (self.n_agents,), dtype=np.float32)}
        if self.link_model.has_delay:  # steps late, as the swarm env's (opt-in: only with a delayed link model)
            box[LINK_AGE_KEY] = spaces.Box(0.0, float(self.link_model.expiry), (self.n_agents,), dtype=np.float32)  # type: ignore[attr-defined]
        if position_fn is not None:
            box[POSITION_KEY] = _real_box((POSITION_DIMS,))
        box[GLOBAL_STATE_KEY] = _real_box(self._shapes[GLOBAL_STATE_KEY])
        if referent_fn is not None:
            box[REFERENT_KEY] = _real_box(self._shapes[REFERENT_KEY])
        action_box = spaces.Box(action_space.low.astype(np.float32), action_space.high.astype(np.float32), dtype=np.float32)
        super().__init__(self.n_swarms * self.n_agents, spaces.Dict(box), action_box)

        self._seed = seed if seed is not None else int(np.random.default_rng().integers(2**31))
        self._seed_pending = True
        self._rngs = self._link_rngs(self._seed)
        self._actions: np.ndarray | None = None
        self._returns = np.zeros((self.n_swarms, self.n_agents))
        self._lengths = np.zeros(self.n_swarms, dtype=np.int64)
        self._metric_sums: list[dict[str, float]] = [{} for _ in range(self.n_swarms)]
        self._last_obs: list[dict[str, np.ndarray]] = []

    # ------------------------------------------------------------------ checks
    def _build_link_model(self, link_model: Any, position_fn: EnvFunction | None) -> LinkModel:
        if link_model is None:
            model: LinkModel = FixedLinks(self.n_swarms, self.n_agents, up=True)
        elif isinstance(link_model, LinkModel):
            model = link_model
        elif callable(link_model):
            model = link_model(self.n_swarms, self.n_agents)
        else:
            raise TypeError(
                f"link_model must be a LinkModel, a LinkSpec or a function (n_swarms, n_agents), got {link_model!r}"
            )
        if (model.n_swarms, model.n_agents) != (self.n_swarms, self.n_agents):
            raise ValueError(
                f"The link model is built for {model.n_swarms} swarms of {model.n_agents} agents; the adapted env has "
                f"{self.n_swarms} copies of {self.n_agents} agents"
            )
        if model.needs_positions and position_fn is None:
            raise ValueError(
                f"{type(model).__name__} needs the agents' positions: pass position_fn(env) -> (N, 2 or 3) array, or "
                "choose a link model without geometry (LinkSpec(link_model='outage', ...))"
            )
        expiry = getattr(model, "expiry", None)
        if model.has_delay and (isinstance(expiry, bool) or not isinstance(expiry, (int, np.integer)) or expiry < 0):
            raise ValueError(f"{type(model).__name__} has delay but no int expiry >= 0 (the largest delay, the bound of "
                             f"the link_age observation), got expiry={expiry!r}")
        return model

    def _probe(self, env: Any, action_space: spaces.Box) -> None:
        """Reset and step a separate copy once: every user function must give the same shapes after reset and step."""
        env.reset(seed=0)
        self._check_agents(env, "reset")
        self._read(env, "reset")
        middle = ((np.nan_to_num(action_space.low) + np.nan_to_num(action_space.high)) / 2).astype(action_space.dtype)
        env.step({agent: middle for agent in self.agents})
        if list(env.agents) == self.agents:
            self._read(env, "the first step")
        env.close()

    def _check_agents(self, env: Any, when: str) -> None:
        if list(env.agents) != self.agents:
            raise ValueError(
                f"After {when} the env has agents {list(env.agents)}, not its possible_agents {self.agents}: the adapter "
                "needs every agent present until the episode ends for all of them"
            )

    def _read(self, env: Any, when: str) -> dict[str, np.ndarray]:
        """The user functions' arrays of one copy, shape-checked against the first read."""
        n = self.n_agents
        out = {}
        own = np.zeros((n, 0)) if self.own_state_fn is None else np.asarray(self.own_state_fn(env), dtype=np.float64)
        if own.ndim != 2 or own.shape[0] != n:
            raise ValueError(f"own_state_fn must return an (N, e) array with N = {n} agents, got shape {own.shape}")
        out["proprio"] = own
        if self.position_fn is not None:
            position = np.asarray(self.position_fn(env), dtype=np.float64)
            if position.shape not in ((n, 2), (n, 3)):
                raise ValueError(
                    f"position_fn must return the positions as an (N, 2) or (N, 3) array with N = {n} agents, got "
                    f"shape {position.shape} after {when}"
                )
            if not np.isfinite(position).all():
                raise ValueError(f"position_fn returned a non-finite position (NaN or inf) after {when}")
            if position.shape[1] == 2:
                position = np.concatenate([position, np.zeros((n, 1))], axis=1)
            out[POSITION_KEY] = position
        out[GLOBAL_STATE_KEY] = np.asarray(self.state_fn(env), dtype=np.float64).reshape(-1)
        if self.referent_fn is not None:
            out[REFERENT_KEY] = np.asarray(self.referent_fn(env), dtype=np.float64).reshape(-1)
        names = {"proprio": "own_state_fn", GLOBAL_STATE_KEY: "state_fn", REFERENT_KEY: "referent_fn"}
        for key in ("proprio", GLOBAL_STATE_KEY, REFERENT_KEY):
            if key not in out:
                continue
            shape = out[key].shape[1:] if key == "proprio" else out[key].shape
            first = self._shapes.setdefault(key, shape)
            if shape != first:
                raise ValueError(
                    f"{names[key]} changed shape from {first} to {shape} after {when}: the "
                    f"{'referent D_eta reconstructs' if key == REFERENT_KEY else 'vector'} must keep one shape"
                )
        return out

    # ------------------------------------------------------------------ VecEnv API
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next :meth:`reset`: copy ``c`` resets with ``seed + c``, its links draw from ``(seed, c)``."""
        if seed is not None:
            self._seed = int(seed)
        self._seed_pending = True
        self._rngs = self._link_rngs(self._seed)
        return [self._seed + c for c in range(self.n_swarms)]

    def _link_rngs(self, seed: int) -> list[np.random.Generator]:
        return [np.random.default_rng([seed, c]) for c in range(self.n_swarms)]

    def reset(self) -> VecEnvObs:
        seeds: list[int | None] = [None] * self.n_swarms
        if self._seed_pending:
            seeds = [self._seed + c for c in range(self.n_swarms)]
        self._seed_pending = False
        self._last_obs = [self._reset_copy(c, seeds[c]) for c in range(self.n_swarms)]
        self.link_model.reset(ALL)
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self._metric_sums = [{} for _ in range(self.n_swarms)]
        return self._observations(self._draw_links())

    def _reset_copy(self, c: int, seed: int | None) -> dict[str, np.ndarray]:
        env = self.envs[c]
        observations, _ = env.reset(seed=seed)
        self._check_agents(env, "reset")
        return self._copy_observation(env, observations, "reset")

    def _copy_observation(self, env: Any, observations: dict[str, Any], when: str) -> dict[str, np.ndarray]:
        obs = self._read(env, when)
        obs["local_obs"] = np.stack([np.asarray(observations[agent], dtype=np.float32) for agent in self.agents])
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs, -1)

    def step_wait(self) -> VecEnvStepReturn:
        assert self._actions is not None, "step_async first"
        n = self.n_agents
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        finished: list[tuple[int, dict[str, np.ndarray], bool, dict[str, float]]] = []
        for c, env in enumerate(self.envs):
            actions = {agent: self._actions[c * n + i] for i, agent in enumerate(self.agents)}
            observations, agent_rewards, terminations, truncations, _ = env.step(actions)
            reward = np.array([float(agent_rewards.get(agent, 0.0)) for agent in self.agents])
            rewards[c * n: (c + 1) * n] = reward
            self._returns[c] += reward
            self._lengths[c] += 1
            metrics = {} if self.metrics_fn is None else {name: float(v) for name, v in self.metrics_fn(env).items()}
            for name, value in metrics.items():
                self._metric_sums[c][name] = self._metric_sums[c].get(name, 0.0) + value
            ended = [bool(terminations.get(agent, False) or truncations.get(agent, False)) for agent in self.agents]
            if all(ended):
                # s_T for the truncation bootstrap: the user functions read the final state (env.agents may be empty)
                terminal = self._read(env, "the last step")
                terminal["local_obs"] = np.stack([np.asarray(observations.get(agent, self._last_obs[c]["local_obs"][i]),
                                                             dtype=np.float32) for i, agent in enumerate(self.agents)])
                truncated = not any(terminations.get(agent, False) for agent in self.agents)
                finished.append((c, terminal, truncated, self._summary(c, metrics)))  # before the reset
                self._last_obs[c] = self._reset_copy(c, None)
            elif any(ended) or list(env.agents) != self.agents:
                raise ValueError(
                    f"Agents {[a for a, e in zip(self.agents, ended) if e]} ended before the others (env.agents is "
                    f"{list(env.agents)}): the adapter needs every agent of a copy to end its episode at the same step"
                )
            else:
                self._last_obs[c] = self._copy_observation(env, observations, "a step")
        if finished:
            self.link_model.reset(np.array([c for c, _, _, _ in finished]))
        observation = self._observations(self._draw_links())
        for c, terminal, truncated, summary in finished:
            terminal["link_row"] = np.zeros((n, n), dtype=np.float32)  # no draw: the link streams stay the same
            terminal[LINK_AGE_KEY] = np.zeros((n, n), dtype=np.float32)
            for i in range(n):
                slot = c * n + i
                dones[slot] = True
                infos[slot] = {
                    "terminal_observation": {key: np.asarray(value[i], dtype=np.float32) for key, value in
                                             self._slot_arrays(terminal).items()},
                    "TimeLimit.truncated": truncated,
                    "episode_metrics": summary,
                }
            self._returns[c] = 0.0
            self._lengths[c] = 0
            self._metric_sums[c] = {}
        return observation, rewards, dones, infos

    def _summary(self, c: int, last_metrics: dict[str, float]) -> dict[str, float]:
        """The finished episode of copy ``c``: mean agent return, length, and ``metrics_fn``'s values at the last step
        (``last_metrics``) and summed over the episode."""
        summary = {"return": float(self._returns[c].mean()), "length": float(self._lengths[c])}
        summary.update({f"final_{name}": value for name, value in last_metrics.items()})
        summary.update({f"sum_{name}": value for name, value in self._metric_sums[c].items()})
        return summary

    def _draw_links(self) -> LinkStep:
        """This step's links: ``mask`` (n_swarms, N, N) bool, ``[c, i, j]`` = the message of j reaches i, and, with
        delay, ``age`` (n_swarms, N, N), how many steps late it is."""
        positions = None
        if self.link_model.needs_positions:
            positions = np.stack([obs[POSITION_KEY] for obs in self._last_obs])  # (n_swarms, N, 3)
        return self.link_model.step(ALL, self._rngs, positions)

    def _slot_arrays(self, copy_obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One copy's arrays per agent, (N, ...) each, in the observation space's key order."""
        n = self.n_agents
        out = {}
        for key in self.observation_space.spaces:  # type: ignore[attr-defined]
            value = copy_obs[key]
            out[key] = np.broadcast_to(value, (n, *value.shape)) if key in (GLOBAL_STATE_KEY, REFERENT_KEY) else value
        return out

    def _observations(self, links: LinkStep) -> dict[str, np.ndarray]:
        ages = np.zeros(links.mask.shape) if links.age is None else links.age
        per_copy = [self._slot_arrays({**obs, "link_row": links.mask[c], LINK_AGE_KEY: ages[c]})
                    for c, obs in enumerate(self._last_obs)]
        return {key: np.concatenate([obs[key] for obs in per_copy]).astype(np.float32, copy=False)
                for key in self.observation_space.spaces}  # type: ignore[attr-defined]

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [env.render() for env in self.envs]

    def _copies(self, indices: VecEnvIndices) -> list[Any]:
        return [self.envs[slot // self.n_agents] for slot in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        if attr_name in ("n_agents", "n_swarms", "link_model", "agents"):
            return [getattr(self, attr_name) for _ in self._get_indices(indices)]
        return [getattr(env, attr_name) for env in self._copies(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for env in self._copies(indices):
            setattr(env, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        return [getattr(env, method_name)(*method_args, **method_kwargs) for env in self._copies(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]


def _env_state(env: Any) -> np.ndarray:
    try:
        return env.state()
    except (AttributeError, NotImplementedError) as error:
        reason = f" ({error})" if str(error) else ""
        raise ValueError(
            f"{type(env).__name__}.state() is not available{reason}: pass state_fn(env) -> array, the global state the "
            "centralized critic reads"
        ) from None


def _real_box(shape: tuple[int, ...]) -> spaces.Box:
    return spaces.Box(-np.inf, np.inf, shape, dtype=np.float32)


def make_adapted_vec_env(
    env_fn: Callable[[], Any],
    n_envs: int = 1,
    link_model: LinkModel | Callable[[int, int], LinkModel] | None = None,
    position_fn: EnvFunction | None = None,
    own_state_fn: EnvFunction | None = None,
    state_fn: EnvFunction | None = None,
    referent_fn: EnvFunction | None = None,
    metrics_fn: Callable[[Any], dict[str, float]] | None = None,
    seed: int | None = None,
    monitor: bool = True,
) -> VecEnv:
    """The VecEnv ``LatentSwarmPPO`` trains on, for any PettingZoo ``ParallelEnv`` with homogeneous agents and ``Box``
    observation and action spaces (see the module docstring for the observation it builds and what it refuses).

    :param env_fn: makes one env copy (called ``n_envs + 1`` times: once for a probe step)
    :param n_envs: copies of the env; the VecEnv has ``n_envs * N`` slots
    :param link_model: which links deliver each step: a :class:`LinkSpec`, a function ``(n_swarms, n_agents) ->
        LinkModel``, or a :class:`~sb3_latentswarm.links.LinkModel` built for ``n_envs`` swarms of N agents; ``None``:
        every link up
    :param position_fn: ``env -> (N, 2 or 3)`` positions, in the units of the link model's range (distance and A2A
        models); also the p_t of the map update
    :param own_state_fn: ``env -> (N, e)``, the paper's e_t (default: none, e = 0)
    :param state_fn: ``env -> array``, the global state s_t of the centralized critic (default ``env.state()``)
    :param referent_fn: ``env -> array``, what the map decoder D_eta reconstructs (default: the global state)
    :param metrics_fn: ``env -> {name: value}`` after every step; each finished episode's ``episode_metrics`` info holds
        ``final_<name>`` (at the last step) and ``sum_<name>`` (over the episode), beside ``return`` and ``length``
    :param seed: copy ``c`` resets with ``seed + c`` (``None``: a random base seed)
    :param monitor: wrap in SB3's ``VecMonitor`` (``rollout/ep_rew_mean``)
    """
    env: VecEnv = AdaptedVecEnv(
        env_fn, n_envs, link_model, position_fn, own_state_fn, state_fn, referent_fn, metrics_fn, seed
    )
    return VecMonitor(env) if monitor else env
