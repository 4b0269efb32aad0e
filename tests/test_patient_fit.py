"""Fitting the patients' avatars (issue 35): the fit's angle range stored in the avatar file, sheared
training cameras (world-fixed lights), the binding transfer to another identity and a fit step on it."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")

from holo_viewer.assets_build import fit_avatar as fa  # noqa: E402
from holo_viewer.avatar.default_gaussians import load_fitted_avatar, save_fitted_avatar  # noqa: E402
from holo_viewer.errors import AvatarError, InputError  # noqa: E402
from holo_viewer.pipeline import Pipeline, ViewSettings  # noqa: E402
from holo_viewer.testing import random_flame_model, random_gaussians  # noqa: E402


def _tiny_asset(tmp_path, **kw):
    model = random_flame_model(n_vertices=40, seed=1)
    g = random_gaussians(20, sh_degree=1, seed=0)
    binding = np.arange(20) % int(model.faces.shape[0])
    head = tmp_path / "head.npz"
    head.write_bytes(b"head")
    return save_fitted_avatar(tmp_path / "a.npz", g, binding, model, "test", head_path=head, **kw)


def test_fit_angle_range_round_trip_and_bad_values(tmp_path):
    path = _tiny_asset(tmp_path, fit_angle_range_deg=(-30.0, 29.5))
    assert load_fitted_avatar(path)[2]["fit_angle_range_deg"] == [-30.0, 29.5]
    assert load_fitted_avatar(_tiny_asset(tmp_path))[2]["fit_angle_range_deg"] is None  # older files
    with pytest.raises(InputError, match="fit_angle_range_deg"):
        _tiny_asset(tmp_path, fit_angle_range_deg=(10.0, -10.0))
    z = dict(np.load(path))
    z["fit_angle_range_deg"] = np.array([1.0, np.nan])
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(AvatarError, match=r"bad\.npz.*fit_angle_range_deg"):
        load_fitted_avatar(tmp_path / "bad.npz")


def test_sheared_cameras_keep_the_orientation_and_the_centre_pixel():
    """A sheared camera (fit_avatar.sheared_cameras) keeps the quilt camera's rotation (so the mesh
    render's camera-set lights stay world-fixed), puts the framing centre at the same pixel, sits at the
    asked yaw; the quilt's own outermost view at the slider's limit is such a camera (same rotation,
    yaw -30 deg)."""
    pipe = Pipeline(model=random_flame_model(n_vertices=60, seed=0), avatar=False,
                    view=ViewSettings(tile_scale=0.1))
    cams = pipe.cameras()
    (framing,), _ = pipe.compute("framing")
    c = np.asarray(framing[0], np.float64)
    sh = fa.sheared_cameras(cams, 24, [(-30.0, 0.0), (20.0, -10.0)], c)
    yaws = fa.camera_yaws(sh, c)
    np.testing.assert_allclose(yaws, [-30.0 + fa.camera_yaws(cams, c)[24], 20.0 + fa.camera_yaws(cams, c)[24]],
                               atol=0.05)  # the pitch turns the horizontal angle a little

    def pix(w2c, K):
        p = K @ (w2c[:3, :3] @ c + w2c[:3, 3])
        return p[:2] / p[2]

    for k in range(2):
        np.testing.assert_allclose(sh.world_to_cam[k][:3, :3], cams.world_to_cam[24][:3, :3], atol=1e-12)
        np.testing.assert_allclose(pix(sh.world_to_cam[k], sh.K[k]), pix(cams.world_to_cam[24], cams.K[24]),
                                   atol=1e-9)
    ro = fa.orbit_cameras(cams, 24, [(-30.0, 0.0)], c)  # the first fit's: turned, so its lights turn too
    assert not np.allclose(ro.world_to_cam[0][:3, :3], cams.world_to_cam[24][:3, :3], atol=1e-3)
    lim = Pipeline(model=pipe.model, avatar=False, view=ViewSettings(tile_scale=0.1, viewer_angle=-10.0)).cameras()
    np.testing.assert_allclose(lim.world_to_cam[0][:3, :3], cams.world_to_cam[24][:3, :3], atol=1e-12)
    assert fa.camera_yaws(lim, c)[0] == pytest.approx(-30.0, abs=0.5)
