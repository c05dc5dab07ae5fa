"""A short, seeded learning check: LatentSwarmPPO beats a random policy on a small map (about a minute on 2 cores)."""

import numpy as np
import pytest
import torch as th

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import SwarmReconEnv, make_vec_env

CONFIG = SwarmConfig(n_agents=2, grid_width=12, grid_height=12, max_steps=40, num_obstacles=5, v_max=1.0)


def mean_final_coverage(act, episodes=20, seed=1000):
    coverages = []
    for episode in range(episodes):
        env = SwarmReconEnv(CONFIG)
        observations, _ = env.reset(seed=seed + episode)
        state, infos = None, {}
        while env.agents:
            actions, state = act(env, observations, state)
            observations, _, _, _, infos = env.step(actions)
        coverages.append(infos["uav_0"]["swarm_summary"]["coverage"])
    return float(np.mean(coverages))


@pytest.mark.slow
def test_trained_swarm_covers_more_than_random():
    th.set_num_threads(1)
    rng = np.random.default_rng(0)
    random_coverage = mean_final_coverage(
        lambda env, obs, state: ({agent: rng.uniform(-1, 1, 4).astype(np.float32) for agent in env.agents}, None)
    )
    model = LatentSwarmPPO(
        "LatentSwarmPolicy",
        make_vec_env(8, config=CONFIG, seed=0),
        learning_rate=3e-4,
        n_steps=40,
        chunk_length=10,
        batch_size=160,
        policy_kwargs=dict(latent_dim=32, predictor_hidden=64, decoder_hidden=64, critic_hidden=64, actor_hidden=64),
        seed=0,
    )
    model.learn(total_timesteps=90_000)
    trained_coverage = mean_final_coverage(lambda env, obs, state: model.predict(obs, state=state, deterministic=True))
    # measured when written: random 0.67, trained 0.99
    assert trained_coverage > random_coverage + 0.15, (trained_coverage, random_coverage)
