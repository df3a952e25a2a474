#!/bin/bash
# Thirty-ninth session, docs/experiments.md "A KL-adaptive learning rate" (the sigma 0.03 row): the thirty-eighth session's whole-bin gSDE run
# (../../thirtyeighth/ppo_cf_gsde/run.sh: gSDE sigma 0.1 here 0.03, joint offsets, r_lift capped at 15 cm, cube + frustum data of
# ../../thirtyfourth/ppo_cf_fc0.2/) with specialists.ppo.lr_schedule=kl_adaptive (rl_games' adaptive rate, kept within
# 2x of target_kl 0.02), 100 iterations, then Syn-Pl (100 poses x 5 trials) with the scripted rows.
# W: a work dir (the data line runs first; served from cache when W already holds it, ~29 min otherwise).
# Run from the repository root.
set -e
W=${1:?usage: run.sh WORKDIR [OUTDIR]}
OUT=${2:-$W/results}
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
G=(--set specialists.ppo.exploration=gsde --set specialists.ppo.init_scale=0.03
   --set lift.joint_action_mode=offset --set lift.lift_reward_cap_m=0.15 --set specialists.ppo.lr_schedule=kl_adaptive)
echo "=== data $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" --only scenes --only synthesize --only pointnet
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}" --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $OUT/
echo "=== done $(date)"
