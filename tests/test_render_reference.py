"""Float64 reference renderer on hand-checkable scenes (docs/design.md "3DGS forward pass")."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.camera import Cameras, intrinsics
from holo_viewer.errors import InputError
from holo_viewer.render import RenderConfig, render_views
from holo_viewer.render.projection import clamp_limits, pixel_box, project_gaussians
from holo_viewer.render.sh import C0, C1, eval_sh, sh_basis

F, W, H = 100.0, 21, 21


def camera(width: int = W, height: int = H, cx: float | None = None) -> Cameras:
    """Camera at the origin looking along world +z (identity world_to_cam), centre pixel (10, 10)."""
    cx = width / 2.0 if cx is None else cx
    return Cameras(np.eye(4), intrinsics(F, F, cx, height / 2.0), width, height, near=0.01, far=100.0)


def gaussians(means, scales, opacity, colors) -> Gaussians:
    """Isotropic-or-not Gaussians with degree-0 SH giving exactly ``colors``."""
    means = np.atleast_2d(np.asarray(means, dtype=np.float64))
    n = means.shape[0]
    scales = np.broadcast_to(np.asarray(scales, dtype=np.float64), (n, 3))
    op = np.broadcast_to(np.asarray(opacity, dtype=np.float64), (n,))
    colors = np.broadcast_to(np.asarray(colors, dtype=np.float64), (n, 3))
    sh = ((colors - 0.5) / C0)[:, None, :]
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return Gaussians.from_arrays(means, quats, np.log(scales), np.log(op / (1 - op)), sh)


def render(g: Gaussians, cams: Cameras | None = None, **cfg) -> np.ndarray:
    return render_views(g, cams or camera(), "reference", RenderConfig(**cfg)).images.astype(np.float64)


def test_single_gaussian_centre_and_falloff():
    s, z, o = 0.02, 2.0, 0.8
    c = np.array([0.9, 0.3, 0.1])
    bg = (0.2, 0.4, 0.6)
    img = render(gaussians([0, 0, z], s, o, c), background=bg)[0]
    alpha = min(0.99, o)
    np.testing.assert_allclose(img[10, 10], alpha * c + (1 - alpha) * np.array(bg), atol=1e-6)
    # 2D variance (F s / z)^2 + 0.3 (dilation): check a pixel 2 columns right of the centre
    var = (F * s / z) ** 2 + 0.3
    a2 = o * np.exp(-0.5 * 4.0 / var)
    np.testing.assert_allclose(img[10, 12], a2 * c + (1 - a2) * np.array(bg), atol=1e-6)
    # symmetric falloff: mirror images in x, y and the diagonal
    np.testing.assert_allclose(img, img[::-1], atol=1e-6)
    np.testing.assert_allclose(img, img[:, ::-1], atol=1e-6)
    np.testing.assert_allclose(img, img.transpose(1, 0, 2), atol=1e-6)
    # monotone falloff from the centre along the row
    lum = img[10, 10:, 0]
    assert np.all(np.diff(lum) <= 1e-12)


def test_radius_cuts_the_tails():
    # 2D variance 8.7 px^2: radius ceil(3 * 2.95) = 9 px; with a low alpha threshold only the
    # radius box limits the splat
    s, z, o = np.sqrt(8.4) * 2.0 / F, 2.0, 0.99
    img = render(gaussians([0, 0, z], s, o, [1, 1, 1]), alpha_threshold=1e-4)[0]
    var = (F * s / z) ** 2 + 0.3
    r = int(np.ceil(3 * np.sqrt(var)))
    assert r == 9
    assert img[10, 10 + r, 0] > 0          # centre distance r: inside the box
    assert img[10, 10 + r + 1, 0] == 0     # one pixel further (alpha ~ 3e-3): outside, exactly background
    # with the default threshold 1/255 the alpha test removes that pixel too
    img = render(gaussians([0, 0, z], s, o, [1, 1, 1]), radius_sigmas=5.0)[0]
    assert img[10, 10 + r + 1, 0] == 0


def test_depth_order_not_input_order():
    red, blue = [1, 0, 0], [0, 0, 1]
    a1, a2 = 0.7, 0.6
    g1 = gaussians([[0, 0, 2.0], [0, 0, 3.0]], 0.02, [a1, a2], [red, blue])
    g2 = gaussians([[0, 0, 3.0], [0, 0, 2.0]], 0.02, [a2, a1], [blue, red])
    bg = np.array([0.0, 1.0, 0.0])
    want = a1 * np.array(red) + (1 - a1) * a2 * np.array(blue) + (1 - a1) * (1 - a2) * bg
    for g in (g1, g2):
        np.testing.assert_allclose(render(g, background=tuple(bg))[0][10, 10], want, atol=1e-6)


def test_early_termination():
    cols = np.eye(3)
    g = gaussians([[0, 0, 2.0], [0, 0, 2.5], [0, 0, 3.0]], 0.05, 0.995, cols)
    bg = np.ones(3)
    a = 0.99  # alpha cap
    T1 = 1 - a
    T2 = T1 * (1 - a)  # 1.0000000000000018e-4 >= t_min: the second splat blends, the pixel goes on
    T3 = T2 * (1 - a)
    assert T2 >= 1e-4 and T3 < 1e-4  # the third takes T below 1e-4: it blends, then the pixel stops
    want = a * cols[0] + T1 * a * cols[1] + T2 * a * cols[2] + T3 * bg
    np.testing.assert_allclose(render(g, background=(1.0, 1.0, 1.0))[0][10, 10], want, atol=1e-9)
    # a fourth splat behind is not blended
    g4 = gaussians([[0, 0, 2.0], [0, 0, 2.5], [0, 0, 3.0], [0, 0, 3.5]], 0.05, 0.995, np.vstack([cols, [1, 1, 0]]))
    np.testing.assert_allclose(render(g4, background=(1.0, 1.0, 1.0))[0][10, 10], want, atol=1e-9)


def test_background_and_culling():
    bg = (0.25, 0.5, 0.75)
    # behind the camera, at the near plane, and below the alpha threshold: nothing drawn
    g = gaussians([[0, 0, -1.0], [0, 0, 0.01], [0, 0, 2.0]], 0.02, [0.9, 0.9, 0.5 / 255], [1, 1, 1])
    np.testing.assert_array_equal(render(g, background=bg)[0], np.broadcast_to(np.float32(bg), (H, W, 3)))


def test_sh_direction_convention():
    # a Gaussian straight ahead (+z from the camera): dir = (0, 0, 1), degree-1 basis = (-C1 y, C1 z, -C1 x)
    sh = np.zeros((1, 4, 3))
    sh[0, 0] = 0.1
    sh[0, 2] = 0.5  # z coefficient
    g = Gaussians.from_arrays(np.array([[0, 0, 2.0]]), np.array([[1.0, 0, 0, 0]]), np.log(np.full((1, 3), 0.02)),
                              np.array([10.0]), sh)
    img = render(g)[0]
    rgb = C0 * 0.1 + C1 * 0.5 + 0.5
    alpha = 0.99
    np.testing.assert_allclose(img[10, 10], alpha * rgb, atol=1e-6)
    # and the lower SH degree knob drops the term
    img0 = render(g, sh_degree=0)[0]
    np.testing.assert_allclose(img0[10, 10], alpha * (C0 * 0.1 + 0.5), atol=1e-6)


def test_sh_basis_orthonormal():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    B = sh_basis(3, d)
    gram = B.T @ B * (4 * np.pi / d.shape[0])
    np.testing.assert_allclose(gram, np.eye(16), atol=0.03)
    sh = rng.normal(size=(5, 16, 3))
    dirs = d[:5]
    np.testing.assert_allclose(eval_sh(3, sh, dirs), np.einsum("nk,nkc->nc", B[:5], sh), atol=1e-12)


def test_projection_clamp_limits_centred_is_inria():
    lo_x, hi_x, lo_y, hi_y = clamp_limits(100.0, 120.0, 32.0, 24.0, 64, 48)
    tan_x, tan_y = 64 / 200.0, 48 / 240.0
    np.testing.assert_allclose([lo_x, hi_x, lo_y, hi_y], [-1.3 * tan_x, 1.3 * tan_x, -1.3 * tan_y, 1.3 * tan_y])


def test_projection_matches_formula():
    rng = np.random.default_rng(1)
    means = rng.normal(size=(4, 3)) * 0.1 + [0, 0, 2]
    A = rng.normal(size=(4, 3, 3)) * 0.02
    cov = A @ A.transpose(0, 2, 1)
    K = intrinsics(F, F, 10.5, 10.5)
    p = project_gaussians(means, cov, np.eye(4), K, W, H, 0.01)
    for i in range(4):
        x, y, z = means[i]
        J = np.array([[F / z, 0, -F * x / z**2], [0, F / z, -F * y / z**2]])
        S = J @ cov[i] @ J.T + 0.3 * np.eye(2)
        np.testing.assert_allclose(p.cov2d[i], [S[0, 0], S[0, 1], S[1, 1]], rtol=1e-12)
        inv = np.linalg.inv(S)
        np.testing.assert_allclose(p.conic[i], [inv[0, 0], inv[0, 1], inv[1, 1]], rtol=1e-10)
        assert p.radius[i] == np.ceil(3 * np.sqrt(np.linalg.eigvalsh(S).max()))
        np.testing.assert_allclose(p.uv[i], [F * x / z + 10.5, F * y / z + 10.5])


def test_pixel_box_uses_pixel_centres():
    # pixel j has its centre at j + 0.5: a radius-1 box around u = 5.5 covers columns 4, 5, 6
    assert pixel_box(5.5, 5.5, 1.0, 20, 20) == (4, 7, 4, 7)
    x0, x1, _, _ = pixel_box(-100.0, 5.5, 1.0, 20, 20)
    assert x0 >= x1  # entirely left of the image: empty


def test_rejects_bad_inputs():
    g = gaussians([0, 0, 2.0], 0.02, 0.5, [1, 1, 1])
    bad = g.replace(means=np.array([[np.nan, 0, 2.0]]))
    with pytest.raises(InputError, match="means"):
        render_views(bad, camera(), "reference")
    with pytest.raises(InputError, match="backend"):
        render_views(g, camera(), "nope")
