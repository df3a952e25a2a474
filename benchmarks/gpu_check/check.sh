#!/bin/bash
# The CUDA check (benchmarks/gpu_check/README.md). Runs on the GPU machine from the repo root, with .gpu/ (made by
# benchmarks/gpu_check/bundle.sh) carried; writes its JSON and logs under $OUT (default: gpu_check_out).
set -u
OUT=${OUT:-gpu_check_out}; mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .gpu/whl/*.whl || exit 3
export PYTHONPATH=$PWD/.gpu/site:/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi -L
python3 -c "import torch, sys; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name())" | tee $OUT/env.txt
python3 -m pytest -q -p no:cacheprovider -o addopts="" \
  tests/test_objects_sdf.py::test_sdf_on_cuda_matches_cpu tests/test_pointnet.py::test_cuda_pretraining_and_load \
  tests/test_generation_networks.py::test_generator_trains_and_samples_on_cuda tests/test_generation_hand.py 2>&1 | tee $OUT/pytest.log | tail -8
B="python3 -m flows.cli bench generation --device cuda --repeats 5"
$B --json $OUT/bench_generation_cuda.json | head -8
$B --set refine.fc_steps=0 --json $OUT/bench_generation_cuda_nofc.json | head -8
$B --profile paper --json $OUT/bench_generation_cuda_paper.json | head -8
timeout 240 python3 -m flows.cli bench synthesis --device cuda --repeats 7 --json $OUT/bench_synthesis_cuda.json | head -12
echo done
