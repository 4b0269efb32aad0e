"""The behaviour layers composed on the reaction model's FLAME parameters, frame by frame.

:class:`ListenerBehaviour` takes one frame of the model's output (``expr``, ``jaw_pose``,
``rotation``, ``neck_pose``, ``eyes_pose``, ``translation``) and returns it with

* **pain** (the PSPI face of the pain shown now, :class:`~.layers.PainDynamics`) combined with the
  model's action units by an element-wise maximum in AU space (as the training listeners were
  made), so pain never double-counts and a level change shows at once;
* **blinks** on the eyelid channel: AU43 (default head components ``AU43_L``/``AU43_R``,
  expression columns 22 and 23; coefficient 1 = shut), raised toward 1 by the blink profile:
  ``a + b (1 - a)``;
* **breathing**: ``translation`` y up to ``breath_mm`` (and z a third of it), the head lifting
  ``breath_deg`` in ``neck_pose`` pitch on each inhale;
* **idle sway**: ``neck_pose`` (pitch, yaw, roll) and ``translation`` x, z;
* **gaze**: ``eyes_pose`` (axis-angle per eye, joint 3 = the eye at +x first) turning each eye
  from its rest axis (+z) to the target point, offset by the gaze layer's aversions and
  saccades; the head turns ``head_share`` of the way (in ``neck_pose``, slowly). The eyes are
  aimed with the final head pose (FLAME's chain root -> neck -> eye), so each eye converges on
  the 3D point: on a light-field panel every viewer sees the patient look at that point.

The model's own ``rotation`` (its nods) is left as it is; every layer writes to ``neck_pose``,
``translation``, ``eyes_pose`` or the AU43 / pain AU columns of ``expr``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping

import numpy as np

from ..errors import InputError
from .layers import FPS, BlinkLayer, BreathingLayer, BrowLayer, GazeLayer, NodLayer, PainDynamics, SwayLayer

__all__ = ["BehaviourConfig", "ListenerBehaviour", "apply_behaviour", "DEFAULT_JOINTS", "DEFAULT_FRAMING",
           "PANEL_HEIGHT_M", "viewer_target", "default_target", "eye_directions", "LAYERS"]

#: the switchable layers, in the order of ``--no-LAYER`` flags
LAYERS = ("gaze", "blinks", "brows", "nods", "breathing", "sway", "flares")

#: the default head's rest joints (root, neck, jaw, eye at +x, eye at -x), metres (FLAME frame)
DEFAULT_JOINTS = np.array([[0.0, -0.175, -0.02], [0.0, -0.07, -0.025], [0.0, -0.042075, -0.0070978],
                           [0.0315, 0.0, 0.0545], [-0.0315, 0.0, 0.0545]])
#: the pipeline's framing of the default head: focal-plane centre (m) and half-height (m)
DEFAULT_FRAMING = (np.array([0.0, -0.05156633, -0.00699555]), 0.1950886943936348)
#: the Looking Glass Portrait's active height (m)
PANEL_HEIGHT_M = 0.16055308641975308


def viewer_target(angle_deg: float, distance_m: float, framing: tuple[np.ndarray, float] = DEFAULT_FRAMING,
                  panel_height_m: float = PANEL_HEIGHT_M, height_m: float = 0.0) -> np.ndarray:
    """A viewer's eye midpoint in the avatar's (FLAME) frame.

    The viewer is ``distance_m`` from the panel's centre in the direction ``angle_deg`` (+ = to
    the right as the viewer faces the panel, the avatar's +x: the conventions of
    ``tracking.viewer``, ``viewer_angle_deg = atan2(x, z)``, ``viewer_distance_m = |p|``, and of
    the quilt cameras), ``height_m`` above it. The panel's focal plane shows the head's framing
    at the scale ``s = half_height / (panel_height / 2)`` (Algorithm 1's cameras for a viewer at
    distance d sit at ``s d``), so the point is ``centre + s (d sin a, h, d cos a)``.
    """
    centre, half = framing
    s = float(half) / (0.5 * float(panel_height_m))
    d, a = float(distance_m), math.radians(float(angle_deg))
    return np.asarray(centre, dtype=np.float64) + s * np.array([d * math.sin(a), float(height_m), d * math.cos(a)])


def default_target() -> np.ndarray:
    """A viewer 0.6 m straight in front of the panel (the react / render-batch default)."""
    return viewer_target(0.0, 0.6)


@dataclass(frozen=True)
class BehaviourConfig:
    """Switches and settings of the no-data layers (docs/behaviour.md).

    ``gaze``, ``blinks``, ``brows``, ``nods``, ``breathing``, ``sway``, ``flares``: each layer on/off
    (``--no-gaze`` ...); pain itself is always shown (its level is the instructor's), ``flares`` only adds episodes.
    """

    gaze: bool = True
    blinks: bool = True
    brows: bool = True
    nods: bool = True
    breathing: bool = True
    sway: bool = True
    flares: bool = True
    seed: int = 0
    blink_rate_per_min: float = 14.0
    head_share: float = 0.25
    breath_mm: float = 1.5
    breath_deg: float = 0.4
    sway_deg: tuple[float, float, float] = (0.25, 0.7, 0.35)  # pitch small: it blurs the nods (docs/behaviour.md)
    sway_mm: float = 2.0
    flare_rate_per_min: float = 3.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in LAYERS:
                if not isinstance(v, bool):
                    raise InputError(f"behaviour.{f.name}: expected true or false, found {v!r}")
            elif f.name == "seed":
                if isinstance(v, bool) or not isinstance(v, int):
                    raise InputError(f"behaviour.seed: expected an integer, found {v!r}")
            elif f.name == "sway_deg":
                vals = tuple(v) if isinstance(v, (list, tuple)) else ()
                if len(vals) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                             and 0 <= x <= 10 for x in vals):
                    raise InputError(f"behaviour.sway_deg: expected 3 numbers in [0, 10], found {v!r}")
                object.__setattr__(self, "sway_deg", tuple(float(x) for x in vals))
            else:
                hi = {"blink_rate_per_min": 60.0, "head_share": 1.0, "breath_mm": 10.0, "breath_deg": 5.0,
                      "sway_mm": 20.0, "flare_rate_per_min": 30.0}[f.name]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= hi:
                    raise InputError(f"behaviour.{f.name}: expected a number in [0, {hi:g}], found {v!r}")

    def to_dict(self) -> dict[str, Any]:
        """JSON form (session.json, render-batch job hash)."""
        d = asdict(self)
        d["sway_deg"] = list(self.sway_deg)
        return d

    @classmethod
    def from_dict(cls, data: Any, source: str = "behaviour") -> "BehaviourConfig":
        """From the JSON form; unknown keys are errors naming ``source``."""
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected an object of behaviour settings, found {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputError(f"{source}: unknown keys {unknown}; expected some of {sorted(known)}")
        try:
            return cls(**dict(data))
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from exc

    def without(self, *layers: str) -> "BehaviourConfig":
        """A copy with the named layers switched off."""
        bad = [x for x in layers if x not in LAYERS]
        if bad:
            raise InputError(f"behaviour layers: expected names from {', '.join(LAYERS)}, found {bad}")
        return replace(self, **{x: False for x in layers})


def _rot(r: np.ndarray) -> np.ndarray:
    from ..geometry import rodrigues_np

    return rodrigues_np(np.asarray(r, dtype=np.float64))


def _axis_angle(R: np.ndarray) -> np.ndarray:
    """Axis-angle of a rotation matrix (angles below 170 deg, as eye and head poses are)."""
    c = max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))
    th = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-7:
        return 0.5 * v
    return th / (2.0 * math.sin(th)) * v


def _yaw_pitch_matrix(yaw: float, pitch: float) -> np.ndarray:
    """R = Ry(yaw) Rx(-pitch): takes +z to (cos p sin y, sin p, cos p cos y) (pitch + = up)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]])
    return ry @ rx


