#!/bin/bash
# Thirty-ninth session, docs/experiments.md "A KL-adaptive learning rate (sigma 0.03)". Run from the repository root: run.sh WORKDIR [OUTDIR]
exec benchmarks/results/thirtyninth/whole_bin.sh "${1:?usage: run.sh WORKDIR [OUTDIR]}" "${2:-$1/results}" --set specialists.ppo.lr_schedule=kl_adaptive --set specialists.ppo.init_scale=0.03
