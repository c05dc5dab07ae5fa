#!/usr/bin/env bash
# The multi-seed experiment of docs/results/archive/coordination/: three learners (LatentSwarmPPO, the same trained without
# links, independent RecurrentPPO) x three training seeds on the `coordination` preset, trained at p_f = 0.3 with
# bursty (Gilbert-Elliott) outages of mean length 10 steps, each model evaluated on 100 held-out episodes per cell:
# Table I's conditions (+ Full comm in range) and the p_f sweep at the training channel, the Bernoulli channel,
# bursts of mean length 30, p_f = 0.7 and p_f = 1 (every link down).
#
#   bash examples/coordination_sweep.sh                       # into runs/sweeps/coordination (about 2.5 h on 2 cores)
#   bash examples/coordination_sweep.sh --resume              # continue it; finished trials are kept
#   bash examples/coordination_sweep.sh --resume --only independent-seed1   # only some of the trials
#
# To continue the committed results: cp -r docs/results/archive/coordination runs/sweeps/coordination, then --resume.
# The committed results were trained with the preset's first-round options (200 updates of minibatch 1,920, 5 epochs,
# learning rate 3e-4: `git checkout b250de8` reproduces them); the preset now trains 300 updates of 3,840 / 3 / 1e-3
# (docs/results/coordination_time_to_coverage/); the second round trained 3,840 / 3 / 6e-4 (examples/round2_sweep.sh).
exec "${SB3_LATENTSWARM:-.venv/bin/sb3-latentswarm}" sweep --preset coordination --seeds 3 \
  --variant proposed no_comm independent \
  --set outage_model=gilbert_elliott mean_outage_steps=10 \
  --eval-episodes 100 \
  --eval-set bernoulli=outage_model=bernoulli \
  --eval-set burst30=mean_outage_steps=30 \
  --eval-set pf0.7=p_fail=0.7,conditions=proposed+no_predictor+no_memory+no_comm \
  --eval-set pf1=p_fail=1.0,conditions=proposed+no_predictor+no_memory \
  --output runs/sweeps/coordination --verbose 1 "$@"
