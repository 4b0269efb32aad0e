"""Pipeline: stage caching (recompute log), framing, streaming with a frame budget.

A small random FLAME-format model (``flame.synthetic``) with a few hundred Gaussians bound
to its triangles keeps every stage fast; the default head is used where the expression
map (pain, named expressions) is needed.
"""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.errors import InputError
from holo_viewer.testing import random_rigged_avatar
from holo_viewer.pipeline import (STAGES, FaceControls, Pipeline, StageTimings, ViewSettings, flame_sequence_frames,
                                  frame_head)


def _small_avatar(model, n=400, seed=0):
    return random_rigged_avatar(model, n=n, seed=seed)


@pytest.fixture()
def small_pipeline(small_model):
    return Pipeline(model=small_model, avatar=_small_avatar(small_model),
                    view=ViewSettings(tile_scale=0.1))


def _log_of_last(p: Pipeline) -> list[str]:
    return p.recomputed_in_last_request()


def test_first_request_computes_every_stage_once(small_pipeline):
    p = small_pipeline
    native = p.native()
    assert native.shape == (p.calibration.screen_h, p.calibration.screen_w, 3)
    assert sorted(_log_of_last(p)) == sorted(STAGES)
    p.native()
    assert _log_of_last(p) == []  # everything cached
    t = p.last_timings
    assert isinstance(t, StageTimings) and t.recomputed() == []


def test_expression_change_reruns_face_stages_not_cameras(small_pipeline):
    p = small_pipeline
    p.native()
    cams_v = p.stage_version("cameras")
    p.set_face(expr=np.array([1.0, -0.5]))
    p.native()
    assert _log_of_last(p) == ["params", "mesh", "gaussians", "views", "quilt", "native"]
    assert p.stage_version("cameras") == cams_v
    assert p.last_timings.cameras is None and p.last_timings.mesh is not None


def test_viewer_distance_reruns_camera_stages_not_mesh(small_pipeline):
    p = small_pipeline
    p.native()
    mesh_v, g_v = p.stage_version("mesh"), p.stage_version("gaussians")
    before = p.cameras()
    p.set_view(viewer_distance=1.2)
    p.native()
    assert _log_of_last(p) == ["cameras", "views", "quilt", "native"]
    assert (p.stage_version("mesh"), p.stage_version("gaussians")) == (mesh_v, g_v)
    assert not np.allclose(before.K, p.cameras().K)  # the fov follows the distance


def test_blend_mode_reruns_only_native(small_pipeline):
    p = small_pipeline
    p.native()
    p.set_view(blend=True)
    p.native()
    assert _log_of_last(p) == ["native"]


def test_same_value_is_a_cache_hit(small_pipeline):
    p = small_pipeline
    p.set_face(expr=np.array([0.3]))
    p.quilt()
    p.set_face(expr=np.array([0.3]))  # a new object with equal content
    p.quilt()
    assert _log_of_last(p) == []


def test_mesh_follows_flame_model(small_model, small_pipeline):
    import torch

    p = small_pipeline
    p.set_face(expr=np.array([0.5, 0.1, 0, 0, 0, -0.2]), jaw_pose=np.array([0.2, 0, 0]))
    with torch.no_grad():
        ref = small_model(expr=torch.tensor([[0.5, 0.1, 0, 0, 0, -0.2]]), jaw_pose=torch.tensor([[0.2, 0.0, 0.0]]))
    np.testing.assert_allclose(p.mesh(), ref.vertices[0].numpy(), atol=1e-6)


def test_views_are_gaussians_rendered_by_the_renderer(small_pipeline):
    from holo_viewer.render.api import render_views

    p = small_pipeline
    views = p.views()
    ref = render_views(p.gaussians(), p.cameras(), backend="reference").images
    assert views.shape == ref.shape
    assert np.abs(views - ref).max() < 2e-3
    assert views.std() > 0.01  # not blank


