"""Algorithm 1 quilt cameras against a direct evaluation of the SDK formula."""

import math

import numpy as np
import pytest

from holo_viewer.camera import opencv_to_opengl
from holo_viewer.display.calibration import DisplayCalibration, default_calibration_path
from holo_viewer.display.cameras import fov_for_viewer_distance, make_quilt_cameras, sdk_view_projection
from holo_viewer.errors import InputError

CAL = DisplayCalibration.from_file(str(default_calibration_path()))


def _sdk_scalars(n, cone, fov, size, angle=0.0):
    """camDist and offsets written out once more, element by element (no numpy broadcasting)."""
    cam_dist = -size / math.tan(math.radians(fov) / 2)
    offs = [cam_dist * math.tan(math.radians((i / (n - 1) - 0.5) * cone + angle)) for i in range(n)]
    return cam_dist, offs


@pytest.mark.parametrize("center,fwd,up,size,fov,angle", [
    ((0, 0, 0), (0, 0, -1), (0, 1, 0), 5.0, 14.0, 0.0),
    ((0.1, 1.6, -0.3), (0, 0, -1), (0, 1, 0), 0.12, 14.0, 7.5),
    ((1, 2, 3), (0.3, -0.2, -1), (0, 1, 0), 0.3, 20.0, -4.0),
])
def test_matches_sdk_to_1e12(center, fwd, up, size, fov, angle):
    cams = make_quilt_cameras(CAL, focal_center=center, size=size, fov_deg=fov, viewer_angle_deg=angle,
                              near=0.05, far=50.0, forward=fwd, up=up)
    assert len(cams) == 48 and (cams.width, cams.height) == (420, 560) and cams.shared_orientation
    # base GL view: the centre camera placed at the focal-plane centre
    f = np.asarray(fwd, float) / np.linalg.norm(fwd)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    base = np.eye(4)
    base[:3, :3] = np.stack([r, u, -f])
    base[:3, 3] = -base[:3, :3] @ np.asarray(center, float)
    V_sdk, P_sdk = sdk_view_projection(48, 40.0, fov, size, 420 / 560, 0.05, 50.0, base, angle)
    V, P = opencv_to_opengl(cams)
    assert np.abs(V - V_sdk).max() < 1e-12 * max(1.0, np.abs(center).max())
    assert np.abs(P - P_sdk).max() < 1e-12
    cam_dist, offs = _sdk_scalars(48, 40.0, fov, size, angle)
    for i in (0, 17, 47):
        assert P_sdk[i, 0, 2] == pytest.approx(offs[i] / (size * 420 / 560), abs=1e-15)
        assert V_sdk[i, 0, 3] - base[0, 3] == pytest.approx(offs[i], abs=1e-12)
        assert V_sdk[i, 2, 3] - base[2, 3] == pytest.approx(cam_dist, abs=1e-12)


def test_focal_centre_same_pixel_and_ordering():
    c = np.array([0.05, 1.55, 0.2])
    cams = make_quilt_cameras(CAL, focal_center=c, size=0.15)
    uv, depth = cams.project(c[None])
    assert np.abs(uv[:, 0] - [210.0, 280.0]).max() < 1e-9
    assert np.allclose(depth, depth[0])
    # a point in front of the focal plane has parallax; a focal-plane corner does not move
    corner = c + np.array([0.15 * 0.75, 0.15, 0.0])
    uv2, _ = cams.project(corner[None])
    assert np.abs(uv2[:, 0] - uv2[0, 0]).max() < 1e-9
    x = cams.positions[:, 0]
    assert np.all(np.diff(x) > 0)  # view 0 leftmost, increasing to the right
    rel = cams.positions - c
    assert np.allclose(rel[:, 0], -rel[::-1, 0], atol=1e-12)  # symmetric offsets
    assert np.allclose(rel[:, 2], rel[0, 2])


def test_viewer_distance_sets_fov_and_angle_shift():
    h = CAL.physical_size_m[1]
    assert fov_for_viewer_distance(h, 0.6) == pytest.approx(math.degrees(2 * math.atan(h / 1.2)))
    cams = make_quilt_cameras(CAL, focal_center=(0, 0, 0), size=0.1, viewer_distance=0.6)
    assert cams.tan_half_fov()[1][0] == pytest.approx(h / 1.2)
    shifted = make_quilt_cameras(CAL, focal_center=(0, 0, 0), size=0.1, viewer_angle_deg=10.0)
    x = shifted.positions[:, 0]
    assert x.mean() > 0 and np.all(np.diff(x) > 0)


def test_bad_arguments():
    with pytest.raises(InputError, match="size"):
        make_quilt_cameras(CAL, focal_center=(0, 0, 0), size=0.0)
    with pytest.raises(InputError, match="focal_center"):
        make_quilt_cameras(CAL, focal_center=(0, 0), size=1.0)
    with pytest.raises(InputError, match="up"):
        make_quilt_cameras(CAL, focal_center=(0, 0, 0), size=1.0, up=(0, 0, 1))
