"""Bad inputs, full disks and killed writers end in clear errors, never tracebacks or wrong output (issue 19).

Every CLI case runs through ``holo_viewer.cli.main`` and checks the exit code (1 for a reported
error), that the message names the file or field, and that nothing (no output, no temporary) is
left behind. A full disk is the kernel's own ENOSPC: the writer's temporary file is a symlink to
``/dev/full``.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import textwrap
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from holo_viewer import fileio
from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.avatar.ply import load_ply, save_ply
from holo_viewer.camera import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, Cameras, intrinsics, look_at
from holo_viewer.cli import main
from holo_viewer.errors import CalibrationError, ExportError, InputError, PlyError, ReactionError
from holo_viewer.fileio import load_image, save_image

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "assets" / "lkg_portrait_visual.json"


# --------------------------------------------------------------------------- helpers


@pytest.fixture()
def disk_full(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """Call it to fill the disk: from then on every atomic write's temporary file under ``tmp_path`` is a
    symlink to /dev/full, so writes fail in the kernel with ENOSPC (inputs are prepared before the call).
    ``tempfile`` is the process's one module: writes elsewhere (numba's kernel cache, the package's disk
    caches) are left alone, or a kernel first compiled during the test would fail instead of the output."""
    if not os.path.exists("/dev/full"):
        pytest.skip("/dev/full is not available here")
    real = tempfile.mkstemp
    root = tmp_path.resolve()

    def mkstemp(*args, **kwargs):
        fd, path = real(*args, **kwargs)
        if Path(path).resolve().is_relative_to(root):
            os.unlink(path)
            os.symlink("/dev/full", path)
        return fd, path

    return lambda: monkeypatch.setattr(fileio.tempfile, "mkstemp", mkstemp)


def _no_temporaries(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if ".tmp" in p.name]


def _assert_reported(rc: int, err: str, *needles: str) -> None:
    assert rc == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, (n, err)


def _png16(path: Path, a: np.ndarray) -> Path:
    """A 16-bit PNG (gray, gray+alpha, RGB or RGBA) written by hand (Pillow cannot write 16-bit RGB)."""
    a = np.asarray(a, dtype=">u2")
    h, w = a.shape[:2]
    color = 0 if a.ndim == 2 else {2: 4, 3: 2, 4: 6}[a.shape[2]]
    raw = b"".join(b"\x00" + a[i].tobytes() for i in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, color, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    return path


def _scene(tmp_path: Path, n: int = 40) -> tuple[Path, Path]:
    rng = np.random.default_rng(0)
    g = Gaussians.from_arrays(rng.normal(0, 0.05, (n, 3)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
                              np.log(rng.uniform(0.005, 0.02, (n, 3))).astype(np.float32),
                              rng.normal(1, 1, n).astype(np.float32), rng.normal(0, 0.4, (n, 1, 3)).astype(np.float32))
    ply = save_ply(g, tmp_path / "scene.ply")
    cams = Cameras(np.stack([look_at([o, 0, 0.6], [o, 0, 0]) for o in (-0.02, 0.02)]),
                   np.stack([intrinsics(30, 30, 12, 8)] * 2), 24, 16)
    cams_path = tmp_path / "cams.json"
    cams_path.write_text(json.dumps(cams.to_dicts()))
    return Path(ply), cams_path


def _empty_gaussians() -> Gaussians:
    return Gaussians(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32), np.zeros((0, 3), np.float32),
                     np.zeros(0, np.float32), np.zeros((0, 1, 3), np.float32))


# --------------------------------------------------------------------------- 3. disk full / write errors


def test_write_error_names_file_and_reason(tmp_path: Path) -> None:
    exc = fileio.write_error(tmp_path / "a.png", OSError(errno.ENOSPC, "No space left on device"))
    assert isinstance(exc, ExportError)
    assert "a.png: cannot write the file: no space left on the device (the disk is full)" in str(exc)
    assert "earlier file there is unchanged" in str(exc)
    assert "permission denied" in str(fileio.write_error("x", PermissionError(errno.EACCES, "Permission denied")))


def test_disk_full_on_every_writer_keeps_the_old_file(tmp_path: Path, disk_full) -> None:
    target = tmp_path / "img.png"
    target.write_bytes(b"old")
    disk_full()
    with pytest.raises(ExportError, match=r"img\.png: cannot write the file: no space left on the device"):
        save_image(target, np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ExportError, match=r"a\.npz: cannot write the file: no space left"):
        fileio.save_npz(tmp_path / "a.npz", x=np.zeros(1000))
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.png"]


def test_disk_full_render_ply(tmp_path: Path, disk_full, capsys: pytest.CaptureFixture) -> None:
    ply, cams = _scene(tmp_path)
    out = tmp_path / "views"
    disk_full()
    rc = main(["render-ply", str(ply), "--cameras", str(cams), "--out", str(out), "--quiet"])
    _assert_reported(rc, capsys.readouterr().err, "view_000.png", "no space left on the device")
    assert list(out.iterdir()) == []


def test_disk_full_quilt_to_native(tmp_path: Path, disk_full, capsys: pytest.CaptureFixture) -> None:
    quilt = tmp_path / "q_qs8x6a0.75.png"
    Image = pytest.importorskip("PIL.Image")
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (96, 64, 3), dtype=np.uint8)).save(quilt)
    native = tmp_path / "native.png"
    native.write_bytes(b"earlier native")
    disk_full()
    rc = main(["quilt-to-native", str(quilt), "--out", str(native)])
    _assert_reported(rc, capsys.readouterr().err, "native.png", "no space left on the device")
    assert native.read_bytes() == b"earlier native"
    assert _no_temporaries(tmp_path) == []


def test_disk_full_export_mesh_and_video(tmp_path: Path, disk_full, capsys: pytest.CaptureFixture) -> None:
    disk_full()
    rc = main(["export-mesh", "--out", str(tmp_path / "head.obj")])
    _assert_reported(rc, capsys.readouterr().err, "head.obj", "no space left on the device")
    from holo_viewer.display.export import write_quilt_video

    frames = [np.full((16, 16, 3), i * 40, np.uint8) for i in range(3)]
    with pytest.raises(ExportError, match=r"v\.mp4"):
        write_quilt_video(tmp_path / "v.mp4", frames, fps=5, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_permission_denied_is_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture) -> None:
    real, root = os.replace, tmp_path.resolve()

    def deny(src, dst):  # os is the process's one module: only this test's outputs are denied (numba's
        if Path(dst).resolve().is_relative_to(root):  # cache of a kernel first compiled here is not)
            raise PermissionError(errno.EACCES, "Permission denied", str(dst))
        return real(src, dst)

    monkeypatch.setattr(fileio.os, "replace", deny)
    quilt = tmp_path / "q_qs8x6a0.75.png"
    from PIL import Image

    Image.fromarray(np.zeros((96, 64, 3), np.uint8)).save(quilt)
    rc = main(["quilt-to-native", str(quilt), "--out", str(tmp_path / "n.png")])
    _assert_reported(rc, capsys.readouterr().err, "n.png", "permission denied")
    assert _no_temporaries(tmp_path) == []


def test_output_below_a_file_is_reported(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["export-mesh", "--out", str(blocker / "sub" / "head.obj")])
    _assert_reported(rc, capsys.readouterr().err, "is a file")
    ply, cams = _scene(tmp_path)
    rc = main(["render-ply", str(ply), "--cameras", str(cams), "--out", str(blocker / "views"), "--quiet"])
    _assert_reported(rc, capsys.readouterr().err, "is a file")
    with pytest.raises(ExportError, match="is a file"):
        save_image(blocker / "a.png", np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(ExportError, match="the path is a directory"):
        fileio.check_writable(tmp_path)


@pytest.mark.slow
def test_disk_full_demo(tmp_path: Path, disk_full, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "demo"
    disk_full()
    rc = main(["demo", "--out", str(out), "--seconds", "0.4", "--fps", "5", "--video-scale", "0.1",
               "--skip-head-renders", "--time-budget", "0"])
    _assert_reported(rc, capsys.readouterr().err, "default_qs8x6a0.75.png", "no space left on the device")
    assert list(out.iterdir()) == []
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["demo", "--out", str(blocker / "demo"), "--skip-head-renders"])
    _assert_reported(rc, capsys.readouterr().err, "is a file")


# --------------------------------------------------------------------------- 4. 16-bit images


def test_16bit_gray_png_is_scaled_not_clipped(tmp_path: Path) -> None:
    a = np.linspace(0, 65535, 12 * 8).reshape(8, 12).astype(np.uint16)
    img = load_image(_png16(tmp_path / "g16.png", a))
    assert img.shape == (8, 12, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img[..., 0], a / 65535.0, atol=1e-6)
    np.testing.assert_array_equal(img[..., 0], img[..., 2])
    rgb = np.stack([a, a // 2, a // 3], -1)
    img = load_image(_png16(tmp_path / "rgb16.png", rgb))  # Pillow reads 16-bit RGB at 8 bits
    np.testing.assert_allclose(img, rgb / 65535.0, atol=1.0 / 255)
    img = load_image(_png16(tmp_path / "rgba16.png", np.concatenate([rgb, a[..., None]], -1)))
    np.testing.assert_allclose(img, rgb / 65535.0, atol=1.0 / 255)


def test_float_and_32bit_images_are_refused(tmp_path: Path) -> None:
    from PIL import Image

    Image.fromarray(np.full((4, 4), 0.5, np.float32), mode="F").save(tmp_path / "f.tif")
    with pytest.raises(ExportError, match=r"f\.tif: 32-bit float image \(Pillow mode 'F'\)"):
        load_image(tmp_path / "f.tif")
    Image.fromarray(np.full((4, 4), 70000, np.int32), mode="I").save(tmp_path / "i.tif")
    with pytest.raises(ExportError, match=r"i\.tif: integer image"):
        load_image(tmp_path / "i.tif")


def test_quilt_to_native_16bit_matches_8bit(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    rng = np.random.default_rng(1)
    gray8 = rng.integers(0, 256, (96, 64), dtype=np.uint16)
    q16 = _png16(tmp_path / "q16_qs8x6a0.75.png", gray8 * 257)  # exact 16-bit copy of the 8-bit values
    from PIL import Image

    q8 = tmp_path / "q8_qs8x6a0.75.png"
    Image.fromarray(gray8.astype(np.uint8)).save(q8)
    assert main(["quilt-to-native", str(q16), "--out", str(tmp_path / "n16.png")]) == 0
    assert main(["quilt-to-native", str(q8), "--out", str(tmp_path / "n8.png")]) == 0
    n16, n8 = load_image(tmp_path / "n16.png"), load_image(tmp_path / "n8.png")
    np.testing.assert_array_equal(n16, n8)
    assert 0.3 < n16.mean() < 0.7  # not the saturated mask of a clipped 16-bit image


# --------------------------------------------------------------------------- 6. empty PLY


@pytest.mark.parametrize("fmt", ["binary", "ascii"])
def test_empty_ply_renders_background_in_every_backend(tmp_path: Path, fmt: str, capsys) -> None:
    from holo_viewer.render.api import render_views
    from holo_viewer.render.config import RenderConfig

    ply = save_ply(_empty_gaussians(), tmp_path / "empty.ply")
    if fmt == "ascii":
        ply.write_bytes(ply.read_bytes().replace(b"binary_little_endian", b"ascii"))
    g = load_ply(ply)
    assert len(g) == 0
    _, cams = _scene(tmp_path)
    from holo_viewer.commands.render_ply import load_cameras

    cameras = load_cameras(cams)
    for backend in ("reference", "fast", "torch", "vtk", "auto"):
        res = render_views(g, cameras, backend=backend, config=RenderConfig(background=(0.2, 0.4, 0.6)))
        assert res.images.shape == (2, 16, 24, 3)
        np.testing.assert_allclose(res.images, np.broadcast_to([0.2, 0.4, 0.6], res.images.shape), atol=1e-7)
    out = tmp_path / "views"
    assert main(["render-ply", str(ply), "--cameras", str(cams), "--out", str(out), "--background", "1,1,1",
                 "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["view_000.png", "view_001.png"]
    assert load_image(out / "view_001.png").min() == 1.0


# --------------------------------------------------------------------------- 7./8. cameras


def test_camera_size_limit_is_checked_before_allocating() -> None:
    K = intrinsics(100, 100, 50, 50)
    for w, h in [(100000, 100000), (20000, 20000), (MAX_IMAGE_SIDE + 1, 16), (9000, 9000)]:
        with pytest.raises(InputError, match=r"width, height: expected at most 16384 pixels per side"):
            Cameras(np.eye(4), K, w, h)
    assert Cameras(np.eye(4), K, 8192, 8192).width == 8192
    assert Cameras(np.eye(4), K, MAX_IMAGE_SIDE, MAX_IMAGE_PIXELS // MAX_IMAGE_SIDE).width == MAX_IMAGE_SIDE


def _cams_json(tmp_path: Path, **change) -> Path:
    cam = {"width": 24, "height": 16, "fx": 30.0, "fy": 30.0, "cx": 12.0, "cy": 8.0,
           "world_to_cam": look_at([0, 0, 0.6], [0, 0, 0]).tolist(), "near": 0.01, "far": 100.0}
    cam.update(change)
    p = tmp_path / "bad_cams.json"
    p.write_text(json.dumps([cam]))
    return p


@pytest.mark.parametrize("change,needle", [
    ({"near": "abc"}, "bad_cams.json[0].near: expected a number, found str 'abc'"),
    ({"near": None}, "bad_cams.json[0].near: expected a number, found null"),
    ({"near": True}, "bad_cams.json[0].near: expected a number, found bool"),
    ({"far": "100"}, "bad_cams.json[0].far: expected a number, found str '100'"),
    ({"near": -1}, "bad_cams.json[0].near: expected > 0.0"),
    ({"near": 5.0, "far": 1.0}, "far: expected > near"),
    ({"width": 64.7}, "bad_cams.json[0].width: expected an integer, found 64.7"),
    ({"width": "24"}, "bad_cams.json[0].width: expected an integer, found str '24'"),
    ({"height": 0}, "width, height: expected positive integers"),
    ({"width": 100000, "height": 100000}, "expected at most 16384 pixels per side"),
    ({"fx": [30]}, "bad_cams.json[0].fx: expected a number, found list"),
    ({"world_to_cam": [["1", 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
     "bad_cams.json[0].world_to_cam: expected a 4x4 matrix of numbers"),
    ({"world_to_cam": None}, "world_to_cam: expected a 4x4 matrix of numbers (a list of 4 rows), found null"),
    ({"world_to_cam": [[1, 0, 0], [0, 1, 0]]}, "found an array of shape (2, 3)"),
])
def test_cameras_json_wrong_types(tmp_path: Path, change: dict, needle: str, capsys) -> None:
    ply, _ = _scene(tmp_path)
    rc = main(["render-ply", str(ply), "--cameras", str(_cams_json(tmp_path, **change)),
               "--out", str(tmp_path / "o"), "--quiet"])
    _assert_reported(rc, capsys.readouterr().err, needle)
    assert not (tmp_path / "o").exists() or list((tmp_path / "o").iterdir()) == []


@pytest.mark.parametrize("text,needle", [("[]", "expected a non-empty list of camera objects"),
                                         ("{}", "expected a non-empty list of camera objects, found dict"),
                                         ("[1]", "[0]: expected an object, found int"),
                                         ("null", "found NoneType")])
def test_zero_cameras(tmp_path: Path, text: str, needle: str, capsys) -> None:
    ply, _ = _scene(tmp_path)
    cams = tmp_path / "c.json"
    cams.write_text(text)
    rc = main(["render-ply", str(ply), "--cameras", str(cams), "--out", str(tmp_path / "o"), "--quiet"])
    _assert_reported(rc, capsys.readouterr().err, needle)


# --------------------------------------------------------------------------- 9. WAV


def _wav_bytes() -> bytes:
    import io

    from scipy.io import wavfile

    b = io.BytesIO()
    wavfile.write(b, 16000, np.zeros(200, np.int16))
    return b.getvalue()


@pytest.mark.filterwarnings("ignore::scipy.io.wavfile.WavFileWarning")
def test_corrupt_wav_headers_are_reported(tmp_path: Path) -> None:
    from holo_viewer.reaction.audio import read_wav

    good = _wav_bytes()
    rng = np.random.default_rng(0)
    kinds = set()
    path = tmp_path / "c.wav"
    for _ in range(400):  # random damage to the RIFF / fmt / data headers
        d = bytearray(good)
        for _ in range(int(rng.integers(1, 4))):
            d[int(rng.integers(0, 44))] = int(rng.integers(0, 256))
        path.write_bytes(bytes(d))
        try:
            read_wav(path)
        except ReactionError as exc:
            kinds.add(str(exc).split("(")[-1].split(":")[0])
        except InputError:
            pass
    assert len(kinds) >= 2  # several different parser failures, all reported as ReactionError
    # the case the issue found: a fmt chunk whose format tag scipy does not know -> UnboundLocalError inside scipy
    d = bytearray(good)
    d[20:22] = struct.pack("<H", 0xFFFE)  # WAVE_FORMAT_EXTENSIBLE without the extension
    path.write_bytes(bytes(d))
    with pytest.raises(ReactionError, match=r"c\.wav: not a readable WAV file"):
        read_wav(path)


def test_truncated_and_empty_wav(tmp_path: Path) -> None:
    from holo_viewer.reaction.audio import read_wav, write_wav

    write_wav(tmp_path / "a.wav", np.zeros(16000), 16000)
    data = (tmp_path / "a.wav").read_bytes()
    (tmp_path / "t.wav").write_bytes(data[: len(data) // 2])
    with pytest.raises(ReactionError, match=r"t\.wav: truncated WAV file"):
        read_wav(tmp_path / "t.wav")
    (tmp_path / "e.wav").write_bytes(b"")
    with pytest.raises(ReactionError, match=r"e\.wav: not a readable WAV file"):
        read_wav(tmp_path / "e.wav")
    write_wav(tmp_path / "z.wav", np.zeros(0), 16000)
    with pytest.raises(ReactionError, match=r"z\.wav: expected a mono or stereo waveform"):
        read_wav(tmp_path / "z.wav")


# --------------------------------------------------------------------------- 10. react --out


def _speaker_files(tmp_path: Path) -> tuple[Path, Path]:
    from holo_viewer.flame.expressions import default_au_map, jaw_for_expression
    from holo_viewer.reaction.api import flame_params_from_states
    from holo_viewer.reaction.audio import write_wav
    from holo_viewer.reaction.data import SyntheticConfig, synth_speaker

    au = default_au_map()
    sp = synth_speaker(np.random.default_rng(3), SyntheticConfig(seconds=1.0), au.names,
                       jaw_for_expression("mouth_open", 1.0))
    wav = write_wav(tmp_path / "s.wav", sp.waveform, 16000)
    npz = tmp_path / "s.npz"
    np.savez(npz, **flame_params_from_states(sp.state, au))
    return wav, npz


def test_react_bad_outputs_and_inputs(tmp_path: Path, capsys) -> None:
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip("shipped reaction checkpoint missing")
    wav, npz = _speaker_files(tmp_path)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["react", "--audio", str(wav), "--speaker", str(npz), "--out", str(blocker / "out.npz")])
    _assert_reported(rc, capsys.readouterr().err, "is a file")
    rc = main(["react", "--audio", str(wav), "--speaker", str(npz), "--out", str(tmp_path)])
    _assert_reported(rc, capsys.readouterr().err, "the path is a directory")
    corrupt = tmp_path / "corrupt.wav"
    d = bytearray(wav.read_bytes())
    d[20:22] = struct.pack("<H", 0xFFFE)
    corrupt.write_bytes(bytes(d))
    rc = main(["react", "--audio", str(corrupt), "--speaker", str(npz), "--out", str(tmp_path / "o.npz")])
    _assert_reported(rc, capsys.readouterr().err, "corrupt.wav: not a readable WAV file")
    empty = tmp_path / "empty.npz"
    np.savez(empty, expr=np.zeros((0, 100)), jaw_pose=np.zeros((0, 3)), rotation=np.zeros((0, 3)))
    rc = main(["react", "--audio", str(wav), "--speaker", str(empty), "--out", str(tmp_path / "o.npz")])
    assert rc == 1 and "Traceback" not in capsys.readouterr().err
    assert not (tmp_path / "o.npz").exists()


def test_disk_full_react(tmp_path: Path, disk_full, capsys) -> None:
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip("shipped reaction checkpoint missing")
    wav, npz = _speaker_files(tmp_path)
    out = tmp_path / "out"
    disk_full()
    rc = main(["react", "--audio", str(wav), "--speaker", str(npz), "--out", str(out / "l.npz")])
    _assert_reported(rc, capsys.readouterr().err, "l.npz", "no space left on the device")
    assert list(out.iterdir()) == []


# --------------------------------------------------------------------------- 11. train-reaction config


@pytest.mark.parametrize("config,needle", [
    ({"max_steps": "x"}, "max_steps: expected an integer, found str 'x'"),
    ({"max_steps": 0}, "max_steps: expected >= 1"),
    ({"max_steps": -5}, "max_steps: expected >= 1"),
    ({"batch_size": 0}, "batch_size: expected >= 1"),
    ({"batch_size": 2.5}, "batch_size: expected an integer, found 2.5"),
    ({"lr": -0.1}, "lr: expected > 0"),
    ({"lr": float("nan")}, "lr: expected a finite number"),
    ({"lr": None}, "lr: expected a number, found null"),
    ({"warmup": 0}, "warmup: expected >= 1"),
    ({"threads": 0}, "threads: expected >= 1"),
    ({"model": {"d_model": "x"}}, "model.d_model: expected an integer, found str 'x'"),
    ({"model": {"d_model": 30, "n_heads": 4}}, "model.d_model: expected a multiple of model.n_heads"),
    ({"model": {"speaker_window": 15}}, "model.speaker_window: expected an even number"),
    ({"model": {"dropout": 1.5}}, "model.dropout: expected <= 1"),
    ({"model": "big"}, "model: expected a JSON object of ModelConfig fields, found str"),
    ({"data": {"seconds": 0}}, "data.seconds: expected >= 1.0"),
    ({"data": {"audio": {"fmax": 9000}}}, "fmin < fmax <= sample_rate / 2"),
    ({"data": {"audio": []}}, "audio: expected a JSON object of AudioConfig fields, found list"),
    ({"n_codes": 1024}, "n_codes: expected <= model.n_codes (512)"),
    ({"unknown": 1}, "unknown keys ['unknown']"),
])
def test_train_reaction_config_is_checked_before_training(tmp_path: Path, config: dict, needle: str, capsys) -> None:
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(config))
    out = tmp_path / "ckpt.pt"
    t0 = time.perf_counter()
    rc = main(["train-reaction", "--config", str(cfg), "--out", str(out), "--config-out", str(tmp_path / "eff.json"),
               "--no-progress"])
    captured = capsys.readouterr()
    _assert_reported(rc, captured.err, "cfg.json", needle)
    assert "generating synthetic data" not in captured.out  # refused before any work
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cfg.json"]
    assert time.perf_counter() - t0 < 60  # (a loose sanity bound: it must not have trained)


def test_train_reaction_overrides_and_unwritable_out(tmp_path: Path, capsys) -> None:
    rc = main(["train-reaction", "--out", str(tmp_path / "c.pt"), "--max-steps", "0", "--no-progress"])
    _assert_reported(rc, capsys.readouterr().err, "max_steps: expected >= 1")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["train-reaction", "--out", str(blocker / "c.pt"), "--no-progress"])
    captured = capsys.readouterr()
    _assert_reported(rc, captured.err, "is a file")
    assert "generating synthetic data" not in captured.out
    rc = main(["train-reaction", "--out", str(tmp_path), "--no-progress"])
    _assert_reported(rc, capsys.readouterr().err, "the path is a directory")
    from holo_viewer.reaction.train import TrainConfig, validate_train_config

    assert validate_train_config(TrainConfig()) == TrainConfig()


# --------------------------------------------------------------------------- 12. calibration and PLY header


@pytest.mark.parametrize("field,value,needle", [
    ("center", 1e300, "field 'center': expected a lens phase in [-1000, 1000], found 1e+300"),
    ("pitch", 1e-300, "field 'pitch': expected lenticules per inch in [1, 1000]"),
    ("pitch", 1e300, "field 'pitch'"),
    ("DPI", 1e-300, "field 'DPI': expected pixels per inch"),
    ("slope", 1e-300, "field 'slope': expected a lens slope"),
    ("screenW", 1.5, "field 'screenW': expected a positive integer"),
    ("pitch", "52", "field 'pitch': expected a number, found '52'"),
    ("viewCone", None, "field 'viewCone': expected a number, found None"),
])
def test_absurd_calibration_values_are_refused(tmp_path: Path, field: str, value, needle: str, capsys) -> None:
    from holo_viewer.display.calibration import DisplayCalibration

    raw = json.loads(FIXTURE.read_text())
    raw[field] = {"value": value}
    cal = tmp_path / "visual.json"
    cal.write_text(json.dumps(raw))
    with pytest.raises(CalibrationError, match="visual.json"):
        DisplayCalibration.load(cal)
    from PIL import Image

    quilt = tmp_path / "q_qs8x6a0.75.png"
    Image.fromarray(np.zeros((96, 64, 3), np.uint8)).save(quilt)
    rc = main(["quilt-to-native", str(quilt), "--calibration", str(cal), "--out", str(tmp_path / "n.png")])
    _assert_reported(rc, capsys.readouterr().err, needle)
    assert not (tmp_path / "n.png").exists()


def test_lens_count_rule() -> None:
    from dataclasses import replace

    from holo_viewer.display.calibration import DisplayCalibration

    cal = DisplayCalibration.load(None)
    with pytest.raises(CalibrationError, match="lenticules across the screen"):
        replace(cal, pitch=1.0, dpi=5000.0)  # 0.3 lenses across the screen
    with pytest.raises(CalibrationError, match="lenticules across the screen"):
        replace(cal, pitch=1000.0, dpi=10.0)  # 1e5 lenses on 1536 pixels


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_ply_header_claiming_billions_of_vertices(tmp_path: Path, fmt: str) -> None:
    ply = save_ply(_empty_gaussians(), tmp_path / "e.ply")
    data = ply.read_bytes().replace(b"binary_little_endian", fmt.encode())
    data = data.replace(b"element vertex 0", b"element vertex 10000000000") + b"1 2 3\n"
    ply.write_bytes(data)
    t0 = time.perf_counter()
    with pytest.raises(PlyError, match=r"e\.ply: truncated: header declares 10000000000 vertices"):
        load_ply(ply)
    assert time.perf_counter() - t0 < 30  # (loose: it must not try to allocate ~1 TB first)


# --------------------------------------------------------------------------- 13. stale temporaries, SIGTERM


def _fake_temp(target: Path, age_s: float) -> Path:
    tmp = target.parent / f".{target.stem}.ab12cd_9.tmp{target.suffix}"
    tmp.write_bytes(b"partial video")
    t = time.time() - age_s
    os.utime(tmp, (t, t))
    return tmp


def test_stale_temporaries_are_removed_by_the_next_write(tmp_path: Path) -> None:
    target = tmp_path / "clip.png"
    stale = _fake_temp(target, age_s=3600)
    other = tmp_path / ".other.ab12cd_9.tmp.png"  # another target's temporary
    other.write_bytes(b"x")
    os.utime(other, (time.time() - 3600,) * 2)
    lookalike = tmp_path / ".clip.notatemp.png"
    lookalike.write_bytes(b"x")
    save_image(target, np.zeros((2, 2, 3), np.uint8))
    assert not stale.exists()
    assert other.exists() and lookalike.exists()


def test_temporaries_of_live_or_newer_writers_are_kept(tmp_path: Path) -> None:
    import fcntl

    target = tmp_path / "clip.png"
    locked = _fake_temp(target, age_s=3600)
    fd = os.open(locked, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)  # a writer that is still alive holds its temporary's lock
    try:
        save_image(target, np.zeros((2, 2, 3), np.uint8))
        assert locked.exists()
    finally:
        os.close(fd)
    locked.unlink()
    fresh = _fake_temp(target, age_s=-5)  # newer than this process: maybe another run's
    save_image(target, np.zeros((2, 2, 3), np.uint8))
    assert fresh.exists()


_SLOW_WRITER = """
import sys, time, types
import numpy as np
from holo_viewer import cli
from holo_viewer.fileio import atomic_path

