"""View synthesis (holo_viewer.render.view_synthesis) and the all_views mode that uses it.

Tolerances (stated once):
* the rig's shift equals the cameras' own projection difference to 1e-6 px;
* a warp of views that are a linear ramp on a plane of known depth equals the ramp that view
  would show, to 1e-5 (bilinear interpolation is exact on a linear image; the fixed-point
  column converges in one step on a constant depth);
* the z-buffer depth of a dense opaque plane equals its inverse depth to 1e-6 (1/m) inside it;
* the all_views native image with view_step 2 is above 40 dB against rendering every view on a
  tilted bumpy surface (measured 47.7 dB; a cross-fade that ignores depth 43.4 dB); the default
  avatar's figures are in docs/live_frame.md;
* the live loop's all_views (default step) is above 37 dB against every view rendered at
  quarter-size tiles (measured 40.2 dB; 43.4 dB at half size, 43.0 dB at full size).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from holo_viewer.avatar.gaussians import Gaussians  # noqa: E402
from holo_viewer.camera import Cameras  # noqa: E402
from holo_viewer.display import eyes  # noqa: E402
from holo_viewer.display.calibration import DisplayCalibration  # noqa: E402
from holo_viewer.display.cameras import make_quilt_cameras  # noqa: E402
from holo_viewer.errors import InputError  # noqa: E402
from holo_viewer.pipeline.live import AUTO_VIEW_STEP, NativeFrameConfig, NativeFrameRenderer  # noqa: E402
from holo_viewer.render import view_synthesis as vs  # noqa: E402

CAL = DisplayCalibration.load(None)
SMALL = CAL.with_quilt(8, 6, 840, 840)  # 105 x 140 tiles


@pytest.fixture(scope="module")
def cams() -> Cameras:
    return make_quilt_cameras(SMALL, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)


def test_source_views_and_brackets():
    np.testing.assert_array_equal(vs.source_views(48, 4), list(range(0, 48, 4)) + [47])
    np.testing.assert_array_equal(vs.source_views(9, 4), [0, 4, 8])
    np.testing.assert_array_equal(vs.source_views(5, 1), range(5))
    b = vs.bracket(9, np.array([0, 4, 8]))
    np.testing.assert_array_equal(b[:, 0], [1, 2, 3, 5, 6, 7])
    np.testing.assert_array_equal(b[:3, 1:], [[0, 4]] * 3)
    np.testing.assert_array_equal(b[3:, 1:], [[4, 8]] * 3)
    with pytest.raises(InputError, match="view_step"):
        vs.source_views(48, 0)
    with pytest.raises(InputError, match="sources"):
        vs.bracket(9, np.array([1, 4, 8]))


def test_auto_cell_keeps_a_dozen_centres_per_cell():
    # the default avatar keeps 77418 centres; its best fixed cells were 6, 3 and 2 px (docs/live_frame.md)
    assert [vs.auto_cell(77418, h, w) for h, w in ((560, 420), (280, 210), (140, 105))] == [6, 3, 2]
    assert vs.auto_cell(0, 560, 420) == 16 and vs.auto_cell(10, 560, 420) == 16 and vs.auto_cell(10**9, 56, 42) == 1


def test_rig_shift_is_the_projection_difference(cams):
    rig = vs.rig_of(cams)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.1, 0.1, size=(50, 3))
    uv, z = cams.project(pts)
    for a, k in ((0, 5), (47, 3), (20, 21)):
        for i in range(len(pts)):
            assert abs(uv[a, i, 0] - uv[k, i, 0] - rig.shift(a, k, 1.0 / z[k, i])) < 1e-6
            assert abs(uv[a, i, 1] - uv[k, i, 1]) < 1e-9  # horizontal rig: rows agree
    # the zero-disparity plane passes through the focal centre (the world origin here): a point
    # on it projects to the same column in every view
    uv0, z0 = cams.project(np.array([[0.01, 0.02, 0.0]]))
    assert abs(1.0 / z0[0, 0] - rig.w_zero) < 1e-9
    assert np.ptp(uv0[:, 0, 0]) < 1e-6


def test_rig_of_rejects_other_cameras(cams):
    w2c = cams.world_to_cam.copy()
    c, s = np.cos(0.1), np.sin(0.1)
    w2c[3, :3, :3] = w2c[3, :3, :3] @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    with pytest.raises(InputError, match="rotation"):
        vs.rig_of(dataclasses.replace(cams, world_to_cam=w2c))
    K = cams.K.copy()
    K[2, 1, 1] *= 1.1
    with pytest.raises(InputError, match="fy"):
        vs.rig_of(dataclasses.replace(cams, K=K))


@pytest.mark.parametrize("iters", [0, 1, 3])
def test_warp_of_a_ramp_on_a_plane_is_exact(cams, iters):
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    w = 1.0 / 1.3  # a plane 1.3 m from the cameras, off the zero-disparity plane
    ref = 7  # the ramp is anchored in view 7's columns

    def ramp(j: int) -> np.ndarray:  # what view j shows of a plane whose colour is linear in x
        x = np.arange(W) - rig.shift(j, ref, w)  # view j's column x sees view ref's column x - shift
        base = np.stack((0.3 + 0.001 * x, 0.5 - 0.0007 * x, 0.2 + 0.0003 * x), axis=-1)
        return np.broadcast_to(base, (H, W, 3)).astype(np.float32)

    sources = vs.source_views(V, 5)
    images = np.stack([ramp(j) for j in sources])
    wmaps = np.full((sources.size, H, W), w, dtype=np.float32)
    out = np.full((V, H, W, 3), -1.0, dtype=np.float32)
    vs.warp_views(images, wmaps, sources, rig, iters=iters, out=out)
    shifts = [abs(rig.shift(src, k, w)) for k, a, b in vs.bracket(V, sources) for src in (a, b)]
    margin = int(np.ceil(max(shifts))) + 2  # columns near the border clamp
    for k in range(V):
        if k in sources:
            assert (out[k] == -1.0).all()  # sources' slots untouched
            continue
        np.testing.assert_allclose(out[k][:, margin:W - margin], ramp(k)[:, margin:W - margin], atol=1e-5)


def test_warp_weights_favour_the_nearer_source(cams):
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    sources = vs.source_views(V, 4)
    level = np.linspace(0.1, 0.9, sources.size)  # each source a different flat grey
    images = np.broadcast_to(level[:, None, None, None], (sources.size, H, W, 3)).astype(np.float32)
    wmaps = np.full((sources.size, H, W), 0.7, np.float32)
    out = np.zeros((V, H, W, 3), np.float32)
    vs.warp_views(images, wmaps, sources, rig, out=out)
    slot = {int(v): i for i, v in enumerate(sources)}
    for k, a, b in vs.bracket(V, sources):
        expected = ((b - k) * level[slot[a]] + (k - a) * level[slot[b]]) / (b - a)
        np.testing.assert_allclose(out[k], expected, atol=1e-6)


def test_background_columns_skipped_equal_the_full_warp(cams):
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    rng = np.random.default_rng(3)
    sources = vs.source_views(V, 6)
    images = np.zeros((sources.size, H, W, 3), np.float32)
    for i in range(sources.size):  # content in a narrow band per row, background elsewhere
        for y in range(H):
            c = int(rng.integers(10, W - 20))
            images[i, y, c:c + int(rng.integers(1, 12))] = rng.uniform(0.1, 1.0, size=3)
    wmaps = rng.uniform(0.3, 1.2, size=(sources.size, H, W)).astype(np.float32)  # shifts of many pixels
    skipped = np.full((V, H, W, 3), 9.0, np.float32)
    vs.warp_views(images, wmaps, sources, rig, out=skipped)  # background (0, 0, 0): columns skipped
    full = np.full((V, H, W, 3), 9.0, np.float32)
    vs.warp_views(images, wmaps, sources, rig, out=full, background=(-1.0, -1.0, -1.0))  # nothing skipped
    np.testing.assert_array_equal(skipped, full)
    assert (full[vs.bracket(V, sources)[:, 0]] > 0).mean() > 0.01  # the bands did move into targets
    tiles = np.array([[(5 - k // 8) * H, (k % 8) * W] for k in range(V)])
    quilts = [np.full((6 * H, 8 * W, 3), 7, np.uint8) for _ in range(2)]  # the float32 quilt kernel: the same
    for quilt, bg in zip(quilts, ((0.0, 0.0, 0.0), (-1.0, -1.0, -1.0))):
        vs.warp_views(images, wmaps, sources, rig, quilt=quilt, tiles=tiles, background=bg)
    np.testing.assert_array_equal(quilts[0], quilts[1])


def test_warp_into_the_quilt_writes_only_the_listed_pixels(cams):
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    rng = np.random.default_rng(1)
    sources = vs.source_views(V, 3)
    images = rng.uniform(size=(sources.size, H, W, 3)).astype(np.float32)
    wmaps = rng.uniform(0.6, 0.9, size=(sources.size, H, W)).astype(np.float32)
    floats = np.zeros((V, H, W, 3), np.float32)
    vs.warp_views(images, wmaps, sources, rig, out=floats)
    tiles = np.array([[(5 - k // 8) * H, (k % 8) * W] for k in range(V)])
    listed = rng.uniform(size=(V, H, W)) < 0.4
    quilts = {}
    for exact in (True, False):  # the float64 kernel (the reference) and the float32 one (the live path)
        quilt = quilts[exact] = np.full((6 * H, 8 * W, 3), 7, np.uint8)
        vs.warp_views(images, wmaps, sources, rig, quilt=quilt, tiles=tiles, pixels=vs.sampled_columns(listed),
                      exact=exact)
        for k in range(V):
            tile = quilt[tiles[k, 0]:tiles[k, 0] + H, tiles[k, 1]:tiles[k, 1] + W]
            if k in sources:
                assert (tile == 7).all()
                continue
            on = listed[k]
            assert (tile[~on] == 7).all()
            expected = np.clip(np.floor(floats[k] * 255.0 + 0.5), 0, 255)
            assert np.abs(tile[on].astype(int) - expected[on]).max() <= 1
    # float32 against float64: within 1 per channel, and only where the value lies within float32's
    # rounding of a half (measured: 6e-6 of a group frame's synthesized pixels on the default avatar)
    diff = np.abs(quilts[False].astype(int) - quilts[True].astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3, (diff > 0).mean()



@pytest.mark.parametrize("kernel", ["auto", "cpp-scalar"])
def test_compiled_warp_writes_the_numba_kernels_bytes(cams, monkeypatch, kernel):
    """The C++ float32 warp into the quilt (AVX-512: depth and image rows read by permutes from windows
    where the 16 columns' reads fit, gathers elsewhere; scalar) writes the numba kernel's bytes: smooth
    depths (the windows), rough ones (shifts of many pixels: the gathers), every column and a sparse list
    (consecutive and scattered stores), background columns skipped; a 1-off fusion fails this."""
    if vs._warp_cpp() is None:
        pytest.skip("the C++ extension holo_viewer.render._splat_cpp (with warp_u8) is not built")
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    rng = np.random.default_rng(29)
    sources = vs.source_views(V, 6)
    tiles = np.array([[(5 - k // 8) * H, (k % 8) * W] for k in range(V)])
    yy, xx = np.mgrid[0:H, 0:W]
    smooth = (0.7 + 0.25 * np.sin(xx / 17.0) * np.cos(yy / 23.0)).astype(np.float32)
    for wmaps in (np.stack([smooth + 0.01 * i for i in range(sources.size)]).astype(np.float32),
                  rng.uniform(0.3, 1.2, size=(sources.size, H, W)).astype(np.float32)):
        images = rng.uniform(size=(sources.size, H, W, 3)).astype(np.float32)
        images[:, :, : W // 5] = 0.0  # background at the left: columns skipped
        # every column; a dense list (16 listed columns span < 32: the depth row's first read by a permute, the
        # image row's from the 32-texel window); a sparse one (gathers)
        for pixels in (None, vs.sampled_columns(rng.uniform(size=(V, H, W)) < 0.8),
                       vs.sampled_columns(rng.uniform(size=(V, H, W)) < 0.4)):
            out = {}
            for k in ("numba", kernel):
                monkeypatch.setattr(vs, "WARP_KERNEL", k)
                out[k] = np.full((6 * H, 8 * W, 3), 7, np.uint8)
                vs.warp_views(images, wmaps, sources, rig, quilt=out[k], tiles=tiles, pixels=pixels)
            np.testing.assert_array_equal(out[kernel], out["numba"])
            assert (out["numba"] != 7).mean() > 0.3

@pytest.mark.parametrize("kernel", ["auto", "cpp-scalar"])
def test_compiled_row_extents_equal_the_numba_kernels(monkeypatch, kernel):
    """row_extents in C++ (AVX-512: 16 pixels' floats against the background's pattern from each end) gives the
    numba kernel's spans and depth ranges: empty rows, spans at either edge, a span that differs from the
    background in one channel only, widths that are and are not multiples of 16, a background per channel."""
    if vs._warp_cpp() is None or not hasattr(vs._warp_cpp(), "row_extents"):
        pytest.skip("the C++ extension holo_viewer.render._splat_cpp (with row_extents) is not built")
    rng = np.random.default_rng(7)
    for W, bg in ((420, (0.0, 0.0, 0.0)), (105, (0.2, 0.5, 1.0)), (7, (0.0, 0.0, 0.0)), (33, (1.0, 0.0, 0.25))):
        S, H = 3, 40
        bg = np.array(bg, np.float32)
        images = np.tile(bg, (S, H, W, 1))
        for s in range(S):
            for y in range(H):
                a = int(rng.integers(0, W + 1))
                b = int(rng.integers(a, W + 1)) if y % 5 else W  # every 5th a span to the right edge
                if y % 7 == 3:
                    continue  # background only
                images[s, y, a:b] = rng.random((b - a, 3))
                if y % 3 == 0:
                    images[s, y, a:b, :2] = bg[:2]  # only the last channel differs
        wmaps = rng.random((S, H, W)).astype(np.float32)
        got = {}
        for k in ("numba", kernel):
            monkeypatch.setattr(vs, "WARP_KERNEL", k)
            got[k] = (np.empty((S, H, 2), np.int64), np.empty((S, H, 2)))
            vs.row_extents(images, wmaps, bg, *got[k])
        for a, b in zip(got[kernel], got["numba"]):
            np.testing.assert_array_equal(a, b)
        assert (got["numba"][0][:, :, 0] == W).any() and (got["numba"][0][:, :, 1] == W - 1).any()


#: the Portrait's texel-to-subpixel ratio at full tiles (3.66 native pixels a texel each way) on SMALL's tiles
NATIVE_PANEL = dataclasses.replace(SMALL, screen_w=384, screen_h=512)


def _native_case(cams, panel=NATIVE_PANEL):
    from holo_viewer.display.lenticular import Interleaver
    from holo_viewer.display.quilt import tile_slices
    from holo_viewer.pipeline.live import read_pixels

    V = len(cams)
    il = Interleaver(panel, (840, 840, 3), cols=8, rows=6, n_views=V)
    tiles = np.array([[s.start for s in tile_slices(840, 840, 8, 6, k)] for k in range(V)])
    sampled = vs.sampled_columns(read_pixels(il, panel, V))
    return il, tiles, sampled, vs.native_targets(il.gather_indices()[0], tiles, sampled, il.quilt_shape, il.shape)


@pytest.mark.parametrize("kernel", ["auto", "cpp-scalar"])
def test_warp_into_native_is_the_quilt_warp_interleaved(cams, monkeypatch, kernel):
    """warp_views(native=) (the warp straight into the native subpixels, one channel each, the sources' from
    their renders) gives the bytes of the reference: the sources' tiles (to_uint8), the float32 warp into the
    quilt's read texels, the nearest interleave. Bit for bit, on random images (values outside [0, 1] and
    exact halves included), smooth and rough depths, view steps 5 and 6, a background colour per channel;
    every subpixel is written (the native starts at 7)."""
    from holo_viewer.display.native import views_to_native

    if not vs.native_warp_available():
        pytest.skip("the C++ extension holo_viewer.render._splat_cpp (with warp_native) is not built")
    monkeypatch.setattr(vs, "WARP_KERNEL", kernel)
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    il, tiles, sampled, targets = _native_case(cams)
    assert targets is not None and targets.codes.size == sampled.columns.size
    rng = np.random.default_rng(41)
    yy, xx = np.mgrid[0:H, 0:W]
    smooth = (0.7 + 0.25 * np.sin(xx / 17.0) * np.cos(yy / 23.0)).astype(np.float32)
    for step, rough, bg in ((6, False, (0.0, 0.0, 0.0)), (5, True, (0.2, 0.5, 1.0))):
        sources = vs.source_views(V, step)
        wmaps = (rng.uniform(0.3, 1.2, size=(sources.size, H, W)) if rough else
                 np.stack([smooth + 0.01 * i for i in range(sources.size)])).astype(np.float32)
        images = (rng.uniform(size=(sources.size, H, W, 3)) * 1.1 - 0.05).astype(np.float32)
        images[:, :, : W // 5] = bg  # background at the left: columns skipped
        images[0, 0, 30:33, 0] = [0.5 / 255, 1.5 / 255, 2.5 / 255]  # to_uint8 rounds halves to even
        quilt = np.zeros(il.quilt_shape, np.uint8)
        views_to_native(images, (8, 6), quilt=quilt, tiles=sources)
        vs.warp_views(images, wmaps, sources, rig, quilt=quilt, tiles=tiles, pixels=sampled, background=bg)
        ref = il(quilt)
        native = np.full(il.shape, 7, np.uint8)
        assert vs.warp_views(images, wmaps, sources, rig, pixels=sampled, background=bg, native=native,
                             targets=targets) is native
        np.testing.assert_array_equal(native, ref)
        assert len(np.unique(ref)) > 200
    with pytest.raises(InputError, match="targets"):  # codes of another table
        vs.warp_views(images, wmaps, sources, rig, pixels=vs.sampled_columns(np.ones((V, H, W), bool)),
                      native=native, targets=targets)
    with pytest.raises(InputError, match="native"):
        vs.warp_views(images, wmaps, sources, rig, pixels=sampled, native=native[:, :-1], targets=targets)


def test_native_targets_only_where_the_codes_fit(cams):
    """native_targets lists each read texel's one or two subpixels; a layout where a texel is read by more
    (a 768 x 1024 panel: ~7.3 native pixels a texel each way; SMALL's full-size one: ~15) gets None, so the
    frames keep the quilt and the interleave (test_all_views_with_synthesis_against_every_view runs that path)."""
    il, tiles, sampled, targets = _native_case(cams)
    flat = np.full(il.shape, 0, np.uint8).reshape(-1)
    offsets, columns = sampled
    V, H, W = sampled.shape
    k_y = np.repeat(np.arange(V * H), np.diff(offsets))
    for b in (targets.codes & 0xFF, targets.codes >> 8):  # every subpixel named by exactly one texel
        np.add.at(flat, targets.rowoff[k_y % H] + targets.coloff[columns] + targets.lut[b], 1)
    lone = (targets.codes & 0xFF) == (targets.codes >> 8)
    np.subtract.at(flat, (targets.rowoff[k_y % H] + targets.coloff[columns] + targets.lut[targets.codes & 0xFF])[lone],
                   1)
    assert (flat == 1).all()
    assert _native_case(cams, dataclasses.replace(SMALL, screen_w=768, screen_h=1024))[3] is None


def test_zbuffer_depth_of_an_opaque_plane(cams):
    z_plane = 0.02  # world z of the plane (the cameras look down -z from ~1.6 m)
    g = np.stack(np.meshgrid(np.linspace(-0.05, 0.05, 200), np.linspace(-0.05, 0.05, 200)), -1).reshape(-1, 2)
    means = np.column_stack((g, np.full(len(g), z_plane)))
    opacity = np.full(len(means), 0.9)
    views = np.array([0, 20, 47])
    wm = vs.inverse_depth(means, opacity, cams, views)
    rig = vs.rig_of(cams)
    uv, z = cams.project(means)
    for i, k in enumerate(views):
        w_true = 1.0 / z[k, 0]
        u0, u1 = uv[k, :, 0].min(), uv[k, :, 0].max()
        v0, v1 = uv[k, :, 1].min(), uv[k, :, 1].max()
        inside = wm[i, int(v0) + 6:int(v1) - 6, int(u0) + 6:int(u1) - 6]
        assert inside.size > 100
        np.testing.assert_allclose(inside, w_true, atol=1e-6)
        assert abs(wm[i, 0, 0] - rig.w_zero) < 1e-6  # background: the zero-disparity plane
    # low-opacity centres do not count
    assert np.all(vs.inverse_depth(means, opacity * 0.1, cams, views) == np.float32(rig.w_zero))


def test_zbuffer_shares_the_rotation_bit_for_bit(cams):
    """The kernel computes the rotation, z and v once per centre for all sources: the same depth maps,
    bit for bit, as each source projecting every centre itself (the loop it replaced, in Python here:
    float64, no fused multiply-adds), with centres behind the near plane, dropped ones and equal depths."""
    rng = np.random.default_rng(5)
    means = rng.normal(0.0, 0.04, (1500, 3))
    means[:50, 2] = 1.7  # behind the cameras' near plane (the cameras sit at z ~1.6 looking down -z)
    means[50:100] = means[100:150]  # equal depths: the first one wins in both
    keep = rng.random(len(means)) < 0.8
    views = np.array([0, 11, 29, 47])
    rig = vs.rig_of(cams)
    R, t0, H, W, cell = cams.R[0], cams.t[0], cams.height, cams.width, 3
    out = np.empty((views.size, H, W), np.float32)
    vs._zbuffer(means, keep, np.ascontiguousarray(R), rig.tx[views], float(t0[1]), float(t0[2]), rig.fx,
                float(cams.fy[0]), rig.cx[views], float(cams.cy[0]), float(cams.near), H, W, cell, rig.w_zero, out)
    h, w = -(-H // cell), -(-W // cell)
    fy, cy, near = float(cams.fy[0]), float(cams.cy[0]), float(cams.near)
    for s, k in enumerate(views):
        zb = np.full((h, w), np.inf)
        tx, cx = float(rig.tx[k]), float(rig.cx[k])
        for i in np.flatnonzero(keep):
            mx, my, mz = (float(c) for c in means[i])
            z = R[2, 0] * mx + R[2, 1] * my + R[2, 2] * mz + float(t0[2])
            if not z > near:
                continue
            u = rig.fx * (R[0, 0] * mx + R[0, 1] * my + R[0, 2] * mz + tx) / z + cx
            v = fy * (R[1, 0] * mx + R[1, 1] * my + R[1, 2] * mz + float(t0[1])) / z + cy
            if u >= 0.0 and v >= 0.0 and int(u / cell) < w and int(v / cell) < h and z < zb[int(v / cell), int(u / cell)]:
                zb[int(v / cell), int(u / cell)] = z
        ref = np.empty((H, W), np.float32)
        vs._cells_to_pixels(zb, h, w, cell, H, W, rig.w_zero, ref)
        assert np.isfinite(zb).sum() > 10
        np.testing.assert_array_equal(out[s], ref)


def _surface(seed: int, n: int = 6000) -> Gaussians:
    """A bumpy, tilted opaque surface facing the cameras (a stand-in for a face: 0.3 m deep, so
    that views differ by a few pixels and the depth matters)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.08, 0.08, size=(n, 2))
    z = 0.2 * np.exp(-(xy ** 2).sum(1) / 0.003) + 0.1 * xy[:, 0] / 0.08
    sh = np.zeros((n, 4, 3))
    sh[:, 0] = (np.stack((0.5 + 0.4 * np.sin(60 * xy[:, 0]), 0.4 + 0.3 * np.cos(50 * xy[:, 1]),
                          0.3 + 0.2 * np.sin(30 * xy.sum(1))), -1) - 0.5) / 0.28209479177387814
    sh[:, 1:] = rng.normal(scale=0.02, size=(n, 3, 3))
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return Gaussians.from_arrays(np.column_stack((xy, z)), quats, np.full((n, 3), np.log(0.0025)),
                                 np.full(n, 3.0), sh)


