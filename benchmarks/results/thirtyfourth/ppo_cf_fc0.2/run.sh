#!/bin/bash
# Does PPO improve on its scripted start when the pre-grasps lift? cube+frustum, bench profile, fc_friction 0.2
cd /work/main
source /work/s34/sets.sh
W=/work/s34/cf02
echo "=== data $(date)"
( time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" --only scenes --only synthesize --only pointnet ) > /work/s34/data.log 2>&1
echo "=== train $(date)"
( time .venv/bin/multigrasp run --profile bench --workdir $W "${SETS[@]}" "${X[@]}" --only specialists ) > /work/s34/train.log 2>&1
echo "=== eval $(date)"
( time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${SETS[@]}" "${X[@]}" ) > /work/s34/eval.log 2>&1
cp $W/results/execution.json /work/s34/execution.json 2>/dev/null
cp $W/results/ablation_execution.json /work/s34/ablation.json 2>/dev/null
echo "=== done $(date)"
