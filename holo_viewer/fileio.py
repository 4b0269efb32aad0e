"""Atomic file writes: a temp file in the target directory, fsync, then rename.

A failure (exception, crash, full disk) leaves any earlier file at the target
path untouched and no partial file behind. Every write of the package goes through
:func:`atomic_path` / :func:`atomic_write`, so one place turns an ``OSError`` (disk
full, permission denied, read-only file system, a parent that is a file) into an
:class:`~holo_viewer.errors.ExportError` naming the file and the reason
(:func:`write_error`, :func:`reporting_write_errors`, :func:`ensure_dir`).

A process killed while writing (SIGKILL, power loss) leaves its hidden temporary
``.{stem}.XXXXXXXX.tmp{suffix}`` behind; the next write of the same target removes
such files when they are older than the running process and no live writer holds
them (each writer keeps an advisory ``flock`` on its temporary while it writes).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
import stat
import tempfile
import time
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import IO, Callable, Iterator

import numpy as np

from .errors import ExportError, HoloViewerError

__all__ = ["atomic_write", "atomic_path", "save_image", "load_image", "save_npz", "read_npz", "read_npy",
           "write_error", "reporting_write_errors", "ensure_dir", "check_writable", "remove_stale_temps",
           "read_json", "write_json", "file_sha256", "parse_json", "check_json_depth", "read_limited", "MAX_JSON_BYTES", "MAX_JSON_DEPTH", "NPZ_BUDGET_BYTES"]

#: largest JSON file any reader parses (manifests, calibrations, sessions, scenarios, maps)
MAX_JSON_BYTES = 64 << 20
#: deepest JSON nesting accepted: our files need 4; Python's parser raises RecursionError near 1000
MAX_JSON_DEPTH = 64
#: uncompressed bytes one .npz read may produce (the largest shipped file, the ICT model, is 36 MB)
NPZ_BUDGET_BYTES = 1 << 30

#: wall-clock time this module was imported: temporaries older than this are not ours
_PROCESS_START = time.time()

_WRITE_REASONS = {
    errno.ENOSPC: "no space left on the device (the disk is full)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large (file-system or process file-size limit)",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.ENOTDIR: "a parent of the path is a file, not a directory",
    errno.EISDIR: "the path is a directory",
    errno.ENAMETOOLONG: "file name too long",
    errno.EIO: "input/output error",
}


def write_error(path: str | os.PathLike, exc: OSError, what: str = "file") -> ExportError:
    """The :class:`ExportError` every command reports when writing ``path`` failed with ``exc``.

    Names the file, the reason in words (disk full, permission denied, ...) and the errno,
    and states that an earlier file there is unchanged (writes are atomic).
    """
    reason = _WRITE_REASONS.get(exc.errno or -1)
    detail = exc.strerror or str(exc)
    if reason is None:
        reason = detail
    elif detail and exc.errno is not None:
        reason = f"{reason}; [Errno {exc.errno}] {detail}"
    return ExportError(f"{path}: cannot write the {what}: {reason} (nothing was written; an earlier file "
                       f"there is unchanged)")


@contextlib.contextmanager
def reporting_write_errors(path: str | os.PathLike, what: str = "file") -> Iterator[None]:
    """Turn an ``OSError`` raised inside the block into :func:`write_error` for ``path``."""
    try:
        yield
    except OSError as exc:
        raise write_error(path, exc, what) from exc


def ensure_dir(path: str | os.PathLike, what: str = "output directory", *,
               for_file: str | os.PathLike | None = None) -> Path:
    """Create directory ``path`` (and parents) if needed; ExportError when it cannot be one.

    ``for_file``: the file about to be written into ``path`` (the message then names it).

    Raises
    ------
    ExportError
        ``path`` or one of its parents exists as a file, or the directory cannot be
        created (permission, read-only file system, disk full).
    """
    p = Path(path)
    for anc in (p, *p.parents):
        if anc.exists() or anc.is_symlink():
            if not anc.is_dir():
                if for_file is not None:
                    raise ExportError(f"{for_file}: cannot write the file: {anc} is a file, not a directory")
                where = "it" if anc == p else f"its parent {anc}"
                raise ExportError(f"{p}: expected a directory for the {what}, but {where} is a file")
            break
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise write_error(p if for_file is None else for_file, exc, what if for_file is None else "file") from exc
    return p


def check_writable(path: str | os.PathLike, what: str = "file") -> Path:
    """Fail now, not after a long job, when ``path`` cannot be written.

    Creates the parent directory if needed and creates and removes a temporary file
    there (the kind :func:`atomic_path` writes). Disk space for the real output is not
    reserved: a disk that fills up later is still reported by the write itself.

    Raises
    ------
    ExportError
        ``path`` is a directory, a parent is a file, or the directory is not writable.
    """
    target = Path(path)
    if _destination_kind(target, what) == "stream":
        return target
    ensure_dir(target.parent, for_file=target)
    with reporting_write_errors(target, what):
        fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent)
        os.close(fd)
        os.unlink(tmp)
    return target


def _temp_pattern(target: Path, suffix: str) -> re.Pattern:
    """Names ``tempfile.mkstemp(prefix=f".{stem}.", suffix=f".tmp{suffix}")`` gives for ``target``."""
    return re.compile(rf"\.{re.escape(target.stem)}\.[A-Za-z0-9_]{{8}}\.tmp{re.escape(suffix)}")


def _try_lock(fd: int) -> bool:
    """Take an exclusive advisory lock without waiting; True if taken (or locks are unsupported)."""
    try:
        import fcntl
    except ImportError:  # Windows: the age rule alone decides
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def remove_stale_temps(target: Path, suffix: str) -> list[Path]:
    """Delete temporaries of ``target`` left by killed writers; returns the removed paths.

    A temporary is stale when its name has the pattern of ``target``'s temporaries, it is
    older than this process, and no writer holds its lock.
    """
    removed: list[Path] = []
    pattern = _temp_pattern(target, suffix)
    try:
        names = [n for n in os.listdir(target.parent) if pattern.fullmatch(n)]
    except OSError:
        return removed
    for name in names:
        tmp = target.parent / name
        try:
            if tmp.is_symlink() or not tmp.is_file() or tmp.stat().st_mtime >= _PROCESS_START:
                continue
            fd = os.open(tmp, os.O_RDONLY)
        except OSError:
            continue
        try:
            if _try_lock(fd):
                tmp.unlink()
                removed.append(tmp)
        except OSError:
            pass
        finally:
            os.close(fd)
    return removed


def _destination_kind(target: Path, what: str = "file") -> str:
    """``"new"``, ``"file"`` (regular, replaced by rename) or ``"stream"`` (FIFO or character device).

    A FIFO or character device (``/dev/null``, a terminal) is written through, as ``cp`` does:
    replacing it with a regular file would break it for every other user (as root, ``--out
    /dev/null`` would replace the system's ``/dev/null``).

    Raises
    ------
    ExportError
        The destination is a directory, socket or block device (never written nor replaced).
    """
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        return "new"
    except OSError:
        return "new"  # a dangling link, a parent that is a file: the write reports it
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
        return "stream"
    kind = ("a directory" if stat.S_ISDIR(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a block device" if stat.S_ISBLK(mode) else "not a regular file")
    raise ExportError(f"{target}: cannot write the {what}: the path is {kind}; refusing to write into or replace "
                      f"it (choose a file path)")


def _write_through(tmp_path: Path, target: Path) -> None:
    """Copy a finished temporary into an existing FIFO or character device (no rename, no truncation)."""
    with open(tmp_path, "rb") as src, open(target, "ab") as dst:
        shutil.copyfileobj(src, dst, 1 << 20)
        dst.flush()


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

    Raises
    ------
    ExportError
        The writer produced nothing, or any ``OSError`` while creating the directory,
        writing or renaming (:func:`write_error`: disk full, permission denied, ...).
        Any earlier file at ``path`` is unchanged and the temporary is removed.
    """
    target = Path(path)
    stream = _destination_kind(target) == "stream"
    if not stream:
        ensure_dir(target.parent, for_file=target)
    suf = target.suffix if suffix is None else suffix
    with reporting_write_errors(target):
        if not stream:
            remove_stale_temps(target, suf)
        # a FIFO or device is written through from a private temporary (its directory may be /dev)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{suf}",
                                   dir=None if stream else target.parent)
    tmp_path = Path(tmp)
    try:
        _try_lock(fd)  # tells remove_stale_temps of other processes that this one is alive
        with reporting_write_errors(target):
            yield tmp_path
            if not tmp_path.exists() or tmp_path.stat().st_size == 0:
                raise ExportError(f"{target}: writer produced no data")
            if stream:
                _write_through(tmp_path, target)
            else:
                os.chmod(tmp_path, _target_mode(target))
                os.replace(tmp_path, target)
    finally:
        try:
            if tmp_path.exists():
                tmp_path.unlink()
        finally:
            os.close(fd)


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


