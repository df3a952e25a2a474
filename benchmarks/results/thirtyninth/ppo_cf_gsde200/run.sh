#!/bin/bash
# Thirty-ninth session, docs/experiments.md "gSDE on the whole cube + frustum bin, 200 iterations": the thirty-eighth
# session's run (../../thirtyeighth/ppo_cf_gsde/run.sh: gSDE sigma 0.1, joint offsets, lift reward capped at 15 cm, the
# whole cube + frustum bin of ../../thirtyfourth/ppo_cf_fc0.2/) trained for 200 PPO iterations instead of 100, then
# scored on Syn-Pl (100 poses x 5 trials) with the scripted rows. Does twice the budget move the whole bin?
# W: a work dir (made here if empty: the data line of the thirty-fourth script runs first, ~29 min on 2 cores).
# Run from the repository root.
set -e
W=${1:?usage: run.sh WORKDIR [OUTDIR]}
OUT=${2:-$W/results}
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
G=(--set specialists.ppo.exploration=gsde --set specialists.ppo.init_scale=0.1
   --set lift.joint_action_mode=offset --set lift.lift_reward_cap_m=0.15 --set specialists.ppo.iterations=200)
echo "=== data $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" --only scenes --only synthesize --only pointnet
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}" --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $OUT/
echo "=== done $(date)"
