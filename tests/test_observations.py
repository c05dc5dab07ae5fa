"""The observation contract (``common/observations.py``): one set of keys and one e_t layout for env, policy, planners."""

import numpy as np
import pytest

from sb3_latentswarm.config import SwarmConfig
from sb3_latentswarm.envs import observations
from sb3_latentswarm.envs.batched_core import SwarmBatch


def test_env_policy_and_planners_use_the_same_key_objects():
    from sb3_latentswarm.baselines import planners
    from sb3_latentswarm.envs import ACTOR_OBS_KEYS, OBS_KEYS, STATE_OBS_KEYS
    from sb3_latentswarm.latent_ppo import policies

    assert ACTOR_OBS_KEYS is observations.ACTOR_OBS_KEYS and STATE_OBS_KEYS is observations.STATE_OBS_KEYS
    assert OBS_KEYS is observations.OBS_KEYS and set(OBS_KEYS) == set(ACTOR_OBS_KEYS + STATE_OBS_KEYS)
    assert policies.REQUIRED_KEYS == ACTOR_OBS_KEYS + STATE_OBS_KEYS and planners.ACTOR_OBS_KEYS is ACTOR_OBS_KEYS


SHIFTED = SwarmConfig(grid_width=13, cell_size=2.5, min_altitude=8.0, initial_altitude=12.0)


@pytest.mark.parametrize("config", [SwarmConfig(), SHIFTED])
def test_proprio_decodes_to_the_core_state(config):
    core = SwarmBatch(config, n_swarms=3)
    core.reset(seeds=[0, 1, 2])
    rng = np.random.default_rng(0)
    for _ in range(5):
        core.step(rng.uniform(-1, 1, (3, config.n_agents, 4)))
    proprio = core.proprio.astype(np.float64)  # (B, N, 8) float32 observation
    np.testing.assert_allclose(observations.proprio_position(proprio, config), core.positions, rtol=1e-6, atol=1e-5)
    heading = core.kinematics[..., observations.PROPRIO_HEADING]
    np.testing.assert_allclose(observations.proprio_heading(proprio), heading, rtol=1e-6, atol=1e-6)
    offset, scale = observations.proprio_normalization(config)
    energy = proprio[..., observations.PROPRIO_ENERGY] / scale[observations.PROPRIO_ENERGY]
    np.testing.assert_allclose(energy, core.kinematics[..., observations.PROPRIO_ENERGY], rtol=1e-6)
    assert offset.shape == scale.shape == (observations.PROPRIO_DIM,)


def test_a_zero_range_reads_zero_in_e_t():
    config = SwarmConfig(min_altitude=20.0, max_altitude=20.0, initial_altitude=20.0, vz_max=0.0)
    _, scale = observations.proprio_normalization(config)
    assert scale[2] == 0.0 and scale[5] == 0.0 and np.all(scale[[0, 1, 3, 4, 6, 7]] > 0)
