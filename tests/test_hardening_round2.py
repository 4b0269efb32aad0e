"""Hardening, round two (issue 31, cases 4-16): resource bombs, clobbered data, bad input.

Cases 1-3 (the FLAME pickle loader) are in ``test_flame_pickle_bombs.py``. Each test here
failed on the code before the fix. Budgets are asserted to apply before the expensive step
(a spy on the step), never by timing.
"""

from __future__ import annotations

import io
import json
import os
import socket
import stat
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest

from holo_viewer import fileio
from holo_viewer.cli import main
from holo_viewer.errors import (CalibrationError, ExportError, HoloViewerError, InputError, ReactionError,
                                TrackingError)

from test_hardening import _empty_gaussians, _speaker_files  # noqa: E402  (tests/ is on sys.path)

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "assets" / "lkg_portrait_visual.json"
DEEP = "[" * 100_000 + "]" * 100_000


# --------------------------------------------------------------------------- case 4: deep JSON


def _json_readers(tmp_path: Path):
    """(name, call) for every JSON reader of the package, each given ``DEEP`` JSON."""
    from holo_viewer.batch.manifest import read_manifest
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.flame.expressions import AUMap
    from holo_viewer.live.controls import Scenario
    from holo_viewer.live.session import load_session
    from holo_viewer.reaction.train import load_train_config
    from holo_viewer.tracking.viewer import WebcamMount

    deep = tmp_path / "deep.json"
    deep.write_text(DEEP)
    session = tmp_path / "session"
    session.mkdir()
    (session / "session.json").write_text(DEEP)
    np.savez(session / "tracks.npz", a=np.zeros(1))
    manifest = tmp_path / "jobs.jsonl"
    manifest.write_text(DEEP + "\n")
    return [
        ("calibration", lambda: DisplayCalibration.from_file(deep)),
        ("AU map", lambda: AUMap.load_json(deep)),
        ("scenario", lambda: Scenario.load(deep)),
        ("mount", lambda: WebcamMount.load(deep)),
        ("session", lambda: load_session(session)),
        ("train config", lambda: load_train_config(deep)),
        ("read_json", lambda: fileio.read_json(deep)),
        ("manifest", lambda: read_manifest(manifest)),
    ]


@pytest.mark.parametrize("index", range(8))
def test_deep_json_is_refused_in_one_line_by_every_reader(tmp_path: Path, index: int) -> None:
    name, call = _json_readers(tmp_path)[index]
    if name == "manifest":
        (row,) = call()
        assert "nested 100000 levels" in row.error
        return
    with pytest.raises(HoloViewerError, match=r"nested 100000 levels deep.*MAX_JSON_DEPTH"):
        call()


@pytest.mark.parametrize("argv", [
    ["quilt-to-native", "q_qs8x6a0.75.png", "--calibration", "{deep}", "--out", "{out}/n.png"],
    ["render-ply", "s.ply", "--cameras", "{deep}", "--out", "{out}"],
    ["export-mesh", "--pain", "1", "--au-map", "{deep}", "--out", "{out}/h.obj"],
])
def test_deep_json_on_the_command_line(tmp_path: Path, argv: list[str], capsys: pytest.CaptureFixture) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text(DEEP)
    out = tmp_path / "out"
    if argv[0] == "render-ply":
        from holo_viewer.avatar.ply import save_ply
        save_ply(_empty_gaussians(), tmp_path / "s.ply")
    elif argv[0] == "quilt-to-native":
        fileio.save_image(tmp_path / "q_qs8x6a0.75.png", np.zeros((48, 64, 3)))
    argv = [a.format(deep=deep, out=out) for a in argv]
    argv = [str(tmp_path / a) if a.endswith((".png", ".ply")) and "/" not in a else a for a in argv]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "deep.json" in err and "nested" in err and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())


def test_json_depth_ignores_brackets_in_strings() -> None:
    assert fileio.json_depth(json.dumps({"a": "[" * 500, "b": [[1]]})) == 3
    assert fileio.parse_json('{"a": "' + "{" * 200 + '"}') == {"a": "{" * 200}


