"""The session video's timed writer (holo_viewer.media, issue 37): a frame handed over (``keep``, as
ThreadedWriter does) is held without a copy and still stored bit-exact; a frame not handed over is copied,
so a caller that reuses its buffer does not change what is stored."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

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


def _video_codec(path: Path) -> str:
    """The codec ffmpeg names for the file's video stream."""
    import re
    import subprocess

    err = subprocess.run([media.ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True).stderr
    return re.search(r"Video: (\w+)", err).group(1)


def test_lossless_fast_timed_video_is_bit_exact_and_timed(tmp_path: Path) -> None:
    """``content="lossless-fast"`` (FFVHuff, ``live --native-codec ffvhuff``): every frame back bit-exact, odd
    sides included, held for its time like the x264 session video (frame round(t * 25) at 25 fps)."""
    rng = np.random.default_rng(5)
    frames = [rng.integers(0, 256, (23, 37, 3), dtype=np.uint8) for _ in range(3)]
    with media.VideoWriter(tmp_path / "f.mkv", 10, content="lossless-fast", timed=True,
                           output_params=(*media.CODECS["lossless-fast"]["output_params"], "-threads", "1")) as w:
        for f, t in zip(frames, (0.0, 0.12, 0.2)):
            w.write(f, t=t)
        w.close(end_s=0.4)
    assert _video_codec(tmp_path / "f.mkv") == "ffvhuff"
    got = list(media.read_frames(tmp_path / "f.mkv"))
    assert len(got) == 3 and all(np.array_equal(a, b) for a, b in zip(got, frames))
    at25 = list(media.read_frames(tmp_path / "f.mkv", fps=25))
    assert len(at25) == 10
    shown = [next(i for i, f in enumerate(frames) if np.array_equal(g, f)) for g in at25]
    assert shown == [0, 0, 0, 1, 1, 2, 2, 2, 2, 2]


def test_native_codec_is_checked() -> None:
    from holo_viewer.errors import InputError
    from holo_viewer.live.loop import SESSION_VIDEO_CODECS, LiveSessionConfig

    assert set(SESSION_VIDEO_CODECS) == {"x264", "ffvhuff"} and LiveSessionConfig().native_codec == "ffvhuff"
    with pytest.raises(InputError, match="native_codec: expected one of .*'ffvhuff'.*found 'h265'"):
        LiveSessionConfig(native_codec="h265")


def test_recording_minutes_is_the_measured_rate_over_the_free_space() -> None:
    """live's disk estimate: MB a frame x 12 fps x 60 s, and the minutes the free bytes hold at that rate."""
    from holo_viewer.errors import InputError
    from holo_viewer.live.loop import SESSION_VIDEO_MB_PER_FRAME, recording_minutes

    for codec, mb in SESSION_VIDEO_MB_PER_FRAME.items():
        gb, minutes = recording_minutes(100e9, codec)
        assert gb == pytest.approx(mb * 12 * 60 / 1000) and minutes == pytest.approx(100 / gb)
    assert recording_minutes(1e9, "ffvhuff")[0] > recording_minutes(1e9, "x264")[0]  # the faster codec's disk
    assert recording_minutes(-5, "x264")[1] == 0.0
    with pytest.raises(InputError, match="native_codec: expected one of .*found 'h265'"):
        recording_minutes(1e9, "h265")
