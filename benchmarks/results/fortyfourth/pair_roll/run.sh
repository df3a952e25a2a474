#!/bin/bash
# Forty-fourth session, docs/experiments.md "Fingers along the object line": the bench profile's synthesis on the 20
# Syn-Pl pair scenes of ../../fortyfirst/bench_pairs.sh (first scene per pair, 64 candidates) with the palm-down
# start's fingers along the object line (init_pair_roll: along) instead of across it, then the pre-grasp table and
# the scripted squeeze on the first 5 accepted pre-grasps per pair x 5 trials. W: a work dir holding the scenes
# (copy cache/ and stages/scenes, stages/pointnet of bench_pairs.sh's work dir to reuse them; ~30 min on 2 cores).
# The reference (across) is the forty-first session's stage: ../../fortythird/closure_variants/base.json, trials 0-4.
# Run from the repository root:  run.sh W
set -e
W=${1:?usage: run.sh WORKDIR}
D=(--set "synthesis.splits=[Pl]" --set "synthesis.max_scenes_per_combination={train: 1, Pl: 1, Com: 1, Geo: 1}"
   --set scenes.singles=false --set synthesis.optimizer.batch_size=64 --set synthesis.optimizer.init_pair_roll=along)
.venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --until synthesize
.venv/bin/multigrasp evaluate pregrasp --source synthetic --profile bench --workdir $W "${D[@]}"
.venv/bin/python -m benchmarks.lift_failures --profile bench --workdir $W "${D[@]}" \
    --split Pl --n-objects 2 --max-poses 5 --trials 5 --controller squeeze --json $W/lift.json
