"""Face boxes and 68 2-D landmarks from RGB frames (dlib; the ``[live]`` extra).

Detector choice (docs/live.md, measured on renders of the project's own head): dlib's HOG
frontal-face detector and its 68-point shape predictor (iBUG 300-W layout), from the packages
``dlib-bin`` (prebuilt dlib, Boost licence) and ``face_recognition_models`` (the weights inside
the sdist; no run-time download). The 68-point model was trained on iBUG 300-W, whose terms
exclude commercial use: fine for research, check before shipping a product.

Speed: HOG detection costs ~80 ms on a 420x560 frame, the shape predictor ~2 ms per face. So
:class:`LandmarkDetector` runs the HOG detector only every ``redetect_every`` frames or when it
has lost the face, on a downscaled copy of the frame; in between, each face's box is the
bounding box of its previous landmarks (the usual landmark-tracking loop).

68-point layout (0-based): 0-16 jaw contour, 17-21 right brow, 22-26 left brow (image left/
right of a frontal face: "right" = the subject's right), 27-35 nose, 36-41 right eye, 42-47
left eye, 48-59 outer lips, 60-67 inner lips.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, MissingDependencyError, TrackingError

__all__ = ["FaceDetection", "LandmarkDetector", "N_LANDMARKS", "RIGHT_EYE", "LEFT_EYE", "predictor_path",
           "check_frame"]

N_LANDMARKS = 68
RIGHT_EYE = slice(36, 42)
LEFT_EYE = slice(42, 48)
_PREDICTOR = "shape_predictor_68_face_landmarks.dat"


@dataclass(frozen=True)
class FaceDetection:
    """One face in one frame.

    Attributes
    ----------
    box : numpy.ndarray
        (4,) ``x0, y0, x1, y1`` in pixels (x right, y down; pixel centres at +0.5).
    landmarks : numpy.ndarray
        (68, 2) ``x, y`` pixel coordinates (iBUG 300-W order), float64.
    score : float
        Detector score (HOG margin; larger is surer; tracked faces keep their last score).
    """

    box: np.ndarray
    landmarks: np.ndarray
    score: float

    @property
    def width(self) -> float:
        """Box width in pixels."""
        return float(self.box[2] - self.box[0])

    @property
    def eye_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """(right eye, left eye) centres (2,) in pixels: means of landmarks 36-41 and 42-47."""
        return self.landmarks[RIGHT_EYE].mean(axis=0), self.landmarks[LEFT_EYE].mean(axis=0)


def _import_dlib():
    try:
        import dlib
    except ImportError as exc:
        raise MissingDependencyError("dlib-bin", "face tracking", extra="live") from exc
    return dlib


@functools.lru_cache(maxsize=1)
def _frontal_detector() -> Any:
    """dlib's HOG face detector, loaded once per process (~0.25 s of CPU) and shared: it keeps no state
    between calls, and dlib holds the GIL while it runs, so two trackers' calls never overlap."""
    return _import_dlib().get_frontal_face_detector()


@functools.lru_cache(maxsize=2)
def _shape_predictor(path: str) -> Any:
    """dlib's shape predictor of ``path``, loaded once per process (~0.5 s of CPU, 100 MB) and shared, as
    :func:`_frontal_detector`."""
    return _import_dlib().shape_predictor(path)


def predictor_path() -> Path:
    """Path of the 68-point shape predictor inside the ``face_recognition_models`` package.

    Located without importing the package (its ``__init__`` needs ``pkg_resources``, which
    recent setuptools no longer ship).
    """
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise MissingDependencyError("face_recognition_models", "face tracking", extra="live")
    for loc in spec.submodule_search_locations:
        p = Path(loc) / "models" / _PREDICTOR
        if p.is_file():
            return p
    raise TrackingError(f"face_recognition_models is installed but lacks models/{_PREDICTOR}; "
                        f"reinstall it (pip install --force-reinstall face_recognition_models)")


