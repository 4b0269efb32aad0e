#!/usr/bin/env bash
# What a lent GPU machine runs (NVIDIA, CUDA; see docs/renderer.md "On a GPU"): the CUDA tests and the
# GPU benchmarks. That machine has its own Python with torch + CUDA and no registry access, so the few
# packages it lacks travel as wheels in .whl/ (gsplat 1.5.3, plyfile, trimesh, pyusb, libusb-package;
# `pip download --no-deps --only-binary=:all: --python-version 3.12 ...`), and the C++ extension is
# built there in place (.whl/ is gitignored: name it among the run's carried paths). Results go to $OUT
# (or bench/results/gpu when OUT is unset). On 2026-11-27 a fresh H200 ran all of it in 485 s (gsplat's
# CUDA build 99 s of it); the live-frame benchmark alone, on a warm machine, in 65 s.
set -uo pipefail
cd "$(dirname "$0")/.."
out="${OUT:-bench/results/gpu}"
mkdir -p "$out"
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "gpu_check: wheel install failed" >&2; exit 1; }
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1
nvidia-smi -L
python3 setup.py -q build_ext --inplace 2>&1 | tail -n 3
python3 - <<'PY'
import time
t = time.perf_counter()
from holo_viewer.render import gsplat_backend
print("gsplat available:", gsplat_backend.is_available(), f"({time.perf_counter() - t:.1f} s incl. its CUDA build)")
PY
# most important first: a lent machine's time is short (the run may be cut off; every step writes to $out)
python3 bench/live_frame.py --quick --device cuda --gpu-only --json "$out/live_frame_gpu.json" 2>&1 | tail -n 14
python3 -m pytest -q -p no:cacheprovider tests/test_render_torch.py tests/test_flame_model.py tests/test_live_frame.py \
  tests/test_view_synthesis.py -k "cuda or gsplat or device" 2>&1 | tee "$out/gpu_tests.log" | tail -n 15
python3 bench/render_gpu.py --json "$out/render_gpu.json" 2>&1 | tail -n 12
# the CPU path on this machine's cores: thread count x numba threading layer (docs/live_frame.md)
python3 bench/cpu_scaling.py --frames 3 --json "$out/cpu_scaling.json" 2>&1 | tail -n 20
