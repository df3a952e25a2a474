#!/bin/bash
# Forty-sixth session, docs/experiments.md "Opposed contacts in the energy": the bench profile's synthesis on the 20
# Syn-Pl pair scenes of ../../fortyfirst/bench_pairs.sh (first scene per pair, 64 candidates) with the overrides
# given (e.g. --set synthesis.optimizer.w_opposition=20), then the pre-grasp table and the scripted squeeze on the
# first 5 accepted pre-grasps per pair x 5 trials, as ../../fortyfourth/pair_roll/run.sh. W: a work dir holding the
# scenes (copy cache/ and stages/scenes, stages/pointnet of bench_pairs.sh's work dir to reuse them; ~35 min on 2
# cores). The reference is the forty-first session's stage: ../../fortythird/closure_variants/base.json, trials 0-4.
# Run from the repository root:  run.sh W [--set KEY=VALUE ...]
set -e
W=${1:?usage: run.sh WORKDIR [--set KEY=VALUE ...]}; shift
D=(--set "synthesis.splits=[Pl]" --set "synthesis.max_scenes_per_combination={train: 1, Pl: 1, Com: 1, Geo: 1}"
   --set scenes.singles=false --set synthesis.optimizer.batch_size=64 "$@")
.venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --until synthesize
.venv/bin/multigrasp evaluate pregrasp --source synthetic --profile bench --workdir $W "${D[@]}"
.venv/bin/python -m benchmarks.lift_failures --profile bench --workdir $W "${D[@]}" \
    --split Pl --n-objects 2 --max-poses 5 --trials 5 --controller squeeze --json $W/lift.json