def check_frame(frame: np.ndarray, name: str = "frame") -> np.ndarray:
    """Validate an RGB frame: (H, W, 3) uint8 (float in [0, 1] is converted). Returns uint8 C-contiguous."""
    a = np.asarray(frame)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 16 or a.shape[1] < 16:
        raise InputError(f"{name}: expected an RGB image of shape (H, W, 3) with H, W >= 16, found {a.shape}")
    if a.dtype != np.uint8:
        if not np.issubdtype(a.dtype, np.floating):
            raise InputError(f"{name}: expected uint8 or float in [0, 1], found {a.dtype}")
        if not np.isfinite(a).all():
            raise InputError(f"{name}: holds NaN or inf")
        a = (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(a)


class LandmarkDetector:
    """Faces and 68 landmarks per frame, tracking boxes between HOG detections.

    Parameters
    ----------
    redetect_every : int >= 1
        Run the HOG detector at least every this many frames (1 = every frame), and always
        when no face is being tracked.
    detect_width : int
        Frames wider than this are downscaled to this width for the HOG detector (landmarks
        are always predicted on the full frame).
    upsample : int
        dlib's detector upsampling (0 or 1; 1 finds faces half as large, 4x slower).
    max_faces : int
        Keep at most this many faces (largest first).
    process : bool
        Run dlib in a child process (:class:`~holo_viewer.tracking.dlib_worker.DlibProcess`: the same results,
        without holding this process's GIL for the ~2 ms of each shape prediction; the live tracker's). If the
        child fails, dlib runs here from then on (``process_error`` says why). :meth:`close` stops it.
    """

    def __init__(self, redetect_every: int = 10, detect_width: int = 640, upsample: int = 0,
                 max_faces: int = 4, process: bool = False) -> None:
        if int(redetect_every) < 1:
            raise InputError(f"redetect_every: expected >= 1, found {redetect_every}")
        if int(detect_width) < 64:
            raise InputError(f"detect_width: expected >= 64 pixels, found {detect_width}")
        if int(upsample) not in (0, 1, 2):
            raise InputError(f"upsample: expected 0, 1 or 2, found {upsample}")
        dlib = _import_dlib()
        self._dlib = dlib
        self._detector = _frontal_detector()
        self._worker = None
        #: why the child process failed (dlib then runs in this process), or None
        self.process_error: str | None = None
        if process:
            from .dlib_worker import DlibProcess

            try:
                self._worker = DlibProcess(predictor_path())
            except TrackingError as exc:
                self.process_error = str(exc)
        self._predictor = None if self._worker is not None else _shape_predictor(os.fspath(predictor_path()))
        self.redetect_every = int(redetect_every)
        self.detect_width = int(detect_width)
        self.upsample = int(upsample)
        self.max_faces = int(max_faces)
        self._tracked: list[FaceDetection] = []
        self._since = 0
        self._box_map = np.array([0.0, 0.05, 1.0])  # centre offset (x, y) / size, size ratio
        #: frames on which the HOG detector ran
        self.n_detections = 0

    def reset(self) -> None:
        """Forget the tracked faces (the next frame runs the detector)."""
        self._tracked = []
        self._since = 0

    def _hog(self, frame: np.ndarray) -> list[tuple[np.ndarray, float]]:
        h, w = frame.shape[:2]
        scale = 1.0
        small = frame
        if w > self.detect_width:
            scale = self.detect_width / w
            # box-average downscale by an integer factor then nearest: cheap and alias-free enough
            step = max(1, int(math.ceil(1.0 / scale)))
            small = frame[: h - h % step, : w - w % step].reshape(h // step, step, w // step, step, 3).mean(
                axis=(1, 3)).astype(np.uint8)
            scale = small.shape[1] / w
        if self._worker is not None:
            try:
                found = self._worker.detect(small, self.upsample)
            except TrackingError as exc:
                self._worker_failed(exc)
                return self._hog(frame)
        else:
            rects, scores, _ = self._detector.run(small, self.upsample, 0.0)
            found = [((r.left(), r.top(), r.right(), r.bottom()), s) for r, s in zip(rects, scores)]
        self.n_detections += 1
        out = []
        for (left, top, right, bottom), s in found:
            box = np.array([left, top, right + 1, bottom + 1], dtype=np.float64) / scale
            out.append((box, float(s)))
        return out

    def _predict(self, frame: np.ndarray, box: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = (int(round(v)) for v in box)
        if self._worker is not None:
            try:
                return self._worker.predict(frame, x0, y0, x1 - 1, y1 - 1) + 0.5  # float64, as below
            except TrackingError as exc:
                self._worker_failed(exc)
        shape = self._predictor(frame, self._dlib.rectangle(x0, y0, x1 - 1, y1 - 1))
        # dlib part coordinates are integer pixel indices; +0.5 puts them at pixel centres
        return np.array([[p.x + 0.5, p.y + 0.5] for p in shape.parts()], dtype=np.float64)

    def _worker_failed(self, exc: Exception) -> None:
        """The child process failed: dlib runs in this process from now on."""
        self.process_error = str(exc)
        worker, self._worker = self._worker, None
        worker.close()
        if self._predictor is None:
            self._predictor = _shape_predictor(os.fspath(predictor_path()))

    def close(self) -> None:
        """Stop the child process, if any (dlib runs in this process afterwards)."""
        if self._worker is not None:
            worker, self._worker = self._worker, None
            worker.close()
            if self._predictor is None:
                self._predictor = _shape_predictor(os.fspath(predictor_path()))

    def __call__(self, frame: np.ndarray, speaker_only: bool = False) -> list[FaceDetection]:
        """Faces in ``frame`` (H, W, 3) RGB uint8, largest first (empty list: none found).

        ``speaker_only``: only the largest tracked face (the speaker), its landmarks predicted in the box
        its previous ones give; no HOG detection and no other face (their landmarks are kept for the next
        full call), and the frame does not count toward ``redetect_every``. With no face tracked it
        returns [] without detecting (the next full call searches); a tracked face lost on such a frame
        runs the detector at once, as a full call does. The live loop's frames between its viewer
        updates (``LiveSessionConfig.viewer_fps``): the speaker's features at the webcam's rate, the
        search for faces and the other faces at the viewer's.
        """
        frame = check_frame(frame)
        if speaker_only:
            if not self._tracked:
                return []
            head = self._tracked[0]
            box = np.clip(self._box_from_landmarks(head.landmarks, self._box_map), 0,
                          [frame.shape[1], frame.shape[0]] * 2)
            if box[2] - box[0] >= 16 and box[3] - box[1] >= 16:
                lm = self._predict(frame, box)
                if self._plausible(lm, box):
                    face = FaceDetection(box=box, landmarks=lm, score=head.score)
                    self._tracked = [face] + self._tracked[1:]
                    return [face]
            self._tracked = []  # lost: search the whole frame now (the speaker's features need it)
        h, w = frame.shape[:2]
        boxes: list[tuple[np.ndarray, float]]
        if not self._tracked or self._since + 1 >= self.redetect_every:
            boxes = self._hog(frame)
            self._since = 0
        else:
            boxes = [(self._box_from_landmarks(f.landmarks, self._box_map), f.score) for f in self._tracked]
            self._since += 1
        faces = []
        for box, score in boxes:
            box = np.clip(box, 0, [w, h, w, h])
            if box[2] - box[0] < 16 or box[3] - box[1] < 16:
                continue
            lm = self._predict(frame, box)
            if not self._plausible(lm, box):
                continue
            if self._since == 0:  # a detector box: learn how it sits relative to the landmarks
                self._box_map = self._calibrate_box(lm, box)
            faces.append(FaceDetection(box=box, landmarks=lm, score=score))
        faces.sort(key=lambda f: -f.width)
        faces = faces[: self.max_faces]
        if not faces and self._tracked:  # lost while tracking: try the detector once more now
            self._tracked = []
            return self(frame)
        self._tracked = faces
        return faces

    @staticmethod
    def _lm_frame(lm: np.ndarray) -> tuple[np.ndarray, float]:
        lo, hi = lm.min(axis=0), lm.max(axis=0)
        return 0.5 * (lo + hi), float(max(hi[0] - lo[0], hi[1] - lo[1]))

    @classmethod
    def _calibrate_box(cls, lm: np.ndarray, box: np.ndarray) -> np.ndarray:
        """(dx, dy, ratio): the detector box's centre offset and size relative to the landmarks' extent."""
        c, size = cls._lm_frame(lm)
        bc = 0.5 * (box[:2] + box[2:])
        return np.array([(bc[0] - c[0]) / size, (bc[1] - c[1]) / size, (box[2] - box[0]) / size])

    @classmethod
    def _box_from_landmarks(cls, lm: np.ndarray, box_map: np.ndarray) -> np.ndarray:
        """The box the detector would give for these landmarks (mapping learnt at the last detection),
        so the shape predictor sees the same framing on tracked frames as on detected ones."""
        c, size = cls._lm_frame(lm)
        centre = c + box_map[:2] * size
        half = 0.5 * box_map[2] * size
        return np.array([centre[0] - half, centre[1] - half, centre[0] + half, centre[1] + half])

    @staticmethod
    def _plausible(lm: np.ndarray, box: np.ndarray) -> bool:
        """Reject landmark sets that collapsed (a tracked box that slid off the face)."""
        size = box[2] - box[0]
        spread = lm.max(axis=0) - lm.min(axis=0)
        if not np.isfinite(lm).all() or spread.min() < 0.3 * size:
            return False
        iod = np.linalg.norm(lm[RIGHT_EYE].mean(0) - lm[LEFT_EYE].mean(0))
        return bool(iod > 0.15 * size)
