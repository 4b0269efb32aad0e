"""Lenticular interleave: quilt -> native panel image (pure array code).

The formula (docs/design.md; HoloPlay.js, Unity HoloPlay, HoloPlayCore 0.1.1, LKG-Toolkit)::

    pitch' = pitch * screenW / DPI * cos(atan(1 / slope))
    tilt   = screenH / (screenW * slope)          (negated if flipImageX)
    subp   = 1 / (3 screenW)
    for native pixel (u, v) (GL texture coordinates of the pixel centre, v up) and subpixel i:
        z    = fract((u + i subp + v tilt) pitch' - center);   z = 1 - z if invView
        view = floor(z N)                                       (clamped to N - 1 when z = 1)
    quilt lookup of view k: x = (k mod cols + u) / cols,  y = (floor(k / cols) + v) / rows   (y up)
    output = (rgb[ri].r, rgb[1].g, rgb[bi].b),  (ri, bi) = (0, 2), or (2, 0) if flipSubp

Native pixel (row r, column c), row 0 at the top: ``u = (c + 0.5) / W``, ``v = 1 - (r + 0.5) / H``.
Quilt sampling is nearest-texel inside the tile: texel column ``floor(u tw)``, texel row from
the tile's bottom ``floor(v tw)`` (tiles ``tw x th`` from the bottom-left, as in
:mod:`holo_viewer.display.quilt`).

Flips (sources differ; we follow HoloPlay.js for X and define Y):

* ``flipImageX``: the lens slant sign is negated (``tilt`` above), as in HoloPlay.js; the quilt
  lookup is not mirrored. (The newer WebXR/Bridge shaders also negate ``subp`` and add 0.5 to
  ``center``; we do not.)
* ``flipImageY``: the quilt lookup is mirrored vertically (``v -> 1 - v`` in the lookup only);
  the lens phase keeps the physical ``v``.
* ``flipSubp``: the panel's subpixel order is BGR: red takes subpixel 2's view and blue subpixel 0's.

Modes: ``nearest`` shows view ``floor(zN)``; ``blend`` linearly interpolates between the two
nearest view *centres*: ``t = zN - 1/2``, ``k0 = floor(t)``, weight ``t - k0`` on ``k0 + 1``, both
clamped to ``[0, N-1]`` (no wrap across the cone edge, which would ghost the first and last views).

:func:`interleave_reference` evaluates this literally per subpixel in float64. :class:`Interleaver`
precomputes flat gather indices (and blend weights) once per calibration and quilt shape; each
frame is then one gather (numba, parallel over rows; or ``numpy.take``).
"""

from __future__ import annotations

import math
import warnings
from typing import Any, Literal

import numpy as np

from ..cache import keep_recent
from ..errors import InputError
from .calibration import DisplayCalibration

__all__ = ["LenticularParams", "lenticular_params", "interleave_reference", "reference_views",
           "Interleaver", "interleave"]

Mode = Literal["nearest", "blend"]


class LenticularParams:
    """Shader constants derived from a calibration: ``pitch'``, ``tilt``, ``subp``, ``center`` and
    the channel -> subpixel map (attributes of the same names)."""

    def __init__(self, cal: DisplayCalibration) -> None:
        self.width = cal.screen_w
        self.height = cal.screen_h
        self.pitch = cal.pitch * cal.screen_w / cal.dpi * math.cos(math.atan(1.0 / cal.slope))
        self.tilt = cal.screen_h / (cal.screen_w * cal.slope) * (-1.0 if cal.flip_image_x else 1.0)
        self.subp = 1.0 / (3.0 * cal.screen_w)
        self.center = cal.center
        self.inv_view = cal.inv_view
        self.flip_y = cal.flip_image_y
        ri, bi = (2, 0) if cal.flip_subp else (0, 2)
        self.channel_subpixel = (ri, 1, bi)


def lenticular_params(cal: DisplayCalibration) -> LenticularParams:
    return LenticularParams(cal)


def _check_quilt(quilt: np.ndarray, cols: int, rows: int, n_views: int) -> np.ndarray:
    q = np.asarray(quilt)
    if q.ndim != 3 or q.shape[2] != 3:
        raise InputError(f"quilt: expected shape (H, W, 3), found {q.shape}")
    if q.dtype != np.uint8 and q.dtype != np.float32 and q.dtype != np.float64:
        raise InputError(f"quilt: expected dtype uint8, float32 or float64, found {q.dtype}")
    if cols < 1 or rows < 1 or not 1 <= n_views <= cols * rows:
        raise InputError(f"quilt layout: expected cols, rows >= 1 and 1 <= n_views <= cols*rows, "
                         f"found {cols}x{rows}, n_views={n_views}")
    if q.shape[0] // rows < 1 or q.shape[1] // cols < 1:
        raise InputError(f"quilt: {q.shape[1]}x{q.shape[0]} pixels cannot hold {cols}x{rows} tiles")
    return q


