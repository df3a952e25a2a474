#!/bin/bash
# Builds .gpu/ (ignored by git): what the GPU machine's image lacks for the CUDA check (README.md beside this file).
#   .gpu/whl/   the project's pure-torch dependencies as CPython 3.12 wheels (pydantic, trimesh, mujoco, ...)
#   .gpu/site/  pybullet 3.2.7 built here for Python 3.12 (PyPI has no 3.12 wheel) and stripped (108 -> 8 MB),
#               the three pybullet_data meshes the object library uses, the Shadow Hand assets of the installed
#               gymnasium-robotics (read as the project reads them: never copied into the repo), and a prefect stand-in.
# Needs: the project's .venv (make install), a python3.12 with pip and a C++ compiler (~8 min to build pybullet).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
PY312=${PY312:-}
if [ -z "$PY312" ]; then  # the first Python 3.12 that runs (a pyenv shim may exist and fail)
  for c in python3.12 "$HOME"/.pyenv/versions/3.12*/bin/python; do
    if "$c" -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null; then PY312=$c; break; fi
  done
fi
[ -n "$PY312" ] || { echo "bundle.sh: no Python 3.12 found: set PY312=/path/to/python3.12" >&2; exit 2; }
SITE_PACKAGES=$("$ROOT/.venv/bin/python" -c "import site; print(site.getsitepackages()[0])")
OUTDIR="$ROOT/.gpu"
grep -qx "/.gpu/" "$ROOT/.git/info/exclude" 2>/dev/null || echo "/.gpu/" >> "$ROOT/.git/info/exclude"
rm -rf "$OUTDIR" && mkdir -p "$OUTDIR/whl" "$OUTDIR/site/pybullet_data" "$OUTDIR/build"
PLATFORMS=(--platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_24_x86_64
           --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any)
for spec in pydantic==2.14.4 pydantic_core==2.50.5 annotated-types==0.8.0 typing-inspection==0.4.5 \
            typing_extensions==4.16.0 trimesh==5.2.0 rtree==1.4.1 mujoco==3.11.0 PyOpenGL==3.1.10 glfw==2.11.0 \
            pytorch_kinematics==0.10.0 arm_pytorch_utilities==0.5.0 pytorch-seed==0.2.0; do
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    "${PLATFORMS[@]}" -d "$OUTDIR/whl" "$spec"
done
"$PY312" -m pip wheel -q pybullet==3.2.7 --no-deps -w "$OUTDIR/build"
(cd "$OUTDIR/build" && python3 -m zipfile -e pybullet-3.2.7-cp312-*.whl unpacked)
U="$OUTDIR/build/unpacked"
strip --strip-unneeded -o "$OUTDIR/site/pybullet.cpython-312-x86_64-linux-gnu.so" "$U"/pybullet.cpython-312-*.so
cp "$U/pybullet_data/__init__.py" "$U/pybullet_data/bunny.obj" "$U/pybullet_data/duck.obj" \
   "$U/pybullet_data/duck_vhacd.obj" "$OUTDIR/site/pybullet_data/"
GR="$SITE_PACKAGES/gymnasium_robotics/envs/assets"
mkdir -p "$OUTDIR/site/gymnasium_robotics/envs/assets/stls"
touch "$OUTDIR/site/gymnasium_robotics/__init__.py"
cp -r "$GR/hand" "$GR/textures" "$OUTDIR/site/gymnasium_robotics/envs/assets/"
cp -r "$GR/stls/hand" "$OUTDIR/site/gymnasium_robotics/envs/assets/stls/"
cp -r "$ROOT/benchmarks/gpu_check/standins/prefect" "$OUTDIR/site/"
rm -rf "$OUTDIR/build"
du -sh "$OUTDIR"
