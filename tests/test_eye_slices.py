"""Tracked frames from eye slices: the crossed-slit eye images (holo_viewer.render.crossed_slit),
the renderer's passes that draw them, and the warp into the native subpixels an eye receives
(holo_viewer.display.slices).

Tolerances (stated once):
* a slice column is the projection of the quilt camera the eye looks through there: the slit
  projection of a point equals that camera's pinhole projection to 1e-9 px (float64);
* a moved centre projects (pinhole) to the slit column to 1e-9 px and its covariance is the
  slit projection's Jacobian footprint to 1e-9 relative (finite differences to 1e-6);
* a point seen in view k lands, through the warp formula with its true inverse depth, on its
  slice column to 1e-9 px;
* a rendered slice equals, column by column, the render of each column's own quilt camera above
  35 dB on a scene of small splats (measured 38-44 dB; EWA's first-order footprint differs from
  the per-column camera's only by the camera change across a splat);
* a render's passes leave its views bit-identical, and an identity pass equals the pinhole
  render of its camera to 1e-5 (colours evaluated outside the kernel: float rounding);
* the numba, C++ scalar and C++ AVX-512 scatter kernels agree bit for bit;
* the written subpixels include every subpixel whose light weight exceeds the threshold at an
  eye anywhere inside the motion margin (VirtualDisplay.weights), exactly;
* a tracked slices frame is above 40 dB per eye against the full quilt path on random scenes
  (measured 46-51 dB on the Portrait's panel, 46-48 on PANEL, where these tests run: its pixels 4x
  coarser; a stale frame gives 20 dB); the default avatar's figures are in docs/live_frame.md.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.scenes import random_scene  # noqa: E402
from holo_viewer.avatar.gaussians import Gaussians  # noqa: E402
from holo_viewer.display import eyes  # noqa: E402
from holo_viewer.display.calibration import DisplayCalibration  # noqa: E402
from holo_viewer.display.cameras import make_quilt_cameras  # noqa: E402
from holo_viewer.display.lenticular import Interleaver  # noqa: E402
from holo_viewer.display.simulate import VirtualDisplay  # noqa: E402
from holo_viewer.display.slices import scatter_slices, subpixel_buckets  # noqa: E402
from holo_viewer.display.slices import cpp_available as slices_cpp_available  # noqa: E402
from holo_viewer.errors import InputError, RenderError  # noqa: E402
from holo_viewer.pipeline.live import NativeFrameConfig, NativeFrameRenderer  # noqa: E402
from holo_viewer.render import RenderConfig, crossed_slit as cs, fast  # noqa: E402
from holo_viewer.render.reference import view_colors  # noqa: E402

CAL = DisplayCalibration.load(None)
SMALL = CAL.with_quilt(8, 6, 840, 840)  # same optics, 105 x 140 tiles
# the same panel (physical size, lenticular pitch and slope, cone) with 4x coarser pixels: 384 x 512 at a quarter of
# the DPI (1/16 of the subpixels, 4.7 subpixels a lens instead of 18.6), for the scatter kernels' exactness and
# coverage tests and the tracked frames against the full path, which hold for any panel whose interleaver, eye
# bounds, slice rig and VirtualDisplay share one calibration (the Portrait's panel: test_live_group.py's slices)
PANEL = dataclasses.replace(SMALL, screen_w=384, screen_h=512, dpi=SMALL.dpi / 4)


@pytest.fixture(scope="module")
def cams():
    return make_quilt_cameras(SMALL, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)


@pytest.fixture(scope="module")
def rig(cams):
    return cs.slice_rig(cams, SMALL)


@pytest.fixture(scope="module")
def panel_rig(cams):
    """The slice rig of PANEL (the quilt cameras are SMALL's: the same aspect, cone and physical width)."""
    return cs.slice_rig(cams, PANEL)


def _scene(seed: int, n: int = 2500, log_scale: tuple[float, float] = (-6.0, -4.0)) -> Gaussians:
    return random_scene(n, degree=1, seed=seed, extent=(0.1, 0.13, 0.06), scale_range=log_scale)


def _rig_frame(rig, means):
    p = means @ rig.R.T
    return p[:, 0], p[:, 1] + rig.ty, p[:, 2] + rig.tz


# ----------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("angle,distance", [(0.0, 0.6), (12.0, 0.45), (-7.0, 0.9)])
def test_slice_column_is_the_projection_of_the_camera_looked_through(rig, angle, distance):
    rng = np.random.default_rng(0)
    means = rng.normal(scale=0.05, size=(200, 3))
    X, Y, Z = _rig_frame(rig, means)
    for eye in cs.eye_slices(rig, eyes.eye_positions(eyes.TrackedViewer(angle, distance))):
        xi = cs.slice_columns(rig, eye, X, Z)
        assert np.isfinite(xi).all()
        for i in range(0, 200, 37):
            cam = cs.column_camera(rig, eye, xi[i])
            pc = cam.world_to_cam[0, :3, :3] @ means[i] + cam.world_to_cam[0, :3, 3]
            u = cam.K[0, 0, 0] * pc[0] / pc[2] + cam.K[0, 0, 2]
            assert abs(u - xi[i]) < 1e-9
        # on the focal plane every camera sees a point in the same column: the slice agrees with view 0
        Zf = np.full(5, 1.0 / rig.w_zero)
        Xf = np.linspace(-0.03, 0.03, 5)
        u0 = rig.fx * (Xf + rig.tx[0]) / Zf + rig.cx[0]
        np.testing.assert_allclose(cs.slice_columns(rig, eye, Xf, Zf), u0, atol=1e-9)
    # each native column's slice column looks through the camera of the view coordinate the eye has there
    viewer = eyes.TrackedViewer(angle, distance)
    t = eyes.eye_view_coordinates(SMALL, viewer, len(rig.tx))
    x_native = (np.arange(SMALL.screen_w) + 0.5) / SMALL.screen_w * rig.width
    for e, eye in enumerate(cs.eye_slices(rig, eyes.eye_positions(viewer))):
        alpha = np.radians((t[e] / (len(rig.tx) - 1) - 0.5) * SMALL.view_cone)
        np.testing.assert_allclose(eye.A + eye.B * x_native, np.tan(alpha), atol=1e-12)


def test_transform_moves_centres_and_covariances_to_the_slit_footprint(rig):
    g = _scene(1, 300)
    gn = g.numpy()
    splats = _sorted_splats(g, rig)
    both = cs.eye_slices(rig, eyes.eye_positions(eyes.TrackedViewer(5.0, 0.55)))
    eye = both[1]
    pcs, covs, cols = cs.transform_splats(rig, both, splats)
    pc, cov, col = pcs[1], covs[1], cols[1]
    m = splats.m
    order = splats.order
    X, Y, Z = _rig_frame(rig, np.asarray(gn.means, np.float64)[order])
    xi = cs.slice_columns(rig, eye, X, Z)
    u = rig.fx * pc[0, :m] / (pc[2, :m] + rig.tz) + rig.cxm
    np.testing.assert_allclose(u, xi, atol=1e-9)
    np.testing.assert_array_equal(pc[2, :m], splats.pc[2, :m])  # the depth, so the order, is kept
    # footprint: J_pinhole(moved) J_move = J_slit, checked through the 2x2 screen covariance
    for i in range(0, m, 29):
        Zi = Z[i]
        Xp = pc[0, i]
        Jp = np.array([[rig.fx / Zi, 0.0, -rig.fx * Xp / Zi ** 2], [0.0, rig.fy / Zi, -rig.fy * pc[1, i] / Zi ** 2]])
        # pc[1] is the rotated y without ty: the camera adds ty
        Jp[1, 2] = -rig.fy * (pc[1, i] + rig.ty) / Zi ** 2
        C = _cov3(cov[:, i])
        screen = Jp @ C @ Jp.T
        h = 1e-6  # the slit projection's Jacobian by central differences
        f = lambda x, z: cs.slice_columns(rig, eye, np.array([x]), np.array([z]))[0]  # noqa: E731
        Js = np.array([[(f(X[i] + h, Zi) - f(X[i] - h, Zi)) / (2 * h), 0.0, (f(X[i], Zi + h) - f(X[i], Zi - h)) / (2 * h)],
                       [0.0, rig.fy / Zi, -rig.fy * Y[i] / Zi ** 2]])
        C0 = _cov3(splats.cov[:, i])
        np.testing.assert_allclose(screen, Js @ C0 @ Js.T, rtol=1e-6, atol=1e-9 * np.abs(screen).max())
    # colours: SH seen from the camera of the centre's column
    s = eye.A + eye.B * xi
    for i in range(0, m, 41):
        cam = cs.column_camera(rig, eye, xi[i])
        sh = np.asarray(gn.sh, np.float64)[order[i]][None]
        want = view_colors(np.asarray(gn.means, np.float64)[order[i]][None], sh, 1, cam.positions[0])[0]
        np.testing.assert_allclose(col[:, i], want, atol=1e-6)
        assert abs(s[i] - (eye.A + eye.B * xi[i])) == 0.0


def _cov3(c):
    return np.array([[c[0], c[1], c[2]], [c[1], c[3], c[4]], [c[2], c[4], c[5]]])


def _sorted_splats(g, rig):
    gn = g.numpy()
    means = np.asarray(gn.means, np.float64)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(gn.opacity_logits, np.float64)))
    from holo_viewer.render import fast_kernels as fk

    z = fk.depth_z(means, rig.R)
    order = np.argsort(z, kind="stable").astype(np.int64)
    sh = np.ascontiguousarray(np.asarray(gn.sh, np.float32))
    ins = fast._sorted_inputs(order, means, np.asarray(gn.quats, np.float64), np.asarray(gn.log_scales, np.float64),
                              opacity, sh, rig.R, 1 / 255)
    return fast.SortedSplats(pc=ins[0], cov=ins[1], means=ins[2], opacity=ins[3], sh=ins[5], degree=gn.sh_degree,
                             order=order)


