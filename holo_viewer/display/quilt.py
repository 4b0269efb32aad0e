"""Quilts: V views tiled ``cols`` x ``rows`` into one image (pure array code).

Convention (docs/design.md section 3): view 0 = leftmost camera = bottom-left tile; views run left to
right, then bottom to top; the last view is top-right. Arrays are (H, W, C) with row 0 at the top,
so tile ``(c, r)`` (column c, row r counted from the bottom) of a quilt ``Hq x Wq`` with tiles
``th = Hq // rows``, ``tw = Wq // cols`` occupies rows ``[Hq - (r+1) th, Hq - r th)`` and columns
``[c tw, (c+1) tw)``. Unused pixels of a non-multiple quilt are the top rows and right columns.
File names carry the layout: ``NAME_qs{cols}x{rows}a{aspect}.png`` (e.g. ``_qs8x6a0.75``).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..images import to_uint8  # the one converter (re-exported here for its users)

__all__ = ["tile_quilt", "split_quilt", "quilt_filename", "parse_quilt_filename", "tile_slices",
           "format_aspect", "to_uint8"]

_QS_RE = re.compile(r"_qs(\d+)x(\d+)a(\d+(?:\.\d+)?)", re.IGNORECASE)


def tile_slices(quilt_h: int, quilt_w: int, cols: int, rows: int, view: int) -> tuple[slice, slice]:
    """(row slice, column slice) of view ``view``'s tile in a quilt array."""
    th, tw = quilt_h // rows, quilt_w // cols
    c, r = view % cols, view // cols
    return slice(quilt_h - (r + 1) * th, quilt_h - r * th), slice(c * tw, (c + 1) * tw)


def _check_layout(cols: int, rows: int) -> None:
    for name, v in (("cols", cols), ("rows", rows)):
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise InputError(f"{name}: expected a positive integer, found {v!r}")


def tile_quilt(views: np.ndarray, cols: int, rows: int, *, as_uint8: bool = False) -> np.ndarray:
    """Tile views into a quilt.

    Parameters
    ----------
    views : numpy.ndarray
        (V, H, W, C) views, view 0 leftmost, any dtype; V <= cols * rows.
    cols, rows : int
        Quilt layout.
    as_uint8 : bool
        Convert float views in [0, 1] (C = 3) with :func:`to_uint8` while tiling, one view at a time,
        so no full-size float temporary is made (a 48-view 420x560 quilt: ~20 ms instead of ~50 ms
        for converting first and tiling after): :func:`holo_viewer.display.native.views_to_native`,
        the one views -> uint8 quilt -> native path. uint8 views are copied as they are.

    Returns
    -------
    numpy.ndarray
        (rows * H, cols * W, C) quilt of the views' dtype (uint8 with ``as_uint8``); unused tiles
        (V < cols*rows) are zero.
    """
    _check_layout(cols, rows)
    views = np.asarray(views)
    if views.ndim != 4:
        raise InputError(f"views: expected shape (V, H, W, C), found {views.shape}")
    V, H, W, C = views.shape
    if V < 1 or V > cols * rows:
        raise InputError(f"views: expected 1..{cols * rows} views for a {cols}x{rows} quilt, found {V}")
    if as_uint8:
        from .native import views_to_native

        return views_to_native(views, (cols, rows)).quilt
    quilt = np.empty((rows * H, cols * W, C), dtype=views.dtype)
    for v in range(cols * rows):  # tile by tile: each view is read once, nothing is transposed
        ys, xs = tile_slices(rows * H, cols * W, cols, rows, v)
        quilt[ys, xs] = 0 if v >= V else views[v]
    return quilt


def split_quilt(quilt: np.ndarray, cols: int, rows: int, n_views: int | None = None) -> np.ndarray:
    """Inverse of :func:`tile_quilt`: (n_views, Hq // rows, Wq // cols, C) views (a copy).

    ``n_views`` defaults to ``cols * rows``. Quilts that are not an exact multiple of the tile
    size are read from the bottom-left corner (unused top rows / right columns are ignored).
    """
    _check_layout(cols, rows)
    quilt = np.asarray(quilt)
    if quilt.ndim == 2:
        quilt = quilt[:, :, None]
    if quilt.ndim != 3:
        raise InputError(f"quilt: expected shape (H, W, C), found {quilt.shape}")
    Hq, Wq, C = quilt.shape
    th, tw = Hq // rows, Wq // cols
    if th < 1 or tw < 1:
        raise InputError(f"quilt: {Wq}x{Hq} pixels cannot hold {cols}x{rows} tiles")
    n = cols * rows if n_views is None else int(n_views)
    if not 1 <= n <= cols * rows:
        raise InputError(f"n_views: expected 1..{cols * rows}, found {n_views}")
    used = quilt[Hq - rows * th:, : cols * tw]
    grid = used.reshape(rows, th, cols, tw, C).transpose(0, 2, 1, 3, 4)[::-1]
    return np.ascontiguousarray(grid.reshape(rows * cols, th, tw, C)[:n])


def format_aspect(aspect: float) -> str:
    """Aspect as written in quilt names: up to 4 decimals, trailing zeros dropped (0.75, 1.7778)."""
    if not (np.isfinite(aspect) and aspect > 0):
        raise InputError(f"aspect: expected a positive number, found {aspect!r}")
    s = f"{aspect:.4f}".rstrip("0").rstrip(".")
    return s


def quilt_filename(stem: str, cols: int, rows: int, aspect: float, suffix: str = ".png") -> str:
    """``{stem}_qs{cols}x{rows}a{aspect}{suffix}``, e.g. ``face_qs8x6a0.75.png``."""
    _check_layout(cols, rows)
    return f"{stem}_qs{int(cols)}x{int(rows)}a{format_aspect(aspect)}{suffix}"


def parse_quilt_filename(name: str | Path) -> tuple[int, int, float]:
    """(cols, rows, aspect) from a quilt file name (the last ``_qs{c}x{r}a{aspect}`` in it).

    Raises
    ------
    InputError
        When the name carries no ``_qs{cols}x{rows}a{aspect}`` tag or the values are invalid.
    """
    base = Path(name).name
    matches = list(_QS_RE.finditer(base))
    if not matches:
        raise InputError(f"{base}: expected a quilt name containing _qs{{cols}}x{{rows}}a{{aspect}} "
                         f"(e.g. face_qs8x6a0.75.png); pass --cols/--rows instead")
    m = matches[-1]
    cols, rows, aspect = int(m.group(1)), int(m.group(2)), float(m.group(3))
    if cols < 1 or rows < 1 or aspect <= 0:
        raise InputError(f"{base}: invalid quilt tag {m.group(0)!r} (cols, rows and aspect must be positive)")
    return cols, rows, aspect
