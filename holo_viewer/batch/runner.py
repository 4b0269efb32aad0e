"""Run a manifest: resume, split into chunks, collect results, join, write ``summary.json``.

Output folder layout (``DIR`` = ``--out``)::

    DIR/summary.json                      every row: status, times, output paths, error
    DIR/<hash>/job.json                   the job (row, hash, frames, timings); present = finished
    DIR/<hash>/quilt_qs8x6a0.75.mp4       quilt video (one per requested kind)
    DIR/<hash>/native.mp4                 native video (lossless RGB H.264)
    DIR/<hash>/frames/quilt_00000_qs8x6a0.75.png, native_00000.png
    DIR/.work/<hash>/                     chunks of unfinished jobs (segments, PNGs, done markers)

``<hash>`` is :func:`~holo_viewer.batch.manifest.job_hash` (the job's content, not its row or id).

Nothing is lost and nothing is partial:

* Workers write no files; this process writes every file atomically (temp file + rename).
* A finished chunk's segments and PNGs are kept under ``.work/<hash>/`` with a done marker written
  last, so a re-run renders only the chunks that are missing.
* A job's folder is assembled under ``.work/<hash>/out`` and renamed to ``DIR/<hash>`` in one step
  when its last chunk is in; ``DIR/<hash>`` therefore exists only complete, and a re-run skips it.
* A failed row or chunk marks its job failed; the other jobs go on.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from ..errors import ExportError, HoloViewerError
from ..fileio import atomic_write, ensure_dir
from .executors import Executor
from .jobs import (PNG_KINDS, VIDEO_KINDS, ChunkResult, ChunkTask, ResolvedJob, chunk_tasks, load_frames,
                   plan_chunks, plan_job)
from .manifest import FileDigests, JobSpec, RowError, job_hash, read_manifest
from .video import join_segments

__all__ = ["run_batch", "BatchSummary", "JobRecord", "output_names", "DEFAULT_CHUNK_FRAMES"]

#: frames per chunk (1 s at 25 fps): a retry loses at most this much work, and each chunk adds
#: one keyframe to the video
DEFAULT_CHUNK_FRAMES = 25
_TEMP_RE = re.compile(r"^\..+\.tmp")


@dataclass
class JobRecord:
    """One manifest row in ``summary.json``.

    ``status``: ``done`` (rendered by this run), ``skipped`` (finished by an earlier run),
    ``duplicate`` (same hash as an earlier row: same outputs), ``failed``, or ``pending``
    (interrupted). ``outputs`` are paths relative to the summary's folder (PNG frames as a
    printf pattern, e.g. ``<hash>/frames/quilt_%05d_qs8x6a0.75.png``).
    """

    line: int
    id: str
    status: str
    hash: str | None = None
    frames: int | None = None
    chunks: int | None = None
    seconds: float | None = None
    render_seconds: float | None = None
    outputs: dict[str, str] = field(default_factory=dict)
    error: str | None = None
    same_as_line: int | None = None
    workers: list[str] = field(default_factory=list)


@dataclass
class BatchSummary:
    """What a run did; written as ``summary.json``."""

    manifest: str
    out: str
    executor: dict[str, Any]
    jobs: list[JobRecord]
    seconds: float = 0.0
    frames_rendered: int = 0
    #: seconds this process spent writing chunks and joining videos (the driver's share of the work)
    driver_seconds: float = 0.0
    #: jobs finished by this run (for the progress bar)
    jobs_done: int = 0

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for j in self.jobs:
            out[j.status] = out.get(j.status, 0) + 1
        return out

    @property
    def failed(self) -> list[JobRecord]:
        return [j for j in self.jobs if j.status == "failed"]

    def as_dict(self) -> dict[str, Any]:
        return {"manifest": self.manifest, "out": self.out, "executor": self.executor, "seconds": self.seconds,
                "frames_rendered": self.frames_rendered, "driver_seconds": self.driver_seconds,
                "counts": self.counts(),
                "jobs": [asdict(j) for j in self.jobs]}


def output_names(job: ResolvedJob) -> dict[str, str]:
    """File names (inside the job folder) of the requested outputs."""
    from ..display.quilt import quilt_filename

    names = {"quilt_mp4": quilt_filename("quilt", job.cols, job.rows, job.aspect, suffix=".mp4"),
             "native_mp4": "native.mp4",
             "quilt_png": "frames/" + quilt_filename("quilt_%05d", job.cols, job.rows, job.aspect),
             "native_png": "frames/native_%05d.png"}
    return {k: names[k] for k in job.spec.outputs}


class _Job:
    """Book-keeping of one job being rendered."""

    def __init__(self, resolved: ResolvedJob, record: JobRecord, work: Path, chunk_frames: int) -> None:
        self.resolved, self.record, self.work = resolved, record, work
        self.ranges = plan_chunks(resolved.n_frames, chunk_frames)
        self.n_chunks = len(self.ranges)
        self.done: set[int] = set()
        self.t0: float | None = None
        self.render_seconds = 0.0
        self.workers: set[str] = set()
        self.plan: dict[str, int] = {}


def run_batch(manifest: str | os.PathLike, out: str | os.PathLike, executor: Executor, *,
              chunk_frames: int = DEFAULT_CHUNK_FRAMES, progress: bool = True,
              log: Callable[[str], None] = print, behaviour_off: tuple[str, ...] = ()) -> BatchSummary:
    """Render every job of ``manifest`` into ``out`` (see the module docstring).

    Parameters
    ----------
    manifest : path-like
        JSON Lines or CSV manifest (:func:`~holo_viewer.batch.manifest.read_manifest`).
    out : path-like
        Output folder (created); re-running into the same folder resumes.
    executor : Executor
        :class:`~holo_viewer.batch.executors.InProcessExecutor` or ``RayExecutor``.
    chunk_frames : int
        Frames per chunk; longer clips are split and their chunks rendered in parallel.
    progress : bool
        One tqdm bar over the frames of all jobs.
    behaviour_off : tuple of str
        Behaviour layers to switch off in every reaction job (``render-batch --no-gaze`` ...;
        "behaviour": all of them, the model alone); part of each job's hash.

    Returns
    -------
    BatchSummary
        Also written to ``out/summary.json``.

    Raises
    ------
    ManifestError
        The manifest cannot be read at all (bad rows do not raise: they fail alone).
    """
    t_start = time.perf_counter()
    rows = read_manifest(manifest)
    if behaviour_off:
        from .manifest import switch_behaviour_off

        rows = [r if isinstance(r, RowError) else switch_behaviour_off(r, behaviour_off) for r in rows]
    root = ensure_dir(out, "output directory (--out)")
    work_root = root / ".work"
    _remove_stale_temps(work_root)
    digests = FileDigests()
    records: list[JobRecord] = []
    jobs: dict[str, _Job] = {}
    first_line: dict[str, JobRecord] = {}
    for row in rows:
        if isinstance(row, RowError):
            records.append(JobRecord(row.line, row.id, "failed", error=row.error))
            continue
        rec = _prepare(row, root, work_root, digests, chunk_frames, first_line, jobs)
        records.append(rec)
    summary = BatchSummary(manifest=str(manifest), out=str(root), executor=executor.describe(), jobs=records)

    todo = [j for j in jobs.values()]
    total_frames = sum(j.resolved.n_frames for j in todo)
    done_frames = sum(_chunk_frames(j, i) for j in todo for i in j.done)
    bar = None
    if progress and todo:
        from tqdm import tqdm

        bar = tqdm(total=total_frames, initial=done_frames, unit="frame", desc="render-batch", dynamic_ncols=True)
    failed: set[str] = set()
    try:
        for j in todo:  # jobs whose chunks were all done by an earlier, interrupted run
            if len(j.done) == j.n_chunks:
                try:
                    _finish(j, root, summary)
                except HoloViewerError as exc:
                    _fail(j, f"{j.resolved.spec.label}: {exc}", failed, log)
        tasks = _tasks(todo, chunk_frames, executor, failed, log)
        for res in executor.run(tasks):
            j = jobs[res.job]
            if j.record.status == "failed":
                continue
            if res.error is not None:
                _fail(j, f"{j.resolved.spec.label}: chunk {res.index} (frames {_range(j, res.index)}): "
                         f"{res.error}", failed, log)
            else:
                t_io = time.perf_counter()
                try:
                    _store_chunk(j, res)
                    summary.frames_rendered += res.n_frames
                    if len(j.done) == j.n_chunks:
                        _finish(j, root, summary)
                except HoloViewerError as exc:
                    _fail(j, f"{j.resolved.spec.label}: {exc}", failed, log)
                summary.driver_seconds += time.perf_counter() - t_io
            if bar is not None:
                bar.update(res.n_frames if res.error is None else 0)
                bar.set_postfix_str(f"jobs {summary.jobs_done}/{len(todo)} done, {len(failed)} failed")
    finally:
        if bar is not None:
            bar.close()
        for rec in records:  # duplicates share their first row's outcome
            if rec.same_as_line is not None:
                first = next(r for r in records if r.line == rec.same_as_line)
                rec.outputs, rec.frames = dict(first.outputs), first.frames
                if first.status == "failed":
                    rec.status, rec.error = "failed", f"same job as line {first.line}, which failed"
        summary.seconds = time.perf_counter() - t_start
        summary.executor = executor.describe()
        if work_root.is_dir() and not any(work_root.iterdir()):
            work_root.rmdir()
        with atomic_write(root / "summary.json", "w") as fh:
            json.dump(summary.as_dict(), fh, indent=2)
    return summary


# ------------------------------------------------------------------------------- steps


def _prepare(spec: JobSpec, root: Path, work_root: Path, digests: FileDigests, chunk_frames: int,
             first_line: dict[str, JobRecord], jobs: dict[str, _Job]) -> JobRecord:
    """Hash a row; skip, dedupe or resolve it into a pending job."""
    rec = JobRecord(spec.line, spec.id, "pending")
    try:
        h = job_hash(spec, digests)
    except OSError as exc:
        rec.status, rec.error = "failed", f"{spec.label}: cannot read an input file ({exc})"
        return rec
    rec.hash = h
    if h in first_line:
        rec.status, rec.same_as_line = "duplicate", first_line[h].line
        return rec
    first_line[h] = rec
    final = root / h
    if (final / "job.json").is_file():
        info = json.loads((final / "job.json").read_text())
        rec.status, rec.frames, rec.chunks = "skipped", info.get("frames"), info.get("chunks")
        rec.render_seconds = info.get("render_seconds")
        rec.outputs = {k: f"{h}/{v}" for k, v in info.get("outputs", {}).items()}
        return rec
    try:
        resolved = plan_job(spec, h)  # the frames are loaded when the job's chunks are sent
    except HoloViewerError as exc:
        rec.status, rec.error = "failed", f"{spec.label}: {exc}"
        return rec
    work = work_root / h
    n_chunks = len(plan_chunks(resolved.n_frames, chunk_frames))
    plan = {"chunk_frames": chunk_frames, "frames": resolved.n_frames}
    plan_file = work / "plan.json"
    if plan_file.is_file() and json.loads(plan_file.read_text()) != plan:
        shutil.rmtree(work)  # chunks of another split: start the job over
    job = _Job(resolved, rec, work, chunk_frames)
    job.plan = plan
    for i in range(n_chunks):
        marker = work / f"chunk_{i:05d}.json"
        if marker.is_file():
            info = json.loads(marker.read_text())
            job.done.add(i)
            job.render_seconds += info.get("seconds", 0.0)
    rec.frames, rec.chunks = resolved.n_frames, n_chunks
    jobs[h] = job
    return rec


def _tasks(todo: list[_Job], chunk_frames: int, executor: Executor, failed: set[str],
           log: Callable[[str], None]) -> Iterator[ChunkTask]:
    """The chunks still to render, job after job; a job's frames are loaded just before its chunks."""
    threads = getattr(executor, "threads", None)
    for j in todo:
        if len(j.done) == j.n_chunks or j.record.status == "failed":
            continue
        j.t0 = time.perf_counter()
        try:
            j.resolved.frames = load_frames(j.resolved)
            tasks = chunk_tasks(j.resolved, chunk_frames, threads, skip=j.done)
        except HoloViewerError as exc:
            _fail(j, f"{j.resolved.spec.label}: {exc}", failed, log)
            continue
        finally:
            j.resolved.frames = None  # the tasks hold their own slices until they are sent
        for task in tasks:
            if task.job in failed:
                break
            yield task