def test_warp_formula_maps_a_view_pixel_to_its_slice_column(rig):
    rng = np.random.default_rng(2)
    means = rng.normal(scale=0.05, size=(100, 3))
    X, _, Z = _rig_frame(rig, means)
    es = cs.eye_slices(rig, eyes.eye_positions(eyes.TrackedViewer(-4.0, 0.7)))
    kv, gh = cs.warp_coefficients(rig, es)
    for e, eye in enumerate(es):
        xi = cs.slice_columns(rig, eye, X, Z)
        for k in (0, 17, len(rig.tx) - 1):
            u = rig.fx * (X + rig.tx[k]) / Z + rig.cx[k]  # continuous column in view k
            w = 1.0 / Z
            back = (u + kv[e, k, 0] + kv[e, k, 1] * w) / (gh[e, 0] + gh[e, 1] * w)
            np.testing.assert_allclose(back, xi, atol=1e-9)


def test_slice_rig_refuses_other_cameras(cams):
    from holo_viewer.camera import Cameras
    import dataclasses

    w2c = np.array(cams.world_to_cam)
    w2c[3, 1, 3] += 0.01  # one camera moved up: not a horizontal rig
    with pytest.raises(InputError, match="horizontal rig"):
        cs.slice_rig(Cameras(w2c, cams.K, cams.width, cams.height, cams.near, cams.far), SMALL)
    with pytest.raises(InputError, match="affine"):  # another panel's cone: not its quilt cameras
        cs.slice_rig(cams, dataclasses.replace(SMALL, view_cone=30.0))
    with pytest.raises(InputError, match="slices"):
        NativeFrameRenderer(SMALL, Cameras(w2c, cams.K, cams.width, cams.height, cams.near, cams.far),
                     NativeFrameConfig(tracked="slices"))
    with pytest.raises(InputError, match="tracked"):
        NativeFrameConfig(tracked="eyes")
    # not a rig: the default falls back to the exact bands
    live = NativeFrameRenderer(SMALL, Cameras(w2c, cams.K, cams.width, cams.height, cams.near, cams.far))
    assert live.tracked_method == "bands"


