"""``SwarmRolloutBuffer``: a rollout buffer whose minibatches are whole swarms over contiguous time chunks.

sb3-contrib's ``RecurrentDictRolloutBuffer`` cuts sequences per vec-env slot and shuffles them, which splits a swarm
apart. Our agents read each other's previous latent state at every step (message aggregation), so a minibatch must
hold all agents of a swarm, time-aligned. Like MAPPO's data chunks, the rollout of ``n_steps`` is cut into chunks of
``chunk_length`` steps; the latent state is stored at the first step of each chunk, and a minibatch is a random set of
(chunk, swarm) pairs replayed from that stored state.

Slots are env-major, agent-minor, so ``(n_steps, n_slots)`` arrays reshape to
``(n_chunks, chunk_length, n_swarms, n_agents)`` with no copy and no Python loop.

Observation keys that every agent of a swarm receives identically (``swarm_keys``: the global state
``swarm_proprio`` and ``global_map`` for ``LatentSwarmPPO``) are stored once per swarm, ``(n_steps, n_swarms, ...)``,
instead of once per slot; the minibatches hand them out per agent-step as before, so the losses do not change.
"""

from __future__ import annotations

from collections.abc import Callable, Generator

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictRolloutBuffer

from sb3_latentswarm.latent_ppo.type_aliases import LatentState, SwarmRolloutBufferSamples


