"""Multi-view quilt cameras, Algorithm 1 of the seed paper / HoloPlayCore SDK example (pure math).

SDK formulation (OpenGL, one view ``i`` of ``N``)::

    camDist  = -size / tan(fov / 2)                       # size = focal-plane half-height
    alpha_i  = (i / (N - 1) - 0.5) * viewCone             # + viewer angle (viewer-adaptive)
    offset_i = camDist * tan(alpha_i)
    view_i   = translate(view, (offset_i, 0, camDist))    # move the camera along its own x
    proj_i   = perspective(fov, aspect, near, far);  proj_i[2][0] += offset_i / (size * aspect)

``proj[2][0]`` is glm's column-major indexing, i.e. row 0, column 2 of a row-major matrix: the
off-axis shear. In OpenCV terms (what :func:`make_quilt_cameras` returns) camera ``i`` sits at
``focal_center - D * forward + x_i * right`` with ``D = size / tan(fov/2)`` and
``x_i = -offset_i = D tan(alpha_i)``; all cameras share one rotation; ``fx = fy = H / (2 tan(fov/2))``
and the shear is the principal point ``cx_i = W/2 * (1 - offset_i / (size * aspect))``, which keeps
the focal-plane centre at pixel ``(W/2, H/2)`` in every view. View 0 is the leftmost camera.

Viewer distance -> fov (seed paper): for the focal plane to coincide with the physical panel seen
from a viewer at distance ``d`` (metres), the frustum must subtend the panel's height ``h``::

    fov(d) = 2 * atan(h / (2 d)),       h = screenH / DPI * 0.0254

so the virtual camera distance is ``D = size * 2 d / h``: the scene is the real viewing geometry
scaled by ``size / (h/2)``. For the Portrait (h = 0.1606 m): fov(0.6 m) = 15.3 deg, fov(0.65 m) = 14.1 deg
(the SDK's 14 deg corresponds to ~0.65 m).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..camera import Cameras, opencv_to_opengl
from ..errors import InputError
from ..validation import check_finite_scalar
from .calibration import DisplayCalibration

__all__ = ["make_quilt_cameras", "fov_for_viewer_distance", "view_angles", "sdk_view_projection",
           "quilt_cameras_to_opengl", "VIEWER_ANGLE_LIMIT_DEG"]


#: a tracked viewer's horizontal angle (degrees) is accepted within +- this (also ViewSettings.viewer_angle)
VIEWER_ANGLE_LIMIT_DEG = 60.0

def fov_for_viewer_distance(panel_height_m: float, distance_m: float) -> float:
    """Vertical fov (degrees) at which the focal plane matches a panel of height ``panel_height_m``
    seen from ``distance_m`` metres: ``2 atan(h / 2d)``."""
    h = check_finite_scalar(panel_height_m, "panel_height_m", low=0.0, low_open=True)
    d = check_finite_scalar(distance_m, "viewer_distance", low=0.0, low_open=True)
    return math.degrees(2.0 * math.atan(h / (2.0 * d)))


def view_angles(n_views: int, view_cone_deg: float, viewer_angle_deg: float = 0.0) -> np.ndarray:
    """(N,) view angles in degrees: ``(i/(N-1) - 0.5) * cone + viewer_angle`` (0 for N = 1)."""
    if n_views < 1:
        raise InputError(f"n_views: expected >= 1, found {n_views}")
    if n_views == 1:
        return np.array([float(viewer_angle_deg)])
    i = np.arange(n_views, dtype=np.float64)
    return (i / (n_views - 1) - 0.5) * float(view_cone_deg) + float(viewer_angle_deg)


def _resolve(calibration_or_preset: "DisplayCalibration | str | None") -> DisplayCalibration:
    if isinstance(calibration_or_preset, DisplayCalibration):
        return calibration_or_preset
    return DisplayCalibration.load(calibration_or_preset)


def make_quilt_cameras(
    calibration_or_preset: "DisplayCalibration | str | None",
    *,
    focal_center: Sequence[float],
    size: float,
    fov_deg: float = 14.0,
    n_views: int | None = None,
    view_cone_deg: float | None = None,
    viewer_angle_deg: float = 0.0,
    viewer_distance: float | None = None,
    tile_width: int | None = None,
    tile_height: int | None = None,
    near: float = 0.01,
    far: float = 10.0,
    forward: Sequence[float] = (0.0, 0.0, -1.0),
    up: Sequence[float] = (0.0, 1.0, 0.0),
) -> Cameras:
    """One OpenCV camera per quilt view (Algorithm 1), view 0 leftmost.

    Parameters
    ----------
    calibration_or_preset : DisplayCalibration or str or None
        Calibration, preset name / visual.json path, or None for the shipped Portrait calibration.
        Supplies the default view count, view cone and tile size.
    focal_center : (3,) array-like
        World point (metres) at the centre of the focal plane (zero-parallax plane).
    size : float
        Half-height of the focal plane in metres (> 0).
    fov_deg : float
        Vertical field of view in degrees (ignored when ``viewer_distance`` is given).
    n_views, view_cone_deg : optional
        Override the calibration's view count and cone (degrees).
    viewer_angle_deg : float
        Shift of the cone centre toward a tracked viewer (degrees, + = toward the camera's right).
    viewer_distance : float, optional
        Metres from the panel; sets ``fov = 2 atan(h / 2d)`` with h the panel height.
    tile_width, tile_height : int, optional
        Image size of each view (default: the calibration's quilt tile).
    near, far : float
        Clip distances in metres (OpenCV +z).
    forward, up : (3,) array-like
        World viewing direction and world up.

    Returns
    -------
    Cameras
        V cameras sharing one orientation; ``world_to_cam`` (V, 4, 4), ``K`` (V, 3, 3).
    """
    cal = _resolve(calibration_or_preset)
    center = np.asarray(focal_center, dtype=np.float64)
    if center.shape != (3,) or not np.all(np.isfinite(center)):
        raise InputError(f"focal_center: expected 3 finite numbers, found {np.asarray(focal_center).tolist()}")
    size = check_finite_scalar(size, "size", low=0.0, low_open=True)
    if viewer_distance is not None:
        fov_deg = fov_for_viewer_distance(cal.physical_size_m[1], viewer_distance)
    fov_deg = check_finite_scalar(fov_deg, "fov_deg", low=0.0, low_open=True)
    if fov_deg >= 179.0:
        raise InputError(f"fov_deg: expected < 179, found {fov_deg}")
    n = int(n_views if n_views is not None else cal.n_views)
    cone = check_finite_scalar(view_cone_deg if view_cone_deg is not None else cal.view_cone,
                               "view_cone_deg", low=0.0, high=170.0)
    lim = VIEWER_ANGLE_LIMIT_DEG
    check_finite_scalar(viewer_angle_deg, "viewer_angle_deg", low=-lim, high=lim)
    W = int(tile_width if tile_width is not None else cal.tile_width)
    H = int(tile_height if tile_height is not None else cal.tile_height)
    if W <= 0 or H <= 0:
        raise InputError(f"tile_width, tile_height: expected positive, found {W} x {H}")
    alphas = np.radians(view_angles(n, cone, viewer_angle_deg))
    if np.any(np.abs(alphas) >= np.radians(89.0)):
        raise InputError(f"view angles: expected within +-89 deg, found up to {np.degrees(np.abs(alphas).max()):.1f}")

    fwd = np.asarray(forward, dtype=np.float64)
    upv = np.asarray(up, dtype=np.float64)
    if fwd.shape != (3,) or upv.shape != (3,) or np.linalg.norm(fwd) == 0:
        raise InputError("forward, up: expected non-zero 3-vectors")
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, upv)
    if np.linalg.norm(right) < 1e-9:
        raise InputError("up: expected a direction not parallel to forward")
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)  # OpenCV +y
    R = np.stack([right, down, fwd])

    tan_half = math.tan(math.radians(fov_deg) / 2.0)
    cam_dist = -size / tan_half  # SDK camDist (negative)
    offsets = cam_dist * np.tan(alphas)  # SDK offset_i
    aspect = W / H
    fy = H / (2.0 * tan_half)
    fx = fy
    positions = center[None, :] - (-cam_dist) * fwd[None, :] + (-offsets)[:, None] * right[None, :]
    w2c = np.tile(np.eye(4), (n, 1, 1))
    w2c[:, :3, :3] = R
    w2c[:, :3, 3] = -(positions @ R.T)
    K = np.zeros((n, 3, 3))
    K[:, 0, 0] = fx
    K[:, 1, 1] = fy
    K[:, 0, 2] = W / 2.0 * (1.0 - offsets / (size * aspect))
    K[:, 1, 2] = H / 2.0
    K[:, 2, 2] = 1.0
    return Cameras(w2c, K, W, H, near, far)


def sdk_view_projection(n_views: int, view_cone_deg: float, fov_deg: float, size: float, aspect: float,
                        near: float, far: float, base_view: np.ndarray | None = None,
                        viewer_angle_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Direct evaluation of the SDK example: OpenGL view and projection matrices (V, 4, 4), row-major.

    ``base_view`` is the OpenGL view matrix of the centre camera placed *at the focal-plane centre*
    (default identity: focal centre at the origin, looking down -z). This is the independent
    reference the tests compare :func:`make_quilt_cameras` against.
    """
    base = np.eye(4) if base_view is None else np.asarray(base_view, dtype=np.float64)
    cam_dist = -size / math.tan(math.radians(fov_deg) / 2.0)
    f = 1.0 / math.tan(math.radians(fov_deg) / 2.0)
    views, projs = [], []
    for i in range(n_views):
        frac = i / (n_views - 1) if n_views > 1 else 0.5
        angle = math.radians((frac - 0.5) * view_cone_deg + viewer_angle_deg)
        offset = cam_dist * math.tan(angle)
        T = np.eye(4)
        T[0, 3] = offset
        T[2, 3] = cam_dist
        views.append(T @ base)  # translation applied in eye (camera) space, after the base view
        P = np.zeros((4, 4))
        P[0, 0] = f / aspect
        P[1, 1] = f
        P[2, 2] = -(far + near) / (far - near)
        P[2, 3] = -2.0 * far * near / (far - near)
        P[3, 2] = -1.0
        P[0, 2] += offset / (size * aspect)  # glm proj[2][0]
        projs.append(P)
    return np.stack(views), np.stack(projs)


def quilt_cameras_to_opengl(cams: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """OpenGL (VTK) view and projection matrices (V, 4, 4) of quilt cameras (foundation conversion)."""
    return opencv_to_opengl(cams)
