"""View synthesis for a horizontal camera rig: render every ``step``-th quilt view, warp the rest.

Neighbouring quilt views are nearly the same picture: the cameras share rotation, focal length
and principal row and differ only by a sideways offset (and the principal column that converges
them on the focal plane). A point at camera depth ``z`` is seen in view ``j`` at

    u_j = fx (x + t_j) / z + cx_j,   so   u_j - u_k = fx (t_j - t_k) / z + (cx_j - cx_k)

(``t`` the camera's x translation): the views differ by a horizontal shift that depends only on
the point's inverse depth. Adjacent views of the default avatar differ by -2.3 .. +2.2 px
(30.9 dB over the head; a plain cross-fade of every other view gives 39.4 dB on the native image).
With each source pixel's inverse depth known, a missing view ``k`` between rendered views
``a < k < b`` is synthesized by a backward warp of both: for target pixel ``x`` the source
column is ``x + fx (t_a - t_k) w + cx_a - cx_k`` with ``w`` the inverse depth *at the source
column*, found by a fixed-point iteration from ``w`` at ``x``; the two warped images are blended
with weights ``(b - k, k - a) / (b - a)``.

The inverse depth comes from the Gaussians, not from the compositor (which has no depth
output): the centres of the Gaussians with opacity >= ``min_opacity`` are projected into each
source view, the nearest one per ``cell`` x ``cell`` pixel cell (about a dozen centres per cell,
:func:`auto_cell`) is kept (a z-buffer), empty
cells inside the head are filled from their neighbours, and the cells are interpolated
bilinearly; cells that stay empty (background) get the zero-disparity plane, where every view
agrees. Measured on the fitted avatar (bench/live_frame.py): every 2nd view 49 dB, every 3rd 46 dB,
every 4th 44 dB, every 5th (the live default) 43 dB over the head of the native image against
rendering all 48 (docs/live_frame.md).

Pure math, no I/O: :func:`rig_of` checks the cameras and returns what the warp needs,
:func:`source_views` which views to render, :func:`inverse_depth` the depth maps,
:func:`warp_views` the missing views (float32, or straight into uint8 quilt tiles).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from ..camera import Cameras
from ..errors import InputError

__all__ = ["Rig", "rig_of", "source_views", "inverse_depth", "warp_views", "bracket", "sampled_columns",
           "SampledColumns", "NativeTargets", "native_targets", "native_warp_available",
           "inverse_depth_torch", "warp_views_torch", "auto_cell", "zbuffer_depth"]


@dataclass(frozen=True)
class Rig:
    """What the warp needs of a horizontal camera rig (see :func:`rig_of`).

    Attributes
    ----------
    fx : float
        Shared focal length in pixels.
    tx : numpy.ndarray
        (V,) camera x translations (world -> camera), metres.
    cx : numpy.ndarray
        (V,) principal columns, pixels.
    w_zero : float
        Inverse depth (1/m) of the plane where all views agree (0 for parallel cameras): what
        background pixels get.
    """

    fx: float
    tx: np.ndarray
    cx: np.ndarray
    w_zero: float

    def shift(self, src: int, dst: int, w: float) -> float:
        """Pixels to add to a column of view ``dst`` to find a point of inverse depth ``w`` in
        view ``src``."""
        return float(self.fx * (self.tx[src] - self.tx[dst]) * w + self.cx[src] - self.cx[dst])


def rig_of(cameras: Cameras, tol: float = 1e-9) -> Rig:
    """The rig parameters of ``cameras``, or InputError when they are not a horizontal rig.

    A horizontal rig: every camera has the same rotation, fx, fy and cy, and the translations
    differ only in camera x (the quilt cameras of :func:`holo_viewer.display.cameras` are one).
    """
    if not isinstance(cameras, Cameras):
        raise InputError(f"cameras: expected holo_viewer.camera.Cameras, found {type(cameras).__name__}")
    V = len(cameras)
    R, t = cameras.R, cameras.t
    checks = (("rotation", np.abs(R - R[0]).max()), ("fx", np.abs(cameras.fx - cameras.fx[0]).max()),
              ("fy", np.abs(cameras.fy - cameras.fy[0]).max()), ("cy", np.abs(cameras.cy - cameras.cy[0]).max()),
              ("translation y, z", np.abs(t[:, 1:] - t[0, 1:]).max()))
    for name, dev in checks:
        scale = max(1.0, float(np.abs(cameras.K).max())) if name in ("fx", "fy", "cy") else 1.0
        if dev > tol * scale:
            raise InputError(f"cameras: view synthesis needs a horizontal rig (shared rotation, fx, fy, cy and "
                             f"camera y, z offsets); the {V} cameras differ in {name} by up to {dev:.3g}")
    fx = float(cameras.fx[0])
    tx = np.ascontiguousarray(t[:, 0], dtype=np.float64)
    cx = np.ascontiguousarray(cameras.cx, dtype=np.float64)
    w_zero = 0.0
    if V > 1 and abs(tx[-1] - tx[0]) > 0:
        w = -(cx[-1] - cx[0]) / (fx * (tx[-1] - tx[0]))
        w_zero = float(w) if np.isfinite(w) and w > 0 else 0.0
    return Rig(fx=fx, tx=tx, cx=cx, w_zero=w_zero)


def source_views(n_views: int, step: int) -> np.ndarray:
    """Views rendered when every ``step``-th is: 0, step, 2 step, ... and always the last."""
    if int(step) != step or step < 1:
        raise InputError(f"view_step: expected an integer >= 1, found {step!r}")
    if n_views < 1:
        raise InputError(f"n_views: expected >= 1, found {n_views}")
    return np.unique(np.concatenate((np.arange(0, n_views, int(step)), [n_views - 1]))).astype(np.int64)


def bracket(n_views: int, sources: np.ndarray) -> np.ndarray:
    """(T, 3) int64 rows (target, a, b): each view not in ``sources`` with its nearest sources
    below and above (``sources`` sorted, holding the first and last view)."""
    src = np.asarray(sources, dtype=np.int64)
    if src.size < 1 or src[0] != 0 or src[-1] != n_views - 1 or np.any(np.diff(src) <= 0):
        raise InputError(f"sources: expected increasing view indices from 0 to {n_views - 1}, found {src.tolist()}")
    targets = np.setdiff1d(np.arange(n_views), src)
    hi = np.searchsorted(src, targets)
    return np.stack((targets, src[hi - 1], src[hi]), axis=1).astype(np.int64)


CENTRES_PER_CELL = 12  # the automatic z-buffer cell holds this many kept centres on average


def auto_cell(n_kept: int, height: int, width: int) -> int:
    """Side of the z-buffer's cells for ``n_kept`` centres in a height x width view: about
    :data:`CENTRES_PER_CELL` per cell on average over the image (~twice that over a head that
    fills half of it), 1..16 px. Measured on the default avatar (step 5, native image): the best
    fixed cell was 6 px at 420x560 (44.6 dB; 4 px 43.5, 2 px 36.8: holes), 3 px at 210x280 and
    2 px at 105x140; this rule gives 6, 3 and 2."""
    if n_kept < 1:
        return 16
    return int(min(16, max(1, round(float(np.sqrt(CENTRES_PER_CELL * height * width / n_kept))))))


@numba.njit(inline="always")
def _cell_taps(i: int, cell: int, n: int) -> tuple[int, int, float]:
    """Linear interpolation of pixel i between cell centres: cells c0, c1 < n and the weight of c1."""
    f = (i + 0.5) / cell - 0.5
    c0 = min(max(int(np.floor(f)), 0), n - 1)
    return c0, min(c0 + 1, n - 1), min(max(f - c0, 0.0), 1.0)


@numba.njit(parallel=True, cache=True, nogil=True)
def _zbuffer(means: np.ndarray, keep: np.ndarray, R: np.ndarray, tx: np.ndarray, ty: float, tz: float, fx: float,
             fy: float, cx: np.ndarray, cy: float, near: float, H: int, W: int, cell: int, w_zero: float,
             out: np.ndarray) -> None:
    # (the rotation is done here, not by numpy: a BLAS matmul leaves OpenBLAS threads spinning,
    # which took a core from the next stages of a live frame: measured 2x slower warp)
    # The sources share the rotation, z and v (the rig's views differ in tx and cx only): computed once
    # per centre, the centres in front kept in order, then per source u alone. The same float64
    # expressions in the same order as computing them per source (no fastmath): the same depth maps bit
    # for bit (tests/test_view_synthesis.py); default avatar, 9 sources: 8.0 -> 6.4 ms of CPU.
    # The cell row too is the sources' (v is): computed once per centre, and the centres whose row is
    # outside the image (v < 0, NaN or past the last cell row), which every source skipped, dropped then;
    # per source only u, its test and its cell column remain (_keep_nearest's tests, split): the same
    # depth maps bit for bit (tested); with the hole filling's skipped background (_cells_to_pixels) the
    # default avatar's 9 sources at 210 x 280 px: 4.8 -> 3.6 ms of CPU.
    S = tx.size
    h, w = (H + cell - 1) // cell, (W + cell - 1) // cell
    n = means.shape[0]
    ok = np.zeros(n, dtype=np.bool_)
    rx, zs = np.empty(n), np.empty(n)
    yis = np.empty(n, dtype=np.int64)
    for i in numba.prange(n):
        if not keep[i]:
            continue
        mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
        z = R[2, 0] * mx + R[2, 1] * my + R[2, 2] * mz + tz
        if not z > near:
            continue
        v = fy * (R[1, 0] * mx + R[1, 1] * my + R[1, 2] * mz + ty) / z + cy
        if not v >= 0.0:
            continue
        yi = int(v / cell)
        if not yi < h:
            continue
        ok[i] = True
        zs[i] = z
        rx[i] = R[0, 0] * mx + R[0, 1] * my + R[0, 2] * mz
        yis[i] = yi
    m = 0
    for i in range(n):  # in order: the first of equal depths wins, as before
        if ok[i]:
            rx[m], zs[m], yis[m] = rx[i], zs[i], yis[i]
            m += 1
    for s in numba.prange(S):
        zb = np.full((h, w), np.inf)
        for i in range(m):
            z = zs[i]
            u = fx * (rx[i] + tx[s]) / z + cx[s]
            if not u >= 0.0:
                continue
            xi, yi = int(u / cell), yis[i]
            if xi < w and z < zb[yi, xi]:
                zb[yi, xi] = z
        _cells_to_pixels(zb, h, w, cell, H, W, w_zero, out[s])


@numba.njit(parallel=True, cache=True, nogil=True)
def _zbuffer_coef(means: np.ndarray, keep: np.ndarray, R: np.ndarray, ty: float, tz: float, coef: np.ndarray,
                  fy: float, cy: float, near: float, H: int, W: int, cell: int, w_zero: float,
                  out: np.ndarray) -> None:
    # as _zbuffer, with column u = (a X + b Z + c) / (e Z + f) per source (coef rows a, b, c, e, f)
    S = coef.shape[0]
    h, w = (H + cell - 1) // cell, (W + cell - 1) // cell
    for s in numba.prange(S):
        a, b, c, e, f = coef[s, 0], coef[s, 1], coef[s, 2], coef[s, 3], coef[s, 4]
        zb = np.full((h, w), np.inf)
        for i in range(means.shape[0]):
            if not keep[i]:
                continue
            mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
            z = R[2, 0] * mx + R[2, 1] * my + R[2, 2] * mz + tz
            den = e * z + f
            if not (z > near and den > 1e-9 * z):
                continue
            u = (a * (R[0, 0] * mx + R[0, 1] * my + R[0, 2] * mz) + b * z + c) / den
            v = fy * (R[1, 0] * mx + R[1, 1] * my + R[1, 2] * mz + ty) / z + cy
            _keep_nearest(zb, u, v, z, cell, h, w)
        _cells_to_pixels(zb, h, w, cell, H, W, w_zero, out[s])


@numba.njit(inline="always")
def _keep_nearest(zb: np.ndarray, u: float, v: float, z: float, cell: int, h: int, w: int) -> None:
    if not (u >= 0.0 and v >= 0.0):
        return
    xi, yi = int(u / cell), int(v / cell)
    if xi < w and yi < h and z < zb[yi, xi]:
        zb[yi, xi] = z


@numba.njit(cache=True, nogil=True)
def _cells_to_pixels(zb: np.ndarray, h: int, w: int, cell: int, H: int, W: int, w_zero: float,
                     out: np.ndarray) -> None:
    """Nearest depth per cell -> (H, W) inverse depth: holes filled, background w_zero, bilinear."""
    # holes inside the head (cells no centre fell in): the mean of >= 3 filled neighbours, 3 passes.
    # Per pass only the cells within one of a filled cell of the row above, its own or the row below are
    # visited (lo..hi): any other has no filled neighbour (it stays empty, as before); the background's
    # cells were ~3/4 of this function's time (9 sources, 210 x 280 px, cell 3: 2.1 -> 0.55 ms of CPU)
    lo_x, hi_x = np.empty(h, dtype=np.int64), np.empty(h, dtype=np.int64)
    for _ in range(3):
        zn = zb.copy()
        for y in range(h):  # each row's first and last filled cell (w, -1: none)
            lo, hi = w, -1
            for x in range(w):
                if zb[y, x] != np.inf:
                    lo = x
                    break
            for x in range(w - 1, lo - 1, -1):
                if zb[y, x] != np.inf:
                    hi = x
                    break
            lo_x[y], hi_x[y] = lo, hi
        for y in range(h):
            lo, hi = w, -1
            for yy in range(max(0, y - 1), min(h, y + 2)):
                lo, hi = min(lo, lo_x[yy]), max(hi, hi_x[yy])
            for x in range(max(0, lo - 1), min(w, hi + 2)):
                if zb[y, x] != np.inf:
                    continue
                acc, n = 0.0, 0
                for yy in range(max(0, y - 1), min(h, y + 2)):
                    for xx in range(max(0, x - 1), min(w, x + 2)):
                        if zb[yy, xx] != np.inf:
                            acc += zb[yy, xx]
                            n += 1
                if n >= 3:
                    zn[y, x] = acc / n
        zb[:, :] = zn
    for y in range(h):  # inverse depth per cell (background: the zero-disparity plane)
        for x in range(w):
            zb[y, x] = 1.0 / zb[y, x] if zb[y, x] != np.inf else w_zero
    # bilinear, separable: along x into a (h, W) buffer, then along y
    rows = np.empty((h, W))
    for x in range(W):
        x0, x1, ax = _cell_taps(x, cell, w)
        for y in range(h):
            rows[y, x] = (1.0 - ax) * zb[y, x0] + ax * zb[y, x1]
    for y in range(H):
        y0, y1, ay = _cell_taps(y, cell, h)
        for x in range(W):
            out[y, x] = (1.0 - ay) * rows[y0, x] + ay * rows[y1, x]


def zbuffer_depth(means: np.ndarray, opacity: np.ndarray, R: np.ndarray, ty: float, tz: float, coef: np.ndarray,
                  fy: float, cy: float, near: float, height: int, width: int, w_zero: float, *,
                  cell: int | None = None, min_opacity: float = 0.5, out: np.ndarray | None = None) -> np.ndarray:
    """(S, H, W) float32 inverse depth maps as :func:`inverse_depth`, for any images whose column
    of a point (X, Y, Z) = ``R p + (0, ty, tz)`` is ``(a X + b Z + c) / (e Z + f)`` (``coef`` (S, 5)
    rows a, b, c, e, f) and whose row is ``fy Y / Z + cy`` (e.g. the crossed-slit eye slices of
    :mod:`holo_viewer.render.crossed_slit`)."""
    means = np.ascontiguousarray(means, dtype=np.float64)
    opacity = np.asarray(opacity, dtype=np.float64)
    coef = np.ascontiguousarray(coef, dtype=np.float64)
    if means.ndim != 2 or means.shape[1] != 3 or opacity.shape != (means.shape[0],):
        raise InputError(f"means, opacity: expected (N, 3) and (N,), found {means.shape} and {opacity.shape}")
    if coef.ndim != 2 or coef.shape[1] != 5:
        raise InputError(f"coef: expected (S, 5) rows a, b, c, e, f, found {coef.shape}")
    keep = opacity >= min_opacity
    cell = auto_cell(int(keep.sum()), height, width) if cell is None else cell
    if int(cell) != cell or cell < 1:
        raise InputError(f"cell: expected an integer >= 1, found {cell!r}")
    S = coef.shape[0]
    if out is None:
        out = np.empty((S, height, width), dtype=np.float32)
    elif out.shape != (S, height, width) or out.dtype != np.float32:
        raise InputError(f"out: expected float32 {(S, height, width)}, found {out.dtype} {out.shape}")
    _zbuffer_coef(means, keep, np.ascontiguousarray(R, dtype=np.float64), float(ty), float(tz), coef, float(fy),
                  float(cy), float(near), int(height), int(width), int(cell), float(w_zero), out)
    return out


def inverse_depth(means: np.ndarray, opacity: np.ndarray, cameras: Cameras, views: np.ndarray, *,
                  rig: Rig | None = None, cell: int | None = None, min_opacity: float = 0.5,
                  out: np.ndarray | None = None) -> np.ndarray:
    """(len(views), H, W) float32 inverse camera depth (1/m) of the nearest surface per pixel.

    Parameters
    ----------
    means : numpy.ndarray
        (N, 3) Gaussian centres, world space.
    opacity : numpy.ndarray
        (N,) opacities in [0, 1]; only centres with opacity >= ``min_opacity`` count.
    cameras : Cameras
        A horizontal rig (:func:`rig_of`).
    views : numpy.ndarray
        The views to make depth maps for.
    cell : int or None
        Side of the z-buffer's cells in pixels; None: :func:`auto_cell` (6 px for the default
        avatar at 420x560).
    out : numpy.ndarray or None
        (len(views), H, W) float32 to write into.
    """
    rig = rig or rig_of(cameras)
    views = np.asarray(views, dtype=np.int64)
    means = np.asarray(means, dtype=np.float64)
    opacity = np.asarray(opacity, dtype=np.float64)
    if means.ndim != 2 or means.shape[1] != 3 or opacity.shape != (means.shape[0],):
        raise InputError(f"means, opacity: expected (N, 3) and (N,), found {means.shape} and {opacity.shape}")
    H, W = cameras.height, cameras.width
    keep = opacity >= min_opacity
    cell = auto_cell(int(keep.sum()), H, W) if cell is None else cell
    if int(cell) != cell or cell < 1:
        raise InputError(f"cell: expected an integer >= 1, found {cell!r}")
    if out is None:
        out = np.empty((views.size, H, W), dtype=np.float32)
    elif out.shape != (views.size, H, W) or out.dtype != np.float32:
        raise InputError(f"out: expected float32 {(views.size, H, W)}, found {out.dtype} {out.shape}")
    t0 = cameras.t[0]
    _zbuffer(np.ascontiguousarray(means), keep, np.ascontiguousarray(cameras.R[0]), rig.tx[views], float(t0[1]),
             float(t0[2]), rig.fx, float(cameras.fy[0]), rig.cx[views], float(cameras.cy[0]), float(cameras.near), H, W,
             int(cell), rig.w_zero, out)
    return out


@numba.njit(inline="always")
def _columns(wrow: np.ndarray, xlist: np.ndarray, d0: float, d1: float, iters: int, xs: np.ndarray,
             i0: np.ndarray, f: np.ndarray) -> None:
    """Source columns of the target columns ``xlist`` of a row: the fixed point of
    col = x + d0 + d1 w(col), w the source row's inverse depth (linear between pixels), started
    from w(x); written as the pixel index i0 and the fraction f of the linear interpolation. One
    pass over the row per iteration, so the independent columns overlap in the CPU."""
    W = wrow.size
    n = xlist.size
    for i in range(n):
        x = xlist[i]
        xs[i] = x + d0 + d1 * wrow[x]
    for it in range(iters + 1):
        for i in range(n):
            v = xs[i]
            p = min(max(int(np.floor(v)), 0), W - 2)
            i0[i] = p
            f[i] = min(max(v - p, 0.0), 1.0)
        if it == iters:
            break
        for i in range(n):
            p = i0[i]
            xs[i] = xlist[i] + d0 + d1 * ((1.0 - f[i]) * wrow[p] + f[i] * wrow[p + 1])


@numba.njit(parallel=True, cache=True, nogil=True)
def _row_extents(images: np.ndarray, wmaps: np.ndarray, bg: np.ndarray, spans: np.ndarray, wr: np.ndarray) -> None:
    """Per (source, row): the first and last column that is not the background colour (an empty
    span is (W, -1)), and the row's inverse-depth range."""
    S, H, W = images.shape[0], images.shape[1], images.shape[2]
    for sy in numba.prange(S * H):
        s, y = sy // H, sy % H
        lo, hi = W, -1
        for x in range(W):
            if images[s, y, x, 0] != bg[0] or images[s, y, x, 1] != bg[1] or images[s, y, x, 2] != bg[2]:
                if lo == W:
                    lo = x
                hi = x
        spans[s, y, 0], spans[s, y, 1] = lo, hi
        wmin, wmax = np.inf, -np.inf
        for x in range(W):
            wmin = min(wmin, wmaps[s, y, x])
            wmax = max(wmax, wmaps[s, y, x])
        wr[s, y, 0], wr[s, y, 1] = wmin, wmax


