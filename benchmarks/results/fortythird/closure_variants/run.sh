#!/bin/bash
# Forty-third session, docs/experiments.md "Choosing the closure per pre-grasp": the scripted squeeze (PPO's start) on
# the forty-first session's 20 bench Syn-Pl pair scenes (the data of ../../fortyfirst/bench_pairs.sh), first 5 accepted
# pre-grasps per pair, under one closure / squeeze variant; then `python -m benchmarks.controller_headroom` over the
# variants' files. The reference ran 10 trials and 'all' 10; the others 6 (the tool uses the trials common to all).
# The committed JSON files keep the summary and the episodes (the per-object rows are left out for size).
# Run from the repository root:  run.sh WORKDIR OUT.json TRIALS [--set KEY=VALUE ...]
#   run.sh W base.json 10
#   run.sh W all.json 10 --set lift.closure_links=all
#   run.sh W opp0.json 6 --set lift.closure_opposed_above=0.0
#   run.sh W opp08.json 6 --set lift.closure_opposed_above=0.8
#   run.sh W force04.json 6 --set specialists.squeeze_force_fraction=0.4
#   run.sh W rad2.json 6 --set lift.closure_radius_m=0.02
#   run.sh W rad3.json 6 --set lift.closure_radius_m=0.03
#   python -m benchmarks.controller_headroom base=base.json all=all.json opp0=opp0.json opp08=opp08.json \
#       force04=force04.json rad2=rad2.json rad3=rad3.json --json headroom.json
set -e
W=${1:?usage: run.sh WORKDIR OUT.json TRIALS [--set KEY=VALUE ...]}
OUT=${2:?usage: run.sh WORKDIR OUT.json TRIALS [--set KEY=VALUE ...]}
TRIALS=${3:?usage: run.sh WORKDIR OUT.json TRIALS [--set KEY=VALUE ...]}
shift 3
exec .venv/bin/python -m benchmarks.lift_failures --profile bench --workdir "$W" \
    --set "synthesis.splits=[train,Pl,Com,Geo]" --set "synthesis.max_scenes_per_combination={train: 1, Pl: 1, Com: 1, Geo: 1}" \
    --set scenes.singles=false --set synthesis.optimizer.batch_size=64 \
    --split Pl --n-objects 2 --max-poses 5 --trials "$TRIALS" --controller squeeze "$@" --json "$OUT"