# ----------------------------------------------------------------------------- rendering
def test_rendered_slice_matches_each_columns_own_camera(cams, rig):
    g = _scene(3, 4000, log_scale=(-6.5, -5.0))
    viewer = eyes.TrackedViewer(6.0, 0.5)
    es = cs.eye_slices(rig, eyes.eye_positions(viewer))
    out = np.zeros((len(es), cams.height, cams.width, 3), np.float32)
    tm = np.zeros((len(cams),) + fast.tile_grid(cams), bool)
    fast.render(g, cams, RenderConfig(), tile_mask=tm, passes=cs.slice_pass(rig, es, out))
    for e, eye in enumerate(es):
        got, want = [], []
        for c in range(10, cams.width - 10, 9):
            col = fast.render(g, cs.column_camera(rig, eye, c + 0.5), RenderConfig()).images[0, :, c]
            got.append(out[e, :, c])
            want.append(col)
        got, want = np.array(got), np.array(want)
        assert np.abs(want).max() > 0.1  # the scene is in the picture
        assert eyes.psnr(want, got) > 35.0


def test_slit_views_are_the_moved_splats_drawn_by_pinholes(cams, rig):
    """The in-kernel crossed-slit views (the live path) against the moved splats written out and
    drawn by pinholes (SplatPass): bit for bit in C++; numba's kernels to the compositors' 1e-4.
    Views rendered in the same pass keep their exact tiles."""
    g = _scene(3, 4000)
    es = cs.eye_slices(rig, eyes.eye_positions(eyes.TrackedViewer(6.0, 0.5)))
    tm = np.zeros((len(cams),) + fast.tile_grid(cams), bool)
    ref = np.zeros((2, cams.height, cams.width, 3), np.float32)
    fast.render(g, cams, RenderConfig(), tile_mask=tm, passes=cs.slice_pass(rig, es, ref))
    assert ref.max() > 0.5
    got = np.zeros_like(ref)
    tm[5, :, 2:4] = True  # and two tile columns of view 5 in the same pass
    views = np.zeros((len(cams), cams.height, cams.width, 3), np.float32)
    res = fast.render(g, cams, RenderConfig(), tile_mask=tm, out=views, slits=cs.slit_views(rig, es, got))
    if fast.cpp_available():
        np.testing.assert_array_equal(got, ref)
    else:
        np.testing.assert_allclose(got, ref, atol=1e-4)
    full = fast.render(g, cams, RenderConfig()).images
    px = np.repeat(np.repeat(tm, 16, axis=1), 16, axis=2)[:, :cams.height, :cams.width]
    np.testing.assert_array_equal(views[px], full[px])
    assert res.stats["rendered_tiles"] == tm.sum()
    nb = np.zeros_like(ref)
    fast.render(g, cams, RenderConfig(kernel="numba"), tile_mask=tm, slits=cs.slit_views(rig, es, nb))
    np.testing.assert_allclose(nb, ref, atol=1e-4)
    with pytest.raises(RenderError, match="SlitViews.out"):
        fast.render(g, cams, RenderConfig(), slits=fast.SlitViews(cs.slice_cameras(rig, 2), np.zeros((2, 13)), got[:1]))
    # their own early termination: a pixel stops after T < t_min, so it moves by less than t_min
    loose = np.zeros_like(ref)
    fast.render(g, cams, RenderConfig(), tile_mask=tm, slits=cs.slit_views(rig, es, loose, t_min=3e-3))
    assert 0 < np.abs(loose - ref).max() < 3e-3 + 1e-4 + 1e-6
    with pytest.raises(RenderError, match="t_min"):
        fast.render(g, cams, RenderConfig(), slits=cs.slit_views(rig, es, loose, t_min=0.7))
    with pytest.raises(RenderError, match="params"):
        fast.render(g, cams, RenderConfig(), slits=fast.SlitViews(cs.slice_cameras(rig, 2), np.zeros((2, 12)), got))


