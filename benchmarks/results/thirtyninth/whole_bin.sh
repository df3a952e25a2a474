#!/bin/bash
# Thirty-ninth session, docs/experiments.md "Twice the budget on the whole bin" and "A KL-adaptive learning rate": the
# thirty-eighth session's whole-bin gSDE setting (../thirtyeighth/ppo_cf_gsde/run.sh: gSDE sigma 0.1, joint offsets,
# r_lift capped at 15 cm, the cube + frustum data of ../thirtyfourth/ppo_cf_fc0.2/) with the caller's extra --set
# options, then Syn-Pl (100 poses x 5 trials) with the scripted rows. Each result folder's run.sh names its options.
# W: a work dir (the data line runs first: served from cache when W holds it, ~21 min on 2 cores otherwise).
# Run from the repository root:  benchmarks/results/thirtyninth/whole_bin.sh WORKDIR OUTDIR [--set KEY=VALUE ...]
set -e
W=${1:?usage: whole_bin.sh WORKDIR OUTDIR [--set KEY=VALUE ...]}
OUT=${2:?usage: whole_bin.sh WORKDIR OUTDIR [--set KEY=VALUE ...]}
shift 2
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
G=(--set specialists.ppo.exploration=gsde --set specialists.ppo.init_scale=0.1
   --set lift.joint_action_mode=offset --set lift.lift_reward_cap_m=0.15 "$@")
echo "=== data $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" --only scenes --only synthesize --only pointnet
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}" --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${G[@]}"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $OUT/
echo "=== done $(date)"