def file_sha256(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_json(path: str | os.PathLike, obj, *, indent: int = 2, default=None) -> Path:
    """Write ``obj`` as JSON atomically, creating the parent folder; returns the path (benches' results)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(target, "w") as fh:
        json.dump(obj, fh, indent=indent, default=default)
    return target


def save_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an (H, W, 3|4) image (uint8, or float in [0, 1]) atomically; format from the suffix."""
    from PIL import Image

    from .images import to_uint8

    img = to_uint8(image)
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


#: Pillow modes of 16-bit single-channel images (PNG gray 16): scaled by 1/65535
_MODES_16 = ("I;16", "I;16B", "I;16L", "I;16N")


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image as float32 RGB in [0, 1], shape (H, W, 3).

    8-bit images (gray, palette, RGB, RGBA: alpha dropped) are scaled by 1/255; 16-bit
    gray (PNG) by 1/65535 and repeated to RGB; 16-bit RGB(A) PNGs are read by Pillow at
    8 bits per channel (high byte). Other modes (32-bit integer or float) have no
    agreed range and are refused naming the mode, rather than clipped.

    Raises
    ------
    ExportError
        Missing, unreadable or unsupported image (the message names the file and mode).
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            mode = im.mode
            if mode in _MODES_16 or (mode == "I" and im.format == "PNG"):  # PNG 16-bit gray
                gray = np.asarray(im, dtype=np.float64)
                if gray.size and (gray.min() < 0 or gray.max() > 65535):
                    raise ExportError(f"{path}: 16-bit image with values outside [0, 65535] "
                                      f"(found {gray.min():g}..{gray.max():g})")
                arr = np.repeat((gray / 65535.0).astype(np.float32)[:, :, None], 3, axis=2)
            elif mode in ("I", "F") or mode.startswith(("I;", "F;")):
                raise ExportError(f"{path}: {'32-bit float' if mode.startswith('F') else 'integer'} image "
                                  f"(Pillow mode {mode!r}) has no defined [0, 1] range; expected an 8-bit or "
                                  f"16-bit gray/RGB/RGBA image")
            else:
                arr = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    except FileNotFoundError as exc:
        raise ExportError(f"{path}: file not found") from exc
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
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
    except HoloViewerError:
        raise
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise error(f"{path}: expected {what}, found a directory") from None
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError, NotImplementedError,
            RuntimeError) as exc:
        # a corrupt or truncated zip raises BadZipFile (not an OSError) at open and
        # zlib.error/EOFError when a member is read, NotImplementedError for an unknown compression
        # method and RuntimeError for an encrypted member: all mean "not a readable file"
        raise error(f"{path}: cannot read {what} ({exc})") from None