def test_quilt_tiles_views_bottom_left_first(small_pipeline):
    p = small_pipeline
    views, quilt = p.views(), p.quilt()
    V, H, W, _ = views.shape
    cols, rows = p.calibration.cols, p.calibration.rows
    assert quilt.shape == (rows * H, cols * W, 3) and quilt.dtype == np.uint8
    v0 = np.clip(np.rint(views[0] * 255), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(quilt[-H:, :W], v0)  # view 0 = bottom-left tile


def test_framing_centres_the_head(small_pipeline):
    p = small_pipeline
    centre, half = p.get("framing")
    rest = p._flame_vertices({"shape": np.zeros(p.model.n_shape)})
    lo, hi = rest.min(0), rest.max(0)
    np.testing.assert_allclose(centre, 0.5 * (lo + hi))
    assert half == pytest.approx(0.5 * (hi[1] - lo[1]) * p.view.framing_margin)
    # the focal-plane centre projects to the middle of every view (sheared cameras)
    uv, depth = p.cameras().project(centre[None])
    np.testing.assert_allclose(uv[:, 0, 0], p.cameras().width / 2, atol=1e-6)
    np.testing.assert_allclose(uv[:, 0, 1], p.cameras().height / 2, atol=1e-6)
    # the head (top to bottom) fits inside the tile height with the margin
    top_bottom = np.array([[centre[0], hi[1], centre[2]], [centre[0], lo[1], centre[2]]])
    uv, _ = p.cameras()[len(p.cameras()) // 2].project(top_bottom)
    frac = (uv[0, 1, 1] - uv[0, 0, 1]) / p.cameras().height
    assert frac == pytest.approx(1.0 / p.view.framing_margin, rel=1e-6)


def test_frame_head_rejects_flat_input():
    with pytest.raises(InputError, match="height"):
        frame_head(np.zeros((10, 3)))
    with pytest.raises(InputError, match="vertices"):
        frame_head(np.full((10, 3), np.nan))


def test_face_controls_validate():
    with pytest.raises(InputError, match="pain"):
        FaceControls(pain=1.5)
    with pytest.raises(InputError, match="jaw_pose"):
        FaceControls(jaw_pose=[0.1, 0.2])
    with pytest.raises(InputError, match="named"):
        FaceControls(named=(("grin", 0.5),))
    with pytest.raises(InputError, match="expr"):
        FaceControls(expr=[np.nan])


def test_too_many_expression_coefficients_is_a_clear_error(small_pipeline):
    small_pipeline.set_face(expr=np.ones(50))
    with pytest.raises(InputError, match="n_expr"):
        small_pipeline.mesh()


# ------------------------------------------------------------------ streaming


def _sequence(T=10, n_expr=6):
    rng = np.random.default_rng(0)
    return {"expr": rng.normal(scale=0.3, size=(T, n_expr)), "jaw_pose": np.zeros((T, 3)),
            "rotation": np.zeros((T, 3)), "neck_pose": np.zeros((T, 3)), "eyes_pose": np.zeros((T, 6)),
            "translation": np.zeros((T, 3)), "shape": np.zeros(8)}


def test_flame_sequence_frames_checks_lengths():
    seq = _sequence(5)
    frames = flame_sequence_frames(seq)
    assert len(frames) == 5 and frames[2]["expr"].shape == (6,)
    bad = dict(seq, jaw_pose=np.zeros((4, 3)))
    with pytest.raises(InputError, match="jaw_pose.*5 frames"):
        flame_sequence_frames(bad)
    with pytest.raises(InputError, match="eyes_pose"):
        flame_sequence_frames(dict(seq, eyes_pose=np.zeros((5, 3))))


def test_stream_all_frames_when_fast_enough(small_pipeline):
    p = small_pipeline
    frames = flame_sequence_frames(_sequence(6))
    seen = []
    rep = p.stream(frames, fps=1e-3, output="mesh", policy="drop", sink=lambda r: seen.append(r.index))
    assert rep.rendered == list(range(6)) and seen == list(range(6))
    assert rep.dropped == [] and rep.held == 0 and rep.late == []
    assert rep.stage_seconds.mesh is not None


def test_stream_drops_and_holds_when_slow(small_pipeline):
    p = small_pipeline
    frames = flame_sequence_frames(_sequence(10))
    state = {"t": 0.0}

    def clock():
        return state["t"]

    def sink(res):  # each computed frame costs 2.5 budgets of 0.1 s
        state["t"] += 0.25

    rep = p.stream(frames, fps=10.0, output="mesh", policy="drop", sink=sink, clock=clock)
    # frame 0 ends at 0.25 s (slot 2): frame 1 dropped, frame 2 next; ends 0.5 (slot 5): 3, 4 dropped ...
    assert rep.rendered == [0, 2, 5, 7]
    assert rep.dropped == [1, 3, 4, 6, 8, 9]
    assert rep.held == len(rep.dropped)
    assert set(rep.rendered) | set(rep.dropped) == set(range(10))
    assert rep.late == rep.rendered
    # "all" computes every frame and counts the overrun slots as held
    state["t"] = 0.0
    rep2 = p.stream(frames, fps=10.0, output="mesh", policy="all", sink=sink, clock=clock)
    assert rep2.rendered == list(range(10)) and rep2.dropped == []
    assert rep2.held > 0 and len(rep2.late) == 10


def test_stream_restores_controls_and_reports_quilts(small_pipeline):
    p = small_pipeline
    base = FaceControls(expr=[0.2])
    p.set_face(base)
    frames = flame_sequence_frames(_sequence(3))
    got = []
    rep = p.stream(frames, fps=1e-3, output="quilt", policy="all", sink=lambda r: got.append(r.quilt))
    assert p.face is base
    assert len(got) == 3 and got[0].shape == p.quilt().shape and not np.array_equal(got[0], got[1])
    assert "3 frames" in rep.summary()


def test_stream_rejects_bad_arguments(small_pipeline):
    with pytest.raises(InputError, match="policy"):
        small_pipeline.stream([], policy="skip")
    with pytest.raises(InputError, match="fps"):
        small_pipeline.stream([], fps=0)
    with pytest.raises(InputError, match="unknown key"):
        small_pipeline.stream([{"exprs": np.zeros(6)}], fps=1e-3, output="mesh")


# ------------------------------------------------------------------ default head: pain, named expressions


@pytest.fixture(scope="module")
def head_pipeline():
    from holo_viewer.flame.default_head import load_default_model

    model = load_default_model()
    return Pipeline(model=model, avatar=_small_avatar(model, n=600), view=ViewSettings(tile_scale=0.1))


def test_pain_reruns_only_the_stages_after_it(head_pipeline):
    p = head_pipeline
    p.set_face(FaceControls())
    p.native()
    versions = {s: p.stage_version(s) for s in STAGES}
    p.set_face(pain=0.8)
    p.native()
    assert _log_of_last(p) == ["params", "mesh", "gaussians", "views", "quilt", "native"]
    assert p.stage_version("cameras") == versions["cameras"]
    assert p.stage_version("framing") == versions["framing"]
    assert all(p.stage_version(s) != versions[s] for s in ("params", "mesh", "gaussians", "views", "quilt", "native"))


def test_pain_and_smile_move_the_face(head_pipeline):
    from holo_viewer.flame.expressions import au_map_for, named_expression, pain_expression, pspi

    p = head_pipeline
    p.set_face(FaceControls())
    neutral = p.mesh().copy()
    p.set_face(FaceControls(pain=1.0, named=(("smile", 0.5),)))
    params = p.flame_params()
    au = au_map_for(p.model)
    expected = named_expression("smile", 0.5, au) + pain_expression(1.0, au)
    np.testing.assert_allclose(params["expr"], expected, atol=1e-12)
    assert pspi(params["expr"], au) > 8.0
    moved = np.linalg.norm(p.mesh() - neutral, axis=1)
    assert moved.max() > 1e-3  # millimetres of motion somewhere on the face


def test_to_uint8_rounds_and_clips_like_the_plain_formula():
    from holo_viewer.display.quilt import to_uint8

    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        a = (rng.random((3, 5, 7, 3)) * 1.4 - 0.2).astype(dtype)
        a.flat[:4] = np.array([0.5, 1.5, 2.5, 254.5]) / 255  # ties round to even
        np.testing.assert_array_equal(to_uint8(a), np.clip(np.rint(a * 255.0), 0, 255).astype(np.uint8))
    u = np.arange(6, dtype=np.uint8)
    assert to_uint8(u) is u


# ------------------------------------------------------------------ one chain: avatars, render_quilt, reactions


def test_render_quilt_is_the_pipelines_quilt(small_pipeline):
    from holo_viewer.pipeline import quilt_layout, render_quilt

    p = small_pipeline
    quilt = render_quilt(p.gaussians(), p.cameras(), *quilt_layout(p.calibration), backend=p.backend)
    assert quilt.dtype == np.uint8
    np.testing.assert_array_equal(quilt, p.quilt())


def test_the_thumbnail_worker_renders_with_render_quilt(small_pipeline):
    from holo_viewer.gui.thumbnail_worker import render_thumbnail

    p = small_pipeline
    q = render_thumbnail(p.gaussians(), p.cameras(), p.backend, None, p.calibration.cols, p.calibration.rows)
    np.testing.assert_array_equal(q, p.quilt())


def test_blendshape_avatar_drives_the_pipeline(small_model):
    """The seed paper's blend shapes behind the same protocol: exact at psi = 0, close for small psi."""
    from holo_viewer.avatar import BlendshapeAvatar

    rigged = _small_avatar(small_model)
    blend = BlendshapeAvatar.from_rigged(rigged)
    pr = Pipeline(model=small_model, avatar=rigged, view=ViewSettings(tile_scale=0.1))
    pb = Pipeline(model=small_model, avatar=blend, view=ViewSettings(tile_scale=0.1))
    assert pb.avatar is blend and len(pb.avatar) == len(rigged)
    for expr in ([0.0], [0.3, -0.2]):
        pr.set_face(expr=expr)
        pb.set_face(expr=expr)
        gr, gb = pr.gaussians().numpy(), pb.gaussians().numpy()
        err = np.abs(gr.means - gb.means).max()
        scale = np.abs(gr.means).max()
        assert err < (1e-5 if expr == [0.0] else 2e-2) * scale, (expr, err)
    pb.set_face(expr=[0.3, -0.2], rotation=[0.0, 0.2, 0.0])
    pr.set_face(expr=[0.3, -0.2], rotation=[0.0, 0.2, 0.0])
    assert np.abs(pr.gaussians().numpy().means - pb.gaussians().numpy().means).max() < 2e-2 * scale
    assert pb.quilt().shape == pr.quilt().shape
    pb.set_face(FaceControls(neck_pose=[0.1, 0.0, 0.0]))
    with pytest.raises(InputError, match="neck_pose: a blend-shape avatar has no neck joint"):
        pb.gaussians()


def test_pipeline_rejects_an_object_that_is_no_avatar(small_model):
    with pytest.raises(InputError, match="avatar: expected a RiggedAvatar, BlendshapeAvatar"):
        Pipeline(model=small_model, avatar=object())


@pytest.mark.slow
def test_face_state_renderer_matches_the_direct_chain():
    """The FRRea renderer (pipeline.FaceStateRenderer) gives the images of the chain it replaced in
    reaction/frrea.py: FLAME batch LBS -> rigged avatar -> render_views from the frontal camera."""
    import torch

    from holo_viewer.pipeline import FaceStateRenderer
    from holo_viewer.reaction.features import flame_from_state
    from holo_viewer.render.api import render_views

    r = FaceStateRenderer(size=24, n_gaussians=3000)
    rng = np.random.default_rng(3)
    states = np.zeros((3, r.state_dim))
    states[:, : r.state_dim - 6] = rng.random((3, r.state_dim - 6))
    states[:, -3:] = rng.normal(0, 0.2, (3, 3))
    imgs = r(states)
    fl = flame_from_state(states, r.au_map)
    model, avatar = r.pipeline.model, r.pipeline.avatar
    with torch.no_grad():
        out = model(expr=torch.from_numpy(fl["expr"]), jaw_pose=torch.from_numpy(fl["jaw_pose"]),
                    rotation=torch.from_numpy(fl["rotation"]))
    ref = np.stack([render_views(avatar.deform(v), r.cameras, backend="fast").images[0] for v in out.vertices])
    assert imgs.shape == (3, 24, 24, 3)
    np.testing.assert_allclose(imgs, ref, rtol=0, atol=1e-6)  # measured: identical