def _chunk_frames(j: _Job, index: int) -> int:
    a, b = j.ranges[index]
    return b - a


def _range(j: _Job, index: int) -> str:
    a, b = j.ranges[index]
    return f"{a}-{b - 1}"


def _store_chunk(j: _Job, res: ChunkResult) -> None:
    """Write a chunk's segments and PNGs atomically, then its done marker."""
    a, b = j.ranges[res.index]
    if not (j.work / "plan.json").is_file():  # the split the chunk files belong to
        with atomic_write(j.work / "plan.json", "w") as fh:
            json.dump(j.plan, fh)
    if res.n_frames != b - a:
        raise HoloViewerError(f"chunk {res.index}: expected {b - a} frames, the worker returned {res.n_frames}")
    for kind, data in res.segments.items():
        with atomic_write(j.work / f"chunk_{res.index:05d}.{kind}.ts") as fh:
            fh.write(data)
    names = output_names(j.resolved)
    for kind, images in res.pngs.items():
        for k, data in enumerate(images):
            with atomic_write(j.work / "out" / (names[kind] % (a + k))) as fh:
                fh.write(data)
    with atomic_write(j.work / f"chunk_{res.index:05d}.json", "w") as fh:
        json.dump({"frames": [a, b], "seconds": res.seconds, "pid": res.pid, "host": res.host}, fh)
    j.done.add(res.index)
    j.render_seconds += res.seconds
    j.workers.add(f"{res.host}:{res.pid}")


