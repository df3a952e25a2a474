#!/bin/bash
# Forty-fifth session, docs/experiments.md "What else moves Q1": one synthesis setting on the eight screening scenes of
# ../../fortyfourth/pair_roll (cube + cylinder, capsule + bar, frustum + hex prism, sphere + ellipsoid; seeds 0 and 1;
# the bench profile at B 64, one thread per process, two processes). Writes OUTDIR/NAME.jsonl (one line per scene).
# Run from the repository root:
#   screen.sh OUTDIR NAME [--set KEY=VALUE ...]                      the profile's optimiser with the overrides
#   RUNNER=benchmarks/results/fortyfifth/q1_screens/wide_patches.py WIDE_DEG=95 screen.sh OUTDIR NAME [...]
#   RUNNER=benchmarks/results/fortyfifth/q1_screens/one_sided_q1_band.py Q1_INSIDE_BAND_M=0.001 screen.sh OUTDIR NAME [...]
# summary.py OUTDIR/NAME.jsonl compares it with the profile's run of the same scenes (../../fortyfourth/pair_roll/across.jsonl).
set -e
OUTDIR=${1:?usage: screen.sh OUTDIR NAME [--set KEY=VALUE ...]}; NAME=${2:?usage: screen.sh OUTDIR NAME [...]}; shift 2
RUNNER=${RUNNER:--m benchmarks.synthesis_experiment}
mkdir -p "$OUTDIR"
run() { for scene in "$@"; do
  PYTHONPATH=$PWD .venv/bin/python $RUNNER --objects "${scene%%:*}" --seed "${scene##*:}" --profile bench \
      --set batch_size=64 "${EXTRA[@]}" --threads 1 --json "$OUTDIR/$NAME.jsonl.part$BASHPID" >> "$OUTDIR/$NAME.log" 2>&1
done; }
EXTRA=("$@")
run cube,cylinder:0 capsule,bar:0 frustum,hex_prism:0 sphere,ellipsoid:0 &
run sphere,ellipsoid:1 frustum,hex_prism:1 capsule,bar:1 cube,cylinder:1 &
wait
cat "$OUTDIR/$NAME.jsonl.part"* > "$OUTDIR/$NAME.jsonl" && rm "$OUTDIR/$NAME.jsonl.part"*
