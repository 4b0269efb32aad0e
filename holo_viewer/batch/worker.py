"""The worker side: render one chunk of frames through the pipeline and encode it.

:func:`render_chunk` is what an executor runs (a Ray task or a plain call). It keeps the loaded
scene (avatar, calibration, renderer) between calls, so a worker process loads the default avatar
once for all the chunks it renders. It never writes files: it returns MPEG-TS segments and PNG
bytes (:class:`~holo_viewer.batch.jobs.ChunkResult`), so a worker killed mid-chunk leaves nothing
behind, and the outputs need no file system shared with the nodes. An error in a chunk (bad input the driver could
not see, e.g. a PLY that does not match its FLAME model) is returned, not raised: the job fails
alone and Ray does not retry a deterministic error.
"""

from __future__ import annotations

import io
import os
import socket
import time
import traceback
from collections import OrderedDict
from typing import TYPE_CHECKING, Any, Iterator, Sequence

import numpy as np

from ..errors import HoloViewerError
from .jobs import ChunkResult, ChunkTask, SceneSpec
from .video import SegmentEncoder

if TYPE_CHECKING:  # pragma: no cover
    from ..pipeline import Pipeline

__all__ = ["render_chunk", "render_frames", "load_scene_pipeline"]

_SCENES: "OrderedDict[SceneSpec, Pipeline]" = OrderedDict()
_MAX_SCENES = 2


def load_scene_pipeline(scene: SceneSpec) -> "Pipeline":
    """The :class:`~holo_viewer.pipeline.Pipeline` of ``scene``, loaded once per process (LRU of 2)."""
    pipe = _SCENES.get(scene)
    if pipe is None:
        from ..pipeline import load_scene

        # avatar_params is the PLY avatar's own flame_param.npz (its identity); its frames are not used
        pipe = load_scene(scene.avatar, scene.flame_model, scene.avatar_params, scene.calibration,
                          scene.renderer).pipeline
        _SCENES[scene] = pipe
        while len(_SCENES) > _MAX_SCENES:
            _SCENES.popitem(last=False)
    else:
        _SCENES.move_to_end(scene)
    return pipe


def render_frames(pipe: "Pipeline", frames: Sequence[dict[str, Any]], named: tuple[tuple[str, float], ...], pain: float,
                  native: bool) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """(quilt, native or None) uint8 images of each frame: the batch's one use of the pipeline.

    Parameters
    ----------
    pipe : Pipeline
    frames : sequence of dict
        Per-frame FLAME parameters (keys of ``pipeline.FLAME_KEYS``, ``shape``, ``pain``).
    named, pain : the base face controls the frames override.
    native : bool
        Also compute the native lenticular image.
    """
    from ..pipeline import FaceControls, apply_frame

    base = FaceControls(named=named, pain=pain)
    stages = ("quilt", "native") if native else ("quilt",)
    for k, frame in enumerate(frames):
        pipe.set_face(apply_frame(base, frame, k))
        values, _ = pipe.compute(*stages)
        yield values[0], (values[1] if native else None)


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def render_chunk(task: ChunkTask) -> ChunkResult:
    """Render and encode one chunk; errors come back in ``ChunkResult.error``."""
    t0 = time.perf_counter()
    res = ChunkResult(job=task.job, index=task.index, pid=os.getpid(), host=socket.gethostname())
    try:
        pipe = load_scene_pipeline(task.scene)
        if task.threads is not None:
            from ..render.config import RenderConfig

            cfg = pipe.render_config or RenderConfig()
            if cfg.num_threads != task.threads:
                import dataclasses

                pipe.set_render(config=dataclasses.replace(cfg, num_threads=int(task.threads)))
        pipe.set_view(tile_scale=task.tile_scale)
        want = set(task.outputs)
        encoders = {}
        if "quilt_mp4" in want:
            encoders["quilt_mp4"] = SegmentEncoder(task.fps, crf=task.crf)
        if "native_mp4" in want:
            encoders["native_mp4"] = SegmentEncoder(task.fps, rgb=True, crf=task.native_crf)
        pngs: dict[str, list[bytes]] = {k: [] for k in ("quilt_png", "native_png") if k in want}
        try:
            for quilt, native in render_frames(pipe, task.frames, task.named, task.pain,
                                               native=bool(want & {"native_mp4", "native_png"})):
                for kind, img in (("quilt", quilt), ("native", native)):
                    if f"{kind}_mp4" in encoders:
                        encoders[f"{kind}_mp4"].write(img)
                    if f"{kind}_png" in pngs:
                        pngs[f"{kind}_png"].append(_png(img))
                res.n_frames += 1
            res.segments = {k: e.finish() for k, e in encoders.items()}
        finally:
            for e in encoders.values():
                e.close()
        res.pngs = pngs
    except HoloViewerError as exc:
        res.error = str(exc)
    except Exception as exc:  # a bug: the job fails alone, with the traceback for the report
        res.error = f"internal error {type(exc).__name__}: {exc}\n{traceback.format_exc(limit=8)}"
    res.seconds = time.perf_counter() - t0
    return res