class SwarmRolloutBuffer(DictRolloutBuffer):
    """Dict rollout buffer for swarms, with latent states stored at chunk starts.

    :param buffer_size: number of steps per slot (``n_steps``)
    :param observation_space: the Dict observation space of one slot
    :param action_space: the action space of one slot
    :param latent_dims: size of each :class:`LatentState` field, in field order
    :param n_agents: agents per swarm (slots of one env copy)
    :param chunk_length: steps per training sequence; must divide ``buffer_size``
    :param device: torch device of the minibatches
    :param gae_lambda: GAE lambda
    :param gamma: discount factor
    :param n_envs: number of vec-env slots (``n_swarms * n_agents``)
    :param swarm_keys: observation keys equal for all agents of a swarm, stored once per swarm (the first agent's)
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        latent_dims: tuple[int, ...],
        n_agents: int,
        chunk_length: int,
        device: th.device | str = "auto",
        gae_lambda: float = 1.0,
        gamma: float = 0.99,
        n_envs: int = 1,
        swarm_keys: tuple[str, ...] = (),
    ):
        if n_envs % n_agents != 0:
            raise ValueError(f"n_envs ({n_envs} slots) must be a multiple of n_agents ({n_agents})")
        if chunk_length < 1 or buffer_size % chunk_length != 0:
            raise ValueError(f"chunk_length must divide n_steps: n_steps={buffer_size}, chunk_length={chunk_length}")
        self.latent_dims = tuple(latent_dims)
        self.n_agents = n_agents
        self.n_swarms = n_envs // n_agents
        self.chunk_length = chunk_length
        self.n_chunks = buffer_size // chunk_length
        unknown = sorted(set(swarm_keys) - set(observation_space.spaces))
        if unknown:
            raise ValueError(f"swarm_keys {unknown} are not keys of the observation space {list(observation_space.spaces)}")
        self.swarm_keys = tuple(swarm_keys)
        super().__init__(buffer_size, observation_space, action_space, device, gae_lambda, gamma, n_envs)

    def reset(self) -> None:
        super().reset()
        for key in self.swarm_keys:  # (n_steps, n_swarms, ...): one copy per swarm
            per_slot = self.observations[key]
            self.observations[key] = np.zeros((self.buffer_size, self.n_swarms, *per_slot.shape[2:]), dtype=per_slot.dtype)
        # (n_chunks, n_slots, dim) per LatentState field
        self.latent_states = [np.zeros((self.n_chunks, self.n_envs, dim), dtype=np.float32) for dim in self.latent_dims]
        self._torch_cache: dict[str, th.Tensor] | None = None

    def add(  # type: ignore[override]
        self,
        obs: dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        episode_start: np.ndarray,
        value: th.Tensor,
        log_prob: th.Tensor,
        latent_state: LatentState,
    ) -> None:
        """Store one step; ``latent_state`` is the state carried *into* this step (before episode-start resets)."""
        if self.pos % self.chunk_length == 0:
            chunk = self.pos // self.chunk_length
            for stored, field in zip(self.latent_states, latent_state):
                stored[chunk] = field.detach().cpu().numpy()
        if self.swarm_keys:
            obs = dict(obs)
            for key in self.swarm_keys:
                obs[key] = obs[key][:: self.n_agents]  # the first agent's copy of each swarm's
        super().add(obs, action, reward, episode_start, value, log_prob)

    @property
    def nbytes(self) -> int:
        """Bytes of the stored rollout (observations, actions, rewards, values, ..., latent states)."""
        arrays = [*self.observations.values(), *self.latent_states]
        arrays += [getattr(self, name) for name in ("actions", "rewards", "returns", "episode_starts", "values")]
        arrays += [self.log_probs, self.advantages]
        return sum(array.nbytes for array in arrays)

    def _as_chunked_tensors(self) -> dict[str, th.Tensor]:
        """Move the whole rollout to the device once, shaped (n_chunks, chunk_length, n_swarms, n_agents, ...)."""
        shape = (self.n_chunks, self.chunk_length, self.n_swarms, self.n_agents)

        def chunked(array: np.ndarray, n_agents: int = self.n_agents) -> th.Tensor:
            return th.as_tensor(array, device=self.device).reshape(*shape[:3], n_agents, *array.shape[2:])

        # swarm keys get an agent axis of size 1, expanded to n_agents in the minibatches
        cache = {}
        for key, obs in self.observations.items():
            cache[f"obs/{key}"] = chunked(obs, 1 if key in self.swarm_keys else self.n_agents)
        cache["actions"] = chunked(self.actions.astype(np.float32, copy=False))
        for name in ("values", "log_probs", "advantages", "returns", "episode_starts"):
            cache[name] = chunked(getattr(self, name))
        for index, stored in enumerate(self.latent_states):
            # (n_chunks, n_swarms, n_agents, dim)
            cache[f"latent/{index}"] = th.as_tensor(stored, device=self.device).reshape(
                self.n_chunks, self.n_swarms, self.n_agents, -1
            )
        return cache

    def get(self, batch_size: int | None = None) -> Generator[SwarmRolloutBufferSamples, None, None]:  # type: ignore[override]
        """Yield minibatches of whole swarms over time chunks, in random order.

        :param batch_size: agent-steps per minibatch; rounded down to whole (swarm, chunk) sequences of
            ``n_agents * chunk_length`` agent-steps. ``None`` gives the whole rollout in one minibatch.
        """
        assert self.full, "The rollout buffer is not full"
        order = th.as_tensor(np.random.permutation(self.n_chunks * self.n_swarms), device=self.device)
        for _, samples in self._minibatches(batch_size, order):
            yield samples

    def replace_log_probs(
        self, batch_size: int | None, log_prob: Callable[[SwarmRolloutBufferSamples], th.Tensor]
    ) -> None:
        """Replace the log-probabilities that :meth:`get` hands out as ``old_log_prob`` by ``log_prob(minibatch)``,
        evaluated on minibatches of the same size as :meth:`get`'s (the numpy ``log_probs`` keep the rollout's).

        :param batch_size: as in :meth:`get`
        :param log_prob: the new log-probabilities of a minibatch, time-major (chunk_length, n_seq * n_agents)
        """
        if self._torch_cache is None:
            self._torch_cache = self._as_chunked_tensors()
        cache = self._torch_cache
        # a copy: on the CPU the cached tensor shares its memory with the numpy array
        replaced = cache["log_probs"].clone()
        for sequence_inds, samples in self._minibatches(batch_size, th.arange(self.n_chunks * self.n_swarms)):
            chunk_idx, swarm_idx = th.div(sequence_inds, self.n_swarms, rounding_mode="floor"), sequence_inds % self.n_swarms
            # (L, n_seq * n_agents) -> (n_seq, L, n_agents), the layout of cache[chunk_idx, :, swarm_idx]
            new = log_prob(samples).reshape(self.chunk_length, len(sequence_inds), self.n_agents).transpose(0, 1)
            replaced[chunk_idx, :, swarm_idx] = new.to(replaced.dtype)
        cache["log_probs"] = replaced

    def _minibatches(
        self, batch_size: int | None, order: th.Tensor
    ) -> Generator[tuple[th.Tensor, SwarmRolloutBufferSamples], None, None]:
        """(sequence indices, samples) of consecutive minibatches of ``order`` (sequence indices, chunk-major)."""
        if self._torch_cache is None:
            self._torch_cache = self._as_chunked_tensors()
        n_sequences = self.n_chunks * self.n_swarms
        per_sequence = self.n_agents * self.chunk_length
        sequences_per_batch = n_sequences if batch_size is None else max(1, batch_size // per_sequence)
        for start in range(0, n_sequences, sequences_per_batch):
            inds = order[start : start + sequences_per_batch].to(self.device)
            yield inds, self._get_samples(inds)

    def _get_samples(self, sequence_inds: th.Tensor, env=None) -> SwarmRolloutBufferSamples:  # type: ignore[override]
        cache = self._torch_cache
        assert cache is not None
        chunk_idx = th.div(sequence_inds, self.n_swarms, rounding_mode="floor")
        swarm_idx = sequence_inds % self.n_swarms
        n_seq = len(sequence_inds)

        def time_major(tensor: th.Tensor) -> th.Tensor:
            # (n_chunks, L, n_swarms, n_agents or 1, *rest) -> (n_seq, L, n_agents, *rest) -> (L, n_seq * n_agents, *rest)
            picked = tensor[chunk_idx, :, swarm_idx]
            picked = picked.transpose(0, 1).expand(-1, -1, self.n_agents, *tensor.shape[4:])
            return picked.reshape(self.chunk_length, n_seq * self.n_agents, *tensor.shape[4:])

        observations = {key[4:]: time_major(value) for key, value in cache.items() if key.startswith("obs/")}
        n_fields = len(self.latent_dims)
        latent = LatentState(
            *(cache[f"latent/{i}"][chunk_idx, swarm_idx].reshape(n_seq * self.n_agents, -1) for i in range(n_fields))
        )
        return SwarmRolloutBufferSamples(
            observations=observations,
            actions=time_major(cache["actions"]),
            old_values=time_major(cache["values"]),
            old_log_prob=time_major(cache["log_probs"]),
            advantages=time_major(cache["advantages"]),
            returns=time_major(cache["returns"]),
            episode_starts=time_major(cache["episode_starts"]),
            latent_state=latent,
        )
