import time, torch as th
th.set_num_threads(1)
from sb3_latentswarm import LatentSwarmPPO, make_vec_env
from sb3_latentswarm.presets import get_preset
cands = {"old": {}, "b3840e3": dict(batch_size=3840, n_epochs=3), "b7680e5": dict(batch_size=7680), "b1920e3": dict(n_epochs=3), "b7680e4": dict(batch_size=7680, n_epochs=4)}
models = {}
for k, o in cands.items():
    p = get_preset("coordination").with_overrides(**o)
    env = make_vec_env(p.n_envs, config=p.config, seed=0)
    models[k] = (LatentSwarmPPO("LatentSwarmPolicy", env, seed=0, **p.algo_kwargs), p)
res = {k: [] for k in cands}
for rep in range(3):
    for k, (m, p) in models.items():
        t = time.thread_time(); m.learn(7680, reset_num_timesteps=False); res[k].append(time.thread_time() - t)
for k, v in res.items():
    print(k, [round(x, 2) for x in v], "median ratio old/this %.2f" % (sorted(res["old"])[1] / sorted(v)[1]))
