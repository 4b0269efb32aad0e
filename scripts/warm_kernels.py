"""Compile and cache the numba kernels once, at set-up, instead of in the first test or demo that calls them.

Usage: python scripts/warm_kernels.py

numba caches compiled kernels beside their sources (``__pycache__/*.nbi, *.nbc``; ``cache=True``). A fresh clone
has none, so its first ``make test`` compiled ~50 kernel specialisations (about 20 s of CPU for the default
render path alone, and twice when two test workers reach a kernel at the same time). ``scripts/setup.sh`` runs
this script after an install: each step below calls one code path on a small input (the kernels' argument
types, not sizes, select what is compiled). A step that fails is reported and skipped (the kernel then
compiles on first use, as before); the script always exits 0 (tests/test_suite_tools.py runs the cheap steps).
The differentiable-renderer, reaction-metrics, cached-binding and float/partial interleave steps cost about 30 s
more of set-up CPU and save a fresh clone's make test their compilation (26 s of CPU for
test_render_differentiable.py + test_reaction_metrics.py with an empty numba cache vs a full one, load 12).
A full numba cache (after whole-suite runs) held 13 specialisations this script did not compile, so a fresh
clone's make test compiled them in its tests. The visibility, one-splat render, viewer-normals, exact-JVP blend,
strided to_uint8 and contiguous warp lines (about 27 s of CPU at load 15) compile 9 of them, the live-frames
step's numba eye-slice scatter a 10th (it had compiled nothing since group frames stopped drawing slices by
default). A fresh clone's make test at 318ae57 still compiled 6 (their cache files written during the tests): the
numba warp into a uint8 quilt, the numba uint8 row gather, the drawn-only deform's subset binding (since ebeddcc
bind_faces_nb, warmed by 6ababbc; bind_subset_nb stays the tests' reference) and the three float64 binding kernels;
the interleaver, live-frames and avatars steps compile them too. Those three steps with
the six kernels' caches removed (their float32 twins with them) 12.3 + 3.7 + 12.9 s of CPU, warm 4.3 + 2.1 + 5.2
(load 15): about 10-13 s of CPU off the tests, 7.7 of it the uint8 warp.
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
    """float -> uint8, and both interleave modes of the lenticular interleaver on uint8 and float32 quilts,
    whole and partial."""
    import numpy as np

    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.display.lenticular import Interleaver

    from holo_viewer.images import to_uint8

    for dtype in (np.float32, np.float64):  # its compiled pass, on both float types, into a new array and a tile
        to_uint8(np.zeros((4, 4, 3), dtype))
        to_uint8(np.zeros((4, 4, 3), dtype), out=np.zeros((4, 8, 3), np.uint8)[:, :4])
    cal = DisplayCalibration.load(None)
    for dtype in (np.uint8, np.float32):
        quilt = np.zeros((cal.quilt_height, cal.quilt_width, 3), dtype)
        for mode in ("nearest", "blend"):
            lin = Interleaver(cal, quilt.shape, mode=mode)
            out = lin(quilt)
            lin.update(quilt, out, np.arange(0, out.size, 97, dtype=np.int32))
            # the one-pass column update (tracked frames; its weights are read-only in nearest mode)
            nb = -(-(quilt.shape[1] // lin.cols) // 16)
            lin.update_columns(quilt, out, np.arange(lin.n_views * nb).reshape(lin.n_views, nb) % 5 == 0, block=16)
            if dtype == np.uint8 and mode == "nearest":  # the numba row gather (the C++ one is used when built;
                lin.row_kernel = "numba"  # test_display_lenticular.py compares the two)
                lin(quilt)


def _live_frames() -> None:
    """Tracked (eye slices) and all-views (synthesized views) live frames on a small random scene."""
    import numpy as np

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
        for mode in ("tracked", "eye_centred"):
            live.frame(g, eyes.TrackedViewer(2.0, 0.6), mode=mode)
    # the eye slices' reference: the moved splats written out (crossed_slit.transform_splats) and drawn by pinholes
    from holo_viewer.render import crossed_slit, fast
    from holo_viewer.render.config import RenderConfig

    rig = crossed_slit.slice_rig(cams, cal)
    es = crossed_slit.eye_slices(rig, eyes.eye_positions(eyes.TrackedViewer(6.0, 0.5)))
    ref = np.zeros((len(es), cams.height, cams.width, 3), np.float32)
    fast.render(g, cams, RenderConfig(), tile_mask=np.zeros((len(cams),) + fast.tile_grid(cams), bool),
                passes=crossed_slit.slice_pass(rig, es, ref))
    # view synthesis on a source stack that is not one contiguous block (its row-extent and warp kernels
    # specialise on the layout; tests pass such stacks)
    from holo_viewer.render import view_synthesis

    sources = view_synthesis.source_views(len(cams), 5)
    stack = np.zeros((sources.size, cams.height, cams.width, 4), np.float32)[..., :3]
    wmaps = np.ones((sources.size, cams.height, cams.width), np.float32)
    for st in (stack, np.ascontiguousarray(stack)):  # and on one block (the live renderer's)
        view_synthesis.warp_views(st, wmaps, sources, view_synthesis.rig_of(cams), iters=1,
                                  out=np.zeros((len(cams), cams.height, cams.width, 3), np.float32))
    # the numba warp straight into a uint8 quilt (the C++ one is used when built; tests compare the two)
    kernel, view_synthesis.WARP_KERNEL = view_synthesis.WARP_KERNEL, "numba"
    try:
        H, W = cams.height, cams.width
        view_synthesis.warp_views(np.ascontiguousarray(stack), wmaps, sources, view_synthesis.rig_of(cams),
                                  quilt=np.zeros((6 * H, 8 * W, 3), np.uint8),
                                  tiles=np.array([[(5 - k // 8) * H, (k % 8) * W] for k in range(len(cams))]))
    finally:
        view_synthesis.WARP_KERNEL = kernel
    # the eye slices' numba scatter (the C++ one is used when built; tests compare the two)
    from holo_viewer.display import slices

    cpp = slices._cpp
    slices._cpp = lambda: None  # noqa: E731 - for this step only
    try:
        # group frames draw eye slices only with group_slices > 0 (the default draws none since d087ac6, so this
        # step compiled nothing until the setting was given here)
        NativeFrameRenderer(cal, cams, NativeFrameConfig(group_slices=1)).frame(g, eyes.TrackedViewer(0.0, 0.6))
    finally:
        slices._cpp = cpp


def _avatars() -> None:
    """The rigged avatar's numba binding (with and without its cache, float32 and float64, all Gaussians or the
    drawn ones) and the blend-shape avatar's kernel."""
    import numpy as np
    import torch

    from holo_viewer.avatar import BlendshapeAvatar
    from holo_viewer.testing import random_flame_model, random_rigged_avatar

    model = random_flame_model(n_vertices=300, n_shape=8, n_expr=6, seed=1)
    rigged = random_rigged_avatar(model, n=400)
    verts = model(expr=torch.zeros(1, 6)).vertices
    rigged.deform(verts[0])
    rigged.deform(verts[0], cache=True, cache_tol=1e-4)
    rigged.deform(verts[0] + 0.01, cache=True, cache_tol=1e-4)
    BlendshapeAvatar.from_rigged(rigged).pose(torch.zeros(6))
    BlendshapeAvatar.from_rigged(rigged, exact_jvp=True).pose(torch.zeros(6))  # its per-Gaussian kernel
    # bind_subset_nb: the drawn deform's unfused reference (test_live_render_cpu.py checks bind_faces_nb by it)
    from holo_viewer.avatar import _bind_kernels, rigged as rigged_module

    faces, binding, mu, ql, ls = rigged._np_local()
    index = np.arange(0, len(binding), 3, dtype=np.int64)
    frame, _ = _bind_kernels.frames(verts[0].numpy(), faces, rigged_module.DEGENERATE_EPS)
    _bind_kernels.bind_subset_nb(frame, binding, mu, ql, ls, index,
                                 *(np.zeros((len(binding), c), np.float32) for c in (3, 4, 3)))
    # the binding kernels on a float64 model (test_avatar_binding.py checks them against float64 math)
    from holo_viewer.flame.model import FlameModel
    from holo_viewer.flame.synthetic import random_flame_arrays

    model64 = FlameModel.from_arrays(random_flame_arrays(n_vertices=300, n_shape=8, n_expr=6, seed=1),
                                     dtype=torch.float64)
    rigged64, v64 = random_rigged_avatar(model64, n=400), model64(expr=torch.zeros(1, 6, dtype=torch.float64)).vertices
    rigged64.deform(v64[0])
    rigged64.deform(v64[0], cache=True, cache_tol=1e-4)
    rigged64.deform(v64[0] + 0.01, cache=True, cache_tol=1e-4)
    # the live renderer's drawn-Gaussian deform (RiggedStage.drawn_deform: every other Gaussian here)
    import numpy as np

    from holo_viewer.pipeline.avatars import RiggedStage

    g = rigged.deform(verts[0])
    deform = RiggedStage(rigged).drawn_deform(np.arange(0, len(g), 2))
    if deform is not None:
        deform(verts[0].numpy(), g.replace(means=g.means.clone(), quats=g.quats.clone(), log_scales=g.log_scales.clone()))


