"""Shared scene and camera builders for renderer benchmarks and tests (deterministic, seeded).

* :func:`quilt_cameras` - the 48 sheared Looking Glass cameras of docs/design.md Algorithm 1
  (uses ``holo_viewer.display.cameras.make_quilt_cameras`` when it exists).
* :func:`shell_scene` - a head-sized ellipsoidal shell of Gaussians that overfills a
  420x560 portrait frame like a face does (~45 blends per pixel at 100k Gaussians).
* :func:`random_scene` - Gaussians scattered in a box in front of the cameras.
* :func:`default_scene` - the default avatar at rest (``holo_viewer.avatar.default_avatar``)
  when it exists, else the shell; :func:`framed_cameras` frames it like the pipeline does.
"""

from __future__ import annotations

import math
import platform

import numpy as np

from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.camera import Cameras
from holo_viewer.geometry import rotmat_to_quat_np

__all__ = ["quilt_cameras", "shell_scene", "random_scene", "default_scene", "framed_cameras", "random_quats"]

SIZE, FOV_DEG, CONE_DEG = 0.12, 14.0, 40.0


def quilt_cameras(n_views: int = 48, width: int = 420, height: int = 560, size: float = SIZE,
                  fov_deg: float = FOV_DEG, cone_deg: float = CONE_DEG, target=(0.0, 0.0, 0.0),
                  use_display: bool = True) -> Cameras:
    """The quilt cameras of docs/design.md Algorithm 1 (OpenCV), view 0 = leftmost.

    ``size`` is the half-height of the focal plane (m) through ``target``; all cameras look
    along world -z with a shared orientation; camera i sits at x offset
    ``camDist tan(alpha_i)``, ``alpha_i = (i/(N-1) - 0.5) cone`` and its principal point is
    shifted so the focal-plane centre stays at the image centre.
    """
    if use_display:
        try:
            from holo_viewer.display.cameras import make_quilt_cameras
        except ImportError:
            make_quilt_cameras = None
        if make_quilt_cameras is not None:
            return make_quilt_cameras(None, focal_center=target, size=size, fov_deg=fov_deg, n_views=n_views,
                                      view_cone_deg=cone_deg, tile_width=width, tile_height=height,
                                      near=0.01, far=100.0)
    tan_half = math.tan(math.radians(fov_deg) / 2.0)
    dist = size / tan_half
    fy = height / (2.0 * tan_half)
    fx = fy
    tx, ty, tz = target
    w2c, Ks = [], []
    for i in range(n_views):
        a = (i / max(n_views - 1, 1) - 0.5) * math.radians(cone_deg)
        off = dist * math.tan(a)
        M = np.eye(4)
        M[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV camera looking along world -z, +y down
        eye = np.array([tx + off, ty, tz + dist])
        M[:3, 3] = -M[:3, :3] @ eye
        w2c.append(M)
        Ks.append([[fx, 0.0, width / 2.0 + fx * off / dist], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])
    return Cameras(np.array(w2c), np.array(Ks), width, height, near=0.01, far=100.0)


def random_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) random unit wxyz quaternions."""
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _sh(rng: np.random.Generator, n: int, degree: int, view_dep: float) -> np.ndarray:
    k = (degree + 1) ** 2
    sh = np.zeros((n, k, 3))
    sh[:, 0] = rng.uniform(-1.2, 1.5, size=(n, 3))
    if k > 1:
        sh[:, 1:] = rng.normal(scale=view_dep, size=(n, k - 1, 3))
    return sh


def shell_scene(n: int = 100_000, degree: int = 3, seed: int = 0, semi_axes=(0.10, 0.14, 0.10),
                scale_mm: float = 1.4, center=(0.0, 0.0, 0.0)) -> Gaussians:
    """A head-sized ellipsoidal shell of ``n`` flat-ish Gaussians (tangent to the surface).

    Default semi-axes (m) overfill the quilt cameras' 0.18 x 0.24 m focal plane; the default
    scale gives ~45 blends per pixel at n = 100k (scale ~ 1/sqrt(n) keeps coverage fixed).
    """
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ax = np.asarray(semi_axes)
    means = d * ax + np.asarray(center)
    normal = d / ax**2
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # orthonormal frame with the surface normal as the third axis (the thin one)
    helper = np.where(np.abs(normal[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normal, t1)
    R = np.stack([t1, t2, normal], axis=2)  # columns = axes
    phi = rng.uniform(0, 2 * np.pi, n)  # random in-plane rotation via the quaternion below
    quats = rotmat_to_quat_np(R @ _rot_z(phi))
    s = scale_mm * 1e-3 * math.sqrt(100_000 / n)
    scales = np.stack([s * rng.lognormal(0, 0.35, n), s * rng.lognormal(0, 0.35, n),
                       0.15 * s * np.ones(n)], axis=1)
    logits = rng.normal(1.0, 1.5, n)
    return Gaussians.from_arrays(means, quats, np.log(scales), logits, _sh(rng, n, degree, 0.15))


def _rot_z(phi: np.ndarray) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    R = np.zeros((phi.size, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def random_scene(n: int = 2000, degree: int = 3, seed: int = 0, extent=(0.1, 0.13, 0.1),
                 scale_range=(-6.5, -3.5), center=(0.0, 0.0, 0.0)) -> Gaussians:
    """``n`` random Gaussians uniform in a box of half-extent ``extent`` (m) around ``center``.

    Log-scales uniform in ``scale_range`` (natural log of metres), random rotations, opacity
    logits ~ N(0, 2), SH of ``degree`` with random view dependence.
    """
    rng = np.random.default_rng(seed)
    means = rng.uniform(-1, 1, size=(n, 3)) * np.asarray(extent) + np.asarray(center)
    log_scales = rng.uniform(*scale_range, size=(n, 3))
    return Gaussians.from_arrays(means, random_quats(rng, n), log_scales, rng.normal(0, 2, n),
                                 _sh(rng, n, degree, 0.3))


def default_scene(n: int = 100_000) -> tuple[Gaussians, str]:
    """(Gaussians, name): the default avatar at rest if it exists, else the shell scene."""
    try:
        from holo_viewer.avatar.default_gaussians import default_avatar
    except ImportError:
        return shell_scene(n), f"shell{n // 1000}k"
    return default_avatar(n).rest(), f"default_avatar{n // 1000}k"


def framed_cameras(g: Gaussians, n_views: int = 48, width: int = 420, height: int = 560,
                   margin: float = 1.08) -> Cameras:
    """Quilt cameras framing ``g`` as the pipeline frames a head (``pipeline.frame_head``).

    The focal plane passes through the centre of the bounding box of the Gaussian centres,
    with half-height ``margin`` x half the box height (the pipeline uses the neutral FLAME
    vertices; the avatar's Gaussians lie on them).
    """
    means = np.asarray(Gaussians._np(g.means), dtype=np.float64)
    try:
        from holo_viewer.pipeline import frame_head

        centre, half = frame_head(means, margin)
    except ImportError:
        lo, hi = means.min(axis=0), means.max(axis=0)
        centre, half = 0.5 * (lo + hi), 0.5 * float(hi[1] - lo[1]) * margin
    return quilt_cameras(n_views, width, height, size=half, target=tuple(centre))


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``'s "model name", else :func:`platform.processor`), for the bench JSONs:
    the project's VMs change between sessions (an AMD EPYC since 2026-11-29), and timings compare only on one CPU."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"
