"""Video segments of frame chunks, and joining them into one mp4 without re-encoding.

A long clip is rendered as chunks on several workers. Each chunk is encoded once, by the worker
that rendered it, into an H.264 **MPEG-TS segment** held in memory (ffmpeg reads raw RGB frames
on stdin and writes the segment to stdout: no temporary file on the worker, so a killed worker
leaves nothing behind). Every segment starts with an IDR frame (a fresh encoder), so the segments
are independently decodable; :func:`join_segments` then concatenates them with ffmpeg's concat
demuxer and ``-c copy`` into one mp4: the packets are copied, not decoded and re-encoded, so the
joined video decodes to exactly the frames of its segments (``tests/test_batch.py`` checks this
bit for bit). MPEG-TS rather than raw H.264 because it carries timestamps: B-frames survive the
join (a raw ``.h264`` stream lost frames in our test), and rather than mp4 segments because it
can be written to a pipe.

Why not lossless intermediate frames encoded once at the end? A 3360x3360 quilt is ~10 MB as
PNG, so a 30 s clip would move 7.5 GB between workers and the joiner, and the final encode would be
serial; segments move ~1 MB per second of video and the encode runs in parallel. The cost: one
extra keyframe per chunk (a 25-frame chunk adds about one IDR per second; x264's default is one
per 250 frames), i.e. slightly larger files at the same quality.

Two kinds of stream:

* quilt video: libx264, yuv420p, ``crf`` (default 18), like ``display.export.write_quilt_video``
  (odd sizes get an edge row on top / column on the right, so bottom-left tiles keep their place);
* native video: RGB H.264 (libx264rgb, High 4:4:4), **lossless** by default (``native_crf`` 0).
  Each subpixel of a lenticular native image belongs to another view: chroma subsampling would
  blend views (the reason native stills are PNG, never JPEG). Lossless costs ~2 MB per
  1536x2048 frame; a row's ``native_crf`` > 0 trades exactness for size, still without
  subsampling.
"""

from __future__ import annotations

import os
import subprocess
import threading
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..errors import ExportError
from ..fileio import atomic_path
from ..media import encoder_flags, ffmpeg_exe, pad_even  # re-exported: one ffmpeg and one padding rule

__all__ = ["SegmentEncoder", "encode_segment", "join_segments", "read_video_frames", "ffmpeg_exe", "pad_even"]


class SegmentEncoder:
    """Encode frames, pushed one at a time, into an in-memory H.264 MPEG-TS segment.

    ffmpeg reads raw RGB on stdin and writes the segment to stdout, drained by a thread, so
    several encoders (quilt and native) can be fed from one render loop with one frame each in
    memory. Use as a context manager (the process is killed if the block raises) and call
    :meth:`finish` for the bytes.

    Parameters
    ----------
    fps : float
        Frame rate written into the segment's timestamps.
    rgb : bool
        True: libx264rgb, RGB without chroma subsampling (native images; ``crf=0`` is bit-exact);
        False: libx264 yuv420p (quilts, what players and Looking Glass tools expect).
    crf : int
        Quality (0..51, lower is better; 0 with ``rgb`` is lossless).
    preset : str
        x264 speed preset.
    """

    def __init__(self, fps: float, *, rgb: bool = False, crf: int = 18, preset: str = "veryfast") -> None:
        self.fps, self.rgb, self.crf, self.preset = float(fps), bool(rgb), int(crf), preset
        self.n_frames = 0
        self._shape: tuple[int, ...] | None = None
        self._proc: subprocess.Popen | None = None
        self._out: list[bytes] = []
        self._err: list[bytes] = []
        self._threads: list[threading.Thread] = []

    def _start(self, h: int, w: int) -> None:
        # the one codec policy (media.CODECS): lossless RGB for native images, watchable yuv420p for quilts
        codec = encoder_flags("lossless" if self.rgb else "watchable", crf=self.crf, preset=self.preset)
        cmd = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
               "-s", f"{w}x{h}", "-r", f"{self.fps:.6g}", "-i", "pipe:0", *codec, "-f", "mpegts", "pipe:1"]
        self._proc = proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                             stderr=subprocess.PIPE)
        self._threads = [threading.Thread(target=lambda: self._out.append(proc.stdout.read()), daemon=True),
                         threading.Thread(target=lambda: self._err.append(proc.stderr.read()), daemon=True)]
        for t in self._threads:
            t.start()

    def write(self, frame: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 frame (all frames the same size)."""
        f = _check(frame, self.n_frames)
        if not self.rgb:
            f = pad_even(f)
        if self._proc is None:
            self._shape = f.shape
            self._start(f.shape[0], f.shape[1])
        elif f.shape != self._shape:
            raise ExportError(f"segment frame {self.n_frames}: expected shape {self._shape} like frame 0, "
                              f"found {f.shape}")
        try:
            self._proc.stdin.write(np.ascontiguousarray(f).tobytes())
        except BrokenPipeError:
            self._fail()  # ffmpeg exited early: its exit code and message say why
        self.n_frames += 1

    def _wait(self) -> int:
        assert self._proc is not None
        try:
            self._proc.stdin.close()
        except BrokenPipeError:
            pass
        for t in self._threads:
            t.join()
        return self._proc.wait()

    def _fail(self) -> None:
        code = self._wait()
        msg = b"".join(self._err).decode(errors="replace").strip()[-500:]
        raise ExportError(f"segment: ffmpeg failed with exit code {code}: {msg}")

    def finish(self) -> bytes:
        """Close the stream; the segment's bytes."""
        if self._proc is None:
            raise ExportError("segment: no frames to encode")
        if self._wait() != 0:
            self._fail()
        return b"".join(self._out)

    def close(self) -> None:
        """Kill ffmpeg if it still runs (after an error)."""
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._wait()

    def __enter__(self) -> "SegmentEncoder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def encode_segment(frames: Iterable[np.ndarray], fps: float, *, rgb: bool = False, crf: int = 18,
                   preset: str = "veryfast") -> tuple[bytes, int]:
    """Encode frames into an in-memory H.264 MPEG-TS segment (see :class:`SegmentEncoder`).

    Returns
    -------
    segment : bytes
    n_frames : int

    Raises
    ------
    ExportError
        No frames, frames of different sizes or types, or ffmpeg failed (its message is included).
    """
    with SegmentEncoder(fps, rgb=rgb, crf=crf, preset=preset) as enc:
        for f in frames:
            enc.write(f)
        return enc.finish(), enc.n_frames


