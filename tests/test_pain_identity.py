"""Pain's identity normalisation (issue 35, flame.expressions.identity_pain_gains): per-head gains on the
shared pain face, computed from the head's own landmark vertices, bring the eye's and the brow gap's
relative change at pain 1 to the reference head's; they only lift, the default head is the reference;
off unless asked (``au_map_for(model, normalise_pain=True)``)."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.errors import InputError
from holo_viewer.flame import expressions as ex


@pytest.fixture(scope="module")
def default_basis():
    from holo_viewer.flame.default_head import load_default_model

    model = load_default_model()
    return model, ex._landmark_basis(model)


def _scaled(basis, eye: float = 1.0, brow: float = 1.0):
    """The basis with every lid point moved from its eye's mid line by ``eye`` x and the brows lifted
    from the upper lids by ``brow`` x (the same expression deltas: a bigger eye, a higher brow)."""
    neutral, dirs = basis
    pts = neutral.copy()
    for lids in ((36, 37, 38, 39, 40, 41), (42, 43, 44, 45, 46, 47)):
        mid = pts[list(lids), 1].mean()
        pts[list(lids), 1] = mid + eye * (pts[list(lids), 1] - mid)
    for brows, upper in ((range(17, 22), (37, 38)), (range(22, 27), (43, 44))):
        top = pts[list(upper), 1].mean()
        pts[list(brows), 1] = top + brow * (pts[list(brows), 1] - top)
    return pts, dirs


def test_the_reference_is_the_default_head_and_gets_no_gain(default_basis):
    model, basis = default_basis
    f = ex.landmark_pain_fractions(basis, ex.default_au_map(model.n_expr), levels=1.0)
    assert f["eye_aperture"][0] == ex.PAIN_REFERENCE_FRACTIONS["eye_aperture"]  # recomputed, not a table
    assert f["brow_eye_gap"][0] == ex.PAIN_REFERENCE_FRACTIONS["brow_eye_gap"]
    assert ex.identity_pain_gains(model) == {}  # the reference: no identity gain ...
    for normalise in (False, True):  # ... only its own brow gain, on or off
        am = ex.au_map_for(model, normalise_pain=normalise)
        assert dict(am.pain_gains) == dict(ex.DEFAULT_HEAD_PAIN_GAINS)


def test_the_default_heads_own_brow_gain(default_basis):
    """The default head's brows descend to DEFAULT_HEAD_BROW_FRACTION at pain 1 (its gain recomputed from
    its vertices), monotone along the curve; its eyes keep the shared face's gain; no patient gets it."""
    from holo_viewer.avatar.patients import load_patient_model

    model, basis = default_basis
    base = ex.default_au_map(model.n_expr)
    gains = ex.identity_pain_gains(model, base, reference={
        "eye_aperture": ex.PAIN_REFERENCE_FRACTIONS["eye_aperture"], "brow_eye_gap": ex.DEFAULT_HEAD_BROW_FRACTION})
    assert gains == pytest.approx(dict(ex.DEFAULT_HEAD_PAIN_GAINS), rel=1e-9) and set(gains) == {"AU4"}
    am = ex.au_map_for(model)
    f = ex.landmark_pain_fractions(basis, am, levels=np.linspace(0, 1, 21))
    assert f["brow_eye_gap"][-1] == pytest.approx(ex.DEFAULT_HEAD_BROW_FRACTION, abs=1e-9)
    assert f["eye_aperture"][-1] <= ex.PAIN_REFERENCE_FRACTIONS["eye_aperture"]
    assert np.all(np.diff(f["brow_eye_gap"]) < 0) and np.all(np.diff(f["eye_aperture"]) < 0)
    i4 = list(model.expression_names).index("AU4")
    shared = ex.pain_expression(1.0, base)
    assert ex.pain_expression(1.0, am)[i4] == pytest.approx(shared[i4] * ex.DEFAULT_HEAD_PAIN_GAINS["AU4"])
    assert ex.pspi_from_aus(ex.pain_aus(1.0)) == pytest.approx(14.05)  # PSPI: the AU intensities, unchanged
    kwame = load_patient_model("kwame")  # the ward's strongest brow descent with the shared face
    assert ex.au_map_for(kwame).pain_gains is None  # a patient's head in the default's format: no own gain
    k = ex.landmark_pain_fractions(kwame, ex.au_map_for(kwame), levels=1.0)["brow_eye_gap"][0]
    assert abs(k - ex.DEFAULT_HEAD_BROW_FRACTION) < 0.001


@pytest.mark.parametrize("eye, brow", [(1.3, 1.0), (1.0, 1.12), (1.25, 1.1)])
def test_a_bigger_eye_or_higher_brow_gets_the_reference_fractions(default_basis, eye, brow):
    model, basis = default_basis
    head = _scaled(basis, eye, brow)
    base = ex.default_au_map(model.n_expr)
    shared = ex.landmark_pain_fractions(head, base, levels=1.0)
    ref = ex.PAIN_REFERENCE_FRACTIONS
    # the same deltas close a bigger eye / lower a higher brow by a smaller fraction ...
    if eye > 1:
        assert shared["eye_aperture"][0] > ref["eye_aperture"] + 0.05
    if brow > 1:
        assert shared["brow_eye_gap"][0] > ref["brow_eye_gap"] + 0.005
    gains = ex.identity_pain_gains(head, base)
    am = base.with_pain_gains(gains)
    levels = (0.25, 0.5, 0.75, 1.0)
    got = ex.landmark_pain_fractions(head, am, levels=levels)
    want = ex.landmark_pain_fractions(basis, base, levels=levels)
    for key in ("eye_aperture", "brow_eye_gap"):  # ... the gains bring it to the reference's at pain 1
        if (key == "eye_aperture" and eye > 1) or (key == "brow_eye_gap" and brow > 1):
            assert abs(got[key][-1] - ref[key]) < 1e-9, key
        else:
            assert got[key][-1] <= ref[key] + 1e-9, key
        assert np.all(np.abs(got[key] - want[key]) < 0.03), (key, got[key], want[key])  # and along the curve
        assert np.all(np.diff(got[key]) < 0), key  # monotone
    if eye > 1:
        assert gains["AU6"] == gains["AU7"] == gains["AU43"] > 1.05
    if brow > 1:
        assert gains["AU4"] > 1.02


