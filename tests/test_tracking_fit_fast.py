"""The landmark fit's compiled steps (holo_viewer.tracking.fit_fast) against the numpy reference (issue 37)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("dlib", reason="face tracking needs the [live] extra (dlib-bin)")


@pytest.fixture(scope="module")
def head():
    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.flame.expressions import default_au_map
    from holo_viewer.tracking.head_model import LandmarkHeadModel

    return LandmarkHeadModel(load_default_model(), default_au_map())


def test_fast_fit_equals_the_numpy_reference(head):
    """Cold and warm fits, noisy landmarks, large and tiny rotations (Rodrigues' Taylor branch), AUs and the jaw
    at their bounds (the clip): the compiled steps give the reference's parameters to 1e-7 and its RMS to 1e-7 px."""
    from holo_viewer.tracking.fit import TrackerFitConfig, fit_landmarks, reduction

    rng = np.random.default_rng(7)
    K = np.array([[550.0, 0, 320], [0, 550, 240], [0, 0, 1]])
    M = reduction(head, TrackerFitConfig())
    nqa = M.shape[1] - 7
    prev = None
    for case in range(6):
        q = np.zeros(M.shape[1])
        q[:nqa] = rng.uniform(0, 1.0, nqa) if case != 3 else 0.0  # case 3: every AU at its lower bound
        q[nqa] = rng.uniform(0, 0.45) if case != 4 else 0.5  # case 4: the jaw wide open, at its bound
        q[nqa + 1:nqa + 4] = np.radians(rng.uniform(-35, 35, 3)) if case != 2 else [1e-5, -2e-5, 0.0]
        q[nqa + 4:] = [0.02, 0.03, 0.6]
        lm = head.project(M @ q, K)[0] + rng.normal(0, 1.0, (68, 2))
        for start in (None, prev):
            ref = fit_landmarks(head, lm, K, prev=start, fast=False)
            fast = fit_landmarks(head, lm, K, prev=start, fast=True)
            assert np.abs(fast.params - ref.params).max() < 1e-7, (case, start is None)
            assert abs(fast.rms_px - ref.rms_px) < 1e-7
            prev = ref.params


def test_tracker_fast_fit_setting(head):
    """TrackerConfig.fast_fit picks the path: both track a face to the same state (the detector stubbed)."""
    from holo_viewer.tracking.landmarks import FaceDetection
    from holo_viewer.tracking.tracker import FaceTracker, TrackerConfig
    from holo_viewer.tracking.viewer import webcam_intrinsics

    K = webcam_intrinsics(320, 240, 60.0)
    p = np.zeros(head.n_params)
    p[head.n_au + 1] = 0.2
    p[-1] = 0.5
    lm = head.project(p[None], K)[0]
    face = FaceDetection(box=np.array([lm[:, 0].min(), lm[:, 1].min(), lm[:, 0].max(), lm[:, 1].max()]),
                         landmarks=lm, score=1.0)
    states = []
    for fast in (True, False):
        tr = FaceTracker(TrackerConfig(fast_fit=fast, smoothing=None), detector=lambda frame: [face])
        tr.head = head
        frame = np.zeros((240, 320, 3), np.uint8)
        states.append([tr(frame, t / 25).state for t in range(3)])
    np.testing.assert_allclose(states[0], states[1], atol=1e-7)
    assert abs(states[0][-1][head.n_au + 3] - 0.2) < 0.02  # the rotation's x of the state (after AUs, jaw axis-angle)


def test_live_loop_uses_the_compiled_fit_only_when_cached(monkeypatch):
    """The live loop fits with the compiled steps when numba has them cached; on a cold cache it fits in numpy and
    starts one nice-19 child that compiles them for the next session, none with HOLO_VIEWER_BACKGROUND_BUILDS=0."""
    import subprocess

    from holo_viewer.live import loop
    from holo_viewer.tracking import fit_fast

    started = []
    monkeypatch.setattr(subprocess, "Popen", lambda cmd, **kw: started.append(cmd))
    monkeypatch.setattr(fit_fast, "kernel_cached", lambda: True)
    assert loop._fast_fit_ready() is True and not started
    monkeypatch.setattr(fit_fast, "kernel_cached", lambda: False)
    monkeypatch.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "0")
    assert loop._fast_fit_ready() is False and not started
    monkeypatch.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "1")
    monkeypatch.delenv("HOLO_VIEWER_PRECOMPILE", raising=False)
    assert loop._fast_fit_ready() is False
    assert len(started) == 1 and started[0][:3] == ["nice", "-n", "19"] and started[0][-1] == "holo_viewer.tracking.fit_fast"