mod = types.ModuleType("holo_viewer.commands._slow_writer")
def add_arguments(p): p.add_argument("out")
def run(args):
    with atomic_path(args.out) as tmp:
        tmp.write_bytes(b"partial")
        print("writing", flush=True)
        time.sleep(60)
    return 0
mod.add_arguments, mod.run = add_arguments, run
sys.modules[mod.__name__] = mod
cli.SUBCOMMANDS["slow-writer"] = ("_slow_writer", "test")
sys.exit(cli.main(["slow-writer", sys.argv[1]]))
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_killed_writer_leaves_no_lasting_temporary(tmp_path: Path, sig: int) -> None:
    target = tmp_path / "video.mp4"
    target.write_bytes(b"earlier video")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(target)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        proc.send_signal(sig)
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    temps = [p for p in tmp_path.iterdir() if ".tmp" in p.name]
    assert target.read_bytes() == b"earlier video"  # the destination is never partial
    if sig == signal.SIGTERM:
        assert rc == 143 and "terminated" in proc.stderr.read()
        assert temps == []
        return
    assert rc == -signal.SIGKILL and len(temps) == 1  # SIGKILL runs no cleanup: the next run does it
    time.sleep(0.05)
    script = ("import numpy as np, sys; from holo_viewer.fileio import save_npz; "
              "save_npz(sys.argv[1], x=np.zeros(3))")
    subprocess.run([sys.executable, "-c", script, str(tmp_path / "video.npz")], check=True, env=env, timeout=60)
    assert temps[0].exists()  # another target's run leaves it alone
    subprocess.run([sys.executable, "-c", textwrap.dedent("""
        import sys
        from holo_viewer.fileio import atomic_path
        with atomic_path(sys.argv[1]) as tmp:
            tmp.write_bytes(b"new video")
        """), str(target)], check=True, env=env, timeout=60)
    assert not temps[0].exists() and target.read_bytes() == b"new video"
    assert [p for p in tmp_path.iterdir() if ".tmp" in p.name] == []


