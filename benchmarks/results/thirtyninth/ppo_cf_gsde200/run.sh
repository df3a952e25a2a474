#!/bin/bash
# Thirty-ninth session, docs/experiments.md "Twice the budget on the whole bin". Run from the repository root: run.sh WORKDIR [OUTDIR]
exec benchmarks/results/thirtyninth/whole_bin.sh "${1:?usage: run.sh WORKDIR [OUTDIR]}" "${2:-$1/results}" --set specialists.ppo.iterations=200
