"""Per-Gaussian float64 projection helpers (EWA splatting, docs/design.md "3DGS forward pass").

Pure numpy, used by the reference renderer and usable by the other backends.

Clamp of the Jacobian with an off-centre principal point
---------------------------------------------------------
Inria clamps the camera-space ``t.x / t.z`` to ``+-1.3 tan(fov_x / 2)`` before forming the
Jacobian ``J``. With a shifted principal point (the sheared quilt cameras) the frustum is not
symmetric, so we clamp per axis to the frustum edges widened by 30 % of the half-size on
each side::

    t.x / t.z in [(-cx - 0.15 W) / fx, (1.15 W - cx) / fx]
    t.y / t.z in [(-cy - 0.15 H) / fy, (1.15 H - cy) / fy]

For a centred camera (cx = W/2) this is exactly Inria's ``+-1.3 tan(fov_x / 2)``. The fast
backend uses the same limits. The clamp only changes ``J`` (the footprint's shape), never the
projected centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import covariance_np

__all__ = ["Projected", "covariance_3d", "clamp_limits", "project_gaussians", "conic_and_radius",
           "pixel_box"]

#: widening of the frustum edges (fraction of the image size per side) for the Jacobian clamp
CLAMP_WIDEN = 0.15


def covariance_3d(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Sigma = R S S^T R^T, (N, 4) wxyz quaternions and (N, 3) linear scales (m) -> (N, 3, 3) m^2."""
    return covariance_np(np.asarray(quats, dtype=np.float64), np.asarray(scales, dtype=np.float64))


