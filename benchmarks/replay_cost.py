"""Cost of the training replay alone: ``evaluate_sequences`` forward + backward on a synthetic minibatch of the paper's
sizes (d = 512, 50 x 50 map, N = 3, T = 25), chunked (``SequenceLinears``) and per step (the rollout's computation),
per-thread CPU seconds, the fastest of ``--reps`` after the first. Prints one JSON line. It runs on any package version
that has ``evaluate_sequences`` and ``chunked_replay``, so that old and new code can be alternated
(docs/algorithm.md, "The training replay"):

    for round in 1 2 3 4; do for root in /tmp/old $PWD; do
      (cd $root && PYTHONPATH=$root python $OLDPWD/benchmarks/replay_cost.py --autocast none)
    done; done

with the old package in ``/tmp/old`` (``git archive REV sb3_latentswarm | tar -x -C /tmp/old``).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--swarms", type=int, default=20, help="swarms of 3 UAVs per minibatch (x 25 steps x 3 agents)")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--autocast", choices=["none", "bf16"], default="bf16")
    parser.add_argument("--modes", nargs="+", choices=["sequence", "steps"], default=["sequence", "steps"])
    args = parser.parse_args()

    import torch as th

    from sb3_latentswarm import LatentSwarmPPO, SwarmConfig
    from sb3_latentswarm.envs import make_vec_env
    from sb3_latentswarm.latent_ppo.policies import LatentSwarmPolicy

    th.set_num_threads(1)
    sizes = dict(latent_dim=512, predictor_hidden=256, decoder_hidden=256, critic_hidden=256, actor_hidden=64)
    model = LatentSwarmPPO("LatentSwarmPolicy", make_vec_env(1, config=SwarmConfig(), seed=0), n_steps=25,
                           chunk_length=25, batch_size=75, policy_kwargs=sizes, seed=0,
                           autocast=None if args.autocast == "none" else args.autocast)
    policy = model.policy
    n_steps, n = 25, 3
    batch = n * args.swarms
    rng = np.random.default_rng(0)
    own_link = np.eye(n)[np.arange(batch) % n]
    obs = {
        "local_obs": th.as_tensor(rng.integers(-1, 2, (n_steps, batch, policy.local_obs_dim)), dtype=th.int8),
        "proprio": th.as_tensor(rng.random((n_steps, batch, 8)), dtype=th.float32),
        "link_row": th.as_tensor((rng.random((n_steps, batch, n)) < 0.6) * (1 - own_link), dtype=th.float32),
        "swarm_proprio": th.as_tensor(rng.random((n_steps, batch, n, 8)), dtype=th.float32),
        "global_map": th.as_tensor(rng.integers(-1, 2, (n_steps, batch, 50, 50)), dtype=th.int8),
    }
    actions = th.as_tensor(rng.standard_normal((n_steps, batch, 4)), dtype=th.float32)
    starts = th.zeros(n_steps, batch)
    starts[10] = 1.0
    state = policy.initial_state(batch)
    results = {}
    chunked = LatentSwarmPolicy.chunked_replay
    try:
        for mode in args.modes:
            LatentSwarmPolicy.chunked_replay = property(lambda self, m=mode: m == "sequence")  # type: ignore[method-assign]
            times = []
            for _ in range(args.reps + 1):
                policy.zero_grad()
                start = time.thread_time()
                out = policy.evaluate_sequences(obs, actions, state, starts)
                (out.log_prob.sum() + out.values.sum() + out.map_reconstruction.sum() + out.predicted_message.sum()).backward()
                times.append(time.thread_time() - start)
            results[mode] = min(times[1:])
    finally:
        LatentSwarmPolicy.chunked_replay = chunked  # type: ignore[method-assign]
    print(json.dumps({"agent_steps": n_steps * batch, "autocast": args.autocast, **results}))


if __name__ == "__main__":
    main()
