"""The embedded default head: format, mesh quality, rig, blend shapes, determinism, asset, preview."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch

from holo_viewer.flame.builder.head import build_default_head, write_default_head
from holo_viewer.flame.default_head import default_head_path, load_default_model
from holo_viewer.flame.builder.head_blendshapes import EXPRESSION_NAMES, LID_FLOOR_Y, MOUTH_COMPONENTS
from holo_viewer.flame.builder.head_sculpt import EYE_CENTRES, EYE_RADIUS, LID_RADIUS, sculpt_head
from holo_viewer.flame.lbs import lbs_reference_np
from holo_viewer.flame.model import FlameModel

FLAME_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")


@pytest.fixture(scope="module")
def head():
    return build_default_head()


@pytest.fixture(scope="module")
def mesh():
    return sculpt_head()


def _pose(arrays, expr=None, jaw=None, neck=None, eyes=None):
    """Our own float64 numpy LBS (docs/design.md formula, lbs_reference_np) of the head arrays."""
    ns, ne = int(arrays["n_shape"]), int(arrays["n_expr"])
    coeff = np.zeros(ns + ne)
    if expr is not None:
        coeff[ns:] = expr
    v = arrays["v_template"] + arrays["shapedirs"] @ coeff
    j = arrays["J_regressor"] @ v
    pose = np.zeros((5, 3))
    if neck is not None:
        pose[1] = neck
    if jaw is not None:
        pose[2] = jaw
    if eyes is not None:
        pose[3:] = np.reshape(eyes, (2, 3))
    out, _ = lbs_reference_np(v[None], j[None], pose[None], arrays["posedirs"], arrays["weights"],
                              arrays["kintree_table"][0].tolist())
    return out[0]


def test_format_and_sizes(head):
    for k in FLAME_KEYS:
        assert k in head
    v = head["v_template"]
    n = len(v)
    assert 4500 <= n <= 5500
    ns, ne = int(head["n_shape"]), int(head["n_expr"])
    assert ns >= 20 and ne >= 20
    assert head["shapedirs"].shape == (n, 3, ns + ne)
    assert head["posedirs"].shape == (n, 3, 36)
    assert head["J_regressor"].shape == (5, n)
    assert head["weights"].shape == (n, 5)
    assert head["kintree_table"][0].tolist() == [-1, 0, 1, 1, 1]
    assert list(head["expression_names"]) == list(EXPRESSION_NAMES)
    assert len(head["vertex_region"]) == n and head["vertex_region"].max() < len(head["region_names"])
    assert int(head["holo_viewer_default_head"]) == 1
    # FLAME-like size: metres, ~0.27 m tall including the neck, face toward +z
    ext = np.ptp(v, axis=0)
    assert 0.14 < ext[0] < 0.19 and 0.22 < ext[1] < 0.3 and 0.19 < ext[2] < 0.25
    nose_tip = v[np.argmax(v[:, 2])]
    assert abs(nose_tip[0]) < 1e-3 and -0.06 < nose_tip[1] < 0.0


def test_every_required_au_component_present(head):
    names = list(head["expression_names"])
    for au in ("AU1", "AU2", "AU4", "AU5", "AU6", "AU7", "AU9", "AU10", "AU12", "AU14", "AU15", "AU17",
               "AU20", "AU23", "AU24", "AU25", "AU26", "AU43"):
        assert any(n == au or n.startswith(au + "_") for n in names), au


@pytest.fixture(scope="module")
def committed():
    """The committed asset as float64 arrays (the regression tests check it as well as a rebuild)."""
    with np.load(default_head_path(build_if_missing=False)) as d:
        return {k: (d[k].astype(np.float64) if d[k].dtype == np.float32 else d[k]) for k in d.files}


def _edges(f):
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return e


def test_mesh_closed_consistent_no_degenerate(head):
    v, f = head["v_template"], head["f"]
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert np.sum(area < 1e-10) == 0  # documented count: no degenerate faces
    e = _edges(f)
    # every directed edge once (consistent winding), and its reverse present (closed surfaces)
    keys = e[:, 0] * len(v) + e[:, 1]
    assert len(np.unique(keys)) == len(keys)
    rev = set((e[:, 1] * len(v) + e[:, 0]).tolist())
    assert all(k in rev for k in keys.tolist())
    # positive volume (outward normals)
    vol = np.sum(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))) / 6
    assert vol > 0.0015


def test_weights_and_regressor(head):
    w = head["weights"]
    assert np.all(w >= 0) and np.allclose(w.sum(1), 1.0, atol=1e-12)
    names = list(head["region_names"])
    reg = head["vertex_region"]
    for e, (name, j) in enumerate((("eyeball_left", 3), ("eyeball_right", 4))):
        ids = np.where(reg == names.index(name))[0]
        assert len(ids) > 50
        # iris/pupil are labelled separately; the whole eyeball is rigid to its joint
        on_sphere = np.abs(np.linalg.norm(head["v_template"] - EYE_CENTRES[e], axis=1) - EYE_RADIUS) < 1e-9
        ball = np.where(on_sphere)[0]
        assert len(ball) >= len(ids)
        assert np.all(w[ball, j] == 1.0)
    jr = head["J_regressor"]
    assert np.allclose(jr.sum(1), 1.0) and np.all(jr >= 0)
    joints = jr @ head["v_template"]
    assert np.allclose(joints[3:], EYE_CENTRES, atol=1e-12)
    assert joints[0, 1] < joints[1, 1] < joints[3, 1]  # root below neck below eyes
    assert joints[2, 1] < joints[3, 1] and joints[2, 2] < joints[3, 2]  # hinge below and behind the eyes


def test_jaw_opens_mouth(head, mesh):
    rest = _pose(head)
    opened = _pose(head, jaw=[0.3, 0, 0])
    up, lo = mesh.parts["mouth_upper"], mesh.parts["mouth_lower"]
    mid_u, mid_l = up[len(up) // 2], lo[len(lo) // 2]
    assert np.allclose(rest[mid_u], rest[mid_l])  # lips closed at rest
    assert opened[mid_l, 1] - rest[mid_l, 1] < -0.02  # lower lip down > 2 cm
    assert np.linalg.norm(opened[mid_u] - rest[mid_u]) < 5e-4  # upper lip stays
    static = (head["weights"][:, 2] == 0) & np.all(head["posedirs"] == 0, axis=(1, 2))
    assert np.allclose(opened[static], rest[static], atol=1e-12)
    # the chin follows the jaw
    chin = np.argmin(np.where(np.abs(head["v_template"][:, 0]) < 0.005, head["v_template"][:, 1] + 10 *
                              (head["v_template"][:, 2] < 0.04), 9))
    assert opened[chin, 1] < rest[chin, 1] - 0.015


def test_neck_and_eyes_rotate(head):
    rest = _pose(head)
    bent = _pose(head, neck=[0, 0.4, 0])
    w = head["weights"]
    root_only = w[:, 0] == 1.0
    assert root_only.sum() > 50
    assert np.allclose(bent[root_only], rest[root_only], atol=1e-12)
    nose = np.argmax(head["v_template"][:, 2])
    assert bent[nose, 0] > rest[nose, 0] + 0.03  # head turned toward +x
    look = _pose(head, eyes=[0, 0.3, 0, 0, 0.3, 0])
    ball = np.where(w[:, 3] == 1.0)[0]
    cornea = ball[np.argmax(head["v_template"][ball, 2])]
    assert look[cornea, 0] > rest[cornea, 0] + 0.003
    centre = head["J_regressor"][3] @ head["v_template"]
    assert np.allclose(np.linalg.norm(look[ball] - centre, axis=1), EYE_RADIUS, atol=1e-12)  # centre fixed
    skin = w[:, 3] + w[:, 4] == 0
    assert np.allclose(look[skin], rest[skin])


def _comp(head, name):
    ns = int(head["n_shape"])
    return head["shapedirs"][:, :, ns + list(head["expression_names"]).index(name)]


def test_expression_components_local_and_directed(head, mesh):
    v = head["v_template"]
    eyeballs = head["weights"][:, 3] + head["weights"][:, 4] > 0
    for name in head["expression_names"]:
        d = _comp(head, name)
        assert np.all(d[eyeballs] == 0), name
        mag = np.linalg.norm(d, axis=1)
        assert 0.002 < mag.max() < 0.03, name
        share = 0.3 if name == "AU26" else 0.15  # the jaw drop moves the whole lower face
        assert np.mean(mag > 0.1 * mag.max()) < share, f"{name} is not localised"
    corner_l = mesh.parts["mouth_upper"][-1] if v[mesh.parts["mouth_upper"][-1], 0] > 0 else mesh.parts["mouth_upper"][0]
    d = _comp(head, "AU12_L")
    assert d[corner_l, 1] > 0.005 and d[corner_l, 2] < 0  # up and back
    assert np.argmax(np.linalg.norm(d, axis=1)) in np.where(np.linalg.norm(v - v[corner_l], axis=1) < 0.02)[0]
    assert np.abs(_comp(head, "AU12_L")[v[:, 0] < -0.03]).max() < 1e-3  # the right side hardly moves
    d = _comp(head, "AU4")
    brow = np.where(head["vertex_region"] == list(head["region_names"]).index("brows"))[0]
    inner = brow[np.abs(v[brow, 0]) < 0.025]
    assert np.all(d[inner, 1] < 0) and np.all(d[inner, 0] * np.sign(v[inner, 0]) < 0)  # down and together
    d = _comp(head, "AU1_L")
    assert d[inner[v[inner, 0] > 0], 1].mean() > 0.002
    for e, name in ((0, "AU43_L"), (1, "AU43_R")):
        rim = mesh.parts[f"lid_upper_{e}"]
        lower_rim = mesh.parts[f"lid_lower_{e}"]
        d = _comp(head, name)
        mid = len(rim) // 2
        assert d[rim[mid], 1] < -0.005  # the upper lid comes down
        closed = v[rim] + d[rim]
        assert np.max(np.linalg.norm(closed[1:-1] - v[lower_rim][1:-1], axis=1)) < 1.5e-3  # meets the lower lid
        other = mesh.parts[f"lid_upper_{1 - e}"]
        assert np.abs(d[other]).max() == 0
        for c in (0.25, 0.5, 0.75, 1.0):  # the lid slides over the eyeball, never through it
            p = v[rim] + c * d[rim]
            assert np.linalg.norm(p - EYE_CENTRES[e], axis=1).min() > EYE_RADIUS
    d = _comp(head, "AU25")
    up, lo = mesh.parts["mouth_upper"], mesh.parts["mouth_lower"]
    m = len(up) // 2
    assert d[up[m], 1] > 0.001 and d[lo[m], 1] < -0.002
    d = _comp(head, "AU26")
    assert d[lo[m], 1] < -0.008 and abs(d[up[m], 1]) < 1e-9


def test_shape_basis_moves_eyeballs_rigidly(head):
    ns = int(head["n_shape"])
    ball = np.where(head["weights"][:, 3] == 1.0)[0]
    for k in range(ns):
        d = head["shapedirs"][ball, :, k]
        assert np.allclose(d, d[0], atol=1e-15)
    mag = np.linalg.norm(head["shapedirs"][:, :, :ns], axis=1).max(0)
    assert np.all((mag > 5e-4) & (mag < 0.01))


def test_random_coefficients_keep_a_plausible_head(head):
    rng = np.random.default_rng(1)
    model = FlameModel.from_arrays(head, n_shape=None, n_expr=None, dtype=torch.float64)
    rest = model().vertices[0].numpy()
    out = model(shape=torch.as_tensor(rng.normal(size=(4, model.n_shape))),
                expr=torch.as_tensor(rng.normal(size=(4, model.n_expr)))).vertices.numpy()
    disp = np.linalg.norm(out - rest, axis=2)
    assert disp.max() < 0.07 and np.percentile(disp, 99) < 0.04 and np.isfinite(out).all()


def test_flame_model_matches_reference_and_teeth(head):
    model = FlameModel.from_arrays(head, n_shape=None, n_expr=None, dtype=torch.float64)
    expr = np.linspace(-1, 1, model.n_expr)
    got = model(expr=torch.as_tensor(expr)[None], jaw_pose=torch.tensor([[0.2, 0.0, 0.0]],
                                                                       dtype=torch.float64)).vertices[0].numpy()
    ref = _pose(head, expr=expr, jaw=[0.2, 0, 0])
    assert np.abs(got - ref).max() < 1e-10
    teeth = FlameModel.from_arrays(head, n_shape=None, n_expr=None, add_teeth=True, dtype=torch.float64)
    assert teeth.n_vertices == model.n_vertices + 8 * len(head["teeth_anchor_upper"])
    up, lo = head["teeth_anchor_upper"], head["teeth_anchor_lower"]
    assert len(up) == len(lo) and np.all(np.diff(head["v_template"][up, 0]) > 0)
    assert np.all(head["v_template"][up, 1] > head["v_template"][lo, 1])


def test_deterministic_bytes_and_committed_asset(head, tmp_path):
    again = build_default_head()
    for k in head:
        assert np.array_equal(np.asarray(head[k]), np.asarray(again[k])), k
    a = write_default_head(tmp_path / "a.npz", head).read_bytes()
    b = write_default_head(tmp_path / "b.npz", again).read_bytes()
    assert hashlib.sha256(a).digest() == hashlib.sha256(b).digest()
    asset = default_head_path(build_if_missing=False)
    assert asset.exists(), "assets/default_head.npz is committed; rebuild with scripts/build_default_head.py"
    assert asset.stat().st_size < 6e6
    with np.load(asset) as stored:
        assert set(stored.files) == set(head)
        for k in head:
            s, h = stored[k], np.asarray(head[k])
            if s.dtype == np.float32:
                assert np.abs(s - h.astype(np.float32)).max() <= 1e-7, k
            else:
                assert np.array_equal(s, h), k


def test_load_default_model():
    m = load_default_model()
    assert m.is_default_head and m.n_expr == len(EXPRESSION_NAMES) and m.expression_names == list(EXPRESSION_NAMES)
    assert m.dtype == torch.float32
    out = m(expr=torch.zeros(2, m.n_expr))
    assert out.vertices.shape == (2, m.n_vertices, 3)


def _render_or_skip(*args, **kwargs):
    from holo_viewer.errors import RenderError
    from holo_viewer.flame.preview import render_mesh

    try:
        return render_mesh(*args, **kwargs)
    except RenderError as exc:  # pragma: no cover - no GL on this machine
        pytest.skip(f"offscreen VTK unavailable: {exc}")


def test_render_mesh_shows_the_head(head):
    imgs = _render_or_skip(head["v_template"], head["f"], views=("front", "side"), size=(64, 80))
    assert len(imgs) == 2
    for img in imgs:
        assert img.shape == (80, 64, 3) and img.dtype == np.float32
        assert 0.15 < np.mean(img.min(axis=2) < 0.95) < 0.8  # the head covers part of the frame
        assert img[0, 0].min() > 0.99  # white background corner


def test_render_mesh_rejects_bad_input(head):
    from holo_viewer.errors import InputError
    from holo_viewer.flame.preview import render_mesh

    with pytest.raises(InputError, match="faces"):
        render_mesh(head["v_template"], head["f"] + 10**6)
    with pytest.raises(InputError, match="views"):
        render_mesh(head["v_template"], head["f"], views=("upside",))


@pytest.mark.slow
def test_write_head_renders(tmp_path, capsys):
    from holo_viewer.flame.preview import write_head_renders

    model = load_default_model()
    try:
        paths = write_head_renders(tmp_path, model, views=("front",), size=(64, 80))
    except Exception as exc:  # pragma: no cover
        from holo_viewer.errors import RenderError
        if isinstance(exc, RenderError):
            pytest.skip(str(exc))
        raise
    assert [p.name for p in paths] == ["neutral_front.png", "smile_front.png", "pain_front.png",
                                       "mouth_open_front.png", "contact_sheet.png"]
    assert all(p.exists() for p in paths)
    assert "contact_sheet.png" in capsys.readouterr().out


# ----------------------------------------------------------------------------- eyes vs. jaw / mouth
# Regression (issue 2): the lower-lid rims are lower-side duplicates of a cut grid row, like the
# lower lip; the jaw mask used to give every such duplicate jaw weight 1, so opening the jaw
# (jaw_pose or AU26) tore the lower eyelids down over the eyeballs.

def _eye_zone(v):
    """(V,) bool: within 15 mm of an eyeball centre, or above the lower-lid skin (y > LID_FLOOR_Y)."""
    near = np.min([np.linalg.norm(v - c, axis=1) for c in EYE_CENTRES], axis=0) < 0.015
    return near | (v[:, 1] > LID_FLOOR_Y)


def _lid_ids(mesh):
    return np.concatenate([mesh.parts[f"lid_{s}_{e}"] for s in ("upper", "lower") for e in range(2)])


@pytest.mark.parametrize("which", ["built", "committed"])
def test_jaw_never_moves_the_eyes(which, head, committed, mesh):
    arrays = head if which == "built" else committed
    v, w = arrays["v_template"], arrays["weights"]
    zone = _eye_zone(v)
    lids = _lid_ids(mesh)
    assert zone[lids].all() and zone.sum() > 300
    assert np.all(w[zone, 2] == 0.0), f"jaw weight on {np.flatnonzero(zone & (w[:, 2] > 0))[:12]}"
    assert np.all(arrays["posedirs"][zone] == 0.0)
    no_corr = dict(arrays, posedirs=np.zeros_like(arrays["posedirs"]))
    for arr in (arrays, no_corr):  # with and without the pose correctives
        rest = _pose(arr)
        for jaw in ([0.35, 0.0, 0.0], [0.2, 0.1, -0.05]):
            opened = _pose(arr, jaw=jaw)
            assert np.abs(opened[zone] - rest[zone]).max() < 1e-12
    # the lower lip still follows the jaw
    lo = mesh.parts["mouth_lower"]
    assert np.all(w[lo[1:-1], 2] == 1.0)


@pytest.mark.parametrize("which", ["built", "committed"])
def test_mouth_components_leave_the_eyes_alone(which, head, committed):
    arrays = head if which == "built" else committed
    v = arrays["v_template"]
    zone = _eye_zone(v)
    nose_tip_y = v[np.argmax(v[:, 2]), 1]
    above_tip = v[:, 1] > nose_tip_y
    ramus = np.abs(v[:, 0]) > 0.055  # AU26 = jaw rotation: the skin over the ramus up to the hinge
    for name in MOUTH_COMPONENTS:
        d = _comp(arrays, name)
        assert np.all(d[zone] == 0.0), f"{name} moves {np.flatnonzero(zone & np.any(d != 0, axis=1))[:12]}"
        if name in ("AU10", "AU12_L", "AU12_R"):  # alar lift / cheek lift: allowed above the nose tip
            continue
        allowed = ramus if name == "AU26" else np.zeros(len(v), dtype=bool)
        assert np.all(d[above_tip & ~allowed] == 0.0), f"{name} moves above the nose tip"
    # the jaw drop / lips part still do their job
    assert np.linalg.norm(_comp(arrays, "AU26"), axis=1).max() > 0.015
    assert np.linalg.norm(_comp(arrays, "AU25"), axis=1).max() > 0.003


@pytest.mark.parametrize("which", ["built", "committed"])
def test_lower_lids_follow_lid_aus(which, head, committed, mesh):
    arrays = head if which == "built" else committed
    v = arrays["v_template"]
    for e, tag in ((0, "L"), (1, "R")):
        up, lo = mesh.parts[f"lid_upper_{e}"], mesh.parts[f"lid_lower_{e}"]
        inner = lo[1:-1]
        d7 = _comp(arrays, "AU7")
        # AU7 raises the lower rim (up to 11 deg of pitch) sliding on the lid sphere
        assert d7[inner, 1].max() > 0.0015 and np.all(d7[inner, 1] > 0)
        r = np.linalg.norm(v[inner] + d7[inner] - EYE_CENTRES[e], axis=1)
        assert np.allclose(r, LID_RADIUS, atol=1e-5)
        assert np.all(_comp(arrays, f"AU43_{tag}")[inner] == 0.0)  # AU43 moves the upper lid (and the corners)
        # a pain-like face: eyes closed while the jaw is open; the lids meet, the lower lid stays
        expr = np.zeros(int(arrays["n_expr"]))
        names = list(arrays["expression_names"])
        for n, c in (("AU43_L", 1.0), ("AU43_R", 1.0), ("AU25", 1.0), ("AU26", 1.0), ("AU20", 0.5)):
            expr[names.index(n)] = c
        rest = _pose(arrays)
        posed = _pose(arrays, expr=expr, jaw=[0.3, 0.0, 0.0])
        assert np.abs(posed[inner] - rest[inner]).max() < 1e-12
        assert np.linalg.norm(posed[up[1:-1]] - posed[inner], axis=1).max() < 1.5e-3


def test_loading_the_default_head_runs_no_build_code():
    """The head builder is build-time code: loading the model imports nothing from flame.builder."""
    import subprocess
    import sys

    code = ("import sys; from holo_viewer.flame.default_head import load_default_model; "
            "from holo_viewer.flame.expressions import default_au_map; load_default_model(); default_au_map(); "
            "print([m for m in sys.modules if m.startswith('holo_viewer.flame.builder')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
