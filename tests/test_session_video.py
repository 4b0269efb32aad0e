"""The session video's timed writer (holo_viewer.media, issue 37): a frame handed over (``keep``, as
ThreadedWriter does) is held without a copy and still stored bit-exact; a frame not handed over is copied,
so a caller that reuses its buffer does not change what is stored."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from holo_viewer import media


def _frames(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    return [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(n)]


def test_timed_writer_holds_handed_over_frames_and_copies_the_others(tmp_path: Path) -> None:
    frames = _frames(3)
    kept = media.VideoWriter(tmp_path / "kept.mkv", 25, timed=True)
    for i, f in enumerate(frames):
        kept.write(f, t=0.1 * i, keep=True)
        assert np.shares_memory(np.frombuffer(kept._held[0], np.uint8), f)  # held, not copied
    kept.close(end_s=0.3)
    copied = media.VideoWriter(tmp_path / "copied.mkv", 25, timed=True)
    buf = np.empty_like(frames[0])
    for i, f in enumerate(frames):
        buf[:] = f
        copied.write(buf, t=0.1 * i)
        buf[:] = 0  # the caller reuses its buffer: the held frame is a copy
    copied.close(end_s=0.3)
    for name in ("kept.mkv", "copied.mkv"):
        got = list(media.read_frames(tmp_path / name))
        assert len(got) == 3 and all(np.array_equal(a, b) for a, b in zip(got, frames)), name