def test_passes_leave_the_views_and_an_identity_pass_is_the_pinhole(cams):
    g = _scene(4, 1500)
    gn = g.numpy()
    sub = cams[[3, 4]]
    plain = fast.render(g, sub, RenderConfig()).images.copy()
    k = 1  # an identity pass with the colours seen from camera k
    pos = sub.positions[k]

    def identity(splats):
        means = splats.means[:, :splats.m].T
        col = np.zeros((3, splats.pc.shape[1]), np.float32)
        sh = np.asarray(gn.sh, np.float64)[splats.order]
        col[:, :splats.m] = view_colors(means, sh, gn.sh_degree, pos).T
        return splats.pc, splats.cov, col

    out = np.zeros((1, sub.height, sub.width, 3), np.float32)
    res = fast.render(g, sub, RenderConfig(), passes=[fast.SplatPass(cameras=sub[[k]], transform=identity, out=out)])
    np.testing.assert_array_equal(res.images, plain)
    np.testing.assert_allclose(out[0], plain[k], atol=1e-5)
    assert "passes" in res.timings
    # no view rendered at all: the pass still runs
    out2 = np.zeros_like(out)
    tm = np.zeros((2,) + fast.tile_grid(sub), bool)
    fast.render(g, sub, RenderConfig(), tile_mask=tm, passes=[fast.SplatPass(sub[[k]], identity, out2)])
    np.testing.assert_array_equal(out2, out)
    # numba kernels: the same pass
    out3 = np.zeros_like(out)
    fast.render(g, sub, RenderConfig(kernel="numba"), passes=[fast.SplatPass(sub[[k]], identity, out3)])
    np.testing.assert_allclose(out3, out, atol=1e-5)
    with pytest.raises(RenderError, match="out"):
        fast.render(g, sub, RenderConfig(), passes=[fast.SplatPass(sub[[k]], identity, out[..., :2])])
    with pytest.raises(RenderError, match="transform"):
        fast.render(g, sub, RenderConfig(), passes=[fast.SplatPass(sub[[k]], lambda s: (s.pc,), out)])
    with pytest.raises(RenderError, match="rotation"):
        turned = np.array(sub.world_to_cam[[0]])
        turned[0, :3, :3] = turned[0, :3, :3] @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        from holo_viewer.camera import Cameras

        fast.render(g, sub, RenderConfig(), passes=[fast.SplatPass(
            Cameras(turned, sub.K[[0]], sub.width, sub.height, sub.near, sub.far), identity, out)])