def test_all_views_with_synthesis_against_every_view(cams):
    g = _surface(0)
    exact = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=1))
    ref = exact.frame(g, mode="all_views")
    assert exact.view_step == 1 and ref.rendered_fraction == 1.0
    np.testing.assert_array_equal(ref.native, exact.frame(g, mode="full_quilt").native)
    live = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=2))
    f = live.frame(g, mode="all_views")
    assert f.mode == "all_views" and f.rendered_fraction == len(vs.source_views(len(cams), 2)) / len(cams)
    assert {"depth", "warp"} <= set(f.timings)
    p2 = eyes.head_psnr(ref.native / 255.0, f.native / 255.0)
    assert 40.0 < p2 < np.inf
    # a plain cross-fade (the same sources, depth ignored: every pixel at the zero-disparity
    # plane) is worse: the depth compensation is what the warp adds
    flat = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=2))
    flat.frame(g, mode="all_views")
    orig = vs.inverse_depth

    def no_depth(*a, out=None, **k):
        out[...] = flat._rig.w_zero
        return out

    vs.inverse_depth = no_depth
    try:
        p_flat = eyes.head_psnr(ref.native / 255.0, flat.frame(g, mode="all_views").native / 255.0)
    finally:
        vs.inverse_depth = orig
    assert p_flat < p2 - 2.0
    # full_quilt stays exact whatever the view step
    np.testing.assert_array_equal(live.frame(g, mode="full_quilt").native, ref.native)


