"""SB3 vectorized environment of ``n_envs`` swarms: SuperSuit's PettingZoo -> SB3 conversion with its traps handled.

``make_vec_env(n_envs)`` returns ``VecMonitor(SwarmVecEnv(concat_vec_envs_v1(pettingzoo_env_to_vec_env_v1(env),
n_envs, base_class="stable_baselines3")))``. Every agent of every swarm is one SB3 slot, so
``num_envs = n_envs * n_agents``.

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

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs.swarm_recon import SwarmReconEnv

__all__ = ["SwarmVecEnv", "make_vec_env"]


def _check_seed(seed: Any, name: str = "seed") -> int | None:
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"{name} must be None or an int >= 0, got {seed!r}")
    return int(seed)


class SerialOnlyError(RuntimeError):
    """Raised by per-copy access (``swarm_envs``, ``get_attr``, ``env_method``) when the copies live in other
    processes (``num_cpus > 1``)."""


class SwarmVecEnv(VecEnvWrapper):
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
        self._pending_seed = _check_seed(seed)
        self._seeded = False
        super().__init__(venv)

    # ------------------------------------------------------------------ seeding and reset
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

    def reset(self) -> VecEnvObs:
        """Reset every copy; reseeds them first after :meth:`seed` and at the first reset."""
        seed = self._pending_seed
        if seed is None and not self._seeded:
            seed = self._random_seed()
        if seed is None:
            observations = self.venv.reset()
        else:
            observations = self._reset_seeded(seed)
            self._pending_seed = None
            self._seeded = True
        self.reset_infos = self.venv.reset_infos
        return observations

    def _reset_seeded(self, seed: int) -> VecEnvObs:
        inner = self.venv.venv
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
        inner = self.venv.venv
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


def make_vec_env(
    n_envs: int, config: SwarmConfig | None = None, seed: int | None = None, num_cpus: int = 0, **overrides: Any
) -> VecMonitor:
    """Build an SB3 ``VecEnv`` of ``n_envs`` swarms, one slot per agent (env-major, agent-minor).

    :param n_envs: number of swarm copies (paper: 40); ``num_envs`` of the result is ``n_envs * n_agents``.
    :param config: the configuration; ``SwarmConfig()`` if ``None``.
    :param seed: base seed: copy ``c`` uses ``seed + c`` (``None``: a random base, copies still differ).
    :param num_cpus: 0 or 1 runs the copies in this process; ``> 1`` runs them in that many processes
        (SuperSuit, shared memory).
    :param overrides: ``SwarmConfig`` fields replacing those of ``config``, and ``render_mode``.
    :return: ``VecMonitor(SwarmVecEnv(...))``; ``n_agents``, ``n_swarms`` and ``config`` are forwarded attributes.
    """
    if isinstance(n_envs, bool) or not isinstance(n_envs, (int, np.integer)) or n_envs < 1:
        raise ValueError(f"n_envs must be an int >= 1, got {n_envs!r}")
    if isinstance(num_cpus, bool) or not isinstance(num_cpus, (int, np.integer)) or num_cpus < 0:
        raise ValueError(f"num_cpus must be an int >= 0, got {num_cpus!r}")
    seed = _check_seed(seed)
    env = SwarmReconEnv(config, **overrides)
    venv = ss.concat_vec_envs_v1(
        ss.pettingzoo_env_to_vec_env_v1(env), int(n_envs), num_cpus=int(num_cpus), base_class="stable_baselines3"
    )
    return VecMonitor(SwarmVecEnv(venv, n_agents=env.n_agents, config=env.config, seed=seed))
