"""Face tracking: head model exactness, fit on synthetic landmarks, closed loop on renders, filters, viewer pose."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from holo_viewer.errors import InputError, TrackingError

pytest.importorskip("dlib", reason="face tracking needs the [live] extra (dlib-bin)")


@pytest.fixture(scope="module")
def au_map():
    from holo_viewer.flame.expressions import default_au_map

    return default_au_map()


@pytest.fixture(scope="module")
def head(au_map):
    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.tracking.head_model import LandmarkHeadModel

    return LandmarkHeadModel(load_default_model(), au_map)


def _random_params(head, rng, b):
    p = np.zeros((b, head.n_params))
    p[:, :head.n_au] = rng.uniform(0, 1, (b, head.n_au))
    p[:, head.n_au] = rng.uniform(0, 0.4, b)
    p[:, head.n_au + 1:head.n_au + 4] = rng.normal(0, 0.3, (b, 3))
    p[:, head.n_au + 4:] = [0.0, 0.02, 0.5]
    return p


def test_head_model_matches_flame_lbs(head, au_map):
    """The fast landmark model = the float64 LBS reference (1e-9 m) = FlameModel vertices interpolated."""
    import torch

    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.reaction.features import au_scales

    rng = np.random.default_rng(0)
    p = _random_params(head, rng, 6)
    fast = head.points_flame(p)
    ref = head.points_flame_reference(p)
    np.testing.assert_allclose(fast, ref, atol=1e-9)
    # the model folded into the 68 landmarks (issue 37) = the per-vertex jaw LBS, to rounding
    for a, b in zip(head._local(p), head._local_vertices(p)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-14)
    m = load_default_model(dtype=torch.float64)
    expr = (p[:, :head.n_au] * au_scales(au_map.names)) @ au_map.matrix
    jaw = np.zeros((6, 3))
    jaw[:, 0] = p[:, head.n_au]
    v = m(expr=expr, jaw_pose=jaw, rotation=p[:, head.n_au + 1:head.n_au + 4]).vertices.numpy()
    # the fixture model keeps float32 buffers: agreement to float32 rounding of the template (1e-7 m)
    np.testing.assert_allclose(fast, head.embedding.points(v, m.faces.numpy()), atol=1e-7)


def test_embedding_back_projection_is_exact():
    """embed_landmarks puts each landmark on the mesh point that projects onto it (inside triangles)."""
    from holo_viewer.camera import look_at
    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.tracking.head_model import embed_landmarks

    m = load_default_model()
    v = m().vertices[0].numpy().astype(np.float64)
    f = m.faces.numpy()
    w2c = look_at([0.05, 0.03, 0.6], [0, 0, 0])
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    pc = v @ w2c[:3, :3].T + w2c[:3, 3]
    px = pc[:, :2] / pc[:, 2:] * 800 + [320, 240]
    rng = np.random.default_rng(1)
    # random pixels inside the face's projection, near its centre
    pts = px[np.argmax(v[:, 2])] + rng.uniform(-30, 30, (20, 2))
    tri, bary = embed_landmarks(pts, w2c, K, v, f)
    X = np.einsum("lkc,lk->lc", v[f[tri]], bary)
    xc = X @ w2c[:3, :3].T + w2c[:3, 3]
    back = xc[:, :2] / xc[:, 2:] * 800 + [320, 240]
    np.testing.assert_allclose(back, pts, atol=1e-6)
    assert np.all(bary >= -1e-9)


def test_fit_recovers_synthetic_landmarks(head):
    """On the model's own projections + 0.5 px noise the fit recovers rotation within 1 deg, jaw 1.5 deg."""
    from holo_viewer.tracking.fit import TrackerFitConfig, fit_landmarks, reduction

    rng = np.random.default_rng(2)
    K = np.array([[550.0, 0, 320], [0, 550, 240], [0, 0, 1]])
    M = reduction(head, TrackerFitConfig())
    for _ in range(5):
        q = np.zeros(M.shape[1])
        nqa = M.shape[1] - 7
        q[:nqa] = rng.uniform(0, 0.6, nqa)
        q[nqa] = rng.uniform(0, 0.3)
        q[nqa + 1:nqa + 4] = np.radians(rng.uniform(-20, 20, 3))
        q[nqa + 4:] = [0.01, 0.03, 0.5]
        p = M @ q
        lm = head.project(p, K)[0] + rng.normal(0, 0.5, (68, 2))
        res = fit_landmarks(head, lm, K)
        _, jaw, rot, T = head.split(res.params)
        _, jaw0, rot0, T0 = head.split(p)
        assert np.degrees(np.abs(rot - rot0)).max() < 1.0
        assert abs(np.degrees(jaw - jaw0)) < 1.5
        assert np.abs(T - T0).max() < 0.02
        assert res.rms_px < 1.5
        warm = fit_landmarks(head, lm, K, prev=res.params)  # a warm start stays put
        assert np.abs(warm.params - res.params).max() < 0.05


