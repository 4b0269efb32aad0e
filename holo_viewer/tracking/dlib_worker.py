"""dlib's HOG face detector and 68-point shape predictor in a child process: the live tracker's GIL-free path.

dlib's Python bindings hold the GIL while they run (``run_predictor`` in dlib's ``shape_predictor.cpp`` has no
``gil_scoped_release``): the shape predictor ~2 ms on every webcam frame, the HOG detector ~15-20 ms every few
seconds. In a live session that is ~50 ms a second during which the render's thread cannot run Python
between its kernels (issue 37). :class:`DlibProcess` runs both in a child process (the same dlib, the same
model file, the same images: bit-identical results, tested); the tracker thread sends the frame once through a
pipe (0.5 MB at 480x360) and waits for the answer with the GIL released.

Protocol (little-endian): the parent writes an op byte (``P`` predict, ``H`` HOG, ``Q`` quit), then four int32
(new image, height, width, channels) and the op's arguments (``P``: left, top, right, bottom int32; ``H``:
upsample int32), then the image's bytes when it is new (the child keeps the last one). The child answers
``P`` with 68 x 2 int32 part coordinates and ``H`` with an int32 count, then per box four int32 (left, top,
right, bottom) and a float64 score. It writes ``R`` once when its models are loaded.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from typing import Any

import numpy as np

from ..errors import TrackingError

__all__ = ["DlibProcess"]

_HEAD = struct.Struct("<4i")
_BOX = struct.Struct("<4i")
_HOG_ROW = struct.Struct("<4id")
_PIPE_BYTES = 1 << 20  # a 640x480 RGB frame in one write (Linux default pipes hold 64 KB)


def _read_exact(f: Any, n: int) -> bytes:
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = f.readinto(view[got:])
        if not k:
            raise EOFError(f"expected {n} bytes, found {got}")
        got += k
    return bytes(buf) if n < 4096 else buf


def _write_all(f: Any, data: Any) -> None:
    view = memoryview(data).cast("B")
    done = 0
    while done < len(view):
        done += f.write(view[done:])


class DlibProcess:
    """The child (see the module docstring), started here; it loads dlib and the model meanwhile and the first
    request waits for it (:meth:`wait_ready`). ``predict`` and ``detect`` take the image each time; it is
    piped only when it is not the one sent last (held here by reference, so the identity test is safe)."""

    def __init__(self, predictor: str | os.PathLike) -> None:
        self._proc = subprocess.Popen([sys.executable, "-m", __name__, os.fspath(predictor)], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, bufsize=0)
        try:
            import fcntl

            fcntl.fcntl(self._proc.stdin.fileno(), fcntl.F_SETPIPE_SZ, _PIPE_BYTES)
        except (ImportError, OSError, AttributeError):  # not Linux, or above /proc/sys/fs/pipe-max-size
            pass
        self._last: np.ndarray | None = None
        self._ready = False  # the child loads dlib and the model (~1-2 s of CPU) while the caller goes on
        self._what = f"python -m {__name__} {os.fspath(predictor)}"

    def wait_ready(self) -> None:
        """Wait until the child has loaded its models (the first request does)."""
        if self._ready:
            return
        if self._proc is None:
            raise TrackingError(f"the dlib worker process is closed ({self._what})")
        try:
            ready = _read_exact(self._proc.stdout, 1)
        except (EOFError, OSError):
            ready = b""
        if ready != b"R":
            raise TrackingError(f"the dlib worker process did not start ({self._what})")
        self._ready = True

    def _send(self, op: bytes, image: np.ndarray, args: bytes) -> None:
        self.wait_ready()
        new = image is not self._last
        h, w = image.shape[:2]
        c = image.shape[2] if image.ndim == 3 else 1
        try:
            _write_all(self._proc.stdin, op + _HEAD.pack(int(new), h, w, c) + args)
            if new:
                _write_all(self._proc.stdin, np.ascontiguousarray(image))
        except (BrokenPipeError, OSError) as exc:
            raise TrackingError(f"the dlib worker process stopped ({exc})") from None
        self._last = image

    def _recv(self, n: int) -> bytes:
        try:
            return _read_exact(self._proc.stdout, n)
        except (EOFError, OSError) as exc:
            raise TrackingError(f"the dlib worker process stopped ({exc})") from None

    def predict(self, image: np.ndarray, left: int, top: int, right: int, bottom: int) -> np.ndarray:
        """(68, 2) int32 part coordinates of the shape predictor in the box (dlib's inclusive corners)."""
        self._send(b"P", image, _BOX.pack(left, top, right, bottom))
        return np.frombuffer(self._recv(68 * 2 * 4), dtype="<i4").reshape(68, 2)

    def detect(self, image: np.ndarray, upsample: int) -> list[tuple[tuple[int, int, int, int], float]]:
        """The HOG detector's boxes ((left, top, right, bottom), score), as ``detector.run(image, upsample, 0.0)``."""
        self._send(b"H", image, struct.pack("<i", int(upsample)))
        (n,) = struct.unpack("<i", self._recv(4))
        data = self._recv(_HOG_ROW.size * n) if n else b""
        rows = [_HOG_ROW.unpack_from(data, k * _HOG_ROW.size) for k in range(n)]
        return [((r[0], r[1], r[2], r[3]), r[4]) for r in rows]

    def close(self) -> None:
        """Stop the child (it also stops by itself when this process's end of the pipe closes)."""
        proc, self._proc = self._proc, None
        self._last = None
        if proc is None:
            return
        try:
            if proc.stdin is not None:
                proc.stdin.write(b"Q")
                proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass
        try:
            proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()

    def __del__(self) -> None:  # pragma: no cover - the owner closes it
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass


def _serve(predictor: str) -> None:
    import dlib

    pred = dlib.shape_predictor(predictor)
    det = dlib.get_frontal_face_detector()
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    out.write(b"R")
    out.flush()
    image = None
    while True:
        op = inp.read(1)
        if not op or op == b"Q":
            return
        new, h, w, c = _HEAD.unpack(_read_exact(inp, _HEAD.size))
        args = _read_exact(inp, _BOX.size if op == b"P" else 4)
        if new:
            buf = _read_exact(inp, h * w * c)
            image = np.frombuffer(buf, dtype=np.uint8).reshape((h, w, c) if c > 1 else (h, w))
        if op == b"P":
            l, t, r, b = _BOX.unpack(args)
            shape = pred(image, dlib.rectangle(l, t, r, b))
            out.write(np.array([[p.x, p.y] for p in shape.parts()], dtype="<i4").tobytes())
        else:
            (up,) = struct.unpack("<i", args)
            rects, scores, _ = det.run(image, up, 0.0)
            out.write(struct.pack("<i", len(rects)) + b"".join(
                _HOG_ROW.pack(r.left(), r.top(), r.right(), r.bottom(), float(s)) for r, s in zip(rects, scores)))
        out.flush()


if __name__ == "__main__":
    _serve(sys.argv[1])
