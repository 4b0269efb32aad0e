"""Frames in, face states out: detector -> landmark fit -> One-Euro smoothing (no devices).

:class:`FaceTracker` turns one RGB frame and its time stamp into a :class:`TrackedFrame`: the
faces' boxes and landmarks, the fitted speaker state of the largest face in the reaction
model's own units (``state`` (n_au + 6,): AU intensity / scale, jaw axis-angle, head rotation;
:mod:`holo_viewer.reaction.features`), its FLAME parameters, the head's 3-D position relative
to the webcam, and every face's eye midpoint (for :class:`~holo_viewer.tracking.viewer.ViewerTracker`).

When the face is lost the speaker state holds for ``hold_s`` and then decays to neutral
(time constant ``decay_s``); ``found`` says which frames had a face.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..validation import check_finite_scalar
from .filters import OneEuroConfig, OneEuroFilter
from .fit import TrackerFitConfig, fit_landmarks
from .head_model import LandmarkHeadModel
from .landmarks import FaceDetection, LandmarkDetector, check_frame
from .viewer import viewer_position, webcam_intrinsics

__all__ = ["TrackerConfig", "TrackedFrame", "FaceTracker"]


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of :class:`FaceTracker`.

    ``hfov_deg``: the camera's horizontal field of view (intrinsics); ``smoothing``: One-Euro
    settings of the state (None = raw fits); ``hold_s``/``decay_s``: behaviour when the face is
    lost; ``redetect_every``: HOG detector period in frames (boxes are tracked in between); ``fast_fit``:
    the fit's compiled steps (:mod:`.fit_fast`) or its numpy reference.
    """

    hfov_deg: float = 60.0
    fit: TrackerFitConfig = field(default_factory=TrackerFitConfig)
    smoothing: OneEuroConfig | None = field(default_factory=lambda: OneEuroConfig(min_cutoff=2.0, beta=1.0))
    hold_s: float = 0.3
    decay_s: float = 0.5
    redetect_every: int = 10
    detect_width: int = 640
    #: the landmark fit's compiled steps (holo_viewer.tracking.fit_fast; False: the numpy reference)
    fast_fit: bool = True
    #: dlib in a child process (LandmarkDetector(process=True): the same landmarks, this process's GIL free
    #: meanwhile; the live loop's tracker); FaceTracker.close() stops it
    detector_process: bool = False

    def __post_init__(self) -> None:
        check_finite_scalar(self.hfov_deg, "hfov_deg", low=1.0, high=170.0)
        check_finite_scalar(self.hold_s, "hold_s", low=0.0)
        check_finite_scalar(self.decay_s, "decay_s", low=0.0, low_open=True)


@dataclass(frozen=True)
class TrackedFrame:
    """What the tracker saw in one frame.

    Attributes
    ----------
    time_s : float
    found : bool                    a face was fitted in this frame
    faces : list of FaceDetection   all faces, largest first
    state : numpy.ndarray, shape (n_au + 6,)  speaker state (smoothed; held/decayed when lost)
    params : numpy.ndarray, shape (n_params,) the raw fit of the largest face (NaN when lost)
    head_position : numpy.ndarray, shape (3,) head root joint in webcam coordinates (m; NaN when lost)
    eye_positions : numpy.ndarray, shape (F, 3) every face's eye midpoint in webcam coordinates (m)
    rms_px : float                  landmark residual of the fit (NaN when lost)
    detect_ms, fit_ms : float       time spent detecting and fitting
    all_faces : bool                every face was looked for (False: ``speaker_only``, the largest only)
    """

    time_s: float
    found: bool
    faces: list[FaceDetection]
    state: np.ndarray
    params: np.ndarray
    head_position: np.ndarray
    eye_positions: np.ndarray
    rms_px: float
    detect_ms: float
    fit_ms: float
    all_faces: bool = True


