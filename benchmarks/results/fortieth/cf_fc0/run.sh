#!/bin/bash
# Fortieth session, docs/experiments.md "Frictionless pre-grasps on the whole bin": the cube + frustum bin of
# ../../thirtyfourth/ppo_cf_fc0.2/ synthesised with the official frictionless E_fc (fc_friction 0) instead of 0.2, with
# more scenes to make up for the lower accept rate (8 training, 50 Pl), then the thirty-ninth session's gSDE sigma
# 0.03 + KL-adaptive specialist for 60 iterations, and Syn-Pl (up to 100 poses x 5 trials) with the scripted rows.
# Run from the repository root:  run.sh WORKDIR [OUTDIR]   (the data line takes ~75 min on 2 cores; every stage is
# cached, so a rerun after a crash resumes where it stopped)
set -e
W=${1:?usage: run.sh WORKDIR [OUTDIR]}
OUT=${2:-$W/results}
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
SETS+=(--set "scenes.per_combination={train: 8, Pl: 50, Com: 0, Geo: 0, many: 0}"
       --set "synthesis.max_scenes_per_combination={train: 8, Pl: 50}" --set synthesis.optimizer.fc_friction=0)
G=(--set specialists.ppo.exploration=gsde --set specialists.ppo.init_scale=0.03
   --set specialists.ppo.lr_schedule=kl_adaptive --set specialists.ppo.iterations=60
   --set lift.joint_action_mode=offset --set lift.lift_reward_cap_m=0.15)
echo "=== data $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" --only scenes --only synthesize --only pointnet
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}" --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $OUT/
echo "=== done $(date)"