def test_gains_only_lift_and_are_capped(default_basis):
    model, basis = default_basis
    base = ex.default_au_map(model.n_expr)
    assert ex.identity_pain_gains(_scaled(basis, 0.8, 0.9), base) == {}  # already closes more: shared face
    huge = ex.identity_pain_gains(_scaled(basis, 4.0, 1.0), base)
    assert huge["AU6"] == ex.PAIN_GAIN_MAX


def test_a_patient_is_normalised_and_listener_pain_uses_the_gains():
    from holo_viewer.avatar.patients import load_patient_model
    from holo_viewer.behaviour import BehaviourConfig, ListenerBehaviour

    model = load_patient_model("amara")  # the widest eye of the ward (0.15 IOD)
    assert ex.au_map_for(model).pain_gains is None  # off unless asked (PAIN_NORMALISE_IDENTITY)
    am = ex.au_map_for(model, normalise_pain=True)
    assert am.pain_gains is not None and 1.1 < am.pain_gains["AU6"] < ex.PAIN_GAIN_MAX
    f = ex.landmark_pain_fractions(model, am, levels=np.linspace(0, 1, 11))
    assert abs(f["eye_aperture"][-1] - ex.PAIN_REFERENCE_FRACTIONS["eye_aperture"]) < 1e-6
    assert np.all(np.diff(f["eye_aperture"]) < 0) and np.all(np.diff(f["brow_eye_gap"]) < 0)
    # PSPI is the AU intensities' and unchanged; the display's coefficients carry the gains
    assert ex.pspi_from_aus(ex.pain_aus(1.0)) == pytest.approx(14.05)
    shared = ex.pain_expression(1.0, am.with_pain_gains(None))
    i6 = list(model.expression_names).index("AU6")
    assert ex.pain_expression(1.0, am)[i6] == pytest.approx(shared[i6] * am.pain_gains["AU6"])
    beh = ListenerBehaviour(BehaviourConfig(seed=0, flares=False), au_map=am)
    vec = beh._pain_vector(1.0)
    assert vec[am.names.index("AU7")] == pytest.approx(5.0 * am.pain_gains["AU7"])


def test_pain_gains_are_checked():
    base = ex.default_au_map()
    with pytest.raises(InputError, match=r"pain_gains\['AU6'\].*\[1, 1.5\].*0.5"):
        base.with_pain_gains({"AU6": 0.5})
    with pytest.raises(InputError, match="pain_gains: 'AU99'"):
        ex.AUMap(names=base.names, matrix=base.matrix, pain_gains={"AU99": 1.2})
    assert base.with_pain_gains({"AU6": 1.0}).pain_gains is None
    with pytest.raises(InputError, match=r"landmarks: expected finite \(68, 2\)"):
        ex.landmark_pain_measures(np.zeros((67, 3)))


def test_a_patient_json_carries_its_own_pain_gains(tmp_path):
    """``patient.json``'s ``pain_gains`` reach the head's AU map through the loader (no path check): a copy
    of a patient's folder under another name gets the gains its JSON states; a bad gain names the field."""
    import json
    import shutil

    from holo_viewer.avatar import patients as P
    from holo_viewer.errors import AvatarError

    src = P.patient_info("kwame")  # no gains of his own
    folder = tmp_path / "zed"
    folder.mkdir()
    shutil.copyfile(src.head_path, folder / "head.npz")
    info = {**src.raw, "name": "zed", "files": {"head.npz": src.files["head.npz"]}, "pain_gains": {"AU4": 1.2}}
    (folder / "patient.json").write_text(json.dumps(info))
    model = P.load_patient_model("zed", tmp_path)
    am = ex.au_map_for(model)
    assert dict(am.pain_gains) == {"AU4": 1.2}
    shared = ex.pain_expression(1.0, am.with_pain_gains(None))
    assert np.abs(shared).max() > 0
    assert ex.pain_expression(1.0, am) == pytest.approx(shared + 0.2 * ex.pain_aus(1.0)["AU4"] * am.row("AU4"))
    assert ex.au_map_for(P.load_patient_model("kwame")).pain_gains is None
    # the shipped ward: helen alone carries a gain (her brows, docs/face_realism.md "helen's brows"), her recipe's
    from holo_viewer.assets_build.patients import RECIPES

    assert {r.name: r.pain_gains for r in RECIPES if r.pain_gains} == {"helen": {"AU4": 1.247}}
    assert dict(ex.au_map_for(P.load_patient_model("helen")).pain_gains) == {"AU4": 1.247}
    for bad in ({"AU4": 2.0}, {"AU99": 1.1}, [1.2]):
        (folder / "patient.json").write_text(json.dumps({**info, "pain_gains": bad}))
        with pytest.raises(AvatarError, match=r"zed.patient\.json: field 'pain_gains'"):
            P.patient_info("zed", tmp_path)
