"""Fast multi-view CPU splat rasterizer (float32, tile-based, compiled).

Same forward pass as :mod:`holo_viewer.render.reference` (tested against it), organised for
a quilt of V views that share one orientation (docs/design.md "Multi-view cameras"):

1. **preprocess** (once per orientation group): camera-frame centres and covariances
   ``W R S S^T R^T W^T`` (float64), culling of splats behind the near plane of every view;
2. **sort**: one stable depth sort serves every view of the group (view depth differs
   between the views only by a constant, so the order is the same), started from the previous
   render's order (``depth_order``: an animation's next frame is nearly sorted, ~1 ms);
3. **project** (per chunk of views): 2D centre, conic, SH colour per view (or shared),
   pixel box = radius box intersected with the ellipse where alpha >= threshold and the image;
   splats whose box is empty in every view are the ones culled by the union of the frusta;
4. **bin**: per (view, 16x16 tile) lists of splat indices in depth order (count, prefix, fill),
   only into the tiles the splat's alpha >= threshold ellipse reaches (per tile row, the
   ellipse's x-extent over the band of rows);
5. **composite**: tiles x views in parallel, front to back with early termination, float32.

With the C++ extension (``_splat_cpp``, the default when built) steps 3 and 4 are one pass over
the splats per chunk of views (``project_bin``: 8 splats at a time as vectorised loops, a block
of them into every view in turn, each record binned while in cache; timed as "project", filling
the lists as "bin") and the compositor is AVX-512 for
16x16 tiles (one register per tile row), else AVX2 (chords, 8-pixel chunks), else scalar,
chosen at run time. Without it every step runs in numba (``fast_kernels``); both give the
same records and lists (tested bit for bit).

Memory is bounded by ``config.max_chunk_bytes``: views are processed in chunks so the per-view
splat records and tile lists never exceed it (nothing is N x pixels).
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..avatar.gaussians import Gaussians
from ..camera import Cameras
from ..errors import RenderError
from .config import RenderConfig, RenderResult
from .projection import clamp_limits

__all__ = ["render", "tile_grid", "cpp_available", "kernel_names", "release_buffers", "SortedSplats", "SplatPass",
           "SlitViews", "CAM"]

#: C++ compositor path: 0 = the best the CPU runs (AVX-512 for 16x16 tiles, else AVX2, else scalar),
#: 1 = scalar, 2 = require AVX2, 3 = require AVX-512 (tests and the benchmark set this)
_CPP_MODE = 0

#: memory per (view, splat) the chunking budgets for: the packed record (64 bytes), ~4 tile-list
#: entries (4 bytes each) and, in the C++ path, the same entries as (splat, tile) pairs while
#: the lists are built (8 bytes each)
_BYTES_PER_SPLAT_VIEW = 64 + 4 * 4 + 4 * 8


def _records(nv: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Packed splat records: (rec (nv, m, REC_STRIDE) float32, box (nv, m, 4) int32 view of it).

    One 64-byte record per (view, splat), 64-byte aligned: floats 0..9 are ``rec``
    (fast_kernels.REC fields), words 10..13 the int32 pixel box, so the compositor reads
    everything it needs about a splat from one cache line.
    """
    from . import fast_kernels as fk

    rec = _aligned_records(np.empty(nv * m * fk.REC_STRIDE + 16, dtype=np.float32), nv, m)
    return rec, rec.view(np.int32)[:, :, fk.BOX_AT:fk.BOX_AT + 4]


def _aligned_records(raw: np.ndarray, nv: int, m: int) -> np.ndarray:
    """(nv, m, REC_STRIDE) float32 view of ``raw`` (>= nv m REC_STRIDE + 16 floats) starting on
    a 64-byte boundary, so each record is one cache line."""
    from . import fast_kernels as fk

    n = nv * m * fk.REC_STRIDE
    start = (-raw.ctypes.data % 64) // 4
    return raw[start:start + n].reshape(nv, m, fk.REC_STRIDE)


