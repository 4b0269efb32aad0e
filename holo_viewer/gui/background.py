"""Background jobs of the viewer (exports): one worker thread, progress read by the UI thread.

The viewer drives VTK's event loop from Python (``HoloViewer.run``: process the pending X
events, then sleep a few milliseconds), so a worker thread gets the CPU whenever the window is
idle; the renderer and the PNG / video encoders release the GIL while they work. Jobs run one at
a time in submission order; a job reports progress with :meth:`Job.progress` and the UI thread
shows it (:meth:`BackgroundJobs.status_line`) and collects finished jobs with
:meth:`BackgroundJobs.finished`. A job never touches VTK.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

__all__ = ["Job", "BackgroundJobs"]


@dataclass
class Job:
    """One background job: its label, progress and outcome (``result`` or ``error``)."""

    label: str
    done: int = 0
    total: int = 0
    unit: str = ""
    result: Any = None
    error: BaseException | None = None
    future: Future | None = field(default=None, repr=False)

    def progress(self, done: int, total: int, unit: str = "") -> None:
        """Called by the job itself (worker thread): ``done`` of ``total`` ``unit`` finished."""
        self.done, self.total, self.unit = int(done), int(total), unit

    @property
    def finished(self) -> bool:
        return self.future is not None and self.future.done()

    def describe(self) -> str:
        if self.total:
            return f"{self.label}: {self.done}/{self.total} {self.unit}".rstrip()
        return f"{self.label}..."


class BackgroundJobs:
    """A single worker thread running :class:`Job` functions in order."""

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._lock = threading.Lock()
        self._jobs: list[Job] = []  # submitted, not yet collected by finished()

    def submit(self, label: str, fn: Callable[[Job], Any]) -> Job:
        """Run ``fn(job)`` in the worker thread; its return value becomes ``job.result``."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="holo-viewer-export")
        job = Job(label)

        def run() -> Any:
            try:
                job.result = fn(job)
            except BaseException as exc:  # noqa: BLE001 - reported to the UI, which shows it
                job.error = exc
            return job.result

        with self._lock:
            job.future = self._pool.submit(run)
            self._jobs.append(job)
        return job

    @property
    def pending(self) -> list[Job]:
        """Jobs submitted and not yet finished (the running one first)."""
        with self._lock:
            return [j for j in self._jobs if not j.finished]

    def finished(self) -> list[Job]:
        """Finished jobs not returned before (each is returned once)."""
        with self._lock:
            done = [j for j in self._jobs if j.finished]
            self._jobs = [j for j in self._jobs if not j.finished]
        return done

    def status_line(self) -> str:
        """``"exporting quilt: 16/48 views (+1 queued)"`` or ``""`` when idle."""
        pending = self.pending
        if not pending:
            return ""
        extra = f" (+{len(pending) - 1} queued)" if len(pending) > 1 else ""
        return f"{pending[0].describe()}{extra}"

    def wait(self, timeout: float | None = None) -> bool:
        """Block until every submitted job has finished; True if they all did within ``timeout``."""
        with self._lock:
            futures = [j.future for j in self._jobs if j.future is not None]
        from concurrent.futures import wait

        _, not_done = wait(futures, timeout=timeout)
        return not not_done

    def close(self) -> None:
        """Wait for the running and queued jobs (their files are not lost), then stop the thread."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
