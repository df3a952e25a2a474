#!/bin/bash
# On the GPU machine, from the repo root, with .gpu/ and .gpu_job/ carried (benchmarks/gpu_check/README.md, "A stage's
# generator trained on the GPU"): trains every exported .gpu_job/<name>/dataset.pt at once, one process each, and
# writes $OUT/<name>/generator.pt and $OUT/<name>.log.
set -u
OUT=${OUT:-gpu_job_out}; mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .gpu/whl/*.whl || exit 3
export PYTHONPATH=$PWD/.gpu/site:/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi -L | tee "$OUT/env.txt"
for data in .gpu_job/*/dataset.pt; do
  name=$(basename "$(dirname "$data")")
  python3 -m benchmarks.gpu_check.generator_job train --data "$data" --out "$OUT/$name" > "$OUT/$name.log" 2>&1 &
done
wait
tail -n 2 "$OUT"/*.log
