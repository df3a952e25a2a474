#!/bin/bash
# fc_friction 0.2 data (train + Pl, first scene per pair, 64 candidates), the bench specialists (4 bins x 40 iterations),
# evaluate execution. Same shape as benchmarks/results/fortyfirst/bench_pairs.sh, Com / Geo left out for time.
set -e
cd /work/main
W=/work/s47/fc02
D=(--set "synthesis.splits=[train,Pl]" --set "synthesis.max_scenes_per_combination={train: 1, Pl: 1, Com: 1, Geo: 1}"
   --set scenes.singles=false --set synthesis.optimizer.batch_size=64 --set synthesis.optimizer.fc_friction=0.2)
echo "=== data $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --until synthesize
echo "=== train $(date)"
time .venv/bin/multigrasp run --profile bench --workdir $W "${D[@]}" --set specialists.ppo.iterations=40 --only pointnet --only specialists
echo "=== eval $(date)"
time .venv/bin/multigrasp evaluate execution --profile bench --workdir $W "${D[@]}" --set specialists.ppo.iterations=40
echo "=== done $(date)"
