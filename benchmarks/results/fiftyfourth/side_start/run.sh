#!/bin/bash
# Fifty-fourth session (the fifty-third's run, whose results were lost with its machine), docs/experiments.md "What
# else moves Q1", "The default start, with the palm": the default (sphere) start with the palm's contact regions
# allowed, on the 20 bench Syn-Pl pair scenes x 64, then the Syn-Pl table and the scripted squeeze on the first 5
# accepted pre-grasps per pair x 5 trials (33 min on 2 cores). paired_by_pair.txt compares it with the profile's
# per-pair success (column A of ../../fortyseventh/fc_friction02/paired_by_pair.txt). Run from the repository root:
#   run.sh WORKDIR
set -e
W=${1:?usage: run.sh WORKDIR}
bash benchmarks/results/fortysixth/opposition/run.sh "$W" \
  --set synthesis.optimizer.init_mode=sphere --set "synthesis.optimizer.contact_regions_excluded=[]"
