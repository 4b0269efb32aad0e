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
  tile binning (16x16 tiles; every Gaussian whose pixel box touches a tile, in depth order) and
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
TILE = 16


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
def _bin(box, tiles_x, tiles_y, tile):  # pragma: no cover - compiled
    """Per tile the indices into ``box`` (depth order kept) of boxes touching it: offsets, ids."""
    m = box.shape[0]
    nt = tiles_x * tiles_y
    count = np.zeros(nt + 1, np.int64)
    for k in range(m):
        x0, x1, y0, y1 = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
        if x0 >= x1 or y0 >= y1:
            continue
        for ty in range(y0 // tile, (y1 - 1) // tile + 1):
            for tx in range(x0 // tile, (x1 - 1) // tile + 1):
                count[ty * tiles_x + tx + 1] += 1
    for t in range(nt):
        count[t + 1] += count[t]
    ids = np.empty(count[nt], np.int32)
    fill = count[:nt].copy()
    for k in range(m):
        x0, x1, y0, y1 = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
        if x0 >= x1 or y0 >= y1:
            continue
        for ty in range(y0 // tile, (y1 - 1) // tile + 1):
            for tx in range(x0 // tile, (x1 - 1) // tile + 1):
                t = ty * tiles_x + tx
                ids[fill[t]] = k
                fill[t] += 1
    return count, ids


@nb.njit(parallel=True, cache=True)
def _forward(uv, conic, opac, col, order, box, off, ids, width, height, tiles_x, tile, bg, thr, cap, t_min,
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
                    g = order[k]
                    dx = fx - uv[g, 0]
                    dy = fy - uv[g, 1]
                    power = -0.5 * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) - conic[g, 1] * dx * dy
                    if power > 0.0:
                        continue
                    alpha = min(cap, opac[g] * math.exp(power))
                    if alpha < thr:
                        continue
                    test_T = T * (1.0 - alpha)
                    if test_T < t_min:
                        break
                    w = alpha * T
                    c0 += w * col[g, 0]
                    c1 += w * col[g, 1]
                    c2 += w * col[g, 2]
                    T = test_T
                    last = j + 1
                img[py, px, 0] = c0 + T * bg[0]
                img[py, px, 1] = c1 + T * bg[1]
                img[py, px, 2] = c2 + T * bg[2]
                t_final[py, px] = T
                n_walk[py, px] = last


@nb.njit(parallel=True, cache=True)
def _backward(uv, conic, opac, col, order, box, off, ids, width, height, tiles_x, tile, bg, thr, cap,
              t_final, n_walk, dimg, n_threads, g_uv, g_conic, g_opac, g_col):  # pragma: no cover - compiled
    """Gradients into per-thread buffers g_* (n_threads, N, ...)."""
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
                        g = order[k]
                        dx = fx - uv[g, 0]
                        dy = fy - uv[g, 1]
                        power = -0.5 * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) - conic[g, 1] * dx * dy
                        if power > 0.0:
                            continue
                        G = math.exp(power)
                        raw = opac[g] * G
                        alpha = min(cap, raw)
                        if alpha < thr:
                            continue
                        T = T / (1.0 - alpha)
                        w = alpha * T
                        g_col[th, g, 0] += w * d0
                        g_col[th, g, 1] += w * d1
                        g_col[th, g, 2] += w * d2
                        acc0 = la * lc0 + (1.0 - la) * acc0
                        acc1 = la * lc1 + (1.0 - la) * acc1
                        acc2 = la * lc2 + (1.0 - la) * acc2
                        la = alpha
                        lc0 = col[g, 0]
                        lc1 = col[g, 1]
                        lc2 = col[g, 2]
                        dalpha = T * ((lc0 - acc0) * d0 + (lc1 - acc1) * d1 + (lc2 - acc2) * d2)
                        dalpha -= T_fin / (1.0 - alpha) * dbg
                        if raw > cap:
                            continue
                        g_opac[th, g] += G * dalpha
                        dpow = raw * dalpha
                        g_uv[th, g, 0] += dpow * (conic[g, 0] * dx + conic[g, 1] * dy)
                        g_uv[th, g, 1] += dpow * (conic[g, 2] * dy + conic[g, 1] * dx)
                        g_conic[th, g, 0] += -0.5 * dx * dx * dpow
                        g_conic[th, g, 1] += -dx * dy * dpow
                        g_conic[th, g, 2] += -0.5 * dy * dy * dpow


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
        uv_n = uv.detach().cpu().numpy().astype(npdt)
        con_n = conic.detach().cpu().numpy().astype(npdt)
        op_n = opacity.detach().cpu().numpy().astype(npdt)
        col_n = colors.detach().cpu().numpy().astype(npdt)
        idx = np.flatnonzero(valid)
        order = idx[np.argsort(depth[idx], kind="stable")].astype(np.int64)
        box = _boxes(uv_n.astype(np.float64), np.asarray(radius, np.float64), order, width, height)
        tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
        off, ids = _bin(box, tiles_x, tiles_y, TILE)
        bg = np.asarray(config.background, npdt)
        img = np.zeros((height, width, 3), npdt)
        t_final = np.ones((height, width), npdt)
        n_walk = np.zeros((height, width), np.int64)
        _forward(uv_n, con_n, op_n, col_n, order, box, off, ids, width, height, tiles_x, TILE, bg,
                 npdt(config.alpha_threshold), npdt(config.alpha_cap), npdt(config.t_min), img, t_final, n_walk)
        ctx.saved = (uv_n, con_n, op_n, col_n, order, box, off, ids, width, height, tiles_x, bg, config,
                     t_final, n_walk)
        ctx.dt = dt
        return torch.from_numpy(img)

    @staticmethod
    def backward(ctx: Any, dimg: Tensor) -> tuple[Any, ...]:
        (uv_n, con_n, op_n, col_n, order, box, off, ids, width, height, tiles_x, bg, config,
         t_final, n_walk) = ctx.saved
        npdt = uv_n.dtype.type
        n = uv_n.shape[0]
        nth = _threads()
        g_uv = np.zeros((nth, n, 2), npdt)
        g_con = np.zeros((nth, n, 3), npdt)
        g_op = np.zeros((nth, n), npdt)
        g_col = np.zeros((nth, n, 3), npdt)
        d = np.ascontiguousarray(dimg.detach().cpu().numpy().astype(npdt))
        _backward(uv_n, con_n, op_n, col_n, order, box, off, ids, width, height, tiles_x, TILE, bg,
                  npdt(config.alpha_threshold), npdt(config.alpha_cap), t_final, n_walk, d, nth,
                  g_uv, g_con, g_op, g_col)
        out = [torch.from_numpy(a.sum(0)).to(ctx.dt) for a in (g_uv, g_con, g_op, g_col)]
        return (*out, None, None, None, None, None, None)


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