def read_json(path: str | os.PathLike, error: type[HoloViewerError] = HoloViewerError, what: str = "JSON file"):
    """The parsed content of a UTF-8 JSON file.

    Raises
    ------
    error
        ``"{path}: {what} not found"`` or ``"{path}: cannot read {what} (...)"`` for a missing,
        unreadable, non-UTF-8 or malformed file (the caller checks the structure it expects).
    """
    p = Path(path)
    with _reading(p, error, what):  # UnicodeDecodeError is a ValueError
        text = read_limited(p, MAX_JSON_BYTES, error, what).decode("utf-8")
    return parse_json(text, error, str(p), what)


def read_limited(path: str | os.PathLike, limit: int, error: type[Exception], what: str) -> bytes:
    """The bytes of ``path``, refused (``error``) when there are more than ``limit``.

    A regular file's size is checked before reading; the read never asks for more than the
    file holds (``read(n)`` allocates ``n`` bytes first), and a FIFO or growing file is read in
    1 MiB chunks up to the limit.
    """
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > limit:
            raise error(f"{path}: {what} of {size:,} bytes, over the limit of {limit:,} bytes")
        chunks = [fh.read(size + 1)]
        total = len(chunks[0])
        while total > size and total <= limit:  # not a regular file, or it grew: chunks up to the limit
            chunk = fh.read(1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    if total > limit:
        raise error(f"{path}: {what} of more than {limit:,} bytes, over the limit")
    return b"".join(chunks)


def json_depth(text: str) -> int:
    """Deepest ``[``/``{`` nesting of JSON ``text`` (brackets inside strings ignored); no recursion."""
    opens = text.count("[") + text.count("{")
    if opens <= MAX_JSON_DEPTH:
        return opens  # an upper bound, and small: the common case costs two counts
    bare = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text).encode("utf-8", "replace")
    b = np.frombuffer(bare, dtype=np.uint8)
    step = ((b == 91) | (b == 123)).astype(np.int32) - ((b == 93) | (b == 125)).astype(np.int32)
    return int(np.cumsum(step).max(initial=0))


