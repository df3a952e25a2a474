#!/bin/bash
# Sixty-fourth session: the three issue-target benchmarks re-measured at the current code (their README figures
# were last measured in the thirtieth, thirty-third and thirty-seventh sessions). Run from the repository root on an
# otherwise idle machine:   bash benchmarks/results/sixtyfourth/recheck/run.sh   (~40 min on 2 cores)
set -e
O=benchmarks/results/sixtyfourth/recheck
M=.venv/bin/multigrasp
for i in 1 2 3 4; do $M bench sim --json $O/sim_$i.json --repeats 7; done
for i in 1 2 3; do $M bench generation --json $O/generation_$i.json --threads 2; done
$M bench synthesis --json $O/synthesis.json --threads 2 --repeats 3
