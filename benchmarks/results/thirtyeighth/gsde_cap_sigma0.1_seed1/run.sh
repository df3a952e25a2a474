#!/bin/bash
# Thirty-eighth session, docs/experiments.md "State-dependent exploration, gSDE": the thirty-seventh session's sigma 0.1 +
# cap run (benchmarks/results/thirtyseventh/gsde_cap_sigma0.1/) again with PPO seed 1, the same 10 pre-grasps of
# benchmarks/results/thirtysixth/ppo_overfit/run.sh with gSDE and joint offsets. W: the work dir holding the
# thirty-fourth session's cube + frustum data (benchmarks/results/thirtyfourth/ppo_cf_fc0.2/run.sh). Run from the
# repository root.
W=${1:?usage: run.sh WORKDIR}
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
O=(--set specialists.records_source=lowest_energy --set specialists.lowest_energy_per_scene=1)
G=(--set specialists.ppo.exploration=gsde --set lift.joint_action_mode=offset)
time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" "${O[@]}" "${G[@]}" --set lift.lift_reward_cap_m=0.15 --set specialists.ppo.init_scale=0.1 --set specialists.ppo.seed=1 --only specialists
# then, with UNIT the bin's folder in stages/specialists/<key>/index.json (the lift sets must match the run's):
#   .venv/bin/python benchmarks/results/thirtysixth/ppo_overfit/overfit_eval.py UNIT 10 11 OUT.json $W \
#       lift.joint_action_mode=offset lift.lift_reward_cap_m=0.15