def _check(frame: np.ndarray, k: int) -> np.ndarray:
    f = np.asarray(frame)
    if f.dtype != np.uint8 or f.ndim != 3 or f.shape[2] != 3:
        raise ExportError(f"segment frame {k}: expected (H, W, 3) uint8, found {f.shape} {f.dtype}")
    return f


def join_segments(segments: list[str | os.PathLike], out: str | os.PathLike, frames: int | None = None) -> Path:
    """Concatenate MPEG-TS segments into one mp4 by stream copy (no re-encoding), atomically.

    Parameters
    ----------
    segments : list of path-like
        Segment files in play order (from :func:`encode_segment`, same codec settings).
    out : path-like
        The ``.mp4`` to write (a temporary file renamed into place on success).
    frames : int, optional
        Frames the joined video must decode to; checked before the rename (``media.count_video_frames``).
    """
    if not segments:
        raise ExportError(f"{out}: no segments to join")
    target = Path(out)
    if target.suffix.lower() != ".mp4":
        raise ExportError(f"{target}: expected an .mp4 file name")
    with atomic_path(target) as tmp:
        listing = tmp.with_name(tmp.name + ".txt")
        try:
            with open(listing, "w", encoding="utf-8") as fh:
                for s in segments:
                    fh.write("file '" + str(Path(s).resolve()).replace("'", "'\\''") + "'\n")
            cmd = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y", "-f", "concat", "-safe", "0",
                   "-i", str(listing), "-c", "copy", "-movflags", "+faststart", "-f", "mp4", str(tmp)]
            res = subprocess.run(cmd, capture_output=True, text=True)
        finally:
            listing.unlink(missing_ok=True)
        if res.returncode != 0:
            raise ExportError(f"{target}: joining {len(segments)} segments failed (ffmpeg exit code "
                              f"{res.returncode}): {res.stderr.strip()[-500:]}")
        if frames is not None:
            from ..media import count_video_frames

            n = count_video_frames(tmp)
            if n != frames:
                raise ExportError(f"{target}: the joined video holds {n} of {frames} frames (a full disk?); "
                                  f"nothing was written")
    return target


def read_video_frames(path: str | os.PathLike) -> Iterator[np.ndarray]:
    """Decode a video (mp4 or MPEG-TS) to (H, W, 3) uint8 RGB frames, each stored frame once
    (:func:`holo_viewer.media.read_frames`; for checks and tests)."""
    from ..media import read_frames

    return read_frames(path)
