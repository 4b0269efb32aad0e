"""On-disk cache of the panel's per-subpixel tables (interleaver gathers, eye-slice buckets).

The tables depend only on the calibration, the quilt layout and the code that builds them, yet took
~5 s of CPU at every ``live`` and ``replay`` start. :func:`cached_tables` keeps them in
:func:`holo_viewer.cache.cache_dir` ``/display_tables/`` (``$HOLO_VIEWER_CACHE``, else
``$XDG_CACHE_HOME/holo_viewer``, else ``~/.cache/holo_viewer``; never inside the clone), one
uncompressed ``.npz`` per table, named by a digest of

* the calibration's values (``repr`` of the frozen dataclass: exact floats),
* the table's parameters (quilt shape, views, mode, block, ...),
* :data:`VERSION` and the source of the modules that compute the tables (an edit rebuilds).

Files are written atomically (:func:`holo_viewer.fileio.save_npz`) and checked on load: the stored
key, every expected array's dtype and shape (from the caller's spec), and a CRC-32 of each array's
bytes. Anything else (truncated, corrupt, foreign) is rebuilt with a warning and rewritten, never
trusted. The :data:`KEEP` most recently used files of each kind stay, :data:`KEEP_KIND` of the kinds
named there (an edit of a table module would otherwise leave its old tables behind): the panel tables
(~145 MB a set for the Portrait, one set per calibration, quilt layout and mode, shared by every avatar)
4 sets, the visible-Gaussian masks (``visible_gaussians``, one per avatar and tile scale, ~5 MB: 49 bytes
a Gaussian at 48 views) 24, the ward's 7 avatars at 3 tile scales. "Used" is the file's modification
time, set at every write and load to the process clock's nanoseconds (strictly increasing in a process;
a file system may stamp at a clock tick's grain, and files written in one tick tie), the name
breaking ties: the order is deterministic. ``HOLO_VIEWER_TABLE_CACHE=0`` turns the cache off (tables
built every time); set to a folder, it holds the tables instead (``bench/live_latency.py`` points a
cold start at an empty one).
The process also keeps the last :data:`_KEPT_N` tables it loaded or wrote and hands out copies of them
while their file is unchanged (same inode, size and modification time): a file is read and checked once.
"""

from __future__ import annotations

import hashlib
import os
import time
import warnings
import zlib
from pathlib import Path
from typing import Callable

import numpy as np

from ..cache import keep_recent

__all__ = ["VERSION", "KEEP", "KEEP_KIND", "keep_count", "DISABLE_VAR", "table_key", "table_path", "cached_tables"]

#: bump when a table's meaning changes in a way the source digest would not show
VERSION = 1
#: files kept per kind of table (least recently used removed; stale sources, other panels)
KEEP = 4
#: kinds that keep another count: a live start without its avatar's mask draws every Gaussian and pays a
#: ~30-60 s CPU rebuild beside it, so the masks of 7 avatars x 3 tile scales (~5 MB each) all stay
KEEP_KIND: dict[str, int] = {"visible_gaussians": 24}
#: ``0``: build the tables every time (no reads, no writes); a folder: keep the tables there
DISABLE_VAR = "HOLO_VIEWER_TABLE_CACHE"
#: modules whose code computes the cached tables: their source is part of every key
_SOURCES = ("calibration.py", "lenticular.py", "device.py", "slices.py", "simulate.py", "table_cache.py")
_source_digest: str | None = None

#: name -> (shape with -1 for any length, dtype)
Spec = dict[str, tuple[tuple[int, ...], str]]


def _sources() -> str:
    global _source_digest
    if _source_digest is None:
        h = hashlib.sha256()
        here = Path(__file__).resolve().parent
        for name in _SOURCES:
            h.update(name.encode() + b"\0" + (here / name).read_bytes() + b"\0")
        _source_digest = h.hexdigest()
    return _source_digest


def table_key(kind: str, calibration: object, **params: object) -> str:
    """The digest naming one table: ``kind``, the calibration's values, ``params``, the version and
    the tables' source code."""
    text = repr((kind, VERSION, _sources(), repr(calibration), sorted((k, repr(v)) for k, v in params.items())))
    return hashlib.sha256(text.encode()).hexdigest()[:32]


def table_path(kind: str, key: str) -> Path:
    """Where the table ``kind`` with digest ``key`` is cached."""
    from ..cache import cache_dir

    folder = os.environ.get(DISABLE_VAR) or cache_dir() / "display_tables"
    return Path(folder) / f"{kind}_{key}.npz"


def _crc(a: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(a).view(np.uint8).reshape(-1))


def _check(arrays: dict[str, np.ndarray], spec: Spec, source: str) -> None:
    """Raise ValueError naming the first array that does not match ``spec``."""
    for name, (shape, dtype) in spec.items():
        if name not in arrays:
            raise ValueError(f"{source}: {name}: missing")
        a = arrays[name]
        if a.dtype != np.dtype(dtype) or a.ndim != len(shape) or any(
                s not in (-1, n) for s, n in zip(shape, a.shape)):
            raise ValueError(f"{source}: {name}: expected {dtype} of shape {shape}, found {a.dtype} {a.shape}")


