"""NamedTuples of the latent-swarm algorithm (the counterpart of sb3-contrib's ``RNNStates``)."""

from __future__ import annotations

from typing import NamedTuple

import torch as th


class LatentState(NamedTuple):
    """Recurrent state each UAV carries from step t-1 into step t (Sec. III-A).

    Every field has a leading dimension of vec-env slots (env-major, agent-minor). ``prev_local_obs`` and
    ``prev_message`` are what the memory update G needs from the previous step; they are part of the state, not of the
    observation.
    """

    map_state: th.Tensor
    """mu_{t-1}, (n_slots, d_mu)."""
    task_state: th.Tensor
    """tau_{t-1}, (n_slots, d_tau)."""
    memory_state: th.Tensor
    """rho_{t-1}, (n_slots, d_rho)."""
    prev_local_obs: th.Tensor
    """o_{t-1}, (n_slots, local_obs_dim)."""
    prev_message: th.Tensor
    """mbar_{t-1}, the best available aggregated message of the previous step, (n_slots, d_mu + d_tau)."""
    held_message: th.Tensor
    """The last message m actually received in this episode (zero before the first), (n_slots, d_mu + d_tau).

    Only read when ``message_substitute="hold_last"`` (an extension beyond the paper); always carried, so a condition
    can switch to it at test time."""
    sent_history: th.Tensor
    """Delayed links only (the ``link_age`` key, an extension): the messages this agent sent before z_{t-1},
    [z_{t-2}; ...; z_{t-1-E}], so that a message arriving a steps late is pooled as it was sent, (n_slots, E * (d_mu +
    d_tau)); zero columns without delay."""
    prev_message_age: th.Tensor
    """Delay-aware policies only: the age of mbar_{t-1} (the mean delay of the messages pooled into it, divided by the
    expiry E; 0 for a substitute), what the memory update reads beside mbar_{t-1}, (n_slots, 1); zero columns
    otherwise."""


class SwarmRolloutBufferSamples(NamedTuple):
    """One minibatch of whole swarms over a contiguous time chunk.

    Time-major: ``(chunk_length, n_sequences * n_agents, ...)`` where each sequence is one swarm (all its agents,
    env-major agent-minor inside the swarm) over one chunk of the rollout.
    """

    observations: dict[str, th.Tensor]
    actions: th.Tensor
    old_values: th.Tensor
    old_log_prob: th.Tensor
    advantages: th.Tensor
    returns: th.Tensor
    episode_starts: th.Tensor
    latent_state: LatentState
    """The stored state at the first step of each chunk, ``(n_sequences * n_agents, ...)``."""
