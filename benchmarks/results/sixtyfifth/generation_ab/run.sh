#!/bin/bash
# Sixty-fifth session: bench generation at the current code against a15775f (the thirty-third session's commit
# whose 9.3 s is in the README), alternated on one idle machine, 3 rounds, --repeats 3 each.
# Run from the repository root:  bash benchmarks/results/sixtyfifth/generation_ab/run.sh
set -e
O=$PWD/benchmarks/results/sixtyfifth/generation_ab
WT=/tmp/wt_a15
[ -d $WT ] || git worktree add $WT a15775f
for i in 1 2 3; do
  .venv/bin/multigrasp bench generation --json $O/head_$i.json --threads 2 --repeats 3
  (cd $WT && PYTHONPATH=$WT $OLDPWD/.venv/bin/multigrasp bench generation --json $O/a15775f_$i.json --threads 2 --repeats 3)
done
