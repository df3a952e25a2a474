#!/bin/bash
# Thirty-eighth session, docs/experiments.md "gSDE on the whole cube + frustum bin": the thirty-seventh session's
# best 10-pose setting (gSDE sigma 0.1, joint offsets, lift reward capped at 15 cm) trained on the whole cube + frustum
# bin of benchmarks/results/thirtyfourth/ppo_cf_fc0.2/run.sh, then scored on Syn-Pl (100 poses x 5 trials) with the scripted
# rows (w/o RL, squeeze). W: the work dir holding that data (run the thirty-fourth script's "data" line first). Run from the
# repository root.
set -e
W=${1:?usage: run.sh WORKDIR [OUTDIR]}
OUT=${2:-$W/results}
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
G=(--set specialists.ppo.exploration=gsde --set specialists.ppo.init_scale=0.1
   --set lift.joint_action_mode=offset --set lift.lift_reward_cap_m=0.15)
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}" --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $OUT/
echo "=== done $(date)"