# ----------------------------------------------------------------------------- into the native image
_BUCKETS: dict = {}


def _buckets(mode: str):
    """The interleaver and subpixel buckets of PANEL in ``mode``, built once per module."""
    if mode not in _BUCKETS:
        il = Interleaver(PANEL, (840, 840, 3), mode=mode)
        _BUCKETS[mode] = il, subpixel_buckets(il, 48, 140, 105)
    return _BUCKETS[mode]


@pytest.fixture(scope="module", params=["nearest", "blend"])
def buckets(request):
    return _buckets(request.param)


@pytest.fixture(scope="module")
def panel_display():
    return VirtualDisplay(PANEL)


def _tables(rig, viewer, seed, mode, motion=0.01):
    """PANEL's eye segments and bounds, random slice images and inverse depths, and ``rig``'s (PANEL's) warp."""
    rng = np.random.default_rng(seed)
    es = cs.eye_slices(rig, eyes.eye_positions(viewer))
    H, W = rig.height, rig.width
    yy, xx = np.mgrid[0:H, 0:W]
    imgs = np.stack([np.stack([0.5 + 0.4 * np.sin(xx / (3 + e + c) + rng.uniform(0, 6)) * np.cos(yy / 7)
                               for c in range(3)], -1) for e in range(len(es))]).astype(np.float32)
    wm = (rig.w_zero + 0.05 * np.sin(xx / 11.0 + yy / 13.0)[None].repeat(len(es), 0)).astype(np.float32)
    segs = eyes.view_segments(PANEL, viewer, n_views=48, mode=mode, motion_m=motion, motion_distance_m=0.04)
    bounds = eyes.eye_view_bounds(PANEL, viewer, n_views=48, motion_m=motion, motion_distance_m=0.04)
    kv, gh = cs.warp_coefficients(rig, es)
    return segs, bounds, imgs, wm, kv, gh


SCATTER_KERNELS = ["numba"] + (["cpp", "cpp-scalar"] if slices_cpp_available() else [])


# (2.5 m: the eyes' reaches overlap, so the nearer-eye test decides; 19 deg: one eye past the cone's
# edge, where the view coordinate wraps). Each position once, in one interleave mode each: the
# kernels' mode-specific code (the blend's second texel) runs in every case of its mode.
@pytest.mark.parametrize("mode,angle,distance", [("nearest", 0.0, 0.6), ("blend", -13.0, 0.5), ("nearest", 9.0, 1.2),
                                                 ("blend", 0.0, 2.5), ("nearest", 19.0, 0.6), ("blend", 19.0, 0.6)])
def test_scatter_kernels_agree_and_cover_every_received_subpixel(panel_display, panel_rig, mode, angle, distance):
    rig = panel_rig
    il, b = _buckets(mode)
    viewer = eyes.TrackedViewer(angle, distance)
    segs, bounds, imgs, wm, kv, gh = _tables(rig, viewer, 0, il.mode)
    reach = eyes.reach_views(0.5, 0.01)
    outs = {}
    for kernel in SCATTER_KERNELS:
        lo = np.zeros(il.shape, np.uint8)
        hi = np.full(il.shape, 255, np.uint8)
        n = scatter_slices(lo, b, segs, bounds, reach, imgs, wm, kv, gh, kernel=kernel)
        assert scatter_slices(hi, b, segs, bounds, reach, imgs, wm, kv, gh, kernel=kernel) == n
        written = lo == hi
        assert written.sum() >= n  # (a written 0 or 255 also counts)
        outs[kernel] = (lo, written)
    ref, written = outs["numba"]
    for kernel, (lo, w) in outs.items():
        np.testing.assert_array_equal(lo, ref, err_msg=kernel)
    display = panel_display
    for dx in (0.0, 0.009, -0.009):  # eyes anywhere inside the sideways margin
        x = viewer.centre_x_m + dx
        moved = eyes.TrackedViewer(math.degrees(math.atan2(x, viewer.distance_m)), viewer.distance_m)
        seen = eyes.received_subpixels(display, moved, 0.01)
        assert not (seen & ~written).any()
    # it writes far fewer than all subpixels
    assert written.mean() < 0.45