def _visibility() -> None:
    """The visible-Gaussian mask's weight kernel, and the fast renderer's numba kernels on a one-splat view:
    its splat boxes are then one contiguous block, a second specialisation of four kernels (~8 s of CPU,
    which a fresh clone's make test paid in a test that renders a single splat)."""
    from bench.scenes import random_scene
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.display.cameras import make_quilt_cameras
    from holo_viewer.render import fast, visibility
    from holo_viewer.render.config import RenderConfig

    cal = DisplayCalibration.load(None).with_quilt(8, 6, 840, 840)
    cams = make_quilt_cameras(cal, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)
    visibility.max_weights(random_scene(500, degree=1, seed=0, extent=(0.1, 0.13, 0.06), scale_range=(-6.0, -4.5)),
                           cams)
    one = random_scene(1, degree=1, seed=0, extent=(0.01, 0.01, 0.01), scale_range=(-4.0, -4.0))
    fast.render(one, cams[[24]], RenderConfig(kernel="numba"))


def _viewer_normals() -> None:
    """The GUI viewer's vertex-normal kernel (needs the gui extra; skipped without it)."""
    import numpy as np

    from holo_viewer.gui.scene import live_vertex_normals

    live_vertex_normals(np.random.default_rng(0).random((5, 3)), np.array([[0, 1, 2], [2, 3, 4]]))


