#!/bin/bash
# Fortieth session, docs/experiments.md "Torsional friction at the finger pads": the thirty-ninth session's gSDE sigma
# 0.03 + KL-adaptive whole-bin specialist (cube + frustum, fc_friction 0.2 data) for 60 iterations, with the hand
# links' spinning friction at 0.00625 (0.005 m at the contact, MuJoCo's torsional default), then Syn-Pl with the
# scripted rows under the same physics. Run from the repository root: run.sh WORKDIR [OUTDIR]
exec benchmarks/results/thirtyninth/whole_bin.sh "${1:?usage: run.sh WORKDIR [OUTDIR]}" "${2:-$1/results}" \
    --set specialists.ppo.init_scale=0.03 --set specialists.ppo.lr_schedule=kl_adaptive \
    --set specialists.ppo.iterations=60 --set lift.hand_spinning_friction=0.00625