# ------------------------------------------------------------------------- reference (float64)
def reference_views(cal: DisplayCalibration, n_views: int, mode: Mode = "nearest"
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Per-subpixel views by direct float64 evaluation of the formula.

    Returns
    -------
    view0 : numpy.ndarray
        (H, W, 3) int64 view of each output channel (``nearest``) or the lower blend view.
    view1, weight : numpy.ndarray or None
        (H, W, 3) upper blend view and its weight in [0, 1) (``blend`` only).
    """
    p = LenticularParams(cal)
    H, W = cal.screen_h, cal.screen_w
    view0 = np.empty((H, W, 3), dtype=np.int64)
    view1 = np.empty((H, W, 3), dtype=np.int64) if mode == "blend" else None
    weight = np.empty((H, W, 3), dtype=np.float64) if mode == "blend" else None
    cc, rr = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    u = (cc + 0.5) / W
    v = 1.0 - (rr + 0.5) / H
    for ch in range(3):
        i = p.channel_subpixel[ch]
        x = (u + i * p.subp + v * p.tilt) * p.pitch - p.center
        z = x - np.floor(x)
        if p.inv_view:
            z = 1.0 - z
        if mode == "nearest":
            view0[:, :, ch] = np.minimum(np.floor(z * n_views), n_views - 1)
        else:
            t = z * n_views - 0.5
            k0 = np.floor(t)
            weight[:, :, ch] = t - k0
            view0[:, :, ch] = np.clip(k0, 0, n_views - 1)
            view1[:, :, ch] = np.clip(k0 + 1, 0, n_views - 1)
    return view0, view1, weight


def interleave_reference(quilt: np.ndarray, cal: DisplayCalibration, cols: int | None = None,
                         rows: int | None = None, n_views: int | None = None, mode: Mode = "nearest"
                         ) -> np.ndarray:
    """Quilt -> native image by direct float64 evaluation (slow, exact; the test oracle).

    Parameters
    ----------
    quilt : numpy.ndarray
        (Hq, Wq, 3) uint8 or float quilt, view 0 bottom-left.
    cal : DisplayCalibration
        Panel calibration (native size ``screen_h x screen_w``).
    cols, rows, n_views : int, optional
        Quilt layout (default: the calibration's).
    mode : {"nearest", "blend"}

    Returns
    -------
    numpy.ndarray
        (screen_h, screen_w, 3) float64 (values in the quilt's units, not rounded).
    """
    cols = cal.cols if cols is None else int(cols)
    rows = cal.rows if rows is None else int(rows)
    n = cols * rows if n_views is None else int(n_views)
    q = _check_quilt(quilt, cols, rows, n).astype(np.float64)
    Hq, Wq = q.shape[:2]
    tw, th = Wq // cols, Hq // rows
    H, W = cal.screen_h, cal.screen_w
    cc, rr = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    u = (cc + 0.5) / W
    v = 1.0 - (rr + 0.5) / H
    vq = 1.0 - v if cal.flip_image_y else v
    view0, view1, weight = reference_views(cal, n, mode)

    def sample(view: np.ndarray, ch: int) -> np.ndarray:
        # GL texture coordinates of the quilt, y up, with viewPortion = (cols tw / Wq, rows th / Hq)
        x = (view % cols + u) / cols * (cols * tw / Wq)
        y = (view // cols + vq) / rows * (rows * th / Hq)
        tx = np.floor(x * Wq).astype(np.int64)
        ty = np.floor(y * Hq).astype(np.int64)  # texel row counted from the bottom
        # nearest texel, clamped to its own tile (no bleeding into the neighbouring view)
        tx = np.clip(tx, (view % cols) * tw, (view % cols) * tw + tw - 1)
        ty = np.clip(ty, (view // cols) * th, (view // cols) * th + th - 1)
        return q[Hq - 1 - ty, tx, ch]

    out = np.empty((H, W, 3), dtype=np.float64)
    for ch in range(3):
        a = sample(view0[:, :, ch], ch)
        if mode == "nearest":
            out[:, :, ch] = a
        else:
            b = sample(view1[:, :, ch], ch)
            w = weight[:, :, ch]
            out[:, :, ch] = (1.0 - w) * a + w * b
    return out


# ------------------------------------------------------------------------------ fast path
_NUMBA_KERNELS = None


def _one_subpixel(src, i0, i1, w8, wf, s, out, mode):  # pragma: no cover - compiled by _numba_kernels
    """out[s] of flat subpixel s: mode 0 nearest, 1 blend of uint8 values, 2 blend of floats."""
    if mode == 0:
        out[s] = src[i0[s]]
    elif mode == 1:
        a = np.uint32(src[i0[s]])
        b = np.uint32(src[i1[s]])
        ww = np.uint32(w8[s])
        out[s] = (a * (256 - ww) + b * ww + 128) >> 8
    else:
        a = src[i0[s]]
        out[s] = a + (src[i1[s]] - a) * wf[s]


_ONE_SUBPIXEL = None


def _gather_cpp():  # noqa: ANN202
    """The compiled row gather's module (``holo_viewer.display._slices_cpp``), or None where it is not built."""
    try:
        from . import _slices_cpp  # type: ignore[attr-defined]
    except ImportError:
        return None
    return _slices_cpp if hasattr(_slices_cpp, "gather_rows") else None


def _numba_threads() -> int:
    """The calling thread's numba thread count (the live renderers set it per frame in flight)."""
    import numba

    return int(numba.get_num_threads())


def _numba_kernels():
    global _NUMBA_KERNELS
    if _NUMBA_KERNELS is None:
        import numba

        @numba.njit(parallel=True, cache=True, boundscheck=False, nogil=True)
        def gather(src, idx, out, nrows):  # pragma: no cover - compiled
            n = idx.shape[0]
            per = (n + nrows - 1) // nrows
            for r in numba.prange(nrows):
                lo = r * per
                hi = min(n, lo + per)
                for k in range(lo, hi):
                    out[k] = src[idx[k]]

        @numba.njit(parallel=True, cache=True, boundscheck=False, nogil=True)
        def blend_u8(src, i0, i1, w, out, nrows):  # pragma: no cover - compiled
            n = i0.shape[0]
            per = (n + nrows - 1) // nrows
            for r in numba.prange(nrows):
                lo = r * per
                hi = min(n, lo + per)
                for k in range(lo, hi):
                    a = np.uint32(src[i0[k]])
                    b = np.uint32(src[i1[k]])
                    ww = np.uint32(w[k])
                    out[k] = np.uint8((a * (256 - ww) + b * ww + 128) >> 8)

        @numba.njit(parallel=True, cache=True, boundscheck=False, nogil=True)
        def blend_f(src, i0, i1, w, out, nrows):  # pragma: no cover - compiled
            n = i0.shape[0]
            per = (n + nrows - 1) // nrows
            for r in numba.prange(nrows):
                lo = r * per
                hi = min(n, lo + per)
                for k in range(lo, hi):
                    a = src[i0[k]]
                    out[k] = a + (src[i1[k]] - a) * w[k]

        global _ONE_SUBPIXEL  # a module global, not a closure: the kernels calling it stay cacheable
        _ONE_SUBPIXEL = numba.njit(inline="always", boundscheck=False)(_one_subpixel)

        @numba.njit(parallel=True, cache=True, boundscheck=False, nogil=True)
        def update(src, i0, i1, w8, wf, sel, out, mode):  # pragma: no cover - compiled
            # out[s] for the listed flat subpixels s only
            n = sel.shape[0]
            nchunks = 64
            per = (n + nchunks - 1) // nchunks
            for c in numba.prange(nchunks):
                for j in range(c * per, min(n, c * per + per)):
                    _ONE_SUBPIXEL(src, i0, i1, w8, wf, sel[j], out, mode)

        @numba.njit(parallel=True, cache=True, boundscheck=False, nogil=True)
        def update_keys(src, i0, i1, w8, wf, key0, key1, chosen, out, mode):  # pragma: no cover - compiled
            # out[s] for the subpixels whose texel block key0[s] (blend: or key1[s]) is chosen, in
            # native order: sequential reads of the tables and writes of out, random reads only
            # of the chosen quilt texels (a list of scattered subpixels read i0 and wrote out at
            # random, 2-3x slower per subpixel)
            n = key0.shape[0]
            nchunks = 256
            per = (n + nchunks - 1) // nchunks
            for c in numba.prange(nchunks):
                for s in range(c * per, min(n, c * per + per)):
                    if chosen[key0[s]] or (mode != 0 and chosen[key1[s]]):
                        _ONE_SUBPIXEL(src, i0, i1, w8, wf, s, out, mode)

        @numba.njit(parallel=True, cache=True, boundscheck=False, nogil=True)
        def gather_rows(src, view, rowpart, colpart, out):  # pragma: no cover - compiled
            # out[y, s] = src[rowpart[y, view[y, s]] + colpart[s]]: the texel index from the row's
            # tile offsets and the column's texel (one byte of view per subpixel read, not an index)
            H, L = view.shape
            for y in numba.prange(H):
                rp = rowpart[y]
                for s in range(L):
                    out[y, s] = src[rp[view[y, s]] + colpart[s]]

        _NUMBA_KERNELS = (gather, blend_u8, blend_f, update, update_keys, gather_rows)
    return _NUMBA_KERNELS


#: Interleaver's tables of this process, (calibration repr, quilt shape, cols, rows, views, mode) -> arrays,
#: the last _TABLES_KEPT layouts (a Portrait layout: ~70 MB nearest, ~170 MB blend)
_TABLES: dict = {}
_TABLES_KEPT = 2
#: the attributes Interleaver._build_tables sets
_TABLE_ATTRS = ("view_index", "view_index1", "weight", "_idx0", "_idx1", "_w8", "_wf", "_rows")


def _copied(v: Any) -> Any:
    """A copy of a table attribute: an array, a tuple of arrays, or None."""
    return tuple(a.copy() for a in v) if isinstance(v, tuple) else v.copy() if isinstance(v, np.ndarray) else v


class Interleaver:
    """Quilt -> native image with gather indices precomputed once.

    Parameters
    ----------
    calibration : DisplayCalibration
        Panel calibration; output is (screen_h, screen_w, 3).
    quilt_shape : tuple
        (Hq, Wq) or (Hq, Wq, 3) of the quilts that will be passed.
    cols, rows, n_views : int, optional
        Quilt layout (default: the calibration's).
    mode : {"nearest", "blend"}
        Nearest view, or linear blend of the two nearest view centres.
    backend : {"auto", "numba", "numpy"}
        Gather implementation (``auto`` = numba when importable).

    Attributes
    ----------
    view_index : numpy.ndarray
        (H, W, 3) int16 view shown by each output channel (lower view in blend mode).
    view_index1, weight : numpy.ndarray or None
        Blend mode: (H, W, 3) upper view (int16) and its weight (float32 in [0, 1)).

    Examples
    --------
    >>> il = Interleaver(cal, quilt.shape)          # doctest: +SKIP
    >>> native = il(quilt)                           # doctest: +SKIP
    """

    def __init__(self, calibration: DisplayCalibration, quilt_shape: tuple[int, ...], cols: int | None = None,
                 rows: int | None = None, n_views: int | None = None, mode: Mode = "nearest",
                 backend: str = "auto") -> None:
        if not isinstance(calibration, DisplayCalibration):
            raise InputError(f"calibration: expected a DisplayCalibration, found {type(calibration).__name__}")
        if mode not in ("nearest", "blend"):
            raise InputError(f"mode: expected 'nearest' or 'blend', found {mode!r}")
        if backend not in ("auto", "numba", "numpy"):
            raise InputError(f"backend: expected 'auto', 'numba' or 'numpy', found {backend!r}")
        if calibration.nominal:
            warnings.warn(f"interleaving with a nominal preset calibration ({calibration.source}); a real panel "
                          "needs its own visual.json", stacklevel=2)
        self.calibration = calibration
        self.cols = calibration.cols if cols is None else int(cols)
        self.rows = calibration.rows if rows is None else int(rows)
        self.n_views = self.cols * self.rows if n_views is None else int(n_views)
        if len(quilt_shape) not in (2, 3) or (len(quilt_shape) == 3 and quilt_shape[2] != 3):
            raise InputError(f"quilt_shape: expected (H, W) or (H, W, 3), found {tuple(quilt_shape)}")
        self.quilt_shape = (int(quilt_shape[0]), int(quilt_shape[1]), 3)
        _check_quilt(np.empty(self.quilt_shape, np.uint8), self.cols, self.rows, self.n_views)
        self.mode = mode
        if backend == "auto":
            try:
                import numba  # noqa: F401
                backend = "numba"
            except ImportError:
                backend = "numpy"
        self.backend = backend
        #: nearest mode, uint8 quilts, numba backend: the row gather's kernel, ``"auto"`` (the C++ one,
        #: :mod:`holo_viewer.display._slices_cpp`, where built: AVX-512 where the CPU has it), ``"cpp-scalar"``
        #: or ``"numba"``; every one gives the same bytes (tests/test_display_lenticular.py)
        self.row_kernel = "auto"
        self.shape = (calibration.screen_h, calibration.screen_w, 3)
        self._precompute()

    # ------------------------------------------------------------------ setup
    def _precompute(self) -> None:
        """The gather tables, or copies of this process's last tables of the same calibration and layout
        (:data:`_TABLES`: building them costs ~0.1-0.5 s of CPU on the Portrait, copying ~20-60 ms)."""
        key = (repr(self.calibration), self.quilt_shape, self.cols, self.rows, self.n_views, self.mode)
        kept = _TABLES.pop(key, None)
        if kept is None:
            self._build_tables()
            kept = {name: _copied(getattr(self, name)) for name in _TABLE_ATTRS if hasattr(self, name)}
        else:  # each Interleaver its own arrays: the kept ones are never handed out
            for name, v in kept.items():
                setattr(self, name, _copied(v))
        keep_recent(_TABLES, key, kept, _TABLES_KEPT)  # the most recently used last

    def _build_tables(self) -> None:
        cal, n, cols = self.calibration, self.n_views, self.cols
        p = LenticularParams(cal)
        H, W = cal.screen_h, cal.screen_w
        Hq, Wq, _ = self.quilt_shape
        tw, th = Wq // cols, Hq // self.rows
        u = (np.arange(W, dtype=np.float64) + 0.5) / W  # (W,)
        v = 1.0 - (np.arange(H, dtype=np.float64) + 0.5) / H  # (H,)
        vq = 1.0 - v if p.flip_y else v
        tex_col = np.minimum(np.floor(u * tw), tw - 1).astype(np.int64)  # (W,) texel column in a tile
        tex_row = np.minimum(np.floor(vq * th), th - 1).astype(np.int64)  # (H,) texel row from tile bottom
        # per view: flat offset of the tile's origin (bottom-left texel row 0, column 0)
        k = np.arange(n)
        tile_col0 = (k % cols) * tw
        tile_row0 = (k // cols) * th
        ch = np.arange(3)
        self.view_index = np.empty(self.shape, dtype=np.int16)
        self._idx0 = np.empty(H * W * 3, dtype=np.int32)
        blend = self.mode == "blend"
        if blend:
            self.view_index1 = np.empty(self.shape, dtype=np.int16)
            self.weight = np.empty(self.shape, dtype=np.float32)
            self._idx1 = np.empty(H * W * 3, dtype=np.int32)
            self._w8 = np.empty(H * W * 3, dtype=np.uint16)
        else:
            self.view_index1 = None
            self.weight = None
        sub = np.array(p.channel_subpixel, dtype=np.float64)
        step = max(1, (1 << 21) // (W * 3))  # rows per chunk (bounded memory)
        for r0 in range(0, H, step):
            r1 = min(H, r0 + step)
            x = ((u[None, :, None] + sub[None, None, :] * p.subp) + v[r0:r1, None, None] * p.tilt) * p.pitch \
                - p.center
            z = x - np.floor(x)
            if p.inv_view:
                z = 1.0 - z

            def flat(view: np.ndarray) -> np.ndarray:
                qrow = Hq - 1 - (tile_row0[view] + tex_row[r0:r1, None, None])
                qcol = tile_col0[view] + tex_col[None, :, None]
                return ((qrow * Wq + qcol) * 3 + ch[None, None, :]).astype(np.int32).ravel()

            sl = slice(r0 * W * 3, r1 * W * 3)
            if not blend:
                view = np.minimum(np.floor(z * n), n - 1).astype(np.int64)
                self.view_index[r0:r1] = view
                self._idx0[sl] = flat(view)
            else:
                t = z * n - 0.5
                k0 = np.floor(t)
                w = t - k0
                v0 = np.clip(k0, 0, n - 1).astype(np.int64)
                v1 = np.clip(k0 + 1, 0, n - 1).astype(np.int64)
                self.view_index[r0:r1] = v0
                self.view_index1[r0:r1] = v1
                self.weight[r0:r1] = w
                self._idx0[sl] = flat(v0)
                self._idx1[sl] = flat(v1)
                self._w8[sl] = np.rint(w * 256.0).astype(np.uint16).ravel()
        self._wf = None
        # nearest mode: the same indices as row part (per native row and view) + column part (per
        # subpixel), read through one byte of view per subpixel (9 MB instead of the 38 MB index
        # table; the full interleave 15 -> 9 ms on the Portrait, 2 cores)
        self._rows = None
        if not blend and n <= 256:
            qrow = Hq - 1 - (tile_row0[None, :] + tex_row[:, None])  # (H, n)
            rowpart = (qrow * Wq + tile_col0[None, :]) * 3
            colpart = (tex_col[:, None] * 3 + ch[None, :]).reshape(-1)
            if rowpart.max() + colpart.max() < np.iinfo(np.int32).max:
                self._rows = (self.view_index.astype(np.uint8).reshape(H, W * 3), rowpart.astype(np.int32),
                              colpart.astype(np.int32))

    # ------------------------------------------------------------------ apply
    def __call__(self, quilt: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Interleave one quilt.

        Parameters
        ----------
        quilt : numpy.ndarray
            (Hq, Wq, 3) uint8 or float32 quilt of the shape given at construction.
        out : numpy.ndarray, optional
            Preallocated (screen_h, screen_w, 3) output of the same dtype.

        Returns
        -------
        numpy.ndarray
            (screen_h, screen_w, 3) native image, same dtype as ``quilt``.
        """
        q = np.asarray(quilt)
        if q.shape != self.quilt_shape:
            raise InputError(f"quilt: expected shape {self.quilt_shape} (given at construction), found {q.shape}")
        if q.dtype == np.float64:
            q = q.astype(np.float32)
        if q.dtype not in (np.uint8, np.float32):
            raise InputError(f"quilt: expected dtype uint8 or float32, found {q.dtype}")
        src = np.ascontiguousarray(q).reshape(-1)
        if out is None:
            out = np.empty(self.shape, dtype=q.dtype)
        elif out.shape != self.shape or out.dtype != q.dtype or not out.flags.c_contiguous:
            raise InputError(f"out: expected a C-contiguous {self.shape} {q.dtype} array, found {out.shape} {out.dtype}")
        flat_out = out.reshape(-1)
        nchunks = self.shape[0]
        if self.mode == "nearest":
            if self.backend == "numba" and self._rows is not None:
                view8, rowpart, colpart = self._rows
                cpp = _gather_cpp() if q.dtype == np.uint8 and self.row_kernel != "numba" else None
                if cpp is not None:  # the same bytes (tested); 16 subpixels per gather, ~half the CPU
                    cpp.gather_rows(src, view8, rowpart, colpart, out, view8.shape[0], view8.shape[1],
                                    rowpart.shape[1], _numba_threads(), 1 if self.row_kernel == "cpp-scalar" else 0)
                else:
                    _numba_kernels()[5](src, view8, rowpart, colpart, out.reshape(self.shape[0], -1))
            elif self.backend == "numba":
                _numba_kernels()[0](src, self._idx0, flat_out, nchunks)
            else:
                np.take(src, self._idx0, out=flat_out)
            return out
        if q.dtype == np.uint8:
            if self.backend == "numba":
                _numba_kernels()[1](src, self._idx0, self._idx1, self._w8, flat_out, nchunks)
            else:
                a = src[self._idx0].astype(np.uint32)
                b = src[self._idx1].astype(np.uint32)
                w = self._w8.astype(np.uint32)
                flat_out[:] = ((a * (256 - w) + b * w + 128) >> 8).astype(np.uint8)
            return out
        if self._wf is None:
            self._wf = self.weight.reshape(-1).astype(np.float32)
        if self.backend == "numba":
            _numba_kernels()[2](src, self._idx0, self._idx1, self._wf, flat_out, nchunks)
        else:
            a = src[self._idx0]
            flat_out[:] = a + (src[self._idx1] - a) * self._wf
        return out


    # ------------------------------------------------------------------ partial updates
    def gather_indices(self) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The flat gather: ``native.ravel()[s]`` = ``quilt.ravel()[idx0[s]]`` (nearest), or the
        blend of ``idx0[s]`` and ``idx1[s]`` with weight ``weight[s]`` on the second (float32; the
        uint8 path rounds it to 1/256). Returns (idx0, idx1, weight): (H W 3,) int32, int32 or
        None, float32 or None. Read-only views: the same indices drive the torch path
        (:mod:`holo_viewer.display.device`)."""
        i0 = self._idx0.view()
        i0.flags.writeable = False
        if self.mode == "nearest":
            return i0, None, None
        if self._wf is None:
            self._wf = self.weight.reshape(-1).astype(np.float32)
        i1, wf = self._idx1.view(), self._wf.view()
        i1.flags.writeable = False
        wf.flags.writeable = False
        return i0, i1, wf

    def _block_keys(self, block: int) -> tuple[np.ndarray, np.ndarray]:
        """Per flat subpixel, the (view, texel column // block) key of the texel it reads (blend
        mode: of both texels; int16 when the keys fit, ~19 MB per table), built once per block and
        cached."""
        cached = getattr(self, "_keys", None)
        if cached is not None and cached[0] == block:
            return cached[1], cached[2]
        Hq, Wq, _ = self.quilt_shape
        tw, th = Wq // self.cols, Hq // self.rows
        nb = -(-tw // block)
        dtype = np.int16 if self.n_views * nb <= np.iinfo(np.int16).max else np.int32

        def key(idx: np.ndarray) -> np.ndarray:
            pix = idx // 3
            qr, qc = pix // Wq, pix % Wq
            view = qc // tw + self.cols * ((Hq - 1 - qr) // th)
            return (view * nb + (qc % tw) // block).astype(dtype)

        def build() -> dict[str, np.ndarray]:
            return {"k0": key(self._idx0), **({"k1": key(self._idx1)} if self.mode == "blend" else {})}

        names = ("k0", "k1") if self.mode == "blend" else ("k0",)
        t = self._cached("block_keys", {n: ((self._idx0.size,), np.dtype(dtype).name) for n in names}, build,
                         block=block)
        k0 = t["k0"]
        k1 = t["k1"] if self.mode == "blend" else k0
        self._keys = (block, k0, k1)
        return k0, k1

    def _cached(self, kind: str, spec: dict, build: Any, **params: Any) -> dict[str, np.ndarray]:
        """A table of this calibration and layout through the disk cache (:mod:`.table_cache`)."""
        from .table_cache import cached_tables, table_key

        key = table_key(kind, self.calibration, quilt_shape=self.quilt_shape, cols=self.cols, rows=self.rows,
                        n_views=self.n_views, mode=self.mode, **params)
        return cached_tables(kind, key, spec, build)

    def update_columns(self, quilt: np.ndarray, out: np.ndarray, columns: np.ndarray, block: int = 16) -> np.ndarray:
        """Recompute the subpixels of ``out`` that read the given texel-column blocks of ``quilt``:
        the same result as ``update(quilt, out, readers(columns, block))``, in one pass in native
        order (2-3x faster for a tracked frame's ~20-30 % of the subpixels, measured). Returns
        ``out``."""
        q = np.asarray(quilt)
        if q.shape != self.quilt_shape or q.dtype not in (np.uint8, np.float32):
            raise InputError(f"quilt: expected {self.quilt_shape} uint8 or float32, found {q.shape} {q.dtype}")
        if out.shape != self.shape or out.dtype != q.dtype or not out.flags.c_contiguous:
            raise InputError(f"out: expected a C-contiguous {self.shape} {q.dtype} array, found {out.shape} {out.dtype}")
        k0, k1 = self._block_keys(int(block))
        tw = self.quilt_shape[1] // self.cols
        nb = -(-tw // int(block))
        chosen = np.asarray(columns, dtype=bool).reshape(-1)
        if chosen.size != self.n_views * nb:
            raise InputError(f"columns: expected {self.n_views} x {nb} bools, found {np.shape(columns)}")
        if not chosen.any():
            return out
        if self.backend != "numba":
            return self.update(q, out, np.flatnonzero(chosen[k0] | chosen[k1]))
        src = np.ascontiguousarray(q).reshape(-1)
        mode, i1, w8, wf = self._kernel_args(q.dtype)
        _numba_kernels()[4](src, self._idx0, i1, w8, wf, k0, k1, np.ascontiguousarray(chosen), out.reshape(-1), mode)
        return out

    def _reader_table(self, block: int) -> tuple[np.ndarray, np.ndarray]:
        """Flat subpixels sorted by the (view, texel column // block) they read, and offsets."""
        cached = getattr(self, "_readers", None)
        if cached is not None and cached[0] == block:
            return cached[1], cached[2]
        nb = -(-(self.quilt_shape[1] // self.cols) // block)
        n = self._idx0.size

        def build() -> dict[str, np.ndarray]:
            k0, k1 = self._block_keys(block)
            if self.mode == "nearest":
                keys = k0
                subs = np.arange(n, dtype=np.int32)
            else:  # a blended subpixel reads two views: listed under both
                keys = np.concatenate([k0, k1])
                subs = np.concatenate([np.arange(n, dtype=np.int32)] * 2)
            order = np.argsort(keys, kind="stable")
            return {"subs": subs[order],
                    "offsets": np.searchsorted(keys[order], np.arange(self.n_views * nb + 1)).astype(np.int64)}

        m = n if self.mode == "nearest" else 2 * n
        t = self._cached("readers", {"subs": ((m,), "int32"), "offsets": ((self.n_views * nb + 1,), "int64")},
                         build, block=block)
        subs, offsets = t["subs"], t["offsets"]
        self._readers = (block, subs, offsets)
        return subs, offsets

    def readers(self, columns: np.ndarray, block: int = 16) -> np.ndarray:
        """Flat native subpixels that read any of the given quilt texel-column blocks.

        Parameters
        ----------
        columns : numpy.ndarray
            (n_views, ceil(tile_width / block)) bool: texel columns ``[j block, (j+1) block)`` of
            each view's tile (all rows).
        block : int
            Column block width (the renderer's tile size); the table is built once per block
            (~1-2 s for the Portrait, then cached).

        Returns
        -------
        numpy.ndarray
            int32 flat indices into ``native.reshape(-1)`` (may repeat in blend mode).
        """
        subs, offsets = self._reader_table(int(block))
        cols = np.asarray(columns, dtype=bool)
        nb = offsets.size - 1
        if cols.size != nb:
            raise InputError(f"columns: expected {self.n_views} x {nb // self.n_views} bools, found {cols.shape}")
        keys = np.flatnonzero(cols.reshape(-1))
        if keys.size == 0:
            return np.empty(0, dtype=np.int32)
        return np.concatenate([subs[offsets[k]:offsets[k + 1]] for k in keys])

    def _kernel_args(self, dtype: Any) -> tuple:
        """(mode, second index, uint8 weight, float weight) of the update kernels: mode 0 nearest,
        1 blend of a uint8 quilt, 2 blend of a float32 one."""
        if self.mode == "nearest":
            return 0, self._idx0, self._idx0[:1].astype(np.uint16), np.zeros(1, np.float32)
        _, _, wf = self.gather_indices()
        return (1 if dtype == np.uint8 else 2), self._idx1, self._w8, wf

    def update(self, quilt: np.ndarray, out: np.ndarray, subpixels: np.ndarray) -> np.ndarray:
        """Recompute only the listed flat subpixels of ``out`` from ``quilt`` (same values as a
        full call there; the rest of ``out`` is left as it is). Returns ``out``."""
        q = np.asarray(quilt)
        if q.shape != self.quilt_shape or q.dtype not in (np.uint8, np.float32):
            raise InputError(f"quilt: expected {self.quilt_shape} uint8 or float32, found {q.shape} {q.dtype}")
        if out.shape != self.shape or out.dtype != q.dtype or not out.flags.c_contiguous:
            raise InputError(f"out: expected a C-contiguous {self.shape} {q.dtype} array, found {out.shape} {out.dtype}")
        sel = np.ascontiguousarray(subpixels, dtype=np.int32)
        if sel.size and (int(sel.min()) < 0 or int(sel.max()) >= out.size):
            raise InputError(f"subpixels: expected flat indices in [0, {out.size}), found [{sel.min()}, {sel.max()}]")
        src = np.ascontiguousarray(q).reshape(-1)
        flat = out.reshape(-1)
        mode, i1, w8, wf = self._kernel_args(q.dtype)
        if self.backend == "numba":
            _numba_kernels()[3](src, self._idx0, i1, w8, wf, sel, flat, mode)
        elif mode == 0:
            flat[sel] = src[self._idx0[sel]]
        elif mode == 1:
            a = src[self._idx0[sel]].astype(np.uint32)
            b = src[i1[sel]].astype(np.uint32)
            w = w8[sel].astype(np.uint32)
            flat[sel] = ((a * (256 - w) + b * w + 128) >> 8).astype(np.uint8)
        else:
            a = src[self._idx0[sel]]
            flat[sel] = a + (src[i1[sel]] - a) * wf[sel]
        return out


def interleave(quilt: np.ndarray, calibration: DisplayCalibration, cols: int | None = None, rows: int | None = None,
               n_views: int | None = None, mode: Mode = "nearest") -> np.ndarray:
    """One-shot :class:`Interleaver` (precomputes, then gathers)."""
    q = np.asarray(quilt)
    return Interleaver(calibration, q.shape, cols, rows, n_views, mode)(q)