@pytest.mark.skipif(not slices_cpp_available(), reason="C++ extension not built")
def test_scatter_kernels_agree_on_many_segments_and_any_texel_table(buckets, panel_rig):
    """The AVX-512 kernel reads up to 64 segments' constants by permutes and computes the texel
    column where floor((x + 1/2) w / W) gives the table (the Portrait's): beyond 64 segments (the
    same ones cut into pieces, so the same output) and with another texel table it gathers, and
    every kernel still gives numba's output."""
    import copy

    il, b = buckets
    viewer = eyes.TrackedViewer(4.0, 0.7)
    segs, bounds, imgs, wm, kv, gh = _tables(panel_rig, viewer, 2, il.mode)
    reach = eyes.reach_views(0.5, 0.01)
    pieces = []
    for e, k, x0, x1 in segs:  # each segment cut in three
        cuts = np.linspace(x0, x1, 4).astype(np.int64)
        pieces += [(e, k, cuts[i], cuts[i + 1]) for i in range(3)]
    many = np.array(pieces, dtype=np.int64)
    assert len(segs) <= 64 < len(many)
    other = copy.copy(b)
    other.tex_col = b.tex_col[::-1].copy()  # valid texels, not floor((x + 1/2) w / W)
    for tables, s in ((b, segs), (b, many), (other, segs)):
        outs = []
        for kernel in SCATTER_KERNELS:
            native = np.zeros(il.shape, np.uint8)
            n = scatter_slices(native, tables, s, bounds, reach, imgs, wm, kv, gh, kernel=kernel)
            outs.append((n, native))
        for n, native in outs[1:]:
            assert n == outs[0][0]
            np.testing.assert_array_equal(native, outs[0][1])
    a, bb = (np.zeros(il.shape, np.uint8) for _ in range(2))
    assert scatter_slices(a, b, segs, bounds, reach, imgs, wm, kv, gh) == \
        scatter_slices(bb, b, many, bounds, reach, imgs, wm, kv, gh)
    np.testing.assert_array_equal(a, bb)


# (0.6 m: the eyes apart; 2.5 m: their reaches overlap, so both slices blend)
@pytest.mark.parametrize("mode,distance", [("nearest", 0.6), ("nearest", 2.5), ("blend", 2.5)])
def test_feathered_scatter_kernels_agree_and_stay_between_fill_and_slices(panel_rig, mode, distance):
    """The feather (``inner``): every kernel gives numba's output bit for bit over a random fill,
    each written subpixel lies between the fill and the eyes' own slice values (a convex blend),
    nothing outside the unfeathered set changes, and well inside an eye's range the slice shows."""
    il, b = _buckets(mode)
    viewer = eyes.TrackedViewer(5.0, distance)
    segs, bounds, imgs, wm, kv, gh = _tables(panel_rig, viewer, 4, il.mode)
    reach = eyes.reach_views(0.5, 0.01)
    fill = np.random.default_rng(5).integers(0, 256, il.shape, dtype=np.uint8)
    outs = []
    for kernel in SCATTER_KERNELS:
        out = fill.copy()
        n = scatter_slices(out, b, segs, bounds, reach, imgs, wm, kv, gh, kernel=kernel, inner=-3.0)
        outs.append((n, out))
    for n, out in outs[1:]:
        assert n == outs[0][0]
        np.testing.assert_array_equal(out, outs[0][1])
    out = outs[0][1].astype(np.int16)
    per_eye = []  # each eye's own (unfeathered) slice values, where it reaches
    for e in range(2):
        own = segs[segs[:, 0] == e] - np.array([e, 0, 0, 0])
        lo, hi = np.zeros(il.shape, np.uint8), np.full(il.shape, 255, np.uint8)
        for nat in (lo, hi):
            scatter_slices(nat, b, own, bounds[e:e + 1], reach, imgs[e:e + 1], wm[e:e + 1], kv[e:e + 1], gh[e:e + 1])
        per_eye.append((lo.astype(np.int16), lo == hi))
    reached = per_eye[0][1] | per_eye[1][1]
    assert np.array_equal(out[~reached], fill[~reached])
    f = fill.astype(np.int16)
    low = np.minimum.reduce([f] + [np.where(m, v, 999) for v, m in per_eye])
    high = np.maximum.reduce([f] + [np.where(m, v, -1) for v, m in per_eye])
    assert (out >= low).all() and (out <= high).all()
    changed = (out != f) & reached
    assert changed.mean() > 0.5 * reached.mean()  # the slices show (most of the fill differs from them)
    with pytest.raises(InputError, match="inner"):
        scatter_slices(fill, b, segs, bounds, reach, imgs, wm, kv, gh, inner=reach)


