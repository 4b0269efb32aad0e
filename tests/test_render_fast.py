"""Fast multi-view rasterizer against the float64 reference (float32 vs float64).

Tolerances (stated once): on every view PSNR >= 50 dB and max |fast - reference| <= 0.01
(float32 compositing and the polynomial exp change alpha by < 2e-5 relative; a splat exactly at
the alpha threshold may flip, which moves a pixel by at most ~1/255 * colour; a pixel at the
termination threshold moves by < t_min, since the splat that ends it is blended). The reference honours every semantic knob, so knob
settings are compared like for like.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bench.scenes import quilt_cameras, random_scene, shell_scene  # the repository root is on sys.path (conftest)
from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.camera import Cameras, intrinsics, look_at
from holo_viewer.errors import RenderError
from holo_viewer.render import RenderConfig, render_views
from holo_viewer.render import fast

PSNR_MIN, MAX_ERR = 50.0, 0.01

#: "cpp" = the path chosen at run time; the suffixed ones force a C++ path where the CPU has it
KERNELS = ["numba"] + (["cpp", "cpp-scalar"] if fast.cpp_available() else [])
if fast.cpp_available() and fast._cpp().has_avx2():
    KERNELS.append("cpp-avx2")
if fast.cpp_available() and fast._cpp().has_avx512():
    KERNELS.append("cpp-avx512")
_MODES = {"cpp-scalar": 1, "cpp-avx2": 2, "cpp-avx512": 3}


def psnr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2, axis=(1, 2, 3))
    return 10 * np.log10(1.0 / np.maximum(mse, 1e-20))


def run_fast(g, cams, kernel: str, **cfg):
    mode = _MODES.get(kernel, 0)
    tile = cfg.get("tile_size", 16)
    if (kernel == "cpp-avx512" and tile != 16) or (kernel == "cpp-avx2" and tile % 8):
        mode = 0  # tile sizes a SIMD path does not take: the run-time choice
    old = fast._CPP_MODE
    fast._CPP_MODE = mode
    try:
        return render_views(g, cams, "fast", RenderConfig(kernel=kernel.split("-")[0], **cfg))
    finally:
        fast._CPP_MODE = old


#: float64 reference renders by their inputs' digest: every kernel of a case compares with the same
#: reference images, rendered once per case instead of once per kernel (the reference is deterministic)
_REFERENCES: dict[str, np.ndarray] = {}


def _digest(g, cams, cfg: dict) -> str:
    import hashlib

    h = hashlib.sha256(repr(sorted(cfg.items())).encode())
    gn = g.numpy()
    for a in (gn.means, gn.quats, gn.log_scales, gn.opacity_logits, gn.sh, cams.world_to_cam, cams.K):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype}{a.shape}".encode() + a.tobytes())
    h.update(repr((cams.width, cams.height, cams.near, cams.far)).encode())
    return h.hexdigest()


def reference(g, cams, **cfg) -> np.ndarray:
    """The float64 reference render (images) for ``cfg`` (tile_size is the fast renderer's alone)."""
    cfg = {k: v for k, v in cfg.items() if k != "tile_size"}
    key = _digest(g, cams, cfg)
    if key not in _REFERENCES:
        _REFERENCES[key] = render_views(g, cams, "reference", RenderConfig(**cfg)).images
    return _REFERENCES[key]


def check(g, cams, kernel: str, **cfg) -> None:
    ref = SimpleNamespace(images=reference(g, cams, **cfg))
    out = run_fast(g, cams, kernel, **cfg)
    assert out.images.shape == ref.images.shape and out.images.dtype == np.float32
    assert np.isfinite(out.images).all()
    p = psnr(out.images, ref.images)
    err = np.abs(out.images - ref.images).max()
    assert p.min() >= PSNR_MIN, f"PSNR per view {p}"
    assert err <= MAX_ERR, f"max abs error {err}"


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("n_views,size", [(1, (64, 48)), (3, (48, 64)), (5, (40, 56))])
@pytest.mark.parametrize("degree", [0, 1, 3])
def test_fast_matches_reference_random(kernel, n_views, size, degree):
    w, h = size
    cams = quilt_cameras(n_views, w, h, use_display=False)
    g = random_scene(300, degree=degree, seed=degree * 10 + n_views)
    check(g, cams, kernel)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bg", [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.2, 0.5, 0.9)])
def test_fast_matches_reference_shell_backgrounds(kernel, bg):
    cams = quilt_cameras(48, 48, 64, use_display=False)[[0, 20, 47]]
    g = shell_scene(3000, degree=2, seed=3)
    check(g, cams, kernel, background=bg)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("cfg", [
    dict(alpha_threshold=0.02), dict(radius_sigmas=2.0), dict(sh_degree=1), dict(shared_sh=True),
    dict(cull_margin=0.05), dict(tile_size=8), dict(tile_size=12), dict(tile_size=32),
    dict(alpha_cap=0.9, t_min=1e-3),
    dict(dilation=0.0), dict(near=1.2), dict(clip_output=False),
])
def test_fast_matches_reference_knobs(kernel, cfg):
    cams = quilt_cameras(6, 56, 40, use_display=False)
    g = random_scene(250, degree=3, seed=7)
    check(g, cams, kernel, **cfg)


@pytest.mark.parametrize("kernel", KERNELS)
def test_termination_tie_agrees_with_float64(kernel):
    """Opaque splats stacked on one pixel: alpha hits the 0.99 cap, so T after two of them is
    (1 - 0.99)^2 = t_min up to rounding (float64 1.0000000000000018e-4, float32 9.99998e-5): the
    float32 kernels and the float64 reference take different sides of the termination test. The
    splat that ends a pixel is blended (docs/renderer.md "Early termination"), so they still agree
    to < t_min; stopping before it would leave them ~0.99 * 0.01 apart."""
    from holo_viewer.avatar.gaussians import Gaussians

    n = 4
    means = np.array([[0.0, 0.0, 2.0 + 0.5 * i] for i in range(n)])
    cols = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]])
    sh = ((cols - 0.5) / 0.28209479177387814)[:, None, :]
    g = Gaussians.from_arrays(means, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.log(np.full((n, 3), 0.05)),
                              np.full(n, np.log(0.995 / 0.005)), sh)
    cams = Cameras(np.eye(4), intrinsics(40.0, 40.0, 10.5, 10.5), 21, 21, near=0.01, far=100.0)
    ref = render_views(g, cams, "reference", RenderConfig(background=(1.0, 1.0, 1.0))).images[0, 10, 10]
    got = run_fast(g, cams, kernel, background=(1.0, 1.0, 1.0)).images[0, 10, 10]
    assert ref[1] > 0.009  # the second splat (green) is in the picture
    np.testing.assert_allclose(got, ref, atol=2e-4)


