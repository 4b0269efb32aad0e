"""Camera conventions (docs/design.md section 3), stated in holo_viewer/camera.py and tested once here."""

import numpy as np
import pytest

from holo_viewer.camera import Cameras, intrinsics, look_at, opencv_to_opengl
from holo_viewer.errors import InputError


def front_camera(width=420, height=560, f=800.0):
    return Cameras(look_at([0, 0, 1.0], [0, 0, 0]), intrinsics(f, f, width / 2, height / 2), width, height)


def test_front_camera_axes_follow_opencv():
    cam = front_camera()
    # world +x (viewer's right) -> image right, world +y (up) -> image up (smaller row)
    uv, z = cam.project(np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]))
    assert np.allclose(uv[0, 0], [210, 280])
    assert uv[0, 1, 0] > 210 and np.isclose(uv[0, 1, 1], 280)
    assert uv[0, 2, 1] < 280 and np.isclose(uv[0, 2, 0], 210)
    assert np.allclose(z, 1.0)
    assert np.allclose(cam.positions, [[0, 0, 1]])


def test_pixel_centre_convention():
    # a point on the optical axis of a camera with cx = W/2 lands on the boundary between the two
    # middle columns: pixel (row i, col j) has its centre at (j + 0.5, i + 0.5)
    cam = Cameras(look_at([0, 0, 1.0], [0, 0, 0]), intrinsics(100, 100, 2.5, 1.5), 5, 3)
    uv, _ = cam.project(np.zeros((1, 3)))
    col, row = np.floor(uv[0, 0]).astype(int)
    assert (row, col) == (1, 2)  # centre pixel of a 5x3 image


def test_opengl_conversion_matches_opencv_pixels():
    rng = np.random.default_rng(0)
    cam = Cameras(look_at([0.1, -0.05, 0.9], [0, 0.02, 0]), intrinsics(700, 710, 230.0, 270.0), 420, 560, 0.05, 5.0)
    pts = rng.uniform(-0.1, 0.1, size=(20, 3))
    uv, depth = cam.project(pts)
    view, proj = opencv_to_opengl(cam)
    hom = np.c_[pts, np.ones(len(pts))]
    clip = hom @ (proj[0] @ view[0]).T
    ndc = clip[:, :3] / clip[:, 3:]
    px = (ndc[:, 0] + 1) / 2 * cam.width
    py = (1 - ndc[:, 1]) / 2 * cam.height
    assert np.allclose(px, uv[0, :, 0], atol=1e-9)
    assert np.allclose(py, uv[0, :, 1], atol=1e-9)
    # depth maps monotonically into [-1, 1] between near and far
    assert np.all((ndc[:, 2] > -1) & (ndc[:, 2] < 1))
    eye = hom @ view[0].T
    assert np.allclose(-eye[:, 2], depth[0])


def test_batch_indexing_and_dict_round_trip():
    cams = Cameras.concatenate([front_camera(), front_camera(f=900.0)])
    assert len(cams) == 2 and cams.shared_orientation
    back = Cameras.from_dicts(cams.to_dicts())
    assert np.allclose(back.world_to_cam, cams.world_to_cam) and np.allclose(back.K, cams.K)
    assert len(cams[1:]) == 1 and cams[1].fx[0] == 900.0


@pytest.mark.parametrize("bad, field", [
    ({"width": 10, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5}, "world_to_cam"),
    ({"width": 10, "height": 10, "fx": 1, "fy": 1, "cx": 5, "world_to_cam": np.eye(4).tolist()}, "cy"),
    ({"width": 10, "height": 10, "fx": "a", "fy": 1, "cx": 5, "cy": 5, "world_to_cam": np.eye(4).tolist()}, "fx"),
    ({"width": 10, "height": 10, "fx": 1, "fy": 1, "cx": 5, "cy": 5, "world_to_cam": [[1, 2], [3, 4]]},
     "world_to_cam"),
])
def test_from_dicts_errors_name_the_field(bad, field):
    with pytest.raises(InputError, match=field):
        Cameras.from_dicts([bad])


def test_invalid_cameras_rejected():
    with pytest.raises(InputError, match="rotation"):
        Cameras(np.diag([2.0, 1, 1, 1]), intrinsics(1, 1, 0, 0), 4, 4)
    with pytest.raises(InputError, match="far"):
        Cameras(np.eye(4), intrinsics(1, 1, 0, 0), 4, 4, near=1.0, far=0.5)
    with pytest.raises(InputError, match="fx"):
        Cameras(np.eye(4), intrinsics(-1, 1, 0, 0), 4, 4)
    with pytest.raises(InputError, match="finite"):
        Cameras(np.eye(4), intrinsics(np.nan, 1, 0, 0), 4, 4)
