#!/bin/bash
# Sixty-third session, docs/experiments.md "Frictionless E_fc under the current lift": the bench profile's synthesis
# on the 20 Syn-Pl pair scenes (first scene per pair) at 128 candidates with the release's frictionless E_fc, then
# the pre-grasp table and the scripted squeeze on the first 5 accepted pre-grasps per pair x 5 trials
# (../../fortysixth/opposition/run.sh). ~50 min on 2 cores from a fresh work dir. Run from the repository root:
#   run.sh W
set -e
W=${1:?usage: run.sh WORKDIR}
bash benchmarks/results/fortysixth/opposition/run.sh "$W" --set synthesis.optimizer.fc_friction=0 \
    --set synthesis.optimizer.batch_size=128
cp "$W/lift.json" benchmarks/results/sixtythird/fc_friction0/lift_squeeze.json
# The same-day reference: the profile on the same scenes (run.sh of ../../fortysixth/opposition without the override)
#   bash benchmarks/results/fortysixth/opposition/run.sh "$W"   then copy $W/lift.json to lift_squeeze_profile_same_day.json