def test_view_step_default_and_errors(cams):
    assert NativeFrameRenderer(SMALL, cams).view_step == AUTO_VIEW_STEP
    w2c = cams.world_to_cam.copy()
    w2c[1, 1, 3] += 0.01  # one camera raised: not a horizontal rig
    odd = dataclasses.replace(cams, world_to_cam=w2c)
    assert NativeFrameRenderer(SMALL, odd).view_step == 1  # default: renders every view
    with pytest.raises(InputError, match="horizontal rig"):
        NativeFrameRenderer(SMALL, odd, NativeFrameConfig(view_step=3))
    with pytest.raises(InputError, match="view_step"):
        NativeFrameConfig(view_step=0)


def test_torch_twins_match_the_numba_path(cams):
    torch = pytest.importorskip("torch")
    rig = vs.rig_of(cams)
    V, H, W = len(cams), cams.height, cams.width
    g = _surface(2)
    means = np.asarray(g.means, dtype=np.float64)
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64)))
    opacity[::7] = 0.2  # some centres below min_opacity
    sources = vs.source_views(V, 5)
    wm = vs.inverse_depth(means, opacity, cams, sources)
    wt = vs.inverse_depth_torch(torch.as_tensor(means), torch.as_tensor(opacity), cams, sources).numpy()
    np.testing.assert_allclose(wt, wm, rtol=0, atol=1e-6)
    rng = np.random.default_rng(5)
    images = rng.uniform(size=(sources.size, H, W, 3)).astype(np.float32)
    out = np.zeros((V, H, W, 3), np.float32)
    vs.warp_views(images, wm, sources, rig, out=out)
    ot = vs.warp_views_torch(torch.as_tensor(images, dtype=torch.float64), torch.as_tensor(wm, dtype=torch.float64),
                             sources, rig).numpy()
    targets = vs.bracket(V, sources)[:, 0]
    np.testing.assert_allclose(ot[targets], out[targets], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(ot[sources], images)


def test_device_path_glue_on_cpu_torch(cams, monkeypatch):
    """The gsplat path's synthesis (render the sources on the device, depth and warp there, one
    gather to the native image), run on CPU torch with the fast renderer standing in for gsplat:
    it must give the CPU path's native image up to rounding (float32 vs float64 warp, and the
    numba path's round-half-up against torch's round-half-even)."""
    torch = pytest.importorskip("torch")
    from holo_viewer.render import fast, gsplat_backend

    def cpu_render_device(g, cameras, config=None, views_per_call=None):
        return torch.as_tensor(fast.render(g, cameras, config).images.copy())

    monkeypatch.setattr(gsplat_backend, "render_device", cpu_render_device)
    import holo_viewer.pipeline.live as live_mod

    monkeypatch.setattr(live_mod, "LIVE_T_MIN", 0.0)  # gsplat's termination is compiled in: compare at the config's
    g = _surface(4)
    cpu = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=5)).frame(g, mode="all_views")
    assert NativeFrameRenderer(SMALL, cams, NativeFrameConfig(backend="gsplat")).view_step == 1  # does not pay on GPUs: opt-in
    dev = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(backend="gsplat", view_step=5))
    f = dev.frame(g, mode="all_views")
    assert f.rendered_fraction == cpu.rendered_fraction < 1.0
    diff = np.abs(f.native.astype(int) - cpu.native.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
    # a group frame on the device is its all_views (no eye slices there), tracked faces or not
    grp = dev.frame(g, eyes.TrackedViewer(5.0, 0.6), mode="group")
    assert grp.mode == "group" and dev.group_view_step == dev.view_step == 5
    np.testing.assert_array_equal(grp.native, f.native)


def test_live_loop_all_views_uses_synthesis_and_replay_renders_every_view():
    from holo_viewer.live.render import LiveAvatarRenderer as LoopRenderer

    listener = {"expr": np.zeros(50), "jaw_pose": np.array([0.1, 0.0, 0.0]), "rotation": np.zeros(3)}
    loop = LoopRenderer(tile_scale=0.25, native=True, preview=False, mode="all_views", render_threads=1)
    assert loop._live.view_step == AUTO_VIEW_STEP
    exact = LoopRenderer(tile_scale=0.25, native=True, preview=False, mode="all_views", render_threads=1, view_step=1)
    a = loop.render(listener, 0.5, (), 0.0, 0.6).native
    b = exact.render(listener, 0.5, (), 0.0, 0.6).native
    assert a.shape == b.shape == tuple(loop._live.native.shape)
    assert 37.0 < eyes.head_psnr(b / 255.0, a / 255.0) < np.inf  # measured 40.2 dB at quarter-size tiles


def test_warp_zbuffer_interleave_and_scatter_kernels_release_the_gil():
    """The live loop's render thread runs these numba kernels while the tracker, reaction and
    recording threads run Python: each is compiled nogil (the C++ kernels release it themselves)."""
    from holo_viewer.display import lenticular
    from holo_viewer.display import slices as sl

    kernels = [vs._zbuffer, vs._zbuffer_coef, vs._cells_to_pixels, vs._row_extents, vs._warp, sl._scatter,
               *lenticular._numba_kernels()]
    assert [k.py_func.__name__ for k in kernels if not k.targetoptions.get("nogil")] == []
