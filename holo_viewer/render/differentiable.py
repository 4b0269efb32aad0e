"""Differentiable CPU 3DGS renderer (for fitting Gaussians by gradient descent).

The forward pass is exactly docs/design.md "3DGS forward pass" (the float64 reference,
:mod:`holo_viewer.render.reference`); this module adds its gradient:

* **Per Gaussian, plain torch autograd** (O(N), cheap): the covariance ``R S S^T R^T`` from the
  quaternion and log-scale, the EWA projection (Jacobian clamped as in
  :mod:`holo_viewer.render.projection`), ``Sigma2D + dilation I``, the conic with the reference's
  cancellation-free determinant, the SH colour toward the camera (``max(sh + 0.5, 0)``) and
  ``sigmoid`` opacity. Depth order, radius and the pixel box are piecewise constant: computed
  without gradient.
* **Per pixel, numba kernels** wrapped in a :class:`torch.autograd.Function` (:class:`Rasterize`):
  tile binning (8x8 tiles; every Gaussian whose pixel box and alpha >= threshold ellipse reach a tile, in
  front-to-back compositing with the reference's rules (pixel box, ``power > 0`` skip,
  ``alpha = min(cap, o e^power)``, ``alpha < threshold`` skip, the ``t_min`` stop). The forward
  stores per pixel the final transmittance and the number of tile-list entries it walked (the last
  contributor); the backward walks each pixel's list back to front, recovering ``T`` by division by
  ``1 - alpha`` (the standard 3DGS backward), and accumulates the gradients of the 2D means, conics,
  opacities and colours (per-thread buffers, summed).

The image is *not* clipped to [0, 1] (the reference clips when ``config.clip_output``): clipping
kills the gradient; callers compare unclipped images or clip themselves.

Pure: no I/O. Inputs are torch tensors (float32 or float64; the kernels run in that dtype).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numba as nb
import numpy as np
import torch
from torch import Tensor

from .config import RenderConfig
from .projection import clamp_limits
from .sh import sh_basis

__all__ = ["Rasterize", "rasterize", "project", "covariance", "sh_rgb", "render_view", "render_gaussians",
           "TILE"]

#: tile edge (pixels) of the binning
TILE = 8


# ----------------------------------------------------------------------------- per Gaussian (torch)
def covariance(quats: Tensor, log_scales: Tensor) -> Tensor:
    """(N, 3, 3) world covariances ``R S S^T R^T`` from (N, 4) wxyz quats (normalised here) and log-scales."""
    q = quats / torch.linalg.norm(quats, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    R = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(-1, 3, 3)
    M = R * torch.exp(log_scales)[:, None, :]
    return M @ M.transpose(1, 2)


def sh_rgb(means: Tensor, sh: Tensor, degree: int, cam_pos: Tensor) -> Tensor:
    """(N, 3) colours ``max(SH(n(mean - cam_pos)) + 0.5, 0)`` (degree <= the coefficients held)."""
    k = (degree + 1) ** 2
    d = means - cam_pos
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True).clamp_min(1e-30)
    basis = sh_basis(degree, d)
    return torch.clamp_min(torch.einsum("nk,nkc->nc", basis, sh[:, :k]) + 0.5, 0.0)


def project(means: Tensor, cov3d: Tensor, world_to_cam: np.ndarray, K: np.ndarray, width: int, height: int,
            near: float, dilation: float = 0.3, radius_sigmas: float = 3.0
            ) -> tuple[Tensor, Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """EWA projection, differentiable in ``means`` and ``cov3d`` (same math as ``projection.project_gaussians``).

    Returns
    -------
    uv : Tensor (N, 2) pixel centres.  conic : Tensor (N, 3) (A, B, C).
    depth : (N,) numpy camera-space z.  radius : (N,) numpy float pixels.  valid : (N,) numpy bool.
    """
    dt = means.dtype
    Wm = torch.tensor(np.asarray(world_to_cam, np.float64), dtype=dt)
    Rw, tw = Wm[:3, :3], Wm[:3, 3]
    t = means @ Rw.T + tw
    fx, fy, cx, cy = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
    tz = t[:, 2]
    front = (tz > near).detach()
    tzs = torch.where(front, tz, torch.ones_like(tz))
    u = fx * t[:, 0] / tzs + cx
    v = fy * t[:, 1] / tzs + cy
    lo_x, hi_x, lo_y, hi_y = clamp_limits(fx, fy, cx, cy, width, height)
    txc = torch.clamp(t[:, 0] / tzs, lo_x, hi_x) * tzs
    tyc = torch.clamp(t[:, 1] / tzs, lo_y, hi_y) * tzs
    zero = torch.zeros_like(tzs)
    J = torch.stack([torch.stack([fx / tzs, zero, -fx * txc / (tzs * tzs)], -1),
                     torch.stack([zero, fy / tzs, -fy * tyc / (tzs * tzs)], -1)], dim=-2)
    M = J @ Rw
    S = M @ cov3d @ M.transpose(1, 2)
    sa, sc = S[:, 0, 0], S[:, 1, 1]
    b = 0.5 * (S[:, 0, 1] + S[:, 1, 0])
    a, c = sa + dilation, sc + dilation
    det = torch.clamp_min(sa * sc - b * b, 0.0) + dilation * (sa + sc) + dilation * dilation
    ok = (det > 0).detach()
    safe = torch.where(ok, det, torch.ones_like(det))
    conic = torch.stack([c / safe, -b / safe, a / safe], -1)
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.0))
        radius = torch.ceil(radius_sigmas * torch.sqrt(torch.clamp_min(lam, 0.0)))
        finite = torch.isfinite(a) & torch.isfinite(b) & torch.isfinite(c) & torch.isfinite(u) & torch.isfinite(v)
        valid = front & ok & finite
    uv = torch.stack([u, v], -1)
    return (uv, conic, tz.detach().cpu().numpy().astype(np.float64),
            torch.where(valid, radius, torch.zeros_like(radius)).cpu().numpy().astype(np.float64),
            valid.cpu().numpy())


# ----------------------------------------------------------------------------- kernels (numba)
@nb.njit(cache=True)
def _boxes(uv, radius, order, width, height):  # pragma: no cover - compiled
    """Pixel boxes (M, 4) int32 [x0, x1, y0, y1) of the Gaussians ``order`` (the reference's pixel_box)."""
    m = order.shape[0]
    box = np.zeros((m, 4), np.int32)
    for k in range(m):
        g = order[k]
        u, v, r = uv[g, 0], uv[g, 1], radius[g]
        if not (math.isfinite(u) and math.isfinite(v)):
            continue
        x0 = max(int(math.ceil(u - r - 0.5)), 0)
        x1 = min(int(math.floor(u + r - 0.5)) + 1, width)
        y0 = max(int(math.ceil(v - r - 0.5)), 0)
        y1 = min(int(math.floor(v + r - 0.5)) + 1, height)
        box[k, 0], box[k, 1], box[k, 2], box[k, 3] = x0, x1, y0, y1
    return box


@nb.njit(cache=True)
def _span(rec, box, k, ya, yb, q):  # pragma: no cover - compiled
    """Pixel columns [c0, c1) of splat ``k``'s alpha >= threshold ellipse (``d^T conic d <= q``) over
    the pixel-centre rows ``ya..yb`` (inclusive), within its box; c0 >= c1 when it misses them."""
    u, v, A, B, C = rec[k, 0], rec[k, 1], rec[k, 2], rec[k, 3], rec[k, 4]
    det = A * C - B * B
    if not (A > 0.0 and C > 0.0 and det > 0.0):
        return box[k, 0], box[k, 1]  # degenerate: fall back to the box
    ext = math.sqrt(q * C / det)  # half-width in x of the ellipse
    dy_l = B * ext / C  # dy of the leftmost point (the rightmost is at -dy_l)
    a, b = ya - v, yb - v
    lo = 1e300
    hi = -1e300
    if a <= dy_l <= b:
        lo = -ext
    if a <= -dy_l <= b:
        hi = ext
    for dy in (a, b):
        disc = B * B * dy * dy - A * (C * dy * dy - q)
        if disc >= 0.0:
            r = math.sqrt(disc)
            lo = min(lo, (-B * dy - r) / A)
            hi = max(hi, (-B * dy + r) / A)
    if lo > hi:
        return 0, 0
    c0 = max(int(math.ceil(u + lo - 0.5)), box[k, 0])
    c1 = min(int(math.floor(u + hi - 0.5)) + 1, box[k, 1])
    return c0, c1


@nb.njit(cache=True)
def _bin(rec, box, tiles_x, tiles_y, tile, thr):  # pragma: no cover - compiled
    """Per tile the indices into ``rec`` / ``box`` (depth order kept) of the splats that can have
    alpha >= thr at one of its pixels (box AND the ellipse ``d^T conic d <= 2 ln(o / thr)``, with a
    small margin): offsets (n_tiles + 1,), ids."""
    m = box.shape[0]
    nt = tiles_x * tiles_y
    count = np.zeros(nt + 1, np.int64)
    for rnd in range(2):
        if rnd == 1:
            for t in range(nt):
                count[t + 1] += count[t]
            ids = np.empty(count[nt], np.int32)
            fill = count[:nt].copy()
        else:
            ids = np.empty(0, np.int32)
            fill = count[:nt]
        for k in range(m):
            x0, x1, y0, y1 = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
            o = rec[k, 5]
            if x0 >= x1 or y0 >= y1 or not o >= thr:
                continue
            q = 2.0 * math.log(o / thr) * (1.0 + 1e-4) + 1e-4
            for ty in range(y0 // tile, (y1 - 1) // tile + 1):
                ra = max(ty * tile, y0)
                rb = min((ty + 1) * tile, y1) - 1
                c0, c1 = _span(rec, box, k, ra + 0.5 - 1e-3, rb + 0.5 + 1e-3, q)
                if c0 >= c1:
                    continue
                for tx in range(c0 // tile, (c1 - 1) // tile + 1):
                    t = ty * tiles_x + tx
                    if rnd == 0:
                        count[t + 1] += 1
                    else:
                        ids[fill[t]] = k
                        fill[t] += 1
    return count, ids


@nb.njit(parallel=True, cache=True)
def _forward(rec, box, off, ids, width, height, tiles_x, tile, bg, thr, cap, t_min,
             img, t_final, n_walk):  # pragma: no cover - compiled
    nt = off.shape[0] - 1
    for t in nb.prange(nt):
        tx0 = (t % tiles_x) * tile
        ty0 = (t // tiles_x) * tile
        for py in range(ty0, min(ty0 + tile, height)):
            for px in range(tx0, min(tx0 + tile, width)):
                T = 1.0
                c0 = 0.0
                c1 = 0.0
                c2 = 0.0
                last = off[t]
                fx = px + 0.5
                fy = py + 0.5
                for j in range(off[t], off[t + 1]):
                    k = ids[j]
                    if px < box[k, 0] or px >= box[k, 1] or py < box[k, 2] or py >= box[k, 3]:
                        continue
                    dx = fx - rec[k, 0]
                    dy = fy - rec[k, 1]
                    power = -0.5 * (rec[k, 2] * dx * dx + rec[k, 4] * dy * dy) - rec[k, 3] * dx * dy
                    if power > 0.0:
                        continue
                    alpha = min(cap, rec[k, 5] * math.exp(power))
                    if alpha < thr:
                        continue
                    test_T = T * (1.0 - alpha)
                    w = alpha * T
                    c0 += w * rec[k, 6]
                    c1 += w * rec[k, 7]
                    c2 += w * rec[k, 8]
                    T = test_T
                    last = j + 1
                    if test_T < t_min:  # blended, then the pixel stops
                        break
                img[py, px, 0] = c0 + T * bg[0]
                img[py, px, 1] = c1 + T * bg[1]
                img[py, px, 2] = c2 + T * bg[2]
                t_final[py, px] = T
                n_walk[py, px] = last


@nb.njit(parallel=True, cache=True)
def _backward(rec, box, off, ids, width, height, tiles_x, tile, bg, thr, cap, t_final, n_walk, dimg,
              n_threads, grad):  # pragma: no cover - compiled
    """Gradients per depth-ordered splat into per-thread buffers grad (n_threads, M, 9):
    u, v, A, B, C, opacity, r, g, b."""
    nt = off.shape[0] - 1
    chunk = (nt + n_threads - 1) // n_threads
    for th in nb.prange(n_threads):
        for t in range(th * chunk, min(nt, (th + 1) * chunk)):
            tx0 = (t % tiles_x) * tile
            ty0 = (t // tiles_x) * tile
            for py in range(ty0, min(ty0 + tile, height)):
                for px in range(tx0, min(tx0 + tile, width)):
                    d0 = dimg[py, px, 0]
                    d1 = dimg[py, px, 1]
                    d2 = dimg[py, px, 2]
                    if d0 == 0.0 and d1 == 0.0 and d2 == 0.0:
                        continue
                    T_fin = t_final[py, px]
                    T = T_fin
                    dbg = bg[0] * d0 + bg[1] * d1 + bg[2] * d2
                    acc0 = 0.0
                    acc1 = 0.0
                    acc2 = 0.0
                    la = 0.0
                    lc0 = 0.0
                    lc1 = 0.0
                    lc2 = 0.0
                    fx = px + 0.5
                    fy = py + 0.5
                    for j in range(n_walk[py, px] - 1, off[t] - 1, -1):
                        k = ids[j]
                        if px < box[k, 0] or px >= box[k, 1] or py < box[k, 2] or py >= box[k, 3]:
                            continue
                        dx = fx - rec[k, 0]
                        dy = fy - rec[k, 1]
                        A = rec[k, 2]
                        B = rec[k, 3]
                        C = rec[k, 4]
                        power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
                        if power > 0.0:
                            continue
                        G = math.exp(power)
                        raw = rec[k, 5] * G
                        alpha = min(cap, raw)
                        if alpha < thr:
                            continue
                        T = T / (1.0 - alpha)
                        w = alpha * T
                        grad[th, k, 6] += w * d0
                        grad[th, k, 7] += w * d1
                        grad[th, k, 8] += w * d2
                        acc0 = la * lc0 + (1.0 - la) * acc0
                        acc1 = la * lc1 + (1.0 - la) * acc1
                        acc2 = la * lc2 + (1.0 - la) * acc2
                        la = alpha
                        lc0 = rec[k, 6]
                        lc1 = rec[k, 7]
                        lc2 = rec[k, 8]
                        dalpha = T * ((lc0 - acc0) * d0 + (lc1 - acc1) * d1 + (lc2 - acc2) * d2)
                        dalpha -= T_fin / (1.0 - alpha) * dbg
                        if raw > cap:
                            continue
                        grad[th, k, 5] += G * dalpha
                        dpow = raw * dalpha
                        grad[th, k, 0] += dpow * (A * dx + B * dy)
                        grad[th, k, 1] += dpow * (C * dy + B * dx)
                        grad[th, k, 2] += -0.5 * dx * dx * dpow
                        grad[th, k, 3] += -dx * dy * dpow
                        grad[th, k, 4] += -0.5 * dy * dy * dpow


def _threads() -> int:
    return max(1, int(nb.get_num_threads()))


class Rasterize(torch.autograd.Function):
    """Front-to-back compositing of projected Gaussians with the standard 3DGS backward.

    ``forward(ctx, uv, conic, opacity, colors, depth, radius, valid, width, height, config)``:
    uv (N, 2), conic (N, 3), opacity (N,), colors (N, 3) tensors (one float dtype); depth, radius,
    valid (N,) numpy (no gradient). Returns the (H, W, 3) image (unclipped) of that dtype.
    """

    @staticmethod
    def forward(ctx: Any, uv: Tensor, conic: Tensor, opacity: Tensor, colors: Tensor, depth: np.ndarray,
                radius: np.ndarray, valid: np.ndarray, width: int, height: int, config: RenderConfig) -> Tensor:
        dt = uv.dtype
        npdt = np.float64 if dt == torch.float64 else np.float32
        idx = np.flatnonzero(valid)
        order = idx[np.argsort(depth[idx], kind="stable")].astype(np.int64)
        ot = torch.from_numpy(order)
        with torch.no_grad():
            rec = torch.cat([uv[ot], conic[ot], opacity[ot, None], colors[ot]], dim=1)
        rec_n = np.ascontiguousarray(rec.cpu().numpy().astype(npdt))
        box = _boxes(uv.detach().cpu().numpy().astype(np.float64), np.asarray(radius, np.float64), order,
                     width, height)
        tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
        off, ids = _bin(rec_n, box, tiles_x, tiles_y, TILE, float(config.alpha_threshold))
        bg = np.asarray(config.background, npdt)
        img = np.zeros((height, width, 3), npdt)
        t_final = np.ones((height, width), npdt)
        n_walk = np.zeros((height, width), np.int64)
        _forward(rec_n, box, off, ids, width, height, tiles_x, TILE, bg, npdt(config.alpha_threshold),
                 npdt(config.alpha_cap), npdt(config.t_min), img, t_final, n_walk)
        ctx.saved = (rec_n, order, box, off, ids, width, height, tiles_x, bg, config, t_final, n_walk,
                     uv.shape[0])
        ctx.dt = dt
        return torch.from_numpy(img)

    @staticmethod
    def backward(ctx: Any, dimg: Tensor) -> tuple[Any, ...]:
        rec_n, order, box, off, ids, width, height, tiles_x, bg, config, t_final, n_walk, n = ctx.saved
        npdt = rec_n.dtype.type
        nth = _threads()
        grad = np.zeros((nth, rec_n.shape[0], 9), npdt)
        d = np.ascontiguousarray(dimg.detach().cpu().numpy().astype(npdt))
        _backward(rec_n, box, off, ids, width, height, tiles_x, TILE, bg, npdt(config.alpha_threshold),
                  npdt(config.alpha_cap), t_final, n_walk, d, nth, grad)
        gk = torch.from_numpy(grad.sum(0)).to(ctx.dt)
        full = torch.zeros((n, 9), dtype=ctx.dt)
        full[torch.from_numpy(order)] = gk
        return (full[:, 0:2], full[:, 2:5], full[:, 5], full[:, 6:9], None, None, None, None, None, None)


def rasterize(uv: Tensor, conic: Tensor, opacity: Tensor, colors: Tensor, depth: np.ndarray, radius: np.ndarray,
              valid: np.ndarray, width: int, height: int, config: RenderConfig | None = None) -> Tensor:
    """(H, W, 3) unclipped image of projected Gaussians (differentiable in uv, conic, opacity, colors)."""
    return Rasterize.apply(uv, conic, opacity, colors, depth, radius, valid, int(width), int(height),
                           config or RenderConfig())


def render_view(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor, sh: Tensor,
                world_to_cam: np.ndarray, K: np.ndarray, width: int, height: int, near: float,
                config: RenderConfig | None = None, sh_degree: int | None = None) -> Tensor:
    """One view (H, W, 3), unclipped, differentiable in every Gaussian parameter.

    Same forward pass as :func:`holo_viewer.render.reference.render_view` (SH evaluated toward this
    camera's centre; ``config.shared_sh`` and ``config.cull_margin`` are not supported here).
    """
    config = config or RenderConfig()
    if config.shared_sh or config.cull_margin is not None:
        raise ValueError("differentiable.render_view: shared_sh and cull_margin are not supported")
    degree = int(round(math.sqrt(sh.shape[1]))) - 1
    if sh_degree is not None:
        degree = min(degree, int(sh_degree))
    if config.sh_degree is not None:
        degree = min(degree, int(config.sh_degree))
    w2c = np.asarray(world_to_cam, np.float64)
    cam_pos = torch.tensor(-w2c[:3, :3].T @ w2c[:3, 3], dtype=means.dtype)
    cov = covariance(quats, log_scales)
    uv, conic, depth, radius, valid = project(means, cov, w2c, K, width, height, near, config.dilation,
                                              config.radius_sigmas)
    colors = sh_rgb(means, sh, degree, cam_pos)
    return rasterize(uv, conic, torch.sigmoid(opacity_logits), colors, depth, radius, valid, width, height, config)


def render_gaussians(gaussians: Any, cameras: Any, indices: Sequence[int] | None = None,
                     config: RenderConfig | None = None) -> Tensor:
    """(V, H, W, 3) unclipped images of torch :class:`~holo_viewer.avatar.gaussians.Gaussians` through ``cameras``."""
    config = config or RenderConfig()
    near = cameras.near if config.near is None else float(config.near)
    idx = range(len(cameras)) if indices is None else indices
    return torch.stack([render_view(gaussians.means, gaussians.quats, gaussians.log_scales,
                                    gaussians.opacity_logits, gaussians.sh, cameras.world_to_cam[i],
                                    cameras.K[i], cameras.width, cameras.height, near, config) for i in idx])
