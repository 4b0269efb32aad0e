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

Codec policy (:data:`CODECS`, one ``content`` per writer):

* ``"lossless"`` (the default): native images and quilts, RGB H.264 (libx264rgb, ``-crf 0``) that
  decodes bit-exact to the frames written. Chroma subsampling (yuv420p) would mix neighbouring
  subpixels, and each subpixel of a native image belongs to another view (rainbow fringes, 28 dB).
* ``"preview"``: what a person watches and nothing reads back (webcam, speaker clips): libx264 yuv420p
  at imageio-ffmpeg's quality 7 (``crf = int((1 - quality / 10) * 51)``), sides scaled up to a
  multiple of ``macro_block_size`` 8.
* ``"watchable"``: quilt videos of batch renders (what players and Looking Glass tools expect):
  libx264 yuv420p, crf 18, veryfast; odd sides padded by an edge row / column.
* ``"lossless-fast"``: bit-exact like ``"lossless"`` for ~50-60 % of its encoder CPU and ~2.2x its disk: FFVHuff
  (Huffman-coded plane prediction, every frame on its own), packed RGB. The live session's video with
  ``live --native-codec ffvhuff`` (issue 37: ~14-17 ms less CPU a displayed frame expected on 2 quiet cores).

The lossless preset is ``ultrafast``: on 2048x1536 session frames slower presets save 16 % of the
size for 3x the encoder's CPU and FFV1 3 % for 1.7x (``bench/session_codecs.py``, docs/live.md),
and on a 2-core machine the live render needs that CPU. Re-laying a native image's subpixels by view
before encoding (each view's together, from the calibration's lens model: quilt-like content) was
measured too and does not pay: 1-2 % smaller, the same encoder CPU, plus ~10 ms of CPU a frame for the
permutation (issue 37, docs/live.md). :func:`encoder_flags` gives the policy's
flags to the one writer that drives ffmpeg itself (``batch/video.py``'s in-memory segments).

**Timed** writers (``timed=True``; live session videos, ``.mkv``) record each frame once with its
presentation time, ``write(frame, t=seconds)``: frames go to ffmpeg in a Matroska stream of raw RGB
blocks carrying their timestamps (ms) and durations (:func:`_mkv_header`, :func:`_mkv_block`), so
a frame held on screen for 300 ms is one encoded frame lasting 300 ms (variable frame rate, not
re-encoded), the video plays in step with ``audio.wav``, and :meth:`VideoWriter.close` with
``end_s`` makes it last as long as the session. Decode at a constant rate with
``read_frames(path, fps=25)``. Matroska survives an interruption: a killed process leaves a file
that plays up to its last cluster.
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

__all__ = ["VideoWriter", "ThreadedWriter", "write_video", "count_video_frames", "read_frames", "mux_audio", "ffmpeg_exe", "pad_even",
           "CODECS", "encoder_flags"]

#: the pipe into ffmpeg holds this many bytes (Linux ``F_SETPIPE_SZ``; 0: the system's 64 KiB): a 9.4 MB
#: native frame then crosses in ~9 writes instead of ~144: ~0.5-2 ms less CPU a frame for the writer and ffmpeg
#: together (issue 37, docs/live.md; paired rounds at load 18-19, near the noise)
PIPE_BYTES = 1 << 20
#: ffmpeg flags that make an MP4 playable while it is written (fragments, index up front)
STREAMING_MOVFLAGS = "+frag_keyframe+empty_moov+default_base_moof"

#: the codec policy: content -> VideoWriter settings (see the module docstring)
CODECS: dict[str, dict[str, Any]] = {
    "lossless": {"codec": "libx264rgb", "pixelformat": "rgb24", "quality": None, "macro_block_size": 1,
                 "output_params": ("-preset", "ultrafast", "-crf", "0")},
    "preview": {"codec": "libx264", "pixelformat": "yuv420p", "quality": 7, "macro_block_size": 8,
                "output_params": ()},
    "watchable": {"codec": "libx264", "pixelformat": "yuv420p", "quality": None, "macro_block_size": 1,
                  "output_params": ("-preset", "veryfast", "-crf", "18")},
    "lossless-fast": {"codec": "ffvhuff", "pixelformat": "rgb24", "quality": None, "macro_block_size": 1,
                      "output_params": ("-pred", "plane")},
}


def encoder_flags(content: str, *, crf: int | None = None, preset: str | None = None) -> list[str]:
    """ffmpeg's video encoder flags (codec, preset, crf, pixel format) of the codec policy for
    ``content`` (:data:`CODECS`), ``crf`` / ``preset`` replacing the policy's: for writers that
    drive ffmpeg themselves (``batch/video.py``'s in-memory segments).

    Raises
    ------
    ExportError
        An unknown ``content``, or one without a crf (``preview`` sets a quality).
    """
    if content not in CODECS or "-crf" not in CODECS[content]["output_params"]:
        raise ExportError(f"content: expected one of {sorted(k for k, v in CODECS.items() if '-crf' in v['output_params'])}"
                          f", found {content!r}")
    policy = CODECS[content]
    params = dict(zip(policy["output_params"][::2], policy["output_params"][1::2]))
    if crf is not None:
        params["-crf"] = str(int(crf))
    if preset is not None:
        params["-preset"] = str(preset)
    return ["-c:v", policy["codec"], *[x for kv in params.items() for x in kv], "-pix_fmt", policy["pixelformat"]]


def _ebml(element_id: bytes, payload: bytes) -> bytes:
    """One EBML element: id, 8-byte size, payload."""
    return element_id + b"\x01" + len(payload).to_bytes(7, "big") + payload


def _ebml_uint(element_id: bytes, value: int) -> bytes:
    return _ebml(element_id, int(value).to_bytes(8, "big"))


def _mkv_header(width: int, height: int) -> bytes:
    """A Matroska stream header (ms timestamps) with one raw RGB24 video track (V_UNCOMPRESSED)."""
    ebml = _ebml(b"\x1a\x45\xdf\xa3", _ebml_uint(b"\x42\x86", 1) + _ebml_uint(b"\x42\xf7", 1)
                 + _ebml_uint(b"\x42\xf2", 4) + _ebml_uint(b"\x42\xf3", 8) + _ebml(b"\x42\x82", b"matroska")
                 + _ebml_uint(b"\x42\x87", 4) + _ebml_uint(b"\x42\x85", 2))
    info = _ebml(b"\x15\x49\xa9\x66", _ebml_uint(b"\x2a\xd7\xb1", 1_000_000)
                 + _ebml(b"\x4d\x80", b"holo_viewer") + _ebml(b"\x57\x41", b"holo_viewer"))
    video = _ebml(b"\xe0", _ebml_uint(b"\xb0", width) + _ebml_uint(b"\xba", height)
                  + _ebml(b"\x2e\xb5\x24", b"RGB\x18"))
    track = _ebml(b"\xae", _ebml_uint(b"\xd7", 1) + _ebml_uint(b"\x73\xc5", 1) + _ebml_uint(b"\x83", 1)
                  + _ebml(b"\x86", b"V_UNCOMPRESSED") + video)
    segment_unknown_size = b"\x18\x53\x80\x67\x01\xff\xff\xff\xff\xff\xff\xff"
    return ebml + segment_unknown_size + info + _ebml(b"\x16\x54\xae\x6b", track)


def _mkv_block(t_ms: int, duration_ms: int, nbytes: int) -> bytes:
    """The bytes before one frame's ``nbytes`` of raw RGB: a cluster at ``t_ms`` holding one block
    group (the block, track 1, and its duration)."""
    head = b"\x81\x00\x00\x00"  # track 1, relative time 0, no flags
    duration = _ebml_uint(b"\x9b", duration_ms)
    block_size = len(head) + nbytes
    group_size = len(duration) + 9 + block_size
    stamp = _ebml_uint(b"\xe7", t_ms)
    cluster_size = len(stamp) + 9 + group_size
    size = lambda n: b"\x01" + n.to_bytes(7, "big")  # noqa: E731
    return (b"\x1f\x43\xb6\x75" + size(cluster_size) + stamp + b"\xa0" + size(group_size) + duration
            + b"\xa1" + size(block_size) + head)


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


def read_frames(path: str | os.PathLike, fps: float | None = None) -> Iterator[np.ndarray]:
    """Decode a video to (H, W, 3) uint8 RGB frames: each stored frame once, or with ``fps`` at that
    constant rate (a frame held for 300 ms comes ``round(0.3 * fps)`` times: frame ``round(t * fps)``
    is what was shown at time ``t``; a timed video's first frame also stands for the time before it)."""
    import imageio_ffmpeg

    # -copyts: the stored times (a live session's first frame is shown a little after 0), counted from 0
    out = ["-vf", f"fps={float(fps):.6g}:start_time=0"] if fps else ["-fps_mode", "passthrough"]
    gen = imageio_ffmpeg.read_frames(os.fspath(path), pix_fmt="rgb24", input_params=["-copyts"], output_params=out)
    meta = next(gen)
    w, h = meta["size"]
    for buf in gen:
        yield np.frombuffer(buf, np.uint8).reshape(h, w, 3)


def count_video_frames(path: str | os.PathLike) -> int:
    """Frames ffmpeg reads from ``path``: its video packets, one per frame for every codec written
    here, counted by a stream copy (``-c copy -f null``) without decoding them. A file cut short
    loses its last packet and counts one frame less, as a decode does; the decoding count took
    ~0.1 s of CPU per 2048x1536 lossless frame (a live session's quit and each replayed frame paid
    it), the packet count ~0.01 s for 20 frames.

    Raises
    ------
    ExportError
        ffmpeg cannot read the file (its last message is quoted).
    """
    import re

    proc = subprocess.run([ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", os.fspath(path), "-map", "0:v:0",
                           "-c", "copy", "-f", "null", "-"], capture_output=True)
    err = proc.stderr.decode("utf-8", "replace")
    counts = re.findall(r"frame=\s*(\d+)", err)
    if proc.returncode != 0 or not counts:
        last = err.strip().splitlines()[-1:] or ["no message"]
        raise ExportError(f"{path}: not a readable video ({last[0][:300]})")
    return int(counts[-1])


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
        Target file (``.mkv``, ``.mp4``, ``.mov``).
    fps : float
        Frames per second (> 0, finite); a timed writer's nominal rate (its frames carry their times).
    content : {"lossless", "lossless-fast", "preview", "watchable"}
        The codec policy (:data:`CODECS`): its codec, pixel format, quality, macro block size and
        flags, each overridden by the keyword of that name when given.
    codec : str, optional
        ffmpeg video codec.
    quality : float, optional
        imageio-ffmpeg's 0-10 quality (libx264: ``crf = int((1 - quality / 10) * 51)``).
    pixelformat : str, optional
        Output pixel format.
    macro_block_size : int, optional
        Frames whose sides are not multiples of it are scaled up to the next multiple (1: none;
        then odd sides are padded by an edge row on top / column on the right for yuv420p).
    output_params : sequence of str, optional
        ffmpeg output flags (``["-preset", "medium", "-crf", "18"]``).
    streaming : bool
        Fragmented MP4, playable up to the last fragment if the process is killed (MP4 targets).
    timed : bool
        Each frame written with its presentation time (``write(frame, t=...)``); variable frame rate.
    what : str
        Name used in error messages ("session video", "quilt video").
    nice : int
        Run ffmpeg this much nicer than the caller (set right after it starts, before it starts its
        encoder threads, which inherit it; where the OS has priorities). The live session's video
        uses it so the encoder runs in the render's gaps instead of taking a core from it.

    Use as a context manager, or call :meth:`write` and then :meth:`close` (or :meth:`abort`).
    """

    def __init__(self, path: str | os.PathLike, fps: float, *, content: str = "lossless", codec: str | None = None,
                 quality: float | None = None, pixelformat: str | None = None, macro_block_size: int | None = None,
                 output_params: Sequence[str] | None = None, streaming: bool = False, timed: bool = False,
                 what: str = "video", nice: int = 0) -> None:
        fps = float(fps)
        if not np.isfinite(fps) or fps <= 0:
            raise ExportError(f"{path}: fps: expected a finite number > 0, found {fps}")
        if content not in CODECS:
            raise ExportError(f"{path}: content: expected one of {sorted(CODECS)}, found {content!r}")
        policy = CODECS[content]
        self.path = Path(path)
        self.content, self.fps = content, fps
        self.codec = codec or policy["codec"]
        self.quality = quality if quality is not None or codec is not None else policy["quality"]
        self.pixelformat = pixelformat or policy["pixelformat"]
        self.macro_block_size = int(macro_block_size if macro_block_size is not None else policy["macro_block_size"])
        self.output_params = list(output_params if output_params is not None else policy["output_params"])
        self.streaming, self.timed, self.what = streaming, timed, what
        self.nice = int(nice)
        self.frames = 0
        #: a timed writer's newest frame and its time in ms, held until the next one gives its duration
        self._held: tuple[bytes, int] | None = None
        self._shape: tuple[int, ...] | None = None
        self._proc: subprocess.Popen | None = None
        self._log: Any = None
        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        self._closed = False

    # ------------------------------------------------------------------ ffmpeg
    def _command(self, width: int, height: int) -> list[str]:
        if self.timed:  # raw RGB in Matroska: each frame carries its time and duration
            cmd = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y", "-f", "matroska", "-i", "-",
                   "-fps_mode", "passthrough", "-copyts", "-enc_time_base", "1:1000",  # ms, not 1/fps: no rounding
                   "-an", "-vcodec", self.codec, "-pix_fmt", self.pixelformat]
        else:
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
        if self.streaming and self.path.suffix.lower() in (".mp4", ".mov"):  # Matroska streams as it is
            cmd += ["-movflags", STREAMING_MOVFLAGS]
        fmt = {".mp4": "mp4", ".mkv": "matroska", ".mov": "mov"}.get(self.path.suffix.lower())
        return cmd + (["-f", fmt] if fmt else []) + [os.fspath(self._tmp)]

    def _start(self, width: int, height: int) -> None:
        self._log = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(self._command(width, height), stdin=subprocess.PIPE,
                                      stdout=subprocess.DEVNULL, stderr=self._log)
        if PIPE_BYTES and hasattr(self._proc.stdin, "fileno"):
            import fcntl

            with contextlib.suppress(OSError, AttributeError):  # not Linux, or above /proc/sys/fs/pipe-max-size
                fcntl.fcntl(self._proc.stdin.fileno(), fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        if self.nice and hasattr(os, "setpriority"):
            with contextlib.suppress(OSError):  # not permitted, or ffmpeg already gone (reported by write)
                os.setpriority(os.PRIO_PROCESS, self._proc.pid, min(19, os.getpriority(os.PRIO_PROCESS, 0) + self.nice))
        if self.timed:
            self._proc.stdin.write(_mkv_header(width, height))  # type: ignore[union-attr]

    def _ffmpeg_message(self) -> str:
        if self._log is None:
            return ""
        self._log.seek(0)
        lines = self._log.read().decode("utf-8", "replace").strip().splitlines()
        return lines[-1][:300] if lines else ""

    # ------------------------------------------------------------------ frames
    def write(self, frame: np.ndarray, t: float | None = None, keep: bool = False) -> None:
        """Append one (H, W, 3) frame (uint8, or float in [0, 1]); all frames the size of the first.

        ``t``: a timed writer's presentation time in seconds (required there; later than the previous
        frame's by at least 1 ms). A timed writer pipes each frame when the next one arrives (its
        duration is then known) or at :meth:`close`; it holds a copy of it meanwhile, or with ``keep``
        (the caller never changes ``frame`` afterwards: :class:`ThreadedWriter`) the frame itself (a
        9.4 MB copy less per 2048x1536 frame).
        """
        from .images import to_uint8

        if self._closed:
            raise ExportError(f"{self.path}: the {self.what} is already closed")
        t_ms = None
        index = self.frames + (self._held is not None)  # a timed writer holds its newest frame
        if self.timed:
            if t is None or not np.isfinite(t) or t < 0:
                raise ExportError(f"{self.path}: frame {index}: t: expected a time >= 0 s, found {t}")
            t_ms = int(round(float(t) * 1000))
            if self._held is not None and t_ms <= self._held[1]:
                raise ExportError(f"{self.path}: frame {index}: t: expected later than {self._held[1] / 1000} s "
                                  f"(the previous frame's time), found {t}")
        f = to_uint8(frame, name="frame")
        if f.ndim != 3 or f.shape[2] != 3:
            raise ExportError(f"{self.path}: frame {index}: expected (H, W, 3), found {f.shape}")
        if self._shape is None:
            self._shape = f.shape
        elif f.shape != self._shape:
            raise ExportError(f"{self.path}: frame {index}: expected shape {self._shape} like frame 0, "
                              f"found {f.shape}")
        if self.macro_block_size <= 1 and self.pixelformat == "yuv420p":
            f = pad_even(f)
        if t_ms is not None:
            c = np.ascontiguousarray(f)
            held, self._held = self._held, (memoryview(c).cast("B") if keep else c.tobytes(), t_ms)
            if self._proc is None:
                with _signals_held():
                    self._start(f.shape[1], f.shape[0])
            if held is not None:
                self._pipe(held[0], held[1], t_ms - held[1])
            return
        data = np.ascontiguousarray(f).data
        with _signals_held():
            if self._proc is None:
                self._start(f.shape[1], f.shape[0])
        self._pipe(data)

    def _pipe(self, data: Any, t_ms: int | None = None, duration_ms: int = 0) -> None:
        """Pipe one frame (a timed writer's with its cluster header) into ffmpeg; count it."""
        with _signals_held():
            try:
                if t_ms is not None:
                    self._proc.stdin.write(_mkv_block(t_ms, duration_ms, len(data)))  # type: ignore[union-attr]
                self._write_frame(data)
            except (BrokenPipeError, OSError) as exc:
                if self._proc is not None:
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        self._proc.wait(timeout=1)  # ffmpeg's last words are in its log once it has exited
                why = self._ffmpeg_message() or exc  # read before abort() closes the log
                self.abort()
                raise ExportError(f"{self.path}: cannot write the {self.what}: ffmpeg stopped "
                                  f"({why}); nothing was written") from None
            self.frames += 1

    def _write_frame(self, data: memoryview) -> None:
        """Pipe one whole frame into ffmpeg."""
        assert self._proc is not None and self._proc.stdin is not None
        self._proc.stdin.write(data)

    # ------------------------------------------------------------------ finish
    def close(self, end_s: float | None = None) -> Path:
        """Finish the file, check ffmpeg's exit status and the decoded frame count, rename it into place.

        ``end_s``: a timed writer's end time (s): its last frame lasts until then, at least 2 ms
        (default: one frame at ``fps``).

        Raises
        ------
        ExportError
            No frames, ffmpeg failed (a full disk, a killed encoder) or the file holds another
            number of frames than were written; nothing is renamed into place.
        """
        if self._closed:
            return self.path
        if self._held is not None and self._proc is not None and self._proc.poll() is None:
            data, t_ms = self._held
            self._held = None
            default = int(round(1000 / self.fps))
            end_ms = t_ms + default if end_s is None or not np.isfinite(end_s) else int(round(1000 * float(end_s)))
            # >= 2 ms: ffmpeg's decoder takes a last frame lasting 1 time-base unit (1 ms) for a duration the
            # demuxer made up and holds it for the previous frame's gap instead (fftools' duration estimate):
            # a session that ended 1 ms after its last frame decoded up to a gap too long (0.1 s under load)
            self._pipe(data, t_ms, max(2, end_ms - t_ms))
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


class ThreadedWriter:
    """A timed :class:`VideoWriter` fed from a thread, so piping a 2048x1536 frame to ffmpeg (5-35 ms,
    longer while ffmpeg is busy) overlaps rendering the next one: the caller only hands the frame
    over (it must not change it afterwards); at most two frames wait. An error of the writer is
    raised at the next call. Used by ``live`` (the session video) and ``replay --quality live``."""

    def __init__(self, writer: VideoWriter) -> None:
        import queue

        self._writer = writer
        self.timed = writer.timed
        self._queue: queue.Queue = queue.Queue(maxsize=2)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="video-writer", daemon=True)
        self._thread.start()

    @property
    def frames(self) -> int:
        """Frames piped to ffmpeg (all written ones after :meth:`close`)."""
        return self._writer.frames

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is None:
                try:
                    self._writer.write(item[0], t=item[1], keep=True)  # the caller hands the frame over
                except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread
                    self._error = exc

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def write(self, frame: np.ndarray, t: float) -> None:
        self._raise()
        self._queue.put((frame, t))

    def close(self, end_s: float) -> int:
        """Wait for the queued frames, close (verify, rename) the video; returns its frame count."""
        self._queue.put(None)
        self._thread.join()
        self._raise()
        self._writer.close(end_s=end_s)
        return self._writer.frames

    def abort(self) -> None:
        self._error = self._error or RuntimeError("aborted")
        self._queue.put(None)
        self._thread.join()
        self._writer.abort()


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float, **options: Any) -> Path:
    """Write all ``frames`` with one :class:`VideoWriter` (``options`` as its keywords); verified, atomic."""
    with VideoWriter(path, fps, **options) as writer:
        for frame in frames:
            writer.write(frame)
    return Path(path)


