#!/bin/bash
# Thirty-eighth session, docs/experiments.md "gSDE on the whole cube + frustum bin": the thirty-seventh session's
# best 10-pose setting (gSDE sigma 0.1, joint offsets, lift reward capped at 15 cm) trained on the whole cube + frustum
# bin of benchmarks/results/thirtyfourth/ppo_cf_fc0.2/run.sh, then scored on Syn-Pl (100 poses x 5 trials) with the
# scripted rows (w/o RL, squeeze). The steps (data line first, served from cache when W holds the data) are
# ../../thirtyninth/whole_bin.sh's, with no extra options. Run from the repository root: run.sh WORKDIR [OUTDIR]
exec benchmarks/results/thirtyninth/whole_bin.sh "${1:?usage: run.sh WORKDIR [OUTDIR]}" "${2:-$1/results}"