def clamp_limits(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> tuple[float, ...]:
    """(lo_x, hi_x, lo_y, hi_y) limits of ``t.x/t.z`` and ``t.y/t.z`` for the Jacobian clamp."""
    lo_x = (-cx - CLAMP_WIDEN * width) / fx
    hi_x = ((1.0 + CLAMP_WIDEN) * width - cx) / fx
    lo_y = (-cy - CLAMP_WIDEN * height) / fy
    hi_y = ((1.0 + CLAMP_WIDEN) * height - cy) / fy
    return lo_x, hi_x, lo_y, hi_y


@dataclass(frozen=True)
class Projected:
    """N Gaussians projected into one view (float64).

    Attributes
    ----------
    depth : (N,) camera-space z (m).
    uv : (N, 2) projected centres in pixels (x right, y down; pixel centres at +0.5).
    cov2d : (N, 3) 2D covariance (a, b, c) = [[a, b], [b, c]] in pixels^2, dilation included.
    conic : (N, 3) inverse covariance (A, B, C) = [[A, B], [B, C]] in 1/pixels^2.
    radius : (N,) splat half-extent in pixels, ceil(radius_sigmas * sqrt(lambda_max)).
    valid : (N,) bool: in front of the near plane and det(cov2d) > 0.
    """

    depth: np.ndarray
    uv: np.ndarray
    cov2d: np.ndarray
    conic: np.ndarray
    radius: np.ndarray
    valid: np.ndarray


def conic_and_radius(cov2d: np.ndarray, radius_sigmas: float,
                     dilation: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of (N, 3) 2D covariances (a, b, c), its radius and a validity mask (det > 0).

    ``cov2d`` includes the ``dilation`` on its diagonal. The determinant is evaluated as
    ``max(det(S), 0) + dilation * tr(S) + dilation^2`` with ``S = cov2d - dilation I`` (the
    projected covariance, positive semi-definite in exact arithmetic): the same number, but
    without the cancellation that makes ``a c - b^2`` of a huge, nearly rank-1 footprint
    (a needle close to the camera) come out <= 0 or wildly wrong.
    """
    a, b, c = cov2d[:, 0], cov2d[:, 1], cov2d[:, 2]
    sa, sc = a - dilation, c - dilation
    det = np.maximum(sa * sc - b * b, 0.0) + dilation * (sa + sc) + dilation * dilation
    valid = det > 0
    safe = np.where(valid, det, 1.0)
    conic = np.stack([c / safe, -b / safe, a / safe], axis=1)
    mid = 0.5 * (a + c)
    lam = mid + np.sqrt(np.maximum(mid * mid - det, 0.0))
    radius = np.ceil(radius_sigmas * np.sqrt(np.maximum(lam, 0.0)))
    return np.where(valid[:, None], conic, 0.0), np.where(valid, radius, 0.0), valid


def project_gaussians(means: np.ndarray, cov3d: np.ndarray, world_to_cam: np.ndarray, K: np.ndarray,
                      width: int, height: int, near: float, dilation: float = 0.3,
                      radius_sigmas: float = 3.0) -> Projected:
    """Project 3D Gaussians into one pinhole view (EWA: Sigma2D = J W Sigma W^T J^T + dilation I).

    Parameters
    ----------
    means : (N, 3) world centres (m).
    cov3d : (N, 3, 3) world covariances (m^2).
    world_to_cam : (4, 4) OpenCV world -> camera transform.
    K : (3, 3) intrinsics (pixels).
    width, height : image size (pixels).
    near : cull depth: Gaussians with t.z <= near are invalid.
    dilation : added to the 2D covariance diagonal (pixels^2).
    radius_sigmas : radius in standard deviations of the major axis.
    """
    means = np.asarray(means, dtype=np.float64)
    W = np.asarray(world_to_cam, dtype=np.float64)[:3, :3]
    t = means @ W.T + np.asarray(world_to_cam, dtype=np.float64)[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tz = t[:, 2]
    front = tz > near
    tzs = np.where(front, tz, 1.0)
    u = fx * t[:, 0] / tzs + cx
    v = fy * t[:, 1] / tzs + cy
    lo_x, hi_x, lo_y, hi_y = clamp_limits(fx, fy, cx, cy, width, height)
    txc = np.clip(t[:, 0] / tzs, lo_x, hi_x) * tzs
    tyc = np.clip(t[:, 1] / tzs, lo_y, hi_y) * tzs
    n = means.shape[0]
    J = np.zeros((n, 2, 3))
    J[:, 0, 0] = fx / tzs
    J[:, 0, 2] = -fx * txc / (tzs * tzs)
    J[:, 1, 1] = fy / tzs
    J[:, 1, 2] = -fy * tyc / (tzs * tzs)
    M = J @ W  # (N, 2, 3)
    S = M @ cov3d @ np.swapaxes(M, 1, 2)  # (N, 2, 2)
    b = 0.5 * (S[:, 0, 1] + S[:, 1, 0])  # symmetric by construction; average the rounding
    cov2d = np.stack([S[:, 0, 0] + dilation, b, S[:, 1, 1] + dilation], axis=1)
    conic, radius, ok = conic_and_radius(cov2d, radius_sigmas, dilation)
    valid = front & ok & np.isfinite(cov2d).all(axis=1)
    return Projected(tz, np.stack([u, v], axis=1), cov2d, conic, radius, valid)


def pixel_box(u: float, v: float, radius: float, width: int, height: int) -> tuple[int, int, int, int]:
    """Pixel columns [x0, x1) and rows [y0, y1) whose centres lie within ``radius`` of (u, v).

    Pixel (row i, col j) has its centre at (j + 0.5, i + 0.5); the box is clipped to the image
    (empty when x0 >= x1 or y0 >= y1).
    """
    x0 = max(int(np.ceil(u - radius - 0.5)), 0) if np.isfinite(u - radius) else 0
    x1 = min(int(np.floor(u + radius - 0.5)) + 1, width) if np.isfinite(u + radius) else width
    y0 = max(int(np.ceil(v - radius - 0.5)), 0) if np.isfinite(v - radius) else 0
    y1 = min(int(np.floor(v + radius - 0.5)) + 1, height) if np.isfinite(v + radius) else height
    return x0, x1, y0, y1