@pytest.mark.parametrize("kernel", KERNELS)
def test_fast_cameras_with_different_orientations(kernel):
    K = intrinsics(60.0, 60.0, 32.0, 24.0)
    w2c = np.stack([look_at([0.3, 0.1, 1.0], [0, 0, 0]), look_at([-0.5, 0.2, 0.8], [0, 0, 0]),
                    look_at([0.0, -0.4, 0.9], [0, 0, 0])])
    cams = Cameras(w2c, np.broadcast_to(K, (3, 3, 3)), 64, 48)
    g = random_scene(300, degree=1, seed=11)
    check(g, cams, kernel)


@pytest.mark.parametrize("kernel", KERNELS)
def test_fast_chunking_is_exact(kernel):
    cams = quilt_cameras(12, 64, 48, use_display=False)
    g = random_scene(2000, degree=1, seed=5)
    a = run_fast(g, cams, kernel).images
    b = run_fast(g, cams, kernel, max_chunk_bytes=2**20).images  # ~7 views per chunk
    np.testing.assert_array_equal(a, b)


def test_fast_reports_timings_and_stats():
    cams = quilt_cameras(4, 64, 48, use_display=False)
    r = render_views(random_scene(200), cams, "fast")
    for k in ("validate", "preprocess", "sort", "project", "bin", "composite", "total"):
        assert r.timings[k] >= 0
    assert r.stats["n_input"] == 200 and 0 < r.stats["n_visible"] <= 200
    assert r.stats["mean_blends_per_pixel"] > 0
    assert r.backend.startswith("fast/")