@numba.njit(inline="always")
def _live_range(span: np.ndarray, wr: np.ndarray, d0: float, d1: float, lo: int, hi: int) -> tuple[int, int]:
    """Grow the target columns [lo, hi] by those that can read a non-background pixel of a source
    row whose non-background span is ``span`` (columns x + d0 + d1 w, w within ``wr``; the linear
    interpolation reads floor(col) and floor(col) + 1)."""
    if span[1] < span[0]:
        return lo, hi
    s0, s1 = d0 + d1 * wr[0], d0 + d1 * wr[1]
    smin, smax = min(s0, s1), max(s0, s1)
    return min(lo, int(np.floor(span[0] - 2.0 - smax))), max(hi, int(np.ceil(span[1] + 2.0 - smin)))


@numba.njit(parallel=True, cache=True, nogil=True)
def _warp(images: np.ndarray, wmaps: np.ndarray, slot: np.ndarray, jobs: np.ndarray, d: np.ndarray,
          iters: int, offsets: np.ndarray, columns: np.ndarray, spans: np.ndarray, wr: np.ndarray,
          bg: np.ndarray, out: np.ndarray, out_u8: np.ndarray, row0: np.ndarray, col0: np.ndarray,
          to_u8: bool) -> None:
    T = jobs.shape[0]
    H, W = images.shape[1], images.shape[2]
    every = np.arange(W).astype(np.int32)
    listed = offsets.size > 0
    bg8 = np.empty(3, np.uint8)
    for c in range(3):
        bg8[c] = min(max(int(bg[c] * 255.0 + 0.5), 0), 255)
    rows = 8  # rows per work item: the per-row buffers are made once per item
    per = (H + rows - 1) // rows
    for item in numba.prange(T * per):  # band-major: neighbouring items read the same source rows
        j, y0 = item % T, (item // T) * rows
        k, a, b = jobs[j, 0], jobs[j, 1], jobs[j, 2]
        sa, sb = slot[a], slot[b]
        wa = (b - k) / (b - a)
        wb = 1.0 - wa
        xs = np.empty(W)
        i0a, i0b = np.empty(W, np.int64), np.empty(W, np.int64)
        fa, fb = np.empty(W), np.empty(W)
        for y in range(y0, min(H, y0 + rows)):
            xall = columns[offsets[k * H + y]:offsets[k * H + y + 1]] if listed else every
            # columns that can only read background in both sources are background: not warped
            lo, hi = _live_range(spans[sa, y], wr[sa, y], d[j, 0], d[j, 1], W, -1)
            lo, hi = _live_range(spans[sb, y], wr[sb, y], d[j, 2], d[j, 3], lo, hi)
            n0 = np.searchsorted(xall, lo) if hi >= lo else xall.size
            n1 = np.searchsorted(xall, hi, side="right") if hi >= lo else xall.size
            for i in range(xall.size):
                if n0 <= i < n1:
                    continue
                x = xall[i]
                for c in range(3):
                    if to_u8:
                        out_u8[row0[j] + y, col0[j] + x, c] = bg8[c]
                    else:
                        out[k, y, x, c] = bg[c]
            xl = xall[n0:n1]
            ia, ib = images[sa, y], images[sb, y]
            _columns(wmaps[sa, y], xl, d[j, 0], d[j, 1], iters, xs, i0a, fa)
            _columns(wmaps[sb, y], xl, d[j, 2], d[j, 3], iters, xs, i0b, fb)
            for i in range(xl.size):
                x, p, q = xl[i], i0a[i], i0b[i]
                ca0, ca1 = wa * (1.0 - fa[i]), wa * fa[i]
                cb0, cb1 = wb * (1.0 - fb[i]), wb * fb[i]
                r = ca0 * ia[p, 0] + ca1 * ia[p + 1, 0] + cb0 * ib[q, 0] + cb1 * ib[q + 1, 0]
                g = ca0 * ia[p, 1] + ca1 * ia[p + 1, 1] + cb0 * ib[q, 1] + cb1 * ib[q + 1, 1]
                bl = ca0 * ia[p, 2] + ca1 * ia[p + 1, 2] + cb0 * ib[q, 2] + cb1 * ib[q + 1, 2]
                if to_u8:  # round half up (to_uint8 rounds half to even: they differ on exact ties only)
                    oy, ox = row0[j] + y, col0[j] + x
                    out_u8[oy, ox, 0] = min(max(int(r * 255.0 + 0.5), 0), 255)
                    out_u8[oy, ox, 1] = min(max(int(g * 255.0 + 0.5), 0), 255)
                    out_u8[oy, ox, 2] = min(max(int(bl * 255.0 + 0.5), 0), 255)
                else:
                    out[k, y, x, 0] = r
                    out[k, y, x, 1] = g
                    out[k, y, x, 2] = bl


#: the float32 warp's compiler freedoms: fused multiply-adds, no NaN / inf / signed-zero cases (none of
#: them occur: finite images and depths); no reassociation. A/B on one group frame's captured inputs
#: (6 alternations, load 13-16, CPU): 46.0 -> 42.2 ms, 103 of 5.4M quilt pixels 1 off the kernel without
#: them (all flags, reassociation included: 41.4 ms; nnan/ninf/nsz alone 44.4 ms, bit-identical)
_WARP32_FASTMATH = {"contract", "nnan", "ninf", "nsz"}


@numba.njit(inline="always", fastmath=_WARP32_FASTMATH)
def _columns32(wrow: np.ndarray, xlist: np.ndarray, d0: np.float32, d1: np.float32, iters: int, xs: np.ndarray,
               i0: np.ndarray, f: np.ndarray) -> None:
    """:func:`_columns` in float32 (``xs``, ``f`` float32, ``i0`` int32): the same expressions."""
    W = wrow.size
    n = xlist.size
    one, zero = np.float32(1.0), np.float32(0.0)
    for i in range(n):
        x = xlist[i]
        xs[i] = np.float32(x) + d0 + d1 * wrow[x]
    for it in range(iters + 1):
        for i in range(n):
            v = xs[i]
            p = min(max(int(np.floor(v)), 0), W - 2)
            i0[i] = p
            f[i] = min(max(v - np.float32(p), zero), one)
        if it == iters:
            break
        for i in range(n):
            p = i0[i]
            xs[i] = np.float32(xlist[i]) + d0 + d1 * ((one - f[i]) * wrow[p] + f[i] * wrow[p + 1])


@numba.njit(parallel=True, cache=True, nogil=True, fastmath=_WARP32_FASTMATH)
def _warp_u8(images: np.ndarray, wmaps: np.ndarray, slot: np.ndarray, jobs: np.ndarray, d: np.ndarray,
             iters: int, offsets: np.ndarray, columns: np.ndarray, spans: np.ndarray, wr: np.ndarray,
             bg: np.ndarray, out_u8: np.ndarray, row0: np.ndarray, col0: np.ndarray) -> None:
    """:func:`_warp` into the uint8 quilt, in float32 (the live path): the same columns, weights and
    rounding half up, the arithmetic in float32 instead of float64 (0.73x the CPU of the float64
    kernel on a group frame's 39 synthesized views, A/B; within 1 of it per channel, tested)."""
    T = jobs.shape[0]
    H, W = images.shape[1], images.shape[2]
    every = np.arange(W).astype(np.int32)
    listed = offsets.size > 0
    bg8 = np.empty(3, np.uint8)
    for c in range(3):
        bg8[c] = min(max(int(bg[c] * 255.0 + 0.5), 0), 255)
    one, half, full = np.float32(1.0), np.float32(0.5), np.float32(255.0)
    rows = 16  # rows per work item: the per-row buffers are made once per item (16: -2 % against 8)
    per = (H + rows - 1) // rows
    for item in numba.prange(T * per):  # band-major: neighbouring items read the same source rows
        j, y0 = item % T, (item // T) * rows
        k, a, b = jobs[j, 0], jobs[j, 1], jobs[j, 2]
        sa, sb = slot[a], slot[b]
        wa = np.float32((b - k) / (b - a))
        wb = one - wa
        da0, da1, db0, db1 = np.float32(d[j, 0]), np.float32(d[j, 1]), np.float32(d[j, 2]), np.float32(d[j, 3])
        xs = np.empty(W, np.float32)
        i0a, i0b = np.empty(W, np.int32), np.empty(W, np.int32)
        fa, fb = np.empty(W, np.float32), np.empty(W, np.float32)
        for y in range(y0, min(H, y0 + rows)):
            xall = columns[offsets[k * H + y]:offsets[k * H + y + 1]] if listed else every
            # columns that can only read background in both sources are background: not warped
            lo, hi = _live_range(spans[sa, y], wr[sa, y], d[j, 0], d[j, 1], W, -1)
            lo, hi = _live_range(spans[sb, y], wr[sb, y], d[j, 2], d[j, 3], lo, hi)
            n0 = np.searchsorted(xall, lo) if hi >= lo else xall.size
            n1 = np.searchsorted(xall, hi, side="right") if hi >= lo else xall.size
            orow = out_u8[row0[j] + y]
            for i in range(n0):  # two loops without a test per column: 0.91x the kernel's CPU (A/B)
                ox = col0[j] + xall[i]
                for c in range(3):
                    orow[ox, c] = bg8[c]
            for i in range(n1, xall.size):
                ox = col0[j] + xall[i]
                for c in range(3):
                    orow[ox, c] = bg8[c]
            xl = xall[n0:n1]
            ia, ib = images[sa, y], images[sb, y]
            _columns32(wmaps[sa, y], xl, da0, da1, iters, xs, i0a, fa)
            _columns32(wmaps[sb, y], xl, db0, db1, iters, xs, i0b, fb)
            for i in range(xl.size):
                p, q = i0a[i], i0b[i]
                ca0, ca1 = wa * (one - fa[i]), wa * fa[i]
                cb0, cb1 = wb * (one - fb[i]), wb * fb[i]
                ox = col0[j] + xl[i]
                for c in range(3):
                    v = ca0 * ia[p, c] + ca1 * ia[p + 1, c] + cb0 * ib[q, c] + cb1 * ib[q + 1, c]
                    orow[ox, c] = min(max(int(v * full + half), 0), 255)


#: the float32 warp into the quilt: ``"auto"`` (C++ where :mod:`holo_viewer.render._splat_cpp` is built, AVX-512
#: where the CPU has it; 16.3 -> 10.1 ms of CPU on a live frame's 39 views, one thread, A/B), ``"cpp-scalar"``
#: or ``"numba"`` (:func:`_warp_u8`); all write the same bytes (tests/test_view_synthesis.py)
WARP_KERNEL = "auto"


def row_extents(images: np.ndarray, wmaps: np.ndarray, bg: np.ndarray, spans: np.ndarray, wr: np.ndarray) -> None:
    """:func:`_row_extents` into ``spans`` (S, H, 2) int64 and ``wr`` (S, H, 2) float64: in C++ where the extension is
    built and :data:`WARP_KERNEL` is not ``"numba"`` (``_splat_cpp.row_extents``, the same values, tested;
    0.4 against 3.3 ms of CPU for a full-tile group frame's 9 sources), else the numba kernel."""
    cpp = _warp_cpp() if WARP_KERNEL != "numba" else None
    if cpp is None or not hasattr(cpp, "row_extents"):
        _row_extents(images, wmaps, bg, spans, wr)
        return
    S, H, W = wmaps.shape
    cpp.row_extents(np.ascontiguousarray(images), np.ascontiguousarray(wmaps), np.ascontiguousarray(bg, np.float32),
                    spans, wr, S, H, W, int(numba.get_num_threads()), 1 if WARP_KERNEL == "cpp-scalar" else 0)


def _warp_cpp():  # noqa: ANN202
    """The compiled warp's module, or None where the extension (or its ``warp_u8``) is not built."""
    from .fast import _cpp

    cpp = _cpp()
    return cpp if cpp is not None and hasattr(cpp, "warp_u8") else None


class SampledColumns(tuple):
    """``(offsets, columns)`` as :func:`sampled_columns` builds them (a 2-tuple), with the ``shape`` (V, H, W)
    of their mask: every column lies in [0, W), each row's columns increase and ``offsets`` ends at their
    count, by construction, so :func:`warp_views` does not check them again each frame. The arrays are
    the table's own: do not write into them (a pair that is not this type is checked at every call)."""

    def __new__(cls, offsets: np.ndarray, columns: np.ndarray, shape: tuple[int, int, int]) -> "SampledColumns":
        self = super().__new__(cls, (offsets, columns))
        self.shape = tuple(int(x) for x in shape)
        return self

    def __getnewargs__(self) -> tuple:  # copy and pickle rebuild it with its shape
        return (self[0], self[1], self.shape)

    @property
    def offsets(self) -> np.ndarray:
        return self[0]

    @property
    def columns(self) -> np.ndarray:
        return self[1]


def sampled_columns(pixels: np.ndarray) -> SampledColumns:
    """(offsets (V H + 1,) int64, columns int32): per (view, row) the columns where ``pixels``
    (V, H, W) bool is set, for :func:`warp_views`' ``pixels`` (e.g. the quilt pixels the
    interleave reads); a :class:`SampledColumns`, which warp_views trusts without a check."""
    pixels = np.asarray(pixels, dtype=bool)
    if pixels.ndim != 3:
        raise InputError(f"pixels: expected a (V, H, W) bool array, found shape {pixels.shape}")
    V, H, W = pixels.shape
    offsets = np.zeros(V * H + 1, dtype=np.int64)
    np.cumsum(pixels.reshape(V * H, W).sum(axis=1), out=offsets[1:])
    columns = np.nonzero(pixels.reshape(V * H, W))[1].astype(np.int32)
    return SampledColumns(offsets, columns, (V, H, W))


class NativeTargets:
    """Where each texel the interleave reads lands in the native image (:func:`native_targets`), for
    :func:`warp_views`' ``native``: per listed texel of a :class:`SampledColumns` (in its order) a code of its
    one or two native subpixels, ``codes`` (n,) uint16 (low and high byte; a texel read once names its byte
    twice), byte b = (p << 2) | channel addressing ``rowoff[y] + coloff[x] + lut[b]`` of the flat native image
    for texel (k, y, x); ``shape`` the native image's, ``sampled`` the table the codes follow."""

    def __init__(self, sampled: SampledColumns, codes: np.ndarray, rowoff: np.ndarray, coloff: np.ndarray,
                 lut: np.ndarray, shape: tuple[int, int, int]) -> None:
        self.sampled, self.rowoff, self.coloff, self.lut = sampled, rowoff, coloff, lut
        #: the kernel's one stream: each listed column | its code << 16 (uint32; 27 MB read a frame for the
        #: Portrait where the columns and the codes apart were 40 MB)
        self.packed = sampled.columns.astype(np.uint32) | (codes.astype(np.uint32) << 16)
        self.shape = tuple(int(s) for s in shape)

    @property
    def codes(self) -> np.ndarray:
        """(n,) uint16: each listed texel's code (low byte, high byte)."""
        return (self.packed >> 16).astype(np.uint16)


def native_targets(idx0: np.ndarray, tiles: np.ndarray, sampled: SampledColumns, quilt_shape: tuple,
                   native_shape: tuple) -> NativeTargets | None:
    """The native subpixels of the texels in ``sampled`` for a nearest interleave whose flat gather is
    ``native.ravel()[s] = quilt.ravel()[idx0[s]]`` (``Interleaver.gather_indices()[0]``), the views' tiles at
    ``tiles`` (V, 2) (row, column) of the quilt; None where the layout does not fit the codes: a subpixel
    reading a texel outside every view's tile or not in ``sampled``, a texel read by more than two subpixels,
    a view's image row (column) read by native rows (columns) that depend on the view, more than 64 native
    pixels per texel, or views wider than 65535. Every native subpixel is then written by ``warp_views(native=)``."""
    idx0 = np.asarray(idx0)
    tiles = np.asarray(tiles, dtype=np.int64)
    Hq, Wq = int(quilt_shape[0]), int(quilt_shape[1])
    Hn, Wn = int(native_shape[0]), int(native_shape[1])
    V, H, W = sampled.shape
    if idx0.size != Hn * Wn * 3 or tiles.shape != (V, 2) or W > 65535:
        return None
    q = idx0.astype(np.int32)
    ch = np.tile(np.arange(3, dtype=np.int32), Hn * Wn)
    q -= ch
    if q.min(initial=0) < 0 or q.max(initial=0) >= Hq * Wq * 3 or (q % 3).any():
        return None  # the interleave reads each subpixel's own channel
    q //= 3
    view_of = np.full((Hq, Wq), -1, dtype=np.int16)
    for k, (r0, c0) in enumerate(tiles):
        view_of[r0:r0 + H, c0:c0 + W] = k
    k = view_of.reshape(-1)[q]
    if k.min() < 0:
        return None
    qr = q // np.int32(Wq)
    y = qr - tiles[:, 0].astype(np.int32)[k]
    x = q - qr * np.int32(Wq) - tiles[:, 1].astype(np.int32)[k]
    yrow = y.reshape(Hn, Wn * 3)
    xcol = x.reshape(Hn, Wn, 3)
    if not (yrow == yrow[:, :1]).all() or not (xcol == xcol[:1, :, :1]).all():
        return None
    y_of, x_of = yrow[:, 0], xcol[0, :, 0]  # the image row of each native row, column of each native column
    rbase = np.full(H, Hn, dtype=np.int64)
    np.minimum.at(rbase, y_of, np.arange(Hn))
    cbase = np.full(W, Wn, dtype=np.int64)
    np.minimum.at(cbase, x_of, np.arange(Wn))
    ry, rx = np.arange(Hn) - rbase[y_of], np.arange(Wn) - cbase[x_of]
    rbase[rbase == Hn] = 0  # rows / columns no subpixel reads (nothing listed there)
    cbase[cbase == Wn] = 0
    RX = int(rx.max()) + 1
    if (int(ry.max()) + 1) * RX > 64:
        return None
    offsets, columns = sampled
    n = columns.size
    tid = np.full(V * H * W, -1, dtype=np.int32)  # texel -> its index in the table
    tid[np.repeat(np.arange(V * H, dtype=np.int64), np.diff(offsets)) * W + columns] = np.arange(n, dtype=np.int32)
    tid = tid[(k.astype(np.int32) * np.int32(H) + y) * np.int32(W) + x] if V * H * W < 2 ** 31 else \
        tid[(k.astype(np.int64) * H + y) * W + x]
    if tid.min(initial=0) < 0:
        return None
    count = np.bincount(tid, minlength=n)
    if count.max(initial=0) > 2 or count.min(initial=1) < 1:
        return None
    b = ((((ry[:, None, None] * RX + rx[None, :, None]) << 2) | np.arange(3)).astype(np.uint16)).reshape(-1)
    lo = np.empty(n, dtype=np.uint16)
    lo[tid] = b  # one of each texel's subpixels (each has one or two), the other below
    other = b != lo[tid]
    hi = lo.copy()
    hi[tid[other]] = b[other]
    codes = lo | (hi << 8)
    lut = np.zeros(256, dtype=np.int32)
    p = np.arange((int(ry.max()) + 1) * RX)
    for c in range(3):
        lut[(p << 2) | c] = (p // RX) * Wn * 3 + (p % RX) * 3 + c
    return NativeTargets(sampled, codes, (rbase * Wn * 3).astype(np.int64), (cbase * 3).astype(np.int32), lut,
                         (Hn, Wn, 3))


#: _warp_plan's last plans: (V, S) -> ((fx, tx copy, cx copy, sources copy), (jobs, slot, d))
_PLANS: dict[tuple[int, int], tuple] = {}


def _warp_plan(rig: Rig, sources: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(jobs (T, 3) int64 :func:`bracket`, slot (V,) int64: each view's index in ``sources`` or -1, d (T, 4)
    float64: column = x + d0 + d1 w for the job's sources a, b) of :func:`warp_views`. The same arrays as
    computing them, kept for the last rig and sources of each (V, S) (a live frame warps with the same ones:
    ~0.3 ms of CPU a frame); the key holds copies of the rig's arrays and of ``sources``, so a changed
    rig or source list is planned again. The arrays returned are shared: read them, do not write."""
    V = rig.tx.size
    key = (V, sources.size)
    hit = _PLANS.get(key)
    if hit is not None:
        (fx, tx, cx, src), plan = hit
        if fx == rig.fx and np.array_equal(tx, rig.tx) and np.array_equal(cx, rig.cx) and np.array_equal(src, sources):
            return plan
    jobs = bracket(V, sources)
    slot = np.full(V, -1, dtype=np.int64)
    slot[sources] = np.arange(sources.size)
    d = np.empty((len(jobs), 4))
    for j, (k, a, b) in enumerate(jobs):  # column = x + d0 + d1 w for sources a, b
        d[j] = (rig.cx[a] - rig.cx[k], rig.fx * (rig.tx[a] - rig.tx[k]),
                rig.cx[b] - rig.cx[k], rig.fx * (rig.tx[b] - rig.tx[k]))
    if len(_PLANS) >= 8:
        _PLANS.clear()
    _PLANS[key] = ((float(rig.fx), np.array(rig.tx, copy=True), np.array(rig.cx, copy=True),
                    np.array(sources, copy=True)), (jobs, slot, d))
    return jobs, slot, d


def warp_views(images: np.ndarray, wmaps: np.ndarray, sources: np.ndarray, rig: Rig, *, iters: int = 1,
               out: np.ndarray | None = None, quilt: np.ndarray | None = None,
               tiles: np.ndarray | None = None, pixels: tuple[np.ndarray, np.ndarray] | None = None,
               background: tuple[float, float, float] = (0.0, 0.0, 0.0), exact: bool = False,
               native: np.ndarray | None = None, targets: NativeTargets | None = None) -> np.ndarray:
    """Synthesize every view of the rig not in ``sources`` from its nearest rendered views on
    either side.

    Parameters
    ----------
    images : numpy.ndarray
        (S, H, W, 3) float32 renders of the ``sources`` views, in that order.
    wmaps : numpy.ndarray
        (S, H, W) float32 inverse depths of the sources (:func:`inverse_depth`).
    sources : numpy.ndarray
        The S rendered views, increasing, holding 0 and V - 1 (:func:`source_views`); V is the
        rig's number of cameras.
    rig : Rig
    iters : int
        Fixed-point iterations for the source column after the first guess (1: the default
        avatar's native image is within 0.05 dB of 3 iterations).
    out : numpy.ndarray or None
        (V, H, W, 3) float32: the synthesized views are written at their indices (the sources'
        slots are not touched).
    quilt, tiles : numpy.ndarray or None
        Instead of ``out``: a uint8 quilt and (V, 2) int64 (row, column) of each view's tile in it;
        the synthesized views are written there (rounded half up to uint8).
    pixels : tuple or None
        :func:`sampled_columns` of a (V, H, W) mask of the pixels to write (the others are left as
        they are); None: every pixel.
    background : tuple of 3 float
        The renders' background colour: target pixels that can read only background pixels of
        both sources (outside each source row's non-background span, grown by the largest shift
        its depths allow) are set to it without a warp, which is what the warp gives there.
    exact : bool
        Into ``quilt``: the float64 kernel (the reference) instead of the float32 one (default; within
        1 per channel of it). ``out`` is always written by the float64 kernel. The float32 one runs in
        C++ where the extension is built (``_splat_cpp.warp_u8``: the numba kernel's bytes, tested;
        :data:`WARP_KERNEL`).
    native, targets : numpy.ndarray or None
        Instead of ``out`` / ``quilt``: the (Hn, Wn, 3) uint8 native image of a nearest interleave, every
        subpixel (``targets``: :func:`native_targets` of that interleave, ``pixels`` its ``sampled``): each
        synthesized view's subpixel gets the byte the float32 warp writes into the quilt for its texel's
        channel, each source view's the byte ``to_uint8`` writes into its tile, so the image equals tiling the
        sources, warping into the quilt and interleaving it, bit for bit (tested), with neither the quilt nor
        the interleave's gather (the source renders are not checked for NaN / inf there). Only the compiled
        kernel (:func:`native_warp_available`; ``_splat_cpp.warp_native``).

    Returns
    -------
    numpy.ndarray
        ``out`` (or ``quilt``).
    """
    images = np.asarray(images)
    sources = np.asarray(sources, dtype=np.int64)
    V = rig.tx.size
    if images.dtype != np.float32 or images.ndim != 4 or images.shape[3] != 3 or images.shape[0] != sources.size:
        raise InputError(f"images: expected ({sources.size}, H, W, 3) float32 (one per source view), found "
                         f"{images.dtype} {images.shape}")
    _, H, W, _ = images.shape
    jobs, slot, d = _warp_plan(rig, sources)
    if wmaps.shape != (sources.size, H, W) or wmaps.dtype != np.float32:
        raise InputError(f"wmaps: expected float32 {(sources.size, H, W)}, found {wmaps.dtype} {wmaps.shape}")
    if W < 2:
        raise InputError(f"views: expected at least 2 columns, found {W}")
    if pixels is None:
        offsets, columns = np.zeros(0, np.int64), np.zeros(0, np.int32)
    else:
        offsets, columns = (np.ascontiguousarray(pixels[0], dtype=np.int64),
                            np.ascontiguousarray(pixels[1], dtype=np.int32))
        # sampled_columns' own tables hold by construction what this checks (every column of 2.8M for the
        # Portrait at tile scale 0.5: 0.3-0.7 ms of CPU a live frame); any other pair is checked
        own = isinstance(pixels, SampledColumns) and pixels.shape == (V, H, W) and pixels.offsets is offsets \
            and pixels.columns is columns
        if not own and (offsets.shape != (V * H + 1,) or offsets[-1] != columns.size or (
                columns.size and (columns.min() < 0 or columns.max() >= W))):
            raise InputError(f"pixels: expected sampled_columns of a ({V}, {H}, {W}) mask")
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    spans = np.empty((sources.size, H, 2), dtype=np.int64)
    wr = np.empty((sources.size, H, 2), dtype=np.float64)
    row_extents(images, wmaps, bg, spans, wr)
    if native is not None:
        _warp_native(images, wmaps, sources, slot, jobs, d, int(iters), pixels, spans, wr, bg, native, targets)
        return native
    if quilt is not None:
        if tiles is None or quilt.dtype != np.uint8:
            raise InputError("quilt: expected a uint8 quilt together with tiles (V, 2) row/column offsets")
        tiles = np.asarray(tiles, dtype=np.int64)
        row0, col0 = tiles[jobs[:, 0], 0].copy(), tiles[jobs[:, 0], 1].copy()
        if (row0.min(initial=0) < 0 or col0.min(initial=0) < 0 or row0.max(initial=0) + H > quilt.shape[0]
                or col0.max(initial=0) + W > quilt.shape[1]):
            raise InputError(f"tiles: a {H}x{W} tile falls outside the {quilt.shape[:2]} quilt")
        if exact:
            _warp(images, wmaps, slot, jobs, d, int(iters), offsets, columns, spans, wr, bg,
                  np.empty((1, 1, 1, 3), np.float32), quilt, row0, col0, True)
        else:
            cpp = _warp_cpp() if WARP_KERNEL != "numba" and quilt.flags.c_contiguous else None
            if cpp is not None:  # the numba kernel's bytes (tested), ~0.6x its CPU
                cpp.warp_u8(np.ascontiguousarray(images), np.ascontiguousarray(wmaps), slot,
                            np.ascontiguousarray(jobs, dtype=np.int64), d, int(iters), offsets, columns, spans, wr, bg,
                            quilt, row0, col0,
                            sources.size, V, len(jobs), H, W, quilt.shape[0], quilt.shape[1],
                            int(numba.get_num_threads()), 1 if WARP_KERNEL == "cpp-scalar" else 0)
            else:
                _warp_u8(images, wmaps, slot, jobs, d, int(iters), offsets, columns, spans, wr, bg, quilt, row0, col0)
        return quilt
    if out is None or out.shape != (V, H, W, 3) or out.dtype != np.float32:
        raise InputError(f"out: expected a float32 {(V, H, W, 3)} array (or quilt and tiles), found "
                         f"{getattr(out, 'dtype', None)} {getattr(out, 'shape', None)}")
    _warp(images, wmaps, slot, jobs, d, int(iters), offsets, columns, spans, wr, bg, out, np.empty((1, 1, 3), np.uint8),
          np.zeros(0, np.int64), np.zeros(0, np.int64), False)
    return out


def native_warp_available() -> bool:
    """True where the compiled kernel of ``warp_views(native=)`` is built (``_splat_cpp.warp_native``)."""
    cpp = _warp_cpp()
    return cpp is not None and hasattr(cpp, "warp_native")


def _warp_native(images: np.ndarray, wmaps: np.ndarray, sources: np.ndarray, slot: np.ndarray, jobs: np.ndarray,
                 d: np.ndarray, iters: int, pixels: Any, spans: np.ndarray, wr: np.ndarray, bg: np.ndarray,
                 native: np.ndarray, targets: NativeTargets | None) -> None:
    """warp_views(native=): the checks, then ``_splat_cpp.warp_native`` (the index bounds it checks itself)."""
    V, H, W = slot.size, images.shape[1], images.shape[2]
    if not isinstance(targets, NativeTargets) or targets.sampled is not pixels or pixels.shape != (V, H, W):
        raise InputError(f"targets: expected native_targets of the pixels given (a ({V}, {H}, {W}) SampledColumns)")
    if native.dtype != np.uint8 or tuple(native.shape) != targets.shape or not native.flags.c_contiguous:
        raise InputError(f"native: expected a C-contiguous uint8 {targets.shape} array, found {native.dtype} "
                         f"{native.shape}")
    cpp = _warp_cpp() if native_warp_available() else None
    if cpp is None:
        raise InputError("native: warp_views(native=) needs the compiled extension (holo_viewer.render._splat_cpp)")
    job_of = np.full(V, -1, dtype=np.int64)
    job_of[jobs[:, 0]] = np.arange(len(jobs))
    cpp.warp_native(np.ascontiguousarray(images), np.ascontiguousarray(wmaps), slot,
                    np.ascontiguousarray(jobs, dtype=np.int64), d, iters, pixels.offsets, pixels.columns,
                    targets.packed, spans, wr, bg, job_of, targets.rowoff, targets.coloff, targets.lut, native,
                    sources.size, V, len(jobs), H, W, int(numba.get_num_threads()), 1 if WARP_KERNEL == "cpp-scalar" else 0)


# ---- torch twins (any device): the GPU path keeps its views on the device -----------------------
def inverse_depth_torch(means: Any, opacity: Any, cameras: Cameras, views: np.ndarray, *, rig: Rig | None = None,
                        cell: int | None = None, min_opacity: float = 0.5) -> Any:
    """:func:`inverse_depth` on torch tensors (the device and float dtype of ``means``): the same
    z-buffer of the centres, the same 3 hole-filling passes and the same bilinear interpolation
    (tested against it on CPU torch). Returns (len(views), H, W)."""
    import torch
    import torch.nn.functional as F

    rig = rig or rig_of(cameras)
    views = np.asarray(views, dtype=np.int64)
    dev, dt = means.device, means.dtype
    H, W = cameras.height, cameras.width
    m = means[opacity >= min_opacity]
    cell = auto_cell(int(m.shape[0]), H, W) if cell is None else cell
    if int(cell) != cell or cell < 1:
        raise InputError(f"cell: expected an integer >= 1, found {cell!r}")
    h, w = -(-H // cell), -(-W // cell)
    S = views.size
    R = torch.as_tensor(np.array(cameras.R[0]), dtype=dt, device=dev)
    t0 = cameras.t[0]
    px = m @ R[0]
    py = m @ R[1]
    z = m @ R[2] + float(t0[2])
    tx = torch.as_tensor(rig.tx[views], dtype=dt, device=dev)[:, None]
    cx = torch.as_tensor(rig.cx[views], dtype=dt, device=dev)[:, None]
    u = rig.fx * (px[None] + tx) / z[None] + cx                                   # (S, N)
    v = (float(cameras.fy[0]) * (py + float(t0[1])) / z + float(cameras.cy[0]))[None].expand(S, -1)
    ok = (z > float(cameras.near))[None] & (u >= 0) & (v >= 0)
    xi = torch.floor(u / cell).clamp(max=w).long()
    yi = torch.floor(v / cell).clamp(max=h).long()
    ok = ok & (xi < w) & (yi < h)
    s_idx = torch.arange(S, device=dev)[:, None].expand(S, -1)
    flat = (s_idx * h + yi) * w + xi
    zb = torch.full((S * h * w,), float("inf"), dtype=dt, device=dev)
    zb.scatter_reduce_(0, flat[ok], z[None].expand(S, -1)[ok], reduce="amin")
    zb = zb.view(S, 1, h, w)
    ones = torch.ones((1, 1, 3, 3), dtype=dt, device=dev)
    for _ in range(3):  # an empty cell takes the mean of >= 3 filled neighbours (of the previous pass)
        filled = torch.isfinite(zb)
        total = F.conv2d(torch.where(filled, zb, torch.zeros_like(zb)), ones, padding=1)
        count = F.conv2d(filled.to(dt), ones, padding=1)
        zb = torch.where(~filled & (count >= 3), total / count.clamp(min=1), zb)
    wc = torch.where(torch.isfinite(zb), 1.0 / zb, torch.full_like(zb, rig.w_zero))
    up = F.interpolate(wc, scale_factor=float(cell), mode="bilinear", align_corners=False,
                       recompute_scale_factor=False)
    return up[:, 0, :H, :W]


def warp_views_torch(images: Any, wmaps: Any, sources: np.ndarray, rig: Rig, *, iters: int = 1) -> Any:
    """:func:`warp_views` on torch tensors: (V, H, W, 3) views, the sources' from ``images`` and the
    others synthesized (every pixel; same columns, weights and interpolation, tested against it
    on CPU torch)."""
    import torch

    sources = np.asarray(sources, dtype=np.int64)
    V = rig.tx.size
    S, H, W, _ = images.shape
    if S != sources.size or tuple(wmaps.shape) != (S, H, W) or W < 2:
        raise InputError(f"images, wmaps: expected ({sources.size}, H, W, 3) and ({sources.size}, H, W) with W >= 2, "
                         f"found {tuple(images.shape)} and {tuple(wmaps.shape)}")
    jobs = bracket(V, sources)
    dev, dt = images.device, images.dtype
    out = torch.empty((V, H, W, 3), dtype=dt, device=dev)
    out[torch.as_tensor(sources, device=dev)] = images
    if jobs.size == 0:
        return out
    slot = np.full(V, -1, dtype=np.int64)
    slot[sources] = np.arange(S)
    k, a, b = jobs[:, 0], jobs[:, 1], jobs[:, 2]
    wa = torch.as_tensor((b - k) / (b - a), dtype=dt, device=dev)[:, None, None, None]
    x = torch.arange(W, dtype=dt, device=dev)
    acc = torch.zeros((len(jobs), H, W, 3), dtype=dt, device=dev)
    for src, weight in ((a, wa), (b, 1.0 - wa)):
        d0 = torch.as_tensor(rig.cx[src] - rig.cx[k], dtype=dt, device=dev)[:, None, None]
        d1 = torch.as_tensor(rig.fx * (rig.tx[src] - rig.tx[k]), dtype=dt, device=dev)[:, None, None]
        sl = torch.as_tensor(slot[src], device=dev)
        wm, img = wmaps[sl], images[sl]
        xs = x + d0 + d1 * wm
        for it in range(int(iters) + 1):
            p = torch.floor(xs).clamp(0, W - 2)
            f = (xs - p).clamp(0.0, 1.0)
            p = p.long()
            if it == iters:
                break
            wv = (1.0 - f) * torch.gather(wm, 2, p) + f * torch.gather(wm, 2, p + 1)
            xs = x + d0 + d1 * wv
        p3 = p[..., None].expand(-1, -1, -1, 3)
        col = (1.0 - f)[..., None] * torch.gather(img, 2, p3) + f[..., None] * torch.gather(img, 2, p3 + 1)
        acc += weight * col
    out[torch.as_tensor(k, device=dev)] = acc
    return out
