"""live/sources.py's Webcam (OpenCV) with a fake camera: RGB frames, OpenCV on one thread."""
import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")


class _FakeCapture:
    def __init__(self, index):
        self.frame = np.arange(480 * 640 * 3, dtype=np.uint32).reshape(480, 640, 3).astype(np.uint8)  # BGR

    def isOpened(self):
        return True

    def set(self, prop, value):
        return True

    def read(self):
        return True, self.frame.copy()

    def release(self):
        pass


def test_webcam_frames_are_rgb_and_opencv_runs_on_one_thread(monkeypatch):
    from holo_viewer.live.sources import Webcam

    before = cv2.getNumThreads()
    monkeypatch.setattr(cv2, "VideoCapture", _FakeCapture)
    cam = Webcam(0)
    try:
        assert cv2.getNumThreads() == 1
        cam.start()
        cam.wait_frame(5.0)
        t, rgb = cam.latest(0.0)
        bgr = cam._cap.frame
        assert rgb.shape == (480, 640, 3) and np.array_equal(rgb, bgr[..., ::-1])  # the same pixels, RGB
    finally:
        cam.stop()
        cv2.setNumThreads(before)
