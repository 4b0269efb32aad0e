"""Views -> uint8 quilt -> native image: the one function every caller goes through (pure array code).

:func:`views_to_native` is the chain written once: float views are rounded to uint8 straight into
their quilt tiles (:func:`holo_viewer.images.to_uint8`, tile layout of
:func:`holo_viewer.display.quilt.tile_slices`), and the quilt is interleaved into the panel's
native image (:class:`~holo_viewer.display.lenticular.Interleaver`). The export path (the
pipeline's ``quilt`` and ``native`` stages, the GUI's exports, ``quilt-to-native`` and ``show`` on
quilt files), the live frames
(:class:`holo_viewer.pipeline.live.NativeFrameRenderer`: every view, synthesized views, the tracked
frames' tile columns) and the GPU path (views on a torch device gathered by a
:class:`~holo_viewer.display.device.DeviceInterleaver`, no quilt built) all call it; they differ
only in which part of the chain they ask for:

=======================================  ============================================================
call                                     does
=======================================  ============================================================
``views_to_native(views, interleaver)``  every view -> quilt -> native
``views_to_native(views, (cols, rows))`` every view -> quilt (no native)
``views_to_native(None, interleaver,     the given quilt -> native
quilt=q)``
``tiles=``                               views fill these quilt tiles (the others are left as they are)
``columns=ColumnUpdate(mask, block)``    only these tile columns of the views -> quilt -> the native
                                         subpixels that read them (the rest is kept)
torch ``views`` + DeviceInterleaver      one gather on the device -> native (no quilt)
=======================================  ============================================================

Rounding is :func:`~holo_viewer.images.to_uint8`'s everywhere (``rint(255 x)``, clipped), so the
paths give the same bytes (tests/test_views_to_native.py checks each form against outputs saved
before the callers were moved onto this function, and spies on every caller). The per-eye scatters of
tracked frames (:mod:`holo_viewer.display.slices`, :func:`holo_viewer.display.eyes.scatter_eye_images`)
are not this chain: they write subpixels from per-eye images, not from views. Nor are synthesized frames
on the CPU (``NativeFrameRenderer.warp_native``, the default): the warp writes each native subpixel itself
(:func:`holo_viewer.render.view_synthesis.warp_views` ``native=``), the bytes of this chain (tested);
with ``warp_native`` off they take the chain.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..errors import InputError
from ..images import to_uint8
from .quilt import tile_slices

__all__ = ["views_to_native", "ColumnUpdate", "Composed", "Progress"]

#: ``progress(done, total, unit)``: ``done`` of ``total`` ``unit`` ("tiles", "native") finished
Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class ColumnUpdate:
    """Only some tile columns of the views changed (a tracked frame).

    Attributes
    ----------
    mask : numpy.ndarray
        (V, tiles_x) bool: tile column ``c`` of view ``k`` (texel columns ``[c block, (c+1) block)``)
        is new.
    block : int
        Texel columns per tile column (the renderer's tile size).
    sparse : bool
        A few columns (a tracked frame's round-robin refresh): update the native subpixels through
        the interleaver's per-column reader lists (:meth:`Interleaver.readers`) instead of one pass
        over every subpixel (:meth:`Interleaver.update_columns`, faster from ~10 % of the columns).
        Same bytes either way.
    """

    mask: np.ndarray
    block: int
    sparse: bool = False


@dataclass
class Composed:
    """What :func:`views_to_native` made.

    Attributes
    ----------
    quilt : numpy.ndarray or None
        (rows H, cols W, 3) uint8 quilt (None on the device path).
    native : numpy.ndarray or torch.Tensor or None
        (screen_h, screen_w, 3) uint8 native image (None for a quilt-only call).
    seconds : dict
        Wall seconds of the parts that ran: ``quilt`` (rounding into tiles), ``interleave``.
    """

    quilt: np.ndarray | None
    native: Any
    seconds: dict[str, float] = field(default_factory=dict)


def _is_torch(x: Any) -> bool:
    return type(x).__module__.split(".")[0] == "torch"


def views_to_native(views: Any, target: Any, *, quilt: np.ndarray | None = None, native: Any = None,
                    tiles: Sequence[int] | None = None, columns: ColumnUpdate | None = None,
                    progress: Progress | None = None) -> Composed:
    """Float views -> uint8 quilt -> native image (see the module docstring for the forms).

    Parameters
    ----------
    views : numpy.ndarray or torch.Tensor or None
        (V, H, W, 3) float views in [0, 1] (or uint8), view 0 leftmost; a torch tensor goes to a
        :class:`~holo_viewer.display.device.DeviceInterleaver` ``target``; None: interleave the
        given ``quilt``.
    target : Interleaver or DeviceInterleaver or tuple of int
        The panel's interleaver (quilt and native), or ``(cols, rows)`` for the quilt alone.
    quilt : numpy.ndarray, optional
        (rows H, cols W, 3) uint8 quilt written in place (its other tiles are kept); the input when
        ``views`` is None. Default: a new quilt, unused tiles zero.
    native : numpy.ndarray, optional
        (screen_h, screen_w, 3) uint8 output, written in place (with ``columns``: only the subpixels
        that read the new columns; the rest must hold the previous frame).
    tiles : sequence of int, optional
        The quilt tile of each view (default ``0 .. V-1``).
    columns : ColumnUpdate, optional
        Only these tile columns of the views are new.
    progress : callable, optional
        ``progress(done, total, unit)`` after each tile and after the interleave.

    Returns
    -------
    Composed

    Raises
    ------
    InputError
        Shapes that do not fit the layout or the interleaver; ExportError for NaN/inf views.
    """
    from .device import DeviceInterleaver

    seconds: dict[str, float] = {}
    if _is_torch(views):
        if not isinstance(target, DeviceInterleaver):
            raise InputError(f"target: device views need a DeviceInterleaver, found {type(target).__name__}")
        t = time.perf_counter()
        res = target(views, out=native)
        seconds["interleave"] = time.perf_counter() - t
        if progress is not None:
            progress(1, 1, "native")
        return Composed(None, res, seconds)
    if isinstance(target, DeviceInterleaver):
        raise InputError("views: a DeviceInterleaver takes torch tensors on its device; found "
                         f"{type(views).__name__}")
    layout_only = isinstance(target, tuple)
    cols, rows = (int(target[0]), int(target[1])) if layout_only else (target.cols, target.rows)
    if views is not None:
        quilt = _to_quilt(views, cols, rows, quilt, tiles, columns, progress, seconds)
    elif quilt is None:
        raise InputError("quilt: expected the quilt to interleave when views is None")
    if layout_only:
        return Composed(quilt, None, seconds)
    t = time.perf_counter()
    if columns is None:
        native = target(quilt, out=native)
    elif native is None:
        raise InputError("native: a column update writes into the previous native image; none given")
    elif columns.sparse:
        if columns.mask.any():
            target.update(quilt, native, target.readers(columns.mask, block=columns.block))
    else:
        target.update_columns(quilt, native, columns.mask, block=columns.block)
    seconds["interleave"] = time.perf_counter() - t
    if progress is not None:
        progress(1, 1, "native")
    return Composed(quilt, native, seconds)


def _to_quilt(views: np.ndarray, cols: int, rows: int, quilt: np.ndarray | None, tiles: Sequence[int] | None,
              columns: ColumnUpdate | None, progress: Progress | None, seconds: dict[str, float]) -> np.ndarray:
    """Round ``views`` into their quilt tiles (or the tile columns of ``columns``); returns the quilt."""
    t = time.perf_counter()
    views = np.asarray(views)
    if views.ndim != 4 or views.shape[3] != 3:
        raise InputError(f"views: expected shape (V, H, W, 3), found {views.shape}")
    for name, v in (("cols", cols), ("rows", rows)):
        if v < 1:
            raise InputError(f"{name}: expected a positive integer, found {v}")
    V, H, W, _ = views.shape
    tiles = list(range(V)) if tiles is None else [int(k) for k in tiles]
    if len(tiles) != V or (V and (min(tiles) < 0 or max(tiles) >= cols * rows)):
        raise InputError(f"tiles: expected {V} tiles in 0..{cols * rows - 1}, found {tiles}")
    if quilt is None:
        quilt = np.zeros((rows * H, cols * W, 3), dtype=np.uint8)
    elif quilt.shape != (rows * H, cols * W, 3) or quilt.dtype != np.uint8:
        raise InputError(f"quilt: expected a ({rows * H}, {cols * W}, 3) uint8 array for {cols}x{rows} tiles "
                         f"of {W}x{H}, found {quilt.dtype} {quilt.shape}")
    Hq, Wq, _ = quilt.shape
    todo = [(i, k) for i, k in enumerate(tiles) if columns is None or columns.mask[k].any()]
    for n, (i, k) in enumerate(todo):
        rs, cs = tile_slices(Hq, Wq, cols, rows, k)
        if columns is None:
            to_uint8(views[i], out=quilt[rs, cs], name=f"views[{i}]")
        else:  # runs of new tile columns
            on = np.concatenate(([False], columns.mask[k], [False]))
            starts = np.flatnonzero(on[1:] & ~on[:-1])
            ends = np.flatnonzero(~on[1:] & on[:-1])
            for a, b in zip(starts * columns.block, np.minimum(ends * columns.block, W)):
                to_uint8(views[i, :, a:b], out=quilt[rs, cs.start + a:cs.start + b], name=f"views[{i}]")
        if progress is not None:
            progress(n + 1, len(todo), "tiles")
    seconds["quilt"] = time.perf_counter() - t
    return quilt