def _yaw_pitch(d: np.ndarray) -> tuple[float, float]:
    return math.atan2(d[0], d[2]), math.atan2(d[1], math.hypot(d[0], d[2]))


def eye_directions(rotation: Any, neck_pose: Any, eyes_pose: Any, translation: Any = None,
                   joints: np.ndarray = DEFAULT_JOINTS) -> tuple[np.ndarray, np.ndarray]:
    """World eye centres (T, 2, 3) and gaze directions (T, 2, 3) of FLAME pose sequences.

    Forward kinematics of the rigid chain root -> neck -> eye (FLAME's LBS for rigidly bound
    eyeballs): centre = ``R0 (R1 (J_e - J_1) + J_1 - J_0) + J_0 + transl``, direction =
    ``R0 R1 R_e (0, 0, 1)``. Eye 0 is joint 3 (``eyes_pose[:, :3]``, the eye at +x). For the
    listener bench: the angle between a direction and ``target - centre`` is the gaze error.
    """
    rot = np.asarray(rotation, dtype=np.float64).reshape(-1, 3)
    T = rot.shape[0]
    neck = np.asarray(neck_pose, dtype=np.float64).reshape(T, 3)
    eyes = np.asarray(eyes_pose, dtype=np.float64).reshape(T, 6)
    tr = np.zeros((T, 3)) if translation is None else np.asarray(translation, dtype=np.float64).reshape(T, 3)
    J = np.asarray(joints, dtype=np.float64)
    R0, R1 = _rot(rot), _rot(neck)
    centres = np.empty((T, 2, 3))
    dirs = np.empty((T, 2, 3))
    for e in range(2):
        Re = _rot(eyes[:, 3 * e:3 * e + 3])
        local = np.einsum("tij,j->ti", R1, J[3 + e] - J[1]) + (J[1] - J[0])
        centres[:, e] = np.einsum("tij,tj->ti", R0, local) + J[0] + tr
        dirs[:, e] = np.einsum("tij,tjk,tkl,l->ti", R0, R1, Re, np.array([0.0, 0.0, 1.0]))
    return centres, dirs


