"""``LatentSwarmAgent``: one UAV of a trained swarm, stepped on its own (decentralized execution, Sec. III).

At execution each UAV acts from its own observation and the messages its radio received; the batched policy pools
messages over a swarm's link mask inside one forward pass, this agent takes the messages as a list. Both run the same
per-step function (:func:`~sb3_latentswarm.latent_ppo.recurrence.agent_update`), so N agents fed the messages routed by
the env's link mask act as the batched policy does (to float rounding: ``tests/test_agent.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from sb3_latentswarm.agent.inputs import AgentSpec, AgentStepInfo, check_step, pooled_message_age
from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy
from sb3_latentswarm.latent_ppo.recurrence import AgentInputs, outgoing_message
from sb3_latentswarm.latent_ppo.type_aliases import LatentState

__all__ = ["LatentSwarmAgent", "agent_spec", "policy_of"]


def policy_of(model: Any) -> LatentSwarmPolicy:
    """The :class:`LatentSwarmPolicy` of a ``LatentSwarmPPO`` (its ``policy``) or the policy itself.

    :raise TypeError: for anything else
    """
    policy = model if isinstance(model, LatentSwarmPolicy) else getattr(model, "policy", None)
    if not isinstance(policy, LatentSwarmPolicy):
        raise TypeError(f"expected a LatentSwarmPPO or a LatentSwarmPolicy, got {type(model).__name__}")
    return policy


def agent_spec(policy: LatentSwarmPolicy) -> AgentSpec:
    """The sizes of one UAV's step under ``policy`` (any observation layout: the swarm env's or an adapted env's)."""
    local_shape = policy.observation_space["local_obs"].shape
    assert local_shape is not None  # checked by the policy
    low, high = (np.broadcast_to(bound, policy.action_space.shape).astype(float) for bound in
                 (policy.action_space.low, policy.action_space.high))
    return AgentSpec(tuple(int(n) for n in local_shape), policy.proprio_dim, policy.message_dim, policy.action_dim,
                     tuple(low.tolist()), tuple(high.tolist()), policy.layout.position_key, policy.position_dims)