class _Workspace:
    """Record and tile-list buffers kept between renders of the C++ path.

    A quilt needs ~70 MB of records and ~20 MB of tile lists per chunk of views; allocating
    them per call made the kernel zero fresh pages (~10% of a quilt's time). A render that finds
    the workspace in use by another thread allocates its own buffers instead.
    """

    def __init__(self) -> None:
        self._rec = np.empty(0, dtype=np.float32)
        self._ids = np.empty(0, dtype=np.int32)
        self._named: dict[str, np.ndarray] = {}
        self.depth_hints: dict[int, np.ndarray] = {}  # per camera group: the last full depth order
        self.lock = threading.Lock()

    def buffer(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """An uninitialised array kept under ``name`` between renders (the depth-ordered copies:
        ~15 MB of fresh pages per render for the avatar cost ~5 ms of page faults, measured)."""
        a = self._named.get(name)
        if a is None or a.shape != tuple(shape) or a.dtype != np.dtype(dtype):
            a = self._named[name] = np.empty(shape, dtype=dtype)
        return a

    def records(self, nv: int, m: int) -> np.ndarray:
        from . import fast_kernels as fk

        n = nv * m * fk.REC_STRIDE + 16
        if self._rec.size < n:
            self._rec = np.empty(n, dtype=np.float32)
        return _aligned_records(self._rec, nv, m)

    def ids(self) -> np.ndarray:
        return self._ids

    def grow_ids(self, n: int) -> None:
        self._ids = np.empty(int(n * 1.25) + 1024, dtype=np.int32)

    def nbytes(self) -> int:
        return int(self._rec.nbytes + self._ids.nbytes + sum(a.nbytes for a in self._named.values()))

    def release(self) -> None:
        """Drop the buffers (memory goes back to the system)."""
        self._rec = np.empty(0, dtype=np.float32)
        self._ids = np.empty(0, dtype=np.int32)
        self._named = {}
        self.depth_hints = {}


_SHARED_WORKSPACE = _Workspace()

#: buffers larger than this are dropped after the render instead of kept for the next one
_KEEP_AT_MOST = 512 * 2**20


class _Lease:
    """Owner of one pooled output buffer, exported to numpy through ``__array_interface__``.

    ``np.asarray(lease)`` makes an array whose ``base`` is the lease; every view of that array
    keeps it alive in turn (as does a buffer-protocol export of any of them), so the lease dies,
    and gives its memory back to the pool, only when no array can read or write the memory.
    """

    __slots__ = ("__array_interface__", "_mem", "_pool")

    def __init__(self, mem: np.ndarray, shape: tuple[int, ...], pool: "_OutputPool") -> None:
        self._mem, self._pool = mem, pool
        self.__array_interface__ = {"shape": shape, "typestr": "<f4", "version": 3,
                                    "data": (mem.ctypes.data, False)}

    def __del__(self) -> None:
        try:
            self._pool._give_back(self._mem)
        except Exception:  # noqa: BLE001 - interpreter shutdown: module globals may be gone
            pass


class _OutputPool:
    """Recycles the memory of output images their caller has dropped.

    A 48-view 420x560 quilt is 135 MB of float32. Fresh memory for it each call made the kernel
    zero 135 MB of new pages inside the compositor (~9 % of a render's CPU time on the 2-core
    VM). The pool keeps up to ``keep`` buffers (``_KEEP_AT_MOST`` bytes in all) whose images
    are no longer referenced and hands them to the next render of the same size; in the usual
    loop (``r = render(...)`` again while the last result is still held) two buffers alternate.
    Nothing is reused while any array still refers to it.
    """

    def __init__(self, keep: int = 2) -> None:
        self.keep = keep
        self._free: list[np.ndarray] = []
        # re-entrant: a garbage collection inside a locked section may run a lease's __del__
        self._lock = threading.RLock()

    def empty(self, shape: tuple[int, ...]) -> np.ndarray:
        """An uninitialised float32 array of ``shape``, on recycled memory when the pool has some."""
        n = int(np.prod(shape))
        mem = None
        with self._lock:
            for i, m in enumerate(self._free):
                if m.size == n:
                    mem = self._free.pop(i)
                    break
        if mem is None:
            mem = np.empty(n, dtype=np.float32)
        return np.asarray(_Lease(mem, tuple(int(x) for x in shape), self))

    def _give_back(self, mem: np.ndarray) -> None:
        with self._lock:
            self._free.append(mem)
            while self._free and (len(self._free) > self.keep or
                                  sum(m.nbytes for m in self._free) > _KEEP_AT_MOST):
                self._free.pop(0)  # the oldest first

    def nbytes(self) -> int:
        with self._lock:
            return sum(m.nbytes for m in self._free)

    def release(self) -> None:
        with self._lock:
            self._free.clear()


_OUTPUTS = _OutputPool()


def release_buffers() -> None:
    """Free the record and tile-list buffers the C++ path keeps between renders (~92 MB after a
    48-view quilt of 100k splats, plus ~45 MB of binning scratch inside the extension) and the
    recycled output images (up to two quilts, 135 MB each, of renders whose images were
    dropped); the next render allocates them again."""
    with _SHARED_WORKSPACE.lock:
        _SHARED_WORKSPACE.release()
    _OUTPUTS.release()
    cpp = _cpp()
    if cpp is not None:
        cpp.release_scratch()


#: sigmoid_cached's last results by shape: (logits float64 copy, opacities); one tuple per key, replaced
#: whole (renderers in several threads read it)
_SIGMOID_CACHE: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}


def sigmoid_cached(logits: Any) -> np.ndarray:
    """``1 / (1 + exp(-logits))`` in float64, a new array; the same values as computing it, taken from the last
    call with equal logits of that shape (an avatar's opacities do not change between live frames: 0.08 ms
    against 0.79 for 102k, measured)."""
    lg = np.asarray(logits, dtype=np.float64)
    hit = _SIGMOID_CACHE.get(lg.shape)
    if hit is not None and np.array_equal(hit[0], lg):
        return hit[1].copy()
    op = 1.0 / (1.0 + np.exp(-lg))
    if len(_SIGMOID_CACHE) >= 4 and lg.shape not in _SIGMOID_CACHE:
        _SIGMOID_CACHE.clear()
    _SIGMOID_CACHE[lg.shape] = (lg.copy(), op.copy())
    return op


def _cpp():  # noqa: ANN202
    try:
        from . import _splat_cpp  # type: ignore[attr-defined]
    except ImportError:
        return None
    return _splat_cpp


def cpp_available() -> bool:
    """True when the compiled C++ kernel (``holo_viewer.render._splat_cpp``) is importable."""
    return _cpp() is not None


def kernel_names() -> list[str]:
    """Compositing kernels usable here ("cpp" only when the extension is built)."""
    return (["cpp"] if cpp_available() else []) + ["numba"]


def _groups(cameras: Cameras) -> list[np.ndarray]:
    """Indices of cameras grouped by identical rotation (one depth sort per group)."""
    R = cameras.R
    left = list(range(len(cameras)))
    groups = []
    while left:
        r0 = R[left[0]]
        same = [i for i in left if np.abs(R[i] - r0).max() < 1e-12]
        groups.append(np.array(same))
        left = [i for i in left if i not in set(same)]
    return groups


