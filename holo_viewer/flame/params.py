"""FLAME parameters: the per-frame keys (listed once), their limits, and the sequence type.

A FLAME *frame* is a dict of 1-D arrays keyed by :data:`FRAME_KEYS` (what
:class:`holo_viewer.pipeline.FaceControls` and ``FlameModel.forward`` take). A FLAME
*sequence* is a :class:`FlameParams`: GaussianAvatars' ``flame_param.npz`` layout,
per-frame keys with T rows plus the per-subject ``shape`` and ``static_offset``;
``FlameParams.as_dict()`` is its npz form and ``FlameParams.from_mapping`` reads it back.

Limits (checked where parameters enter the pipeline, :class:`~holo_viewer.pipeline.FaceControls`,
and by ``holo-viewer export-mesh``):

* expression coefficients: ``|psi_k| <= EXPR_LIMIT`` (10, in units of the component's standard
  deviation: FLAME faces stay plausible within about +-3, beyond +-10 the head is torn apart; the
  default head's coefficient 1 is full action-unit intensity);
* jaw: rotation angle ``|jaw_pose| <= 90 deg`` and opening (x component) in
  ``JAW_LIMITS_DEG = (-45, 90)`` degrees, the range of ``export-mesh --jaw``.

Pure numpy; no file I/O (``holo_viewer.avatar.load_flame_params`` reads the npz).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from ..errors import InputError

__all__ = ["FRAME_KEYS", "IDENTITY_KEYS", "EXPR_LIMIT", "JAW_LIMITS_DEG", "check_expr", "check_jaw_pose",
           "FlameParams"]

#: per-frame FLAME parameters and their widths (None: any width, the model's n_expr), in
#: GaussianAvatars' flame_param.npz order; radians (axis-angle) and metres
FRAME_KEYS: dict[str, int | None] = {"expr": None, "rotation": 3, "neck_pose": 3, "jaw_pose": 3,
                                     "translation": 3, "eyes_pose": 6}
#: per-subject parameters of a sequence
IDENTITY_KEYS: tuple[str, ...] = ("shape", "static_offset")

#: largest |expression coefficient| accepted (the API's and ``export-mesh --expr``'s one limit)
EXPR_LIMIT = 10.0
#: jaw opening (rotation about x, degrees) accepted: closed past rest by 45, open by 90
JAW_LIMITS_DEG = (-45.0, 90.0)


def check_expr(expr: np.ndarray, name: str = "expr") -> np.ndarray:
    """Raise InputError unless every coefficient of ``expr`` (any shape) is finite and within :data:`EXPR_LIMIT`."""
    a = np.asarray(expr, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name}: expected finite expression coefficients, found NaN/inf")
    big = np.flatnonzero(np.abs(a.reshape(-1)) > EXPR_LIMIT)
    if big.size:
        i = int(big[0])
        raise InputError(f"{name}[{i}]: expected an expression coefficient in [-{EXPR_LIMIT:g}, {EXPR_LIMIT:g}], "
                         f"found {a.reshape(-1)[i]:g}")
    return a


def check_jaw_pose(jaw_pose: np.ndarray, name: str = "jaw_pose") -> np.ndarray:
    """Raise InputError unless the (3,) axis-angle jaw is within :data:`JAW_LIMITS_DEG` (radians in)."""
    j = np.asarray(jaw_pose, dtype=np.float64).reshape(-1)
    if j.shape != (3,) or not np.all(np.isfinite(j)):
        raise InputError(f"{name}: expected 3 finite axis-angle values (radians), found {j.tolist()}")
    lo, hi = JAW_LIMITS_DEG
    angle, opening = math.degrees(float(np.linalg.norm(j))), math.degrees(float(j[0]))
    if angle > max(-lo, hi) + 1e-9 or not lo - 1e-9 <= opening <= hi + 1e-9:
        raise InputError(f"{name}: expected a jaw opening (x rotation) in [{lo:g}, {hi:g}] deg and a rotation of at "
                         f"most {max(-lo, hi):g} deg, found {opening:.4g} deg opening, {angle:.4g} deg in all")
    return j


@dataclass(frozen=True, eq=False)
class FlameParams:
    """A FLAME parameter sequence of T frames (GaussianAvatars ``flame_param.npz``; float32 arrays).

    Attributes
    ----------
    shape : numpy.ndarray
        (n_shape,) identity coefficients.
    expr : numpy.ndarray
        (T, n_expr).
    rotation, neck_pose, jaw_pose, translation : numpy.ndarray
        (T, 3) axis-angle (radians) / metres.
    eyes_pose : numpy.ndarray
        (T, 6).
    static_offset : numpy.ndarray or None
        (1, V, 3) per-vertex rest offsets, metres.
    dynamic_offset : numpy.ndarray or None
        (T, V, 3) per-frame offsets, metres.
    """

    shape: np.ndarray
    expr: np.ndarray
    rotation: np.ndarray
    neck_pose: np.ndarray
    jaw_pose: np.ndarray
    translation: np.ndarray
    eyes_pose: np.ndarray
    static_offset: np.ndarray | None = None
    dynamic_offset: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.expr.shape[0])

    def __len__(self) -> int:
        return self.n_frames

    def identity(self) -> dict[str, np.ndarray]:
        """Per-subject parameters (``shape``, ``static_offset``) for :class:`~holo_viewer.avatar.RiggedAvatar`."""
        out = {"shape": self.shape}
        if self.static_offset is not None:
            out["static_offset"] = self.static_offset
        return out

    def frame(self, index: Any) -> dict[str, np.ndarray]:
        """Per-frame keyword arguments for ``RiggedAvatar.pose`` (index: int, slice or index array)."""
        idx = np.atleast_1d(np.arange(self.n_frames)[index])
        out = {k: getattr(self, k)[idx] for k in FRAME_KEYS}
        if self.dynamic_offset is not None:
            out["dynamic_offset"] = self.dynamic_offset[idx]
        return out

    def __iter__(self) -> Iterator[dict[str, np.ndarray]]:
        for i in range(self.n_frames):
            yield self.frame(i)

    def as_dict(self) -> dict[str, np.ndarray]:
        """The ``flame_param.npz`` arrays (keys with a value)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    @classmethod
    def zeros(cls, n_frames: int, n_expr: int, n_shape: int = 0) -> "FlameParams":
        """T frames of the neutral face (every key present, float32 zeros)."""
        z = {k: np.zeros((n_frames, n_expr if w is None else w), np.float32) for k, w in FRAME_KEYS.items()}
        return cls(shape=np.zeros(n_shape, np.float32), **z)

    @classmethod
    def from_frames(cls, shape: np.ndarray | None = None, **per_frame: np.ndarray) -> "FlameParams":
        """A sequence from some per-frame arrays (T rows each); the missing keys are zeros.

        Raises InputError naming the key when widths or frame counts disagree.
        """
        unknown = sorted(set(per_frame) - set(FRAME_KEYS) - {"static_offset", "dynamic_offset"})
        if unknown or "expr" not in per_frame:
            raise InputError(f"FLAME frames: expected 'expr' and keys of {sorted(FRAME_KEYS)}, found {sorted(per_frame)}")
        expr = np.asarray(per_frame["expr"], dtype=np.float32)
        if expr.ndim != 2:
            raise InputError(f"expr: expected shape (T, n_expr), found {expr.shape}")
        base = cls.zeros(expr.shape[0], expr.shape[1], 0 if shape is None else int(np.size(shape)))
        out = base.as_dict()
        for key, value in per_frame.items():
            a = np.asarray(value, dtype=np.float32)
            want = FRAME_KEYS.get(key)
            if key in FRAME_KEYS and a.shape != (expr.shape[0], expr.shape[1] if want is None else want):
                raise InputError(f"{key}: expected shape ({expr.shape[0]}, {want or expr.shape[1]}), found {a.shape}")
            out[key] = a
        if shape is not None:
            out["shape"] = np.asarray(shape, dtype=np.float32).reshape(-1)
        return cls(**out)

    def save(self, path: str | os.PathLike) -> Path:
        """Write ``flame_param.npz`` (atomic)."""
        from ..fileio import save_npz

        return save_npz(path, **self.as_dict())

    def __getitem__(self, key: str) -> np.ndarray:
        """``params["expr"]``: the npz form's array of ``key`` (KeyError if absent)."""
        value = getattr(self, key, None) if key in {f.name for f in fields(self)} else None
        if value is None:
            raise KeyError(key)
        return value

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and key in self.as_dict()

    def keys(self) -> list[str]:
        """Keys of the npz form."""
        return list(self.as_dict())


def as_mapping(params: "FlameParams | Mapping[str, Any]") -> Mapping[str, Any]:
    """The npz form of a sequence given as :class:`FlameParams` or as a mapping."""
    return params.as_dict() if isinstance(params, FlameParams) else params