# --------------------------------------------------------------------------- export-mesh --expr range


def test_export_mesh_expression_values_are_range_checked(tmp_path: Path, capsys) -> None:
    rc = main(["export-mesh", "--expr", "0=1e6", "--out", str(tmp_path / "h.obj")])
    _assert_reported(rc, capsys.readouterr().err, "--expr 0: expected <= 10")
    rc = main(["export-mesh", "--expr", "1=-11", "--out", str(tmp_path / "h.obj")])
    _assert_reported(rc, capsys.readouterr().err, "--expr 1: expected >= -10")
    assert not (tmp_path / "h.obj").exists()
    assert main(["export-mesh", "--expr", "0=2.5", "--out", str(tmp_path / "h.obj")]) == 0


# --------------------------------------------------------------------------- sweep: empty inputs, JSON types, writes


def test_zero_cameras_in_the_api() -> None:
    with pytest.raises(InputError, match="expected at least one camera, found 0"):
        Cameras(np.zeros((0, 4, 4)), np.zeros((0, 3, 3)), 10, 10)
    cams = Cameras(np.eye(4), intrinsics(10, 10, 5, 5), 10, 10)
    with pytest.raises(InputError, match="at least one camera"):
        cams[[]]


@pytest.mark.parametrize("loader", ["au_map", "calibration", "train_config", "cameras"])
def test_json_inputs_that_are_not_text(tmp_path: Path, loader: str) -> None:
    from holo_viewer.commands.render_ply import load_cameras
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.errors import HoloViewerError
    from holo_viewer.flame.expressions import AUMap
    from holo_viewer.reaction.train import load_train_config

    p = tmp_path / "binary.json"
    p.write_bytes(b"\xff\xfe\x00\x01 not utf-8")
    fn = {"au_map": AUMap.load_json, "calibration": DisplayCalibration.load, "train_config": load_train_config,
          "cameras": load_cameras}[loader]
    with pytest.raises(HoloViewerError, match=r"binary\.json: cannot read"):
        fn(p)


