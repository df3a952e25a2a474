#!/bin/bash
# Forty-first session: the bench profile's specialists on every pair under the new lift defaults (opposed closure,
# torsional friction 0.00625), docs/experiments.md "The opposed closure and torsional friction on every bench pair".
# Data: the first scene of every pair per split (train / Pl / Com / Geo), 64 candidates each, no singles (the
# synthesis is ~19 min for the 20 Pl scenes on 2 cores, ~1.5 h for all 51); then the profile's specialists
# (max_bins 4, 100 iterations each) and `evaluate execution` (Syn-Pl / Com / Geo, 100 poses x 5 trials, with the
# w/o RL and squeeze rows). Every stage is cached: a rerun after a crash resumes where it stopped.
# Run from the repository root:  bench_pairs.sh WORKDIR OUTDIR [--set KEY=VALUE ...]
set -e
W=${1:?usage: bench_pairs.sh WORKDIR OUTDIR [--set KEY=VALUE ...]}
OUT=${2:?usage: bench_pairs.sh WORKDIR OUTDIR [--set KEY=VALUE ...]}
shift 2
D=(--set "synthesis.splits=[train,Pl,Com,Geo]" --set "synthesis.max_scenes_per_combination={train: 1, Pl: 1, Com: 1, Geo: 1}"
   --set scenes.singles=false --set synthesis.optimizer.batch_size=64)
echo "=== data $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --until synthesize
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" "$@" --only pointnet --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${D[@]}" "$@"
mkdir -p $OUT
cp $W/results/execution.json $W/results/ablation_execution.json $OUT/
echo "=== done $(date)"