class FaceTracker:
    """Track the speaker's face state in a frame sequence (see the module docstring).

    Parameters
    ----------
    config : TrackerConfig
    model : FlameModel, optional   the head (default: the default head)
    au_map : AUMap, optional       (default: the default head's)
    detector : callable, optional  frame -> list of FaceDetection (default: :class:`LandmarkDetector`)
    """

    def __init__(self, config: TrackerConfig = TrackerConfig(), model: Any = None, au_map: Any = None,
                 detector: Any = None) -> None:
        from ..flame.default_head import load_default_model
        from ..flame.expressions import default_au_map

        self.config = config
        self.au_map = au_map if au_map is not None else default_au_map()
        self.head = LandmarkHeadModel(model if model is not None else load_default_model(), self.au_map)
        self.detector = detector if detector is not None else LandmarkDetector(
            redetect_every=config.redetect_every, detect_width=config.detect_width, process=config.detector_process)
        self.n_au = self.head.n_au
        self.state_dim = self.n_au + 6
        self._smooth = None if config.smoothing is None else OneEuroFilter(self.state_dim, config.smoothing)
        self.reset()

    def reset(self) -> None:
        """Forget the previous frames."""
        self._prev: np.ndarray | None = None
        self._state = np.zeros(self.state_dim)
        self._last_found: float | None = None
        self._t: float | None = None
        if self._smooth is not None:
            self._smooth.reset()
        if hasattr(self.detector, "reset"):
            self.detector.reset()

    def close(self) -> None:
        """Stop the detector's child process, if any (``TrackerConfig.detector_process``)."""
        if hasattr(self.detector, "close"):
            self.detector.close()

    def state_from_params(self, params: np.ndarray) -> np.ndarray:
        """Reaction state (n_au + 6,) of fitted parameters: AU state, jaw [pitch, 0, 0], rotation."""
        aus, jaw, rot, _ = self.head.split(params)
        return np.concatenate([aus, [jaw, 0.0, 0.0], rot])

    def __call__(self, frame: np.ndarray, time_s: float, speaker_only: bool = False) -> TrackedFrame:
        """Track one RGB frame (H, W, 3) taken at ``time_s`` seconds.

        ``speaker_only``: the speaker (the largest tracked face) alone, without searching for faces
        (:meth:`LandmarkDetector.__call__`; a detector without that option looks at every face): its state
        as on any frame, ``faces``/``eye_positions`` that face only, ``all_faces`` False.
        """
        frame = check_frame(frame)
        t = check_finite_scalar(time_s, "time_s")
        h, w = frame.shape[:2]
        K = webcam_intrinsics(w, h, self.config.hfov_deg)
        t0 = time.perf_counter()
        speaker_only = bool(speaker_only) and isinstance(self.detector, LandmarkDetector)
        faces = list(self.detector(frame, speaker_only=True) if speaker_only else self.detector(frame))
        t1 = time.perf_counter()
        nan3 = np.full(3, np.nan)
        params = np.full(self.head.n_params, np.nan)
        rms = math.nan
        found = bool(faces)
        if found:
            fit = fit_landmarks(self.head, faces[0].landmarks, K, prev=self._prev, config=self.config.fit,
                               fast=self.config.fast_fit)
            params, rms = fit.params, fit.rms_px
            self._prev = params
            raw = self.state_from_params(params)
            self._state = raw if self._smooth is None else self._smooth(raw, t)
            self._last_found = t
        else:
            self._prev = None  # cold start when the face comes back
            if self._last_found is None or t - self._last_found > self.config.hold_s:
                dt = 0.0 if self._t is None else max(0.0, t - self._t)
                self._state = self._state * math.exp(-dt / self.config.decay_s)
            if self._smooth is not None:
                self._smooth.reset(self._state, t)
        t2 = time.perf_counter()
        self._t = t
        yaw = float(params[self.n_au + 2]) if found else 0.0
        eyes = []
        for i, f in enumerate(faces):
            eyes.append(viewer_position(f.landmarks, K, yaw_rad=yaw if i == 0 else 0.0))
        return TrackedFrame(time_s=t, found=found, faces=faces, state=self._state.copy(), params=params,
                            head_position=params[self.n_au + 4:] if found else nan3,
                            eye_positions=np.array(eyes).reshape(-1, 3), rms_px=rms,
                            detect_ms=1000 * (t1 - t0), fit_ms=1000 * (t2 - t1), all_faces=not speaker_only)

    def flame_params(self, states: np.ndarray) -> dict[str, np.ndarray]:
        """GaussianAvatars-keyed arrays (``expr``, ``jaw_pose``, ``rotation``) of states (T, n_au + 6)."""
        from ..reaction.features import flame_from_state

        s = np.asarray(states, dtype=np.float64)
        if s.ndim != 2 or s.shape[1] != self.state_dim:
            raise InputError(f"states: expected shape (T, {self.state_dim}), found {s.shape}")
        return flame_from_state(s, self.au_map)
