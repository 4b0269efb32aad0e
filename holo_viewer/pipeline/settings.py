"""Settings and results of the pipeline (pure data, no stage code): what drives the face
(:class:`FaceControls`), how the cameras look (:class:`ViewSettings`), one streamed frame and the
streaming report; plus FLAME sequence helpers. Re-exported by :mod:`holo_viewer.pipeline`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
import numpy.typing as npt

from ..display.cameras import VIEWER_ANGLE_LIMIT_DEG
from ..errors import InputError
from ..flame.expressions import EXPRESSION_NAMES_KNOWN, PAIN_RANGE
from ..flame.params import FRAME_KEYS, FlameParams, check_expr, check_jaw_pose
from ..validation import check_array, check_finite_scalar
from .stages import StageTimings

__all__ = ["FLAME_KEYS", "FlameFrame", "FaceControls", "ViewSettings", "FrameResult", "StreamReport", "apply_frame",
           "flame_sequence_frames"]

#: per-frame FLAME parameter keys and widths (:data:`holo_viewer.flame.params.FRAME_KEYS`)
FLAME_KEYS = FRAME_KEYS

#: one frame of a FLAME sequence: keys of :data:`FLAME_KEYS` (+ ``shape``, ``pain``, ``dynamic_offset``)
#: to 1-D arrays (``expr`` (n_expr,), poses (3,) / (6,), ``dynamic_offset`` (V, 3))
FlameFrame = Mapping[str, npt.ArrayLike]


# =============================================================================== settings


def _vec(x: npt.ArrayLike, name: str, n: int | None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if n is not None and a.shape[0] != n:
        raise InputError(f"{name}: expected {n} values, found {a.shape[0]}")
    check_array(a, name, ("N",))
    a.setflags(write=False)
    return a


def _zeros(n: int) -> Callable[[], np.ndarray]:
    return lambda: np.zeros(n)


@dataclass(frozen=True, eq=False)
class FaceControls:
    """What drives the face: FLAME parameters plus named expressions and pain.

    The final FLAME parameters (the pipeline's ``params`` stage) are::

        expr     = expr + sum_i named_expression(name_i, w_i) + pain_expression(pain)
        jaw_pose = jaw_pose + sum_i jaw_for_expression(name_i, w_i)

    so named expressions and pain *add* to the base coefficients (``export-mesh --expr`` adds
    the same way). Pain has one meaning: ``pain_expression(pain)``, the PSPI-calibrated pain
    face, with no extra jaw rotation. ``named=(("pain", p),)`` is accepted as another
    spelling of ``pain=p`` and stored as ``pain`` (giving both, with different values, is an
    error). Arrays are given as any array-like and stored as read-only float64 numpy arrays.

    Attributes
    ----------
    expr : numpy.ndarray
        (k,) base expression coefficients, k <= the model's n_expr (zero-padded), each within
        ``+-flame.params.EXPR_LIMIT``.
    shape : numpy.ndarray
        (k,) identity coefficients (zero-padded); empty or all zero = the avatar's own
        identity (``avatar.identity["shape"]``) when it has one.
    jaw_pose : numpy.ndarray
        (3,) axis-angle, radians; opening (x) in ``flame.params.JAW_LIMITS_DEG`` = [-45, 90] deg.
    rotation, neck_pose : numpy.ndarray
        (3,) axis-angle, radians.
    translation : numpy.ndarray
        (3,) metres.
    eyes_pose : numpy.ndarray
        (6,) axis-angle of both eyes, radians.
    named : tuple of (str, float)
        Named expressions (``flame.expressions.EXPRESSION_NAMES_KNOWN``) and intensities in
        [0, 1], e.g. ``(("smile", 0.8),)``; never contains "pain" (see above).
    pain : float
        Pain intensity in ``flame.expressions.PAIN_RANGE`` = [0, 1].
    dynamic_offset : numpy.ndarray or None
        (V, 3) per-frame vertex offsets in metres (GaussianAvatars ``dynamic_offset``), added to
        the avatar's ``static_offset``.
    """

    expr: np.ndarray = field(default_factory=_zeros(0))
    shape: np.ndarray = field(default_factory=_zeros(0))
    jaw_pose: np.ndarray = field(default_factory=_zeros(3))
    rotation: np.ndarray = field(default_factory=_zeros(3))
    neck_pose: np.ndarray = field(default_factory=_zeros(3))
    eyes_pose: np.ndarray = field(default_factory=_zeros(6))
    translation: np.ndarray = field(default_factory=_zeros(3))
    named: tuple[tuple[str, float], ...] = ()
    pain: float = 0.0
    dynamic_offset: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.dynamic_offset is not None:
            off = np.array(self.dynamic_offset, dtype=np.float64)
            off = off.reshape(off.shape[-2:]) if off.ndim == 3 and off.shape[0] == 1 else off
            check_array(off, "dynamic_offset", ("V", 3))
            off.setflags(write=False)
            object.__setattr__(self, "dynamic_offset", off)
        for key, width in (("expr", None), ("shape", None), ("jaw_pose", 3), ("rotation", 3), ("neck_pose", 3),
                           ("translation", 3), ("eyes_pose", 6)):
            value = getattr(self, key)
            object.__setattr__(self, key, _vec(np.zeros(width or 0) if value is None else value, key, width))
        check_expr(self.expr, "expr")
        check_jaw_pose(self.jaw_pose, "jaw_pose")
        lo, hi = PAIN_RANGE
        pain = check_finite_scalar(self.pain, "pain", low=lo, high=hi)
        named, named_pain = [], None
        for item in self.named:
            try:
                name, w = item
            except (TypeError, ValueError) as exc:
                raise InputError(f"named: expected (name, intensity) pairs, found {item!r}") from exc
            if name not in EXPRESSION_NAMES_KNOWN:
                raise InputError(f"named: expected an expression in {EXPRESSION_NAMES_KNOWN}, found {name!r}")
            w = check_finite_scalar(w, f"named[{name!r}]", low=lo, high=hi)
            if name == "pain":
                if named_pain is not None and named_pain != w:
                    raise InputError(f"named: 'pain' given twice ({named_pain} and {w})")
                named_pain = w
            else:
                named.append((str(name), w))
        if named_pain is not None:
            if pain not in (0.0, named_pain):
                raise InputError(f"pain: given twice with different values, pain={pain} and named pain {named_pain} "
                                 "(they mean the same; give one)")
            pain = named_pain
        object.__setattr__(self, "named", tuple(named))
        object.__setattr__(self, "pain", pain)

    def replace(self, **changes: object) -> "FaceControls":
        """A copy with some fields replaced."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    def with_named(self, name: str, intensity: float) -> "FaceControls":
        """A copy with the named expression ``name`` set to ``intensity`` (0 removes it; "pain" sets ``pain``)."""
        if name == "pain":
            return self.replace(pain=float(intensity))
        rest = tuple((n, w) for n, w in self.named if n != name)
        return self.replace(named=rest + (((name, float(intensity)),) if intensity > 0 else ()))

    def with_expr_component(self, index: int, value: float) -> "FaceControls":
        """A copy with base expression coefficient ``index`` set to ``value``."""
        if index < 0:
            raise InputError(f"expr index: expected >= 0, found {index}")
        e = np.zeros(max(index + 1, self.expr.shape[0]))
        e[: self.expr.shape[0]] = self.expr
        e[index] = value
        return self.replace(expr=e)


@dataclass(frozen=True)
class ViewSettings:
    """How the 48 quilt cameras look at the head (Algorithm 1 inputs besides the calibration).

    Attributes
    ----------
    viewer_distance : float or None
        Viewer's eye distance from the panel in metres (sets the fov, ``display.cameras``);
        None = the calibration's default.
    view_cone : float or None
        Total view cone in degrees; None = the calibration's ``viewCone``.
    viewer_angle : float
        Horizontal angle (degrees) of a tracked viewer, within +-``display.cameras.VIEWER_ANGLE_LIMIT_DEG``
        (60); shifts the cone centre.
    tile_scale : float
        Tile size relative to the calibration's quilt tile (e.g. 0.25 for a quick thumbnail quilt).
    framing_margin : float
        Focal-plane half-height = ``framing_margin`` x half the head's bounding-box height.
    blend : bool
        Two-view blending in the lenticular interleave.
    """

    viewer_distance: float | None = None
    view_cone: float | None = None
    viewer_angle: float = 0.0
    tile_scale: float = 1.0
    framing_margin: float = 1.08
    blend: bool = False

    def __post_init__(self) -> None:
        if self.viewer_distance is not None:
            check_finite_scalar(self.viewer_distance, "viewer_distance", low=0.05, high=20.0)
        if self.view_cone is not None:
            check_finite_scalar(self.view_cone, "view_cone", low=0.0, high=120.0, low_open=True)
        lim = VIEWER_ANGLE_LIMIT_DEG  # the cameras' own limit (display/cameras.py)
        check_finite_scalar(self.viewer_angle, "viewer_angle", low=-lim, high=lim)
        check_finite_scalar(self.tile_scale, "tile_scale", low=0.02, high=4.0)
        check_finite_scalar(self.framing_margin, "framing_margin", low=0.2, high=5.0)


# =============================================================================== results


@dataclass
class FrameResult:
    """One rendered frame: what was asked for and how long each stage took."""

    index: int
    timings: StageTimings
    quilt: np.ndarray | None = None
    native: np.ndarray | None = None
    views: np.ndarray | None = None


@dataclass
class StreamReport:
    """Outcome of :meth:`Pipeline.stream`.

    Attributes
    ----------
    n_frames : int
        Frames in the input sequence.
    rendered : list of int
        Indices of the frames that were computed (in order).
    dropped : list of int
        Frames skipped because the pipeline was behind schedule (policy ``"drop"``).
    held : int
        Display slots that showed an older frame again (one per dropped frame, plus the
        slots a late frame overran in policy ``"all"``).
    late : list of int
        Frames finished after their deadline.
    frame_seconds : list of float
        Wall time per computed frame.
    budget : float
        Seconds per frame (1 / fps).
    stage_seconds : StageTimings
        Total seconds per stage over all computed frames.
    """

    n_frames: int
    budget: float
    policy: str
    rendered: list[int] = field(default_factory=list)
    dropped: list[int] = field(default_factory=list)
    late: list[int] = field(default_factory=list)
    held: int = 0
    frame_seconds: list[float] = field(default_factory=list)
    stage_seconds: StageTimings = field(default_factory=StageTimings)

    @property
    def achieved_fps(self) -> float:
        """Computed frames per second of wall time."""
        t = sum(self.frame_seconds)
        return len(self.frame_seconds) / t if t > 0 else float("inf")

    def summary(self) -> str:
        return (f"{self.n_frames} frames at budget {self.budget * 1e3:.1f} ms ({self.policy}): "
                f"{len(self.rendered)} rendered, {len(self.dropped)} dropped, {self.held} held, "
                f"{len(self.late)} late; {self.achieved_fps:.2f} computed frames/s")



# =============================================================================== sequences


def apply_frame(base: FaceControls, frame: FlameFrame, index: int = 0) -> FaceControls:
    """``base`` with the FLAME parameters of one sequence frame (see :func:`flame_sequence_frames`)."""
    changes: dict[str, Any] = {}
    for key, value in frame.items():
        if key in FLAME_KEYS or key == "shape":
            changes[key] = np.asarray(value, dtype=np.float64).reshape(-1)
        elif key == "pain":
            changes["pain"] = float(np.asarray(value).reshape(-1)[0])
        elif key == "dynamic_offset":
            changes["dynamic_offset"] = np.asarray(value, dtype=np.float64).reshape(-1, 3)
        else:
            raise InputError(f"frame {index}: unknown key {key!r}; expected FLAME keys {sorted(FLAME_KEYS)}, "
                             f"'shape' or 'pain'")
    return base.replace(**changes)


def flame_sequence_frames(params: FlameParams | Mapping[str, Any], *,
                          source: str = "flame params") -> list[dict[str, np.ndarray]]:
    """Split a FLAME sequence into frames (dicts of 1-D arrays, as :func:`apply_frame` takes).

    ``params`` is a :class:`~holo_viewer.flame.params.FlameParams` or its npz form (a mapping in
    the flame_param.npz layout: per-frame keys with T rows). Per-frame keys are those of
    :data:`FLAME_KEYS` (and ``pain`` (T,) when present); keys left out keep the controls' values
    when the frames are applied. ``shape`` ((n,) or (1, n)) and ``static_offset`` are per
    sequence. Raises InputError naming the key when the frame counts disagree, a value is not a
    number, or there are no frames.
    """
    if isinstance(params, FlameParams):
        params = params.as_dict()

    def floats(key: str) -> np.ndarray:
        a = np.asarray(params[key])
        if a.dtype.kind not in "biuf":
            raise InputError(f"{source}: {key}: expected numbers, found dtype {a.dtype}")
        return a.astype(np.float64)

    T = None
    seq: dict[str, np.ndarray] = {}
    for key in list(FLAME_KEYS) + ["pain"]:
        if key not in params:
            continue
        a = floats(key)
        width = FLAME_KEYS.get(key)
        if key == "pain":
            a = a.reshape(-1, 1)
        elif a.ndim == 1:
            a = a[None]
        if a.ndim != 2 or (width is not None and a.shape[1] != width):
            raise InputError(f"{source}: {key}: expected shape (T, {width or 'n'}), found {np.shape(params[key])}")
        if not np.all(np.isfinite(a)):
            raise InputError(f"{source}: {key}: contains NaN/inf")
        if T is None:
            T = a.shape[0]
        elif a.shape[0] != T:
            raise InputError(f"{source}: {key}: expected {T} frames (as the other keys), found {a.shape[0]}")
        seq[key] = a
    if T is None:
        raise InputError(f"{source}: expected at least one of the keys {sorted(FLAME_KEYS)}, found "
                         f"{sorted(params)}")
    if T == 0:
        raise InputError(f"{source}: expected at least one frame, found 0")
    dyn = params.get("dynamic_offset") if isinstance(params, Mapping) else None
    if dyn is not None:
        dyn = floats("dynamic_offset")
        if dyn.ndim != 3 or dyn.shape[0] != T or dyn.shape[2] != 3:
            raise InputError(f"{source}: dynamic_offset: expected shape ({T}, V, 3), found {dyn.shape}")
    shape = None
    if "shape" in params:
        shape = floats("shape").reshape(-1)
    frames = []
    for t in range(T):
        fr = {k: (v[t, 0] if k == "pain" else v[t]) for k, v in seq.items()}
        if shape is not None:
            fr["shape"] = shape
        if dyn is not None:
            fr["dynamic_offset"] = dyn[t]
        frames.append(fr)
    return frames
