"""SwarmEvalCallback: evaluations of whole swarm episodes, every eval_freq agent-steps, logged under eval/."""

import pandas as pd
import pytest
from stable_baselines3.common.logger import configure

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig, make_vec_env
from sb3_latentswarm.callbacks import SwarmEvalCallback
from sb3_latentswarm.evaluation import evaluate

SMALL = SwarmConfig(n_agents=3, grid_width=10, grid_height=10, max_steps=20, num_obstacles=5)
TINY_POLICY = dict(latent_dim=8, predictor_hidden=16, decoder_hidden=16, critic_hidden=16, actor_hidden=16)


def tiny_model(n_envs: int, n_steps: int) -> LatentSwarmPPO:
    return LatentSwarmPPO(
        "LatentSwarmPolicy",
        make_vec_env(n_envs, config=SMALL, seed=0),
        n_steps=n_steps,
        chunk_length=5,
        batch_size=30,
        n_epochs=1,
        policy_kwargs=TINY_POLICY,
        seed=0,
    )


def test_swarm_eval_callback_counts_swarm_episodes_and_agent_steps(tmp_path):
    model = tiny_model(n_envs=2, n_steps=20)
    model.train = lambda *args: None  # the policy stays as evaluated, so evaluate() afterwards must give the same numbers
    model.set_logger(configure(str(tmp_path), ["csv"]))
    per_update = 20 * 2 * 3  # n_steps * n_envs * n_agents agent-steps
    callback = SwarmEvalCallback(eval_freq=2 * per_update, n_eval_episodes=3, best_model_save_path=tmp_path)
    model.learn(total_timesteps=4 * per_update, callback=callback)
    assert [e["num_timesteps"] for e in callback.evaluations] == [2 * per_update, 4 * per_update]
    # each evaluation is 3 swarm episodes of the training config: the same numbers as evaluate() on them
    expected = evaluate(model, n_episodes=3)  # the default (held-out) seeds of both
    assert callback.evaluations[-1]["coverage"] == pytest.approx(expected["coverage"].mean())
    assert callback.evaluations[-1]["collisions"] == pytest.approx(expected["collisions"].mean())
    progress = pd.read_csv(tmp_path / "progress.csv")
    for key in ("eval/coverage", "eval/collisions", "eval/steps_to_90", "eval/reached_90"):
        assert key in progress.columns, key
    assert progress["eval/coverage"].notna().sum() == 2
    assert (tmp_path / "best_model.zip").exists()


def test_swarm_eval_callback_rejects_bad_arguments():
    with pytest.raises(ValueError, match=r"eval_freq \(agent-steps\) must be an int in \[1, inf\)"):
        SwarmEvalCallback(eval_freq=0)
    with pytest.raises(ValueError, match="Unknown condition"):
        SwarmEvalCallback(eval_freq=10, condition="everything")


def test_rollout_progress_bar_ends_at_100_percent_of_whole_rollouts(tmp_path):
    from sb3_latentswarm.callbacks import RolloutProgressBarCallback, whole_rollouts

    model = tiny_model(n_envs=1, n_steps=10)
    model.train = lambda *args: None  # only the rollout counts matter here
    per_rollout = 10 * 1 * 3
    assert whole_rollouts(2 * per_rollout + 1, per_rollout) == 3 * per_rollout
    assert whole_rollouts(per_rollout, per_rollout) == per_rollout
    bar = RolloutProgressBarCallback()
    model.learn(total_timesteps=2 * per_rollout + 1, callback=bar)  # SB3's bar would end at 90/61
    assert model.num_timesteps == 3 * per_rollout
    assert (bar.pbar.n, bar.pbar.total) == (3 * per_rollout, 3 * per_rollout)
    with pytest.raises(ValueError, match="per_rollout must be an int in"):
        whole_rollouts(10, 0)
