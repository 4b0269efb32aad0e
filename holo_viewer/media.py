"""One verified, atomic video writer: every video the package writes goes through here.

:class:`VideoWriter` pipes raw RGB frames into the ffmpeg of imageio-ffmpeg (a dependency), writes
a hidden temporary next to the target (:func:`~holo_viewer.fileio.atomic_path`) and renames it into
place only after both checks pass:

* ffmpeg's **exit status** is 0 (imageio-ffmpeg's own writer ignores it, so a full disk while
  ffmpeg wrote the index left an unplayable file that was then renamed into place), and
* the finished file **decodes to exactly the frames written** (ffmpeg counts them).

Otherwise an :class:`~holo_viewer.errors.ExportError` names the file and the reason, nothing
appears under the final name and an earlier file there is unchanged.

Interruption: a frame is written whole. A Ctrl-C (SIGINT) or SIGTERM arriving while a frame is
being piped is held until the frame is complete and then raised, so the caller's ``finally``
can :meth:`~VideoWriter.close` (finish, verify, rename) a video holding every frame it counted.
Session videos (``streaming=True``) are fragmented MP4: a process killed outright (SIGKILL, power
loss) leaves a temporary that still plays up to its last fragment, never a file without an index.

Codec settings stay those of each caller (issue 33 owns the codec policy): ``quality`` follows
imageio-ffmpeg's 0-10 scale (libx264: ``crf = int((1 - quality / 10) * 51)``), ``macro_block_size``
scales frames up to a multiple of it, as imageio-ffmpeg did.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from .errors import ExportError
from .fileio import atomic_path

__all__ = ["VideoWriter", "write_video", "count_video_frames", "ffmpeg_exe", "pad_even"]

#: ffmpeg flags that make an MP4 playable while it is written (fragments, index up front)
STREAMING_MOVFLAGS = "+frag_keyframe+empty_moov+default_base_moof"


def ffmpeg_exe() -> str:
    """The ffmpeg binary of imageio-ffmpeg (a dependency; no system ffmpeg needed)."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def pad_even(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 with an edge row on top / column on the right where H / W is odd (yuv420p).

    Tile positions measured from the bottom-left (quilts) are unchanged.
    """
    f = frame
    if f.shape[1] % 2:
        f = np.concatenate([f, f[:, -1:]], axis=1)
    if f.shape[0] % 2:
        f = np.concatenate([f[:1], f], axis=0)
    return f


def count_video_frames(path: str | os.PathLike) -> int:
    """Frames ffmpeg decodes from ``path``.

    Raises
    ------
    ExportError
        ffmpeg cannot read the file (its last message is quoted).
    """
    import imageio_ffmpeg

    try:
        n, _ = imageio_ffmpeg.count_frames_and_secs(os.fspath(path))
    except (RuntimeError, OSError, ValueError) as exc:
        last = str(exc).strip().splitlines()[-1:] or [""]
        raise ExportError(f"{path}: not a readable video ({last[0][:300]})") from exc
    return int(n)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Hold SIGINT/SIGTERM (main thread only) until the block ends, then deliver them.

    A Python handler raising in the middle of a pipe write would leave a partial frame in
    ffmpeg's input; held, the frame completes and the same handler then runs.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    saved: dict[int, Any] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(sig)
        if callable(handler):
            saved[sig] = handler
            signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        for signum in pending[:1]:
            saved[signum](signum, None)


class VideoWriter:
    """Write frames to a video file atomically; the file is verified before it is renamed into place.

    Parameters
    ----------
    path : path-like
        Target file (``.mp4``; ``.mkv`` also works).
    fps : float
        Frames per second (> 0, finite).
    codec : str
        ffmpeg video codec (default libx264).
    quality : float, optional
        imageio-ffmpeg's 0-10 quality (libx264: ``crf = int((1 - quality / 10) * 51)``).
    pixelformat : str
        Output pixel format (default yuv420p).
    macro_block_size : int
        Frames whose sides are not multiples of it are scaled up to the next multiple (1: none;
        then odd sides are padded by an edge row on top / column on the right for yuv420p).
    output_params : sequence of str
        Extra ffmpeg output flags (``["-preset", "medium", "-crf", "18"]``).
    streaming : bool
        Fragmented MP4, playable up to the last fragment if the process is killed (live sessions).
    what : str
        Name used in error messages ("session video", "quilt video").

    Use as a context manager, or call :meth:`write` and then :meth:`close` (or :meth:`abort`).
    """

    def __init__(self, path: str | os.PathLike, fps: float, *, codec: str = "libx264", quality: float | None = None,
                 pixelformat: str = "yuv420p", macro_block_size: int = 1, output_params: Sequence[str] = (),
                 streaming: bool = False, what: str = "video") -> None:
        fps = float(fps)
        if not np.isfinite(fps) or fps <= 0:
            raise ExportError(f"{path}: fps: expected a finite number > 0, found {fps}")
        self.path = Path(path)
        self.fps, self.codec, self.quality, self.pixelformat = fps, codec, quality, pixelformat
        self.macro_block_size, self.output_params = int(macro_block_size), list(output_params)
        self.streaming, self.what = streaming, what
        self.frames = 0
        self._shape: tuple[int, ...] | None = None
        self._proc: subprocess.Popen | None = None
        self._log: Any = None
        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        self._closed = False

    # ------------------------------------------------------------------ ffmpeg
    def _command(self, width: int, height: int) -> list[str]:
        cmd = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
               "-s", f"{width}x{height}", "-r", f"{self.fps:.6g}", "-i", "-", "-an", "-vcodec", self.codec,
               "-pix_fmt", self.pixelformat]
        if self.quality is not None:
            q = 1.0 - float(self.quality) / 10.0
            cmd += ["-crf", str(int(q * 51))] if self.codec == "libx264" else ["-qscale:v", str(1 + int(q * 30))]
        m = self.macro_block_size
        if m > 1 and (width % m or height % m):
            cmd += ["-vf", f"scale={-(-width // m) * m}:{-(-height // m) * m}"]
        cmd += self.output_params
        if self.streaming:
            cmd += ["-movflags", STREAMING_MOVFLAGS]
        fmt = {".mp4": "mp4", ".mkv": "matroska", ".mov": "mov"}.get(self.path.suffix.lower())
        return cmd + (["-f", fmt] if fmt else []) + [os.fspath(self._tmp)]

    def _start(self, width: int, height: int) -> None:
        self._log = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(self._command(width, height), stdin=subprocess.PIPE,
                                      stdout=subprocess.DEVNULL, stderr=self._log)

    def _ffmpeg_message(self) -> str:
        if self._log is None:
            return ""
        self._log.seek(0)
        lines = self._log.read().decode("utf-8", "replace").strip().splitlines()
        return lines[-1][:300] if lines else ""

    # ------------------------------------------------------------------ frames
    def write(self, frame: np.ndarray) -> None:
        """Append one (H, W, 3) frame (uint8, or float in [0, 1]); all frames the size of the first."""
        from .images import to_uint8

        if self._closed:
            raise ExportError(f"{self.path}: the {self.what} is already closed")
        f = to_uint8(frame, name="frame")
        if f.ndim != 3 or f.shape[2] != 3:
            raise ExportError(f"{self.path}: frame {self.frames}: expected (H, W, 3), found {f.shape}")
        if self._shape is None:
            self._shape = f.shape
        elif f.shape != self._shape:
            raise ExportError(f"{self.path}: frame {self.frames}: expected shape {self._shape} like frame 0, "
                              f"found {f.shape}")
        if self.macro_block_size <= 1 and self.pixelformat == "yuv420p":
            f = pad_even(f)
        data = np.ascontiguousarray(f).data
        with _signals_held():
            if self._proc is None:
                self._start(f.shape[1], f.shape[0])
            try:
                self._write_frame(data)
            except (BrokenPipeError, OSError) as exc:
                self.abort()
                raise ExportError(f"{self.path}: cannot write the {self.what}: ffmpeg stopped "
                                  f"({self._ffmpeg_message() or exc}); nothing was written") from None
            self.frames += 1

    def _write_frame(self, data: memoryview) -> None:
        """Pipe one whole frame into ffmpeg."""
        assert self._proc is not None and self._proc.stdin is not None
        self._proc.stdin.write(data)

    # ------------------------------------------------------------------ finish
    def close(self) -> Path:
        """Finish the file, check ffmpeg's exit status and the decoded frame count, rename it into place.

        Raises
        ------
        ExportError
            No frames, ffmpeg failed (a full disk, a killed encoder) or the file holds another
            number of frames than were written; nothing is renamed into place.
        """
        if self._closed:
            return self.path
        with _signals_held():
            try:
                if self._proc is None:
                    raise ExportError(f"{self.path}: no frames to write")
                try:
                    self._proc.stdin.close()  # type: ignore[union-attr]
                except OSError:
                    pass
                code = self._proc.wait()
                if code != 0:
                    raise ExportError(f"{self.path}: cannot write the {self.what}: ffmpeg exited with status {code} "
                                      f"({self._ffmpeg_message() or 'no message'}); nothing was written")
                try:
                    n = count_video_frames(self._tmp)
                except ExportError as exc:
                    raise ExportError(f"{self.path}: ffmpeg did not produce a readable {self.what} (a full disk or "
                                      f"a killed encoder?); nothing was written ({exc})") from None
                if n != self.frames:
                    raise ExportError(f"{self.path}: ffmpeg wrote {n} of {self.frames} frames (a full disk or a "
                                      f"killed encoder?); nothing was written")
            except BaseException as exc:
                self._finish(exc)
                raise
            self._finish(None)
        return self.path

    def abort(self) -> None:
        """Stop ffmpeg and remove the temporary; nothing is written (an earlier file stays)."""
        if self._closed:
            return
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
        self._finish(ExportError("aborted"))

    def _finish(self, exc: BaseException | None) -> None:
        self._closed = True
        if self._proc is not None:
            if self._proc.poll() is None:
                self._proc.kill()
            self._proc.wait()
            with contextlib.suppress(OSError):
                self._proc.stdin.close()  # type: ignore[union-attr]
        if self._log is not None:
            self._log.close()
        if exc is None:
            self._stack.close()  # renames the verified temporary into place
        else:
            self._stack.__exit__(type(exc), exc, exc.__traceback__)  # removes the temporary

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float, **options: Any) -> Path:
    """Write all ``frames`` with one :class:`VideoWriter` (``options`` as its keywords); verified, atomic."""
    with VideoWriter(path, fps, **options) as writer:
        for frame in frames:
            writer.write(frame)
    return Path(path)
