"""Lenticular interleave: fast path == float64 reference, for every subpixel."""

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest

from holo_viewer.display.calibration import DisplayCalibration, QuiltLayout, default_calibration_path
from holo_viewer.display.lenticular import Interleaver, interleave_reference, reference_views
from holo_viewer.display.quilt import tile_quilt
from holo_viewer.errors import InputError

FIX = DisplayCalibration.from_file(str(default_calibration_path()))
FLAGS = [dict(flip_image_x=x, flip_image_y=y, inv_view=i, flip_subp=s)
         for x in (False, True) for y in (False, True) for i in (False, True) for s in (False, True)]


def _random_cal(rng, **flags):
    cols, rows = int(rng.integers(2, 7)), int(rng.integers(2, 7))
    tw, th = int(rng.integers(5, 40)), int(rng.integers(5, 40))
    q = QuiltLayout(cols, rows, cols * tw + int(rng.integers(0, 3)), rows * th + int(rng.integers(0, 3)), 1.0)
    return DisplayCalibration(pitch=float(rng.uniform(20, 80)), slope=float(rng.choice([-1, 1]) * rng.uniform(2, 12)),
                              center=float(rng.uniform(-1, 1)), view_cone=40.0, dpi=float(rng.uniform(100, 500)),
                              screen_w=int(rng.integers(40, 160)), screen_h=int(rng.integers(40, 200)), quilt=q,
                              **flags)


def _not_tie(cal, shape):
    """(H, W, 1) mask of native pixels whose centre is not exactly on a quilt texel edge
    (nearest sampling is ambiguous there: GL and integer arithmetic may round either way)."""
    tw, th = shape[1] // cal.cols, shape[0] // cal.rows
    u = (np.arange(cal.screen_w) + 0.5) / cal.screen_w * tw
    v = (1 - (np.arange(cal.screen_h) + 0.5) / cal.screen_h) * th
    ok_u = np.abs(u - np.rint(u)) > 1e-9
    ok_v = np.abs(v - np.rint(v)) > 1e-9
    return (ok_v[:, None] & ok_u[None, :])[:, :, None]


def _scalar_view(cal, n, r, c, ch):
    """The docs/design.md formula for one subpixel with Python floats (no numpy)."""
    W, H = cal.screen_w, cal.screen_h
    pitch = cal.pitch * W / cal.dpi * math.cos(math.atan(1 / cal.slope))
    tilt = H / (W * cal.slope) * (-1 if cal.flip_image_x else 1)
    subp = 1 / (3 * W)
    i = [2, 1, 0][ch] if cal.flip_subp else ch
    u, v = (c + 0.5) / W, 1 - (r + 0.5) / H
    x = (u + i * subp + v * tilt) * pitch - cal.center
    z = x - math.floor(x)
    if cal.inv_view:
        z = 1 - z
    return min(math.floor(z * n), n - 1)


@pytest.mark.parametrize("flags", FLAGS, ids=lambda f: "".join(k[0] + k[-1] + str(int(v)) for k, v in f.items()))
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_random_calibrations_match_reference(flags, backend):
    rng = np.random.default_rng(abs(hash(tuple(flags.values()))) % 2**32)
    for trial in range(3):
        cal = _random_cal(rng, **flags)
        n = int(rng.integers(2, cal.cols * cal.rows + 1))
        shape = (cal.quilt_height, cal.quilt_width, 3)
        q8 = rng.integers(0, 256, shape, dtype=np.uint8)
        qf = rng.random(shape, dtype=np.float32)
        # nearest
        il = Interleaver(cal, shape, n_views=n, backend=backend)
        v0, _, _ = reference_views(cal, n)
        assert np.array_equal(il.view_index, v0), "view index differs from the reference"
        ok = np.broadcast_to(_not_tie(cal, shape), il.shape)
        assert ok.mean() > 0.5
        assert np.array_equal(il(q8)[ok], interleave_reference(q8, cal, n_views=n).astype(np.uint8)[ok])
        assert np.array_equal(il(qf)[ok], interleave_reference(qf, cal, n_views=n).astype(np.float32)[ok])
        for _ in range(20):
            r, c, ch = int(rng.integers(cal.screen_h)), int(rng.integers(cal.screen_w)), int(rng.integers(3))
            assert il.view_index[r, c, ch] == _scalar_view(cal, n, r, c, ch)
        # blend
        ib = Interleaver(cal, shape, n_views=n, mode="blend", backend=backend)
        b0, b1, w = reference_views(cal, n, "blend")
        assert np.array_equal(ib.view_index, b0) and np.array_equal(ib.view_index1, b1)
        assert np.abs(ib.weight - w).max() < 1e-6
        ref8 = interleave_reference(q8, cal, n_views=n, mode="blend")
        assert np.abs(ib(q8).astype(np.float64) - ref8)[ok].max() <= 1.0
        assert np.abs(ib(qf) - interleave_reference(qf, cal, n_views=n, mode="blend"))[ok].max() < 1e-5


