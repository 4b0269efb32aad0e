"""Compile and cache the numba kernels once, at set-up, instead of in the first test or demo that calls them.

Usage: python scripts/warm_kernels.py

numba caches compiled kernels beside their sources (``__pycache__/*.nbi, *.nbc``; ``cache=True``). A fresh clone
has none, so its first ``make test`` compiled ~50 kernel specialisations (about 20 s of CPU for the default
render path alone, and twice when two test workers reach a kernel at the same time). ``scripts/setup.sh`` runs
this script after an install: each step below calls one code path on a small input (the kernels' argument
types, not sizes, select what is compiled). A step that fails is reported and skipped (the kernel then
compiles on first use, as before); the script always exits 0.
"""

from __future__ import annotations

import resource
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # bench.scenes


def _pipeline() -> None:
    """The default avatar through the fast renderer (C++ and numba kernels), the quilt and the native image."""
    from holo_viewer.pipeline import Pipeline
    from holo_viewer.render.config import RenderConfig
    from holo_viewer.render.fast import kernel_names

    pipe = Pipeline()
    pipe.native()
    for kernel in kernel_names():
        pipe.set_render(config=RenderConfig(kernel=kernel))
        pipe.render_view(24)


def _interleave() -> None:
    """Both interleave modes of the lenticular interleaver (live frames below reach its partial updates)."""
    import numpy as np

    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.display.lenticular import Interleaver

    cal = DisplayCalibration.load(None)
    quilt = np.zeros((cal.quilt_height, cal.quilt_width, 3), np.uint8)
    for mode in ("nearest", "blend"):
        lin = Interleaver(cal, quilt.shape, mode=mode)
        lin(quilt)


def _live_frames() -> None:
    """Tracked (eye slices) and all-views (synthesized views) live frames on a small random scene."""
    from bench.scenes import random_scene
    from holo_viewer.display import eyes
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.display.cameras import make_quilt_cameras
    from holo_viewer.pipeline.live import NativeFrameConfig, NativeFrameRenderer

    cal = DisplayCalibration.load(None).with_quilt(8, 6, 840, 840)
    cams = make_quilt_cameras(cal, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)
    g = random_scene(500, degree=1, seed=0, extent=(0.1, 0.13, 0.06), scale_range=(-6.0, -4.5))
    for blend in (False, True):
        live = NativeFrameRenderer(cal, cams, NativeFrameConfig(blend=blend))
        live.frame(g, eyes.TrackedViewer(0.0, 0.6))
        live.frame(g, eyes.TrackedViewer(3.0, 0.6))
        live.frame(g, mode="all_views")


def _avatars() -> None:
    """The rigged avatar's numba binding and the blend-shape avatar's kernel."""
    import torch

    from holo_viewer.avatar import BlendshapeAvatar
    from holo_viewer.testing import random_flame_model, random_rigged_avatar

    model = random_flame_model(n_vertices=300, n_shape=8, n_expr=6, seed=1)
    rigged = random_rigged_avatar(model, n=400)
    verts = model(expr=torch.zeros(1, 6)).vertices
    rigged.deform(verts[0])
    BlendshapeAvatar.from_rigged(rigged).pose(torch.zeros(6))


STEPS = (("default pipeline", _pipeline), ("interleaver", _interleave), ("live frames", _live_frames),
         ("avatars", _avatars))


def main() -> int:
    t0 = time.perf_counter()
    for name, step in STEPS:
        t = time.perf_counter()
        try:
            step()
            print(f"warm_kernels: {name}: {time.perf_counter() - t:.1f} s")
        except Exception as exc:  # noqa: BLE001 - best effort: the kernel compiles on first use instead
            print(f"warm_kernels: {name}: skipped ({type(exc).__name__}: {exc})")
            traceback.print_exc(limit=2)
    cpu = resource.getrusage(resource.RUSAGE_SELF)
    print(f"warm_kernels: {time.perf_counter() - t0:.1f} s wall, {cpu.ru_utime + cpu.ru_stime:.1f} s CPU")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