# --------------------------------------------------------------------------- case 5: .npz bombs


def _zeros_npz(path: Path, n_bytes: int, name: str = "expr") -> Path:
    """An .npz holding ``n_bytes`` of float64 zeros, deflated (small on disk)."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (n_bytes // 8,)})
    chunk = bytes(1 << 22)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
            fh.write(header.getvalue())
            for start in range(0, n_bytes, len(chunk)):
                fh.write(chunk[: min(len(chunk), n_bytes - start)])
    return path


def test_npz_bomb_is_refused_before_decompressing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture) -> None:
    bomb = _zeros_npz(tmp_path / "speaker.npz", 96 << 20)
    assert bomb.stat().st_size < 1 << 20
    monkeypatch.setattr(fileio, "NPZ_BUDGET_BYTES", 32 << 20)
    reads: list[int] = []
    real = zipfile.ZipExtFile.read
    monkeypatch.setattr(zipfile.ZipExtFile, "read", lambda self, n=-1: reads.append(n) or real(self, n))
    from holo_viewer.reaction.api import load_speaker_npz
    with pytest.raises(ReactionError, match=r"speaker\.npz: .*declares 100,663,[0-9]+ uncompressed bytes.*budget"):
        load_speaker_npz(bomb, None)
    assert reads == []  # refused from the central directory, nothing inflated
    from holo_viewer.live.session import load_session
    folder = tmp_path / "session"
    folder.mkdir()
    (folder / "session.json").write_text("{}")
    _zeros_npz(folder / "tracks.npz", 96 << 20)
    with pytest.raises(InputError, match=r"tracks\.npz: .*budget"):
        load_session(folder)


def test_npz_header_is_checked_before_the_buffer_is_allocated(tmp_path: Path, monkeypatch) -> None:
    """A header claiming more than the budget is refused before its buffer exists, even when the
    declared zip sizes are small (a forged central directory)."""
    path = tmp_path / "forged.npz"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**9,)})
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("a.npy", header.getvalue() + bytes(64))
    allocs: list[int] = []
    monkeypatch.setattr(fileio, "bytearray", lambda n: allocs.append(n) or bytearray(n), raising=False)
    with pytest.raises(HoloViewerError, match=r"forged\.npz: .*member 'a' of shape \(1000000000,\).*budget"):
        fileio.read_npz(path)
    assert allocs == []
    small = tmp_path / "small.npz"
    np.savez(small, a=np.arange(6.0).reshape(2, 3), b=np.array(["x"]), f=np.asfortranarray(np.eye(3)))
    got = fileio.read_npz(small)
    assert allocs  # the allocation the budget guards is the one the spy sees
    np.testing.assert_array_equal(got["a"], np.arange(6.0).reshape(2, 3))
    np.testing.assert_array_equal(got["f"], np.eye(3))
    assert got["b"][0] == "x" and got["a"].flags.writeable


def test_npy_header_larger_than_the_file_is_refused_unallocated(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "coeffs.npy"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**10,)})
    path.write_bytes(header.getvalue() + bytes(64))  # 80 GB declared in 200 bytes
    allocs: list[int] = []
    monkeypatch.setattr(fileio, "bytearray", lambda n: allocs.append(n) or bytearray(n), raising=False)
    with pytest.raises(ReactionError, match=r"coeffs\.npy: cannot read 3DMM.*needs 80,000,000,000 bytes"):
        fileio.read_npy(path, ReactionError, "3DMM coefficients")
    assert allocs == []
    np.save(path, np.arange(5.0))
    np.testing.assert_array_equal(fileio.read_npy(path), np.arange(5.0))


def test_npz_member_longer_than_its_header_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "long.npz"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (2,)})
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("a.npy", header.getvalue() + bytes(10 * 8))
    with pytest.raises(HoloViewerError, match=r"long\.npz: cannot read .*more data than its header"):
        fileio.read_npz(path)


# --------------------------------------------------------------------------- case 7: calibration sizes


def test_calibration_screen_size_is_bounded_by_real_panels(tmp_path: Path, capsys) -> None:
    data = json.loads(FIXTURE.read_text())
    data["screenW"], data["screenH"] = {"value": 32768}, {"value": 32768}
    data["DPI"] = {"value": 5000}
    bad = tmp_path / "huge.json"
    bad.write_text(json.dumps(data))
    from holo_viewer.display.calibration import DisplayCalibration
    with pytest.raises(CalibrationError, match=r"huge\.json: field 'screenW': .*<= 8192.*32768"):
        DisplayCalibration.from_file(bad)
    data["screenW"], data["screenH"] = {"value": 8192}, {"value": 8192}
    bad.write_text(json.dumps(data))
    with pytest.raises(CalibrationError, match=r"at most 33,177,600 pixels.*8192 x 8192"):
        DisplayCalibration.from_file(bad)
    data["screenW"], data["screenH"] = {"value": 7680}, {"value": 4320}
    bad.write_text(json.dumps(data))
    assert DisplayCalibration.from_file(bad).screen_w == 7680


# --------------------------------------------------------------------------- case 11: not a regular file


def _char_device(path: Path) -> Path:
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # a /dev/null of our own
    except (PermissionError, OSError) as exc:
        pytest.skip(f"cannot create a character device here ({exc})")
    return path


def test_atomic_write_writes_through_a_character_device(tmp_path: Path) -> None:
    fake = _char_device(tmp_path / "fakenull")
    with fileio.atomic_write(fake) as fh:
        fh.write(b"data")
    assert stat.S_ISCHR(fake.stat().st_mode)
    assert sorted(os.listdir(tmp_path)) == ["fakenull"]


def test_react_out_to_a_device_keeps_the_device(tmp_path: Path, capsys) -> None:
    fake = _char_device(tmp_path / "fakenull")
    wav, npz = _speaker_files(tmp_path)
    rc = main(["react", "--audio", str(wav), "--speaker", str(npz), "--out", str(fake)])
    assert rc == 0, capsys.readouterr().err
    assert stat.S_ISCHR(fake.stat().st_mode)


def test_atomic_write_writes_through_a_fifo(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    try:
        with fileio.atomic_write(fifo) as fh:
            fh.write(b"through the pipe")
        assert stat.S_ISFIFO(fifo.stat().st_mode)
    finally:
        if reader.is_alive() and not stat.S_ISFIFO(fifo.stat().st_mode):
            pytest.fail("the FIFO was replaced by a file")
        reader.join(10)
    assert got == [b"through the pipe"]


def test_directories_and_sockets_are_refused(tmp_path: Path) -> None:
    sock_path = tmp_path / "s.sock"
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(sock_path))
    try:
        for target, kind in ((tmp_path, "a directory"), (sock_path, "a socket")):
            with pytest.raises(ExportError, match=rf"the path is {kind}; refusing"):
                with fileio.atomic_write(target) as fh:
                    fh.write(b"x")
            with pytest.raises(ExportError, match=kind):
                fileio.check_writable(target)
        assert stat.S_ISSOCK(sock_path.stat().st_mode)
    finally:
        sock.close()


# --------------------------------------------------------------------------- case 6: checkpoint size


def _checkpoint_with(tmp_path: Path, name: str, **model: int) -> Path:
    import torch

    from holo_viewer.reaction.api import default_checkpoint_path

    d = torch.load(default_checkpoint_path(), map_location="cpu", weights_only=True)
    d["train_config"]["model"].update(model)
    path = tmp_path / name
    torch.save(d, path)
    return path


def test_huge_checkpoint_config_is_refused_before_building(tmp_path: Path, monkeypatch) -> None:
    from holo_viewer.reaction import train

    built: list[object] = []
    real = train._build_model
    monkeypatch.setattr(train, "_build_model", lambda cfg: built.append(cfg) or real(cfg))
    bomb = _checkpoint_with(tmp_path, "bomb.pt", d_model=4096, ff_dim=65536)
    assert bomb.stat().st_size < 2 << 20
    with pytest.raises(ReactionError, match=r"bomb\.pt: .*asks for [0-9,]+ parameters.*MAX_REACTION_PARAMETERS"):
        train.load_checkpoint(bomb)
    assert built == []
    odd = _checkpoint_with(tmp_path, "odd.pt", ff_dim=64)
    with pytest.raises(ReactionError, match=r"odd\.pt: model_state\['.*'\]: expected shape .* found"):
        train.load_checkpoint(odd)
    assert built == []
    from holo_viewer.reaction.api import default_checkpoint_path
    train.load_checkpoint(default_checkpoint_path())
    assert len(built) == 1


# --------------------------------------------------------------------------- cases 8, 9: verified videos


def _frames(n: int, h: int = 48, w: int = 64) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [np.clip(rng.normal(0.5, 0.1, (h, w, 3)) + 0.04 * i, 0, 1) for i in range(n)]


def test_video_writer_round_trip_and_atomic(tmp_path: Path) -> None:
    from holo_viewer import media

    out = tmp_path / "v.mp4"
    out.write_bytes(b"earlier")
    media.write_video(out, _frames(5, 47, 63), 10.0, codec="libx264", output_params=["-crf", "0"])
    assert media.count_video_frames(out) == 5
    assert sorted(os.listdir(tmp_path)) == ["v.mp4"]
    with pytest.raises(ExportError, match="no frames"):
        media.write_video(tmp_path / "none.mp4", [], 10.0)
    assert sorted(os.listdir(tmp_path)) == ["v.mp4"]


def test_ffmpeg_exit_status_is_checked(tmp_path: Path, monkeypatch) -> None:
    """ffmpeg failing (here: an impossible option) is an error, not a renamed broken file."""
    from holo_viewer import media

    out = tmp_path / "v.mp4"
    out.write_bytes(b"earlier")
    with pytest.raises(ExportError, match=r"v\.mp4: cannot write the video: ffmpeg"):
        media.write_video(out, _frames(3), 10.0, output_params=["-profile:v", "no-such-profile"])
    assert out.read_bytes() == b"earlier" and sorted(os.listdir(tmp_path)) == ["v.mp4"]


def _writers(tmp_path: Path):
    """(name, call writing one video) for every video writer of the package that is cheap to run."""
    from holo_viewer.batch.video import encode_segment, join_segments
    from holo_viewer.display.export import write_quilt_video
    from holo_viewer.live import replay

    def joined() -> None:
        seg = tmp_path / "a.ts"
        if not seg.exists():
            seg.write_bytes(encode_segment([(f * 255).astype(np.uint8) for f in _frames(3)], 10.0)[0])
        join_segments([seg], tmp_path / "joined.mp4", frames=3)

    return [
        ("quilt video", lambda: write_quilt_video(tmp_path / "q.mp4", _frames(3), 10.0, progress=False)),
        ("replay", lambda: replay.replay_session(tmp_path / "session", tmp_path / "replay.mp4")),
        ("batch join", joined),
    ]


@pytest.mark.parametrize("index", range(3))
def test_every_video_writer_verifies_before_the_rename(tmp_path: Path, index: int, monkeypatch) -> None:
    """A file holding fewer frames than written (a full disk, a killed encoder) never gets the final name."""
    from holo_viewer import media
    from holo_viewer.live import replay

    monkeypatch.setattr(replay, "replay_frames", lambda *a, **k: iter(_frames(3)))  # the session's frames
    name, call = _writers(tmp_path)[index]
    call()  # the real thing works
    before = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    real = media.count_video_frames
    monkeypatch.setattr(media, "count_video_frames", lambda p: real(p) - 1)
    with pytest.raises(ExportError, match=r"of 3 frames.*nothing was written"):
        call()
    after = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    assert after == before, name  # no temporary left, the earlier file untouched


_FULL_DISK_REPLAY = """
import resource, sys
import numpy as np
from holo_viewer.cli import main
from holo_viewer.live import replay
rng = np.random.default_rng(0)
replay.replay_frames = lambda *a, **k: iter(rng.integers(0, 255, (10, 240, 320, 3), dtype=np.uint8))
# the disk fills up while ffmpeg writes (a file-size limit: the kernel stops ffmpeg with SIGXFSZ)
resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, resource.RLIM_INFINITY))
sys.exit(main(["replay", sys.argv[1], "--out", sys.argv[2]]))
"""


def test_replay_to_a_full_disk_is_an_error(tmp_path: Path) -> None:
    """ffmpeg stopped by the disk filling up mid-video: exit 1, nothing under the final name."""
    import subprocess
    import sys

    out = tmp_path / "r.mp4"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", _FULL_DISK_REPLAY, str(tmp_path), str(out)], capture_output=True,
                          text=True, env=env, timeout=120)
    assert proc.returncode == 1, (proc.returncode, proc.stdout, proc.stderr[-2000:])
    assert "wrote" not in proc.stdout and "r.mp4" in proc.stderr and "Traceback" not in proc.stderr
    assert os.listdir(tmp_path) == []


class _FakeRenderer:
    """Small native frames, fast: the test is about the video, not the avatar."""

    def render(self, *args, **kwargs):
        from holo_viewer.live.render import RenderedFrame

        return RenderedFrame(native=np.full((48, 64, 3), 128, np.uint8), preview=None, seconds=0.001)


def test_ctrl_c_inside_the_frame_write_leaves_a_playable_session_video(tmp_path: Path, monkeypatch) -> None:
    """SIGINT delivered (as a terminal sends it) in the middle of piping frame 4 to ffmpeg: the frame
    completes, the session ends as interrupted, native.mkv decodes to the frames session.json counts."""
    import signal

    from holo_viewer import media
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.pipeline.live_support import SyntheticSpeaker

    real = media.VideoWriter._write_frame
    calls: list[int] = []

    def write_frame(self, data):
        calls.append(len(data))
        if len(calls) == 4:
            half = len(data) // 2
            real(self, data[:half])
            self._proc.stdin.flush()
            os.kill(os.getpid(), signal.SIGINT)  # handled now, in the middle of the frame
            real(self, data[half:])
        else:
            real(self, data)

    monkeypatch.setattr(media.VideoWriter, "_write_frame", write_frame)
    syn = SyntheticSpeaker(4.0)
    out = tmp_path / "s"
    session = LiveSession(LiveSessionConfig(out=str(out), tile_scale=0.1, behaviour=None),
                          sources.ArrayAudio(syn.waveform), None, syn)
    summary = session.run(_FakeRenderer())
    assert summary["status"]["end"] == "interrupted (Ctrl-C)"
    meta = json.loads((out / "session.json").read_text())
    # the timed writer pipes a frame when the next one is shown, from the session's writer thread:
    # SIGINT in frame 4's write ends the session after frame 5 is shown (later if that thread was
    # not scheduled before the next frame), and close() pipes the last one
    n = meta["displayed_frames"]
    assert media.count_video_frames(out / "native.mkv") == n == len(calls) and 5 <= n <= 8
    assert meta["summary"]["status"]["native_video_frames"] == n
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []


# --------------------------------------------------------------------------- case 10: never overwrite a session


def test_live_refuses_an_existing_session_folder(tmp_path: Path, capsys, monkeypatch) -> None:
    from holo_viewer.commands.live import check_session_out

    old = tmp_path / "session"
    old.mkdir()
    (old / "session.json").write_text('{"displayed_frames": 460}')
    rc = main(["live", "--synthetic", "--seconds", "0.5", "--headless", "--out", str(old)])
    err = capsys.readouterr().err
    assert rc == 1 and "a session folder already exists there" in err and "--out DIR" in err
    assert (old / "session.json").read_text() == '{"displayed_frames": 460}' and len(os.listdir(old)) == 1
    (tmp_path / "empty").mkdir()
    assert check_session_out(str(tmp_path / "empty")) == str(tmp_path / "empty")
    monkeypatch.chdir(tmp_path)
    first = check_session_out(None)
    assert first.startswith("session-") and not Path(first).exists()
    Path(first).mkdir()
    assert check_session_out(None) != first


# --------------------------------------------------------------------------- case 12: tampered replay sessions


def _good_session(folder: Path, n: int = 4) -> Path:
    from holo_viewer.live.session import TRACK_KEYS

    folder.mkdir()
    (folder / "session.json").write_text(json.dumps({"settings": {"tile_scale": 0.1}}))
    tracks = {k: np.zeros((n, 3)) if k.startswith(("listener_", "speaker_")) else np.zeros(n) for k in TRACK_KEYS}
    np.savez(folder / "tracks.npz", **tracks)
    return folder


@pytest.mark.parametrize("meta, tamper, match", [
    ([], None, r"session\.json: expected a JSON object, found list"),
    ({"settings": []}, None, r"session\.json: settings: expected a JSON object, found list"),
    ({"settings": {"tile_scale": "abc"}}, None, r"settings\.tile_scale: expected a number, found str"),
    ({"settings": {"tile_scale": float("nan")}}, None, r"settings\.tile_scale"),
    (None, {"time_s": np.float64(1.0)}, r"tracks\.npz: time_s: expected a 1-D array"),
    (None, {"listener_expr": np.zeros((2, 3))}, r"tracks\.npz: listener_expr: expected 4 rows"),
    (None, {"listener_expr": np.array([["a"] * 3] * 4)}, r"tracks\.npz: listener_expr: expected numbers"),
])
def test_tampered_sessions_are_refused_naming_the_field(tmp_path: Path, meta, tamper, match, capsys) -> None:
    from holo_viewer.live.session import load_session

    folder = _good_session(tmp_path / "s")
    if meta is not None:
        (folder / "session.json").write_text(json.dumps(meta))
    if tamper is not None:
        with np.load(folder / "tracks.npz") as z:
            tracks = {k: z[k] for k in z.files}
        tracks.update(tamper)
        np.savez(folder / "tracks.npz", **tracks)
    with pytest.raises(InputError, match=match):
        load_session(folder)
    rc = main(["replay", str(folder), "--out", str(tmp_path / "r.mp4")])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err and not (tmp_path / "r.mp4").exists()


# --------------------------------------------------------------------------- case 13: JSON types


@pytest.mark.parametrize("event, match", [
    ('{"t": NaN, "pain": 1.0}', r"events\[0\]\.t: expected a finite"),
    ('{"t": 1, "pain": 0.5, "duration": NaN}', r"events\[0\]\.duration"),
    ('{"t": "3", "pain": 0.5}', r"events\[0\]\.t: expected a number, found str"),
    ('{"t": 1, "pain": true}', r"events\[0\]\.pain: expected a number, found bool"),
])
def test_scenario_values_are_type_checked(tmp_path: Path, event: str, match: str) -> None:
    from holo_viewer.live.controls import Scenario

    path = tmp_path / "sc.json"
    path.write_text('{"events": [' + event + ']}')
    with pytest.raises(InputError, match=match):
        Scenario.load(path)


@pytest.mark.parametrize("mount, match", [
    ({"mirrored": "no"}, r"mirrored: expected true or false, found str 'no'"),
    ({"mirrored": 0}, r"mirrored: expected true or false, found int"),
    ({"hfov_deg": "60"}, r"hfov_deg: expected a number, found str"),
    ({"position_m": [0, "0.1", 0]}, r"position_m\[1\]: expected a number"),
])
def test_mount_values_are_type_checked(tmp_path: Path, mount: dict, match: str) -> None:
    from holo_viewer.tracking.viewer import WebcamMount

    path = tmp_path / "mount.json"
    path.write_text(json.dumps(mount))
    with pytest.raises(TrackingError, match=r"mount\.json: " + match):
        WebcamMount.load(path)
    path.write_text(json.dumps({"mirrored": True, "hfov_deg": 70}))
    assert WebcamMount.load(path).mirrored is True


# --------------------------------------------------------------------------- case 14: AU map limit


@pytest.mark.parametrize("value", [1e300, 1e3, 2.5])
def test_au_map_cannot_push_the_expression_past_the_limit(tmp_path: Path, value: float, capsys) -> None:
    from holo_viewer.flame.expressions import default_au_map

    data = default_au_map().to_dict()
    data["aus"]["AU4"][0] = value
    path = tmp_path / "au.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "head.obj"
    rc = main(["export-mesh", "--pain", "1", "--au-map", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "au.json" in err and "aus.AU4[0]" in err and "<= 2" in err, err
    assert not out.exists()


def test_summed_au_map_is_checked_after_it_is_applied(tmp_path: Path, capsys) -> None:
    from holo_viewer.flame.expressions import default_au_map

    data = default_au_map().to_dict()
    for au in ("AU4", "AU6", "AU7", "AU9", "AU10"):
        data["aus"][au][0] = 2.0  # each alone stays within +-10 at full intensity; pain sums them
    path = tmp_path / "au.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "head.obj"
    rc = main(["export-mesh", "--pain", "1", "--au-map", str(path), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "au.json" in err and "expression[0]: expected an expression coefficient in [-10, 10]" in err
    assert not out.exists()


# --------------------------------------------------------------------------- case 15: one seed rule


@pytest.mark.parametrize("argv", [
    ["react", "--seed", "-1"], ["live", "--seed", "-1"], ["demo", "--seed", "-1"],
    ["evaluate-reactions", "--seed", "-1"], ["train-reaction", "--out", "x.pt", "--seed", "-1"],
    ["live", "--seed", str(2**32)], ["react", "--seed", "1.5"],
    ["live", "--video-fps", "nan"], ["live", "--video-fps", "0"], ["demo", "--fps", "inf"], ["show", "f", "--fps", "-2"],
])
def test_seed_and_fps_are_checked_at_parse_time(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    assert ("seed in [0, 2**32)" in err) or ("frames per second" in err)


def test_seed_rule_accepts_the_whole_range() -> None:
    from holo_viewer.validation import seed_arg

    assert seed_arg("0") == 0 and seed_arg(str(2**32 - 1)) == 2**32 - 1


# --------------------------------------------------------------------------- case 16: inputs first


def test_live_probes_a_corrupt_video_first(tmp_path: Path, capsys, monkeypatch) -> None:
    from holo_viewer.live import render
    from holo_viewer.reaction.audio import write_wav

    def expensive(*args, **kwargs):
        raise AssertionError("the renderer was built before the inputs were checked")

    monkeypatch.setattr(render.LiveAvatarRenderer, "__init__", expensive)
    corrupt = tmp_path / "corrupt.mp4"
    corrupt.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    wav = write_wav(tmp_path / "a.wav", np.zeros(16000, np.float32), 16000)
    out = tmp_path / "s"
    rc = main(["live", "--video", str(corrupt), "--audio", str(wav), "--headless", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "corrupt.mp4: cannot read the video" in err, err
    assert len(err.strip().splitlines()) == 1 and "ffmpeg version" not in err
    assert not out.exists()


# --------------------------------------------------------------------------- found by the fuzz suite


def test_fuzz_findings_stay_fixed(tmp_path: Path) -> None:
    """Regressions the Hypothesis suite found: each a one-line error, no big allocation."""
    import tracemalloc

    from holo_viewer.avatar.ply import load_ply
    from holo_viewer.errors import PlyError
    from holo_viewer.reaction.audio import read_wav, write_wav

    ply = tmp_path / "noprops.ply"
    ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nend_header\n\x00")
    with pytest.raises(PlyError, match=r"noprops\.ply: element 'vertex': expected properties"):
        load_ply(ply)  # was ZeroDivisionError
    ply.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n\n")
    with pytest.raises(PlyError, match=r"noprops\.ply: element 'vertex': expected properties"):
        load_ply(ply)  # was IndexError
    wav = write_wav(tmp_path / "a.wav", np.zeros(800, np.float32), 16000)
    data = bytearray(wav.read_bytes())
    at = data.index(b"data") + 4
    data[at:at + 4] = (0x10000640).to_bytes(4, "little")  # 268 MB of samples declared in 1.6 kB
    wav.write_bytes(bytes(data))
    tracemalloc.start()
    try:
        with pytest.raises(ReactionError, match=r"a\.wav: truncated WAV file .*'data' chunk declares 268,437,056 bytes"):
            read_wav(wav)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20
    bad_zip = tmp_path / "method.npz"
    with zipfile.ZipFile(bad_zip, "w") as zf:
        zf.writestr("a.npy", b"x")
    raw = bytearray(bad_zip.read_bytes())
    raw[8:10] = (99).to_bytes(2, "little")  # an unknown compression method in the local header
    cd = raw.rfind(b"PK\x01\x02")
    raw[cd + 10:cd + 12] = (99).to_bytes(2, "little")
    bad_zip.write_bytes(bytes(raw))
    with pytest.raises(HoloViewerError, match=r"method\.npz: cannot read"):
        fileio.read_npz(bad_zip)  # was NotImplementedError
    header = b"{'descr': ('<f8',\n"
    bad_npy = tmp_path / "header.npy"
    bad_npy.write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header)
    with pytest.raises(HoloViewerError, match=r"header\.npy: cannot read .*malformed \.npy header"):
        fileio.read_npy(bad_npy)  # was tokenize.TokenError


def test_live_session_video_cut_short_is_never_renamed_into_place(tmp_path: Path, monkeypatch) -> None:
    """A full disk while the session video is finished (here: one frame short) is an error, not a corrupt video."""
    from holo_viewer import media
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.live.session import NATIVE_VIDEO
    from holo_viewer.pipeline.live_support import SyntheticSpeaker

    real = media.count_video_frames
    monkeypatch.setattr(media, "count_video_frames", lambda p: real(p) - 1)
    syn = SyntheticSpeaker(1.0)
    out = tmp_path / "s"
    session = LiveSession(LiveSessionConfig(out=str(out), tile_scale=0.1, behaviour=None, frames=3),
                          sources.ArrayAudio(syn.waveform), None, syn)
    with pytest.raises(ExportError, match=rf"{NATIVE_VIDEO}: ffmpeg wrote 2 of 3 frames"):
        session.run(_FakeRenderer())
    assert not (out / NATIVE_VIDEO).exists() and not [p for p in out.iterdir() if p.name.startswith(".")]
    assert (out / "session.json").exists()  # the session itself is kept


def test_no_video_is_written_around_media() -> None:
    """Every video writer of the package and apps/ goes through media.VideoWriter (verified, atomic)."""
    offenders = []
    for path in sorted([*(ROOT / "holo_viewer").rglob("*.py"), *(ROOT / "apps").rglob("*.py")]):
        if path.name == "media.py":
            continue
        text = path.read_text(encoding="utf-8")
        offenders += [f"{path.relative_to(ROOT)}: {needle}" for needle in ("get_writer(", "write_frames(")
                      if needle in text]
    assert offenders == []


def test_a_broken_ffmpeg_pipe_is_our_error_naming_the_file(tmp_path: Path, monkeypatch) -> None:
    """ffmpeg gone while a frame is piped (the race a full disk makes): ExportError with ffmpeg's last
    words, no temporary left; the log was once read after abort() had closed it (ValueError)."""
    from holo_viewer import media
    from holo_viewer.errors import ExportError

    writer = media.VideoWriter(tmp_path / "v.mkv", 10, what="test video")
    writer.write(np.zeros((16, 16, 3), np.uint8))

    def broken(data):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(writer, "_write_frame", broken)
    with pytest.raises(ExportError, match=r"v\.mkv: cannot write the test video: ffmpeg stopped"):
        writer.write(np.zeros((16, 16, 3), np.uint8))
    assert os.listdir(tmp_path) == []
