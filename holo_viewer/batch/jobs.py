"""From a validated manifest row to chunk tasks: the driver's frames, the scene, the split.

Everything here runs in the process that reads the manifest (the Ray *driver*): the face
sequence of a job is resolved once (a reaction is generated once, with its seed) and sliced into
chunks, so every worker renders frames of the same sequence, whatever node it runs on. The
tasks and results are plain picklable dataclasses; workers return encoded bytes, never write
files (see :mod:`holo_viewer.batch.runner`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from .manifest import SCENARIOS, JobSpec

__all__ = ["SceneSpec", "ChunkTask", "ChunkResult", "ResolvedJob", "plan_job", "load_frames", "resolve_job",
           "plan_chunks", "chunk_tasks",
           "VIDEO_KINDS", "PNG_KINDS"]

VIDEO_KINDS = ("quilt_mp4", "native_mp4")
PNG_KINDS = ("quilt_png", "native_png")


@dataclass(frozen=True)
class SceneSpec:
    """What a worker loads once and keeps between chunks (its cache key)."""

    avatar: str = "default"
    flame_model: str | None = None
    avatar_params: str | None = None
    calibration: str | None = None
    renderer: str = "fast"


@dataclass(frozen=True)
class ChunkTask:
    """Frames ``start .. start + len(frames) - 1`` of one job, for one worker.

    Attributes
    ----------
    frames : tuple of dict
        Per-frame FLAME parameters (:func:`holo_viewer.pipeline.flame_sequence_frames` items).
    named, pain : the base face the frames override (``FaceControls.named`` / ``pain``).
    threads : int or None
        Renderer threads (None = all cores).
    """

    job: str
    index: int
    n_chunks: int
    start: int
    frames: tuple[dict[str, Any], ...]
    scene: SceneSpec
    named: tuple[tuple[str, float], ...]
    pain: float
    tile_scale: float
    outputs: tuple[str, ...]
    fps: float
    crf: int
    native_crf: int = 0
    threads: int | None = None

    @property
    def n_frames(self) -> int:
        return len(self.frames)


@dataclass
class ChunkResult:
    """What a worker sends back: encoded segments and PNGs, or the error that stopped it."""

    job: str
    index: int
    n_frames: int = 0
    seconds: float = 0.0
    pid: int = 0
    host: str = ""
    segments: dict[str, bytes] = field(default_factory=dict)  # quilt_mp4 / native_mp4 -> MPEG-TS bytes
    pngs: dict[str, list[bytes]] = field(default_factory=dict)  # quilt_png / native_png -> one per frame
    error: str | None = None


@dataclass
class ResolvedJob:
    """A job ready to split: its length, frame rate, base face and quilt layout (for output names).

    ``frames`` (the per-frame FLAME parameters) is filled by :func:`load_frames` just before the
    job's chunks are sent, and may be dropped afterwards: a batch of 1,000 long clips never holds
    all its sequences (or runs all its reactions) up front.
    """

    spec: JobSpec
    hash: str
    n_frames: int
    named: tuple[tuple[str, float], ...]
    pain: float
    fps: float
    cols: int
    rows: int
    aspect: float
    frames: list[dict[str, Any]] | None = None

    @property
    def scene(self) -> SceneSpec:
        s = self.spec
        return SceneSpec(s.avatar, s.flame_model, s.avatar_params, s.calibration, s.renderer)


def plan_job(spec: JobSpec, job_hash: str) -> ResolvedJob:
    """The job's length, frame rate and layout, cheaply (no reaction model run, no frames kept).

    Raises
    ------
    HoloViewerError
        InputError, ReactionError, CalibrationError, ... naming the file and what is wrong.
    """
    from ..display.calibration import DisplayCalibration
    from ..fileio import read_npz

    cal = DisplayCalibration.load(spec.calibration)
    named, pain, fps = spec.expressions, spec.pain, spec.fps
    if spec.driver == "flame_params":
        n = len(_sequence(spec))
    elif spec.driver == "reaction":
        z = read_npz(spec.speaker_params, InputError, "speaker FLAME parameters")
        if "expr" not in z or np.ndim(z["expr"]) != 2:
            raise InputError(f"{spec.speaker_params}: expr: expected an array (T, n_expr), found "
                             f"{np.shape(z['expr']) if 'expr' in z else 'no such key'}")
        n = int(np.shape(z["expr"])[0])
        pain, fps = 0.0, 25.0  # the model's expressions carry the requested pain
    elif spec.driver == "synthetic_reaction":
        n = max(1, int(round(spec.seconds * 25.0)))
        pain, fps = 0.0, 25.0
    else:
        n = spec.frames
    if n < 1:
        raise InputError(f"{spec.label}: expected at least one frame from the driver, found none")
    return ResolvedJob(spec=spec, hash=job_hash, n_frames=n, named=named, pain=pain, fps=fps,
                       cols=int(cal.cols), rows=int(cal.rows), aspect=float(cal.aspect))


def _sequence(spec: JobSpec) -> list[dict[str, Any]]:
    from ..fileio import read_npz
    from ..pipeline import flame_sequence_frames

    params = read_npz(spec.flame_params, InputError, "FLAME parameters")
    seq = {k: v for k, v in params.items() if k not in ("static_offset", "fps")}
    frames = flame_sequence_frames(seq, source=spec.flame_params)
    stop = len(frames) if spec.stop is None else spec.stop
    if stop > len(frames) or spec.start >= stop:
        raise InputError(f"{spec.flame_params}: start/stop: expected 0 <= start < stop <= {len(frames)} "
                         f"(the sequence's frames), found start={spec.start}, stop={spec.stop}")
    return frames[spec.start:stop]


def load_frames(job: ResolvedJob) -> list[dict[str, Any]]:
    """Read or generate the job's per-frame FLAME parameters (runs the reaction model once).

    Raises
    ------
    HoloViewerError
        A bad driver file, or a driver that gives another number of frames than planned.
    """
    from ..pipeline import flame_sequence_frames

    spec = job.spec
    pain: Any = spec.pain
    if spec.pain_timeline is not None:
        from ..behaviour import PainKey, PainTimeline

        pain = PainTimeline(PainKey(t, v) for t, v in spec.pain_timeline)
    behaviour = target = au_map = None
    if spec.behaviour is not None:
        from ..behaviour import BehaviourConfig, viewer_target

        behaviour = BehaviourConfig.from_dict(dict(spec.behaviour), source=f"{spec.label}: behaviour")
        target = viewer_target(0.0 if spec.viewer_angle is None else spec.viewer_angle,
                               0.6 if spec.viewer_distance is None else spec.viewer_distance)
        if spec.driver in ("reaction", "synthetic_reaction"):  # the layers' pain face is the avatar's own
            from .worker import load_scene_pipeline

            au_map = load_scene_pipeline(job.scene).au_map
    if spec.driver == "flame_params":
        frames = _sequence(spec)
    elif spec.driver == "reaction":
        from ..pipeline.reactions import react_to_speaker
        from ..reaction.decoding import DEFAULT_TEMPERATURE

        params, _ = react_to_speaker(spec.speaker_audio, spec.speaker_params, pain=pain, seed=spec.seed,
                                     temperature=DEFAULT_TEMPERATURE if spec.temperature is None else spec.temperature,
                                     behaviour=behaviour, target=target, au_map=au_map)
        params.pop("pain_shown", None)  # already in the expressions
        frames = flame_sequence_frames(params, source=spec.speaker_params)
    elif spec.driver == "synthetic_reaction":
        from ..pipeline.reactions import reaction_frames

        kw = {} if spec.temperature is None else {"temperature": spec.temperature}
        frames, _ = reaction_frames(seconds=spec.seconds, pain=pain, seed=spec.seed, behaviour=behaviour,
                                    target=target, au_map=au_map, **kw)
    else:
        frames = [{} for _ in range(spec.frames)]
    if len(frames) != job.n_frames:
        raise InputError(f"{spec.label}: the driver gave {len(frames)} frames, expected {job.n_frames}")
    if spec.pain_timeline is not None and spec.driver in ("flame_params", "still"):
        levels = pain.levels(len(frames), job.fps)  # no behaviour layers here: the level itself per frame
        frames = [dict(f, pain=np.float64(levels[k])) for k, f in enumerate(frames)]
    elif spec.scenario != "constant":
        profile = SCENARIOS[spec.scenario]
        n = len(frames)
        frames = [dict(f, pain=np.float64(spec.pain * profile(k / max(1, n - 1)))) for k, f in enumerate(frames)]
    return frames


def resolve_job(spec: JobSpec, job_hash: str) -> ResolvedJob:
    """:func:`plan_job` with the frames loaded (:func:`load_frames`)."""
    job = plan_job(spec, job_hash)
    job.frames = load_frames(job)
    return job


def plan_chunks(n_frames: int, chunk_frames: int) -> list[tuple[int, int]]:
    """``[start, stop)`` ranges of at most ``chunk_frames`` frames covering ``0 .. n_frames - 1``.

    The frames are spread evenly over ``ceil(n_frames / chunk_frames)`` chunks (sizes differ by at
    most one), so no chunk is a short straggler.
    """
    if n_frames < 1 or chunk_frames < 1:
        raise InputError(f"plan_chunks: expected n_frames >= 1 and chunk_frames >= 1, found {n_frames}, "
                         f"{chunk_frames}")
    n = math.ceil(n_frames / chunk_frames)
    edges = [round(i * n_frames / n) for i in range(n + 1)]
    return [(edges[i], edges[i + 1]) for i in range(n)]


def chunk_tasks(job: ResolvedJob, chunk_frames: int, threads: int | None,
                skip: set[int] | frozenset[int] = frozenset()) -> list[ChunkTask]:
    """The job's chunk tasks (its frames loaded), leaving out the chunk indices in ``skip`` (done)."""
    if job.frames is None:
        raise InputError(f"{job.spec.label}: frames not loaded (load_frames)")
    ranges = plan_chunks(job.n_frames, chunk_frames)
    s = job.spec
    return [ChunkTask(job=job.hash, index=i, n_chunks=len(ranges), start=a, frames=tuple(job.frames[a:b]),
                      scene=job.scene, named=job.named, pain=job.pain, tile_scale=s.tile_scale, outputs=s.outputs,
                      fps=job.fps, crf=s.crf, native_crf=s.native_crf, threads=threads)
            for i, (a, b) in enumerate(ranges) if i not in skip]