def _load(path: Path, key: str, spec: Spec) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        stored_key = str(z["__key__"])
        if stored_key != key:
            raise ValueError(f"{path}: key {stored_key!r}, expected {key!r}")
        crcs = z["__crc__"]
        arrays = {name: z[name] for name in spec}
    _check(arrays, spec, str(path))
    if crcs.shape != (len(spec),) or [int(c) for c in crcs] != [_crc(arrays[n]) for n in spec]:
        raise ValueError(f"{path}: checksum mismatch (a damaged file)")
    return arrays


def keep_count(kind: str) -> int:
    """How many ``kind`` files the cache keeps: :data:`KEEP_KIND`'s count, else :data:`KEEP`."""
    return KEEP_KIND.get(kind, KEEP)


_last_used_ns = 0


def _mark_used(path: Path) -> None:
    """Set ``path``'s times to now in nanoseconds, later than any this process set before."""
    global _last_used_ns
    _last_used_ns = max(time.time_ns(), _last_used_ns + 1)
    os.utime(path, ns=(_last_used_ns, _last_used_ns))


def _prune(folder: Path, kind: str) -> None:
    """Remove all but the :func:`keep_count` most recently used ``kind`` files of ``folder``."""
    def used(p: Path) -> tuple[int, str]:
        try:
            return p.stat().st_mtime_ns, p.name
        except OSError:  # removed meanwhile by another process
            return -1, p.name

    files = sorted(folder.glob(f"{kind}_*.npz"), key=used, reverse=True)
    for old in files[keep_count(kind):]:
        try:
            old.unlink(missing_ok=True)
        except OSError:
            pass


#: the tables this process last loaded or wrote, (path, key) -> (the file's identity then, arrays): read again
#: only when the file changed (loading and checking one costs ~0.1-0.3 s of CPU, a copy ~10-30 ms)
_KEPT: dict = {}
_KEPT_N = 4


def _identity(path: Path) -> tuple[int, int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _kept(path: Path, key: str) -> dict[str, np.ndarray] | None:
    """The arrays this process kept of ``path`` when the file is still the one they came from."""
    got = _KEPT.get((str(path), key))
    return got[1] if got is not None and got[0] == _identity(path) else None


def _keep(path: Path, key: str, arrays: dict[str, np.ndarray]) -> None:
    """Keep ``arrays`` (never handed out: callers get copies) as the content of ``path`` as it is now."""
    ident = _identity(path)
    if ident is None:
        _KEPT.pop((str(path), key), None)
        return
    keep_recent(_KEPT, (str(path), key), (ident, arrays), _KEPT_N)


def cached_tables(kind: str, key: str, spec: Spec, build: Callable[[], dict[str, np.ndarray]]
                  ) -> dict[str, np.ndarray]:
    """The arrays of table ``kind`` keyed ``key`` (:func:`table_key`): loaded from the cache when a
    valid file is there, else ``build()`` (checked against ``spec``) and cached.

    A file that fails any check is rebuilt with a ``RuntimeWarning`` naming it; a cache folder that
    cannot be written only warns (the built tables are returned all the same).
    """
    if os.environ.get(DISABLE_VAR, "1") == "0":
        arrays = build()
        _check(arrays, spec, f"{kind} (built)")
        return arrays
    path = table_path(kind, key)
    if path.is_file():
        try:
            kept = _kept(path, key)
            arrays = _load(path, key, spec) if kept is None else {n: a.copy() for n, a in kept.items()}
            _mark_used(path)  # recently used (pruning)
            _keep(path, key, kept if kept is not None else {n: a.copy() for n, a in arrays.items()})
            return arrays
        except FileNotFoundError:  # pruned by another process meanwhile: simply rebuilt
            pass
        except Exception as exc:  # noqa: BLE001 - numpy/zipfile raise many types for damaged files
            warnings.warn(f"{path}: cached {kind} table unreadable ({type(exc).__name__}: {exc}); rebuilding it",
                          RuntimeWarning, stacklevel=2)
    arrays = build()
    _check(arrays, spec, f"{kind} (built)")
    from ..errors import HoloViewerError
    from ..fileio import save_npz

    crcs = np.array([_crc(arrays[n]) for n in spec], dtype=np.int64)
    try:
        save_npz(path, __key__=np.array(key), __crc__=crcs, **{n: arrays[n] for n in spec})
        _mark_used(path)
        _prune(path.parent, kind)
        _keep(path, key, {n: arrays[n].copy() for n in spec})
    except (HoloViewerError, OSError) as exc:
        warnings.warn(f"{path}: cannot cache the {kind} table ({exc}); it is rebuilt at every start",
                      RuntimeWarning, stacklevel=2)
    return arrays
