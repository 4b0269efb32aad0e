"""Where chunks run: in this process, or on Ray (a local Ray or a cluster), behind one interface.

An executor takes an iterable of :class:`~holo_viewer.batch.jobs.ChunkTask` and yields a
:class:`~holo_viewer.batch.jobs.ChunkResult` per task as each finishes (any order). It pulls tasks
lazily, so the runner can stop feeding the chunks of a job that already failed.

Ray is an optional dependency (the ``cluster`` extra): :func:`make_executor` falls back to
:class:`InProcessExecutor` without it and says how to install it.
"""

from __future__ import annotations

import itertools
import os
from typing import Any, Callable, Iterable, Iterator, Protocol

from ..errors import InputError, MissingDependencyError
from .jobs import ChunkResult, ChunkTask
from .worker import render_chunk

__all__ = ["Executor", "InProcessExecutor", "RayExecutor", "make_executor", "RAY_MISSING_MESSAGE"]

RAY_MISSING_MESSAGE = ('Ray is not installed, so the jobs run here, in this process, one after another; for '
                       'parallel workers or a cluster install the extra: pip install "holo_viewer[cluster]"')


class Executor(Protocol):
    """Runs chunk tasks; see the module docstring."""

    name: str
    workers: int

    def run(self, tasks: Iterable[ChunkTask]) -> Iterator[ChunkResult]: ...

    def describe(self) -> dict[str, Any]: ...

    def close(self) -> None: ...


class InProcessExecutor:
    """Renders the chunks one after another in the calling process."""

    name = "in-process"
    workers = 1

    def __init__(self, threads: int | None = None) -> None:
        self.threads = threads

    def run(self, tasks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        for task in tasks:
            yield render_chunk(task)

    def describe(self) -> dict[str, Any]:
        return {"executor": self.name, "workers": 1, "threads_per_worker": self.threads}

    def close(self) -> None:
        pass


class RayExecutor:
    """Runs each chunk as a Ray task (``num_cpus = threads``, retried when its worker dies).

    Parameters
    ----------
    address : str or None
        None starts a local Ray with ``workers * threads`` CPUs (or joins the one already
        initialized in this process); ``"auto"`` joins the cluster of this node; ``ray://host:10001``
        connects through Ray Client.
    workers : int or None
        Chunks rendered at the same time (None = cluster CPUs // threads).
    threads : int
        CPU threads per chunk (the renderer's thread count and the task's ``num_cpus``).
    max_retries : int
        Times Ray re-runs a chunk whose worker process died (killed, out of memory, node lost).
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None, threads: int = 1,
                 max_retries: int = 3) -> None:
        import ray  # fails here, not at the first task, when Ray is missing

        if workers is not None and workers < 1 or threads < 1:
            raise InputError(f"--workers/--threads-per-worker: expected positive integers, found {workers}, "
                             f"{threads}")
        self._ray = ray
        self._owns = False
        self._remote: Any = None
        self.address = address
        self.threads = int(threads)
        self.workers = int(workers) if workers else 0  # 0 = from the cluster's CPUs, once connected
        self._requested_workers = workers
        self.max_retries = int(max_retries)

    def _connect(self) -> None:
        """Start or join Ray (on first use: a run with nothing to render never starts it)."""
        if self._remote is not None:
            return
        ray = self._ray
        if not ray.is_initialized():
            kw: dict[str, Any] = {"log_to_driver": False, "logging_level": "WARNING"}
            if self.address is None:
                cpus = (self._requested_workers or max(1, _usable_cpus() // self.threads)) * self.threads
                kw.update(num_cpus=cpus, include_dashboard=False)
            try:
                ray.init(address=self.address, **kw)
            except (ConnectionError, ValueError, RuntimeError, TimeoutError) as exc:
                where = f"--address {self.address}" if self.address else "a local Ray"
                raise InputError(f"{where}: cannot start or join Ray ({type(exc).__name__}: {exc}); for a cluster "
                                 "check `ray status` on its head node, and for ray://HOST:10001 with token "
                                 "authentication set RAY_AUTH_MODE=token and the cluster's token (docs/batch.md)"
                                 ) from exc
            self._owns = True
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = int(self._requested_workers or max(1, cpus // self.threads))
        self._remote = ray.remote(num_cpus=self.threads, max_retries=self.max_retries,
                                  retry_exceptions=False)(render_chunk)

    def run(self, tasks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        ray = self._ray
        it = iter(tasks)
        first = next(it, None)
        if first is None:
            return
        self._connect()
        it = itertools.chain([first], it)
        pending: dict[Any, ChunkTask] = {}
        limit = self.workers  # exactly N chunks at a time, also on a bigger cluster

        def submit() -> None:
            while len(pending) < limit:
                task = next(it, None)
                if task is None:
                    return
                pending[self._remote.remote(task)] = task

        submit()
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            ref = done[0]
            task = pending.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayError as exc:  # the worker died more than max_retries times
                result = ChunkResult(job=task.job, index=task.index,
                                     error=f"chunk {task.index} failed after {self.max_retries + 1} attempts: "
                                           f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
            del ref
            submit()
            yield result

    def describe(self) -> dict[str, Any]:
        ray = self._ray
        out = {"executor": self.name, "ray": ray.__version__, "address": self.address or "local",
               "workers": self.workers or None, "threads_per_worker": self.threads, "max_retries": self.max_retries,
               "started": self._remote is not None}
        if self._remote is not None and ray.is_initialized():
            out.update(cluster_cpus=ray.cluster_resources().get("CPU"),
                       nodes=len([n for n in ray.nodes() if n.get("Alive")]))
        return out

    def close(self) -> None:
        if self._owns:
            self._ray.shutdown()
            self._owns = False


def _usable_cpus() -> int:
    """CPUs this process may run on (the affinity mask in a container), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def make_executor(address: str | None = None, workers: int | None = None, threads: int = 1,
                  in_process: bool = False, log: Callable[[str], None] = print) -> Executor:
    """Ray when it is installed (and not ``in_process``), else :class:`InProcessExecutor`.

    Raises
    ------
    MissingDependencyError
        ``address`` names a cluster but Ray is not installed.
    """
    if in_process:
        if address:
            raise InputError(f"--address {address}: expected no cluster address with --in-process")
        return InProcessExecutor(threads)
    try:
        import ray  # noqa: F401
    except ImportError:
        if address:
            raise MissingDependencyError("ray", f"render-batch --address {address}", extra="cluster") from None
        log(f"render-batch: {RAY_MISSING_MESSAGE}")
        return InProcessExecutor(threads)
    return RayExecutor(address=address, workers=workers, threads=threads)
