"""``holo-viewer compact`` (issue 37): a finished session's FFVHuff ``native.mkv`` re-encoded to x264rgb crf 0,
verified bit-exact with every frame's times before it replaces the original; a copy that differs anywhere, a
damaged original, a session still being written are refused and the original stays as it was."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from holo_viewer import media
from holo_viewer.cli import main
from holo_viewer.commands import compact
from holo_viewer.errors import InputError


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    """A 1 s synthetic session recorded by the live loop with ``native_codec="ffvhuff"`` (noise frames,
    48x64), and the native frames it displayed."""
    from test_sessions import _NoiseRenderer, _session  # tests/ is on sys.path

    root = tmp_path_factory.mktemp("compact")
    renderer = _NoiseRenderer()
    _session(root, 1.0, native_codec="ffvhuff").run(renderer)
    return root / "s", renderer.natives[1:]  # [0]: the warm-up call


def _copy(recorded: tuple[Path, list], tmp_path: Path) -> Path:
    out = tmp_path / "session"
    shutil.copytree(recorded[0], out)
    return out


def _digest(path: Path) -> str:
    return hashlib.blake2b(path.read_bytes(), digest_size=16).hexdigest()


def test_compact_replaces_ffvhuff_by_bit_exact_x264_with_the_same_times(recorded, tmp_path, capsys) -> None:
    folder = _copy(recorded, tmp_path)
    video = folder / "native.mkv"
    assert compact.video_codec(video) == "ffvhuff"
    before = video.stat().st_size
    times = compact.packet_times(video)
    at25 = list(media.read_frames(video, fps=25))
    # a folder that fails does not stop the next one; the exit status says one failed
    assert main(["compact", "--no-progress", str(tmp_path / "nope"), str(folder)]) == 1
    out = capsys.readouterr()
    assert "nope: no such session folder" in out.err and "ffvhuff -> libx264rgb crf 0" in out.out
    assert compact.video_codec(video) == "h264"
    stored = list(media.read_frames(video))
    assert len(stored) == len(recorded[1]) >= 2 and all(np.array_equal(a, b) for a, b in zip(stored, recorded[1]))
    assert compact.packet_times(video) == times  # each frame's dts, pts and duration
    again = list(media.read_frames(video, fps=25))
    assert len(again) == len(at25) and all(np.array_equal(a, b) for a, b in zip(again, at25))
    rec = json.loads((folder / "session.json").read_text())["compacted"]
    assert rec["codec_before"] == "ffvhuff" and rec["codec_after"] == "libx264rgb crf 0"
    assert rec["bytes_before"] == before and rec["bytes_after"] == video.stat().st_size and rec["frames"] == len(stored)
    assert sorted(p.name for p in folder.iterdir()) == ["audio.wav", "native.mkv", "session.json", "tracks.npz"]
    # already x264: left as it is, exit 0
    digest = _digest(video)
    assert main(["compact", "--no-progress", str(folder)]) == 0
    assert "already x264" in capsys.readouterr().out and _digest(video) == digest


@pytest.mark.parametrize("flags, says", [
    (["-vf", "drawbox=x=0:y=0:w=4:h=4:color=red:t=fill:enable='eq(n,1)'"],
     r"frame 1: the compacted copy differs from the original in 16 pixels \(first at row 0, column 0\)"),
    (["-frames:v", "2"], r"the compacted copy holds 2 frames, the original \d+"),
    (["-output_ts_offset", "0.001"], r"frame 0: the compacted copy's \(dts, pts, duration\) \(\d+, \d+, \d+\) differ"),
], ids=["a-changed-frame", "a-lost-frame", "shifted-times"])
def test_compact_refuses_a_copy_that_differs(recorded, tmp_path, capsys, monkeypatch, flags, says) -> None:
    """The re-encode made to differ (a box drawn on frame 1, the frames after the second dropped, every time
    1 ms later): refused with exit 1, naming the file and the first differing frame; the original, session.json
    and the folder are as they were (no temporary left)."""
    import re

    folder = _copy(recorded, tmp_path)
    digests = {p.name: _digest(p) for p in folder.iterdir()}
    monkeypatch.setattr(compact, "_extra_output_params", lambda: list(flags))
    assert main(["compact", "--no-progress", str(folder)]) == 1
    err = capsys.readouterr().err
    assert re.search(re.escape(str(folder / "native.mkv")) + ": " + says, err), err
    assert "the original is unchanged" in err
    assert {p.name: _digest(p) for p in folder.iterdir()} == digests


def test_compact_errors_name_the_folder(recorded, tmp_path) -> None:
    import fcntl
    import os

    with pytest.raises(InputError, match=r"nope: no such session folder"):
        compact.compact_session(tmp_path / "nope")
    (tmp_path / "f.txt").write_text("x")
    with pytest.raises(InputError, match=r"f.txt: expected a session folder, found a file"):
        compact.compact_session(tmp_path / "f.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"empty: expected a live session folder"):
        compact.compact_session(tmp_path / "empty")
    folder = _copy(recorded, tmp_path)
    # the live writer holds the lock on its temporary while it writes (holo_viewer.fileio.atomic_path)
    tmp = folder / ".native.abcd1234.tmp.mkv"
    fd = os.open(tmp, os.O_CREAT | os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(InputError, match=r"the session is still being written \(\.native\.abcd1234\.tmp\.mkv"):
            compact.compact_session(folder)
    finally:
        os.close(fd)
    tmp.unlink()
    meta = json.loads((folder / "session.json").read_text())
    (folder / "session.json").write_text(json.dumps({k: v for k, v in meta.items() if k != "end_s"}))
    with pytest.raises(InputError, match=r"session.json: end_s: expected the session's end, found none \(the session "
                       r"is still being written\)"):
        compact.compact_session(folder)
    (folder / "native.mkv").unlink()
    with pytest.raises(InputError, match=r"native.mkv: expected the session video, found no file \(session.json has "
                       r"no end_s: the session is still starting or was killed before its end\)"):
        compact.compact_session(folder)


def test_report_compact_compacts_after_the_report(recorded, tmp_path, capsys) -> None:
    folder = _copy(recorded, tmp_path)
    assert main(["report", str(folder), "--out", str(tmp_path / "r.png"), "--compact"]) == 0
    assert (tmp_path / "r.png").is_file() and "ffvhuff -> libx264rgb crf 0" in capsys.readouterr().out
    assert compact.video_codec(folder / "native.mkv") == "h264"
    assert json.loads((folder / "session.json").read_text())["compacted"]["frames"] == len(recorded[1])
