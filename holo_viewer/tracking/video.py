"""Track a recorded video: frames at any rate in, a 25 fps ``speaker.npz`` that ``react`` reads out.

The video is sampled at the reaction model's 25 fps: output frame ``i`` (time ``i / 25`` s) is
the video frame shown at that time (the latest frame with ``t_frame <= i / 25``). The output has
``T = floor(duration * 25)`` frames, so a WAV recorded with the video spans the same frames
within one frame, as ``react`` requires.

Output keys (docs/live.md): ``expr`` (T, n_expr), ``jaw_pose`` (T, 3), ``rotation`` (T, 3)
(GaussianAvatars flame_param names, the speaker's state), ``fps`` (25), plus ``state``
(T, n_au + 6), ``found`` (T,) bool, ``head_position`` (T, 3) (webcam coordinates, metres; NaN
where no face), ``landmarks`` (T, 68, 2) (NaN where no face), ``rms_px`` (T,).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ..errors import InputError, TrackingError
from .tracker import FaceTracker, TrackerConfig

__all__ = ["iter_video_frames", "track_video", "FPS"]

FPS = 25


def iter_video_frames(path: str | os.PathLike) -> Iterator[tuple[float, np.ndarray]]:
    """(time_s, frame (H, W, 3) uint8) of every frame of a video file (imageio + its bundled ffmpeg)."""
    import imageio.v2 as imageio

    p = Path(path)
    if not p.is_file():
        raise TrackingError(f"{p}: video file not found")
    try:
        # one decoder thread: ffmpeg's default frame threads cost ~25 % more CPU on a 480x360 clip (the live
        # loop's replayed webcam beside the render; issue 37); the frames are the same
        reader = imageio.get_reader(os.fspath(p), format="FFMPEG", input_params=["-threads", "1"])
    except (OSError, ValueError, RuntimeError) as exc:
        raise TrackingError(f"{p}: cannot open the video ({exc})") from exc
    try:
        fps = float(reader.get_meta_data().get("fps") or 0.0)
        if not fps > 0:
            raise TrackingError(f"{p}: the video has no frame rate in its metadata")
        for i, frame in enumerate(reader):
            yield i / fps, np.asarray(frame)[..., :3]
    except (OSError, RuntimeError) as exc:
        raise TrackingError(f"{p}: cannot decode the video ({exc})") from exc
    finally:
        reader.close()


def track_video(path: str | os.PathLike, config: TrackerConfig = TrackerConfig(),
                progress: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """Track every 25 fps sample of a video (see the module docstring); returns the npz arrays."""
    tracker = FaceTracker(config)
    rows: list = []
    last = None
    n_out = 0
    for t, frame in iter_video_frames(path):
        # emit the output frames whose time lies before this video frame, from the previous one
        while last is not None and n_out / FPS < t - 1e-9:
            rows.append(tracker(last, n_out / FPS))
            n_out += 1
            if progress:
                progress(n_out)
        last = frame
        end_t = t
    if last is None:
        raise TrackingError(f"{path}: the video has no frames")
    # the last video frame covers [end_t, end_t + 1/fps_video); keep samples up to end_t
    while n_out / FPS <= end_t + 1e-9:
        rows.append(tracker(last, n_out / FPS))
        n_out += 1
    if not rows:
        raise InputError(f"{path}: the video is shorter than one 25 fps frame")
    states = np.stack([r.state for r in rows])
    fl = tracker.flame_params(states)
    nan_lm = np.full((68, 2), np.nan)
    return {
        "expr": fl["expr"], "jaw_pose": fl["jaw_pose"], "rotation": fl["rotation"], "fps": np.array(FPS),
        "state": states.astype(np.float32),
        "found": np.array([r.found for r in rows]),
        "head_position": np.stack([r.head_position for r in rows]).astype(np.float32),
        "landmarks": np.stack([r.faces[0].landmarks if r.faces else nan_lm for r in rows]).astype(np.float32),
        "rms_px": np.array([r.rms_px for r in rows], dtype=np.float32),
    }
