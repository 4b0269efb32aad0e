"""The one codec policy (holo_viewer.media.CODECS) and the writers that drive ffmpeg themselves."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer import media
from holo_viewer.errors import ExportError


def test_encoder_flags_are_the_policy_with_crf_and_preset_replaced() -> None:
    assert media.encoder_flags("lossless") == ["-c:v", "libx264rgb", "-preset", "ultrafast", "-crf", "0",
                                               "-pix_fmt", "rgb24"]
    assert media.encoder_flags("watchable", crf=23, preset="slow") == ["-c:v", "libx264", "-preset", "slow",
                                                                      "-crf", "23", "-pix_fmt", "yuv420p"]
    with pytest.raises(ExportError, match=r"content: expected one of \['lossless', 'watchable'\], found 'preview'"):
        media.encoder_flags("preview")


@pytest.mark.parametrize("rgb", [True, False])
def test_batch_segments_encode_with_the_media_policy(monkeypatch: pytest.MonkeyPatch, rgb: bool) -> None:
    """batch/video.py's segment encoder takes its codec flags from media.CODECS (one policy): a policy
    change (the pixel format) reaches its ffmpeg command; its crf and preset stay its own."""
    import subprocess

    from holo_viewer.batch import video

    commands: list[list[str]] = []
    real = subprocess.Popen

    def popen(cmd, *args, **kwargs):
        if "mpegts" in cmd:  # the segment encoder's (not, e.g., a probe of ffmpeg's version)
            commands.append(list(cmd))
        return real(cmd, *args, **kwargs)

    monkeypatch.setattr(video.subprocess, "Popen", popen)
    content = "lossless" if rgb else "watchable"
    pix = "bgr24" if rgb else "yuv444p"  # a policy change the segment does not override
    monkeypatch.setitem(media.CODECS, content, {**media.CODECS[content], "pixelformat": pix,
                                                "output_params": ("-preset", "superfast", "-crf", "0" if rgb else "30")})
    frames = [np.random.default_rng(i).integers(0, 256, (16, 24, 3), dtype=np.uint8) for i in range(2)]
    data, n = video.encode_segment(frames, 25, rgb=rgb, crf=0 if rgb else 20)
    (cmd,) = commands
    flags = media.encoder_flags(content, crf=0 if rgb else 20, preset="veryfast")
    i = cmd.index("-c:v")
    assert cmd[i:i + len(flags)] == flags and n == 2 and data and cmd[cmd.index("-pix_fmt", i) + 1] == pix
    assert "superfast" not in cmd  # the segment's own preset replaces the policy's, as given
