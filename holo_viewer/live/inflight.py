"""Frames in flight: the live loop renders up to ``n`` frames at once, each on its own renderer and
thread, and shows them in the order they were started (issue 37's displayed-fps target).

On 2 cores one group frame keeps ~0.9 of a core busy (most of it the render's serial Python and numba
steps on one thread; docs/live.md "Measured latency"), so the other core idles while a frame renders. A
second renderer (:meth:`~holo_viewer.live.render.LiveAvatarRenderer.twin`) on a second thread starts
the next frame from the newest listener frame and viewer pose while this one finishes.

Rules (tested in ``tests/test_live_inflight.py``):

* Only renderers whose frames do not depend on earlier frames take part
  (:attr:`~holo_viewer.live.render.LiveAvatarRenderer.frames_independent`: the CPU backend's ``group``
  and ``all_views`` frames). A renderer without a twin (the ``tracked`` mode draws on the previous frame,
  ``cone``, gsplat's one device, a test's stand-in) renders alone, in the caller's thread, exactly as
  before. So ``replay --quality live``, which repeats the displayed frames' render calls on one
  renderer, gives ``native.mkv``'s frames again bit-exact.
* Frames are shown first started, first shown: a frame never follows a newer one. A frame that is still
  rendering when the session ends (quit, ``--frames``) is never shown nor recorded.
* The twins are built and warmed up in a background thread (~0.6-0.8 s of CPU each), so the first frame
  waits for none of them; until they are ready the loop renders with one renderer.
* Starts are spaced by about a frame period over ``n`` (the median of the last renders' wall time
  divided by the renderers busy), so the frames are shown evenly instead of in pairs.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

import numpy as np

__all__ = ["FramesInFlight", "RenderJob"]


class RenderJob:
    """One render call: ``args``/``kwargs`` of ``renderer.render``, ``tag`` (the caller's), and when done
    ``result`` (a RenderedFrame) or ``error``, ``started`` / ``finished`` (perf_counter)."""

    __slots__ = ("args", "kwargs", "tag", "result", "error", "started", "finished", "done", "renderer")

    def __init__(self, args: tuple, kwargs: dict, tag: Any) -> None:
        self.args, self.kwargs, self.tag = args, kwargs, tag
        self.result: Any = None
        self.error: BaseException | None = None
        self.started = self.finished = 0.0
        self.done = threading.Event()
        self.renderer: Any = None

    @property
    def seconds(self) -> float:
        """Wall seconds from the start of the render call to its end."""
        return self.finished - self.started


class _Worker:
    """A thread that owns one renderer and runs its jobs one at a time."""

    def __init__(self, renderer: Any, wake: threading.Condition, name: str) -> None:
        self.renderer = renderer
        #: a thread count to give the renderer before its next job (None: keep it)
        self.threads: int | None = None
        self._wake = wake
        self._job: RenderJob | None = None
        self._go = threading.Condition()
        self._stop = False
        self.busy = False
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def submit(self, job: RenderJob) -> None:
        with self._go:
            self._job = job
            self._go.notify()

    def stop(self) -> None:
        with self._go:
            self._stop = True
            self._go.notify()

    def _run(self) -> None:
        while True:
            with self._go:
                while self._job is None and not self._stop:
                    self._go.wait()
                if self._job is None:
                    return
                job, self._job = self._job, None
                threads, self.threads = self.threads, None
            if threads is not None:  # between frames, in the thread that renders them
                self.renderer.set_render_threads(threads)
            _render(self.renderer, job)
            with self._wake:
                self.busy = False
                job.done.set()
                self._wake.notify_all()


def _render(renderer: Any, job: RenderJob) -> None:
    job.renderer = renderer
    job.started = time.perf_counter()
    try:
        job.result = renderer.render(*job.args, **job.kwargs)
    except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread when the job is taken
        job.error = exc
    job.finished = time.perf_counter()


class FramesInFlight:
    """Up to ``n`` render calls at once, taken back in the order they were submitted.

    Parameters
    ----------
    renderer : LiveAvatarRenderer or any object with ``render(...)``
        The first renderer. With ``n > 1`` and ``renderer.frames_independent`` true, ``n - 1`` twins
        (``renderer.twin()``) are built in a background thread and warmed up with ``warmup`` (the
        args of one render call); otherwise every call renders in the caller's thread, at once.
    n : int
        Frames in flight at most (>= 1).
    warmup : tuple, optional
        A render call's args for each twin before it takes frames (its first frame is not slow).
    threads_each : int, optional
        Each renderer's threads once a twin has joined (default: the cores over ``n``, at least 1: on
        2 cores two frames of one thread each cost ~10 % less CPU a frame than two of two threads,
        measured at load 15-17, docs/live.md). The first renderer keeps its own until then.

    ``submit(args, kwargs, tag)`` when :meth:`can_submit`; :meth:`take` gives back the oldest job once it
    is done (or None); :meth:`wait` sleeps until some job finishes or ``timeout``; :meth:`close` stops the
    threads (a job still running is waited for, then dropped).
    """

    def __init__(self, renderer: Any, n: int = 1, warmup: tuple | None = None, threads_each: int | None = None) -> None:
        import os

        n = int(n)
        if n < 1:
            from ..errors import InputError

            raise InputError(f"frames_in_flight: expected >= 1, found {n}")
        self.first = renderer
        self.threaded = n > 1 and bool(getattr(renderer, "frames_independent", False)) and hasattr(renderer, "twin")
        self.n = n if self.threaded else 1
        self.threads_each = max(1, int(threads_each) if threads_each is not None else (os.cpu_count() or 1) // self.n)
        self._wake = threading.Condition()
        self._workers: list[_Worker] = []
        self._pending: deque[RenderJob] = deque()
        self._durations: deque[float] = deque(maxlen=9)
        self._last_start = -np.inf
        self._closed = False
        self.twin_error: BaseException | None = None
        #: seconds the twins took to build and warm up (None until they are ready)
        self.twins_ready_s: float | None = None
        self._builder = None
        if self.threaded:
            self._workers.append(_Worker(renderer, self._wake, "render-0"))
            self._builder = threading.Thread(target=self._build_twins, args=(warmup,), name="render-twins",
                                             daemon=True)
            self._builder.start()

    # ------------------------------------------------------------------ twins
    def _build_twins(self, warmup: tuple | None) -> None:
        t0 = time.perf_counter()
        try:
            for i in range(1, self.n):
                if self._closed:
                    return
                twin = self.first.twin(render_threads=self.threads_each)
                if warmup is not None:
                    twin.render(*warmup)
                with self._wake:
                    if self._closed:
                        return
                    if i == 1 and hasattr(self.first, "set_render_threads"):
                        self._workers[0].threads = self.threads_each  # from its next frame on
                    self._workers.append(_Worker(twin, self._wake, f"render-{i}"))
                    self._wake.notify_all()
            self.twins_ready_s = time.perf_counter() - t0
        except BaseException as exc:  # noqa: BLE001 - the session goes on with the renderers it has
            self.twin_error = exc

    @property
    def renderers(self) -> int:
        """Renderers taking frames now (the twins join when they are built)."""
        return len(self._workers) if self.threaded else 1

    # ------------------------------------------------------------------ jobs
    @property
    def in_flight(self) -> int:
        return len(self._pending)

    def can_submit(self, now: float | None = None) -> bool:
        """A renderer is free, and (with another frame in flight) about a period over ``n`` has passed
        since the last start: frames are spread over the period instead of started in pairs."""
        if not self.threaded:
            return not self._pending
        with self._wake:
            if not any(not w.busy for w in self._workers):
                return False
        if not self._pending or not self._durations:
            return True
        now = time.perf_counter() if now is None else now
        spacing = 0.8 * float(np.median(self._durations)) / max(1, self.renderers)
        return now - self._last_start >= spacing

    def submit(self, args: tuple, kwargs: dict | None = None, tag: Any = None) -> RenderJob:
        job = RenderJob(tuple(args), dict(kwargs or {}), tag)
        self._pending.append(job)
        self._last_start = time.perf_counter()
        if not self.threaded:
            _render(self.first, job)
            job.done.set()
            return job
        with self._wake:
            worker = next(w for w in self._workers if not w.busy)
            worker.busy = True  # taken now: can_submit must not offer it again before its thread runs
        worker.submit(job)
        return job

    def take(self) -> RenderJob | None:
        """The oldest job if it is done (removed; its error raised), else None."""
        if not self._pending or not self._pending[0].done.is_set():
            return None
        job = self._pending.popleft()
        self._durations.append(job.seconds)
        if job.error is not None:
            raise job.error
        return job

    def wait(self, timeout: float) -> None:
        """Until some job finishes (or a twin joins), at most ``timeout`` seconds."""
        if self._pending and self._pending[0].done.is_set():
            return
        with self._wake:
            self._wake.wait(timeout)

    def close(self, timeout: float = 30.0) -> None:
        """Stop the workers: each finishes the job it runs (nothing more is shown), joined. A twin still
        being built is not waited for (the quit of a 3-frame session would wait ~1 s for it): the builder
        drops it when done."""
        self._closed = True
        with self._wake:
            workers = list(self._workers)
        for w in workers:
            w.stop()
        deadline = time.perf_counter() + timeout
        for w in workers:
            w.thread.join(max(0.0, deadline - time.perf_counter()))
        self._pending.clear()
