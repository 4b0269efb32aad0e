"""A worker process that renders the viewer's thumbnail quilt.

VTK's event loop (``vtkRenderWindowInteractor::Start``) holds Python's GIL, so a worker *thread*
gets only the moments when the loop calls back into Python (measured: ~4% of a core). The
thumbnail therefore renders in a separate process, started once with ``python -m
holo_viewer.gui.thumbnail_worker`` (no re-import of the caller's ``__main__``, unlike
multiprocessing's spawn). Jobs and results are pickled over the child's stdin / stdout, between
processes of the same program only. At most one job is in flight; a newer request replaces a
queued one, so a burst of slider releases renders only the latest state. A job (~25 MB for the
100k-Gaussian default avatar) is written to the pipe by a short-lived writer thread, so the
event loop does not wait while the child reads it.

Starting the child costs seconds of CPU (it imports the renderer); a viewer that closes hands an idle
worker back (:meth:`ThumbnailWorker.release`) and the next viewer of the same process takes it
(:meth:`ThumbnailWorker.acquire`): tests and scripts that open several windows start one or two children,
not one per window. Pooled workers end at exit (or when their stdin closes with the parent).
"""

from __future__ import annotations

import atexit
import pickle
import select
import subprocess
import sys
import threading
from typing import Any

__all__ = ["ThumbnailWorker", "render_thumbnail", "render_native"]


def render_thumbnail(gaussians: Any, cameras: Any, backend: str, config: Any, cols: int, rows: int) -> Any:
    """(rows*h, cols*w, 3) uint8 quilt of ``cameras`` (runs in the worker): :func:`holo_viewer.pipeline.render_quilt`."""
    from ..pipeline.rendering import render_quilt

    return render_quilt(gaussians, cameras, cols, rows, backend=backend, config=config)


def render_native(gaussians: Any, cameras: Any, backend: str, config: Any, cols: int, rows: int, calibration: Any,
                  blend: bool) -> Any:
    """(screen_h, screen_w, 3) uint8 native image of the full-resolution quilt of ``cameras`` (runs in the
    worker): the quilt as :func:`render_thumbnail`, interleaved as ``Pipeline.native()`` does."""
    from ..display.lenticular import Interleaver
    from ..display.native import views_to_native

    quilt = render_thumbnail(gaussians, cameras, backend, config, cols, rows)
    inter = Interleaver(calibration, quilt.shape, cols=cols, rows=rows, mode="blend" if blend else "nearest")
    return views_to_native(None, inter, quilt=quilt).native


#: what a job's first element names (a job without a name renders the thumbnail quilt)
JOBS = {"native": render_native}


_POOL: list["ThumbnailWorker"] = []  # idle workers handed back by closed viewers
POOL_SIZE = 2


def _close_pool() -> None:
    while _POOL:
        _POOL.pop().close()


atexit.register(_close_pool)


class ThumbnailWorker:
    """The parent's handle on the worker process."""

    @classmethod
    def acquire(cls) -> "ThumbnailWorker":
        """An idle pooled worker whose child is alive, else a new one (started on its first job)."""
        while _POOL:
            worker = _POOL.pop()
            if worker._proc is not None and worker._proc.poll() is None:
                return worker
            worker.close()
        return cls()

    def release(self) -> None:
        """Hand this worker back to the pool when it is idle and alive (else close it)."""
        if (not self.busy and self._proc is not None and self._proc.poll() is None and len(_POOL) < POOL_SIZE
                and self not in _POOL):
            _POOL.append(self)
        else:
            self.close()

    def __init__(self) -> None:
        self._proc: subprocess.Popen | None = None
        self._in_flight: Any = None  # key of the running job
        self._queued: tuple[Any, tuple] | None = None
        self._writer: threading.Thread | None = None

    def _start(self) -> subprocess.Popen:
        if self._proc is None or self._proc.poll() is not None:
            self._proc = subprocess.Popen([sys.executable, "-m", "holo_viewer.gui.thumbnail_worker"],
                                          stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            self._in_flight = None
        return self._proc

    @property
    def busy(self) -> bool:
        return self._in_flight is not None or self._queued is not None

    def submit(self, key: Any, args: tuple) -> None:
        """Render ``args`` (see :func:`render_thumbnail`) for ``key``; replaces a queued job."""
        if self._in_flight is not None:
            self._queued = (key, args)
            return
        proc = self._start()
        data = pickle.dumps((key, args), protocol=pickle.HIGHEST_PROTOCOL)
        if self._writer is not None:
            self._writer.join()

        def write() -> None:
            try:
                proc.stdin.write(data)
                proc.stdin.flush()
            except (BrokenPipeError, ValueError, OSError):
                pass  # the child died: poll() reports it

        self._writer = threading.Thread(target=write, name="thumbnail-job-writer", daemon=True)
        self._writer.start()
        self._in_flight = key

    def poll(self, wait: bool = False) -> tuple[Any, Any] | None:
        """(key, quilt) of a finished job, or None. Raises RuntimeError if the job failed."""
        proc = self._proc
        if self._in_flight is None or proc is None:
            return None
        if not wait and not select.select([proc.stdout], [], [], 0)[0]:
            return None
        try:
            key, (status, value) = pickle.load(proc.stdout)
        except EOFError:
            self._in_flight = None
            raise RuntimeError(f"thumbnail worker exited (code {proc.poll()})") from None
        self._in_flight = None
        if self._queued is not None:
            q, self._queued = self._queued, None
            self.submit(*q)
        if status != "ok":
            raise RuntimeError(f"thumbnail worker: {value}")
        return key, value

    def close(self) -> None:
        proc, self._proc = self._proc, None
        self._queued = self._in_flight = None
        if self._writer is not None:
            self._writer.join()
            self._writer = None
        if proc is None:
            return
        try:
            proc.stdin.close()
            proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            proc.kill()
            proc.wait()
        proc.stdout.close()


def main() -> int:
    """Worker loop: read (key, args) jobs from stdin, write (key, (status, value)) to stdout."""
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # keep stdout for results only
    while True:
        try:
            key, args = pickle.load(inp)
        except EOFError:
            return 0
        try:
            fn = JOBS[args[0]] if args and isinstance(args[0], str) else render_thumbnail
            result: tuple[str, Any] = ("ok", fn(*(args[1:] if fn is not render_thumbnail else args)))
        except Exception as exc:  # noqa: BLE001 - reported to the parent, which shows it
            result = ("error", f"{type(exc).__name__}: {exc}")
        pickle.dump((key, result), out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    sys.exit(main())
