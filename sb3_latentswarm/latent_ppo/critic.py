"""The centralized critic V_omega(s_t) of Sec. III-D, for both observation layouts
(:func:`~sb3_latentswarm.envs.observations.observation_layout`):

* swarm env: s_t = ({e_t^j}_j, M_hat_t): a map encoder plus a mean-pooled encoder of the agents' e_t (N-independent);
* adapted env: s_t = ``global_state``, one vector: the same map encoder on it, no per-agent part.

The modules are attributes of :class:`~sb3_latentswarm.latent_ppo.policies.LatentSwarmPolicy` (``critic_map``,
``critic_agents``, ``critic_head``: the names of its model files); this module builds them and evaluates them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch as th
from torch import nn

if TYPE_CHECKING:
    from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

__all__ = ["build_critic", "critic_output", "mlp"]


def mlp(sizes: list[int], activation: type[nn.Module] = nn.Tanh) -> nn.Sequential:
    """Linear layers of ``sizes`` with ``activation`` between them (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(activation())
    return nn.Sequential(*layers)


def build_critic(
    state_dim: int, proprio_dim: int | None, hidden: int
) -> tuple[nn.Sequential, nn.Sequential | None, nn.Sequential]:
    """``(critic_map, critic_agents, critic_head)``.

    :param state_dim: inputs of ``critic_map``: the map cells (swarm env) or the global state's size (adapted env)
    :param proprio_dim: e_dim for the per-agent encoder (swarm env), ``None`` for none (adapted env)
    :param hidden: the critic's width
    """
    critic_map = nn.Sequential(nn.Linear(state_dim, hidden), nn.ReLU())
    agents_hidden = 0 if proprio_dim is None else hidden // 4
    critic_agents = None if proprio_dim is None else nn.Sequential(nn.Linear(proprio_dim, agents_hidden), nn.ReLU())
    return critic_map, critic_agents, mlp([hidden + agents_hidden, hidden, 1], nn.ReLU)


def critic_output(policy: LatentSwarmPolicy, obs: dict[str, th.Tensor]) -> th.Tensor:
    """The critic's raw output for every slot, (..., B, 1); computed once per swarm and broadcast to its agents.

    :param obs: the critic's keys and ``link_row`` (for N), leading dims (..., B) with B = n_swarms * N, env-major
    """
    n_agents = obs["link_row"].shape[-1]
    if policy.critic_agents is None:
        state = obs["global_state"]  # (..., B, S)
        batch_shape = state.shape[:-1]
        flat_state = state.reshape(-1, n_agents, state.shape[-1])[:, 0].float()  # (n_swarms, S)
        with policy.latent_autocast():
            values = policy.critic_head(policy.critic_map(flat_state)).float()  # (n_swarms, 1)
        return values.repeat_interleave(n_agents, dim=0).reshape(*batch_shape, 1)
    swarm_proprio = obs["swarm_proprio"]  # (..., B, N, e_dim)
    batch_shape = swarm_proprio.shape[:-2]
    # each swarm's global state (repeated for its agents) is selected before the float conversion
    flat_proprio = swarm_proprio.reshape(-1, n_agents, n_agents, policy.proprio_dim)[:, 0].float()  # (n_swarms, N, e_dim)
    flat_map = obs["global_map"].reshape(-1, n_agents, policy.n_cells)[:, 0].float()  # (n_swarms, n_cells)
    with policy.latent_autocast():
        features = th.cat([policy.critic_map(flat_map), policy.critic_agents(flat_proprio).mean(dim=1)], dim=-1)
        values = policy.critic_head(features).float()  # (n_swarms, 1)
    return values.repeat_interleave(n_agents, dim=0).reshape(*batch_shape, 1)
