"""Skipping the Gaussians nobody sees (issue 37): ``render.visibility`` and ``NativeFrameRenderer(keep=)``.

Tolerances (stated once):

* ``max_weights``'s tiled kernel (boxes, tile lists, early termination) equals a plain loop over every
  pixel and every splat in depth order, in float64, within 1e-6 per Gaussian (kept as float32);
* the Gaussians whose largest weight is 0 are never blended: the float64 reference render without them
  equals the render with them within 1e-6 per channel;
* a group frame that skips the Gaussians whose largest weight over the 48 quilt views (at that pose) is
  <= ``KEEP_WEIGHT`` (1/255) is seen at -15, 0 and +15 deg within >= 45 dB of the frame with all of them
  (the default avatar, quarter-size views: 41.7k of 102k kept; measured 67.0-68.0 dB; 73.6-75.1 dB at
  0.5/255); ``keep`` all True gives the same frame bit for bit, and a mask of another avatar's length is
  ignored;
* per view (``max_weights(per_view=True)``, ``fast.render(view_keep=)``, a (V, N) ``keep``): the views'
  weights' maximum is ``max_weights`` exactly; a view drawing only its own row is bit for bit the render of
  that row's Gaussians alone (C++ and numba kernels); the group frame whose source views each skip the
  Gaussians <= 1/255 in that view is within >= 45 dB of the frame with all of them at -15, 0, +15 deg
  (quarter-size views, one pose: 34-35k of 41.7k per source view; measured 61.3-62.3 dB), and a (V, N)
  mask all True gives the same frame bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.errors import InputError
from holo_viewer.render import fast
from holo_viewer.render import fast_kernels as fk
from holo_viewer.render import visibility
from holo_viewer.render.config import RenderConfig


@pytest.fixture(scope="module")
def quarter():
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.pipeline import Pipeline, ViewSettings

    cal = DisplayCalibration.load(None)
    pipe = Pipeline(calibration=cal, view=ViewSettings(tile_scale=0.25))
    return {"cal": cal, "pipe": pipe, "cams": pipe.cameras()}


def _scene(n=200, seed=4):
    """A dense, nearly opaque clump in front of the quilt cameras: some Gaussians hidden behind others."""
    from holo_viewer.pipeline.live_support import HEAD_CENTRE
    from holo_viewer.testing import random_gaussians

    g = random_gaussians(n, sh_degree=1, seed=seed, scale=0.02)
    return g.replace(means=(g.means + HEAD_CENTRE.astype(np.float32)).astype(np.float32),
                     opacity_logits=(g.opacity_logits + 3.0).astype(np.float32))


def _brute_force(g, cams, config):
    """Largest weight per Gaussian: every pixel, every splat in depth order, float64 numpy."""
    gn = g.numpy()
    means, quats, ls = (np.ascontiguousarray(a, dtype=np.float64) for a in (gn.means, gn.quats, gn.log_scales))
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(gn.opacity_logits, dtype=np.float64)))
    sh = np.ascontiguousarray(gn.sh, dtype=np.float32)
    W, H = cams.width, cams.height
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    out = np.zeros(len(g))
    for v in range(len(cams)):
        Wrot = np.ascontiguousarray(cams.R[v])
        pc, cov = fk.prep_3d(means, quats, ls, Wrot)
        order, _ = fast.depth_order(pc[:, 2], (pc[:, 2] + cams.t[v, 2]) > cams.near)
        rec, box = fast._records(1, order.size)
        fk.project_views(order, pc, cov, means, opacity, sh, gn.sh_degree, np.zeros((1, 3), np.float32), False,
                         fast._view_params(cams, np.array([v])), W, H, cams.near, float(config.dilation),
                         float(config.radius_sigmas), float(config.alpha_threshold), -1.0, rec, box)
        T = np.ones((H, W))
        live = np.ones((H, W), dtype=bool)
        for k in range(order.size):
            x0, x1, y0, y1 = box[0, k]
            if x0 >= x1 or y0 >= y1:
                continue
            u, vv, A, B, C, op = (float(rec[0, k, i]) for i in range(6))
            dx, dy = xs + 0.5 - u, ys + 0.5 - vv
            power = -0.5 * A * dx * dx - B * dx * dy - 0.5 * C * dy * dy
            alpha = np.minimum(config.alpha_cap, op * np.exp(np.minimum(power, 0.0)))
            inbox = (xs >= x0) & (xs < x1) & (ys >= y0) & (ys < y1)
            ok = live & inbox & (power <= 0) & (alpha >= config.alpha_threshold)
            if ok.any():
                out[order[k]] = max(out[order[k]], float((alpha * T)[ok].max()))
            T = np.where(ok, T * (1.0 - alpha), T)
            live &= ~(ok & (T < config.t_min))
    return out


def test_max_weights_equal_a_plain_loop_over_every_pixel(quarter):
    cams = quarter["cams"][[0, 23, 47]]
    g = _scene()
    config = RenderConfig()
    w = visibility.max_weights(g, cams, config, chunk=2)
    ref = _brute_force(g, cams, config)
    assert ref.max() > 0.5 and (ref == 0).sum() >= 1  # something seen, something hidden
    np.testing.assert_allclose(w, ref, rtol=0, atol=1e-6)  # stored as float32
    from holo_viewer.render.reference import render as render64

    keep = visibility.visible_keep(w, 0.0)
    a = render64(g, cams, config).images
    b = render64(g.subset(keep), cams, config).images
    assert np.abs(a - b).max() < 1e-6
    with pytest.raises(InputError, match="weights: expected"):
        visibility.visible_keep(np.zeros((2, 2)))


@pytest.mark.parametrize("kernel", ["cpp", "numba"])
def test_per_view_keep_renders_each_views_own_subset(quarter, kernel):
    if kernel == "cpp" and not fast.cpp_available():
        pytest.skip("C++ extension not built")
    from holo_viewer.errors import RenderError

    cams = quarter["cams"][[0, 23, 47]]
    g = _scene()
    per_view = visibility.max_weights(g, cams, per_view=True)
    assert per_view.shape == (3, len(g))
    np.testing.assert_array_equal(per_view.max(axis=0), visibility.max_weights(g, cams))
    vk = per_view > visibility.KEEP_WEIGHT
    assert not np.array_equal(vk[0], vk[2]) and vk.sum() < vk.size  # the views keep different Gaussians
    config = RenderConfig(kernel=kernel)
    images = fast.render(g, cams, config, view_keep=vk).images.copy()
    for v in range(3):
        alone = fast.render(g.subset(np.flatnonzero(vk[v])), cams[[v]], config).images[0]
        assert np.array_equal(images[v], alone), v
    assert not np.array_equal(images, fast.render(g, cams, config).images)  # something skipped changed a pixel
    with pytest.raises(RenderError, match="view_keep: expected"):
        fast.render(g, cams, config, view_keep=vk[:2])


@pytest.mark.parametrize("kernel", ["numba", "cpp"])
def test_index_renders_the_subset_without_copying_it(quarter, kernel):
    """fast.render(index=) (live frames' level of detail): the images of rendering the subset, bit for bit,
    in any index order, with a per-view keep over the indexed Gaussians too; a bad index is refused."""
    if kernel == "cpp" and not fast.cpp_available():
        pytest.skip("C++ extension not built")
    from holo_viewer.errors import RenderError

    cams = quarter["cams"][[0, 23, 47]]
    g = _scene(300, seed=6)
    rng = np.random.default_rng(2)
    config = RenderConfig(kernel=kernel)
    for idx in (np.sort(rng.choice(len(g), 190, replace=False)), rng.permutation(len(g))[:120]):
        sub = g.subset(idx)
        vk = rng.random((len(cams), idx.size)) < 0.7
        for keep in (None, vk):
            want = fast.render(sub, cams, config, view_keep=keep).images.copy()
            got = fast.render(g, cams, config, view_keep=keep, index=idx)
            assert np.array_equal(got.images, want) and got.stats["n_input"] == idx.size
    assert not np.array_equal(want, fast.render(g, cams, config).images)  # the subset is another picture
    with pytest.raises(RenderError, match=r"index: expected \(n,\) integers in \[0, 300\)"):
        fast.render(g, cams, config, index=np.array([0, 300]))
    with pytest.raises(RenderError, match="view_keep: expected"):
        fast.render(g, cams, config, index=idx, view_keep=np.ones((3, len(g)), bool))


def test_group_frames_skip_what_nobody_sees(quarter):
    from holo_viewer.display.eyes import ConeSweep
    from holo_viewer.display.simulate import VirtualDisplay
    from holo_viewer.pipeline import FaceControls
    from holo_viewer.pipeline.live import NativeFrameRenderer

    cal, cams, pipe = quarter["cal"], quarter["cams"], quarter["pipe"]
    pipe.set_face(FaceControls(pain=0.9, rotation=np.array([0.1, 0.0, 0.0])))
    g = pipe.gaussians()
    pipe.set_face(FaceControls())
    per_view = visibility.max_weights(g, cams, per_view=True) > visibility.KEEP_WEIGHT
    mask = per_view.any(axis=0)
    assert 0.3 * mask.size < mask.sum() < 0.9 * mask.size
    full = NativeFrameRenderer(cal, cams).frame(g, None, "group").native.copy()
    kept = NativeFrameRenderer(cal, cams, keep=mask).frame(g, None, "group").native.copy()
    cone = ConeSweep(VirtualDisplay(cal), [(-15.0, 0.6), (0.0, 0.6), (15.0, 0.6)])
    assert not np.array_equal(full, kept)
    assert cone.psnr(full, kept).min() >= 45.0
    same = NativeFrameRenderer(cal, cams, keep=np.ones(len(g), dtype=bool)).frame(g, None, "group").native
    assert np.array_equal(same, full)
    other = NativeFrameRenderer(cal, cams, keep=mask[:-1]).frame(g, None, "group").native  # another avatar's
    assert np.array_equal(other, full)
    # each source view drawing only the Gaussians it shows: fewer again, the same picture
    live = NativeFrameRenderer(cal, cams, keep=per_view)
    src = live._synth_buffers(live.group_view_step)[0]
    assert per_view[src].sum(axis=1).max() < mask.sum()
    views = live.frame(g, None, "group").native.copy()
    assert not np.array_equal(views, kept)
    render = fast.render  # the frame draws its Gaussians by index (fast.render(index=)): as the subset drawn
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fast, "render", lambda gs, *a, index=None, **k: render(gs if index is None else gs.subset(index),
                                                                           *a, **k))
        assert np.array_equal(NativeFrameRenderer(cal, cams, keep=per_view).frame(g, None, "group").native, views)
    assert cone.psnr(full, views).min() >= 45.0
    same = NativeFrameRenderer(cal, cams, keep=np.ones((len(cams), len(g)), dtype=bool)).frame(g, None, "group")
    assert np.array_equal(same.native, full)
    with pytest.raises(InputError, match="keep: expected"):
        NativeFrameRenderer(cal, cams, keep=np.flatnonzero(mask))
    with pytest.raises(InputError, match="keep: expected"):
        NativeFrameRenderer(cal, cams, keep=per_view[:2])


def test_visible_mask_is_built_once_then_loaded(tmp_path, monkeypatch):
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.pipeline import FaceControls, Pipeline, ViewSettings
    from holo_viewer.pipeline.live_support import visible_mask

    monkeypatch.setenv("HOLO_VIEWER_TABLE_CACHE", str(tmp_path))
    pipe = Pipeline(calibration=DisplayCalibration.load(None), view=ViewSettings(tile_scale=0.05))
    face = FaceControls(pain=0.3)
    pipe.set_face(face)
    poses = ({"jaw_pose": (0.3, 0.0, 0.0)},)
    assert visible_mask(pipe, poses=poses, cached_only=True) is None
    built = visible_mask(pipe, poses=poses)
    assert pipe.face == face  # restored
    pipe.set_face(FaceControls(jaw_pose=np.array([0.3, 0.0, 0.0])))
    w = visibility.max_weights(pipe.gaussians(), pipe.cameras())
    np.testing.assert_array_equal(built, w > visibility.KEEP_WEIGHT)
    assert len(list(tmp_path.glob("visible_gaussians_*.npz"))) == 1
    np.testing.assert_array_equal(visible_mask(pipe, poses=poses, cached_only=True), built)
    views = visible_mask(pipe, poses=poses, per_view=True, cached_only=True)  # the same file
    np.testing.assert_array_equal(views, visibility.max_weights(pipe.gaussians(), pipe.cameras(), per_view=True)
                                  > visibility.KEEP_WEIGHT)
    np.testing.assert_array_equal(views.any(axis=0), built)
    assert visible_mask(pipe, poses=({"jaw_pose": (0.2, 0.0, 0.0)},), cached_only=True) is None  # another key
