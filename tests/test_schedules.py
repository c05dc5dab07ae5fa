"""The paper's learning-rate schedule: 1e-4 for the first 1000 of 1600 updates, 1e-5 after."""

import pytest

from sb3_latentswarm.latent_ppo.schedules import StepSchedule, paper_learning_rate


def test_paper_schedule_switches_after_update_1000_of_1600():
    schedule = paper_learning_rate()
    # SB3 evaluates the schedule after update k with progress_remaining = 1 - k / total
    rates = [schedule(1.0 - k / 1600) for k in range(1, 1601)]
    assert rates[:1000] == [1e-4] * 1000
    assert rates[1000:] == [1e-5] * 600


def test_step_schedule_and_validation():
    schedule = StepSchedule(3.0, 1.0, switch_fraction=0.5)
    assert schedule(1.0) == 3.0 and schedule(0.5) == 3.0 and schedule(0.49) == 1.0
    with pytest.raises(ValueError, match="switch_fraction"):
        StepSchedule(1.0, 0.1, switch_fraction=1.5)
    with pytest.raises(ValueError, match="switch_update"):
        paper_learning_rate(total_updates=10, switch_update=11)


def test_learning_rate_follows_the_schedule_in_training():
    from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env

    config = SwarmConfig(grid_width=10, grid_height=10, max_steps=30, num_obstacles=5)
    model = LatentSwarmPPO(
        "LatentSwarmPolicy",
        make_vec_env(2, config=config, seed=0),
        learning_rate=StepSchedule(1e-3, 1e-5, switch_fraction=0.5),
        n_steps=20,
        chunk_length=5,
        batch_size=30,
        n_epochs=1,
        policy_kwargs=dict(latent_dim=8, predictor_hidden=8, decoder_hidden=8, critic_hidden=8, actor_hidden=8),
        seed=0,
    )
    model.learn(total_timesteps=4 * 20 * 6)  # 4 updates of 20 steps x 6 slots
    assert model.policy.optimizer.param_groups[0]["lr"] == pytest.approx(1e-5)
