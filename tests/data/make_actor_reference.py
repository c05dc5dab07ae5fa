"""Writes ``actor_reference.npz``: what two committed models do on fixed observations, recorded with the code of
commit 7559e37 (before the smooth std mapping and the squashed Gaussian existed). ``tests/test_actor.py`` checks
that today's code reproduces every array bit for bit (old model files load with ``log_std_mapping="clamp"``).

Run from the repository root: ``python tests/data/make_actor_reference.py``. Rerunning it with newer code only
proves self-consistency; the committed file is the reference.
"""

from pathlib import Path

import numpy as np
import torch as th

from sb3_latentswarm import LatentSwarmPPO, make_vec_env

ROOT = Path(__file__).resolve().parents[2]
MODELS = {
    # weight-only copies of the committed models the references were recorded on (the same weights); the code of
    # 7559e37 reads no weight-only file: there, use the originals (git checkout 206f0d5 -- docs/results/coordination
    # docs/results/fast_1800_updates)
    "coordination_proposed_seed0": "tests/data/models/coordination-proposed-seed0.zip",
    "fast_1800_updates": "tests/data/models/fast_1800_updates.zip",
}
N_STEPS = 6
ACTOR_KEYS = ("local_obs", "proprio", "link_row")
CRITIC_KEYS = ("swarm_proprio", "global_map")


def record(name: str, path: str) -> dict[str, np.ndarray]:
    model = LatentSwarmPPO.load(ROOT / path, device="cpu")
    policy = model.policy
    env = make_vec_env(2, config=model.swarm_config, seed=12345)
    obs = env.reset()
    rng = np.random.default_rng(0)
    n_slots = env.num_envs
    state = policy.initial_state(n_slots)
    starts = np.ones(n_slots, dtype=np.float32)
    out: dict[str, list[np.ndarray]] = {}

    def put(key: str, value) -> None:
        out.setdefault(f"{name}/{key}", []).append(np.asarray(value))

    predict_state = None
    for _ in range(N_STEPS):
        for key in ACTOR_KEYS + CRITIC_KEYS:
            put(f"obs_{key}", obs[key])
        put("episode_starts", starts)
        tensors = {key: th.as_tensor(obs[key]) for key in ACTOR_KEYS + CRITIC_KEYS}
        with th.no_grad():
            actions, values, log_prob, new_state = policy(tensors, state, th.as_tensor(starts), deterministic=True)
            distribution = policy.action_distribution(new_state.task_state)
            given = th.as_tensor(rng.uniform(-1.5, 1.5, size=actions.shape).astype(np.float32))
            put("mean", distribution.distribution.mean)
            put("stddev", distribution.distribution.stddev)
            put("deterministic_actions", actions)
            put("deterministic_log_prob", log_prob)
            put("values", values)
            put("given_actions", given)
            put("given_log_prob", distribution.log_prob(given))
            put("entropy", distribution.entropy())
        predicted, predict_state = policy.predict(obs, predict_state, starts, deterministic=True)
        put("predict_actions", predicted)
        state = new_state
        obs, _, dones, _ = env.step(actions.numpy().clip(-1, 1))
        starts = dones.astype(np.float32)
    env.close()
    return {key: np.stack(values) for key, values in out.items()}


if __name__ == "__main__":
    arrays: dict[str, np.ndarray] = {}
    for name, path in MODELS.items():
        arrays.update(record(name, path))
    np.savez_compressed(Path(__file__).with_name("actor_reference.npz"), **arrays)
    print({key: value.shape for key, value in arrays.items()})