def test_fit_rejects_bad_landmarks(head):
    from holo_viewer.tracking.fit import TrackerFitConfig, fit_landmarks

    K = np.eye(3)
    with pytest.raises(InputError, match="landmarks"):
        fit_landmarks(head, np.zeros((5, 2)), K)
    with pytest.raises(InputError, match="landmarks"):
        fit_landmarks(head, np.full((68, 2), np.nan), K)
    with pytest.raises(TrackingError, match="inter-ocular"):
        fit_landmarks(head, np.zeros((68, 2)), K)
    with pytest.raises(InputError, match="AU26"):
        TrackerFitConfig(aus=("AU26",))


def test_one_euro_filter_smooths_and_lags_little():
    from holo_viewer.tracking.filters import OneEuroConfig, OneEuroFilter, measure_lag

    rng = np.random.default_rng(3)
    f = OneEuroFilter(2, OneEuroConfig(min_cutoff=1.0, beta=0.0))
    t = np.arange(200) / 25
    x = np.stack([np.full(200, 1.0), np.zeros(200)], axis=1) + rng.normal(0, 0.1, (200, 2))
    y = np.array([f(xi, ti) for xi, ti in zip(x, t)])
    assert y[50:].std(axis=0).max() < 0.5 * x[50:].std(axis=0).min()  # jitter reduced
    slow = measure_lag(OneEuroConfig(min_cutoff=1.0, beta=0.0))
    fast = measure_lag(OneEuroConfig(min_cutoff=1.0, beta=5.0))
    assert 0.0 < fast < slow < 0.3  # the speed term cuts the lag of a moving signal


def test_viewer_pose_geometry_and_easing(tmp_path):
    from holo_viewer.tracking.viewer import (IPD_M, ViewerTracker, ViewerTrackerConfig, WebcamMount, viewer_position,
                                             webcam_intrinsics)

    K = webcam_intrinsics(640, 480, 60.0)
    assert K[0, 0] == pytest.approx(320 / math.tan(math.radians(30)))
    # eyes 63 mm apart at 0.8 m straight ahead of the webcam -> position (0, 0, 0.8)
    f = K[0, 0]
    iod = f * IPD_M / 0.8
    lm = np.zeros((68, 2))
    lm[36:42] = [320 - iod / 2, 240]
    lm[42:48] = [320 + iod / 2, 240]
    p = viewer_position(lm, K)
    np.testing.assert_allclose(p, [0, 0, 0.8], atol=1e-9)
    # a viewer to the panel's right appears on the image's left of an upright webcam facing them
    mount = WebcamMount(position_m=(0.0, 0.0, 0.0))
    right = mount.to_panel(np.array([-0.2, 0.0, 0.8]))
    assert right[0] == pytest.approx(0.2)
    tr = ViewerTracker(mount, ViewerTrackerConfig(hold_s=0.2, ease_s=0.3, default_distance_m=0.6))
    for i in range(50):
        pose = tr.update(np.array([[-0.2, 0.0, 0.8]]), i / 25)
    assert pose.tracked and pose.angle_deg == pytest.approx(math.degrees(math.atan2(0.2, 0.8)), abs=0.3)
    assert pose.distance_m == pytest.approx(math.hypot(0.2, 0.8), abs=0.01)
    # lost: held for hold_s, then eases back to the default
    held = tr.update(np.zeros((0, 3)), 50 / 25)
    assert held.angle_deg == pytest.approx(pose.angle_deg) and not held.tracked
    for i in range(51, 100):
        eased = tr.update(np.zeros((0, 3)), i / 25)
    assert abs(eased.angle_deg) < 0.5 and eased.distance_m == pytest.approx(0.6, abs=0.02)
    # group mode centres on all faces; nearest picks the closest
    two = np.array([[-0.3, 0.0, 1.0], [0.2, 0.0, 0.7]])
    g = ViewerTracker(mount, ViewerTrackerConfig(mode="group")).update(two, 0.0)
    a = np.degrees(np.arctan2([0.3, -0.2], [1.0, 0.7]))
    assert g.angle_deg == pytest.approx(0.5 * (a.min() + a.max()))
    nearest = ViewerTracker(mount).update(two, 0.0)
    assert nearest.angle_deg == pytest.approx(a[1])
    # every face is passed on (group live frames serve each): the others, nearest first
    d = np.hypot([0.3, 0.2], [1.0, 0.7])
    assert np.ravel(nearest.others) == pytest.approx([a[0], d[0]])
    assert np.ravel(g.others) == pytest.approx([a[1], d[1], a[0], d[0]])
    assert ViewerTracker(mount).update(np.zeros((0, 3)), 1.0).others == ()
    # mount JSON
    path = tmp_path / "mount.json"
    path.write_text(json.dumps({"position_m": [0, 0.12, 0.01], "hfov_deg": 70}))
    assert WebcamMount.load(path).hfov_deg == 70
    path.write_text(json.dumps({"position": [0, 0, 0]}))
    with pytest.raises(TrackingError, match="unknown keys"):
        WebcamMount.load(path)
    with pytest.raises(TrackingError, match="not found"):
        WebcamMount.load(tmp_path / "missing.json")