def test_scatter_validates_its_inputs(buckets, panel_rig):
    il, b = buckets
    segs, bounds, imgs, wm, kv, gh = _tables(panel_rig, eyes.TrackedViewer(0.0, 0.6), 1, il.mode)
    native = np.zeros(il.shape, np.uint8)
    reach = eyes.reach_views(0.5, 0.01)
    with pytest.raises(InputError, match="native"):
        scatter_slices(native[:-1], b, segs, bounds, reach, imgs, wm, kv, gh)
    with pytest.raises(InputError, match="segments"):
        scatter_slices(native, b, segs + np.array([0, 48, 0, 0]), bounds, reach, imgs, wm, kv, gh)
    with pytest.raises(InputError, match="bounds"):
        scatter_slices(native, b, segs, bounds[:, :, :-1], reach, imgs, wm, kv, gh)
    with pytest.raises(InputError, match="images"):
        scatter_slices(native, b, segs, bounds, reach, imgs[:, :, :50], wm[:, :, :50], kv, gh)
    with pytest.raises(InputError, match="kernel"):
        scatter_slices(native, b, segs, bounds, reach, imgs, wm, kv, gh, kernel="gpu")


def test_view_segments_are_the_view_columns_per_eye():
    for viewer in (eyes.TrackedViewer(0.0, 0.6), eyes.TrackedViewer(10.0, 2.5), eyes.TrackedViewer(-19.0, 0.5)):
        segs = eyes.view_segments(SMALL, viewer, n_views=48, motion_m=0.01, motion_distance_m=0.04)
        cover = np.zeros((2, 48, SMALL.screen_w), np.int32)
        for e, k, x0, x1 in segs:
            assert 0 <= x0 < x1 <= SMALL.screen_w and e in (0, 1)
            cover[e, k, x0:x1] += 1
        assert cover.max() == 1  # one eye's segments of a view are disjoint
        cover = cover.sum(axis=0)
        cols = eyes.view_columns(SMALL, viewer, SMALL.screen_w, n_views=48, motion_m=0.01, motion_distance_m=0.04)
        np.testing.assert_array_equal(cover > 0, cols)  # together: view_columns at native resolution
        # each row's lobe: the eye's view coordinate mid-row lies nearest view k + lobe * 48
        same, lobe = eyes.view_segments(SMALL, viewer, n_views=48, motion_m=0.01, motion_distance_m=0.04, lobes=True)
        np.testing.assert_array_equal(same, segs)
        bounds = eyes.eye_view_bounds(SMALL, viewer, n_views=48, motion_m=0.01, motion_distance_m=0.04)
        e, k, x0, x1 = segs.T
        xm = (x0 + x1 - 1) // 2
        t_mid = 0.5 * (bounds[e, 0, xm] + bounds[e, 1, xm])
        np.testing.assert_array_equal(lobe, np.rint((t_mid - k) / 48))
        assert (lobe != 0).any() == (abs(viewer.angle_deg) > 15)  # only the viewer at -19 deg wraps


# ----------------------------------------------------------------------------- the live mode
@pytest.mark.parametrize("blend", [False, True])
def test_tracked_slices_frame_against_the_full_path(cams, panel_display, blend):
    display = panel_display
    cfg = NativeFrameConfig(blend=blend, motion_m=0.01, motion_distance_m=0.04, refresh_columns=3)
    live = NativeFrameRenderer(PANEL, cams, cfg)
    assert live.tracked_method == "slices"
    reference = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(blend=blend))
    g0 = _scene(5, 3000, log_scale=(-6.0, -4.5))
    rng = np.random.default_rng(7)
    live.frame(g0, eyes.TrackedViewer(0.0, 0.6), mode="tracked")
    for step in range(2):
        g = _moved(g0, step)
        viewer = eyes.TrackedViewer(float(rng.uniform(-12, 12)), float(rng.uniform(0.5, 0.9)))
        f = live.frame(g, viewer, mode="tracked")
        assert f.mode == "tracked" and {"render", "depth", "scatter"} <= set(f.timings)
        ref = reference.frame(g, mode="full_quilt").native
        assert (f.native != ref).any()  # approximate, and the unseen subpixels hold the last frame
        assert eyes.eye_psnr(display, ref, f.native, viewer) > 40.0
    # the refreshed columns went through the quilt exactly, like the bands method's
    assert live._rr == 2 * cfg.refresh_columns