@pytest.mark.parametrize("flags", FLAGS[:3], ids=lambda f: "".join(k[0] + k[-1] + str(int(v)) for k, v in f.items()))
def test_nearest_row_kernel_reads_the_index_tables_texels(flags):
    """The numba nearest kernel reads each subpixel's texel as row part (native row, view) +
    column part (subpixel) through one byte of view: exactly the flat index table's texel, for
    every subpixel, uint8 and float32 quilts."""
    rng = np.random.default_rng(17)
    for cal in (_random_cal(rng, **flags), FIX):
        shape = (cal.quilt_height, cal.quilt_width, 3)
        il = Interleaver(cal, shape, backend="numba")
        assert il._rows is not None
        for q in (rng.integers(0, 256, shape, dtype=np.uint8), rng.random(shape, dtype=np.float32)):
            want = np.take(q.reshape(-1), il._idx0).reshape(il.shape)
            np.testing.assert_array_equal(il(q), want)



@pytest.mark.parametrize("kernel", ["cpp-scalar", "auto"])
def test_compiled_row_gather_equals_the_numba_kernel(kernel):
    """The C++ row gather (AVX-512 where the CPU has it: two permutes for the row's texel offsets, one
    32-bit gather; rows whose gather could read past the quilt's end run the scalar loop) writes the
    numba kernel's bytes for every subpixel, random calibrations and the Portrait's, including the
    rows that read the quilt's last texels; tables pointing outside the quilt are refused."""
    from holo_viewer.display import lenticular

    cpp = lenticular._gather_cpp()
    if cpp is None:
        pytest.skip("the C++ extension holo_viewer.display._slices_cpp is not built")
    rng = np.random.default_rng(23)
    for cal in (_random_cal(rng, **FLAGS[1]), _random_cal(rng, **FLAGS[2]), FIX):
        shape = (cal.quilt_height, cal.quilt_width, 3)
        il = Interleaver(cal, shape, backend="numba")
        q = rng.integers(0, 256, shape, dtype=np.uint8)
        il.row_kernel = "numba"
        want = il(q).copy()
        il.row_kernel = kernel
        np.testing.assert_array_equal(il(q), want)
        np.testing.assert_array_equal(want, np.take(q.reshape(-1), il._idx0).reshape(il.shape))
    view8, rowpart, colpart = il._rows
    src = q.reshape(-1)
    bad = rowpart.copy()
    bad[5, :] = src.size  # every view of row 5 past the quilt's end
    with pytest.raises(ValueError, match="outside src"):
        cpp.gather_rows(src, view8, bad, colpart, np.empty(il.shape, np.uint8), *view8.shape, rowpart.shape[1], 1, 0)

def test_fixture_full_size_every_subpixel():
    rng = np.random.default_rng(0)
    q = rng.integers(0, 256, (3360, 3360, 3), dtype=np.uint8)
    il = Interleaver(FIX, q.shape)
    v0, _, _ = reference_views(FIX, 48)
    assert np.array_equal(il.view_index, v0)
    assert np.array_equal(il(q), interleave_reference(q, FIX).astype(np.uint8))
    assert il(q).shape == (2048, 1536, 3)
    counts = np.bincount(il.view_index.ravel(), minlength=48)
    assert counts.min() > 0.8 * counts.mean()  # every view gets its share of subpixels


def test_flat_views_give_slanted_stripes():
    views = np.zeros((48, 560, 420, 3), np.uint8)
    views[..., 0] = np.arange(48)[:, None, None] * 5  # view id in red
    views[..., 1] = np.arange(48)[:, None, None] * 5
    views[..., 2] = np.arange(48)[:, None, None] * 5
    native = Interleaver(FIX, (3360, 3360, 3))(tile_quilt(views, 8, 6))
    vid = native[..., 1] // 5
    # along a row the view index is periodic with the lens period (W / pitch' pixels)
    pitch_px = FIX.pitch * 1536 / 324 * math.cos(math.atan(1 / FIX.slope))
    period = 1536 / pitch_px
    row = vid[1000].astype(int)
    jumps = np.flatnonzero(np.diff(row) > 24)  # wrap from the high views back to the low ones
    assert np.median(np.diff(jumps)) == pytest.approx(period, abs=1.0)
    # stripes are slanted: the pattern shifts by (H/slope)/pitch-ish between rows
    shift = np.argmax([np.sum(vid[1000, 100:400] == np.roll(vid[1001], -s)[100:400]) for s in range(-3, 4)]) - 3
    assert shift != 0 or np.any(vid[1000] != vid[1001])


def test_nominal_warns_and_bad_inputs():
    with pytest.warns(UserWarning, match="nominal"):
        Interleaver(DisplayCalibration.preset("go"), (4092, 4092))
    il = Interleaver(replace(FIX, screen_w=64, screen_h=48), (60, 80, 3), cols=4, rows=3)
    with pytest.raises(InputError, match="quilt"):
        il(np.zeros((61, 80, 3), np.uint8))
    with pytest.raises(InputError, match="dtype"):
        il(np.zeros((60, 80, 3), np.int32))
    with pytest.raises(InputError, match="mode"):
        Interleaver(FIX, (60, 80), mode="cubic")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Interleaver(replace(FIX, screen_w=32, screen_h=32), (60, 80), cols=4, rows=3)
