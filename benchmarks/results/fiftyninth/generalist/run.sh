#!/usr/bin/env bash
# The fifty-ninth session's generalist measurement (docs/experiments.md "The curriculum and the generalist with a
# generator that touches"): every stage of the mini profile with config.yaml, then Table I's specialist and generalist
# columns on Syn-Pl and Gen-Pl, and Table II(c) on Gen-Pl.
# Usage: benchmarks/results/fiftyninth/generalist/run.sh WORKDIR   (from the repository root; ~2 h on 2 cores)
# The fifty-ninth session ran every line but the last (`evaluate curriculum`, run by the sixtieth on the same work dir
# with --set run.torch_threads=2); it resumed the stages at generator step 1,000 with
# --set run.torch_threads=2 (no key changes), and ran `evaluate generalist` with it too, after the session's tests.
set -euo pipefail
W=${1:?work dir}
HERE=benchmarks/results/fiftyninth/generalist
ARGS=(--profile mini --config "$HERE/config.yaml" --workdir "$W")
multigrasp run "${ARGS[@]}"
multigrasp evaluate pregrasp --source generated "${ARGS[@]}"
multigrasp evaluate execution "${ARGS[@]}"
multigrasp evaluate execution --source generated "${ARGS[@]}"
multigrasp evaluate generalist "${ARGS[@]}"
multigrasp evaluate curriculum "${ARGS[@]}"
for f in pregrasp_generated execution execution_generated execution_generalist ablation_curriculum; do
  cp "$W/results/$f.json" "$HERE/"
done
