"""Export quilts and native images (PNG) and quilt videos (mp4); every write is atomic."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import ExportError
from ..fileio import load_image, save_image
from .quilt import format_aspect, parse_quilt_filename, quilt_filename, split_quilt, tile_quilt

__all__ = ["save_quilt_png", "save_native_png", "write_quilt_video", "load_quilt", "quilt_path"]


def quilt_path(path_stem_or_dir: str | os.PathLike, cols: int, rows: int, aspect: float) -> Path:
    """Resolve where :func:`save_quilt_png` writes.

    * an existing directory (or a path ending in a separator): ``DIR/quilt_qs{c}x{r}a{aspect}.png``;
    * a name already tagged ``_qs..``: kept, after checking the tag matches ``cols, rows, aspect``;
    * otherwise a stem: ``STEM_qs{c}x{r}a{aspect}.png`` (a ``.png`` suffix is dropped first).
    """
    p = Path(path_stem_or_dir)
    if p.is_dir() or str(path_stem_or_dir).endswith(os.sep):
        return p / quilt_filename("quilt", cols, rows, aspect)
    if "_qs" in p.name:
        c, r, a = parse_quilt_filename(p.name)
        if (c, r) != (cols, rows) or format_aspect(a) != format_aspect(aspect):
            raise ExportError(f"{p}: name says {c}x{r} aspect {a:g}, but the quilt is {cols}x{rows} "
                              f"aspect {format_aspect(aspect)}")
        return p if p.suffix.lower() == ".png" else p.with_name(p.name + ".png")
    stem = p.name[:-4] if p.name.lower().endswith(".png") else p.name
    return p.with_name(quilt_filename(stem, cols, rows, aspect))


def save_quilt_png(path_stem_or_dir: str | os.PathLike, views_or_quilt: np.ndarray, cols: int, rows: int,
                   aspect: float) -> Path:
    """Write a quilt PNG named ``..._qs{cols}x{rows}a{aspect}.png``.

    Parameters
    ----------
    views_or_quilt : numpy.ndarray
        (V, H, W, 3) views (tiled here, view 0 bottom-left) or an (Hq, Wq, 3) quilt;
        uint8 or float in [0, 1].

    Returns
    -------
    pathlib.Path
        The file written.
    """
    arr = np.asarray(views_or_quilt)
    if arr.ndim == 4:
        arr = tile_quilt(arr, cols, rows)
    elif arr.ndim != 3:
        raise ExportError(f"views_or_quilt: expected (V, H, W, 3) views or an (H, W, 3) quilt, found {arr.shape}")
    target = quilt_path(path_stem_or_dir, cols, rows, aspect)
    return save_image(target, arr)


def save_native_png(path: str | os.PathLike, native: np.ndarray) -> Path:
    """Write a native (screen_h, screen_w, 3) image as PNG (lossless; never JPEG: it would blur subpixels)."""
    p = Path(path)
    if p.suffix.lower() != ".png":
        raise ExportError(f"{p}: native images must be written as .png (lossless), found suffix {p.suffix!r}")
    arr = np.asarray(native)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ExportError(f"native: expected shape (H, W, 3), found {arr.shape}")
    return save_image(p, arr)


def load_quilt(path: str | os.PathLike, cols: int | None = None, rows: int | None = None,
               n_views: int | None = None) -> tuple[np.ndarray, tuple[int, int, float]]:
    """Read a quilt file back into views.

    Returns
    -------
    views : numpy.ndarray
        (V, H, W, 3) float32 in [0, 1].
    layout : (int, int, float)
        (cols, rows, aspect); from the file name unless ``cols``/``rows`` are given.
    """
    img = load_image(path)
    if cols is None or rows is None:
        c, r, a = parse_quilt_filename(path)
        cols = c if cols is None else cols
        rows = r if rows is None else rows
    else:
        a = (img.shape[1] // cols) / (img.shape[0] // rows)
    return split_quilt(img, cols, rows, n_views), (int(cols), int(rows), float(a))


def write_quilt_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 30.0, *,
                      progress: bool = True, preset: str = "medium", crf: int = 0,
                      total: int | None = None) -> Path:
    """Encode quilt frames as RGB H.264 mp4 (libx264rgb; ``crf`` 0: lossless) via imageio-ffmpeg, atomically.

    The codec policy of :mod:`holo_viewer.media` for quilts: RGB without chroma subsampling, lossless
    by default (a decoded frame equals the quilt); ``crf`` > 0 trades exactness for size.

    Parameters
    ----------
    frames : iterable of numpy.ndarray
        (Hq, Wq, 3) quilts, uint8 or float in [0, 1], all the same size (any size: RGB needs no
        even sides).
    fps : float
        Frames per second.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    pathlib.Path
    """
    from tqdm import tqdm

    from ..media import VideoWriter

    p = Path(path)
    if p.suffix.lower() != ".mp4":
        raise ExportError(f"{p}: expected an .mp4 file name")
    if not fps > 0:
        raise ExportError(f"fps: expected > 0, found {fps}")
    if total is None and hasattr(frames, "__len__"):
        total = len(frames)  # type: ignore[arg-type]
    # verified before the rename: ffmpeg's exit status and the decoded frame count (holo_viewer.media)
    with VideoWriter(p, fps, content="lossless", output_params=["-preset", preset, "-crf", str(int(crf))],
                     what="quilt video") as writer:
        for frame in tqdm(frames, total=total, disable=not progress, desc=f"encoding {p.name}", unit="frame"):
            writer.write(frame)
    return p