def _finish(j: _Job, root: Path, summary: BatchSummary) -> None:
    """Join the job's segments, write job.json, move the folder into place, drop the chunks."""
    r, rec = j.resolved, j.record
    stage = j.work / "out"
    names = output_names(r)
    for kind in VIDEO_KINDS:
        if kind in names:
            segs = [j.work / f"chunk_{i:05d}.{kind}.ts" for i in range(j.n_chunks)]
            join_segments(segs, stage / names[kind], frames=r.n_frames)
    for kind in PNG_KINDS:
        if kind in names:
            ensure_dir(stage / "frames", "frames directory")
    seconds = time.perf_counter() - j.t0 if j.t0 is not None else 0.0
    info = {"hash": r.hash, "line": r.spec.line, "id": r.spec.id, "frames": r.n_frames, "fps": r.fps,
            "chunks": j.n_chunks, "render_seconds": j.render_seconds, "wall_seconds": seconds,
            "outputs": names, "quilt": {"cols": r.cols, "rows": r.rows, "aspect": r.aspect},
            "job": {k: v for k, v in asdict(r.spec).items() if k not in ("line", "id")},
            "workers": sorted(j.workers)}
    with atomic_write(stage / "job.json", "w") as fh:
        json.dump(info, fh, indent=2)
    final = root / r.hash
    if final.exists() and not (final / "job.json").is_file():
        raise ExportError(f"{final}: expected a finished job folder (with job.json) or none, found a folder "
                          "without job.json (not written by render-batch?); move it away and re-run")
    if not final.exists():  # else an earlier run finished it: keep that one
        os.replace(stage, final)  # one rename: the job folder appears complete or not at all
    shutil.rmtree(j.work, ignore_errors=True)
    rec.status, rec.seconds, rec.render_seconds = "done", seconds, j.render_seconds
    summary.jobs_done += 1
    rec.outputs = {k: f"{r.hash}/{v}" for k, v in names.items()}
    rec.workers = sorted(j.workers)


def _fail(j: _Job, message: str, failed: set[str], log: Callable[[str], None]) -> None:
    j.record.status, j.record.error = "failed", message
    failed.add(j.resolved.hash)
    log(f"render-batch: job failed: {message}")


def _remove_stale_temps(work_root: Path) -> None:
    """Temp files of an earlier run killed mid-write (``.name.XXXX.tmp...``; never outputs)."""
    if not work_root.is_dir():
        return
    for dirpath, _, files in os.walk(work_root):
        for name in files:
            if _TEMP_RE.match(name):
                Path(dirpath, name).unlink(missing_ok=True)
