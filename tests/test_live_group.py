"""Group frames (issue 37): every position of the viewing cone sees the present face.

The default live frame (``auto`` -> ``group``) renders every view (every 6th, the others synthesized
by depth): the cone fill, which every viewer sees (``group_slices`` 0); ``group_slices`` > 0 draws the
first viewers' exact eye slices over it. Judged as a person standing there
sees it (:class:`holo_viewer.display.eyes.ConeSweep`, single eyes, head region) against the *present*
frame's full quilt. Tolerances (stated once):

* ``ConeSweep.see`` equals ``VirtualDisplay.see`` within 2e-4 per pixel (weights below 1e-4 of the
  strongest are left out);
* a pain flare (with a nod) shown to two tracked viewers at +6 deg and -4 deg (both see the fill) is
  seen at -15, 0 and +15 deg within one frame at >= 35 dB (the issue's cone target) and at both
  viewers' eyes at >= 40 dB (the issue's tracked-eye target; measured 40.1 / 42.7 dB at these
  quarter-size views, 40.8 dB the worst eye of a full-size walk over the flare); the old
  eyes-only default (``tracked``) is checked to fail there (< 25 dB: bystanders saw the neutral face;
  measured 17 dB);
* comfort: with the face still, consecutive default frames are identical without a tracked viewer,
  with one, and while one walks past (nothing depends on the viewers); with eye slices
  (``group_slices`` 1) positions away from a face see nothing change when it is found or lost, and
  fixed positions at 0 and -3 deg agree to >= 48 dB (the issue's target) while a tracked viewer walks
  past: measured 50.0 dB here with the slices feathered into the fill
  (``NativeFrameConfig.group_feather``), 41.5 dB with the slices replacing it (checked to fail the
  target; docs/live_frame.md "Comfort").

Views at tile_scale 0.25 (105x140) keep the renders cheap; the optics are the Portrait's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from holo_viewer.display.calibration import DisplayCalibration
from holo_viewer.display.eyes import ConeSweep, TrackedViewer, eye_psnr, head_psnr
from holo_viewer.display.simulate import VirtualDisplay
from holo_viewer.errors import InputError
from holo_viewer.pipeline import FaceControls, Pipeline, ViewSettings
from holo_viewer.pipeline.live import NativeFrameConfig, NativeFrameRenderer

BYSTANDERS = [(-15.0, 0.6), (0.0, 0.6), (15.0, 0.6)]


def _seen(cone: ConeSweep, native: np.ndarray) -> list[np.ndarray]:
    """What each of ``cone``'s positions perceives of ``native`` (``ConeSweep.see``), so that a frame
    compared twice (against the one before and the one after it, or one reference against two frames) is
    seen once: :func:`_psnr` of two of these is ``cone.psnr`` of the two frames, value for value."""
    return [cone.see(native, k) for k in range(len(cone.positions))]


def _psnr(ref_seen: list[np.ndarray], test_seen: list[np.ndarray]) -> np.ndarray:
    """``ConeSweep.psnr`` (head-region PSNR per position) of two frames' :func:`_seen` images."""
    return np.array([head_psnr(r, t) for r, t in zip(ref_seen, test_seen)])


@pytest.fixture(scope="module")
def rig():
    cal = DisplayCalibration.load(None)
    pipe = Pipeline(calibration=cal, view=ViewSettings(tile_scale=0.25))
    neutral = pipe.gaussians()
    pipe.set_face(FaceControls(pain=0.9, rotation=np.array([0.1, 0.0, 0.0])))
    flare = pipe.gaussians()
    display = VirtualDisplay(cal)
    cams = pipe.cameras()
    return {"cal": cal, "cams": cams, "neutral": neutral, "flare": flare, "display": display,
            "cone": ConeSweep(display, BYSTANDERS),
            "group": NativeFrameRenderer(cal, cams)}  # group frames keep nothing: one renderer serves every test


def test_cone_sweep_sees_what_the_virtual_display_sees(rig):
    rng = np.random.default_rng(3)
    native = rng.integers(0, 256, (2048, 1536, 3), dtype=np.uint8)
    cone = rig["cone"]
    for k in (0, 2):
        a, d = cone.positions[k]
        assert np.abs(cone.see(native, k) - rig["display"].see(native, a, d)).max() < 2e-4
    with pytest.raises(InputError, match="native: expected shape"):
        cone.see(native[:10], 0)