def depth_order(z: np.ndarray, keep: np.ndarray, hint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the kept splats by increasing depth, ties by index (a stable sort).

    Parameters
    ----------
    z : numpy.ndarray
        (N,) finite view depths.
    keep : numpy.ndarray
        (N,) bool: which splats to order.
    hint : numpy.ndarray or None
        The full order this function returned for the previous frame (any permutation of
        ``range(N)`` is correct), used without the C++ extension: consecutive frames move little,
        so ``z[hint]`` is nearly sorted and numpy's stable sort (timsort) runs through it in
        ~1-4 ms instead of ~10 ms for 100k splats (runs of equal depths are put back in index
        order afterwards). With the extension, an LSD radix sort of the depths' bits
        (``_splat_cpp.argsort_stable``, ~1.3 ms for 100k on an animated avatar, where the hint
        costs timsort ~4 ms) gives the same order without it. The result never depends on it.

    Returns
    -------
    order : numpy.ndarray
        (keep.sum(),) int64 indices.
    full : numpy.ndarray
        (N,) the order of all splats: the next frame's hint.
    """
    cpp = _cpp()
    if cpp is not None and hasattr(cpp, "argsort_stable"):  # a radix sort: the same order, 2-5x faster
        full = np.empty(z.size, dtype=np.int64)
        cpp.argsort_stable(np.ascontiguousarray(z, dtype=np.float64), full)
    elif hint is None or hint.shape != z.shape:
        full = np.argsort(z, kind="stable").astype(np.int64, copy=False)
    else:
        full = hint[np.argsort(z[hint], kind="stable")]
        zs = z[full]
        eq = zs[1:] == zs[:-1]
        if eq.any():  # equal depths in hint order: sort each run by index
            in_run = np.zeros(z.size, dtype=bool)
            in_run[1:] |= eq
            in_run[:-1] |= eq
            run = np.cumsum(np.concatenate(([True], ~eq)))[in_run]
            tied = full[in_run]
            full[in_run] = tied[np.lexsort((tied, run))]
    return full[keep[full]], full


#: doubles per view in the projection kernels' camera parameters (fast_kernels.project_views)
CAM = 29


def _view_params(cameras: Cameras, views: np.ndarray, rects: np.ndarray | None = None) -> np.ndarray:
    """(len(views), CAM) float64 per-view parameters of the projection kernels (project_views docs;
    pinholes: the crossed-slit entries 18.. are 0).

    ``rects``: (V, 4) pixel rectangles x0, x1, y0, y1 (all cameras) the splat boxes are clipped
    to; None = the image."""
    W, H = cameras.width, cameras.height
    cams = np.zeros((len(views), CAM))
    if rects is None:
        cams[:, 14:18] = (0.0, W, 0.0, H)
    else:
        cams[:, 14:18] = rects[views]
    cams[:, 0], cams[:, 1] = cameras.fx[views], cameras.fy[views]
    cams[:, 2], cams[:, 3] = cameras.cx[views], cameras.cy[views]
    cams[:, 4:7] = cameras.t[views]
    cams[:, 7:10] = cameras.positions[views]
    for j, vi in enumerate(views):
        cams[j, 10:14] = clamp_limits(cameras.fx[vi], cameras.fy[vi], cameras.cx[vi], cameras.cy[vi], W, H)
    return cams


def _sorted_inputs(order: np.ndarray, means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray,
                   opacity: np.ndarray, colours: np.ndarray, Wrot: np.ndarray, alpha_threshold: float,
                   workspace: "_Workspace | None" = None) -> tuple[np.ndarray, ...]:
    """Depth-ordered inputs of ``_splat_cpp.project_bin``: pc, cov, means, opacity, q, colours.

    Structure of arrays (one row per component) with a row length ``mp`` = m rounded up to a
    multiple of 8 (the kernel projects 8 splats at a time; the padding has opacity 0, so it is
    never drawn), made in one pass (``fast_kernels.prep_sorted``: pc, cov as ``prep_3d``).
    colours: (N, nk, 3) SH coefficients (rows j * 3 + channel), or (N, 3) shared colours.
    q = 2 ln(opacity / threshold).
    """
    from . import fast_kernels as fk

    m = order.size
    mp = -(-m // 8) * 8
    cols = np.ascontiguousarray(colours.reshape(len(colours), -1))
    ws = workspace or _Workspace()
    pc, cov, mout = ws.buffer("pc", (3, mp), np.float64), ws.buffer("cov", (6, mp), np.float64), \
        ws.buffer("means", (3, mp), np.float64)
    op, sh = ws.buffer("opacity", (mp,), np.float64), ws.buffer("sh", (cols.shape[1], mp), cols.dtype)
    opacity = np.ascontiguousarray(opacity, dtype=np.float64)
    cpp = _cpp()
    geo = [np.ascontiguousarray(a) for a in (means, quats, log_scales)]
    f32 = all(a.dtype == np.float32 for a in geo)
    if cpp is not None and hasattr(cpp, "prep_sorted") and cols.dtype == np.float32:  # the same values, 2-4x faster
        if not f32:  # float32 inputs are read as they are (widened exactly in the kernel)
            geo = [np.ascontiguousarray(a, dtype=np.float64) for a in geo]
        cpp.prep_sorted(np.ascontiguousarray(order, dtype=np.int64), *geo, opacity, cols,
                        np.ascontiguousarray(Wrot, dtype=np.float64), pc, cov, mout, op, sh, m, mp, len(means),
                        cols.shape[1], int(f32), _cpu_threads())
    else:
        fk.prep_sorted(order, *(np.ascontiguousarray(a, dtype=np.float64) for a in geo), opacity, cols, Wrot, pc, cov,
                       mout, op, sh)
    q = 2.0 * (np.log(np.maximum(op, 1e-300)) - math.log(alpha_threshold))  # padding: op = 0, never drawn
    return pc, cov, mout, op, q, sh


def _soa(a: np.ndarray, order: np.ndarray, dtype: type) -> np.ndarray:
    """Rows of ``a`` (N, ...) in ``order`` as a (C, mp) structure of arrays, mp = len(order) rounded
    up to 8, the padding zero."""
    from . import fast_kernels as fk

    m = order.size
    mp = -(-m // 8) * 8
    a = np.ascontiguousarray(a.reshape(len(a), -1), dtype=dtype)
    out = np.empty((a.shape[1], mp), dtype=dtype)
    out[:, m:] = 0
    fk.gather_soa(a, order, out)
    return out


def _cpu_threads() -> int:
    """The threads the compiled kernels use: numba's current count."""
    import numba

    return int(numba.get_num_threads())


def _threads(config: RenderConfig) -> int:
    import numba

    n = config.num_threads or numba.config.NUMBA_NUM_THREADS
    n = max(1, min(int(n), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return n


def tile_grid(cameras: Cameras, config: RenderConfig | None = None) -> tuple[int, int]:
    """(tiles_y, tiles_x) of the compositor's tile grid for these cameras (``config.tile_size``)."""
    tile = int((config or RenderConfig()).tile_size)
    return -(-cameras.height // tile), -(-cameras.width // tile)


def _check_region(cameras: Cameras, config: RenderConfig, tile_mask: np.ndarray | None,
                  out: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Validated (tile_mask, pixel rectangles (V, 4) of its tiles per view) or (None, None)."""
    V, H, W = len(cameras), cameras.height, cameras.width
    if out is not None:
        if not (isinstance(out, np.ndarray) and out.shape == (V, H, W, 3) and out.dtype == np.float32
                and out.flags.c_contiguous and out.flags.writeable):
            raise RenderError(f"fast backend: out: expected a writeable C-contiguous ({V}, {H}, {W}, 3) float32 "
                              f"array, found {getattr(out, 'shape', None)} {getattr(out, 'dtype', type(out).__name__)}")
    if tile_mask is None:
        return None, None
    ty, tx = tile_grid(cameras, config)
    mask = np.asarray(tile_mask)
    if mask.dtype != np.bool_ or mask.shape != (V, ty, tx):
        raise RenderError(f"fast backend: tile_mask: expected a bool ({V}, {ty}, {tx}) array (views, tile rows, "
                          f"tile columns of {config.tile_size}-pixel tiles), found {mask.dtype} {mask.shape}")
    tile = int(config.tile_size)
    rects = np.zeros((V, 4))
    cols_any, rows_any = mask.any(axis=1), mask.any(axis=2)
    for v in np.flatnonzero(cols_any.any(axis=1)):
        c, r = np.flatnonzero(cols_any[v]), np.flatnonzero(rows_any[v])
        rects[v] = (c[0] * tile, min(W, (c[-1] + 1) * tile), r[0] * tile, min(H, (r[-1] + 1) * tile))
    return mask, rects


def render(gaussians: Gaussians, cameras: Cameras, config: RenderConfig | None = None, *,
           tile_mask: np.ndarray | None = None, out: np.ndarray | None = None,
           passes: tuple[SplatPass, ...] | list[SplatPass] = (), slits: SlitViews | None = None,
           view_keep: np.ndarray | None = None, index: np.ndarray | None = None) -> RenderResult:
    """Render every camera with the fast backend (see the module docstring).

    Inputs are assumed validated (use :func:`holo_viewer.render.render_views`).

    Parameters
    ----------
    tile_mask : numpy.ndarray or None
        (V, tiles_y, tiles_x) bool (:func:`tile_grid`): render only these tiles of each view.
        The pixels of a masked tile are exactly those of the full render; the other tiles are
        not written (they keep ``out``'s values, or 0 in a new array). Views without a tile are
        skipped; each view's splat boxes are clipped to the bounding rectangle of its tiles, and
        (C++ path) splats that cannot reach it are dropped by a cheap conservative test before
        they are projected, so the cost follows the rendered area.
    out : numpy.ndarray or None
        (V, H, W, 3) float32 C-contiguous array to render into (e.g. the previous frame's views).
    passes : sequence of SplatPass
        Extra images drawn from the same depth sort (:class:`SplatPass`); the cameras must then
        share one rotation. A render whose mask leaves no view still draws its passes.
    slits : SlitViews or None
        Crossed-slit views drawn in the same projection pass as the first chunk of cameras (their
        images into ``slits.out``); the cameras must share one rotation. A render whose mask
        leaves no view still draws them.
    view_keep : numpy.ndarray or None
        (V, N) bool: camera v draws only the Gaussians where ``view_keep[v]`` is set (the others'
        boxes are empty in that view: never binned nor composited; still projected). The image is
        that of rendering ``gaussians.subset(view_keep[v])`` alone in view v (tested); passes and
        slits draw every Gaussian. Used by live frames to skip, per source view, the Gaussians no
        pose shows there (:func:`holo_viewer.pipeline.live_support.visible_mask`). With ``index``: (V, len(index)),
        over the indexed Gaussians.
    index : numpy.ndarray or None
        (n,) int64 indices of ``gaussians``: render ``gaussians.subset(index)`` without copying the subset
        (the C++ path reads the indexed Gaussians straight into its depth-ordered copies; the numba path,
        passes and shared colours take the subset). The images are those of the subset bit for bit (tested);
        ``stats["n_input"]`` counts the indexed ones. Live frames draw their level of detail so.

    Returns
    -------
    RenderResult
        images (V, H, W, 3) float32 (``out`` when given); timings "preprocess", "sort", "project",
        "bin", "composite", "passes" (their transforms), "total"; stats n_input, n_visible,
        mean_blends_per_pixel (the cameras' images), threads, kernel, rendered_tiles.
    """
    config = config or RenderConfig()
    mask, rects = _check_region(cameras, config, tile_mask, out)
    n = len(gaussians)
    if index is not None:
        ix = np.asarray(index)
        ints = ix.ndim == 1 and ix.dtype.kind in "iu"
        if not ints or (ix.size and (int(ix.min()) < 0 or int(ix.max()) >= n)):
            span = f" from {int(ix.min())} to {int(ix.max())}" if ints and ix.size else ""
            raise RenderError(f"fast backend: index: expected (n,) integers in [0, {n}), found {ix.dtype} {ix.shape}"
                              f"{span}")
        index = np.ascontiguousarray(ix, dtype=np.int64)
        n = index.size
        cpp_ok = _cpp() is not None and config.kernel in ("auto", "cpp")
        if passes or config.shared_sh or not cpp_ok:  # those read the inputs in their own order: the subset
            gaussians, index = gaussians.subset(index), None
    if view_keep is not None:
        vk = np.asarray(view_keep)
        if vk.dtype != np.bool_ or vk.shape != (len(cameras), n):
            raise RenderError(f"fast backend: view_keep: expected a bool ({len(cameras)}, {n}) array "
                              f"(cameras, Gaussians), found {vk.dtype} {vk.shape}")
        view_keep = vk
    passes = tuple(passes)
    for p in passes:
        _check_pass(p, cameras)
    if slits is not None:
        _check_slits(slits, cameras)
    if (passes or slits is not None) and len(_groups(cameras)) != 1:
        raise RenderError("fast backend: passes, slits: expected cameras sharing one rotation")
    shared = _SHARED_WORKSPACE.lock.acquire(blocking=False)
    try:
        return _render(gaussians, cameras, config, _SHARED_WORKSPACE if shared else _Workspace(),
                       mask, rects, out, passes, slits, view_keep, index)
    finally:
        if shared:
            if _SHARED_WORKSPACE.nbytes() > _KEEP_AT_MOST:  # a huge scene: do not hold its buffers
                _SHARED_WORKSPACE.release()
            _SHARED_WORKSPACE.lock.release()


def _check_slits(slits: "SlitViews", cameras: Cameras) -> None:
    if not isinstance(slits, SlitViews) or not isinstance(slits.cameras, Cameras):
        raise RenderError(f"fast backend: slits: expected SlitViews, found {type(slits).__name__}")
    S = len(slits.cameras)
    if len(cameras) and np.abs(slits.cameras.R - cameras.R[0]).max() > 1e-12:
        raise RenderError("fast backend: SlitViews.cameras: expected the rotation of the render's cameras")
    if slits.t_min is not None and not (0.0 <= float(slits.t_min) <= 0.5):
        raise RenderError(f"fast backend: SlitViews.t_min: expected in [0, 0.5] or None, found {slits.t_min!r}")
    p = np.asarray(slits.params)
    if p.shape != (S, 13) or p.dtype != np.float64 or not np.isfinite(p).all():
        raise RenderError(f"fast backend: SlitViews.params: expected finite float64 ({S}, 13), found {p.dtype} {p.shape}")
    shape = (S, cameras.height, cameras.width, 3)
    o = slits.out
    if (slits.cameras.width, slits.cameras.height) != (cameras.width, cameras.height) or not (
            isinstance(o, np.ndarray) and o.shape == shape and o.dtype == np.float32 and o.flags.c_contiguous
            and o.flags.writeable):
        raise RenderError(f"fast backend: SlitViews.out: expected a writeable C-contiguous {shape} float32 array "
                          f"(the render's size), found {getattr(o, 'shape', None)} {getattr(o, 'dtype', None)}")


def _check_pass(p: "SplatPass", cameras: Cameras) -> None:
    if not isinstance(p, SplatPass):
        raise RenderError(f"fast backend: passes: expected SplatPass items, found {type(p).__name__}")
    if not isinstance(p.cameras, Cameras) or len(_groups(p.cameras)) != 1:
        raise RenderError("fast backend: SplatPass.cameras: expected Cameras sharing one rotation")
    if len(cameras) and np.abs(p.cameras.R[0] - cameras.R[0]).max() > 1e-12:
        raise RenderError("fast backend: SplatPass.cameras: expected the rotation of the render's cameras")
    if (p.cameras.width, p.cameras.height) != (cameras.width, cameras.height):
        raise RenderError(f"fast backend: SplatPass.cameras: expected {cameras.width}x{cameras.height} images (the "
                          f"render's), found {p.cameras.width}x{p.cameras.height}")
    shape = (len(p.cameras), cameras.height, cameras.width, 3)
    o = p.out
    if not (isinstance(o, np.ndarray) and o.shape == shape and o.dtype == np.float32 and o.flags.c_contiguous
            and o.flags.writeable):
        raise RenderError(f"fast backend: SplatPass.out: expected a writeable C-contiguous {shape} float32 array, "
                          f"found {getattr(o, 'shape', None)} {getattr(o, 'dtype', type(o).__name__)}")


@dataclass(frozen=True)
class SortedSplats:
    """The splats of one render in depth order, as the projection reads them (structure of arrays,
    row stride ``mp`` = ``m`` rounded up to 8; the padding has opacity 0 and is never drawn).

    Attributes
    ----------
    pc : (3, mp) float64 centres in the cameras' rotated frame, ``R mean`` (no translation).
    cov : (6, mp) float64 covariances (xx, xy, xz, yy, yz, zz) in that frame.
    means : (3, mp) float64 world centres.  opacity : (mp,) float64.
    sh : (nk 3, mp) float32 SH coefficients (row j 3 + channel) of degree ``degree``.
    order : (m,) int64 indices of these splats in the input.
    """

    pc: np.ndarray
    cov: np.ndarray
    means: np.ndarray
    opacity: np.ndarray
    sh: np.ndarray
    degree: int
    order: np.ndarray

    @property
    def m(self) -> int:
        return int(self.order.size)


@dataclass
class SlitViews:
    """Crossed-slit views (:mod:`holo_viewer.render.crossed_slit`) drawn with a render's cameras, in
    the same projection pass: each splat's centre moves to its slice column ``xi = (a X + b Z + c)
    / (e Z + f)`` (X, Z in the cameras' frame, R p + their translation) at the same depth, its
    covariance by that move's Jacobian, and its SH is seen from the camera of that column.

    Attributes
    ----------
    cameras : Cameras
        S pinholes with the render's rotation carrying fx, fy, cy, the principal column the moved
        centres are splatted with and the translation; their positions are ``P0`` below.
    params : (S, 13) float64
        a, b, c, e, f; A, B (the column's camera is ``s = A + B xi``); P0 (3), P1 (3): its position
        ``P0 + s P1``.
    out : (S, H, W, 3) float32
        The images (the render's size), every pixel written.
    t_min : float or None
        Their compositing's early-termination threshold (None: the render's ``t_min``): a
        pixel's error stays below it (docs/renderer.md "Early termination").
    """

    cameras: Cameras
    params: np.ndarray
    out: np.ndarray
    t_min: float | None = None


def _slit_params(slits: SlitViews) -> np.ndarray:
    cams = _view_params(slits.cameras, np.arange(len(slits.cameras)))
    p = slits.params
    cams[:, 18] = 1.0
    cams[:, 19:26] = p[:, 0:7]
    cams[:, 7:10] = p[:, 7:10]
    cams[:, 26:29] = p[:, 10:13]
    return cams


@dataclass
class SplatPass:
    """Extra images drawn from the same depth-sorted splats as a render's views.

    For projections that pinhole cameras only emulate after a change of the splats (e.g. the
    crossed-slit eye images of :mod:`holo_viewer.render.crossed_slit`): ``transform`` maps the
    :class:`SortedSplats` to ``(pc, cov, colours)`` with pc (3, mp) and cov (6, mp) float64 in
    the frame of ``cameras`` (which add their translations) and colours (3, mp) float32 RGB shared
    by the pass's cameras; the depth order of the render is kept, so the transform must keep
    each splat's depth (a splat it cannot map goes behind the near plane). ``out`` receives the
    (len(cameras), H, W, 3) float32 images (the size of the render's cameras).
    """

    cameras: Cameras
    transform: Callable[[SortedSplats], tuple[np.ndarray, np.ndarray, np.ndarray]]
    out: np.ndarray


def _runs(views: np.ndarray) -> list[np.ndarray]:
    """Split sorted view indices into runs of consecutive indices."""
    if views.size == 0:
        return []
    cut = np.flatnonzero(np.diff(views) != 1) + 1
    return np.split(views, cut)


def _render(gaussians: Gaussians, cameras: Cameras, config: RenderConfig, workspace: _Workspace,
            mask: np.ndarray | None = None, rects: np.ndarray | None = None,
            out_images: np.ndarray | None = None, passes: tuple[SplatPass, ...] = (),
            slits: SlitViews | None = None, view_keep: np.ndarray | None = None,
            index: np.ndarray | None = None) -> RenderResult:
    from . import fast_kernels as fk

    kernel = config.kernel
    cpp = _cpp()
    if kernel == "cpp" and cpp is None:
        raise RenderError("fast backend: kernel 'cpp' requested but the C++ extension "
                          "holo_viewer.render._splat_cpp is not built (reinstall with a C++17 compiler; "
                          "kernel='numba' works without it)")
    use_cpp = cpp is not None and kernel in ("auto", "cpp")
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    threads = _threads(config)
    timings = dict.fromkeys(("preprocess", "sort", "project", "bin", "composite"), 0.0)
    if passes:
        timings["passes"] = 0.0

    g = gaussians.numpy()
    # the C++ depth-ordered copies read float32 inputs as they are; the numba kernels get float64
    raw = [np.ascontiguousarray(a) for a in (g.means, g.quats, g.log_scales)]
    if not (use_cpp and all(a.dtype == np.float32 for a in raw)):
        raw = [np.ascontiguousarray(a, dtype=np.float64) for a in raw]
    means, quats, log_scales = raw
    # index (C++ path only, render()): the depth sort over the indexed centres (the subset's z, bit for bit),
    # its order mapped to the whole arrays for the depth-ordered copies; n the indexed count
    # (opacity stays whole: read through that order alone; elementwise, so the indexed ones are the subset's)
    n = len(g) if index is None else index.size
    # np.take: the same rows as means[index], ~4x faster for (N, 3) (0.57 -> 0.14 ms for 59k of 102k)
    zmeans = means if index is None else np.take(means, index, axis=0)
    opacity = sigmoid_cached(g.opacity_logits)
    degree = g.sh_degree if config.sh_degree is None else min(g.sh_degree, int(config.sh_degree))
    sh = np.ascontiguousarray(np.asarray(g.sh)[:, : (degree + 1) ** 2], dtype=np.float32)
    near = cameras.near if config.near is None else float(config.near)
    V, H, W = len(cameras), cameras.height, cameras.width
    if out_images is not None:
        images = out_images
    elif mask is not None:
        images = np.zeros((V, H, W, 3), dtype=np.float32)
    else:
        images = _OUTPUTS.empty((V, H, W, 3))
    active = np.ones(V, dtype=bool) if mask is None else mask.any(axis=(1, 2))
    positions = cameras.positions
    if config.shared_sh:
        from .reference import view_colors

        shared_rgb = view_colors(means, sh.astype(np.float64), degree, positions.mean(axis=0)).astype(np.float32)
    else:
        shared_rgb = np.zeros((1, 3), dtype=np.float32)
    draw = _Draw(config, workspace, cpp if use_cpp else None, threads, W, H, near, n, timings)
    timings["preprocess"] += time.perf_counter() - t_start

    for gi, group in enumerate(_groups(cameras)):
        group = group[active[group]]
        if group.size == 0 and not passes and slits is None:
            continue
        t0 = time.perf_counter()
        Wrot = np.ascontiguousarray(cameras.R[int(group[0]) if group.size else 0])
        sorted_path = use_cpp or bool(passes)  # depth-ordered copies: the C++ pass reads every input in order
        pc = cov = None
        if sorted_path:
            z = fk.depth_z(zmeans, Wrot)  # (float32 centres widen exactly: the same z)
        else:
            pc, cov = fk.prep_3d(means, quats, log_scales, Wrot)
            z = pc[:, 2]
        tz = cameras.t[group, 2] if group.size else np.zeros(0)
        for p in passes:  # a pass keeps the depths: its cameras add their z offsets as the render's do
            tz = np.concatenate((tz, p.cameras.t[:, 2]))
        if slits is not None:  # so do crossed-slit views
            tz = np.concatenate((tz, slits.cameras.t[:, 2]))
        front = (z + tz.max()) > near if tz.size else np.zeros(n, dtype=bool)
        t1 = time.perf_counter()
        order, workspace.depth_hints[gi] = depth_order(z, front, workspace.depth_hints.get(gi))
        m = order.size
        sorted_in = None
        if sorted_path:
            # with index: the whole arrays read in the indexed depth order
            sorted_in = _sorted_inputs(order if index is None else index[order], means, quats, log_scales, opacity,
                                       shared_rgb if config.shared_sh else sh, Wrot, float(config.alpha_threshold),
                                       workspace)
            if not use_cpp:  # the numba kernels read the inputs through the order instead (float64 here)
                pc, cov = fk.prep_3d(means, quats, log_scales, Wrot)
        t2 = time.perf_counter()
        timings["preprocess"] += t1 - t0
        timings["sort"] += t2 - t1  # the depth sort and the depth-ordered copies
        chunks: list[np.ndarray] = []
        if group.size:
            chunk = max(1, min(len(group), int(config.max_chunk_bytes // max(1, m * _BYTES_PER_SPLAT_VIEW))))
            chunks = [r[c0:c0 + chunk] for r in (_runs(np.sort(group)) if mask is not None else [group])
                      for c0 in range(0, len(r), chunk)]
        slit_cams = None if slits is None else _slit_params(slits)
        if slit_cams is not None and not chunks:
            chunks = [np.zeros(0, dtype=np.int64)]
        for ci, views in enumerate(chunks):
            cams = _view_params(cameras, views, rects)
            with_slits = slit_cams is not None and ci == 0  # drawn in the first chunk's projection pass
            jobs = None if mask is None else np.flatnonzero(mask[views].reshape(-1)).astype(np.int32)
            contiguous = views.size == 0 or bool(np.all(np.diff(views) == 1))  # always, with a mask
            out = (images[views[0]:views[-1] + 1] if views.size else images[:0]) if contiguous else \
                np.empty((len(views), H, W, 3), np.float32)
            # the chunk's rows of the per-view keep mask (None: every splat in every view), put in depth
            # order by the kernels' callers
            vkeep = None
            if view_keep is not None and views.size:
                vkeep = view_keep if views.size == V and bool(np.all(views == np.arange(V))) else view_keep[views]
            if use_cpp:
                seen = draw.cpp_views(sorted_in, m, degree, bool(config.shared_sh), cams, out, jobs,
                                      slits=(slit_cams, slits.out, slits.t_min) if with_slits else None,
                                      view_keep=None if vkeep is None else (vkeep, order))
            else:
                seen = np.zeros(m, dtype=np.uint8)
                if views.size:
                    seen = draw.numba_views(order, pc, cov, means, opacity, sh, degree, shared_rgb,
                                            bool(config.shared_sh), cams, out,
                                            mask[views] if mask is not None else None,
                                            view_keep=None if vkeep is None else vkeep[:, order])
                if with_slits:
                    draw.numba_views(order, pc, cov, means, opacity, sh, degree, shared_rgb, bool(config.shared_sh),
                                     slit_cams, slits.out, None, count_blends=False, t_min=slits.t_min)
            draw.seen.append((order, seen))
            if not contiguous:
                images[views] = out
        splats = None
        for p in passes:
            t3 = time.perf_counter()
            if splats is None:  # one object for every pass (a pass may cache work across them)
                # the SH coefficients in depth order (the cameras may share colours instead)
                pass_sh = _soa(sh, order, np.float32) if config.shared_sh else sorted_in[5]
                splats = SortedSplats(pc=sorted_in[0], cov=sorted_in[1], means=sorted_in[2], opacity=sorted_in[3],
                                      sh=pass_sh, degree=degree, order=order)
            ppc, pcov, pcol = _pass_inputs(p, splats)
            timings["passes"] += time.perf_counter() - t3
            pcams = _view_params(p.cameras, np.arange(len(p.cameras)))
            if use_cpp:
                draw.cpp_views((ppc, pcov, sorted_in[2], sorted_in[3], sorted_in[4], pcol), m, 0, True, pcams,
                               p.out, None, count_blends=False)
            else:
                draw.numba_views(np.arange(m), np.ascontiguousarray(ppc[:, :m].T), np.ascontiguousarray(pcov[:, :m].T),
                                 means[order], opacity[order], sh[order], 0, np.ascontiguousarray(pcol[:, :m].T), True,
                                 pcams, p.out, None, count_blends=False)
    timings["total"] = time.perf_counter() - t_start
    stats = {"n_input": n, "n_visible": draw.n_visible(),
             "mean_blends_per_pixel": draw.blends / float(V * H * W), "threads": threads,
             "cpu_seconds": time.process_time() - cpu_start, "tile_entries": draw.entries,
             "rendered_tiles": draw.tiles}
    return RenderResult(images=images, timings=timings, stats=stats,
                        backend=f"fast/cpp-{draw.path}" if use_cpp else "fast/numba")


def _pass_inputs(p: SplatPass, splats: SortedSplats) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mp = splats.pc.shape[1]
    out = p.transform(splats)
    try:
        ppc, pcov, pcol = out
    except (TypeError, ValueError):
        raise RenderError("fast backend: SplatPass.transform: expected a tuple (pc, cov, colours)") from None
    ppc = np.ascontiguousarray(ppc, dtype=np.float64)
    pcov = np.ascontiguousarray(pcov, dtype=np.float64)
    pcol = np.ascontiguousarray(pcol, dtype=np.float32)
    for name, a, rows in (("pc", ppc, 3), ("cov", pcov, 6), ("colours", pcol, 3)):
        if a.shape != (rows, mp):
            raise RenderError(f"fast backend: SplatPass.transform: {name}: expected shape ({rows}, {mp}), "
                              f"found {a.shape}")
    return ppc, pcov, pcol


class _Draw:
    """Projection, binning and compositing of chunks of views, with the counters of a render."""

    def __init__(self, config: RenderConfig, workspace: _Workspace, cpp, threads: int, W: int, H: int,  # noqa: ANN001
                 near: float, n: int, timings: dict[str, float]) -> None:
        self.config, self.workspace, self.cpp, self.threads = config, workspace, cpp, threads
        self.W, self.H, self.near = W, H, near
        self.tile = int(config.tile_size)
        self.tiles_x, self.tiles_y = -(-W // self.tile), -(-H // self.tile)
        self.timings = timings
        self.n = n
        #: (order, seen) of each chunk: which of the ordered splats any of its views drew (n_visible)
        self.seen: list[tuple[np.ndarray, np.ndarray]] = []
        self.blends = self.entries = self.tiles = 0
        self.path = ""
        self.cull = -1.0 if config.cull_margin is None else float(config.cull_margin)

    def cpp_views(self, sorted_in: tuple, m: int, degree: int, shared: bool, cams: np.ndarray, out: np.ndarray,
                  jobs: np.ndarray | None, count_blends: bool = True,
                  slits: tuple[np.ndarray, np.ndarray, float | None] | None = None,
                  view_keep: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """One chunk of views through the C++ extension (projection and binning fused, buffers reused),
        with ``slits`` = (their camera parameters, their images, their t_min or None for the
        config's) projected in the same pass and composited into their own images; ``view_keep``
        ((n views, N) bool, the depth order (m,)): the Gaussians each (non-slit) view draws; returns
        which of the m sorted splats any view drew."""
        c, n_main = self.config, len(cams)
        if slits is not None:
            cams = np.concatenate((cams, slits[0]))
        nv = len(cams)
        n_tiles = self.tiles_x * self.tiles_y
        t3 = time.perf_counter()
        rec = self.workspace.records(nv, m)
        off = np.empty((nv, n_tiles + 1), dtype=np.int64)
        base = np.empty(nv, dtype=np.int64)
        seen = np.empty(m, dtype=np.uint8)
        mp = sorted_in[3].size
        vm: tuple = ()
        if view_keep is not None:  # (views, mp) uint8 rows in depth order, the sorted inputs' stride
            rows, order = view_keep
            vmask = self.workspace.buffer("view_keep", (n_main, mp), np.uint8)
            np.take(rows.view(np.uint8), order, axis=1, out=vmask[:, :m])  # 0.4 ms against 1.2 (index, copy)
            vmask[:, m:] = 0
            vm = (vmask, n_main)
        while True:
            ids_buf = self.workspace.ids()
            total, fill_s = self.cpp.project_bin(*sorted_in, cams, m, mp, nv, self.W, self.H,
                                                 degree, int(shared), self.tile, self.tiles_x, self.tiles_y,
                                                 self.near, float(c.dilation), float(c.radius_sigmas),
                                                 float(c.alpha_threshold), self.cull, rec, off, base, seen,
                                                 ids_buf, self.threads, *vm)
            if total <= ids_buf.size:
                break
            self.workspace.grow_ids(total)
        ids = ids_buf[:total]
        t4 = time.perf_counter() - fill_s  # the fused pass counts as project, filling the lists as bin
        t5 = time.perf_counter()
        blends = np.zeros(max(n_main, 1) * n_tiles, dtype=np.int64)
        bg = np.asarray(c.background, dtype=np.float32)
        parts = ((0, n_main, out, jobs, blends, float(c.t_min)),
                 (n_main, nv, None if slits is None else slits[1], None,
                  np.zeros((nv - n_main) * n_tiles, dtype=np.int64),
                  float(c.t_min if slits is None or slits[2] is None else slits[2])))
        for lo, hi, img, sel, bl, t_min in parts:
            if hi > lo:  # the views, then the slit views into their own images (records of one pass)
                self.path = self.cpp.composite(rec[lo:hi], off[lo:hi], base[lo:hi], ids, hi - lo, m, self.tile,
                                               self.tiles_x, self.tiles_y, self.W, self.H, float(c.alpha_threshold),
                                               float(c.alpha_cap), t_min, bg, bool(c.clip_output), img, bl,
                                               self.threads, _CPP_MODE,
                                               np.empty(0, dtype=np.int32) if sel is None else sel)
        t6 = time.perf_counter()
        self._count(ids.size, blends, n_main * n_tiles if jobs is None else jobs.size, count_blends)
        self.timings["project"] += t4 - t3
        self.timings["bin"] += t5 - t4
        self.timings["composite"] += t6 - t5
        return seen

    def numba_views(self, order: np.ndarray, pc: np.ndarray, cov: np.ndarray, means: np.ndarray,
                    opacity: np.ndarray, sh: np.ndarray, degree: int, shared_rgb: np.ndarray, shared: bool,
                    cams: np.ndarray, out: np.ndarray, mask: np.ndarray | None, count_blends: bool = True,
                    t_min: float | None = None, view_keep: np.ndarray | None = None) -> np.ndarray:
        """One chunk of views through the numba kernels (every tile composited; a mask keeps its
        tiles; ``view_keep`` (views, m) bool in depth order: the splats each view draws, the
        others' boxes made empty as the C++ pass writes them); returns which of the ordered
        splats any view drew."""
        from . import fast_kernels as fk

        c, nv = self.config, len(cams)
        tile, W, H = self.tile, self.W, self.H
        t3 = time.perf_counter()
        rec, box = _records(nv, order.size)
        seen = fk.project_views(order, pc, cov, means, opacity, sh, degree, shared_rgb, shared, cams, W, H,
                                self.near, float(c.dilation), float(c.radius_sigmas), float(c.alpha_threshold),
                                self.cull, rec, box)
        if view_keep is not None:
            drop = ~view_keep
            box[..., 1][drop] = box[..., 0][drop]
            drawn = (box[..., 0] < box[..., 1]) & (box[..., 2] < box[..., 3])
            seen = drawn.any(axis=0).astype(seen.dtype)
        t4 = time.perf_counter()
        off = fk.count_tiles(rec, box, tile, self.tiles_x, self.tiles_y)
        base = np.zeros(nv, dtype=np.int64)
        base[1:] = np.cumsum(off[:-1, -1])
        ids = np.empty(int(off[:, -1].sum()), dtype=np.int32)
        fk.fill_tiles(rec, box, tile, self.tiles_x, off, base, ids)
        t5 = time.perf_counter()
        target = out
        if mask is not None:  # the numba compositor does every tile: keep only the masked ones
            out = np.empty((nv, H, W, 3), np.float32)
        blends = np.zeros(nv * self.tiles_x * self.tiles_y, dtype=np.int64)
        fk.composite(rec, box, off, base, ids, tile, self.tiles_x, self.tiles_y, W, H,
                     float(c.alpha_threshold), float(c.alpha_cap), float(c.t_min if t_min is None else t_min),
                     np.asarray(c.background, dtype=np.float32), bool(c.clip_output), out, blends)
        if mask is not None:
            px = np.repeat(np.repeat(mask, tile, axis=1), tile, axis=2)[:, :H, :W]
            np.copyto(target, out, where=px[..., None])
        t6 = time.perf_counter()
        self._count(ids.size, blends, nv * self.tiles_x * self.tiles_y if mask is None else int(mask.sum()),
                    count_blends)
        self.timings["project"] += t4 - t3
        self.timings["bin"] += t5 - t4
        self.timings["composite"] += t6 - t5
        return seen

    def n_visible(self) -> int:
        """How many splats any view drew: the union of the chunks' drawn splats; one chunk's count of its
        own (a depth order lists each splat once), without the (N,) union (~0.3 ms a live frame)."""
        if len(self.seen) == 1:
            return int(np.count_nonzero(self.seen[0][1]))
        visible = np.zeros(self.n, dtype=bool)
        for order, seen in self.seen:
            visible[order[seen.astype(bool)]] = True
        return int(visible.sum())

    def _count(self, entries: int, blends: np.ndarray, tiles: int, count_blends: bool) -> None:
        if count_blends:  # a pass's images are not the cameras' statistics
            self.entries += entries
            self.tiles += tiles
            self.blends += int(blends.sum())