def mux_audio(video: str | os.PathLike, audio: str | os.PathLike, out: str | os.PathLike, fps: float = 25.0,
              what: str = "review video", duration_s: float | None = None) -> Path:
    """``video`` at a constant ``fps`` (a timed video's frames held as they were shown, from time 0)
    with ``audio`` muxed in (AAC), lossless RGB video (:data:`CODECS` ``"lossless"``), atomically.
    ``duration_s``: the result's length (a session's ``end_s``): ffmpeg's ``fps`` filter otherwise
    pads a last frame held for under a frame period by up to a few frame periods.

    Raises
    ------
    ExportError
        ffmpeg failed (its message is quoted) or the result holds no frames; nothing is written.
    """
    out = Path(out)
    policy = CODECS["lossless"]
    with atomic_path(out) as tmp:
        fmt = {".mp4": "mp4", ".mkv": "matroska", ".mov": "mov"}.get(out.suffix.lower(), "matroska")
        cmd = [ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y", "-copyts", "-i", os.fspath(video),
               "-i", os.fspath(audio), "-map", "0:v:0", "-map", "1:a:0", "-vf", f"fps={float(fps):.6g}:start_time=0",
               "-vcodec", policy["codec"], "-pix_fmt", policy["pixelformat"], *policy["output_params"],
               "-c:a", "aac", "-b:a", "128k"]
        if duration_s is not None:
            if not np.isfinite(duration_s) or duration_s <= 0:
                raise ExportError(f"{out}: the {what}'s duration must be a positive number of seconds, "
                                  f"found {duration_s!r}")
            cmd += ["-t", f"{float(duration_s):.6f}"]
        cmd += ["-f", fmt, os.fspath(tmp)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            last = (proc.stderr.strip().splitlines() or ["no message"])[-1][:300]
            raise ExportError(f"{out}: cannot write the {what}: ffmpeg exited with status {proc.returncode} ({last}); "
                              f"nothing was written")
        if count_video_frames(tmp) < 1:
            raise ExportError(f"{out}: ffmpeg wrote no frames of the {what}; nothing was written")
    return out
