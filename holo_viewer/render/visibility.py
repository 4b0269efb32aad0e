"""Which Gaussians can anybody see? Per-Gaussian largest blending weight over a set of views.

A Gaussian's *weight* at a pixel is what the compositor adds of its colour there: ``alpha x T``
(``alpha = min(alpha_cap, opacity exp(-d^T conic d / 2))`` where ``alpha >= alpha_threshold``, ``T``
the transmittance left in front of it, the pixel finishing after the splat that takes ``T`` below
``t_min``), i.e. exactly the fast renderer's rule (:func:`holo_viewer.render.fast_kernels.composite`)
evaluated in float64 with an exact ``exp``. :func:`max_weights` returns, per Gaussian, the largest
weight at any pixel of any of the given views; a Gaussian whose largest weight over every view and
pose a live frame can show stays below a small threshold changes no pixel by more than that
threshold's share of its colour, so live frames may skip it (:func:`visible_keep`).

Since a pixel's colour is ``sum_i w_i c_i`` (+ the background times the final T), dropping a set of
Gaussians changes a pixel by the dropped weights times their colours *and* lets the Gaussians behind
them take the transmittance they blocked; both are bounded by the sum of the dropped weights at
that pixel, not by the largest one, so the keep mask is checked by rendering (the bench and the
tests measure the image error; the threshold alone is not a bound).

This is the offline reference path (numba, one view per thread, scalar float64): ~1-3 s of CPU per
48 views of 420x560 on the default avatar.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..camera import Cameras
from ..errors import InputError
from .config import RenderConfig

__all__ = ["max_weights", "visible_keep", "KEEP_WEIGHT"]

#: visible_keep's and the live mask's threshold: a Gaussian is kept when its weight exceeds this somewhere.
#: 1/255: on the default avatar (union of the live poses, A/B group frames over a pain flare, load 9) 0.5 /
#: 1 / 2 /255 kept 70.2k / 66.6k / 61.8k of 102k for 0.211 / 0.204 / 0.199 s of CPU a frame against 0.226
#: with all, cone worst 41.35 / 41.35 / 41.34 dB (41.35 with all), median 46.22 / 46.22 / 46.18
KEEP_WEIGHT = 1.0 / 255.0


@nb.njit(parallel=True, cache=True)
def _max_weight_views(rec, box, off, base, ids, tile, tiles_x, tiles_y, width, height, alpha_threshold,
                      alpha_cap, t_min, wmax):  # pragma: no cover - compiled
    """wmax (V, M) float32: per view and depth-ordered splat, its largest weight alpha x T at any
    pixel (float64 arithmetic; the compositing rule of fast_kernels.composite)."""
    nv = rec.shape[0]
    nt = tiles_x * tiles_y
    for v in nb.prange(nv):
        T = np.ones(tile * tile)
        live = np.ones(tile * tile, dtype=np.bool_)
        b = base[v]
        for t in range(nt):
            ty = t // tiles_x
            tx = t - ty * tiles_x
            px0 = tx * tile
            py0 = ty * tile
            pw = min(tile, width - px0)
            ph = min(tile, height - py0)
            T[:] = 1.0
            live[:] = True
            n_live = pw * ph
            for e in range(off[v, t], off[v, t + 1]):
                k = ids[b + e]
                x0 = max(box[v, k, 0], px0) - px0
                x1 = min(box[v, k, 1], px0 + pw) - px0
                y0 = max(box[v, k, 2], py0) - py0
                y1 = min(box[v, k, 3], py0 + ph) - py0
                if x0 >= x1 or y0 >= y1:
                    continue
                u = float(rec[v, k, 0]) - (px0 + 0.5)
                vv = float(rec[v, k, 1]) - (py0 + 0.5)
                A = float(rec[v, k, 2])
                B = float(rec[v, k, 3])
                C = float(rec[v, k, 4])
                op = float(rec[v, k, 5])
                best = 0.0
                for y in range(y0, y1):
                    dy = y - vv
                    for x in range(x0, x1):
                        p = y * tile + x
                        if not live[p]:
                            continue
                        dx = x - u
                        power = -0.5 * A * dx * dx - B * dx * dy - 0.5 * C * dy * dy
                        if power > 0.0:
                            continue
                        alpha = min(alpha_cap, op * math.exp(power))
                        if alpha < alpha_threshold:
                            continue
                        w = alpha * T[p]
                        if w > best:
                            best = w
                        T[p] = T[p] * (1.0 - alpha)
                        if T[p] < t_min:
                            live[p] = False
                            n_live -= 1
                if best > wmax[v, k]:
                    wmax[v, k] = best
                if n_live <= 0:
                    break


def max_weights(gaussians, cameras: Cameras, config: RenderConfig | None = None, chunk: int = 8,
                per_view: bool = False) -> np.ndarray:
    """(N,) float64: each Gaussian's largest blending weight at any pixel of any of ``cameras``
    (``per_view``: (V, N), its largest weight in each camera; their maximum over the cameras is the
    (N,) result).

    Parameters
    ----------
    gaussians : Gaussians
    cameras : Cameras
    config : RenderConfig, optional
        The renderer's knobs (alpha threshold and cap, ``t_min``, dilation, radius, near, culling);
        default ``RenderConfig()`` (the exact export's ``t_min``, so a pixel's later splats count
        as long as any frame of any mode could draw them).
    chunk : int
        Views projected at a time (memory: ~64 bytes per Gaussian and view).
    """
    from . import fast
    from . import fast_kernels as fk

    config = config or RenderConfig()
    g = gaussians.numpy()
    n = len(g)
    means, quats, log_scales = (np.ascontiguousarray(a, dtype=np.float64) for a in (g.means, g.quats, g.log_scales))
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64)))
    degree = g.sh_degree if config.sh_degree is None else min(g.sh_degree, int(config.sh_degree))
    sh = np.ascontiguousarray(np.asarray(g.sh)[:, : (degree + 1) ** 2], dtype=np.float32)
    near = cameras.near if config.near is None else float(config.near)
    W, H = cameras.width, cameras.height
    tile = int(config.tile_size)
    tiles_x, tiles_y = -(-W // tile), -(-H // tile)
    cull = -1.0 if config.cull_margin is None else float(config.cull_margin)
    out = np.zeros(n, dtype=np.float64)
    views_out = np.zeros((len(cameras), n), dtype=np.float64) if per_view else None
    shared_rgb = np.zeros((1, 3), dtype=np.float32)
    for group in fast._groups(cameras):
        Wrot = np.ascontiguousarray(cameras.R[int(group[0])])
        pc, cov = fk.prep_3d(means, quats, log_scales, Wrot)
        z = pc[:, 2]
        front = (z + cameras.t[group, 2].max()) > near
        order, _ = fast.depth_order(z, front)
        m = order.size
        if m == 0:
            continue
        for c0 in range(0, group.size, max(1, int(chunk))):
            views = group[c0:c0 + max(1, int(chunk))]
            cams = fast._view_params(cameras, views)
            rec, box = fast._records(len(views), m)
            fk.project_views(order, pc, cov, means, opacity, sh, degree, shared_rgb, False, cams, W, H, near,
                             float(config.dilation), float(config.radius_sigmas), float(config.alpha_threshold),
                             cull, rec, box)
            off = fk.count_tiles(rec, box, tile, tiles_x, tiles_y)
            base = np.zeros(len(views), dtype=np.int64)
            base[1:] = np.cumsum(off[:-1, -1])
            ids = np.empty(int(off[:, -1].sum()), dtype=np.int32)
            fk.fill_tiles(rec, box, tile, tiles_x, off, base, ids)
            wmax = np.zeros((len(views), m), dtype=np.float32)
            _max_weight_views(rec, box, off, base, ids, tile, tiles_x, tiles_y, W, H, float(config.alpha_threshold),
                              float(config.alpha_cap), float(config.t_min), wmax)
            np.maximum.at(out, order, wmax.max(axis=0).astype(np.float64))
            if views_out is not None:  # order holds each Gaussian once: a plain scatter per view
                views_out[views[:, None], order[None, :]] = wmax
    return views_out if views_out is not None else out


def visible_keep(weights, threshold: float = KEEP_WEIGHT) -> np.ndarray:
    """Sorted int64 indices of the Gaussians whose largest weight (``max_weights``, or the maximum of
    several poses' ``max_weights``) exceeds ``threshold``."""
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1:
        raise InputError(f"weights: expected (N,) largest weights, found shape {w.shape}")
    if not (0.0 <= float(threshold) < 1.0):
        raise InputError(f"threshold: expected a weight in [0, 1), found {threshold!r}")
    return np.flatnonzero(w > float(threshold)).astype(np.int64)
