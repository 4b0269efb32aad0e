"""Device and replay sources of a live session (the I/O edge): audio in, video frames in.

Audio sources deliver 16 kHz mono float32 in order; ``read(upto_s)`` returns the samples from
the last read up to media time ``upto_s`` (fewer when the device has not delivered them yet) and
``finished`` says a replayed file has no more. Video sources give the latest frame at a media
time (latest wins: frames in between are skipped, never queued). ``status`` is "ok" or a short
message the overlay shows (a device that disappeared mid-session degrades to silence / no face).

* :class:`WavReplay`, :class:`VideoReplay`: files replayed against the session clock.
* :class:`ArrayAudio`: samples already in memory (the synthetic speaker).
* :class:`Microphone` (sounddevice / PortAudio), :class:`Webcam` (OpenCV): real devices; a missing
  device raises :class:`~holo_viewer.errors.DeviceError` naming it.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DeviceError, MissingDependencyError, TrackingError

__all__ = ["SAMPLE_RATE", "ArrayAudio", "WavReplay", "Microphone", "VideoReplay", "Webcam"]

SAMPLE_RATE = 16000


class ArrayAudio:
    """Replay samples (L,) float32 at 16 kHz against the media clock."""

    def __init__(self, samples: np.ndarray, name: str = "audio") -> None:
        self._x = np.asarray(samples, dtype=np.float32).reshape(-1)
        self._pos = 0
        self.name = name
        self.status = "ok"

    @property
    def duration_s(self) -> float:
        return len(self._x) / SAMPLE_RATE

    @property
    def finished(self) -> bool:
        return self._pos >= len(self._x)

    def start(self) -> None:
        self._pos = 0

    def read(self, upto_s: float) -> np.ndarray:
        end = min(len(self._x), max(self._pos, int(round(upto_s * SAMPLE_RATE))))
        out = self._x[self._pos:end]
        self._pos = end
        return out

    def stop(self) -> None:
        pass


class WavReplay(ArrayAudio):
    """A 16 kHz WAV file replayed in real time (mono; stereo is averaged)."""

    def __init__(self, path: str | os.PathLike) -> None:
        from ..reaction.audio import read_wav

        p = Path(path)
        if not p.is_file():
            raise DeviceError(f"{p}: audio file not found")
        audio, sr = read_wav(p)
        if int(sr) != SAMPLE_RATE:
            raise DeviceError(f"{p}: expected {SAMPLE_RATE} Hz audio, found {sr} Hz; resample it first")
        super().__init__(audio, name=f"file:{p}")


class Microphone:
    """The default (or given) input device through sounddevice, 16 kHz mono, blocks of 20 ms.

    A callback pushes blocks into a bounded deque (at most ``max_seconds``; older blocks are
    dropped and counted as an overflow, as PortAudio's own input overflows are).
    """

    def __init__(self, device: Any = None, max_seconds: float = 5.0) -> None:
        try:
            import sounddevice as sd
        except ImportError as exc:
            raise MissingDependencyError("sounddevice", "the microphone", extra="live") from exc
        except OSError as exc:  # sounddevice imports but PortAudio is missing
            raise DeviceError(f"microphone: the PortAudio library is missing ({exc}); "
                              f"install it with: apt-get install libportaudio2") from exc
        self._sd = sd
        try:
            info = sd.query_devices(device, "input")
        except (ValueError, sd.PortAudioError) as exc:
            raise DeviceError(f"microphone: no audio input device found ({exc}); plug one in, or replay a "
                              f"recording with --audio FILE.wav") from exc
        self.name = f"microphone:{info.get('name', device)}"
        self._device = device
        self._blocks: deque = deque(maxlen=int(max_seconds * 50))
        self._lock = threading.Lock()
        self._stream = None
        self.overflows = 0
        self.status = "ok"
        self.finished = False

    def _callback(self, indata, frames, time_info, status) -> None:  # PortAudio thread
        if status and status.input_overflow:
            self.overflows += 1
            self.status = f"audio overflow x{self.overflows}"
        with self._lock:
            if len(self._blocks) == self._blocks.maxlen:
                self.overflows += 1
            self._blocks.append(indata[:, 0].astype(np.float32).copy())

    def start(self) -> None:
        try:
            self._stream = self._sd.InputStream(samplerate=SAMPLE_RATE, channels=1, dtype="float32",
                                                blocksize=SAMPLE_RATE // 50, device=self._device,
                                                callback=self._callback)
            self._stream.start()
        except self._sd.PortAudioError as exc:
            raise DeviceError(f"{self.name}: cannot open the input stream ({exc})") from exc

    def read(self, upto_s: float) -> np.ndarray:
        with self._lock:
            blocks = list(self._blocks)
            self._blocks.clear()
        if self._stream is not None and not self._stream.active and self.status == "ok":
            self.status = "microphone stopped"
        return np.concatenate(blocks) if blocks else np.zeros(0, np.float32)

    def stop(self) -> None:
        if self._stream is not None:
            self._stream.close()
            self._stream = None


class VideoReplay:
    """A video file replayed against the media clock: ``latest(t)`` is the frame shown at time t."""

    def __init__(self, path: str | os.PathLike) -> None:
        from ..tracking.video import iter_video_frames

        p = Path(path)
        if not p.is_file():
            raise DeviceError(f"{p}: video file not found")
        self.name = f"file:{p}"
        self._path = p
        self._iter_fn = iter_video_frames
        self._it = None
        self._next: tuple[float, np.ndarray] | None = None
        self._cur: tuple[float, np.ndarray] | None = None
        self.status = "ok"
        self.finished = False
        self._open()  # probe now: a corrupt file is reported before anything else starts

    def _open(self) -> None:
        try:
            self._it = iter(self._iter_fn(self._path))
            self._next = next(self._it)
        except StopIteration:
            raise DeviceError(f"{self._path}: cannot read the video (it has no frames)") from None
        except TrackingError as exc:
            lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
            reason = lines[-1] if lines else type(exc).__name__  # ffmpeg's own reason, not its banner
            raise DeviceError(f"{self._path}: cannot read the video ({reason[:200]})") from None

    def start(self) -> None:
        if self._it is None:
            self._open()

    def latest(self, t: float) -> tuple[float, np.ndarray] | None:
        """(frame time, frame) of the last frame with time <= t (None before the first)."""
        while self._next is not None and self._next[0] <= t:
            self._cur = self._next
            try:
                self._next = next(self._it)
            except StopIteration:
                self._next = None
                self.finished = True
            except TrackingError as exc:
                self._next = None
                self.finished = True
                self.status = f"video ended: {exc}"
        return self._cur

    def next_time(self) -> float | None:
        """Media time of the next frame (None: no more frames): the tracker sleeps until then instead of
        polling ``latest`` (issue 37)."""
        return None if self._next is None else self._next[0]

    def stop(self) -> None:
        self._it = None


class Webcam:
    """An OpenCV camera read by a background thread that keeps only the newest frame (RGB).

    OpenCV runs on one thread (``cv2.setNumThreads(1)``, for the process: the live loop uses OpenCV for
    nothing else): its pool split each 640x480 ``cvtColor`` across the cores, 0.56-0.58 ms of CPU a frame
    against 0.14 on one thread, the same pixels (three rounds at 30 Hz, 2026-11-29; ~13 ms of CPU a
    second the renderer can have, docs/live.md)."""

    def __init__(self, index: int = 0, width: int = 640, height: int = 480) -> None:
        try:
            import cv2
        except ImportError as exc:
            raise MissingDependencyError("opencv-python-headless", "the webcam", extra="live") from exc
        cv2.setNumThreads(1)  # a 640x480 colour swap is cheaper on the calling thread than woken workers
        self._cv2 = cv2
        cap = cv2.VideoCapture(int(index))
        if not cap.isOpened():
            cap.release()
            raise DeviceError(f"webcam: no camera at index {index} (OpenCV could not open it); plug one in, "
                              f"choose another with --camera N, or replay a recording with --video FILE.mp4")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(width))
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(height))
        self.name = f"webcam:{index}"
        self._cap = cap
        self._lock = threading.Lock()
        self._cur: tuple[float, np.ndarray] | None = None
        self._stop = threading.Event()
        self._new = threading.Event()  # set by each frame read: wait_frame() returns then
        self._thread = threading.Thread(target=self._run, name="webcam", daemon=True)
        self._t0 = time.perf_counter()
        self.status = "ok"
        self.finished = False

    def _run(self) -> None:
        fails = 0
        while not self._stop.is_set():
            ok, frame = self._cap.read()
            if not ok:
                fails += 1
                if fails > 25:
                    self.status = "webcam lost"
                time.sleep(0.02)
                continue
            fails = 0
            self.status = "ok"
            rgb = self._cv2.cvtColor(frame, self._cv2.COLOR_BGR2RGB)
            with self._lock:
                self._cur = (time.perf_counter() - self._t0, rgb)
            self._new.set()

    def start(self) -> None:
        self._t0 = time.perf_counter()
        self._thread.start()

    def latest(self, t: float) -> tuple[float, np.ndarray] | None:
        with self._lock:
            self._new.clear()
            return self._cur

    def wait_frame(self, timeout: float) -> None:
        """Return when a frame newer than the last ``latest`` arrives, or after ``timeout`` seconds (the
        tracker waits here instead of polling ``latest``; issue 37)."""
        self._new.wait(timeout)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        self._cap.release()
