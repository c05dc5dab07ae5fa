"""Actors of the evaluation runner: a latent-swarm policy (with its diagnostics) or any SB3-style recurrent model.

Execution is decentralized: every UAV acts from its own ``local_obs``, ``proprio`` and the messages that reached it
(``link_row``); the referent D_eta reconstructs (the swarm env's ``global_map``, an adapted env's global state or
``referent``) is read only for the ``map_error`` diagnostic.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch as th

from sb3_latentswarm.envs.batched_core import ACTOR_OBS_KEYS, LINK_AGE_KEY
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

__all__ = ["LatentActor", "PredictActor"]


class LatentActor:
    """Runs a :class:`LatentSwarmPolicy` on all slots of all swarms with one ``latent_step`` per env step.

    :param policy: the policy (its ablation switches already set, see
        :func:`~sb3_latentswarm.evaluation.policy_switches`)
    :param n_slots: agent slots stepped together (swarms x agents, env-major)
    :param n_agents: N, agents per swarm
    """

    def __init__(self, policy: LatentSwarmPolicy, n_slots: int, n_agents: int) -> None:
        self.policy = policy
        self.n_agents = n_agents
        self.state = policy.initial_state(n_slots)

    def act(
        self, obs: dict[str, np.ndarray], episode_starts: np.ndarray, noise: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actions of every slot, and its map error and substitute error (NaN where it had a message).

        :param obs: the policy's actor keys (``local_obs``, ``proprio``, ``link_row``, ...) of shape (n_slots, ...) and
            its referent (``policy.layout.referent_key``: ``global_map`` (n_swarms, H, W) on the swarm env) per swarm,
            (n_swarms, ...)
        :param episode_starts: (n_slots,) 1.0 at the first step of an episode
        :param noise: (n_slots, action_dim) standard normal draws for sampled actions, or ``None`` for mean actions
        :return: actions (n_slots, 4) clipped to [-1, 1], map error (n_slots,), substitute error (n_slots,), float64
        """
        policy, n = self.policy, self.n_agents
        device = policy.device
        with th.no_grad():
            tensors = {key: th.as_tensor(obs[key], device=device) for key in policy.layout.actor_keys}
            starts = th.as_tensor(episode_starts, dtype=th.float32, device=device)
            step = policy.latent_step(tensors, self.state, starts)
            self.state = step.state
            # the mean action, or a sample with eps from the episode's own generator
            actions = policy.actions_from_noise(step.state.task_state, noise)

            # map_error: per-cell squared error of D(mu_t^i) against M_hat_t (the target of Eq. (3))
            decoded = policy.decode_map(step.state.map_state).view(-1, n, policy.n_cells)  # (n_swarms, N, H*W)
            referent = obs[policy.layout.referent_key]
            target = th.as_tensor(referent, device=device).float().flatten(1).unsqueeze(1)  # (n_swarms, 1, H*W)
            map_error = ((decoded - target) ** 2).mean(-1).view(-1)

            # substitute error: mbar_t (the message used in place of the received one at a dropout step) against the
            # message a full link set would have delivered, the mean of z_{t-1}^j over all peers j != i
            if n > 1:
                sent = step.sent_message.view(-1, n, step.sent_message.shape[-1])
                full_message = ((sent.sum(1, keepdim=True) - sent) / (n - 1)).view_as(step.sent_message)
                pred_error = ((step.state.prev_message - full_message) ** 2).mean(-1)
                pred_error = th.where(step.has_message, th.full_like(pred_error, math.nan), pred_error)
            else:
                pred_error = th.full_like(map_error, math.nan)
        return (
            policy.env_actions(actions).cpu().numpy(),
            map_error.cpu().numpy().astype(np.float64),
            pred_error.cpu().numpy().astype(np.float64),
        )


class PredictActor:
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
        """Actions of every slot (clipped to [-1, 1], float64) and no diagnostics."""
        actor_obs = {key: obs[key] for key in (*ACTOR_OBS_KEYS, LINK_AGE_KEY) if key in obs}
        actions, self.state = self.model.predict(
            actor_obs, state=self.state, episode_start=episode_starts, deterministic=self.deterministic
        )
        return np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0), None, None
