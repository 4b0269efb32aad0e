"""Virtual display: each view is recovered from its own angle; crosstalk is reported."""

import numpy as np
import pytest

from holo_viewer.display.calibration import DisplayCalibration, default_calibration_path
from holo_viewer.display.lenticular import Interleaver
from holo_viewer.display.quilt import tile_quilt
from holo_viewer.display.simulate import VirtualDisplay, identify_bar, id_pattern_views
from holo_viewer.errors import InputError

FIX = DisplayCalibration.from_file(str(default_calibration_path()))


@pytest.fixture(scope="module")
def setup():
    q = tile_quilt(id_pattern_views(48, 560, 420, "bars"), 8, 6)
    return VirtualDisplay(FIX), Interleaver(FIX, q.shape)(q)


@pytest.mark.parametrize("view", [0, 24, 47])
def test_view_recovered_at_its_angle(setup, view):
    vd, native = setup
    seen = vd.see(native, vd.view_angle(view))
    slot, means = identify_bar(seen, 48)
    assert slot == view
    assert means[view] > 1.5 * np.delete(means, view).max()
    frac = vd.light_fractions(vd.view_angle(view))
    assert np.argmax(frac) == view and frac[view] > 0.6
    assert vd.crosstalk(vd.view_angle(view)) == pytest.approx(1 - frac[view])


def test_wrong_calibration_fails_to_recover(setup):
    """A display simulated with a different lens phase does not show view i at view i's angle."""
    from dataclasses import replace

    _, native = setup
    vd = VirtualDisplay(replace(FIX, center=FIX.center + 0.25))
    assert identify_bar(vd.see(native, vd.view_angle(24)), 48)[0] != 24


@pytest.mark.slow
def test_all_views_and_finite_distance(setup):
    vd, native = setup
    assert all(identify_bar(vd.see(native, vd.view_angle(i)), 48)[0] == i for i in range(1, 48, 6))
    # at 0.6 m the eye sees different views across the panel: the centre column still shows view 24
    seen = vd.see(native, vd.view_angle(24), distance_m=0.6)
    centre = seen[:, seen.shape[1] // 2 - 20: seen.shape[1] // 2 + 20]
    assert identify_bar(np.pad(centre, ((0, 0), (172, 172), (0, 0))), 48)[0] == 24


@pytest.mark.parametrize("shape, window, stride", [((37, 29, 3), (10, 7), 4), ((16, 12, 1), (20, 5), 3),
                                                   ((9, 40, 2), (3, 50), 1), ((25, 25, 3), (1, 1), 5)])
def test_window_sums_equal_exact_sums(shape, window, stride):
    """The perceived image's window sums against math.fsum of each window (shifted inside the
    image, never cut; windows larger than the image cover it): within 1e-12 relative."""
    import math

    from holo_viewer.display.simulate import _box

    a = np.random.default_rng(sum(shape)).random(shape)
    got = _box(a, window, stride)
    H, W = shape[:2]
    wy, wx = window
    assert got.shape == (H // stride, W // stride, shape[2])
    for i in range(H // stride):
        for j in range(W // stride):
            y0 = min(max(i * stride + stride // 2 - wy // 2, 0), max(H - wy, 0))
            x0 = min(max(j * stride + stride // 2 - wx // 2, 0), max(W - wx, 0))
            for c in range(shape[2]):
                exact = math.fsum(a[y0:y0 + wy, x0:x0 + wx, c].ravel())
                assert abs(got[i, j, c] - exact) <= 1e-12 * max(1.0, exact)


def test_see_many_is_see_of_each(setup):
    """One eye position, several images: the same perceived images as one see() each."""
    disp = setup[0]
    cal = disp.cal
    rng = np.random.default_rng(3)
    imgs = [rng.integers(0, 256, (cal.screen_h, cal.screen_w, 3), dtype=np.uint8) for _ in range(2)]
    imgs.append(imgs[0] / 255.0)
    many = disp.see_many(imgs, 7.0, 0.55)
    for img, got in zip(imgs, many):
        np.testing.assert_array_equal(got, disp.see(img, 7.0, 0.55))
    np.testing.assert_array_equal(many[0], many[2])
    with pytest.raises(InputError, match="native"):
        disp.see_many([imgs[0], imgs[0][:-1]], 0.0)


def test_weights_are_the_beam_formula_bit_for_bit():
    """VirtualDisplay.weights (computed in place) equals exp(-0.5 ((mod(zeta - t + N/2, N) - N/2) / sigma)^2)
    written plainly, exactly, at infinity and at finite distances (a 384 x 512 panel of the Portrait's optics)."""
    from dataclasses import replace

    vd = VirtualDisplay(replace(FIX, screen_w=384, screen_h=512), sigma_views=0.7)
    n = vd.n_views
    for angle, dist in ((0.0, None), (13.0, 0.6), (-19.0, 2.5)):
        t = vd._eye_coordinate(angle, dist)[None, :, None]
        want = np.exp(-0.5 * ((np.mod(vd.zeta - t + n / 2.0, n) - n / 2.0) / vd.sigma) ** 2)
        got = vd.weights(angle, dist)
        assert got.shape == (512, 384, 3) and got.dtype == np.float64
        np.testing.assert_array_equal(got, want)
    assert not np.array_equal(vd.weights(1.0, 0.6), vd.weights(1.5, 0.6))  # another eye, other weights
