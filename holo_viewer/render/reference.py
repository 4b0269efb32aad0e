"""Float64 reference splat renderer: the oracle every other backend is tested against.

Plain and slow on purpose: one view at a time, one Gaussian at a time (numpy over the
Gaussian's pixel box), exactly docs/design.md's 3DGS forward pass:

1. colour: SH of degree <= 3 with ``dir = normalise(mean - cam_pos)``, ``rgb = max(sh + 0.5, 0)``
   (``config.shared_sh``: one direction from the mean camera position for every view);
2. ``Sigma = R S S^T R^T``; camera-space ``t``; ``J`` with ``t.x/t.z, t.y/t.z`` clamped to the widened
   frustum (see :mod:`holo_viewer.render.projection`); ``Sigma2D = J W Sigma W^T J^T + 0.3 I``;
3. cull ``t.z <= near``; conic = Sigma2D^-1, skip det <= 0; radius = ceil(3 sqrt(lambda_max));
   the splat touches pixel centres within the square of half-size radius around its centre;
4. front to back by view depth (stable sort): ``power = -1/2 d^T conic d`` (skip > 0);
   ``alpha = min(0.99, o e^power)``; skip alpha < 1/255; a pixel stops after the splat that
   takes ``T (1 - alpha) < 1e-4`` (blended: docs/renderer.md, "early termination"); ``C = sum c alpha T + T_final bg``; clipped to [0, 1].

Every semantic knob of :class:`~holo_viewer.render.config.RenderConfig` is honoured
(thresholds, radius, SH degree, shared SH, culling margin, background, near).
"""

from __future__ import annotations

import time

import numpy as np

from ..avatar.gaussians import Gaussians
from ..camera import Cameras
from .config import RenderConfig, RenderResult
from .projection import covariance_3d, pixel_box, project_gaussians
from .sh import eval_sh, sh_to_rgb

__all__ = ["render", "render_view", "view_colors", "used_sh_degree", "centre_culled"]


def used_sh_degree(gaussians: Gaussians, config: RenderConfig) -> int:
    """SH degree actually evaluated: min(config.sh_degree, the Gaussians' degree)."""
    d = gaussians.sh_degree
    return d if config.sh_degree is None else min(d, int(config.sh_degree))


def view_colors(means: np.ndarray, sh: np.ndarray, degree: int, cam_pos: np.ndarray) -> np.ndarray:
    """(N, 3) float64 colours seen from ``cam_pos`` (3,): SH along normalise(mean - cam_pos)."""
    d = means - cam_pos[None, :]
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    d = d / np.where(norm > 0, norm, 1.0)
    return sh_to_rgb(eval_sh(degree, sh, d))


def centre_culled(uv: np.ndarray, width: int, height: int, margin: float | None) -> np.ndarray:
    """(N,) bool: centre outside the image widened by ``margin`` x size per side (None: never)."""
    if margin is None:
        return np.zeros(uv.shape[0], dtype=bool)
    u, v = uv[:, 0], uv[:, 1]
    return ((u < -margin * width) | (u > (1.0 + margin) * width)
            | (v < -margin * height) | (v > (1.0 + margin) * height))


def render_view(means: np.ndarray, cov3d: np.ndarray, opacity: np.ndarray, colors: np.ndarray,
                world_to_cam: np.ndarray, K: np.ndarray, width: int, height: int, near: float,
                config: RenderConfig) -> tuple[np.ndarray, int]:
    """Render one view in float64.

    Parameters
    ----------
    means : (N, 3) world centres (m).  cov3d : (N, 3, 3) world covariances (m^2).
    opacity : (N,) in [0, 1].  colors : (N, 3) RGB of each Gaussian in this view.
    world_to_cam : (4, 4).  K : (3, 3).  width, height : pixels.  near : cull depth (m).

    Returns
    -------
    image : (H, W, 3) float64 (clipped to [0, 1] when ``config.clip_output``).
    blends : total number of (pixel, splat) blends (alpha-composited contributions).
    """
    p = project_gaussians(means, cov3d, world_to_cam, K, width, height, near,
                          dilation=config.dilation, radius_sigmas=config.radius_sigmas)
    keep = p.valid & ~centre_culled(p.uv, width, height, config.cull_margin)
    idx = np.flatnonzero(keep)
    order = idx[np.argsort(p.depth[idx], kind="stable")]
    C = np.zeros((height, width, 3))
    T = np.ones((height, width))
    done = np.zeros((height, width), dtype=bool)
    thr, cap, t_min = config.alpha_threshold, config.alpha_cap, config.t_min
    blends = 0
    n_done = 0
    for g in order:
        u, v = p.uv[g]
        x0, x1, y0, y1 = pixel_box(u, v, p.radius[g], width, height)
        if x0 >= x1 or y0 >= y1:
            continue
        A, B, Cc = p.conic[g]
        dx = (np.arange(x0, x1) + 0.5 - u)[None, :]
        dy = (np.arange(y0, y1) + 0.5 - v)[:, None]
        power = -0.5 * (A * dx * dx + Cc * dy * dy) - B * dx * dy
        alpha = np.minimum(cap, opacity[g] * np.exp(power))
        Tb = T[y0:y1, x0:x1]
        db = done[y0:y1, x0:x1]
        use = (power <= 0.0) & (alpha >= thr) & ~db
        test_T = Tb * (1.0 - alpha)
        stop = use & (test_T < t_min)  # blended, then the pixel stops
        if stop.any():
            db |= stop
            n_done += int(stop.sum())
        w = np.where(use, alpha * Tb, 0.0)
        C[y0:y1, x0:x1] += w[..., None] * colors[g][None, None, :]
        T[y0:y1, x0:x1] = np.where(use, test_T, Tb)
        blends += int(use.sum())
        if n_done == width * height:
            break
    img = C + T[..., None] * np.asarray(config.background, dtype=np.float64)
    if config.clip_output:
        img = np.clip(img, 0.0, 1.0)
    return img, blends


def render(gaussians: Gaussians, cameras: Cameras, config: RenderConfig | None = None) -> RenderResult:
    """Render every camera of ``cameras`` in float64 (see the module docstring).

    Inputs are assumed validated (use :func:`holo_viewer.render.render_views`).

    Returns
    -------
    RenderResult
        images (V, H, W, 3) float32, timings per stage, stats (n_input, n_visible, mean blends).
    """
    config = config or RenderConfig()
    t0 = time.perf_counter()
    g = gaussians.numpy(np.float64)
    means = g.means
    cov3d = covariance_3d(g.quats, g.scales)
    opacity = g.opacities
    degree = used_sh_degree(g, config)
    near = cameras.near if config.near is None else float(config.near)
    t1 = time.perf_counter()
    shared = view_colors(means, g.sh, degree, cameras.positions.mean(axis=0)) if config.shared_sh else None
    V, H, W = len(cameras), cameras.height, cameras.width
    images = np.empty((V, H, W, 3), dtype=np.float32)
    blends = 0
    for i in range(V):
        colors = shared if shared is not None else view_colors(means, g.sh, degree, cameras.positions[i])
        img, nb = render_view(means, cov3d, opacity, colors, cameras.world_to_cam[i], cameras.K[i],
                              W, H, near, config)
        images[i] = img
        blends += nb
    t2 = time.perf_counter()
    return RenderResult(images=images,
                        timings={"preprocess": t1 - t0, "composite": t2 - t1, "total": t2 - t0},
                        stats={"n_input": len(g), "mean_blends_per_pixel": blends / float(V * H * W)},
                        backend="reference")