@pytest.mark.slow
def test_bystanders_see_a_pain_flare_within_one_frame(rig):
    cal, cams, cone = rig["cal"], rig["cams"], rig["cone"]
    ref = NativeFrameRenderer(cal, cams).frame(rig["flare"], mode="full_quilt").native.copy()
    viewer, second = TrackedViewer(6.0, 0.6), TrackedViewer(-4.0, 0.75)  # both see the fill (group_slices 0)
    seen, ref_seen = {}, _seen(cone, ref)
    for mode in ("auto", "tracked"):
        live = rig["group"] if mode == "auto" else NativeFrameRenderer(cal, cams)
        both = [viewer, second] if mode == "auto" else viewer
        live.frame(rig["neutral"], both, mode)
        live.frame(rig["neutral"], both, mode)
        f = live.frame(rig["flare"], both, mode)  # the first frame of the flare
        seen[mode] = (f.mode, _psnr(ref_seen, _seen(cone, f.native)), f.native.copy())
    mode, cone_db, native = seen["auto"]
    assert mode == "group"
    assert cone_db.min() >= 35.0, dict(zip(BYSTANDERS, cone_db))
    assert eye_psnr(rig["display"], ref, native, viewer) >= 40.0
    assert eye_psnr(rig["display"], ref, native, second) >= 40.0
    # the eyes-only frames this replaced: the bystanders saw the old face
    _, old_cone, _ = seen["tracked"]
    assert old_cone.max() < 25.0, old_cone


@pytest.mark.slow
def test_still_face_frames_agree_at_fixed_positions(rig):
    display = rig["display"]
    fixed = ConeSweep(display, [(0.0, 0.6), (-3.0, 0.6)])
    live = rig["group"]
    a = live.frame(rig["neutral"]).native.copy()
    assert np.array_equal(a, live.frame(rig["neutral"]).native)  # no viewer: nothing changes
    for angle in (-6.0, -1.5, 3.0):  # the default (no eye slices): a walking viewer changes nothing either
        assert np.array_equal(a, live.frame(rig["neutral"], TrackedViewer(angle, 0.6)).native)
    default = live.config
    try:  # eye slices for the first viewer (the same renderer: group frames keep nothing)
        live.config = dataclasses.replace(default, group_slices=1)
        # a face found, then lost: positions away from it see nothing change (one fill with faces or without)
        away = ConeSweep(display, [(-15.0, 0.6), (15.0, 0.6)])
        found = live.frame(rig["neutral"], TrackedViewer(6.0, 0.6)).native.copy()
        lost = live.frame(rig["neutral"]).native
        assert np.isinf(away.psnr(a, found)).all() and np.isinf(away.psnr(found, lost)).all()
        worst = {}
        for name, feather in (("feathered", default.group_feather), ("replacing", None)):
            live.config = dataclasses.replace(default, group_slices=1, group_feather=feather)
            prev, worst[name] = None, np.inf
            for angle in np.arange(-6.0, 4.6, 1.5):  # a tracked viewer walks past
                f = _seen(fixed, live.frame(rig["neutral"], TrackedViewer(float(angle), 0.6)).native)
                if prev is not None:  # fixed.psnr(previous frame, this frame), each frame seen once
                    worst[name] = min(worst[name], float(_psnr(prev, f).min()))
                prev = f
    finally:
        live.config = default
    assert worst["feathered"] >= 48.0 > worst["replacing"], worst


def test_group_frames_take_up_to_six_viewers_and_name_a_bad_one(rig):
    live = rig["group"]
    viewers = [TrackedViewer(a, 0.6) for a in (-20, -12, -4, 4, 12, 20, 25)]
    f = live.frame(rig["neutral"], viewers)
    seen = f.native.copy()  # (the renderer's buffer: the next frame overwrites it)
    assert f.mode == "group"
    # the cone fill at group_view_step (6: 9 source views, with faces or without); no eye slices by
    # default (group_slices 0: every viewer sees the fill)
    assert live.group_view_step == 6 and f.rendered_fraction == pytest.approx(9 / 48)
    fill = live.frame(rig["neutral"]).native.copy()
    assert live.frame(rig["neutral"]).rendered_fraction == pytest.approx(9 / 48)
    assert np.array_equal(seen, fill)
    default = live.config
    try:  # the same renderer with other group_slices (read per frame; a new renderer's tables cost ~0.9 s)
        live.config = dataclasses.replace(default, group_slices=1)
        assert live.frame(rig["neutral"], viewers).rendered_fraction == pytest.approx((9 + 2) / 48)  # the first
        live.config = dataclasses.replace(default, group_slices=6)
        assert live.frame(rig["neutral"], viewers).rendered_fraction == pytest.approx((9 + 12) / 48)  # 6 of 7
    finally:
        live.config = default
    with pytest.raises(InputError, match=r"group_slices: expected an integer in 0..6, found 7"):
        NativeFrameConfig(group_slices=7)
    with pytest.raises(InputError, match=r"viewers\[1\]: expected a holo_viewer.display.eyes.TrackedViewer"):
        live.frame(rig["neutral"], [viewers[0], (5.0, 0.6)])
    with pytest.raises(InputError, match="group_view_step: expected an integer >= 2, found 1"):
        NativeFrameConfig(group_view_step=1)
