#!/bin/bash
# Forty-seventh session, docs/experiments.md "Less friction in E_fc, under the current profile": the bench specialists
# on pre-grasps synthesised at fc_friction 0.2. The shape of ../../../fortyfirst/bench_pairs.sh without Com and Geo:
# the first scene of every pair in train and Pl at 64 candidates, the profile's 4 largest bins x 40 iterations, then
# `evaluate execution` (Syn-Pl 100 poses x 5 with the w/o RL and squeeze rows). W: a work dir holding the bench scenes
# (the session reused the work dir of ../../../fortysixth/opposition/run.sh W --set synthesis.optimizer.fc_friction=0.2,
# so its Pl stage was cached). ~85 min on 2 cores. Every stage is cached: a rerun after a crash resumes.
# Run from the repository root:  run.sh W OUTDIR
set -e
W=${1:?usage: run.sh WORKDIR OUTDIR}; OUT=${2:?usage: run.sh WORKDIR OUTDIR}
D=(--set "synthesis.splits=[train,Pl]" --set "synthesis.max_scenes_per_combination={train: 1, Pl: 1, Com: 1, Geo: 1}"
   --set scenes.singles=false --set synthesis.optimizer.batch_size=64 --set synthesis.optimizer.fc_friction=0.2
   --set specialists.ppo.iterations=40)
.venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --until synthesize
.venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --only pointnet --only specialists
.venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${D[@]}"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $W/results/execution.md $OUT/
cp $W/results/execution/Syn-Pl/outcomes.json $OUT/outcomes_Syn-Pl.json
.venv/bin/python -m benchmarks.paired_execution $OUT/outcomes_Syn-Pl.json --column squeeze --column-b policy \
    --json $OUT/paired_policy_vs_squeeze.json