def _positions_at(angle_deg, distance_m):
    """Webcam-frame eye midpoints (N, 3) of a viewer at these panel angles and distances (webcam
    at the panel centre, upright: x_cam = -x_panel)."""
    a = np.radians(np.asarray(angle_deg, dtype=np.float64))
    d = np.broadcast_to(np.asarray(distance_m, dtype=np.float64), a.shape)
    return np.stack([-d * np.sin(a), np.zeros_like(a), d * np.cos(a)], axis=-1)


def test_viewer_prediction_is_exact_on_a_steady_motion():
    """A viewer moving at a steady 12 deg/s and 5 cm/s: once the smoothing has settled, the pose
    predicted for a frame shown 70 ms after its webcam frame is where the viewer then is (the
    filtered pose alone trails by the smoothing's lag plus the 70 ms)."""
    from holo_viewer.tracking.viewer import ViewerTracker, WebcamMount

    tr = ViewerTracker(WebcamMount(position_m=(0.0, 0.0, 0.0)))
    fps, lead = 25.0, 0.07
    t = np.arange(100) / fps
    ang, dist = -10.0 + 12.0 * t, 0.5 + 0.05 * t
    pos = _positions_at(ang, dist)
    for i in range(t.size):
        pose = tr.update(pos[i:i + 1], float(t[i]))
    truth = (-10.0 + 12.0 * (t[-1] + lead), 0.5 + 0.05 * (t[-1] + lead))
    assert pose.rate[0] == pytest.approx(12.0, rel=1e-3) and pose.rate[1] == pytest.approx(0.05, rel=1e-2)
    assert all(0.0 < lag < 0.2 for lag in pose.lag_s)
    assert abs(pose.angle_deg - truth[0]) > 0.8  # the filtered pose trails
    ahead = pose.predicted(lead)
    assert ahead.angle_deg == pytest.approx(truth[0], abs=0.01)
    assert ahead.distance_m == pytest.approx(truth[1], abs=1e-3)
    # the look-ahead is capped, and an untracked pose is not moved
    capped = pose.predicted(10.0)
    assert capped.angle_deg == pytest.approx(pose.angle_deg + 12.0 * 0.3, rel=1e-3)
    assert pose.predicted(10.0, max_lead_s=0.0) == pose
    lost = tr.update(np.zeros((0, 3)), float(t[-1]) + 0.04)
    assert not lost.tracked and lost.rate == (0.0, 0.0) and lost.predicted(0.1) == lost
    with pytest.raises(InputError, match="lead_s"):
        pose.predicted(float("nan"))


