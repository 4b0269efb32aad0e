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

import numpy as np

from ..avatar.gaussians import Gaussians
from ..camera import Cameras
from ..errors import RenderError
from .config import RenderConfig, RenderResult
from .projection import clamp_limits

__all__ = ["render", "tile_grid", "cpp_available", "kernel_names", "release_buffers"]

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
        self.depth_hints: dict[int, np.ndarray] = {}  # per camera group: the last full depth order
        self.lock = threading.Lock()

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
        return int(self._rec.nbytes + self._ids.nbytes)

    def release(self) -> None:
        """Drop the buffers (memory goes back to the system)."""
        self._rec = np.empty(0, dtype=np.float32)
        self._ids = np.empty(0, dtype=np.int32)
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
        ``range(N)`` is correct). Consecutive frames move little, so ``z[hint]`` is nearly sorted
        and numpy's stable sort (timsort) runs through it in ~1 ms instead of ~7 ms for 100k
        splats. The result does not depend on the hint: runs of equal depths are put back in
        index order afterwards.

    Returns
    -------
    order : numpy.ndarray
        (keep.sum(),) int64 indices.
    full : numpy.ndarray
        (N,) the order of all splats: the next frame's hint.
    """
    if hint is None or hint.shape != z.shape:
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


def _view_params(cameras: Cameras, views: np.ndarray, rects: np.ndarray | None = None) -> np.ndarray:
    """(len(views), 18) float64 per-view parameters of the projection kernels (project_views docs).

    ``rects``: (V, 4) pixel rectangles x0, x1, y0, y1 (all cameras) the splat boxes are clipped
    to; None = the image."""
    W, H = cameras.width, cameras.height
    cams = np.empty((len(views), 18))
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


def _sorted_inputs(order: np.ndarray, pc: np.ndarray, cov: np.ndarray, means: np.ndarray, opacity: np.ndarray,
                   colours: np.ndarray, alpha_threshold: float) -> tuple[np.ndarray, ...]:
    """Depth-ordered inputs of ``_splat_cpp.project_bin``: pc, cov, means, opacity, q, colours.

    Structure of arrays (one row per component) with a row length ``mp`` = m rounded up to a
    multiple of 8 (the kernel projects 8 splats at a time; the padding has opacity 0, so it is
    never drawn). colours: (N, nk, 3) SH coefficients (rows j * 3 + channel), or (N, 3) shared
    colours. q = 2 ln(opacity / threshold).
    """
    from . import fast_kernels as fk

    m = order.size
    mp = -(-m // 8) * 8

    def soa(a: np.ndarray, dtype: type) -> np.ndarray:
        a = np.ascontiguousarray(a.reshape(len(a), -1), dtype=dtype)
        out = np.empty((a.shape[1], mp), dtype=dtype)
        out[:, m:] = 0
        fk.gather_soa(a, order, out)
        return out

    op = soa(opacity, np.float64)[0]
    q = 2.0 * (np.log(np.maximum(op, 1e-300)) - math.log(alpha_threshold))  # padding: op = 0, never drawn
    return soa(pc, np.float64), soa(cov, np.float64), soa(means, np.float64), op, q, soa(colours, np.float32)


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
           tile_mask: np.ndarray | None = None, out: np.ndarray | None = None) -> RenderResult:
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

    Returns
    -------
    RenderResult
        images (V, H, W, 3) float32 (``out`` when given); timings "preprocess", "sort", "project",
        "bin", "composite", "total"; stats n_input, n_visible, mean_blends_per_pixel, threads,
        kernel, rendered_tiles.
    """
    config = config or RenderConfig()
    mask, rects = _check_region(cameras, config, tile_mask, out)
    shared = _SHARED_WORKSPACE.lock.acquire(blocking=False)
    try:
        return _render(gaussians, cameras, config, _SHARED_WORKSPACE if shared else _Workspace(),
                       mask, rects, out)
    finally:
        if shared:
            if _SHARED_WORKSPACE.nbytes() > _KEEP_AT_MOST:  # a huge scene: do not hold its buffers
                _SHARED_WORKSPACE.release()
            _SHARED_WORKSPACE.lock.release()