def _differentiable() -> None:
    """The differentiable renderer's forward and backward kernels, float64 and float32 (the avatar fit)."""
    import numpy as np
    import torch

    from holo_viewer.avatar.gaussians import Gaussians
    from holo_viewer.camera import Cameras, intrinsics, look_at
    from holo_viewer.render import differentiable as dr

    rng = np.random.default_rng(0)
    n = 50
    arrays = (rng.normal(0.0, 0.1, (n, 3)), rng.normal(size=(n, 4)), np.log(rng.uniform(0.1, 1.0, (n, 3)) * 0.04),
              rng.normal(1.0, 1.5, n), rng.normal(0.0, 0.4, (n, 4, 3)))
    cams = Cameras(look_at([0.0, 0.02, 0.9], [0.0, 0.0, 0.0])[None], intrinsics(55.0, 57.0, 20.0, 16.0)[None], 40, 32)
    for dtype in (torch.float64, torch.float32):
        params = [torch.tensor(a, dtype=dtype, requires_grad=True) for a in arrays]
        dr.render_gaussians(Gaussians(*params), cams).sum().backward()


def _metrics() -> None:
    """The reaction metrics' DTW (FRDist) and lagged-correlation (FRSyn) kernels."""
    import numpy as np

    from holo_viewer.reaction import metrics as M

    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        p, g, s = (rng.random(shape).astype(dtype) for shape in ((2, 2, 56, 25), (2, 56, 25), (2, 56, 25)))
        nb = np.ones((2, 2), np.int64)
        M.frdist(p, g, nb)
        M.frsyn(p, s)
        M.frsyn_robust(p, s)


def _tracker_fit() -> None:
    """The live tracker's compiled landmark fit (holo_viewer.tracking.fit_fast, ~6 s of CPU): without it cached a
    live session fits with the numpy reference and compiles it in a background child for the next one."""
    from holo_viewer.tracking.fit_fast import compile_kernel

    compile_kernel()


STEPS = (("default pipeline", _pipeline), ("interleaver", _interleave), ("live frames", _live_frames),
         ("avatars", _avatars), ("differentiable renderer", _differentiable), ("reaction metrics", _metrics),
         ("visibility", _visibility), ("viewer normals", _viewer_normals), ("tracker fit", _tracker_fit))


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