@pytest.mark.parametrize("angle,blend", [(15.0, False), (-19.0, True)])
def test_tracked_slices_at_the_cone_edge(cams, panel_display, angle, blend):
    """Near the edge of the cone an eye looks past the last view through part of the panel and
    receives the first views of the next lobe there (the lenticular wrap): those subpixels show
    views the eye's slice cannot hold, so they are rendered exactly through the quilt. Per eye
    > 40 dB against the full path (the slices alone gave 15-34 dB here). Both sides, both
    interleave modes, where the wrap begins (15 deg) and deep in it (19 deg)."""
    display = panel_display
    live = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(blend=blend, motion_m=0.005, motion_distance_m=0.02, refresh_columns=0))
    reference = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(blend=blend))
    g = _scene(6, 3000, log_scale=(-6.0, -4.5))
    live.frame(_moved(g, 0), eyes.TrackedViewer(0.0, 0.6), mode="tracked")  # everything, from another frame
    viewer = eyes.TrackedViewer(angle, 0.6)
    f = live.frame(g, viewer, mode="tracked")
    assert f.mode == "tracked"
    ref = reference.frame(g, mode="full_quilt").native
    assert eyes.eye_psnr(display, ref, f.native, viewer) > 40.0


def _moved(g: Gaussians, seed: int) -> Gaussians:
    rng = np.random.default_rng(100 + seed)
    gg = g.numpy()
    return Gaussians(gg.means + rng.normal(scale=0.004, size=gg.means.shape), gg.quats, gg.log_scales,
                     gg.opacity_logits, gg.sh + rng.normal(scale=0.2, size=gg.sh.shape))


@pytest.mark.parametrize("tracked", ["slices", "bands"])
def test_prepare_tracked_builds_the_first_frames_tables(cams, tracked):
    """prepare_tracked builds every one-off table a tracked frame needs (the slices' subpixel
    buckets; the interleaver's column readers or keys), so the first tracked frame of a live
    session builds none of them, and it runs once."""
    live = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(tracked=tracked, refresh_columns=2))
    il = live.interleaver
    assert getattr(il, "_readers", None) is None and getattr(il, "_keys", None) is None
    live.prepare_tracked()
    if tracked == "slices":
        assert live._buckets is not None and il._readers is not None
    else:
        assert il._keys is not None
    tables = (live._buckets, getattr(il, "_readers", None), getattr(il, "_keys", None))
    if tracked == "slices":  # the subpixel buckets are shared by every renderer of the panel, quilt and mode
        other = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(tracked=tracked, refresh_columns=0))
        other.prepare_tracked()
        assert other._buckets is live._buckets
        blend = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(tracked=tracked, blend=True))
        blend.prepare_tracked()
        assert blend._buckets is not live._buckets and blend._buckets.mode == "blend"
    g = _scene(3, 500)
    live.frame(g, eyes.TrackedViewer(0.0, 0.6), mode="tracked")  # the first frame: everything
    live.frame(g, eyes.TrackedViewer(2.0, 0.6), mode="tracked")
    after = (live._buckets, getattr(il, "_readers", None), getattr(il, "_keys", None))
    assert all(a is b for a, b in zip(tables, after))  # nothing rebuilt


@pytest.mark.parametrize("tracked", ["slices", "bands"])
def test_prepare_tracked_after_frames_changes_no_image(cams, tracked):
    """prepare_tracked also runs the slices frame's compiled kernels once (on no centre, no
    subpixel, and one tile column of the quilt rewritten from its own views): the kept views, the
    quilt and the native image are left exactly as they were."""
    live = NativeFrameRenderer(PANEL, cams, NativeFrameConfig(tracked=tracked, refresh_columns=2))
    live.frame(_scene(4, 500), eyes.TrackedViewer(0.0, 0.6), mode="tracked")  # everything
    before = [a.copy() for a in (live.views, live.quilt, live.native)]
    assert before[1].any() and before[2].any()
    live.prepare_tracked()
    for a, b in zip(before, (live.views, live.quilt, live.native)):
        np.testing.assert_array_equal(a, b)