class LatentSwarmAgent:
    """One UAV's latent-swarm policy: its latent state (map mu, task tau, memory rho, and what the message substitutes
    need), the message it broadcasts, and its action from its own observation and the messages it received.

    Each step, in order: every UAV broadcasts :meth:`message` (z_{t-1} = [mu_{t-1}; tau_{t-1}], Sec. III-B); the radio
    delivers some of them; each UAV calls :meth:`step` with its observation and what arrived: mean pooling over the
    received messages (Sec. III-B), the memory update and the predictor when nothing arrived (Sec. III-A, III-C), the
    asymmetric map update and the task update (Sec. III-A), and the actor pi(a | tau_t) (Sec. III-D).

    The agent shares ``model``'s policy (its networks, ``autocast`` and ``message_substitute``, e.g. set by
    :func:`~sb3_latentswarm.evaluation.policy_switches`); it holds only its own state. Thread-unsafe, like the policy.

    :param model: a trained :class:`~sb3_latentswarm.LatentSwarmPPO` or its :class:`~sb3_latentswarm.LatentSwarmPolicy`
    :raise TypeError: for anything else

    Example (one swarm of the PettingZoo env; ``link_rows[i, j]`` = 1 iff j -> i delivered, from the env's info)::

        agents = {name: LatentSwarmAgent(model) for name in env.possible_agents}
        for agent in agents.values():
            agent.reset(seed=0)
        messages = np.stack([agent.message() for agent in agents.values()])  # (N, d)
        actions = {name: agent.step(obs[name], messages[link_rows[i] > 0]) for i, (name, agent) in enumerate(agents.items())}
    """

    def __init__(self, model: Any) -> None:
        self.policy = policy_of(model)
        self.spec = agent_spec(self.policy)
        self.delay_aware: bool = self.policy.delay_aware
        """Whether :meth:`step` reads ``message_ages`` (a policy built with ``delay_aware=True``)."""
        self.message_expiry: int = self.policy.message_expiry
        """E, the largest message age in steps the policy was built for (0 without delayed links)."""
        self._state: LatentState | None = None
        self._rng = np.random.default_rng()

    @property
    def message_dim(self) -> int:
        """d = d_mu + d_tau, the floats of one message."""
        return self.spec.message_dim

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: the latent state becomes zero (as the batched policy's at an episode start).

        :param seed: seeds the generator that sampled actions draw from when :meth:`step` gets neither ``noise`` nor
            ``rng`` (``None``: fresh entropy)
        """
        self._state = self.policy.initial_state(1)
        self._rng = np.random.default_rng(seed)

    def message(self) -> np.ndarray:
        """z = [mu; tau] (Sec. III-B): the message this UAV broadcasts now, built from its state after the last step
        (zero right after :meth:`reset`); float32, (d,), d = d_mu + d_tau.

        :raise RuntimeError: before the first :meth:`reset`
        """
        return outgoing_message(self._current_state()).squeeze(0).cpu().numpy()

    def step(self, observation: Any, received_messages: Any, deterministic: bool = False, noise: Any = None,
             rng: np.random.Generator | None = None, return_info: bool = False, message_ages: Any = None) -> Any:
        """One step of this UAV: pool what arrived, update the latent state, act.

        :param observation: this UAV's observation: a mapping with ``local_obs`` (the env's per-agent shape) and
            ``proprio`` (e_dim,); other keys are ignored (a PettingZoo observation fits as is)
        :param received_messages: the messages z_{t-1}^j of the peers whose links delivered this step, (k, d) with any
            k >= 0 (what the peers' :meth:`message` returned before this step)
        :param deterministic: the mean action; ``False`` (default, the paper's protocol): a sample
        :param noise: eps ~ N(0, I) of the sample, (action_dim,): action = mean + std * eps (then tanh for the squashed
            Gaussian), as the evaluation runner draws it
        :param rng: draw eps from this generator instead (else from the generator seeded by :meth:`reset`)
        :param return_info: also return an :class:`AgentStepInfo`
        :param message_ages: delay-aware policies only (``delay_aware=True``, an extension): how many steps late each
            received message is, (k,) in [0, E], in the order of ``received_messages`` (each message as its peer sent
            it, z_{t-1-a}); ``None``: all on time. The step reads their mean divided by E (``docs/concepts.md``,
            "Delayed messages")
        :return: the action, float32, (action_dim,), inside the action space (normalized commands in [-1, 1] on the
            swarm env; :meth:`LatentSwarmPolicy.env_actions <sb3_latentswarm.LatentSwarmPolicy.env_actions>`);
            with ``return_info``: ``(action, info)``
        :raise RuntimeError: before the first :meth:`reset`
        :raise TypeError: for an observation that is not a mapping or arrays that do not hold numbers
        :raise ValueError: for a missing observation key, a wrong shape (observation, a message not of d floats,
            noise), a non-finite message, noise given with ``deterministic=True``; the state is unchanged when an error
            is raised; message ages given to a policy that does not read them, or of the wrong shape or range
        """
        state = self._current_state()
        arrays = check_step(self.spec, observation, received_messages, deterministic, noise, rng, self._rng)
        policy = self.policy
        message_age = pooled_message_age(message_ages, arrays.message_count, policy.message_expiry, policy.delay_aware)
        device = policy.device
        with th.no_grad():
            proprio = th.as_tensor(arrays.proprio, device=device).unsqueeze(0)
            inputs = AgentInputs(
                keep=th.ones(1, 1, device=device),
                local_obs=th.as_tensor(arrays.local_obs, device=device).unsqueeze(0),
                proprio=proprio,
                position=policy.map_position(
                    {} if arrays.position is None else {"position": th.as_tensor(arrays.position, device=device)[None]},
                    proprio),
                received_message=th.as_tensor(arrays.message_mean, device=device).unsqueeze(0),
                has_message=th.tensor([arrays.message_count > 0], device=device),
                message_age=None if message_age is None else th.tensor([[message_age]], device=device),
            )
            out = policy.agent_step(inputs, state)
            noise_tensor = None if arrays.noise is None else th.as_tensor(arrays.noise, device=device).unsqueeze(0)
            actions = policy.env_actions(policy.actions_from_noise(out.state.task_state, noise_tensor))
        action = actions.squeeze(0).cpu().numpy().astype(np.float32)
        self._state = out.state
        if not return_info:
            return action
        info = AgentStepInfo(
            message=self.message(),
            received_message=arrays.message_mean,
            has_message=arrays.message_count > 0,
            predicted_message=out.predicted_message.squeeze(0).cpu().numpy(),
            best_message=out.state.prev_message.squeeze(0).cpu().numpy(),
        )
        return action, info

    def _current_state(self) -> LatentState:
        if self._state is None:
            raise RuntimeError("LatentSwarmAgent: call reset() before message() or step()")
        return self._state