def test_viewer_prediction_cuts_the_error_at_display_time():
    """Where the eyes are when a frame is shown (70 ms after its webcam frame), against the pose
    it was rendered for: on a slow sway and on walk-and-stop motions with 0.2 deg of tracking
    noise the prediction cuts the RMS error of the filtered pose by more than a third (measured:
    about half); for a viewer standing still it stays under 0.2 deg (2 mm at 0.6 m)."""
    from holo_viewer.tracking.viewer import ViewerTracker, WebcamMount

    fps, lead = 25.0, 0.07
    t = np.arange(300) / fps
    phase = t % 4.0
    walk = np.where(phase < 2.0, 15.0 * np.minimum(phase, 1.0), 15.0 * np.maximum(0.0, 3.0 - phase)) - 7.5
    rng = np.random.default_rng(0)
    for name, ang in (("sway", 15.0 * np.sin(2 * np.pi * 0.3 * t)), ("walk", walk), ("still", np.zeros_like(t))):
        tr = ViewerTracker(WebcamMount(position_m=(0.0, 0.0, 0.0)))
        pos = _positions_at(ang + rng.normal(0.0, 0.2, t.size), 0.6)
        shown = np.interp(t + lead, t, ang)
        err = {"filtered": [], "predicted": []}
        for i in range(t.size):
            pose = tr.update(pos[i:i + 1], float(t[i]))
            if i >= 25:
                err["filtered"].append(pose.angle_deg - shown[i])
                err["predicted"].append(pose.predicted(lead).angle_deg - shown[i])
        rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in err.items()}
        if name == "still":
            assert rms["predicted"] < 0.2
        else:
            assert rms["predicted"] < 0.65 * rms["filtered"], (name, rms)


# ----------------------------------------------------------------------------- closed loop on renders

def _rotation_truth_in_camera(cam, rot):
    """Head rotation as the fit reports it: R_fit = F R_cam R_head (F = diag(1, -1, -1))."""
    from scipy.spatial.transform import Rotation

    F = np.diag([1.0, -1.0, -1.0])
    Rc = cam.world_to_cam[0][:3, :3]
    return np.array([Rotation.from_matrix(F @ Rc @ Rotation.from_rotvec(r).as_matrix()).as_rotvec() for r in rot])


def _sequence(au_map, T):
    names = list(au_map.names)
    n = len(names)
    tt = np.arange(T) / 25

    def wave(f, ph, lo, hi):
        return lo + (hi - lo) * (0.5 + 0.5 * np.sin(2 * np.pi * f * tt + ph))

    st = np.zeros((T, n + 6))
    st[:, names.index("AU12")] = wave(0.45, 0.0, 0.0, 0.8)
    jaw = wave(1.1, 0.5, 0.0, 0.15)
    st[:, n] = jaw
    st[:, names.index("AU26")] = jaw * 7 / 3
    st[:, n + 3] = np.radians(8) * np.sin(2 * np.pi * 0.45 * tt)
    st[:, n + 4] = np.radians(15) * np.sin(2 * np.pi * 0.3 * tt + 1)
    st[:, n + 5] = np.radians(5) * np.sin(2 * np.pi * 0.4 * tt + 2)
    return st


# Stated accuracy (docs/live.md). Measured with dlib's 68 points on renders of the default avatar
# (640x480, 60 deg webcam at 0.5 m, pixel noise sigma 0.03). On the ICT-based head (issue 17; landmarks =
# ICT's landmarks68 vertices): rotation error median 1.7 / 2.8 / 2.2 deg at front / (-12, 5) / (10, -5)
# (p90 2.9-5.7), jaw MAE 3.1-3.6 deg with correlation 0.55-0.87: dlib puts the lower lip and chin 3-4 px
# (~2 mm) below ICT's landmark vertices on these renders, a bias of ~2 deg of jaw. (The sculpted head
# before it, with a detector-fitted embedding: rotation 6-13 deg, jaw MAE 1.7-2.3 deg.) Off-axis cameras
# keep their wider rotation bounds. Thresholds leave a margin.
ROT_MEDIAN_DEG = {"front": 11.0, "off-axis": 16.0}
ROT_P90_DEG = {"front": 18.0, "off-axis": 24.0}
JAW_MAE_DEG = 4.5
JAW_CORR = 0.3
AU12_CORR = 0.3


