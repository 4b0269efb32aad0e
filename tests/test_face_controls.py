"""One face-control type, one FLAME-parameter type: pain has one meaning, ranges are checked once.

What changed with issue 21 (stated here so the change is visible): the named expression "pain"
no longer opens the jaw (it used to add 0.06 rad per unit pain, the pipeline's ``pain`` field did
not), ``FaceControls(named=(("pain", p),))`` is stored as ``pain=p``, and ``export-mesh --expr``
adds to the pain face instead of overwriting it, as the Python API does.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from holo_viewer.cli import main
from holo_viewer.errors import InputError
from holo_viewer.flame import expressions as ex
from holo_viewer.flame.params import EXPR_LIMIT, FRAME_KEYS, JAW_LIMITS_DEG, FlameParams
from holo_viewer.pipeline import FaceControls, Pipeline, ViewSettings, flame_sequence_frames


@pytest.fixture(scope="module")
def head():
    from holo_viewer.flame.default_head import load_default_model

    return load_default_model()


@pytest.fixture(scope="module")
def mesh_pipeline(head):
    return Pipeline(model=head, avatar=False)


def _params(pipe: Pipeline, face: FaceControls) -> dict[str, np.ndarray]:
    pipe.set_face(face)
    return {k: v.copy() for k, v in pipe.flame_params().items()}


# ------------------------------------------------------------------ pain: one field, one meaning


@pytest.mark.parametrize("p", [0.0, 0.35, 1.0])
def test_pain_field_and_named_pain_give_the_same_face(mesh_pipeline, p):
    a = _params(mesh_pipeline, FaceControls(pain=p))
    b = _params(mesh_pipeline, FaceControls(named=(("pain", p),)))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert FaceControls(named=(("pain", p),)).pain == p and FaceControls(named=(("pain", p),)).named == ()
    np.testing.assert_array_equal(a["jaw_pose"], np.zeros(3))  # pain opens no jaw beyond its AU25/AU26


def test_pain_is_the_pain_expression_everywhere(head):
    amap = ex.au_map_for(head)
    np.testing.assert_array_equal(ex.named_expression("pain", 0.6, amap), ex.pain_expression(0.6, amap))
    np.testing.assert_array_equal(ex.jaw_for_expression("pain", 1.0), np.zeros(3))
    assert FaceControls().with_named("pain", 0.4).pain == 0.4
    assert FaceControls(pain=0.5).with_named("smile", 0.2).pain == 0.5


def test_pain_given_twice_differently_is_an_error():
    with pytest.raises(InputError, match="pain: given twice"):
        FaceControls(pain=0.2, named=(("pain", 0.7),))
    assert FaceControls(pain=0.7, named=(("pain", 0.7),)).pain == 0.7


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_pain_range_is_checked_at_the_boundary(bad):
    with pytest.raises(InputError, match="pain"):
        FaceControls(pain=bad)
    with pytest.raises(InputError, match="pain"):
        FaceControls(named=(("pain", bad),))


def test_expression_names_are_declared_once():
    from holo_viewer.pipeline import settings

    assert ex.EXPRESSION_NAMES_KNOWN == tuple(ex.NAMED_EXPRESSIONS)
    assert not hasattr(settings, "_NAMED")
    with pytest.raises(InputError, match="named: expected an expression in"):
        FaceControls(named=(("grin", 0.5),))


# ------------------------------------------------------------------ ranges (issue 19 items 5 and 12-jaw)


@pytest.mark.parametrize("expr", [[1e6], [0.0, -25.0], [float("inf")]])
def test_expression_coefficients_are_range_checked(expr):
    with pytest.raises(InputError, match=r"expr(\[\d\])?: expected (an expression coefficient in|finite)"):
        FaceControls(expr=expr)


def test_expression_limit_edge_is_accepted():
    assert FaceControls(expr=[EXPR_LIMIT, -EXPR_LIMIT]).expr.tolist() == [EXPR_LIMIT, -EXPR_LIMIT]


@pytest.mark.parametrize("deg", [720.0, 180.0, 91.0, -46.0])
def test_jaw_outside_the_cli_limits_is_rejected(deg):
    with pytest.raises(InputError, match=r"jaw_pose: expected a jaw opening .* \[-45, 90\] deg"):
        FaceControls(jaw_pose=[math.radians(deg), 0.0, 0.0])


def test_jaw_inside_the_limits_and_sideways_jaw_is_accepted():
    lo, hi = JAW_LIMITS_DEG
    for deg in (lo, 0.0, 30.0, hi):
        FaceControls(jaw_pose=[math.radians(deg), 0.0, 0.0])
    FaceControls(jaw_pose=[0.2, 0.05, -0.03])
    with pytest.raises(InputError, match="jaw_pose"):
        FaceControls(jaw_pose=[0.0, math.radians(120.0), 0.0])  # 120 deg of rotation in all


def test_viewer_angle_limits_agree_between_view_settings_and_cameras():
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.display.cameras import VIEWER_ANGLE_LIMIT_DEG, make_quilt_cameras

    cal = DisplayCalibration.load(None)
    for angle in (-VIEWER_ANGLE_LIMIT_DEG, VIEWER_ANGLE_LIMIT_DEG - 1):
        ViewSettings(viewer_angle=angle)
        make_quilt_cameras(cal, focal_center=(0, 0, 0), size=0.1, viewer_angle_deg=angle, view_cone_deg=1.0)
    for angle in (VIEWER_ANGLE_LIMIT_DEG + 1, -70.0):
        with pytest.raises(InputError, match="viewer_angle"):
            ViewSettings(viewer_angle=angle)
        with pytest.raises(InputError, match="viewer_angle"):
            make_quilt_cameras(cal, focal_center=(0, 0, 0), size=0.1, viewer_angle_deg=angle)


# ------------------------------------------------------------------ the CLI and the API agree


def test_export_mesh_adds_expression_to_pain_like_the_api(tmp_path, head):
    import trimesh

    name = "AU4"  # a component the pain face uses: adding and replacing differ here
    idx = list(head.expression_names).index(name)
    amap = ex.au_map_for(head)
    assert ex.pain_expression(0.8, amap)[idx] != 0
    out = tmp_path / "m.ply"
    assert main(["export-mesh", "--pain", "0.8", "--expr", f"{name}=0.3", "--jaw", "10", "--out", str(out)]) == 0
    got = np.asarray(trimesh.load(out, process=False).vertices)
    expr = np.zeros(head.n_expr)
    expr[idx] = 0.3
    api = Pipeline(model=head, avatar=False, face=FaceControls(expr=expr, pain=0.8,
                                                               jaw_pose=[math.radians(10), 0, 0])).mesh()
    np.testing.assert_allclose(got, api, atol=1e-6)
    replaced = ex.pain_expression(0.8, amap)
    replaced[idx] = 0.3  # the old overwrite rule gives another face
    old = head(expr=replaced[None], jaw_pose=np.array([[math.radians(10), 0, 0]])).vertices[0].detach().numpy()
    assert np.abs(got - old).max() > 1e-5


def test_export_mesh_rejects_a_huge_coefficient(tmp_path, capsys):
    rc = main(["export-mesh", "--expr", "AU12_L=1e6", "--out", str(tmp_path / "x.obj")])
    assert rc == 1
    err = capsys.readouterr().err
    assert "--expr AU12_L" in err and f"<= {EXPR_LIMIT:g}" in err
    assert not (tmp_path / "x.obj").exists()


# ------------------------------------------------------------------ one FLAME sequence type


def test_flame_params_is_the_one_sequence_type():
    T = 3
    seq = FlameParams.from_frames(expr=np.arange(T * 4, dtype=np.float32).reshape(T, 4) / 10,
                                  jaw_pose=np.full((T, 3), 0.1), shape=np.zeros(5))
    assert set(seq.as_dict()) == set(FRAME_KEYS) | {"shape"}
    assert seq.eyes_pose.shape == (T, 6) and len(seq) == T and "expr" in seq and seq["jaw_pose"].shape == (T, 3)
    a = flame_sequence_frames(seq)
    b = flame_sequence_frames(seq.as_dict())
    assert len(a) == T and all(set(x) == set(y) for x, y in zip(a, b))
    for x, y in zip(a, b):
        for k in x:
            np.testing.assert_array_equal(x[k], y[k])
    with pytest.raises(InputError, match=r"jaw_pose: expected shape \(3, 3\)"):
        FlameParams.from_frames(expr=np.zeros((T, 4)), jaw_pose=np.zeros((T + 1, 3)))


def test_reaction_output_has_every_frame_key():
    from holo_viewer.flame.expressions import default_au_map
    from holo_viewer.reaction.api import flame_params_from_states

    amap = default_au_map()
    out = flame_params_from_states(np.zeros((4, len(amap.names) + 6)), amap, n_shape=2)
    assert set(out) == set(FRAME_KEYS) | {"shape"} and all(out[k].shape[0] == 4 for k in FRAME_KEYS)
