#!/usr/bin/env bash
# The generalist measurement of the fifty-eighth session (README "The curriculum and distill stages"): every stage of
# the mini profile with config.yaml, then the specialists' and the generalist's Syn-Pl success on the same trials.
# Usage: benchmarks/results/fiftyeighth/generalist/run.sh WORKDIR   (from the repository root; ~1 h on 2 cores)
set -euo pipefail
W=${1:?work dir}
HERE=benchmarks/results/fiftyeighth/generalist
ARGS=(--profile mini --config "$HERE/config.yaml" --workdir "$W")
multigrasp run "${ARGS[@]}"
multigrasp evaluate execution "${ARGS[@]}"
multigrasp evaluate generalist "${ARGS[@]}"
cp "$W/results/execution.json" "$W/results/execution_generalist.json" "$HERE/"
