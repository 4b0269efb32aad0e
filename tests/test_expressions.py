"""AUs, AU maps (JSON), pain and PSPI, named expressions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from holo_viewer.errors import FlameError, InputError
from holo_viewer.flame import expressions as ex
from holo_viewer.flame.default_head import load_default_model
from holo_viewer.flame.default_head import EXPRESSION_NAMES


@pytest.fixture(scope="module")
def amap():
    return ex.default_au_map()


def test_au_names_cover_react_and_issue():
    for au in ex.REACT_AUS + ("AU5", "AU20", "AU43"):
        assert au in ex.AU_NAMES
    assert len(ex.REACT_AUS) == 15


def test_default_map_full_intensity_is_coefficient_one(amap):
    assert amap.matrix.shape == (len(ex.AU_NAMES), len(EXPRESSION_NAMES))
    e = ex.expression_from_aus({"AU12": 5.0, "AU43": 1.0}, amap)
    assert e[EXPRESSION_NAMES.index("AU12_L")] == 1.0 and e[EXPRESSION_NAMES.index("AU12_R")] == 1.0
    assert e[EXPRESSION_NAMES.index("AU43_L")] == 1.0
    assert np.linalg.matrix_rank(amap.matrix) == len(ex.AU_NAMES)  # every AU expressible, separable


def test_pain_zero_is_neutral_and_peak_pspi(amap):
    assert np.all(ex.pain_expression(0.0, amap) == 0)
    assert ex.pspi_from_aus(ex.pain_aus(0.0)) == 0
    peak = ex.pspi(ex.pain_expression(1.0, amap), amap)
    assert 12 <= float(peak) <= 16
    assert abs(float(peak) - ex.pspi_from_aus(ex.pain_aus(1.0))) < 1e-9
    aus = ex.pain_aus(1.0)
    dominant = {k for k, v in aus.items() if k != "AU43" and v >= 3.0}
    assert dominant == {"AU4", "AU6", "AU7", "AU9", "AU10"} and 0 < aus["AU43"] < 0.5  # narrowed, not shut


def test_pain_monotone_spearman_one(amap):
    from scipy.stats import spearmanr

    p = np.linspace(0, 1, 41)
    e = ex.pain_expression(p, amap)
    assert e.shape == (41, amap.n_expr)
    s = ex.pspi(e, amap)
    assert np.all(np.diff(s) > 0)
    assert spearmanr(p, s).statistic == pytest.approx(1.0)


def test_pspi_recovers_from_coefficients(amap):
    rng = np.random.default_rng(0)
    for _ in range(20):
        aus = {n: float(rng.uniform(0, ex.AU_MAX[n])) for n in ex.AU_NAMES}
        e = ex.expression_from_aus(aus, amap)
        assert float(ex.pspi(e)) == pytest.approx(ex.pspi_from_aus(aus), abs=1e-9)
        est = ex.estimate_aus(e, amap)
        assert np.allclose(est, [aus[n] for n in amap.names], atol=1e-9)
    # clipping to the valid range
    assert np.all(ex.estimate_aus(-np.ones(amap.n_expr), amap) == 0)


def test_au_map_json_round_trip(amap, tmp_path):
    path = amap.to_json(tmp_path / "map.json")
    back = ex.AUMap.load_json(path, n_expr=amap.n_expr)
    assert back.names == amap.names and np.array_equal(back.matrix, amap.matrix)


def _write(tmp_path, data, raw=None):
    p = tmp_path / "bad.json"
    p.write_text(raw if raw is not None else json.dumps(data))
    return p


@pytest.mark.parametrize("data, raw, field", [
    ({"aus": {"AU4": [0.0] * 3}}, None, "n_expr"),
    ({"n_expr": 3, "aus": {"AU4": [0.0] * 2}}, None, "aus.AU4"),
    ({"n_expr": 3, "aus": {"AU99": [0.0] * 3}}, None, "aus.AU99"),
    (None, '{"n_expr": 3, "aus": {"AU12": [0.0, NaN, 1.0]}}', r"aus.AU12\[1\]"),
    ({"n_expr": 4, "aus": {"AU4": [0.0] * 4}}, None, "n_expr: expected 3"),
    ({"n_expr": 3, "aus": []}, None, "aus"),
    (None, "{not json", "not valid JSON"),
])
def test_bad_au_map_json_names_the_field(tmp_path, data, raw, field):
    with pytest.raises(InputError, match=field):
        ex.AUMap.load_json(_write(tmp_path, data, raw), n_expr=3)


def test_au_map_for_default_and_user_model(tmp_path):
    model = load_default_model()
    amap = ex.au_map_for(model)
    assert amap.n_expr == model.n_expr
    from holo_viewer.flame.default_head import default_head_path
    from holo_viewer.flame.io import load_flame_arrays
    from holo_viewer.flame.model import FlameModel

    arrays = load_flame_arrays(default_head_path())
    del arrays["holo_viewer_default_head"]
    user = FlameModel.from_arrays(arrays, n_shape=None, n_expr=None)
    with pytest.raises(FlameError, match="--au-map"):
        ex.au_map_for(user)
    path = amap.to_json(tmp_path / "user.json")
    assert ex.au_map_for(user, path).n_expr == user.n_expr
    with pytest.raises(FlameError, match="AU map"):
        ex.au_map_for(user)


def test_bad_intensities_and_names(amap):
    with pytest.raises(InputError, match="AU12"):
        ex.expression_from_aus({"AU12": 6.0}, amap)
    with pytest.raises(InputError, match="AU43"):
        ex.expression_from_aus({"AU43": 2.0}, amap)
    with pytest.raises(InputError, match="AU77"):
        ex.expression_from_aus({"AU77": 1.0}, amap)
    with pytest.raises(InputError, match="p"):
        ex.pain_expression(float("nan"), amap)
    with pytest.raises(InputError, match="p"):
        ex.pain_expression(1.5, amap)
    with pytest.raises(InputError, match="expression name"):
        ex.named_expression("grin", 1.0, amap)


def test_named_expressions_and_jaw(amap):
    for name in ex.EXPRESSION_NAMES_KNOWN:
        e = ex.named_expression(name, 1.0, amap)
        assert e.shape == (amap.n_expr,)
        assert (np.abs(e).sum() == 0) == (name == "neutral")
    assert np.allclose(ex.named_expression("pain", 0.5, amap), ex.pain_expression(0.5, amap))
    assert ex.jaw_for_expression("mouth_open", 1.0)[0] > 0.2
    assert np.all(ex.jaw_for_expression("neutral", 1.0) == 0)


def test_smile_on_model_lifts_mouth_corners():
    model = load_default_model(dtype=torch.float64)
    amap = ex.au_map_for(model)
    rest = model().vertices[0].numpy()
    smile = model(expr=torch.as_tensor(ex.named_expression("smile", 1.0, amap))[None]).vertices[0].numpy()
    corners = np.asarray(model.metadata["landmark_vertices"])[[48, 54]]  # dlib mouth corners
    assert np.all(smile[corners, 1] - rest[corners, 1] > 0.002)


def test_pain_action_units_rise_and_saturate_at_one():
    """Every AU of the pain face is non-decreasing in p and largest at p = 1 (no turn back at the top)."""
    p = np.linspace(0.0, 1.0, 101)
    table = {au: np.array([ex.pain_aus(float(x))[au] for x in p]) for au in ex.PAIN_PEAK}
    for au, v in table.items():
        assert np.all(np.diff(v) >= 0), au
        assert v[-1] == ex.PAIN_PEAK[au] and v[0] == 0.0, au
    assert ex.pain_aus(1.0)["AU43"] <= 0.1  # narrowed by orbital tightening, not by closing the lids


@pytest.fixture(scope="module")
def pain_landmarks():
    """Per head (default + the shipped patients): the 68 landmark vertices at pain p = 0, 0.05, ... 1."""
    from holo_viewer.avatar.patients import list_patients, load_patient_model

    models = {"default": load_default_model()}
    models.update({p.name: load_patient_model(p.name) for p in list_patients()})
    p = np.linspace(0.0, 1.0, 21)
    out = {}
    for name, model in models.items():
        idx = np.asarray(model.metadata["landmark_vertices"]).reshape(-1)
        expr = torch.as_tensor(ex.pain_expression(p, ex.au_map_for(model)), dtype=model.dtype)
        with torch.no_grad():
            out[name] = model(expr=expr).vertices.numpy()[:, idx].astype(np.float64)
    return p, out


def test_pain_landmark_measures_fall_monotonically_on_every_head(pain_landmarks):
    """The pain mapping's geometry, before any renderer or detector: on the 68 landmark vertices seen
    from the front (bench/face_realism.py's measures), eye aperture, brow-to-upper-lid gap and
    nose-to-lip gap never rise with p, and at p = 1 are <= 0.6 / 0.85 / 0.85 of neutral, on every head."""
    from bench.face_realism import face_measures

    p, heads = pain_landmarks
    assert len(heads) >= 7
    for name, lm in heads.items():
        m = [face_measures(frame[:, :2] * [1.0, -1.0]) for frame in lm]
        for key, limit in (("eye_aperture", 0.6), ("brow_eye_gap", 0.85), ("nose_lip_gap", 0.85)):
            v = np.array([x[key] for x in m])
            assert np.all(np.diff(v) <= 1e-9), (name, key, np.round(v / v[0], 3))
            assert v[-1] / v[0] <= limit, (name, key, v[-1] / v[0])
