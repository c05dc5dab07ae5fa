"""LatentSwarmPPO on the fast preset with the independent baseline's update cadence (short rollouts, 10 epochs)."""
import time
import torch as th
from sb3_latentswarm import LatentSwarmPPO, make_vec_env
from sb3_latentswarm.presets import get_preset

th.set_num_threads(1)
preset = get_preset("fast")
kwargs = dict(preset.algo_kwargs)
kwargs.update(n_steps=125, chunk_length=25, batch_size=750, n_epochs=10)
env = make_vec_env(preset.n_envs, config=preset.config, seed=0)
model = LatentSwarmPPO("LatentSwarmPolicy", env, seed=0, **kwargs)
start = time.perf_counter()
model.learn(4_320_000)
model.save("/tmp/cadence/model.zip")
print("trained", model.num_timesteps, "agent-steps in", round(time.perf_counter() - start), "s", kwargs, flush=True)