def test_cpp_kernel_missing_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(fast, "_cpp", lambda: None)
    cams = quilt_cameras(2, 32, 24, use_display=False)
    with pytest.raises(RenderError, match="C\\+\\+ extension"):
        render_views(random_scene(20), cams, "fast", RenderConfig(kernel="cpp"))
    # "auto" falls back to numba
    assert render_views(random_scene(20), cams, "fast").backend == "fast/numba"


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
def test_cpp_forced_simd_path_for_other_tile_size_is_an_error():
    cams = quilt_cameras(2, 32, 24, use_display=False)
    old = fast._CPP_MODE
    fast._CPP_MODE = 3  # AVX-512 takes 16x16 tiles only
    try:
        with pytest.raises(RuntimeError, match="AVX-512 path unavailable"):
            render_views(random_scene(20), cams, "fast", RenderConfig(kernel="cpp", tile_size=8))
    finally:
        fast._CPP_MODE = old


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
@pytest.mark.parametrize("degree,shared,cull", [(0, False, -1.0), (1, False, -1.0), (3, False, 0.05),
                                                (2, True, -1.0)])
@pytest.mark.parametrize("threads,tile", [(1, 16), (2, 16), (5, 16), (2, 8), (2, 24)])
def test_cpp_project_bin_equals_numba(degree, shared, cull, threads, tile):
    """The fused C++ projection + binning gives numba's records, boxes and tile lists.

    Same float64 formulas in the same order (the extension is built with -ffp-contract=off):
    boxes and lists are identical, records equal to float32 rounding. 9001 splats make two
    segments of the splat range (one per 4096), each binned into every view by its own work
    unit (lists must stay in depth order across them); tile 24 takes the integer-division and
    per-row band path (no vectorised bands for non-power-of-two tiles).
    """
    from holo_viewer.render import fast_kernels as fk
    from holo_viewer.render.reference import view_colors

    cams_all = quilt_cameras(3, 96, 72, use_display=False)
    g = random_scene(9001, degree=3, seed=degree + 3).numpy()  # not a multiple of the 8-splat blocks
    views = np.arange(3)
    means = np.ascontiguousarray(g.means, dtype=np.float64)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64)))
    opacity[::50] = 0.001  # below the alpha threshold
    sh = np.ascontiguousarray(np.asarray(g.sh)[:, : (degree + 1) ** 2], dtype=np.float32)
    shared_rgb = view_colors(means, sh.astype(np.float64), degree, cams_all.positions.mean(axis=0)).astype(np.float32)
    pc, cov = fk.prep_3d(means, np.asarray(g.quats, np.float64), np.asarray(g.log_scales, np.float64),
                         np.ascontiguousarray(cams_all.R[0]))
    order = np.argsort(pc[:, 2], kind="stable").astype(np.int64)
    m, W, H, thr, near = order.size, 96, 72, 1 / 255, cams_all.near
    tx, ty = -(-W // tile), -(-H // tile)
    cams = fast._view_params(cams_all, views)
    rec, box = fast._records(3, m)
    seen = fk.project_views(order, pc, cov, means, opacity, sh, degree, shared_rgb, shared, cams, W, H, near, 0.3,
                            3.0, thr, cull, rec, box)
    off = fk.count_tiles(rec, box, tile, tx, ty)
    base = np.zeros(3, dtype=np.int64)
    base[1:] = np.cumsum(off[:-1, -1])
    ids = np.empty(int(off[:, -1].sum()), dtype=np.int32)
    fk.fill_tiles(rec, box, tile, tx, off, base, ids)

    rec2, box2 = fast._records(3, m)
    off2, base2, seen2 = np.empty_like(off), np.empty_like(base), np.empty(m, np.uint8)
    ins = fast._sorted_inputs(order, means, np.asarray(g.quats, np.float64), np.asarray(g.log_scales, np.float64),
                              opacity, shared_rgb if shared else sh, np.ascontiguousarray(cams_all.R[0]), thr)
    # the one-pass sorted copies are prep_3d's values gathered in depth order, bit for bit
    mp = ins[0].shape[1]
    assert np.array_equal(ins[0][:, :m], pc[order].T) and np.array_equal(ins[1][:, :m], cov[order].T)
    assert np.array_equal(ins[2][:, :m], means[order].T) and np.array_equal(ins[3][:m], opacity[order])
    assert not ins[0][:, m:].any() and not ins[3][m:].any() and mp % 8 == 0
    args = (*ins, cams, m, ins[3].size, 3, W, H, degree, int(shared), tile, tx, ty, near, 0.3, 3.0, thr, cull, rec2, off2, base2,
            seen2)
    small = np.empty(10, dtype=np.int32)
    total, _ = fast._cpp().project_bin(*args, small, threads)
    assert total == ids.size > small.size  # too small: the size comes back, nothing written past it
    ids2 = np.empty(total, dtype=np.int32)
    assert fast._cpp().project_bin(*args, ids2, threads)[0] == total
    assert np.array_equal(box, box2) and np.array_equal(seen, seen2)
    drawn = box[..., 0] < box[..., 1]
    assert drawn.sum() > 2000
    # the scene reaches both binning paths: boxes over at most 2 x 2 tiles (one and two tile
    # columns: the branch-free path when the tile is a power of two) and larger ones (entries_of)
    b = box[drawn]
    span_x, span_y = (b[:, 1] - 1) // tile - b[:, 0] // tile + 1, (b[:, 3] - 1) // tile - b[:, 2] // tile + 1
    in4 = (span_x <= 2) & (span_y <= 2)
    assert (in4 & (span_x == 1)).sum() > 100 and (in4 & (span_x == 2) & (span_y == 2)).sum() > 100
    assert (~in4).sum() > 100
    np.testing.assert_allclose(rec2[..., :10][drawn], rec[..., :10][drawn], rtol=1e-6, atol=1e-6)
    assert np.array_equal(off, off2) and np.array_equal(base, base2) and np.array_equal(ids, ids2)


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
def test_fast_renders_from_two_threads_at_once():
    """Concurrent renders: one takes the shared buffers, the other its own; both are right."""
    from concurrent.futures import ThreadPoolExecutor

    cams = quilt_cameras(6, 64, 48, use_display=False)
    scenes = [random_scene(3000, degree=1, seed=s) for s in (1, 2)]
    expected = [render_views(s, cams, "fast").images for s in scenes]
    with ThreadPoolExecutor(2) as pool:
        for _ in range(3):
            got = list(pool.map(lambda s: render_views(s, cams, "fast").images, scenes))
            for a, b in zip(got, expected):
                np.testing.assert_array_equal(a, b)


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
def test_release_buffers_then_render_again():
    cams = quilt_cameras(3, 64, 48, use_display=False)
    g = random_scene(500, degree=1, seed=4)
    a = render_views(g, cams, "fast").images
    cpp = fast._cpp()
    assert fast._SHARED_WORKSPACE._rec.size > 0 and cpp.scratch_bytes() > 0
    fast.release_buffers()
    assert fast._SHARED_WORKSPACE._rec.size == 0 and fast._SHARED_WORKSPACE._ids.size == 0
    assert fast._SHARED_WORKSPACE.depth_hints == {}
    assert fast._OUTPUTS.nbytes() == 0 and cpp.scratch_bytes() == 0
    np.testing.assert_array_equal(render_views(g, cams, "fast").images, a)


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
def test_radix_argsort_is_numpys_stable_argsort():
    """_splat_cpp.argsort_stable (LSD radix on the depths' bits) = numpy's stable argsort,
    ties (-0.0 and +0.0 among them) in index order, over magnitudes, signs, infinities,
    subnormals, NaN of either sign (last) and digits shared by every key (skipped passes)."""
    cpp = fast._cpp()
    rng = np.random.default_rng(11)
    cases = [rng.normal(size=20000), rng.uniform(0.4, 0.9, 30000), np.round(rng.uniform(-1, 1, 9000), 2),
             np.array([0.0, -0.0, 1.0, -1.0, -0.0, 0.0, np.inf, -np.inf, 5e-324, -5e-324, 1e308, -1e-308]),
             np.array([np.nan, 2.0, -np.nan, -np.inf, np.nan, np.inf, 0.5, -np.nan]),
             rng.choice([1.5, -2.25, 1e-300], 5000), np.full(100, 0.7), np.zeros(0), np.array([3.0]),
             np.ldexp(rng.uniform(1, 2, 8000), rng.integers(-1070, 1020, 8000)) * rng.choice([-1, 1], 8000)]
    for z in cases:
        got = np.full(z.size, -1, dtype=np.int64)
        cpp.argsort_stable(np.ascontiguousarray(z), got)
        np.testing.assert_array_equal(got, np.argsort(z, kind="stable"))


@pytest.mark.parametrize("radix", [True, False])
def test_depth_order_is_the_stable_sort_whatever_the_hint(radix, monkeypatch):
    if radix and not fast.cpp_available():
        pytest.skip("C++ extension not built")
    if not radix:  # numpy's timsort through the hint
        monkeypatch.setattr(fast, "_cpp", lambda: None)
    rng = np.random.default_rng(3)
    z = np.round(rng.normal(1.0, 0.2, 5000), 2)  # many equal depths
    z[:50] = -0.0
    z[50:100] = 0.0  # -0 and +0 are equal depths too
    keep = rng.random(z.size) > 0.2
    want = np.flatnonzero(keep)[np.argsort(z[keep], kind="stable")]
    order, full = fast.depth_order(z, keep)
    np.testing.assert_array_equal(order, want)
    moved = z + rng.normal(0.0, 1e-3, z.size) * (rng.random(z.size) < 0.1)
    want_moved = np.flatnonzero(keep)[np.argsort(moved[keep], kind="stable")]
    for hint in (full, rng.permutation(z.size), full[::-1].copy(), np.arange(7)):
        np.testing.assert_array_equal(fast.depth_order(z, keep, hint)[0], want)
        got, nxt = fast.depth_order(moved, keep, hint)
        np.testing.assert_array_equal(got, want_moved)
        np.testing.assert_array_equal(np.sort(nxt), np.arange(z.size))


def test_render_after_another_frame_equals_a_fresh_render():
    """The last depth order is kept as the next render's sort hint; the images do not depend on it."""
    cams = quilt_cameras(3, 64, 48, use_display=False)
    g0 = random_scene(3000, degree=1, seed=8)
    g1 = random_scene(3000, degree=1, seed=9)  # same size, other depths
    fast.release_buffers()
    assert fast._SHARED_WORKSPACE.depth_hints == {}
    want = render_views(g1, cams, "fast").images.copy()
    render_views(g0, cams, "fast")
    assert len(fast._SHARED_WORKSPACE.depth_hints) == 1
    np.testing.assert_array_equal(render_views(g1, cams, "fast").images, want)


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
def test_kept_binning_scratch_never_leaks_between_renders():
    """The C++ binning scratch is kept between calls: a render after a larger or smaller one
    (more or fewer views, splats and tiles) gives the same images as in a fresh process state."""
    big = (random_scene(9000, degree=1, seed=21), quilt_cameras(7, 96, 80, use_display=False))
    small = (random_scene(300, degree=0, seed=22), quilt_cameras(2, 40, 24, use_display=False))
    fast.release_buffers()
    want_big = render_views(*big, "fast").images.copy()
    fast.release_buffers()
    want_small = render_views(*small, "fast").images.copy()
    for g, cams, want in (big + (want_big,), small + (want_small,), big + (want_big,)):
        np.testing.assert_array_equal(render_views(g, cams, "fast").images, want)


@pytest.mark.parametrize("kernel", KERNELS)
def test_output_memory_is_recycled_only_when_nothing_refers_to_it(kernel):
    """A dropped result's memory serves the next render of that size; a result (or any view of
    it) still held is never written again."""
    cams = quilt_cameras(3, 64, 48, use_display=False)
    g1, g2 = random_scene(800, degree=1, seed=5), random_scene(800, degree=1, seed=6)
    fast.release_buffers()
    want1 = run_fast(g1, cams, kernel).images.copy()
    want2 = run_fast(g2, cams, kernel).images.copy()
    assert not np.array_equal(want1, want2)
    first = run_fast(g1, cams, kernel).images
    ptr = first.ctypes.data
    view = first[1, 10:20]  # a view keeps the memory of `first` alive
    del first
    second = run_fast(g2, cams, kernel).images
    assert second.ctypes.data != ptr
    np.testing.assert_array_equal(view, want1[1, 10:20])
    np.testing.assert_array_equal(second, want2)
    held = fast._OUTPUTS.nbytes()
    del view  # now nothing refers to the first result's memory: the next render reuses it
    assert fast._OUTPUTS.nbytes() == held + want1.nbytes
    third = run_fast(g1, cams, kernel).images
    assert third.ctypes.data == ptr
    np.testing.assert_array_equal(third, want1)
    np.testing.assert_array_equal(second, want2)


@pytest.mark.skipif(not fast.cpp_available(), reason="C++ extension not built")
def test_float32_inputs_render_as_their_exact_float64_widening():
    """The C++ depth-ordered copies read float32 Gaussians as they are (no float64 copy first): the
    widening is exact, so the images are those of the same values given as float64, bit for bit."""
    g = random_scene(2000, degree=1, seed=11).numpy()
    g32 = Gaussians(*(np.asarray(getattr(g, f), np.float32) for f in ("means", "quats", "log_scales",
                                                                       "opacity_logits", "sh")))
    g64 = Gaussians(*(np.asarray(getattr(g32, f), np.float64) for f in ("means", "quats", "log_scales",
                                                                        "opacity_logits", "sh")))
    cams = quilt_cameras(4, 64, 48, use_display=False)
    a = render_views(g32, cams, "fast").images
    b = render_views(g64, cams, "fast").images
    np.testing.assert_array_equal(a, b)
    c = render_views(g64, cams, "fast", RenderConfig(kernel="numba")).images
    np.testing.assert_allclose(a, c, atol=1e-4)


def test_sigmoid_cached_equals_the_formula_and_follows_the_logits():
    """fast.sigmoid_cached (live frames' opacities): the formula's values bit for bit on the first call, from the
    cache and after the logits change in place (same shape); the array returned is the caller's own."""
    from holo_viewer.render.fast import sigmoid_cached

    rng = np.random.default_rng(41)
    logits = rng.normal(0.0, 3.0, 1001).astype(np.float32)

    def want() -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-np.asarray(logits, dtype=np.float64)))

    a = sigmoid_cached(logits)
    np.testing.assert_array_equal(a, want())
    a[:] = -1.0  # the caller's copy: the cache keeps its own
    np.testing.assert_array_equal(sigmoid_cached(logits), want())
    logits[7] += 1.0  # changed in place: recomputed
    np.testing.assert_array_equal(sigmoid_cached(logits), want())
    np.testing.assert_array_equal(sigmoid_cached(logits[:500]), 1.0 / (1.0 + np.exp(-logits[:500].astype(np.float64))))