def check_json_depth(text: str | bytes, error: type[HoloViewerError] = HoloViewerError, source: str = "<json>",
                     what: str = "JSON") -> None:
    """Refuse JSON nested deeper than :data:`MAX_JSON_DEPTH` before it is parsed.

    Python's parser recurses per level: ``'[' * 100000`` raises ``RecursionError`` (a
    traceback); this check is one line, linear time and no recursion.
    """
    if isinstance(text, bytes):
        text = text.decode("utf-8", "replace")
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise error(f"{source}: cannot read {what}: nested {depth} levels deep, more than the {MAX_JSON_DEPTH} "
                    f"accepted (fileio.MAX_JSON_DEPTH)")


def parse_json(text: str | bytes, error: type[HoloViewerError] = HoloViewerError, source: str = "<json>",
               what: str = "JSON"):
    """``json.loads`` after :func:`check_json_depth`; every JSON reader of the package uses one of them.

    Raises
    ------
    error
        ``"{source}: cannot read {what}: ..."`` for too deeply nested or malformed JSON
        (``not valid JSON (...)`` with the parser's line and column).
    """
    import json

    check_json_depth(text, error, source, what)
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise error(f"{source}: cannot read {what}: not valid JSON ({exc})") from None


def read_npz(path: str | os.PathLike, error: type[HoloViewerError] = HoloViewerError,
             what: str = "file", budget: int | None = None) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file, read eagerly (no pickles), at most ``budget`` bytes
    (default :data:`NPZ_BUDGET_BYTES`).

    Raises
    ------
    error
        ``"{path}: cannot read {what} (...)"`` for a missing, truncated or corrupt file;
        ``"... over the budget"`` before allocating when the declared sizes, an array's
        header or the decompressed bytes exceed ``budget`` (a 2 MB file of deflated zeros
        cannot make a reader allocate gigabytes).
    """
    p = Path(path)
    with _reading(p, error, what):
        with open(p, "rb") as fh:
            if fh.read(6) == b"\x93NUMPY":
                raise ValueError("expected an .npz archive, found a single .npy array")
        with zipfile.ZipFile(p) as zf:
            return _read_npz_members(zf, p, error, what, NPZ_BUDGET_BYTES if budget is None else budget)


def _read_npz_members(zf: zipfile.ZipFile, path: Path, error: type[HoloViewerError], what: str,
                      budget: int) -> dict[str, np.ndarray]:
    """Every ``.npy`` member of an open archive, each checked against ``budget`` before it is read.

    The budget is checked three times: the sum of the members' declared sizes, each array's
    header (shape x itemsize, before its buffer is allocated), and the bytes actually
    decompressed (a forged declared size cannot make a member inflate past its header).
    """
    infos = zf.infolist()
    declared = sum(i.file_size for i in infos)
    if declared > budget:
        raise error(f"{path}: {what} declares {declared:,} uncompressed bytes, over the budget of {budget:,} "
                    f"(fileio.NPZ_BUDGET_BYTES)")
    out: dict[str, np.ndarray] = {}
    left = budget
    for info in infos:
        name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        with zf.open(info) as fh:
            out[name] = _read_npy_stream(fh, f"member {name!r}", left, lambda msg: error(
                f"{path}: {what}: {msg}, over the budget of {budget:,} (fileio.NPZ_BUDGET_BYTES)"))
        left -= out[name].nbytes
    return out


def _read_npy_stream(fh: IO[bytes], name: str, left: int, over: Callable[[str], Exception]) -> np.ndarray:
    """One ``.npy`` stream: header checked (no objects, at most ``left`` bytes) before its buffer exists.

    ``over(message)`` is the error raised when the array needs more than ``left`` bytes; a
    stream shorter or longer than its header declares is a ``ValueError``.
    """
    version = np.lib.format.read_magic(fh)
    if version not in ((1, 0), (2, 0)):
        raise ValueError(f"{name}: unsupported .npy version {version}")
    read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    try:
        shape, fortran, dtype = read_header(fh)
    except (SyntaxError, tokenize.TokenError, TypeError, IndexError, KeyError, AttributeError, RecursionError) as exc:
        # numpy parses the header text with tokenize/ast: a malformed one raises these, not ValueError
        raise ValueError(f"{name}: malformed .npy header ({type(exc).__name__}: {exc})") from None
    if dtype.hasobject:
        raise ValueError(f"{name}: an array of Python objects (pickles are not loaded)")
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if nbytes > left:
        raise over(f"{name} of shape {shape} and dtype {dtype} needs {nbytes:,} bytes")
    buf = bytearray(nbytes)
    got = fh.readinto(buf) if nbytes else 0
    if got != nbytes:
        raise ValueError(f"{name}: truncated ({got} of {nbytes} bytes)")
    if fh.read(1):
        raise ValueError(f"{name}: more data than its header declares")
    return np.frombuffer(buf, dtype=dtype).reshape(shape, order="F" if fortran else "C")


def read_npy(path: str | os.PathLike, error: type[HoloViewerError] = HoloViewerError,
             what: str = "file") -> np.ndarray:
    """The array of an ``.npy`` file (no pickles); errors as :func:`read_npz`.

    The header's size is checked against the file's before the buffer is allocated (a 100-byte
    file declaring 80 GB is refused, not allocated).
    """
    p = Path(path)
    with _reading(p, error, what):
        with open(p, "rb") as fh:
            if fh.read(4) == b"PK\x03\x04":
                raise ValueError("expected a single .npy array, found an .npz archive")
            fh.seek(0)
            size = os.fstat(fh.fileno()).st_size
            return _read_npy_stream(fh, "array", size, lambda msg: error(
                f"{p}: cannot read {what}: {msg}, more than the file's {size:,} bytes hold"))
