"""Eye slices straight into the native subpixels a tracked viewer's eyes receive (pure array code).

A tracked frame (``NativeFrameConfig(tracked="slices")``) renders one crossed-slit image per eye
(:mod:`holo_viewer.render.crossed_slit`) instead of bands of the 48 views. Every native subpixel
that can send light to an eye (:func:`~holo_viewer.display.eyes.view_segments`: the views within
reach of the eye's view coordinate, per native column, over the head-motion margin) gets the
value the full path would give it, with each quilt view's texel warped out of that eye's slice
by depth: no quilt, no interleave pass (the subpixel's view, texel and blend weight are the
interleaver's own). The other subpixels keep what they showed.

:class:`SubpixelBuckets` sorts each native row's subpixels by the view they show, once per
calibration, so a frame visits only the subpixels of its segments (~15-30 % of the 9.4 M).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from ..errors import InputError

__all__ = ["SubpixelBuckets", "subpixel_buckets", "scatter_slices", "cpp_available", "BUCKET_CACHE_SIZE"]

#: :func:`subpixel_buckets` keeps the tables of this many (panel, quilt, mode) combinations
BUCKET_CACHE_SIZE = 2


class SubpixelBuckets:
    """Per native row and quilt view, the subpixels showing that view (the lower one in blend mode).

    Parameters
    ----------
    interleaver : Interleaver
        The panel's interleaver (its views, texels, blend weights are used as they are).
    n_views, height, width : int
        The quilt views (each ``height`` x ``width``, the quilt's tiles).

    Attributes
    ----------
    positions : (H W 3,) int16
        Per row, ``3 x + channel`` of its subpixels, sorted by (view, position).
    zeta : (H W 3,) float32
        Lens view coordinate of each listed subpixel (:attr:`VirtualDisplay.zeta`), same order.
    offsets : (H, n_views + 1) int32
        ``positions[y W 3 + offsets[y, k] : y W 3 + offsets[y, k + 1]]`` show view ``k``.
    tex_row : (H,) int32 row (from the top) of the view's texel each native row reads.
    tex_col : (W,) int32 texel column each native column reads.
    view1, w8 : blend mode: (H W 3,) int16 upper view and uint16 weight (1/256) of each subpixel
        (native order).
    """

    def __init__(self, interleaver: Any, n_views: int, height: int, width: int) -> None:
        from .device import view_gather_indices
        from .simulate import VirtualDisplay

        il = interleaver
        H, W, _ = il.shape
        idx0, idx1, w8 = view_gather_indices(il, n_views, height, width)
        per_view = height * width * 3
        view0 = (idx0 // per_view).astype(np.int16)
        texel = idx0 % per_view
        # the interleaver's texel depends on the native row and column alone (not the view, not
        # the channel beyond the channel itself): read it back and check
        grid = texel.reshape(H, W, 3)
        if not (np.all(grid[:, :, 0] % 3 == 0) and np.all(grid[:, :, 1] - grid[:, :, 0] == 1)
                and np.all(grid[:, :, 2] - grid[:, :, 0] == 2)):
            raise InputError("interleaver: a native pixel's channels read different texels: not supported")
        pix = grid[:, :, 0] // 3
        self.tex_row = (pix[:, 0] // width).astype(np.int32)
        self.tex_col = (pix[0, :] % width).astype(np.int32)
        if not np.array_equal(pix, self.tex_row[:, None] * width + self.tex_col[None, :]):
            raise InputError("interleaver: texel rows and columns are not separable over the native image")
        self.shape = (H, W, 3)
        self.n_views = int(n_views)
        self.mode = il.mode
        keys = view0.reshape(H, W * 3).astype(np.int32) * (W * 3) + np.arange(W * 3, dtype=np.int32)[None, :]
        keys.sort(axis=1)
        pos = keys % (W * 3)
        self.positions = pos.astype(np.int16).reshape(-1)
        zeta = VirtualDisplay(il.calibration, n_views=il.n_views).zeta.astype(np.float32).reshape(H, W * 3)
        self.zeta = np.take_along_axis(zeta, pos, axis=1).reshape(-1)
        per_row = np.bincount((np.arange(H)[:, None] * self.n_views + view0.reshape(H, W * 3)).ravel(),
                              minlength=H * self.n_views).reshape(H, self.n_views)
        self.offsets = np.zeros((H, self.n_views + 1), dtype=np.int32)
        np.cumsum(per_row, axis=1, out=self.offsets[:, 1:])
        if self.mode == "blend":
            self.view1 = (idx1 // per_view).astype(np.int16)
            self.w8 = w8.astype(np.uint16)
        else:
            self.view1 = view0[:1].copy()
            self.w8 = np.zeros(1, dtype=np.uint16)

    #: the arrays :func:`subpixel_buckets` caches on disk (:mod:`.table_cache`)
    _TABLES = ("positions", "zeta", "offsets", "tex_row", "tex_col", "view1", "w8")

    @classmethod
    def _cached(cls, interleaver: Any, n_views: int, height: int, width: int) -> "SubpixelBuckets":
        """The buckets through the disk cache: built (and stored) once per calibration and layout."""
        from .table_cache import cached_tables, table_key

        il = interleaver
        H, W, _ = il.shape
        n, one = H * W * 3, H * W * 3 if il.mode == "blend" else 1
        spec = {"positions": ((n,), "int16"), "zeta": ((n,), "float32"), "offsets": ((H, int(n_views) + 1), "int32"),
                "tex_row": ((H,), "int32"), "tex_col": ((W,), "int32"), "view1": ((one,), "int16"),
                "w8": ((one,), "uint16")}
        key = table_key("buckets", il.calibration, quilt_shape=il.quilt_shape, cols=il.cols, rows=il.rows,
                        il_views=il.n_views, mode=il.mode, n_views=int(n_views), height=int(height), width=int(width))

        def build() -> dict:
            b = cls(il, n_views, height, width)
            return {name: getattr(b, name) for name in cls._TABLES}

        b = cls.__new__(cls)
        for name, a in cached_tables("buckets", key, spec, build).items():
            setattr(b, name, a)
        b.shape, b.n_views, b.mode = (H, W, 3), int(n_views), il.mode
        return b

    @property
    def nbytes(self) -> int:
        return int(self.positions.nbytes + self.zeta.nbytes + self.offsets.nbytes + self.view1.nbytes
                   + self.w8.nbytes)


_BUCKETS: dict = {}


def subpixel_buckets(interleaver: Any, n_views: int, height: int, width: int) -> SubpixelBuckets:
    """:class:`SubpixelBuckets` of ``interleaver``'s panel, quilt layout and mode, built once and
    shared (nothing writes them; ~2 s and ~60 MB for the Portrait): a live session's renderer, one
    rebuilt for a new avatar size and the tests reuse them. The last :data:`BUCKET_CACHE_SIZE`
    combinations are kept."""
    il = interleaver
    key = (il.calibration, il.quilt_shape, il.cols, il.rows, il.n_views, il.mode, int(n_views), int(height),
           int(width))
    b = _BUCKETS.pop(key, None)
    if b is None:
        b = SubpixelBuckets._cached(il, n_views, height, width)
    _BUCKETS[key] = b  # (re)inserted last: the most recent
    while len(_BUCKETS) > BUCKET_CACHE_SIZE:
        del _BUCKETS[next(iter(_BUCKETS))]
    return b


_F0, _F05, _F1, _F255 = np.float32(0.0), np.float32(0.5), np.float32(1.0), np.float32(255.0)


@numba.njit(inline="always", error_model="numpy")
def _column(xi, Wf, W):  # pragma: no cover - compiled
    """Pixel p and fraction f of the linear interpolation at column xi (centres at +1/2), written
    as the C++ kernel's selects (AVX-512 max/min semantics, NaN -> the bound)."""
    xm = xi - _F05
    xm = xm if xm > np.float32(-1.0) else np.float32(-1.0)
    xm = xm if xm < Wf else Wf
    p = int(math.floor(xm))
    p = p if p > 0 else 0
    p = p if p < W - 2 else W - 2
    f = xm - np.float32(p)
    f = f if f > _F0 else _F0
    f = f if f < _F1 else _F1
    return p, f


@numba.njit(inline="always", error_model="numpy")
def _slice_value(img, wrow, ch, uc, d0, d1, g, h, iters, W):  # pragma: no cover - compiled
    """One view texel (column centre uc, channel ch) warped out of a slice row: float32, the C++
    kernel's expressions in the same order."""
    Wf = np.float32(W)
    w = wrow[int(uc)]
    xi = (uc + d0 + d1 * w) / (g + h * w)
    for _ in range(iters):
        p, f = _column(xi, Wf, W)
        w0 = wrow[p]
        w = w0 + f * (wrow[p + 1] - w0)
        xi = (uc + d0 + d1 * w) / (g + h * w)
    p, f = _column(xi, Wf, W)
    a = img[p * 3 + ch]
    v = np.rint((a + f * (img[p * 3 + 3 + ch] - a)) * _F255)
    v = v if v > _F0 else _F0
    return v if v < _F255 else _F255


@numba.njit(inline="always")
def _gap(zeta, lo, hi, n):  # pragma: no cover - compiled
    """Circular distance (period n views) from zeta to [lo, hi] (<= 0 inside), float32."""
    best = np.float32(np.inf)
    for s in range(3):
        z = zeta + np.float32(s - 1) * n
        a, b = lo - z, z - hi
        gap = a if a > b else b
        best = gap if gap < best else best
    return best


@numba.njit(inline="always", error_model="numpy")
def _eye_value(img, wrow, kve, g, hh, view1, w8, blend, k, p, x, uc, s, iters, Wv):  # pragma: no cover - compiled
    """The value (0..255, integral, float32) a slice row gives subpixel p (native-order index s) showing
    view k (blend: and ``view1``): the C++ kernel's ``eye_value``."""
    ch = p - 3 * x
    v0 = _slice_value(img, wrow, ch, uc, kve[k, 0], kve[k, 1], g, hh, iters, Wv)
    if not blend:
        return v0
    k1 = view1[s]
    v1 = v0 if k1 == k else _slice_value(img, wrow, ch, uc, kve[k1, 0], kve[k1, 1], g, hh, iters, Wv)
    ww = np.uint32(w8[s])
    return np.float32((np.uint32(v0) * (256 - ww) + np.uint32(v1) * ww + 128) >> 8)


@numba.njit(inline="always", error_model="numpy")
def _feather_weight(gap, reach, inv):  # pragma: no cover - compiled
    """1 up to ``inner`` (``inv = 1 / (reach - inner)``), 0 from ``reach``, linear between: float32."""
    w = (reach - gap) * inv
    w = w if w > _F0 else _F0
    return w if w < _F1 else _F1


@numba.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def _scatter(native, positions, zetas, offsets, tex_row, tex_col, view1, w8, blend, segs, bounds, reach, images,
             wmaps, kv, gh, iters, counts, inner):  # pragma: no cover - compiled
    H = offsets.shape[0]
    W3 = native.shape[1]
    Wv = wmaps.shape[2]
    n = np.float32(offsets.shape[1] - 1)
    feather = inner < reach
    inv = _F1 / (reach - inner) if feather else _F0
    for y in numba.prange(H):
        ty = tex_row[y]
        base = y * W3
        cnt = 0
        for j in range(segs.shape[0]):
            e, k, x0, x1 = segs[j, 0], segs[j, 1], segs[j, 2], segs[j, 3]
            lo, hi = offsets[y, k], offsets[y, k + 1]
            a = lo + np.searchsorted(positions[base + lo:base + hi], 3 * x0)
            b = lo + np.searchsorted(positions[base + lo:base + hi], 3 * x1)
            for i in range(a, b):
                p = np.int64(positions[base + i])
                x = p // 3
                z = zetas[base + i]
                gap = _gap(z, bounds[e, 0, x], bounds[e, 1, x], n)
                if not gap < reach:
                    continue  # sends this eye less than the threshold, wherever it is in the margin
                mine = True
                ob = -1  # the nearest other eye and its gap
                gob = np.float32(np.inf)
                for o in range(bounds.shape[0]):  # a subpixel both eyes receive: the nearer eye's
                    if o != e:
                        go = _gap(z, bounds[o, 0, x], bounds[o, 1, x], n)
                        if go < gap or (go == gap and o < e):
                            mine = False
                        if go < gob:
                            gob = go
                            ob = o
                if not mine:
                    continue
                s = base + p
                uc = np.float32(tex_col[x]) + _F05
                ve = _eye_value(images[e, ty], wmaps[e, ty], kv[e], gh[e, 0], gh[e, 1], view1, w8, blend, k, p, x, uc,
                                s, iters, Wv)
                if not feather:
                    native[y, p] = np.uint8(ve)
                else:  # the eyes' slices blended by their weights, over the fill by the larger weight
                    we = _feather_weight(gap, reach, inv)
                    sv = ve
                    if ob >= 0 and gob < reach:
                        wo = _feather_weight(gob, reach, inv)
                        vo = _eye_value(images[ob, ty], wmaps[ob, ty], kv[ob], gh[ob, 0], gh[ob, 1], view1, w8, blend,
                                        k, p, x, uc, s, iters, Wv)
                        sv = (we * ve + wo * vo) / (we + wo)
                        we = we if we > wo else wo
                    f = np.float32(native[y, p])
                    v = np.rint(f + we * (sv - f))
                    v = v if v > _F0 else _F0
                    v = v if v < _F255 else _F255
                    native[y, p] = np.uint8(v)
                cnt += 1
        counts[y] = cnt


def scatter_slices(native: np.ndarray, buckets: SubpixelBuckets, segments: np.ndarray, bounds: np.ndarray,
                   reach: float, images: np.ndarray, wmaps: np.ndarray, kv: np.ndarray, gh: np.ndarray,
                   iters: int = 1, kernel: str = "auto", inner: float | None = None) -> int:
    """Write the subpixels of ``segments`` that an eye can receive, from the eyes' slices.

    Parameters
    ----------
    native : numpy.ndarray
        (H, W, 3) uint8 native image, updated in place.
    buckets : SubpixelBuckets
    segments : numpy.ndarray
        (S, 4) int64 (eye, view, x0, x1) of :func:`~holo_viewer.display.eyes.view_segments`.
    bounds : numpy.ndarray
        (E, 2, W) view-coordinate range of each eye per native column
        (:func:`~holo_viewer.display.eyes.eye_view_bounds`).
    reach : float
        A listed subpixel is written when its lens coordinate is within ``reach`` views of its
        eye's range (:func:`~holo_viewer.display.eyes.reach_views`), i.e. when it can send that
        eye more than the threshold, and is not nearer the other eye's range (that eye's slice
        writes it).
    images, wmaps : numpy.ndarray
        (E, h, w, 3) float32 slices and (E, h, w) float32 their inverse depths
        (:func:`~holo_viewer.render.crossed_slit.slice_depth`).
    kv, gh : numpy.ndarray
        :func:`~holo_viewer.render.crossed_slit.warp_coefficients` (used as float32).
    iters : int
        Fixed-point steps for the source column after the first guess.
    kernel : {"auto", "cpp", "cpp-scalar", "numba"}
        The C++ kernel (AVX-512 where the CPU has it, 16 subpixels at a time, in nearest mode,
        feathered or not; "cpp-scalar" without) when built, else numba; all compute the same
        float32 expressions (tested equal).
    inner : float, optional
        Feather the slices into what ``native`` shows (the cone fill), for comfort: a written
        subpixel whose lens coordinate is ``gap`` views from its eye's range takes the slice with
        the weight ``(reach - gap) / (reach - inner)`` clipped to [0, 1] (1 up to ``inner``, 0 at
        ``reach``; ``inner`` < ``reach``, negative: inside the range), and where the other eye's
        reach overlaps, both eyes' slices blended by their weights, over the fill by the larger
        one: the written values change smoothly as the eyes move. None: the slice replaces.

    Returns
    -------
    int
        Subpixels written.
    """
    if native.shape != buckets.shape or native.dtype != np.uint8 or not native.flags.c_contiguous:
        raise InputError(f"native: expected a C-contiguous uint8 {buckets.shape} array, found {native.dtype} "
                         f"{native.shape}")
    images = np.ascontiguousarray(images, dtype=np.float32)
    wmaps = np.ascontiguousarray(wmaps, dtype=np.float32)
    E = images.shape[0]
    if images.ndim != 4 or images.shape[3] != 3 or wmaps.shape != images.shape[:3] or images.shape[2] < 2:
        raise InputError(f"images, wmaps: expected (E, h, w, 3) and (E, h, w), found {images.shape} and {wmaps.shape}")
    H, W, _ = buckets.shape
    segs = np.ascontiguousarray(segments, dtype=np.int64).reshape(-1, 4)
    if segs.size and (segs[:, 0].min() < 0 or segs[:, 0].max() >= E or segs[:, 1].min() < 0
                      or segs[:, 1].max() >= buckets.n_views or segs[:, 2].min() < 0
                      or segs[:, 3].max() > W or np.any(segs[:, 3] < segs[:, 2])):
        raise InputError(f"segments: expected rows (eye < {E}, view < {buckets.n_views}, 0 <= x0 <= x1 <= {W})")
    if bounds.shape != (E, 2, W):
        raise InputError(f"bounds: expected ({E}, 2, {W}), found {bounds.shape}")
    if kv.shape != (E, buckets.n_views, 2) or gh.shape != (E, 2):
        raise InputError(f"kv, gh: expected ({E}, {buckets.n_views}, 2) and ({E}, 2), found {kv.shape}, {gh.shape}")
    if inner is not None and not (math.isfinite(inner) and inner < reach):
        raise InputError(f"inner: expected a finite number of views < reach {reach:.4g}, found {inner!r}")
    if kernel not in ("auto", "cpp", "cpp-scalar", "numba"):
        raise InputError(f"kernel: expected 'auto', 'cpp', 'cpp-scalar' or 'numba', found {kernel!r}")
    if int(tex_max := buckets.tex_col.max()) >= images.shape[2] or int(buckets.tex_row.max()) >= images.shape[1]:
        raise InputError(f"images: expected slices of the views' size, found {images.shape[1:3]} (texel {tex_max})")
    args = (native.reshape(H, W * 3), buckets.positions, buckets.zeta, buckets.offsets, buckets.tex_row,
            buckets.tex_col, buckets.view1, buckets.w8, buckets.mode == "blend", segs,
            np.ascontiguousarray(bounds, dtype=np.float32), np.float32(reach), images.reshape(E, images.shape[1], -1),
            wmaps, np.ascontiguousarray(kv, dtype=np.float32), np.ascontiguousarray(gh, dtype=np.float32), int(iters))
    cpp = _cpp() if kernel != "numba" else None
    if kernel.startswith("cpp") and cpp is None:
        raise InputError("kernel 'cpp': the C++ extension holo_viewer.display._slices_cpp is not built")
    counts = np.zeros(H, dtype=np.int64)
    inner32 = np.float32(np.inf if inner is None else inner)
    if cpp is not None:
        cpp.scatter_slices(*args, counts, H, W * 3, buckets.n_views, E, images.shape[1], images.shape[2], _threads(),
                           1 if kernel == "cpp-scalar" else 0, float(inner32))
    else:
        _scatter(*args, counts, inner32)
    return int(counts.sum())


def _cpp():  # noqa: ANN202
    try:
        from . import _slices_cpp  # type: ignore[attr-defined]
    except ImportError:
        return None
    return _slices_cpp


def cpp_available() -> bool:
    """True when the compiled kernel (``holo_viewer.display._slices_cpp``) is importable."""
    return _cpp() is not None


def _threads() -> int:
    import numba

    return int(numba.get_num_threads())
