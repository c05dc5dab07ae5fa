"""SB3 vectorized environments of ``n_envs`` swarms, one slot per agent: two backends over the same simulator core.

``make_vec_env(n_envs, backend=...)`` returns a ``VecMonitor`` around one of

* ``"batched"`` (default): :class:`BatchedSwarmVecEnv`, an SB3 ``VecEnv`` directly over
  :class:`~sb3_latentswarm.envs.batched_core.SwarmBatch`, which steps all swarms with one set of array operations.
* ``"supersuit"``: :class:`SwarmVecEnv` around SuperSuit's PettingZoo -> SB3 conversion,
  ``concat_vec_envs_v1(pettingzoo_env_to_vec_env_v1(SwarmReconEnv(critic_keys=True)), n_envs, ...)``: the
  design's path through the PettingZoo env, one Python env per swarm; it alone runs the copies in several processes
  (``num_cpus > 1``) and gives access to the :class:`SwarmReconEnv` copies (``swarm_envs``).

Both give the same SB3 view: ``num_envs = n_envs * n_agents``; the same observation keys, dtypes and spaces; the same
seeding (swarm ``c`` uses ``seed + c``) and therefore the same episodes for the same seed and actions (each swarm draws
from its own RNG in the same order in both); ``terminal_observation``, ``TimeLimit.truncated`` and ``swarm_summary``
in the infos of the slots of a finished swarm; ``n_agents``, ``n_swarms``, ``config`` and ``seed()``.

Slot layout: **env-major, agent-minor**. Slot ``k`` is agent ``k % n_agents`` (in ``possible_agents`` order) of swarm
copy ``k // n_agents``: ``[uav_0 of copy 0, uav_1 of copy 0, ..., uav_0 of copy 1, ...]``; the slots of copy ``c`` are
``c * n_agents : (c + 1) * n_agents``. This also holds with ``num_cpus > 1`` (contiguous chunks of copies per process).

Traps of SuperSuit 3.11 + SB3 2.x handled here (the documentation lists them: ``docs/env.md``, "SuperSuit traps handled"):

* The copies are cloudpickled from one env, so they share one RNG state unless seeded one by one:
  :class:`SwarmVecEnv` seeds copy ``c`` with ``seed + c`` at the first reset (a random base seed if ``seed`` is
  ``None``), also with ``num_cpus > 1`` (SuperSuit's own multiprocess reset would give overlapping seeds).
* ``ConcatVecEnv`` has no ``seed()`` and SuperSuit's SB3 wrapper does not forward seeds, so ``RecurrentPPO(...,
  seed=0)`` fails on a bare SuperSuit env: :meth:`SwarmVecEnv.seed` stores the seed and the next ``reset()`` reseeds.
* SuperSuit drops the truncation flag: :class:`SwarmVecEnv` restores SB3's ``info["TimeLimit.truncated"]`` on done
  slots from the env's ``swarm_summary`` so SB3 bootstraps truncated episodes from ``terminal_observation``.
* ``VecMonitor`` provides ``ep_info_buffer`` (``rollout/ep_rew_mean``); it counts agent-steps (each slot is one
  timestep) and its per-slot episode return is the shared swarm return.
* An episode ends for all slots of a copy at once (the env never removes one agent); those slots' infos then carry
  ``swarm_summary`` and ``terminal_observation``, and the copy restarts.

Differences between the backends: SuperSuit returns ``dones`` as uint8, the batched backend as bool (SB3's
convention); per-swarm access is ``swarm_envs`` (SuperSuit, serial) or ``get_attr`` / ``env_method`` with the names
in :data:`~sb3_latentswarm.envs.batched_core.SWARM_ATTRIBUTES` and
:data:`~sb3_latentswarm.envs.batched_core.SWARM_METHODS` (both backends).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import supersuit as ss
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn
from supersuit.vector import ConcatVecEnv, ProcConcatVec
from supersuit.vector.multiproc_vec import decompress_info, numpy_deepcopy

from sb3_latentswarm.config import SwarmConfig, resolve_config
from sb3_latentswarm.envs.batched_core import (
    LINK_AGE_KEY,
    SWARM_ATTRIBUTES,
    SWARM_METHODS,
    SwarmBatch,
    agent_action_space,
    agent_observation_space,
    check_actions,
)
from sb3_latentswarm.envs.swarm_recon import SwarmReconEnv, render_frame
from sb3_latentswarm.utils.checks import check_int

__all__ = ["BACKENDS", "BatchedSwarmVecEnv", "SwarmVecEnv", "check_vec_normalize", "make_vec_env"]

NORMALIZABLE_OBS_KEYS: tuple[str, ...] = ()
"""Observation keys that ``VecNormalize`` may normalize: none (see :func:`check_vec_normalize`)."""


def check_vec_normalize(env: VecEnv) -> None:
    """Refuse a swarm VecEnv wrapped in ``VecNormalize(norm_obs=True)``, with the reason; reward normalization passes.

    SB3's ``VecNormalize`` normalizes every Dict key: the 0/1 ``link_row`` the policy pools messages over stops being a
    mask (a row [0, 1] becomes [-0.69, 1.40]), the int8 keys ``local_obs`` and ``global_map`` are truncated when the
    rollout buffer stores them in their space's dtype (the replay's log-probabilities then differ from the rollout's),
    and :func:`~sb3_latentswarm.evaluation.evaluate` builds its envs without the statistics. ``proprio`` and
    ``swarm_proprio`` are already scaled by the env (positions in [0, 1], velocities in units of their maximum).

    :raise ValueError: when some ``VecNormalize`` in the wrapper chain normalizes observations
    """
    from stable_baselines3.common.vec_env import VecNormalize

    current = env
    while isinstance(current, VecEnvWrapper):
        if isinstance(current, VecNormalize) and current.norm_obs:
            raise ValueError(
                "VecNormalize(norm_obs=True) is refused for a swarm VecEnv: it would normalize link_row (a 0/1 link mask "
                "the policy pools messages over) and the int8 keys local_obs and global_map (truncated in the rollout "
                "buffer), and evaluate() does not apply its statistics. No observation key may be normalized (proprio "
                "and swarm_proprio are already scaled by the env). Use VecNormalize(venv, norm_obs=False) to normalize "
                "rewards only, or LatentSwarmPPO(normalize_value=True) for MAPPO's value normalization"
            )
        current = current.venv


#: The vec env backends of :func:`make_vec_env`.
BACKENDS = ("batched", "supersuit")


def _check_seed(seed: Any, name: str = "seed") -> int | None:
    if seed is None:
        return None
    return check_int(f"{name} (None or an int)", seed, low=0)


class SerialOnlyError(RuntimeError):
    """Raised by per-copy access (``swarm_envs``, ``get_attr``, ``env_method``) when the copies live in other
    processes (``num_cpus > 1``)."""


class _SwarmSeeding:
    """The seeding rule of both backends: swarm ``c`` gets ``seed + c`` at the first reset and after :meth:`seed`;
    every other reset continues the swarms' RNGs."""

    n_agents: int
    num_envs: int

    def _init_seeding(self, seed: int | None) -> None:
        self._pending_seed = _check_seed(seed)
        self._seeded = False

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Store a base seed; the next ``reset()`` seeds copy ``c`` with ``seed + c`` (random base if ``None``).

        :return: the seed of the copy of every slot.
        """
        seed = _check_seed(seed)
        if seed is None:
            seed = self._random_seed()
        self._pending_seed = seed
        return [seed + k // self.n_agents for k in range(self.num_envs)]

    @staticmethod
    def _random_seed() -> int:
        return int(np.random.SeedSequence().generate_state(1)[0])

    def _take_seed(self) -> int | None:
        """The base seed of this reset (pending, or random at the first reset), or ``None`` to continue the RNGs."""
        seed = self._pending_seed
        if seed is None and not self._seeded:
            seed = self._random_seed()
        self._pending_seed = None
        self._seeded = True
        return seed


class SwarmVecEnv(_SwarmSeeding, VecEnvWrapper):
    """Seeds the swarm copies of a SuperSuit SB3 vec env and exposes the swarm layout.

    Slots are env-major, agent-minor: slot ``k`` is agent ``k % n_agents`` of copy ``k // n_agents``.

    :param venv: ``concat_vec_envs_v1(pettingzoo_env_to_vec_env_v1(env), n_envs, base_class="stable_baselines3")``.
    :param n_agents: N, the number of UAVs per swarm.
    :param config: the configuration of the copies.
    :param seed: base seed: copy ``c`` is seeded with ``seed + c`` at the first reset; ``None`` draws a random base.
    """

    def __init__(self, venv: VecEnv, n_agents: int, config: SwarmConfig, seed: int | None = None) -> None:
        inner = getattr(venv, "venv", None)
        if not isinstance(inner, (ConcatVecEnv, ProcConcatVec)):
            raise TypeError(
                "SwarmVecEnv wraps the output of supersuit.concat_vec_envs_v1(..., base_class='stable_baselines3'), "
                f"got {type(venv).__name__} around {type(inner).__name__}"
            )
        if venv.num_envs % n_agents != 0:
            raise ValueError(f"num_envs ({venv.num_envs}) must be a multiple of n_agents ({n_agents})")
        self.n_agents = n_agents
        self.n_swarms = venv.num_envs // n_agents
        self.config = config
        self._reset_done = False
        self._init_seeding(seed)
        super().__init__(venv)

    # ------------------------------------------------------------------ reset and step
    def reset(self) -> VecEnvObs:
        """Reset every copy; reseeds them first after :meth:`seed` and at the first reset."""
        seed = self._take_seed()
        observations = self.venv.reset() if seed is None else self._reset_seeded(seed)
        self._reset_done = True
        self.reset_infos = self.venv.reset_infos
        return observations

    def _reset_seeded(self, seed: int) -> VecEnvObs:
        inner = self.venv.venv  # type: ignore[attr-defined]  # SuperSuit's SB3VecEnvWrapper; SB3 types venv as VecEnv
        if isinstance(inner, ConcatVecEnv):
            # ConcatVecEnv seeds its i-th MarkovVectorEnv (= copy i) with seed + i.
            observations, infos = inner.reset(seed=seed)
        else:
            # ProcConcatVec.reset would send seed + p to process p, whose ConcatVecEnv adds its local copy index:
            # overlapping seeds. Send each process the seed of its first copy instead.
            for pipe, start in zip(inner.pipes, inner.idx_starts):
                pipe.send(("reset", (seed + start // self.n_agents, None)))
            infos = decompress_info(inner.num_envs, inner.idx_starts, inner._receive_info())
            observations = numpy_deepcopy(inner.observations_buffers)
        self.venv.reset_infos = infos
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        """Check the actions as the batched backend does (same messages), then pass them to the copies."""
        if not self._reset_done:
            raise RuntimeError("step() called before reset(): call reset() first")
        self.venv.step_async(check_actions(actions, (self.num_envs, 4), "one row per slot", self.n_agents))

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, dones, infos = self.venv.step_wait()
        if dones.any():
            for k in np.flatnonzero(dones):
                summary = infos[k].get("swarm_summary")
                if summary is not None:
                    infos[k]["TimeLimit.truncated"] = bool(summary["truncated"])
        return observations, rewards, dones, infos

    # ------------------------------------------------------------------ access to the copies
    @property
    def swarm_envs(self) -> list[SwarmReconEnv]:
        """The :class:`SwarmReconEnv` copies in copy order (serial vec envs only, ``num_cpus <= 1``).

        :raises SerialOnlyError: with ``num_cpus > 1`` (the copies live in other processes).
        """
        inner = self.venv.venv  # type: ignore[attr-defined]  # SuperSuit's SB3VecEnvWrapper; SB3 types venv as VecEnv
        if not isinstance(inner, ConcatVecEnv):
            # Not an AttributeError: inside a property it would fall through to VecEnvWrapper.__getattr__.
            raise SerialOnlyError("swarm_envs, get_attr and env_method need a serial vec env (num_cpus <= 1)")
        return [vec_env.par_env for vec_env in inner.vec_envs]

    def _slot_envs(self, indices: VecEnvIndices) -> list[SwarmReconEnv]:
        envs = self.swarm_envs
        return [envs[k // self.n_agents] for k in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Attribute of the swarm copy of each slot (serial only; ``render_mode`` always works)."""
        if attr_name == "render_mode":
            return [self.venv.render_mode for _ in self._get_indices(indices)]
        return [getattr(env, attr_name) for env in self._slot_envs(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute on the swarm copy of each slot (serial only)."""
        for env in self._slot_envs(indices):
            setattr(env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call a method of the swarm copy of each slot (serial only; a copy is called once per slot)."""
        return [getattr(env, method_name)(*method_args, **method_kwargs) for env in self._slot_envs(indices)]

    def has_attr(self, attr_name: str) -> bool:
        if attr_name == "render_mode":
            return True
        try:
            return hasattr(self.swarm_envs[0], attr_name)
        except SerialOnlyError:
            return False


class BatchedSwarmVecEnv(_SwarmSeeding, VecEnv):
    """An SB3 ``VecEnv`` of ``n_swarms`` swarms stepped together by one :class:`SwarmBatch` (the ``"batched"`` backend).

    Same slots, spaces, seeding, infos and episodes as the SuperSuit backend (see the module docstring); a finished
    swarm restarts inside :meth:`step_wait`, the others run on.

    :param config: the configuration of the swarms.
    :param n_swarms: number of swarms; ``num_envs = n_swarms * n_agents``.
    :param seed: base seed: swarm ``c`` is seeded with ``seed + c`` at the first reset; ``None`` draws a random base.
    :param render_mode: ``None`` or ``"rgb_array"``: ``render()`` returns SB3's tiling of every slot's picture.
    """

    def __init__(self, config: SwarmConfig, n_swarms: int, seed: int | None = None, render_mode: str | None = None) -> None:
        SwarmReconEnv.check_render_mode(render_mode)
        self.core = SwarmBatch(config, n_swarms)
        self.config = config
        self.n_agents = config.n_agents
        self.n_swarms = self.core.n_swarms
        self.render_mode = render_mode
        self._actions: np.ndarray | None = None
        self._init_seeding(seed)
        super().__init__(self.n_swarms * self.n_agents, agent_observation_space(config), agent_action_space())

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> VecEnvObs:
        """Reset every swarm; reseeds them first after :meth:`seed` and at the first reset."""
        seed = self._take_seed()
        self.core.reset(seeds=None if seed is None else [seed + c for c in range(self.n_swarms)])
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._observations()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        core, n = self.core, self.n_agents
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async(actions)")
        if core.rngs[0] is None:
            raise RuntimeError("step() called before reset(): call reset() first")
        actions = check_actions(self._actions, (self.num_envs, 4), "one row per slot", n)
        self._actions = None
        reward, terminated, truncated = core.step(actions.reshape(self.n_swarms, n, 4))
        observations = self._observations()
        done = terminated | truncated
        infos = [info for swarm_infos in core.step_infos(terminated, truncated) for info in swarm_infos]
        if done.any():
            finished = np.flatnonzero(done)
            for swarm in finished.tolist():
                for k in range(swarm * n, (swarm + 1) * n):
                    infos[k]["terminal_observation"] = {key: value[k] for key, value in observations.items()}
                    infos[k]["TimeLimit.truncated"] = bool(truncated[swarm])
            core.reset(finished)  # their RNGs continue
            observations = self._observations()
        return observations, np.repeat(reward.astype(np.float32), n), np.repeat(done, n), infos

    def close(self) -> None:
        """Nothing to release (the swarms live in this process)."""

    def get_images(self) -> list[np.ndarray]:
        """The picture of the swarm of every slot (:func:`~sb3_latentswarm.envs.swarm_recon.render_frame`), which SB3's
        ``render()`` tiles; the slots of one swarm share one image."""
        frames = [render_frame(self.core, swarm) for swarm in range(self.n_swarms)]
        return [frames[k // self.n_agents] for k in range(self.num_envs)]

    # ------------------------------------------------------------------ per-swarm access
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Per-swarm state (:data:`SWARM_ATTRIBUTES`, e.g. ``positions`` (N, 3)) of the swarm of each slot, or an
        attribute of this vec env (``config``, ``n_agents``, ``render_mode``, ...) once per slot."""
        slots = list(self._get_indices(indices))
        if attr_name in SWARM_ATTRIBUTES:
            values = getattr(self.core, attr_name)
            if values.ndim == 1:
                values = values.tolist()  # Python scalars, as the SwarmReconEnv properties give
            return [values[k // self.n_agents] for k in slots]
        if attr_name.startswith("_") or not hasattr(self, attr_name):
            raise AttributeError(
                f"{type(self).__name__} has no attribute {attr_name!r}; per-swarm attributes: {list(SWARM_ATTRIBUTES)}"
            )
        value = getattr(self, attr_name)
        return [value for _ in slots]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of this vec env (shared by every slot); the per-swarm state is read-only."""
        if attr_name in SWARM_ATTRIBUTES or attr_name in ("config", "n_agents", "n_swarms", "core"):
            raise AttributeError(f"{attr_name!r} cannot be set on {type(self).__name__}")
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call a per-swarm method (:data:`SWARM_METHODS`) for the swarm of each slot (once per slot, as SuperSuit)."""
        if method_name not in SWARM_METHODS:
            raise AttributeError(f"{type(self).__name__} supports env_method for {list(SWARM_METHODS)}, got {method_name!r}")
        method = getattr(self.core, method_name)
        return [method(k // self.n_agents, *method_args, **method_kwargs) for k in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def _observations(self) -> dict[str, np.ndarray]:
        """The slot-major observation dict (fresh writable arrays: torch warns about read-only ones)."""
        core, n, slots = self.core, self.n_agents, self.num_envs
        observations = {
            "local_obs": core.local_obs.reshape(slots, -1).copy(),
            "proprio": core.proprio.reshape(slots, -1).copy(),
            "link_row": core.link_rows.reshape(slots, n).copy(),
            "swarm_proprio": np.repeat(core.proprio, n, axis=0),  # (B * N, N, 8): every agent sees its swarm's
            "global_map": np.repeat(core.global_map, n, axis=0),
        }
        if core.link_ages is not None:
            observations[LINK_AGE_KEY] = core.link_ages.reshape(slots, n).copy()
        return observations


def make_vec_env(
    n_envs: int,
    config: SwarmConfig | None = None,
    seed: int | None = None,
    num_cpus: int = 0,
    backend: str = "batched",
    **overrides: Any,
) -> VecMonitor:
    """Build an SB3 ``VecEnv`` of ``n_envs`` swarms, one slot per agent (env-major, agent-minor).

    :param n_envs: number of swarm copies (paper: 40); ``num_envs`` of the result is ``n_envs * n_agents``.
    :param config: the configuration; ``SwarmConfig()`` if ``None``.
    :param seed: base seed: copy ``c`` uses ``seed + c`` (``None``: a random base, copies still differ).
    :param num_cpus: 0 or 1 runs the copies in this process; ``> 1`` runs them in that many processes
        (SuperSuit, shared memory; ``backend="supersuit"`` only).
    :param backend: ``"batched"`` (default: one array program for all swarms, the fast path) or ``"supersuit"``
        (the PettingZoo env through SuperSuit). Both give the same episodes for the same seed and actions.
    :param overrides: ``SwarmConfig`` fields replacing those of ``config``, and ``render_mode``.
    :return: ``VecMonitor(BatchedSwarmVecEnv(...))`` or ``VecMonitor(SwarmVecEnv(...))``; ``n_agents``,
        ``n_swarms`` and ``config`` are forwarded attributes.
    """
    check_int("n_envs", n_envs, low=1)
    check_int("num_cpus", num_cpus, low=0)
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    seed = _check_seed(seed)
    render_mode = overrides.pop("render_mode", None)
    config = resolve_config(config, **overrides)
    if backend == "batched":
        if num_cpus > 1:
            raise ValueError(
                f"num_cpus={num_cpus} needs backend='supersuit' (the batched backend steps every swarm in this process)"
            )
        return VecMonitor(BatchedSwarmVecEnv(config, int(n_envs), seed=seed, render_mode=render_mode))
    env = SwarmReconEnv(config, render_mode=render_mode, critic_keys=True)  # every slot also carries the critic's keys
    venv = ss.concat_vec_envs_v1(
        ss.pettingzoo_env_to_vec_env_v1(env), int(n_envs), num_cpus=int(num_cpus), base_class="stable_baselines3"
    )
    return VecMonitor(SwarmVecEnv(venv, n_agents=env.n_agents, config=env.config, seed=seed))
