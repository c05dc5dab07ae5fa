#!/usr/bin/env bash
# The evidence, second round (issue 23, item 3): a task where peers' current state is necessary. Three training seeds
# each of LatentSwarmPPO (`proposed`), the same trained without links (`no_comm`), and with zeros (`zero_substitute`)
# or the last received message (`hold_last`) in place of the predicted message during dropout, on the `random_corner`
# preset (N = 5, the launch corner drawn per episode, T = 48; the best message-free scripted policy loses 19.9 points
# to a coordinated planner, docs/results/random_corner_preset_gap/), trained at the preset's own channel (bursty
# Gilbert-Elliott outages, p_f = 0.5, mean failure run 25 steps). Every model is evaluated on 100 held-out episodes
# per cell with SAMPLED actions (the paper's protocol): every condition at the training channel (and the p_f sweep
# 0 .. 0.5 there), bursts of mean 10 and 30 steps at p_f = 0.3 (target 3), the Bernoulli channel at p_f = 0.3,
# p_f = 0.7 and p_f = 1 (every link down).
#
#   bash examples/random_corner_sweep.sh            # into runs/sweeps/random_corner (hours on 2 cores; resumable)
#   bash examples/random_corner_sweep.sh --resume   # continue it: finished trials are kept, running ones resume
set -euo pipefail
exec "${SB3_LATENTSWARM:-.venv/bin/sb3-latentswarm}" sweep --preset random_corner --seeds "${SEEDS:-3}" \
  --variant ${VARIANTS:-proposed no_comm zero_substitute hold_last} \
  --eval-episodes 100 --stochastic \
  --eval-set burst10=p_fail=0.3,mean_outage_steps=10 \
  --eval-set burst30=p_fail=0.3,mean_outage_steps=30 \
  --eval-set bernoulli=p_fail=0.3,outage_model=bernoulli \
  --eval-set pf0.7=p_fail=0.7,conditions=proposed+no_predictor+hold_last+no_memory+no_comm \
  --eval-set pf1=p_fail=1.0,conditions=proposed+no_predictor+hold_last+no_memory \
  --output "${OUT:-runs/sweeps/random_corner}" --verbose 1 "$@"