def test_results_json_checked_before_evaluating(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["evaluate-reactions", "--json", str(blocker / "r.json")])
    captured = capsys.readouterr()
    _assert_reported(rc, captured.err, "r.json: cannot write the file", "is a file, not a directory")
    assert "generating" not in captured.out


def test_pipeline_after_importing_the_default_avatar_module() -> None:
    """Importing the default avatar's module (``holo_viewer.avatar.default_gaussians``, as
    evaluate-reactions does) must not break the default scene."""
    import importlib

    importlib.import_module("holo_viewer.avatar.default_gaussians")
    from holo_viewer.pipeline.scene import load_scene

    scene = load_scene("default", None, None, None)
    assert len(scene.pipeline.avatar) > 0


def test_check_array_refuses_non_numeric_arrays() -> None:
    from holo_viewer.validation import check_array

    for bad in (np.array(["1", "2"]), np.array([b"x"]), np.array([None, 1.0], dtype=object)):
        with pytest.raises(InputError, match=r"x: expected a numeric array, found dtype"):
            check_array(bad, "x")
    assert check_array(np.array([True, False]), "x").dtype == bool


def test_react_empty_past_and_text_arrays(tmp_path: Path, capsys) -> None:
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip("shipped reaction checkpoint missing")
    wav, npz = _speaker_files(tmp_path)
    past = tmp_path / "past0.npz"
    np.savez(past, expr=np.zeros((0, 24)), jaw_pose=np.zeros((0, 3)), rotation=np.zeros((0, 3)))
    out = tmp_path / "o.npz"
    assert main(["react", "--audio", str(wav), "--speaker", str(npz), "--listener-past", str(past),
                 "--out", str(out)]) == 0  # an empty past is no past
    with np.load(npz) as z:
        text = {k: z[k] for k in z.files}
    text["expr"] = text["expr"].astype(str)
    bad = tmp_path / "text.npz"
    np.savez(bad, **text)
    rc = main(["react", "--audio", str(wav), "--speaker", str(bad), "--out", str(tmp_path / "o2.npz")])
    _assert_reported(rc, capsys.readouterr().err, "text.npz: expr: expected a numeric array, found dtype <U")


