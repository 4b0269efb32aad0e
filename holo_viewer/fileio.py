"""Atomic file writes: a temp file in the target directory, fsync, then rename.

A failure (exception, crash, full disk) leaves any earlier file at the target
path untouched and no partial file behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import IO, Iterator

import numpy as np

from .errors import ExportError, HoloViewerError

__all__ = ["atomic_write", "atomic_path", "save_image", "load_image", "save_npz", "read_npz", "read_npy"]


def _target_mode(target: Path) -> int:
    """Permission bits for a new file: the existing target's, else 0o666 minus the umask.

    ``mkstemp`` creates files readable by the owner only; outputs should get the usual mode.
    """
    if target.exists():
        return target.stat().st_mode & 0o7777
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    Use for writers that want a file name (ffmpeg, trimesh, numpy). The temporary
    file keeps the target's suffix so format detection by extension still works.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    suf = target.suffix if suffix is None else suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{suf}", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if not tmp_path.exists() or tmp_path.stat().st_size == 0:
            raise ExportError(f"{target}: writer produced no data")
        os.chmod(tmp_path, _target_mode(target))
        os.replace(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file for writing; on success fsync and rename it onto ``path``."""
    if "w" not in mode:
        raise ValueError(f"atomic_write: mode must be a write mode, found {mode!r}")
    with atomic_path(path) as tmp:
        with open(tmp, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())


def _to_uint8(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    if not np.issubdtype(img.dtype, np.floating):
        raise ExportError(f"image: expected uint8 or float in [0, 1], found dtype {img.dtype}")
    if not np.all(np.isfinite(img)):
        raise ExportError("image: contains NaN/inf values; refusing to write a wrong picture")
    return np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)


def save_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an (H, W, 3|4) image (uint8, or float in [0, 1]) atomically; format from the suffix."""
    from PIL import Image

    img = _to_uint8(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3, 4)):
        raise ExportError(f"{path}: expected an image of shape (H, W), (H, W, 3) or (H, W, 4), found {img.shape}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    target = Path(path)
    fmt = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".bmp": "BMP", ".tif": "TIFF",
           ".tiff": "TIFF"}.get(target.suffix.lower())
    if fmt is None:
        raise ExportError(f"{path}: unknown image suffix {target.suffix!r}; expected .png, .jpg, .bmp or .tif")
    with atomic_write(target) as fh:
        Image.fromarray(img).save(fh, format=fmt)
    return target


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float32 RGB in [0, 1], shape (H, W, 3)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            arr = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except FileNotFoundError as exc:
        raise ExportError(f"{path}: file not found") from exc
    except (UnidentifiedImageError, OSError) as exc:
        raise ExportError(f"{path}: not a readable image ({exc})") from exc
    return arr


def save_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    """``numpy.savez`` written atomically (uncompressed)."""
    target = Path(path)
    with atomic_write(target) as fh:
        np.savez(fh, **arrays)
    return target


@contextlib.contextmanager
def _reading(path: Path, error: type[HoloViewerError], what: str) -> Iterator[None]:
    """Map every way numpy can fail to read a file to ``error`` naming the file."""
    try:
        yield
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise error(f"{path}: expected {what}, found a directory") from None
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError) as exc:
        # a corrupt or truncated zip raises BadZipFile (not an OSError) at open and
        # zlib.error/EOFError when a member is read: all mean "not a readable file"
        raise error(f"{path}: cannot read {what} ({exc})") from None


def read_npz(path: str | os.PathLike, error: type[HoloViewerError] = HoloViewerError,
             what: str = "file") -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file, read eagerly (no pickles).

    Raises
    ------
    error
        ``"{path}: cannot read {what} (...)"`` for a missing, truncated or corrupt file.
    """
    with _reading(Path(path), error, what):
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError("expected an .npz archive, found a single .npy array")
        with z:
            return {k: z[k] for k in z.files}


def read_npy(path: str | os.PathLike, error: type[HoloViewerError] = HoloViewerError,
             what: str = "file") -> np.ndarray:
    """The array of an ``.npy`` file (no pickles); errors as :func:`read_npz`."""
    with _reading(Path(path), error, what):
        arr = np.load(path, allow_pickle=False)
        if not isinstance(arr, np.ndarray):
            arr.close()
            raise ValueError("expected a single .npy array, found an .npz archive")
        return arr