def _runs(views: np.ndarray) -> list[np.ndarray]:
    """Split sorted view indices into runs of consecutive indices."""
    if views.size == 0:
        return []
    cut = np.flatnonzero(np.diff(views) != 1) + 1
    return np.split(views, cut)


def _render(gaussians: Gaussians, cameras: Cameras, config: RenderConfig, workspace: _Workspace,
            mask: np.ndarray | None = None, rects: np.ndarray | None = None,
            out_images: np.ndarray | None = None) -> RenderResult:
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

    g = gaussians.numpy()
    means = np.ascontiguousarray(g.means, dtype=np.float64)
    quats = np.ascontiguousarray(g.quats, dtype=np.float64)
    log_scales = np.ascontiguousarray(g.log_scales, dtype=np.float64)
    opacity = (1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64))))
    degree = g.sh_degree if config.sh_degree is None else min(g.sh_degree, int(config.sh_degree))
    sh = np.ascontiguousarray(np.asarray(g.sh)[:, : (degree + 1) ** 2], dtype=np.float32)
    near = cameras.near if config.near is None else float(config.near)
    V, H, W = len(cameras), cameras.height, cameras.width
    tile = int(config.tile_size)
    tiles_x, tiles_y = -(-W // tile), -(-H // tile)
    n_tiles = tiles_x * tiles_y
    if out_images is not None:
        images = out_images
    elif mask is not None:
        images = np.zeros((V, H, W, 3), dtype=np.float32)
    else:
        images = _OUTPUTS.empty((V, H, W, 3))
    active = np.ones(V, dtype=bool) if mask is None else mask.any(axis=(1, 2))
    no_jobs = np.empty(0, dtype=np.int32)
    bg = np.asarray(config.background, dtype=np.float32)
    cull = -1.0 if config.cull_margin is None else float(config.cull_margin)
    positions = cameras.positions
    if config.shared_sh:
        from .reference import view_colors

        shared_rgb = view_colors(means, sh.astype(np.float64), degree, positions.mean(axis=0)).astype(np.float32)
    else:
        shared_rgb = np.zeros((1, 3), dtype=np.float32)
    total_blends = 0
    total_entries = 0
    rendered_tiles = 0
    path = ""
    n_visible_mask = np.zeros(len(g), dtype=bool)
    timings["preprocess"] += time.perf_counter() - t_start

    for gi, group in enumerate(_groups(cameras)):
        group = group[active[group]]
        if group.size == 0:
            continue
        t0 = time.perf_counter()
        Wrot = np.ascontiguousarray(cameras.R[group[0]])
        pc, cov = fk.prep_3d(means, quats, log_scales, Wrot)
        tvec = cameras.t[group]
        front = (pc[:, 2] + tvec[:, 2].max()) > near
        t1 = time.perf_counter()
        order, workspace.depth_hints[gi] = depth_order(pc[:, 2], front, workspace.depth_hints.get(gi))
        m = order.size
        if use_cpp:  # depth-ordered copies: the C++ pass reads every input sequentially
            sorted_in = _sorted_inputs(order, pc, cov, means, opacity, shared_rgb if config.shared_sh else sh,
                                       float(config.alpha_threshold))
        t2 = time.perf_counter()
        timings["preprocess"] += t1 - t0
        timings["sort"] += t2 - t1  # the depth sort and the depth-ordered copies
        chunk = max(1, min(len(group), int(config.max_chunk_bytes // max(1, m * _BYTES_PER_SPLAT_VIEW))))
        chunks = [r[c0:c0 + chunk] for r in (_runs(np.sort(group)) if mask is not None else [group])
                  for c0 in range(0, len(r), chunk)]
        for views in chunks:
            t3 = time.perf_counter()
            cams = _view_params(cameras, views, rects)
            if use_cpp:  # projection and binning fused in one pass per view, buffers reused
                rec = workspace.records(len(views), m)
                off = np.empty((len(views), n_tiles + 1), dtype=np.int64)
                base = np.empty(len(views), dtype=np.int64)
                seen = np.empty(m, dtype=np.uint8)
                while True:
                    ids_buf = workspace.ids()
                    total, fill_s = cpp.project_bin(*sorted_in, cams, m, sorted_in[3].size, len(views), W, H,
                                                    degree, int(config.shared_sh), tile, tiles_x, tiles_y, near,
                                                    float(config.dilation), float(config.radius_sigmas),
                                                    float(config.alpha_threshold), cull, rec, off, base, seen,
                                                    ids_buf, threads)
                    if total <= ids_buf.size:
                        break
                    workspace.grow_ids(total)
                ids = ids_buf[:total]
                t4 = time.perf_counter() - fill_s  # the fused pass counts as project, filling the lists as bin
            else:
                rec, box = _records(len(views), m)
                seen = fk.project_views(order, pc, cov, means, opacity, sh, degree, shared_rgb,
                                        bool(config.shared_sh), cams, W, H, near, float(config.dilation),
                                        float(config.radius_sigmas), float(config.alpha_threshold), cull, rec, box)
                t4 = time.perf_counter()
                off = fk.count_tiles(rec, box, tile, tiles_x, tiles_y)
                base = np.zeros(len(views), dtype=np.int64)
                base[1:] = np.cumsum(off[:-1, -1])
                ids = np.empty(int(off[:, -1].sum()), dtype=np.int32)
                fk.fill_tiles(rec, box, tile, tiles_x, off, base, ids)
            n_visible_mask[order[seen.astype(bool)]] = True
            total_entries += ids.size
            t5 = time.perf_counter()
            contiguous = bool(np.all(np.diff(views) == 1))  # always, with a mask
            out = images[views[0]:views[-1] + 1] if contiguous else np.empty((len(views), H, W, 3), np.float32)
            blends = np.zeros(len(views) * n_tiles, dtype=np.int64)
            jobs = no_jobs
            if mask is not None:
                jobs = np.flatnonzero(mask[views].reshape(-1)).astype(np.int32)
                rendered_tiles += jobs.size
            else:
                rendered_tiles += len(views) * n_tiles
            if use_cpp:
                path = cpp.composite(rec, off, base, ids, len(views), m, tile, tiles_x, tiles_y, W, H,
                                     float(config.alpha_threshold), float(config.alpha_cap), float(config.t_min),
                                     bg, bool(config.clip_output), out, blends, threads, _CPP_MODE, jobs)
            else:
                target = out
                if mask is not None:  # the numba compositor does every tile: keep only the masked ones
                    out = np.empty((len(views), H, W, 3), np.float32)
                fk.composite(rec, box, off, base, ids, tile, tiles_x, tiles_y, W, H,
                             float(config.alpha_threshold), float(config.alpha_cap), float(config.t_min),
                             bg, bool(config.clip_output), out, blends)
                if mask is not None:
                    px = np.repeat(np.repeat(mask[views], tile, axis=1), tile, axis=2)[:, :H, :W]
                    np.copyto(target, out, where=px[..., None])
                    out = target
            if not contiguous:
                images[views] = out
            total_blends += int(blends.sum())
            t6 = time.perf_counter()
            timings["project"] += t4 - t3
            timings["bin"] += t5 - t4
            timings["composite"] += t6 - t5
    timings["total"] = time.perf_counter() - t_start
    stats = {"n_input": len(g), "n_visible": int(n_visible_mask.sum()),
             "mean_blends_per_pixel": total_blends / float(V * H * W), "threads": threads,
             "cpu_seconds": time.process_time() - cpu_start, "tile_entries": total_entries,
             "rendered_tiles": rendered_tiles}
    return RenderResult(images=images, timings=timings, stats=stats,
                        backend=f"fast/cpp-{path}" if use_cpp else "fast/numba")
