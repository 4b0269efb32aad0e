"""Webcam face position -> viewer angle and distance for Algorithm 1's cameras (pure math + one JSON).

Frames (docs/design.md "Webcam → viewer angle and distance"):

* **panel frame** = the display world frame: origin at the panel centre, +x to the right of a
  viewer facing the panel, +y up, +z from the panel toward the viewer (FLAME's frame, metres).
* **webcam**: a pinhole with intrinsics from its horizontal field of view
  (:func:`webcam_intrinsics`). Mounted upright and facing the viewer, its OpenCV axes are
  ``x_cam = -x_panel, y_cam = -y_panel, z_cam = +z_panel``; :class:`WebcamMount` adds the measured
  position and tilt (a small JSON the user writes once, :meth:`WebcamMount.load`).
* **viewer**: the midpoint of the eyes. Depth from the inter-pupillary distance prior
  (63 mm; corrected by ``cos(yaw)`` of the fitted head when known): ``z = f IPD cos(yaw) / iod_px``.

``viewer_angle_deg = atan2(x, z)`` (positive = viewer to the right, the same sign as
``display.cameras.view_angles``: view 0 is the leftmost camera) and ``viewer_distance_m = |p|``.

:class:`ViewerTracker` picks the nearest face (or centres the cone on all faces in group
mode), smooths with a One-Euro filter, holds the last pose for ``hold_s`` when the face is lost,
then eases back to the default pose. Each tracked pose carries its smoothed rate and the filter's
lag, so :meth:`ViewerPose.predicted` can extrapolate it to when a frame rendered for it is shown.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Sequence

import numpy as np

from ..errors import InputError, TrackingError
from ..fileio import read_json
from ..validation import check_array, check_finite_scalar, check_json_number
from .filters import OneEuroConfig, OneEuroFilter, _alpha

__all__ = ["webcam_intrinsics", "WebcamMount", "viewer_position", "ViewerPose", "ViewerTrackerConfig",
           "ViewerTracker", "IPD_M", "MAX_LEAD_S"]

#: adult mean inter-pupillary distance prior (metres)
IPD_M = 0.063
_CAM_TO_PANEL = np.diag([-1.0, -1.0, 1.0])


def webcam_intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """(3, 3) K of a webcam from its horizontal field of view: square pixels, centred principal point."""
    w, h = int(width), int(height)
    if w < 1 or h < 1:
        raise InputError(f"width, height: expected positive, found {width} x {height}")
    hfov = check_finite_scalar(hfov_deg, "hfov_deg", low=1.0, high=170.0)
    f = 0.5 * w / math.tan(math.radians(hfov) / 2)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


def _euler_xyz(deg: Sequence[float]) -> np.ndarray:
    rx, ry, rz = (math.radians(float(a)) for a in deg)
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rx @ Ry @ Rz


@dataclass(frozen=True)
class WebcamMount:
    """Where the webcam sits on the panel.

    JSON (all keys optional)::

        {"position_m": [0.0, 0.13, 0.0],   # webcam optical centre in the panel frame
         "rotation_deg": [-5.0, 0.0, 0.0], # extra tilt, XYZ Euler in the panel frame (x: pitch up)
         "hfov_deg": 60.0,                 # the webcam's horizontal field of view
         "mirrored": false}                # true if the webcam delivers mirror images

    Attributes
    ----------
    position_m : tuple of 3 float
    rotation_deg : tuple of 3 float
    hfov_deg : float
    mirrored : bool
    """

    position_m: tuple[float, float, float] = (0.0, 0.13, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hfov_deg: float = 60.0
    mirrored: bool = False

    def __post_init__(self) -> None:
        pos = tuple(float(v) for v in np.asarray(check_array(self.position_m, "position_m", (3,))))
        rot = tuple(float(v) for v in np.asarray(check_array(self.rotation_deg, "rotation_deg", (3,))))
        if max(abs(v) for v in pos) > 5.0:
            raise InputError(f"position_m: expected within 5 m of the panel centre, found {pos}")
        object.__setattr__(self, "position_m", pos)
        object.__setattr__(self, "rotation_deg", rot)
        object.__setattr__(self, "hfov_deg", check_finite_scalar(self.hfov_deg, "hfov_deg", low=1.0, high=170.0))
        object.__setattr__(self, "mirrored", bool(self.mirrored))

    @classmethod
    def load(cls, path: str | os.PathLike) -> "WebcamMount":
        """Read the JSON described in the class docstring."""
        p = Path(path)
        data = read_json(p, TrackingError, "webcam mount JSON")
        if not isinstance(data, dict):
            raise TrackingError(f"{p}: expected a JSON object, found {type(data).__name__}")
        unknown = sorted(set(data) - {"position_m", "rotation_deg", "hfov_deg", "mirrored"})
        if unknown:
            raise TrackingError(f"{p}: unknown keys {unknown}; expected position_m, rotation_deg, hfov_deg, mirrored")
        try:  # JSON types checked first: "mirrored": "no" is not True, "60" is not a number
            if "mirrored" in data and not isinstance(data["mirrored"], bool):
                raise InputError(f"mirrored: expected true or false, found {type(data['mirrored']).__name__} "
                                 f"{data['mirrored']!r}")
            for key in ("position_m", "rotation_deg"):
                if key in data:
                    if not isinstance(data[key], list) or len(data[key]) != 3:
                        raise InputError(f"{key}: expected a list of 3 numbers, found {data[key]!r}")
                    for j, v in enumerate(data[key]):
                        check_json_number(v, f"{key}[{j}]")
            if "hfov_deg" in data:
                check_json_number(data["hfov_deg"], "hfov_deg")
            return cls(**data)
        except (InputError, TypeError, ValueError) as exc:
            raise TrackingError(f"{p}: {exc}") from exc

    def to_panel(self, p_cam: np.ndarray) -> np.ndarray:
        """(..., 3) webcam OpenCV coordinates -> panel frame."""
        c = _CAM_TO_PANEL.copy()
        if self.mirrored:
            c[0, 0] = -c[0, 0]
        R = _euler_xyz(self.rotation_deg) @ c
        return np.asarray(p_cam, dtype=np.float64) @ R.T + np.asarray(self.position_m)


def viewer_position(landmarks: np.ndarray, K: np.ndarray, yaw_rad: float = 0.0, ipd_m: float = IPD_M) -> np.ndarray:
    """(3,) eye midpoint in webcam OpenCV coordinates (metres) from 68 landmarks (68, 2).

    Depth ``z = f * ipd * cos(yaw) / iod_px`` (yaw: the head's rotation about its vertical axis,
    e.g. from the landmark fit; 0 if unknown).
    """
    lm = np.asarray(check_array(landmarks, "landmarks", (68, 2)), dtype=np.float64)
    re, le = lm[36:42].mean(0), lm[42:48].mean(0)
    iod = float(np.linalg.norm(re - le))
    if iod < 1.0:
        raise TrackingError(f"landmarks: inter-ocular distance {iod:.2f} px is too small")
    f = 0.5 * (K[0, 0] + K[1, 1])
    z = f * float(ipd_m) * max(math.cos(float(yaw_rad)), 0.3) / iod
    mid = 0.5 * (re + le)
    return np.array([(mid[0] - K[0, 2]) * z / K[0, 0], (mid[1] - K[1, 2]) * z / K[1, 1], z])


#: longest look-ahead of :meth:`ViewerPose.predicted` (seconds): the default smoothing's lag
#: (at most 1 / (2 pi 1 Hz) = 0.16 s) plus a frame's latency stay under it; a stalled frame must
#: not throw the views far ahead of the eyes
MAX_LEAD_S = 0.3
#: ViewerPose.others keeps at most this many faces (group live frames serve up to 6 viewers)
MAX_OTHERS = 5


@dataclass(frozen=True)
class ViewerPose:
    """Viewer angle (degrees, + = right) and distance (metres), and whether a face drove it.

    ``rate``: how fast the smoothed pose moves ((degrees/s, m/s), low-passed), ``lag_s``: how far
    the smoothing trails a steady motion (seconds, per component); zero when no face drives it.
    ``others``: the (angle, distance) of the other faces seen in this webcam frame, unsmoothed,
    nearest first, at most :data:`MAX_OTHERS` (mode ``nearest``: every face but the one the pose
    follows; ``group``: every face, since the pose follows none). Group live frames serve each.
    """

    angle_deg: float
    distance_m: float
    tracked: bool
    rate: tuple[float, float] = (0.0, 0.0)
    lag_s: tuple[float, float] = (0.0, 0.0)
    others: tuple[tuple[float, float], ...] = ()

    def predicted(self, lead_s: float, max_lead_s: float = MAX_LEAD_S) -> "ViewerPose":
        """The pose ``lead_s`` seconds after the webcam frame it came from (e.g. when the frame
        rendered for it will be shown): extrapolated at ``rate`` over the smoothing's lag plus the
        lead, each capped at ``max_lead_s``. Exact for a steady motion once the filter has settled;
        an untracked pose is returned as it is."""
        lead = check_finite_scalar(lead_s, "lead_s")
        cap = check_finite_scalar(max_lead_s, "max_lead_s", low=0.0)
        if not self.tracked:
            return self
        ahead = [min(max(lag + lead, 0.0), cap) for lag in self.lag_s]
        return dataclasses.replace(self, angle_deg=self.angle_deg + self.rate[0] * ahead[0],
                                   distance_m=self.distance_m + self.rate[1] * ahead[1])


@dataclass(frozen=True)
class ViewerTrackerConfig:
    """Settings of :class:`ViewerTracker`.

    ``default_angle_deg``/``default_distance_m``: the pose with nobody tracked; ``hold_s``: how
    long a lost face's pose is held; ``ease_s``: time constant of the return to the default;
    ``mode``: ``"nearest"`` face or ``"group"`` (cone centred on the angular span of all faces,
    mean distance); ``max_angle_deg`` and the distance range clamp the output to what
    ``ViewSettings`` accepts.
    """

    default_angle_deg: float = 0.0
    default_distance_m: float = 0.6
    hold_s: float = 0.5
    ease_s: float = 0.8
    mode: Literal["nearest", "group"] = "nearest"
    max_angle_deg: float = 45.0
    distance_range_m: tuple[float, float] = (0.2, 5.0)
    smoothing: OneEuroConfig = field(default_factory=lambda: OneEuroConfig(min_cutoff=1.0, beta=0.05))

    def __post_init__(self) -> None:
        if self.mode not in ("nearest", "group"):
            raise InputError(f"mode: expected 'nearest' or 'group', found {self.mode!r}")
        check_finite_scalar(self.hold_s, "hold_s", low=0.0)
        check_finite_scalar(self.ease_s, "ease_s", low=0.0, low_open=True)
        check_finite_scalar(self.max_angle_deg, "max_angle_deg", low=0.0, high=60.0)


class ViewerTracker:
    """Smoothed viewer pose from per-frame face positions (see the module docstring)."""

    def __init__(self, mount: WebcamMount = WebcamMount(), config: ViewerTrackerConfig = ViewerTrackerConfig()
                 ) -> None:
        self.mount = mount
        self.config = config
        self._filter = OneEuroFilter(2, config.smoothing)
        self.recentre()

    def recentre(self) -> None:
        """Jump to the default pose and forget the history."""
        c = self.config
        self._pose = np.array([c.default_angle_deg, c.default_distance_m])
        self._filter.reset()
        self._rate = np.zeros(2)
        self._last_seen: float | None = None
        self._t: float | None = None

    def _target(self, positions_panel: np.ndarray) -> tuple[np.ndarray, tuple[tuple[float, float], ...]]:
        """The pose to follow and the other faces (see :class:`ViewerPose`), clamped."""
        c = self.config
        ang = np.clip(np.degrees(np.arctan2(positions_panel[:, 0], positions_panel[:, 2])),
                      -c.max_angle_deg, c.max_angle_deg)
        dist = np.clip(np.linalg.norm(positions_panel, axis=1), *c.distance_range_m)
        order = np.argsort(dist, kind="stable")
        faces = [(float(ang[i]), float(dist[i])) for i in order]
        if c.mode == "nearest":
            return np.array(faces[0]), tuple(faces[1:1 + MAX_OTHERS])
        return np.array([0.5 * (ang.min() + ang.max()), float(dist.mean())]), tuple(faces[:MAX_OTHERS])

    def update(self, positions_cam: np.ndarray, t: float) -> ViewerPose:
        """Pose at time ``t`` (seconds) from the eye midpoints (F, 3) of the faces seen (F may be 0)."""
        c = self.config
        pos = np.asarray(positions_cam, dtype=np.float64).reshape(-1, 3)
        t = check_finite_scalar(t, "t")
        lo, hi = c.distance_range_m
        if len(pos) and np.isfinite(pos).all():
            target, others = self._target(self.mount.to_panel(pos))
            target = np.array([np.clip(target[0], -c.max_angle_deg, c.max_angle_deg), np.clip(target[1], lo, hi)])
            before, was_tracked = self._pose, self._last_seen is not None and self._last_seen == self._t
            self._pose = self._filter(target, t)
            if was_tracked and self._t is not None and t > self._t:
                # the smoothed pose's speed, low-passed at the smoothing's derivative cutoff
                dt = t - self._t
                a = _alpha(np.array(c.smoothing.d_cutoff), dt)
                self._rate = self._rate + a * ((self._pose - before) / dt - self._rate)
            elif not was_tracked:
                self._rate = np.zeros(2)
            self._last_seen = t
            tracked = True
        else:
            tracked = False
            self._rate = np.zeros(2)
            if self._last_seen is None or t - self._last_seen > c.hold_s:
                dt = 0.0 if self._t is None else max(0.0, t - self._t)
                a = 1.0 - math.exp(-dt / c.ease_s)
                default = np.array([c.default_angle_deg, c.default_distance_m])
                self._pose = self._pose + a * (default - self._pose)
                self._filter.reset(self._pose, t)
        self._t = t
        if not tracked:
            return ViewerPose(angle_deg=float(self._pose[0]), distance_m=float(self._pose[1]), tracked=False)
        lag = self._filter.lag_s()
        return ViewerPose(angle_deg=float(self._pose[0]), distance_m=float(self._pose[1]), tracked=True,
                          rate=(float(self._rate[0]), float(self._rate[1])), lag_s=(float(lag[0]), float(lag[1])),
                          others=others)
