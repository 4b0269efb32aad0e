"""The face tracker's dlib in a child process (LandmarkDetector(process=True), issue 37): the same results."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("dlib", reason="face tracking needs the [live] extra (dlib-bin)")


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    from holo_viewer.pipeline.live_support import write_talking_head_clip

    return write_talking_head_clip(tmp_path_factory.mktemp("clip"), seconds=0.32, n_gaussians=10_000)


@pytest.fixture(scope="module")
def frames(clip):
    from holo_viewer.tracking.video import iter_video_frames

    return [f for _, f in iter_video_frames(clip["video"])]


@pytest.mark.slow
def test_child_process_detector_gives_the_same_landmarks(frames):
    """Full and speaker-only frames, the downscaled HOG path of a wide frame with two faces: boxes, landmarks and
    scores equal to dlib in this process; a child that died: dlib runs here from then on, the reason kept."""
    from holo_viewer.tracking.landmarks import LandmarkDetector

    here, child = LandmarkDetector(), LandmarkDetector(process=True)
    worker = child._worker
    assert child.process_error is None and child._worker is not None
    wide = np.concatenate([frames[0], frames[1]], axis=1)  # 960 wide > detect_width 640: HOG on a downscaled copy
    seq = [(f, i % 3 != 0) for i, f in enumerate(frames)] + [(None, False), (wide, False), (wide, True)]
    for frame, speaker_only in seq:
        if frame is None:  # forget the faces: the wide frame's full call runs the detector and finds both
            here.reset(), child.reset()
            continue
        a, b = here(frame, speaker_only=speaker_only), child(frame, speaker_only=speaker_only)
        assert len(a) == len(b) and len(a) >= 1
        for fa, fb in zip(a, b):
            np.testing.assert_array_equal(fa.landmarks, fb.landmarks)
            np.testing.assert_array_equal(fa.box, fb.box)
            assert fa.score == fb.score
    assert here.n_detections == child.n_detections >= 2 and len(a) == 1
    assert len(here(wide)) == len(child(wide)) == 2  # the full call looks at both faces again
    proc = worker._proc
    proc.kill()  # a child that died: the next call runs dlib here and says why
    proc.wait()
    got = child(frames[0])
    np.testing.assert_array_equal(got[0].landmarks, here(frames[0])[0].landmarks)
    assert child._worker is None and "stopped" in child.process_error and worker._proc is None  # closed
    child.close()  # nothing left to stop


@pytest.mark.slow
def test_live_session_with_the_tracker_in_a_child_process(clip, tmp_path):
    """``LiveSessionConfig.tracker_process``: a replayed session (no renderer) tracks the speaker through the
    child, and the session's end stops it."""
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig

    session = LiveSession(LiveSessionConfig(out=str(tmp_path / "s"), tracker_process=True),
                          sources.WavReplay(clip["wav"]), sources.VideoReplay(clip["video"]))
    session.run(None)
    det = session._face_tracker.detector
    # the child started (detector_process), never failed (process_error), and close() stopped it (_worker)
    assert session._face_tracker.config.detector_process and det.process_error is None and det._worker is None
    with np.load(tmp_path / "s" / "tracks.npz") as z:
        assert z["speaker_found"].mean() > 0.5
    assert len(session.tracker_ms) >= 4
