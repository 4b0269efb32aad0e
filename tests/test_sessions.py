"""Sessions an instructor can run and review (issue 33): lossless, synced recordings (media.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from holo_viewer import media
from holo_viewer.errors import ExportError


def _frames(n: int, h: int = 33, w: int = 65, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)  # noise: every subpixel differs from its neighbours (a native image's worst case)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


@pytest.mark.parametrize("suffix", [".mkv", ".mp4"])
def test_lossless_video_decodes_bit_exact(tmp_path: Path, suffix: str) -> None:
    """The default policy (native images, quilts) is lossless RGB: no chroma subsampling mixes views."""
    frames = _frames(3)
    media.write_video(tmp_path / f"v{suffix}", frames, 25)
    back = list(media.read_frames(tmp_path / f"v{suffix}"))
    assert len(back) == 3 and all(np.array_equal(a, b) for a, b in zip(frames, back))


def test_preview_policy_is_lossy_yuv420(tmp_path: Path) -> None:
    frames = _frames(2, 32, 64)
    media.write_video(tmp_path / "p.mp4", frames, 25, content="preview")
    back = list(media.read_frames(tmp_path / "p.mp4"))
    assert len(back) == 2 and not np.array_equal(back[0], frames[0])
    with pytest.raises(ExportError, match="content: expected one of"):
        media.VideoWriter(tmp_path / "x.mkv", 25, content="best")


def test_timed_video_holds_each_frame_for_its_time(tmp_path: Path) -> None:
    """Each frame is encoded once with its presentation time; decoded at 25 fps, frame round(t * 25)
    is the one shown at t, and the video lasts until the end time given at close."""
    frames = _frames(4)
    with media.VideoWriter(tmp_path / "s.mkv", 25, timed=True) as w:
        for f, t in zip(frames, (0.0, 0.04, 0.2, 0.24)):
            w.write(f, t=t)
        w.close(end_s=0.4)
    assert media.count_video_frames(tmp_path / "s.mkv") == 4  # held frames are not re-encoded
    stored = list(media.read_frames(tmp_path / "s.mkv"))
    assert all(np.array_equal(a, b) for a, b in zip(frames, stored))
    at25 = list(media.read_frames(tmp_path / "s.mkv", fps=25))
    assert len(at25) == 10  # 0.4 s
    shown = [next(i for i, f in enumerate(frames) if np.array_equal(f, g)) for g in at25]
    assert shown == [0, 1, 1, 1, 1, 2, 3, 3, 3, 3]


def test_timed_video_refuses_times_that_do_not_advance(tmp_path: Path) -> None:
    w = media.VideoWriter(tmp_path / "s.mkv", 25, timed=True)
    f = _frames(1)[0]
    w.write(f, t=0.1)
    with pytest.raises(ExportError, match=r"s.mkv: frame 1: t: expected later than 0.1 s"):
        w.write(f, t=0.1)
    with pytest.raises(ExportError, match="frame 1: t: expected a time >= 0 s, found None"):
        w.write(f)
    w.abort()
    assert not (tmp_path / "s.mkv").exists()