def test_flame_sequence_text_and_empty() -> None:
    from holo_viewer.pipeline import flame_sequence_frames

    with pytest.raises(InputError, match=r"seq: expr: expected numbers, found dtype <U3"):
        flame_sequence_frames({"expr": np.array([["abc"] * 4])}, source="seq")
    with pytest.raises(InputError, match=r"seq: shape: expected numbers"):
        flame_sequence_frames({"expr": np.zeros((2, 4)), "shape": np.array(["x"])}, source="seq")
    with pytest.raises(InputError, match=r"seq: expected at least one frame, found 0"):
        flame_sequence_frames({"expr": np.zeros((0, 4)), "jaw_pose": np.zeros((0, 3))}, source="seq")
    assert len(flame_sequence_frames({"expr": np.zeros((2, 4))}, source="seq")) == 2


def test_render_batch_bad_out_and_disk_full(tmp_path: Path, disk_full, capsys) -> None:
    manifest = tmp_path / "m.jsonl"
    manifest.write_text(json.dumps({"id": "a", "frames": 2, "tile_scale": 0.1, "outputs": ["quilt_png"]}) + "\n")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc = main(["render-batch", str(manifest), "--out", str(blocker / "o"), "--in-process", "--no-progress"])
    _assert_reported(rc, capsys.readouterr().err, "is a file")
    empty = tmp_path / "empty.jsonl"
    empty.write_text("\n")
    rc = main(["render-batch", str(empty), "--out", str(tmp_path / "o"), "--in-process", "--no-progress"])
    _assert_reported(rc, capsys.readouterr().err, "expected at least one job row, found none")
    out = tmp_path / "full"
    out.mkdir()
    disk_full()
    rc = main(["render-batch", str(manifest), "--out", str(out), "--in-process", "--no-progress"])
    captured = capsys.readouterr()
    assert rc == 1 and "Traceback" not in captured.err + captured.out
    assert "no space left on the device" in captured.err + captured.out
    assert [p for p in out.rglob("*") if p.is_file()] == []


@pytest.mark.parametrize("case", ["missing", "malformed", "not_utf8", "directory"])
def test_read_json_errors_name_the_file(tmp_path, case):
    """fileio.read_json (training config, webcam mount, scenario, session metadata): every way a
    JSON file can be unreadable is the caller's error class naming the file and what it is."""
    from holo_viewer.errors import TrackingError

    p = tmp_path / "mount.json"
    if case == "malformed":
        p.write_text("{oops")
    elif case == "not_utf8":
        p.write_bytes(b"\xff\xfe{}")
    elif case == "directory":
        p.mkdir()
    with pytest.raises(TrackingError, match=r"mount\.json.*webcam mount JSON"):
        fileio.read_json(p, TrackingError, "webcam mount JSON")


def test_read_json_returns_the_content(tmp_path):
    p = tmp_path / "x.json"
    p.write_text(json.dumps({"a": [1, 2.5, None]}), encoding="utf-8")
    assert fileio.read_json(p) == {"a": [1, 2.5, None]}
