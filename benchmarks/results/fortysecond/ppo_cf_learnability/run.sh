#!/bin/bash
# Forty-second session, docs/experiments.md "Learnability start sampling": the fortieth session's whole-bin run
# (../../fortieth/ppo_cf_spin_opposed/run.sh: gSDE sigma 0.03, KL-adaptive rate, 60 iterations, torsional friction
# 0.00625, opposed closure; the cube + frustum fc_friction 0.2 data) with training starts drawn by learnability
# (lift.start_sampling=learnability), then Syn-Pl with the scripted rows. The results beside this script are the first
# run (commit 06e50a8: each collector worker counted on its own); ../ppo_cf_learnability_shared/ holds the second
# (the workers share the counts, as the code does now). Per-pose outcomes: outcomes_Syn-Pl.json, copied from
# WORKDIR/results/execution/Syn-Pl/outcomes.json. Run from the repository root:
# run.sh WORKDIR [OUTDIR]
W=${1:?usage: run.sh WORKDIR [OUTDIR] [--set KEY=VALUE ...]}
OUT=${2:-$W/results}
shift; shift || true
exec benchmarks/results/thirtyninth/whole_bin.sh "$W" "$OUT" \
    --set specialists.ppo.init_scale=0.03 --set specialists.ppo.lr_schedule=kl_adaptive \
    --set specialists.ppo.iterations=60 --set lift.hand_spinning_friction=0.00625 --set lift.closure_links=opposed \
    --set lift.start_sampling=learnability "$@"
