"""Fullscreen window under Xvfb: a screenshot of the window equals the expected native image."""

import os
import subprocess
import sys

import numpy as np
import pytest

from holo_viewer.display.calibration import DisplayCalibration, default_calibration_path
from holo_viewer.display.export import save_native_png, save_quilt_png
from holo_viewer.display.lenticular import Interleaver
from holo_viewer.display.quilt import tile_quilt
from holo_viewer.display.simulate import id_pattern_views
from holo_viewer.fileio import load_image

FIXTURE = str(default_calibration_path())
pytestmark = pytest.mark.gui


@pytest.fixture(scope="module")
def xvfb(xvfb_server):
    with xvfb_server("1536x2048x24") as display:  # the Portrait's screen
        yield display


def _show(display, *args):
    env = {k: v for k, v in os.environ.items() if k != "VTK_DEFAULT_OPENGL_WINDOW"}
    env["DISPLAY"] = display
    return subprocess.run([sys.executable, "-m", "holo_viewer", "show", *args, "--calibration", FIXTURE],
                          env=env, capture_output=True, text=True, timeout=300)


def test_native_and_quilt_screenshots(xvfb, tmp_path):
    cal = DisplayCalibration.from_file(FIXTURE)
    views = id_pattern_views(48, 560, 420, "flat")
    quilt = tile_quilt(views, 8, 6)
    native = Interleaver(cal, quilt.shape)(quilt)
    qpath = save_quilt_png(tmp_path / "flat", quilt, 8, 6, 0.75)
    r = _show(xvfb, str(qpath), "--screenshot", str(tmp_path / "shot_q.png"))
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    shot = np.rint(load_image(tmp_path / "shot_q.png") * 255).astype(np.uint8)
    assert shot.shape == (2048, 1536, 3) and np.array_equal(shot, native)
    rng = np.random.default_rng(3)
    noise = rng.integers(0, 256, (2048, 1536, 3), dtype=np.uint8)
    npath = save_native_png(tmp_path / "native.png", noise)
    r = _show(xvfb, str(npath), "--screenshot", str(tmp_path / "shot_n.png"))
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    assert np.array_equal(np.rint(load_image(tmp_path / "shot_n.png") * 255).astype(np.uint8), noise)


def test_sequence_plays_and_wrong_size_is_refused(xvfb, tmp_path, monkeypatch, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    for i in range(3):
        save_native_png(seq / f"f{i}.png", np.full((2048, 1536, 3), 60 * i, np.uint8))
    r = _show(xvfb, str(seq), "--frames", "3", "--fps", "30")
    assert r.returncode == 0 and "shown 3 frame(s)" in r.stderr, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    # the refusals come before any window opens: in process (the real process is the runs above)
    from holo_viewer.cli import main

    monkeypatch.setenv("DISPLAY", xvfb)
    save_native_png(tmp_path / "small.png", np.zeros((10, 10, 3), np.uint8))
    assert main(["show", str(tmp_path / "small.png"), "--screenshot", str(tmp_path / "s.png"),
                 "--calibration", FIXTURE]) == 1
    assert "not the panel's native" in capsys.readouterr().err
    assert not (tmp_path / "s.png").exists()
    save_native_png(tmp_path / "native.png", np.zeros((2048, 1536, 3), np.uint8))
    assert main(["show", str(tmp_path / "native.png"), "--monitor", "5", "--calibration", FIXTURE]) == 1
    assert "monitor" in capsys.readouterr().err
