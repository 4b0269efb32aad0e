"""DisplayCalibration: parsing (wrapped and flat), validation errors naming the field, presets."""

import json

import pytest

from holo_viewer.display.calibration import PRESETS, DisplayCalibration, default_calibration_path, preset_for_serial
from holo_viewer.errors import CalibrationError

FIXTURE = str(default_calibration_path())


def _raw():
    with open(FIXTURE) as fh:
        return json.load(fh)


def test_fixture_wrapped_values():
    cal = DisplayCalibration.from_file(FIXTURE)
    assert cal.pitch == pytest.approx(52.594383239746094)
    assert cal.slope == pytest.approx(-7.21152925491333)
    assert cal.center == pytest.approx(0.40277382731437683)
    assert (cal.screen_w, cal.screen_h, cal.dpi, cal.view_cone) == (1536, 2048, 324.0, 40.0)
    assert cal.inv_view and not cal.flip_image_x and not cal.flip_image_y and not cal.flip_subp
    assert (cal.cols, cal.rows, cal.quilt_width, cal.quilt_height) == (8, 6, 3360, 3360)
    assert (cal.tile_width, cal.tile_height, cal.n_views) == (420, 560, 48)
    assert cal.quilt.aspect == 0.75 and cal.aspect == 0.75
    assert cal.model == "Looking Glass Portrait" and not cal.nominal


def test_flat_values_equal_wrapped():
    raw = _raw()
    flat = {k: (v["value"] if isinstance(v, dict) else v) for k, v in raw.items()}
    assert DisplayCalibration.from_json(flat) == DisplayCalibration.from_json(raw)


def test_round_trip_to_json():
    cal = DisplayCalibration.from_file(FIXTURE)
    assert DisplayCalibration.from_json(cal.to_json(), source=cal.source) == cal


@pytest.mark.parametrize("key", ["pitch", "slope", "center", "viewCone", "invView", "DPI", "screenW", "screenH"])
def test_missing_field_named(key):
    raw = _raw()
    del raw[key]
    with pytest.raises(CalibrationError, match=f"'{key}' is missing"):
        DisplayCalibration.from_json(raw)


@pytest.mark.parametrize("key", ["pitch", "slope", "center", "DPI", "screenW", "flipImageX"])
@pytest.mark.parametrize("bad", ["abc", None, [1], True])
def test_non_numeric_field_named(key, bad):
    raw = _raw()
    raw[key] = {"value": bad}
    with pytest.raises(CalibrationError, match=f"'{key}'"):
        DisplayCalibration.from_json(raw)


@pytest.mark.parametrize("key,value,msg", [
    ("slope", 0.0, "'slope'"), ("DPI", 0.0, "'DPI'"), ("DPI", -3.0, "'DPI'"), ("screenW", 0.0, "'screenW'"),
    ("screenH", -2048.0, "'screenH'"), ("screenW", 1536.5, "'screenW'"), ("pitch", -1.0, "'pitch'"),
    ("viewCone", 0.0, "'viewCone'"), ("invView", 0.5, "'invView'"), ("pitch", float("nan"), "'pitch'"),
])
def test_invalid_values_named(key, value, msg):
    raw = _raw()
    raw[key] = {"value": value}
    with pytest.raises(CalibrationError, match=msg):
        DisplayCalibration.from_json(raw)


def test_wrapped_without_value_and_bad_json(tmp_path):
    raw = _raw()
    raw["pitch"] = {"val": 3}
    with pytest.raises(CalibrationError, match="'pitch'"):
        DisplayCalibration.from_json(raw)
    p = tmp_path / "visual.json"
    p.write_text("{not json")
    with pytest.raises(CalibrationError, match="not valid JSON"):
        DisplayCalibration.from_file(p)
    with pytest.raises(CalibrationError, match="not found"):
        DisplayCalibration.from_file(tmp_path / "missing.json")


def test_optional_fields_default():
    raw = _raw()
    for k in ("fringe", "verticalAngle", "flipImageX", "flipImageY", "flipSubp"):
        del raw[k]
    cal = DisplayCalibration.from_json(raw)
    assert not cal.flip_image_x and cal.fringe == 0.0


@pytest.mark.parametrize("serial,name,layout", [
    ("LKG-P01234", "portrait", (8, 6, 3360, 3360)), ("LKG-E00001", "go", (11, 6, 4092, 4092)),
    ("LKG-A1234", "16in-gen2", (5, 9, 4096, 4096)), ("LKG-B1", "32in-gen2", (5, 9, 8192, 8192)),
    ("LKG-D7", "65in", (8, 9, 8192, 8192)), ("LKG-2K0042", "gen1-8.9in", (5, 9, 4096, 4096)),
    ("LKG-4K1", "gen1-15.6in", (5, 9, 4096, 4096)), ("LKG-8K1", "gen1-8k", (5, 9, 8192, 8192)),
])
def test_presets_by_serial(serial, name, layout):
    assert preset_for_serial(serial) is PRESETS[name]
    cal = DisplayCalibration.for_serial(serial)
    q = cal.quilt
    assert (q.cols, q.rows, q.width, q.height) == layout and cal.serial == serial and cal.nominal
    assert DisplayCalibration.preset(name).quilt == cal.quilt
    raw = _raw()
    raw["serial"] = serial
    assert DisplayCalibration.from_json(raw).quilt.cols == layout[0]


def test_unknown_preset():
    with pytest.raises(CalibrationError, match="preset"):
        DisplayCalibration.preset("nope")
    with pytest.raises(CalibrationError, match="serial"):
        DisplayCalibration.for_serial("XYZ-1")
