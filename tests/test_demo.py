"""``holo-viewer demo`` end to end (small settings), and its timing table."""

from __future__ import annotations

import json

import numpy as np
import pytest

from holo_viewer.commands.demo import format_timing_table


def test_timing_table_layout():
    table = format_timing_table([("quilt", 1.25, "a.png"), ("native image", 0.5, "")])
    lines = table.splitlines()
    assert lines[0].split()[:2] == ["step", "seconds"]
    assert "1.250" in lines[2] and "a.png" in lines[2]
    assert lines[2].index("1.250") == lines[3].index("0.500")  # right-aligned seconds column


def test_demo_rejects_bad_options(tmp_path, capsys):
    from holo_viewer.cli import main

    assert main(["demo", "--out", str(tmp_path), "--pain", "2"]) == 1
    assert "--pain" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_writes_quilt_native_video_and_timings(tmp_path, capsys):
    from holo_viewer.cli import main
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.fileio import load_image
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip(f"the shipped reaction checkpoint {default_checkpoint_path()} is not there yet")
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--seconds", "0.4", "--fps", "5", "--video-scale", "0.1",
               "--skip-head-renders", "--time-budget", "0"])
    assert rc == 0
    cal = DisplayCalibration.load(None)
    quilt = load_image(out / "default_qs8x6a0.75.png")
    assert quilt.shape == (cal.quilt_height, cal.quilt_width, 3)
    tiles = quilt.reshape(cal.rows, quilt.shape[0] // cal.rows, cal.cols, quilt.shape[1] // cal.cols, 3)
    assert np.all(tiles.std(axis=(1, 3, 4)) > 0.05)  # every one of the 48 views shows something
    native = load_image(out / "default_native.png")
    assert native.shape == (cal.screen_h, cal.screen_w, 3) and native.std() > 0.05
    import imageio.v3 as iio

    video = iio.imread(out / "default_reaction_qs8x6a0.75.mp4")
    assert video.shape[0] == 2  # 0.4 s at 5 fps
    assert video.shape[1:3] == (6 * round(560 * 0.1), 8 * round(420 * 0.1))
    rec = json.loads((out / "timings.json").read_text())
    assert rec["video"]["frames"] == 2 and rec["first_quilt_stage_seconds"]["views"] > 0
    assert rec["config"]["behaviour"]["gaze"] and rec["config"]["behaviour"]["blinks"]  # on by default
    printed = capsys.readouterr().out
    assert "pipeline stages" in printed and "reaction quilt video" in printed
    assert not list(out.glob("*.tmp*"))
