"""Train LatentSwarmPPO on an env this package did not design (docs/own_env.md, "Your own env").

Two envs go through the same adapter (``sb3_latentswarm.envs.make_adapted_vec_env``):

* ``custom``: :class:`Rendezvous`, a 40-line PettingZoo ``ParallelEnv`` written below;
* ``mpe``: MPE2's ``simple_spread_v3`` with continuous actions, each agent seeing only its nearest other agent and
  landmark (``pip install sb3-latentswarm[mpe]``).

Each run trains briefly, then prints the env's own metrics on held-out episodes (episode return; for simple_spread
the share of landmarks covered at the end and the colliding pairs summed over an episode):

    python examples/own_env.py --env custom --link outage --timesteps 3000
    python examples/own_env.py --env mpe --link distance --timesteps 3000
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv


# start-rendezvous (docs/own_env.md includes from here)
class Rendezvous(ParallelEnv):
    """N agents on a line meet: each sees only its own position; the shared reward is minus the spread."""

    metadata = {"name": "rendezvous_v0", "render_modes": [], "is_parallelizable": True}

    def __init__(self, n_agents: int = 3, max_steps: int = 20):
        self.possible_agents = [f"agent_{i}" for i in range(n_agents)]
        self.max_steps = max_steps
        self.render_mode = None
        self._obs_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self._act_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self.rng = np.random.default_rng()

    def observation_space(self, agent):
        return self._obs_space

    def action_space(self, agent):
        return self._act_space

    def reset(self, seed=None, options=None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.agents = list(self.possible_agents)
        self.x = self.rng.uniform(-1.0, 1.0, len(self.agents))
        self.t = 0
        return self._obs(), {a: {} for a in self.agents}

    def step(self, actions):
        moves = np.array([np.clip(actions[a][0], -1.0, 1.0) for a in self.agents])
        self.x = np.clip(self.x + 0.1 * moves, -1.0, 1.0)
        self.t += 1
        reward = -float(np.abs(self.x - self.x.mean()).mean())
        done = self.t >= self.max_steps
        observations, agents = self._obs(), self.agents
        if done:
            self.agents = []
        return (observations, {a: reward for a in agents}, {a: False for a in agents},
                {a: done for a in agents}, {a: {} for a in agents})

    def _obs(self):
        return {a: np.array([self.x[i]], dtype=np.float32) for i, a in enumerate(self.possible_agents)}

    def state(self):
        return self.x.astype(np.float32)


def rendezvous_positions(env: Rendezvous) -> np.ndarray:
    """(N, 2): x on the line, y = 0 (for distance links)."""
    return np.stack([env.x, np.zeros_like(env.x)], axis=1)
# end-rendezvous


def simple_spread(n_agents: int = 3, neighbors: int = 1, max_cycles: int = 25) -> Any:
    """MPE2 simple_spread with continuous actions, each agent seeing only its ``neighbors`` nearest agents and landmarks."""
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=n_agents, continuous_actions=True, max_cycles=max_cycles,
                                         num_agent_neighbors=neighbors, num_landmark_neighbors=neighbors)


LINKS: dict[str, dict[str, Any]] = {
    "full": dict(link_mode="full"),
    "none": dict(link_mode="none"),
    "outage": dict(link_model="outage", outage_model="gilbert_elliott", p_fail=0.5, mean_outage_steps=5),
    "distance": dict(link_model="distance", link_range=0.8, p_fail=0.0),
    "a2a": dict(link_model="a2a"),
}
"""The link models of the example, by name, as ``LinkSpec`` fields; ``link_range`` in the env's position units."""


@dataclasses.dataclass
class Args:
    env: str = "custom"
    """``custom`` (:class:`Rendezvous`) or ``mpe`` (MPE2 simple_spread, partial observability)."""
    link: str = "outage"
    """A key of :data:`LINKS`."""
    timesteps: int = 3000
    """Training agent-steps."""
    n_envs: int = 4
    """Env copies."""
    eval_episodes: int = 8
    """Held-out evaluation episodes (seeds 10_000 + k)."""
    seed: int = 0


def adapted_env(args: Args, n_envs: int, seed: int):
    """The adapted VecEnv of ``args.env`` with the link model ``args.link``."""
    from sb3_latentswarm.envs import LinkSpec, make_adapted_vec_env  # here, so that --help answers without torch
    from sb3_latentswarm.envs.mpe import mpe_positions, simple_spread_metrics

    link_model = LinkSpec(**LINKS[args.link])
    if args.env == "mpe":
        return make_adapted_vec_env(simple_spread, n_envs, link_model=link_model, position_fn=mpe_positions,
                                    metrics_fn=simple_spread_metrics, seed=seed)
    return make_adapted_vec_env(Rendezvous, n_envs, link_model=link_model, position_fn=rendezvous_positions, seed=seed)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    for field in dataclasses.fields(Args):
        parser.add_argument(f"--{field.name.replace('_', '-')}", type=type(field.default), default=field.default)
    args = Args(**vars(parser.parse_args(argv)))
    from sb3_latentswarm import LatentSwarmPPO
    from sb3_latentswarm.evaluation.adapted import evaluate_adapted

    env = adapted_env(args, args.n_envs, args.seed)
    n_agents = env.get_attr("n_agents", indices=0)[0]
    episode_steps = 25 if args.env == "mpe" else 20
    model = LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=episode_steps * 2, chunk_length=episode_steps,
                           batch_size=episode_steps * n_agents * args.n_envs, n_epochs=4, learning_rate=3e-4,
                           policy_kwargs=dict(latent_dim=32, predictor_hidden=32, decoder_hidden=32, critic_hidden=64,
                                              actor_hidden=32), seed=args.seed)
    model.learn(args.timesteps)
    results = evaluate_adapted(model, functools.partial(adapted_env, args), n_episodes=args.eval_episodes, seed=10_000)
    print(f"{args.env} / links {args.link}: " + ", ".join(f"{k} {v:.3f}" for k, v in results.items()))
    return results


if __name__ == "__main__":
    main()
