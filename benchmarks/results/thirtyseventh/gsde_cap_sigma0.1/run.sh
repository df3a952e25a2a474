#!/bin/bash
cd /work/main
source benchmarks/results/thirtyfourth/ppo_cf_fc0.2/sets.sh
O=(--set specialists.records_source=lowest_energy --set specialists.lowest_energy_per_scene=1)
G=(--set specialists.ppo.exploration=gsde --set lift.joint_action_mode=offset)
time .venv/bin/multigrasp run --profile bench --workdir /work/s34/cf02 "${SETS[@]}" "${X[@]}" "${O[@]}" "${G[@]}" --set lift.lift_reward_cap_m=0.15 --set specialists.ppo.init_scale=0.1 --only specialists