class ListenerBehaviour:
    """Stream the layers frame by frame (see the module docstring).

    Parameters
    ----------
    config : BehaviourConfig
    n_expr : int
        Expression coefficients of the frames (the default head's AU map sized to it).
    au_map : holo_viewer.flame.expressions.AUMap, optional
        The avatar's map (``Pipeline.au_map``, ``au_map_for(model)``): its ``pain_gains`` shape the pain
        face, as in the pipeline's ``FaceControls(pain)``. Default: the shipped default head's own map
        (:func:`default_au_map` with :data:`DEFAULT_HEAD_PAIN_GAINS`, what ``au_map_for`` gives that head);
        pass a patient's or a user model's map for their avatars.
    joints : (5, 3) rest joints (default: the default head's)
    fps : frames per second of the stream
    """

    def __init__(self, config: BehaviourConfig | None = None, n_expr: int | None = None, au_map: Any = None,
                 joints: np.ndarray = DEFAULT_JOINTS, fps: float = FPS) -> None:
        from ..flame.expressions import DEFAULT_HEAD_PAIN_GAINS, default_au_map

        self.config = c = config or BehaviourConfig()
        self.au_map = au_map if au_map is not None else default_au_map(n_expr).with_pain_gains(DEFAULT_HEAD_PAIN_GAINS)
        self.n_expr = self.au_map.n_expr
        self._pinv = np.linalg.pinv(self.au_map.matrix)
        names = self.au_map.names
        self._i43 = names.index("AU43") if "AU43" in names else None
        self._brows = np.array([1.0 if n in ("AU1", "AU2") else 0.0 for n in names])  # AU1, AU2 (0-5 scale)
        self.joints = np.asarray(joints, dtype=np.float64)
        self.fps = float(fps)
        self.gaze = GazeLayer(c.seed, fps=fps)
        self.blinks = BlinkLayer(c.seed, rate_per_min=c.blink_rate_per_min, fps=fps)
        self.brows = BrowLayer(c.seed, fps=fps)
        self.nods = NodLayer(c.seed, fps=fps)
        self.breathing = BreathingLayer(c.seed, fps=fps)
        self.sway = SwayLayer(c.seed, std_deg=c.sway_deg, std_mm=c.sway_mm, fps=fps)
        self.pain = PainDynamics(c.seed, flares=c.flares, flare_rate_per_min=c.flare_rate_per_min, fps=fps)
        self._head = np.zeros(2)  # head share of the gaze (yaw, pitch), radians, smoothed
        self.last: dict[str, float] = {}

    def _pain_vector(self, p: float) -> np.ndarray:
        from ..flame.expressions import _pain_aus

        aus, gains = _pain_aus(p), self.au_map.pain_gains or {}  # a patient's identity normalisation
        return np.array([aus.get(n, 0.0) * gains.get(n, 1.0) for n in self.au_map.names])

    def step(self, frame: Mapping[str, Any], pain_level: float = 0.0, target: Any = None,
             speaking: bool = True, pause_onset: bool = False) -> dict[str, np.ndarray]:
        """One frame: the model's FLAME arrays in, the composed arrays out (float64).

        ``pain_level``: the instructor's level in [0, 1] now; ``target``: (3,) the point to look at
        in the avatar frame (None: :func:`default_target`); ``speaking``: the speaker's voice is
        active; ``pause_onset``: the speaker has just paused (>= 200 ms after >= 700 ms of speech).
        ``self.last`` holds this frame's layer values (pain shown, blink, breath, gaze on target).
        """
        c = self.config
        expr = np.zeros(self.n_expr)
        e_in = np.asarray(frame.get("expr", expr), dtype=np.float64).reshape(-1)[:self.n_expr]
        expr[:e_in.size] = e_in
        out = {k: np.asarray(frame[k], dtype=np.float64).reshape(-1).copy() if k in frame else np.zeros(n)
               for k, n in (("jaw_pose", 3), ("rotation", 3), ("neck_pose", 3), ("translation", 3),
                            ("eyes_pose", 6))}
        # pain: the PSPI face of the pain shown now, max-combined with the model's AUs
        p = self.pain.step(float(pain_level))
        aus = np.clip(expr @ self._pinv, 0.0, None)
        if p > 0:
            delta = np.maximum(self._pain_vector(p) - aus, 0.0)
            expr = expr + delta @ self.au_map.matrix
            aus = aus + delta
        brow = self.brows.step(pause_onset)
        if c.brows and brow > 0:  # a brow raise (AU1 + AU2), max-combined like the pain face
            delta = np.maximum(5.0 * brow - aus, 0.0) * self._brows
            expr = expr + delta @ self.au_map.matrix
            aus = aus + delta
        blink = self.blinks.step(p, pause_onset)
        if c.blinks and self._i43 is not None and blink > 0:
            a = min(1.0, aus[self._i43])
            expr = expr + blink * (1.0 - a) * self.au_map.matrix[self._i43]
        breath = self.breathing.step(p)
        if c.breathing:
            out["translation"] += np.array([0.0, 1e-3 * c.breath_mm * breath, 1e-3 * c.breath_mm / 3 * breath])
            out["neck_pose"][0] -= math.radians(c.breath_deg) * breath  # -x pitch lifts the chin
        nod = self.nods.step(pause_onset)
        if c.nods and nod > 0:  # a backchannel nod: +x pitch of the neck turns the face down
            out["neck_pose"][0] += math.radians(nod)
        sway = self.sway.step()
        if c.sway:
            out["neck_pose"] += np.radians(sway[:3])
            out["translation"] += 1e-3 * np.array([sway[3], 0.0, sway[4]])
        g = self.gaze.step(speaking)
        if c.gaze:
            tgt = default_target() if target is None else np.asarray(target, dtype=np.float64).reshape(3)
            J = self.joints
            mid_rest = 0.5 * (J[3] + J[4])
            # the head turns a share of the way toward the target (slowly, ~0.5 s), a little with aversions
            R0 = _rot(out["rotation"])
            d0 = R0.T @ (tgt - (R0 @ (mid_rest - J[0]) + J[0] + out["translation"]))
            ty, tp = _yaw_pitch(d0)
            want = c.head_share * np.array([ty + 0.3 * math.radians(g.yaw_deg), tp + 0.3 * math.radians(g.pitch_deg)])
            self._head += (1.0 - math.exp(-1.0 / (self.fps * 0.5))) * (want - self._head)
            Rh = _yaw_pitch_matrix(self._head[0], self._head[1])
            out["neck_pose"] = _axis_angle(Rh @ _rot(out["neck_pose"]))
            R1 = _rot(out["neck_pose"])
            Rhead = R0 @ R1
            for e in range(2):
                centre = R0 @ (R1 @ (J[3 + e] - J[1]) + J[1] - J[0]) + J[0] + out["translation"]
                y, pt = _yaw_pitch(Rhead.T @ (tgt - centre))
                Re = _yaw_pitch_matrix(y + math.radians(g.yaw_deg), pt + math.radians(g.pitch_deg))
                out["eyes_pose"][3 * e:3 * e + 3] = _axis_angle(Re)
        self.last = {"pain": p, "blink": blink if c.blinks else 0.0, "brows": brow if c.brows else 0.0,
                     "nod": nod if c.nods else 0.0,
                     "breath": breath if c.breathing else 0.0,
                     "gaze_on_target": float(g.on_target) if c.gaze else float("nan")}
        out["expr"] = expr
        return out


