"""Virtual display: each view is recovered from its own angle; crosstalk is reported."""

import numpy as np
import pytest

from holo_viewer.display.calibration import DisplayCalibration
from holo_viewer.display.lenticular import Interleaver
from holo_viewer.display.quilt import tile_quilt
from holo_viewer.display.simulate import VirtualDisplay, identify_bar, id_pattern_views

FIX = DisplayCalibration.from_file("/work/shared/fixtures/lkg_portrait_visual.json")


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
