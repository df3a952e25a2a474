#!/bin/bash
# Fortieth session, docs/experiments.md "A closure that keeps the opposition": ../ppo_cf_spin/ (gSDE sigma 0.03 +
# KL-adaptive, 60 iterations, spinning friction 0.00625) with the closure pressing only opposed links
# (lift.closure_links=opposed), then Syn-Pl with the scripted rows under the same env. Run from the repository root:
# run.sh WORKDIR [OUTDIR]
exec benchmarks/results/thirtyninth/whole_bin.sh "${1:?usage: run.sh WORKDIR [OUTDIR]}" "${2:-$1/results}" \
    --set specialists.ppo.init_scale=0.03 --set specialists.ppo.lr_schedule=kl_adaptive \
    --set specialists.ppo.iterations=60 --set lift.hand_spinning_friction=0.00625 --set lift.closure_links=opposed