def apply_behaviour(params: Mapping[str, Any], config: BehaviourConfig | None = None, *, pain: Any = 0.0,
                    target: Any = None, speaking: Any = None, pause_onsets: Any = None,
                    fps: float = FPS, au_map: Any = None) -> dict[str, np.ndarray]:
    """The layers over a whole clip: :class:`ListenerBehaviour` stepped over its T frames.

    Parameters
    ----------
    params : flame_param arrays (``expr`` (T, n_expr), ``rotation`` (T, 3), ...); other keys
        (``shape``, ...) are passed through.
    pain : float, (T,) array, or a :class:`~.timeline.PainTimeline` (the instructor's level per frame)
    target : (3,) or (T, 3) point(s) to look at (avatar frame; default :func:`default_target`)
    speaking, pause_onsets : (T,) bool, optional (default: speaking throughout, no pauses)
    au_map : AUMap, optional
        The avatar's map (:class:`ListenerBehaviour`; default: the shipped default head's own); the
        composed ``expr`` has its ``n_expr`` columns (``params["expr"]`` padded with zeros or cut).

    Returns
    -------
    dict : the same keys, per-frame keys composed (float32), plus ``pain_shown`` (T,) the pain shown
        (already in ``expr``: it is not the ``pain`` key that renderers add on top).
    """
    from .timeline import PainTimeline

    if "expr" not in params:
        raise InputError(f"behaviour: expected flame params with 'expr', found keys {sorted(params)}")
    expr = np.asarray(params["expr"], dtype=np.float64)
    if expr.ndim != 2:
        raise InputError(f"behaviour: expr: expected shape (T, n_expr), found {expr.shape}")
    T = expr.shape[0]
    if T == 0:
        raise InputError("behaviour: expr: expected at least one frame, found 0")
    if isinstance(pain, PainTimeline):
        levels = pain.levels(T, fps)
    else:
        levels = np.broadcast_to(np.asarray(pain, dtype=np.float64), (T,))
    if levels.size and (not np.all(np.isfinite(levels)) or levels.min() < 0 or levels.max() > 1):
        raise InputError("pain: expected levels in [0, 1]")
    tg = None if target is None else np.asarray(target, dtype=np.float64)
    if tg is not None and tg.shape not in ((3,), (T, 3)):
        raise InputError(f"target: expected shape (3,) or ({T}, 3), found {tg.shape}")
    sp = np.ones(T, bool) if speaking is None else np.asarray(speaking, bool).reshape(T)
    po = np.zeros(T, bool) if pause_onsets is None else np.asarray(pause_onsets, bool).reshape(T)
    beh = ListenerBehaviour(config, n_expr=expr.shape[1], au_map=au_map, fps=fps)
    keys = ("expr", "jaw_pose", "rotation", "neck_pose", "translation", "eyes_pose")
    per_frame = {k: np.asarray(params[k], dtype=np.float64) for k in keys if k in params}
    rows: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    shown = np.empty(T)
    for t in range(T):
        fr = {k: v[t] for k, v in per_frame.items()}
        o = beh.step(fr, float(levels[t]), None if tg is None else (tg if tg.ndim == 1 else tg[t]),
                     bool(sp[t]), bool(po[t]))
        for k in keys:
            rows[k].append(o[k])
        shown[t] = beh.last["pain"]
    out = {k: v for k, v in params.items() if k not in keys}
    for k in keys:
        out[k] = np.stack(rows[k]).astype(np.float32)
    out["pain_shown"] = shown.astype(np.float32)
    return out
