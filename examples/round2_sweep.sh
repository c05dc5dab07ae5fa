#!/usr/bin/env bash
# The evidence, second round (issue 23, item 1): five training seeds each of LatentSwarmPPO (`proposed`), the same
# trained without links (`no_comm`), with zeros (`zero_substitute`) and with the last received message
# (`hold_last`) in place of the predicted message during dropout, on the `coordination` preset as it is now (the
# squashed actor, the issue-21 training options of that round: learning rate 6e-4, pinned below since the preset
# moved to 1e-3 on 2026-12-04), trained at p_f = 0.3 with bursty (Gilbert-Elliott) outages of mean
# length 10 steps (the first round's training channel: bursts give the predictor work that Bernoulli drops do not).
# Every model is evaluated on 100 held-out episodes per cell with SAMPLED actions (the paper's protocol): every
# condition (Table I's five, full_comm_in_range, hold_last, own_message) and the p_f sweep at the training channel,
# the Bernoulli channel, bursts of mean length 30, p_f = 0.7 and p_f = 1 (every link down). The independent
# RecurrentPPO baseline (3 seeds) is the second command.
#
#   bash examples/round2_sweep.sh                   # into runs/sweeps/round2 (many hours on 2 cores; resumable)
#   bash examples/round2_sweep.sh --resume          # continue it: finished trials are kept, running ones resume
#                                                   # from their last checkpoint
#   SEEDS=3 VARIANTS=independent OUT=runs/sweeps/round2_independent bash examples/round2_sweep.sh
set -euo pipefail
exec "${SB3_LATENTSWARM:-.venv/bin/sb3-latentswarm}" sweep --preset coordination --seeds "${SEEDS:-5}" \
  --variant ${VARIANTS:-proposed no_comm zero_substitute hold_last} \
  --set outage_model=gilbert_elliott mean_outage_steps=10 learning_rate=6e-4 \
  --eval-episodes 100 --stochastic \
  --eval-set bernoulli=outage_model=bernoulli \
  --eval-set burst30=mean_outage_steps=30 \
  --eval-set pf0.7=p_fail=0.7,conditions=proposed+no_predictor+hold_last+no_memory+no_comm \
  --eval-set pf1=p_fail=1.0,conditions=proposed+no_predictor+hold_last+no_memory \
  --output "${OUT:-runs/sweeps/round2}" --verbose 1 "$@"