@pytest.mark.slow
@pytest.mark.parametrize("cam_yaw, cam_pitch", [(0.0, 0.0), (-12.0, 5.0), (10.0, -5.0)])
def test_closed_loop_on_renders(au_map, cam_yaw, cam_pitch):
    """Render the default avatar driven by a known sequence, track it, compare (can fail)."""
    from scipy.spatial.transform import Rotation

    from holo_viewer.pipeline.live_support import HeadRenderer, webcam_camera
    from holo_viewer.reaction.features import flame_from_state
    from holo_viewer.tracking.tracker import FaceTracker, TrackerConfig

    T = 40
    st = _sequence(au_map, T)
    n = len(au_map.names)
    fl = flame_from_state(st, au_map)
    r = HeadRenderer(n_gaussians=30_000)
    cam = webcam_camera(640, 480, 60.0, 0.5, yaw_deg=cam_yaw, pitch_deg=cam_pitch)
    tracker = FaceTracker(TrackerConfig(hfov_deg=60.0))
    rng = np.random.default_rng(int(cam_yaw) + 100)
    rows = [tracker(r.render({k: fl[k][t] for k in fl}, cam, noise_std=0.03, rng=rng), t / 25) for t in range(T)]
    found = np.array([x.found for x in rows])
    assert found.mean() >= 0.9
    est = np.stack([x.state for x in rows])[found]
    truth = st[found]
    R_true = _rotation_truth_in_camera(cam, truth[:, n + 3:])
    err = np.degrees(np.array([(Rotation.from_rotvec(a).inv() * Rotation.from_rotvec(b)).magnitude()
                               for a, b in zip(R_true, est[:, n + 3:])]))
    jaw_err = np.degrees(np.abs(est[:, n] - truth[:, n]))
    au12 = au_map.names.index("AU12")
    corr_jaw = np.corrcoef(est[:, n], truth[:, n])[0, 1]
    corr_au12 = np.corrcoef(est[:, au12], truth[:, au12])[0, 1]
    msg = (f"rotation error median {np.median(err):.1f} p90 {np.percentile(err, 90):.1f} deg, jaw MAE "
           f"{jaw_err.mean():.2f} deg corr {corr_jaw:.2f}, AU12 corr {corr_au12:.2f}")
    print(msg)
    kind = "front" if cam_yaw == 0.0 and cam_pitch == 0.0 else "off-axis"
    assert np.median(err) < ROT_MEDIAN_DEG[kind], msg
    assert np.percentile(err, 90) < ROT_P90_DEG[kind], msg
    assert jaw_err.mean() < JAW_MAE_DEG, msg
    assert corr_jaw > JAW_CORR, msg
    if cam_yaw == 0.0:
        assert corr_au12 > AU12_CORR, msg


@pytest.mark.slow
def test_track_command_feeds_react(tmp_path):
    """`track` on a rendered clip writes what `react` reads (end to end through the CLI)."""
    from holo_viewer.cli import main
    from holo_viewer.pipeline.live_support import write_talking_head_clip

    files = write_talking_head_clip(tmp_path / "clip", seconds=1.2, n_gaussians=20_000)
    out = tmp_path / "speaker.npz"
    assert main(["track", str(files["video"]), "--out", str(out)]) == 0
    with np.load(out) as z:
        assert z["expr"].shape[0] == 30 and z["found"].mean() > 0.9
        assert np.isfinite(z["expr"]).all() and np.isfinite(z["rotation"]).all()
    listener = tmp_path / "listener.npz"
    assert main(["react", "--audio", str(files["wav"]), "--speaker", str(out), "--out", str(listener)]) == 0
    with np.load(listener) as z:
        assert z["expr"].shape[0] == 30


def test_track_command_errors(tmp_path, capsys):
    from holo_viewer.cli import main

    assert main(["track", str(tmp_path / "none.mp4"), "--out", str(tmp_path / "o.npz")]) == 1
    assert "video file not found" in capsys.readouterr().err
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    assert main(["track", str(bad), "--out", str(tmp_path / "o.npz")]) == 1
    assert not (tmp_path / "o.npz").exists()
