"""What replaces the message during dropout: LatentSwarmPolicy.message_substitute, the test-time conditions that set
it (no_predictor, hold_last, own_message) and the sweep variants trained with it (zero_substitute, hold_last)."""

import numpy as np
import pytest
import torch as th

from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
from sb3_latentswarm.envs import make_vec_env
from sb3_latentswarm.evaluation import policy_switches
from sb3_latentswarm.experiments.trial import variant_algo_kwargs
from sb3_latentswarm.latent_ppo.policies import MESSAGE_SUBSTITUTES
from sb3_latentswarm.latent_ppo.type_aliases import LatentState

CONFIG = SwarmConfig(n_agents=2, grid_width=9, grid_height=9, max_steps=10, num_obstacles=0)
TINY_POLICY = dict(latent_dim=6, predictor_hidden=8, decoder_hidden=8, critic_hidden=8, actor_hidden=8)


@pytest.fixture(scope="module")
def policy():
    env = make_vec_env(1, config=CONFIG, seed=0)
    return LatentSwarmPPO("LatentSwarmPolicy", env, n_steps=10, chunk_length=5, batch_size=10, policy_kwargs=TINY_POLICY,
                          seed=0).policy


def _obs(policy, link_row, seed):
    rng = np.random.default_rng(seed)
    return {
        "local_obs": th.as_tensor(rng.integers(-1, 2, (2, policy.local_obs_dim)), dtype=th.int8),
        "proprio": th.as_tensor(rng.random((2, policy.proprio_dim)), dtype=th.float32),
        "link_row": th.as_tensor(np.asarray(link_row, dtype=np.float32)),
    }


def _run(policy, substitute):
    """Three steps of one 2-UAV swarm: t0 UAV 0 hears UAV 1 (UAV 1 hears nothing), t1 and t2 nobody hears anybody."""
    gen = th.Generator().manual_seed(3)
    state = LatentState(*(th.randn(2, dim, generator=gen) for dim in policy.latent_dims))
    state = state._replace(held_message=th.zeros_like(state.held_message))  # nothing received yet in this episode
    links = ([[0, 1], [0, 0]], [[0, 0], [0, 0]], [[0, 0], [0, 0]])
    policy.message_substitute = substitute
    steps = []
    with th.no_grad():
        for t, link_row in enumerate(links):
            step = policy.latent_step(_obs(policy, link_row, seed=t), state, th.zeros(2))
            steps.append(step)
            state = step.state
    policy.message_substitute = "predicted"
    return steps


@pytest.mark.parametrize("substitute", MESSAGE_SUBSTITUTES)
def test_substitute_on_a_hand_built_dropout_sequence(policy, substitute):
    steps = _run(policy, substitute)
    t0, t1, t2 = steps
    # t0: UAV 0 received UAV 1's z_{-1}; mbar is that message whatever the substitute
    th.testing.assert_close(t0.received_message[0], t0.sent_message[1])
    th.testing.assert_close(t0.state.prev_message[0], t0.sent_message[1])
    th.testing.assert_close(t0.state.held_message[0], t0.sent_message[1])
    assert th.all(t0.state.held_message[1] == 0)  # UAV 1 has received nothing in the episode
    for step in (t1, t2):
        assert not step.has_message.any()
        expected = {
            "predicted": step.predicted_message,
            "zero": th.zeros_like(step.predicted_message),
            # the last message actually received in the episode: UAV 0's from t0; UAV 1 none yet, so zeros
            "hold_last": th.stack([t0.sent_message[1], th.zeros_like(t0.sent_message[1])]),
            "own_message": step.sent_message,
        }[substitute]
        th.testing.assert_close(step.state.prev_message, expected, rtol=0, atol=0)
        th.testing.assert_close(step.state.held_message, t0.state.held_message, rtol=0, atol=0)


def test_episode_start_clears_the_held_message(policy):
    state = LatentState(*(th.ones(2, dim) for dim in policy.latent_dims))
    policy.message_substitute = "hold_last"
    try:
        with th.no_grad():
            step = policy.latent_step(_obs(policy, [[0, 0], [0, 0]], seed=0), state, th.ones(2))
    finally:
        policy.message_substitute = "predicted"
    assert th.all(step.state.held_message == 0) and th.all(step.state.prev_message == 0)
    assert th.all(step.sent_message == 0)


def test_no_predictor_is_the_zero_substitute(policy):
    policy.no_predictor = True
    assert policy.message_substitute == "zero"
    policy.no_predictor = False
    assert policy.message_substitute == "predicted"
    with pytest.raises(ValueError, match="message_substitute must be one of"):
        type(policy)(policy.observation_space, policy.action_space, lambda _: 1e-4, message_substitute="last")


def test_conditions_keep_a_trained_substitute_unless_they_name_one(policy):
    policy.message_substitute = "hold_last"
    try:
        for condition, expected in (("proposed", "hold_last"), ("no_comm", "hold_last"), ("no_predictor", "zero"),
                                    ("own_message", "own_message"), ("hold_last", "hold_last")):
            with policy_switches(policy, condition):
                assert policy.message_substitute == expected, condition
            assert policy.message_substitute == "hold_last"
    finally:
        policy.message_substitute = "predicted"


def test_variants_train_with_their_substitute_and_save_it(tmp_path):
    kwargs = variant_algo_kwargs("zero_substitute", {"n_steps": 10, "policy_kwargs": dict(TINY_POLICY)})
    assert kwargs["policy_kwargs"]["message_substitute"] == "zero"
    assert variant_algo_kwargs("proposed", {"policy_kwargs": {}}) == {"policy_kwargs": {}}
    env = make_vec_env(1, config=CONFIG, seed=0)
    model = LatentSwarmPPO("LatentSwarmPolicy", env, chunk_length=5, batch_size=10, seed=0,
                           **variant_algo_kwargs("hold_last", {"n_steps": 10, "policy_kwargs": dict(TINY_POLICY)}))
    model.learn(20)
    model.save(tmp_path / "m.zip")
    assert LatentSwarmPPO.load(tmp_path / "m.zip").policy.message_substitute == "hold_last"
