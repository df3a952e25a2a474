#!/bin/bash
# Diagnostic (thirty-sixth session): can PPO improve on its scripted start when it trains on 10 pre-grasps only
# (the lowest-energy candidate of each of the 10 training scenes)?  W: a work dir holding the thirty-fourth
# session's cube + frustum data (benchmarks/results/thirtyfourth/ppo_cf_fc0.2/run.sh makes it, ~29 min).
# Run from the repository root.
W=${1:?usage: run.sh WORKDIR}
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
O=(--set specialists.records_source=lowest_energy --set specialists.lowest_energy_per_scene=1)
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${O[@]}" --only specialists  # 39 min
# then, with UNIT the bin's folder printed in stages/specialists/<key>/index.json:
#   .venv/bin/python benchmarks/results/thirtysixth/ppo_overfit/overfit_eval.py UNIT 10 11 OUT.json W      # 3 min
#   .venv/bin/python benchmarks/results/thirtysixth/ppo_overfit/action_search.py 0.15,0.4 10 3 OUT.json W   # ~20 min
