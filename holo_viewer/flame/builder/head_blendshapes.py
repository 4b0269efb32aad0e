"""Shape and expression blend shapes of the default head.

Pure numpy, deterministic (the only randomness is a seeded generator for the
generic shape components). Every component is a smooth, localised displacement
field (metres per unit coefficient) built from region masks on the rest mesh.

Units
-----
* Shape: coefficient 1.0 is about one standard deviation of adult variation for
  that feature (3-6 mm at the feature), so shape ~ N(0, 1) gives plausible heads.
* Expression: coefficient 1.0 is the *full* (FACS E, maximum) intensity of the
  action unit the component is named after, e.g. ``AU12_L`` = 1 pulls the left lip
  corner 8 mm up and 5 mm back; ``AU43_L`` = 1 closes the left eye. Coefficients
  ~ N(0, 1) therefore look like strong but plausible faces; negative coefficients
  are the opposite motions at the same scale.

Eyeballs never move in the expression basis; in the shape basis they translate
rigidly with the displacement of their centre (so the sockets keep fitting).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..default_head import EXPRESSION_NAMES  # noqa: F401 - the order the components are built in
from .head_sculpt import EYE_CENTRES, HINGE, REGION_NAMES, HeadMesh, smoothstep

__all__ = ["EXPRESSION_NAMES", "SHAPE_NAMES", "shape_basis", "expression_basis", "N_GENERIC_SHAPE",
           "MOUTH_COMPONENTS", "LID_FLOOR_Y"]

SHAPE_NAMES = ("head_width", "head_depth", "head_height", "face_length", "face_width", "jaw_width",
               "chin_protrusion", "chin_height", "nose_length", "nose_width", "nose_projection",
               "nose_bridge", "cheekbones", "brow_ridge", "eye_spacing", "eye_height", "mouth_width",
               "lip_thickness", "ear_size", "ear_protrusion", "neck_width", "forehead_slope",
               "cheek_fullness")
N_GENERIC_SHAPE = 9
#: Components that act on the mouth, lips, cheeks or jaw. None of them moves a vertex above
#: ``LID_FLOOR_Y`` (the eyelids and everything above them); all but AU10 (its alar lift) and
#: AU12 (its cheek lift) are also exactly zero above the nose tip, except that AU26 (a
#: linearised jaw rotation) moves the skin over the mandibular ramus (|x| > 0.055 m) up to
#: the hinge level, as the jaw does.
MOUTH_COMPONENTS = ("AU10", "AU12_L", "AU12_R", "AU14", "AU15", "AU16", "AU17", "AU18", "AU20",
                    "AU23", "AU24", "AU25", "AU26")
#: y (metres) below which the lower-lid skin rows end; mouth components vanish above it.
LID_FLOOR_Y = -0.012


def _g(p: np.ndarray, centre, radii) -> np.ndarray:
    q = (p - np.asarray(centre, dtype=np.float64)) / np.asarray(radii, dtype=np.float64)
    return np.exp(-np.sum(q * q, axis=-1))


def _front(p: np.ndarray, z0: float = 0.02, z1: float = 0.05) -> np.ndarray:
    return smoothstep(p[:, 2], z0, z1)


class _Ctx:
    """Per-vertex helpers shared by the component builders."""

    def __init__(self, head: HeadMesh, jaw: np.ndarray):
        self.h = head
        self.v = head.vertices
        self.n = len(self.v)
        self.jaw = jaw
        self.surf = np.isfinite(head.theta)
        row_thetas = head.theta[head.grid[:, 0]]
        self.row = np.full(self.n, np.nan)
        ids = np.where(self.surf)[0]
        self.row[ids] = np.argmin(np.abs(head.theta[ids, None] - row_thetas[None, :]), axis=1)
        self.region = head.region
        r_m, c0, c1 = head.mouth_slit
        self.r_m = r_m
        self.corner_x = float(abs(self.v[head.grid[r_m, c1], 0]))
        self.mouth_y = float(self.v[head.grid[r_m, (c0 + c1) // 2], 1])
        self.mouth_z = float(self.v[head.grid[r_m, (c0 + c1) // 2], 2])
        k = self.row - r_m
        self.k_mouth = k
        near_mouth = self.surf & (np.abs(self.v[:, 0]) < 1.6 * self.corner_x) & (self.v[:, 2] > 0.02)
        lip_low = head.lower_lip_side  # the mouth slit's lower side, not the lower-lid rims
        self.upper = near_mouth & ((k < 0) | ((k == 0) & ~lip_low))
        self.lower = near_mouth & ((k > 0) | ((k == 0) & lip_low))
        t = self.v[:, 0] / self.corner_x
        self.lat = np.clip(1 - t * t, 0, 1)
        # compact vertical supports of the mouth components (exactly 0 above their top):
        # below the nose tip for the lip/corner/chin fields, below the eyelids (LID_FLOOR_Y)
        # for the cheek and alar parts of AU12 / AU10
        y = self.v[:, 1]
        self.y_tip = float(self.v[np.argmax(np.where(self.surf, self.v[:, 2], -np.inf)), 1])
        self.below_tip = 1.0 - smoothstep(y, self.y_tip - 0.008, self.y_tip)
        self.below_lids = 1.0 - smoothstep(y, LID_FLOOR_Y - 0.016, LID_FLOOR_Y)

    def rows_w(self, side: str, n_rows: float) -> np.ndarray:
        """Weight decaying with the row distance from the mouth line on one side."""
        k = np.abs(np.nan_to_num(self.k_mouth, nan=99.0))
        w = np.clip(1 - k / n_rows, 0, 1)
        return w * (self.upper if side == "upper" else self.lower)

    def lid_rotation(self, e: int, side: str, angle: Callable[[np.ndarray], np.ndarray], n_rows: int,
                     taper: bool = True) -> np.ndarray:
        """Displacement rotating lid vertices of eye ``e`` about the eye's x axis (pitch change).

        ``angle(t)`` gives the pitch change (radians, + = up) of the rim at fissure
        parameter t in [0, 1] (0 inner corner); rows away from the rim get it times a
        linear falloff over ``n_rows`` rows.
        """
        row, ca, cb, sgn = self.h.eye_cols[e]
        c = EYE_CENTRES[e]
        d = np.zeros((self.n, 3))
        for j in range(ca, cb + 1):
            t = (j - ca) / (cb - ca)
            if sgn < 0:
                t = 1 - t
            fade = np.sin(np.pi * t) ** 0.5 if taper else 1.0
            for k in range(n_rows):
                if side == "upper":
                    vid = self.h.grid[row - k, j]
                else:
                    vid = (self.h.parts[f"lid_lower_{e}"][j - ca] if k == 0 else self.h.grid[row + k, j])
                w = (1 - k / n_rows) * fade
                q = self.v[vid] - c
                r = np.linalg.norm(q)
                yaw = np.arctan2(q[0], q[2])
                pitch = np.arcsin(q[1] / r)
                p2 = pitch + w * float(angle(np.array(t)))
                new = c + r * np.array([np.cos(p2) * np.sin(yaw), np.sin(p2), np.cos(p2) * np.cos(yaw)])
                d[vid] = new - self.v[vid]
        return d

    def corner(self, s: int, rx: float = 0.016, ry: float = 0.014) -> np.ndarray:
        p = self.v
        return (np.exp(-((p[:, 0] - s * self.corner_x) / rx) ** 2 - ((p[:, 1] - self.mouth_y) / ry) ** 2)
                * _front(p, 0.03, 0.06) * self.surf * self.below_tip)

    def lips(self) -> np.ndarray:
        p = self.v
        return (np.exp(-(p[:, 0] / (1.15 * self.corner_x)) ** 4 - ((p[:, 1] - self.mouth_y) / 0.011) ** 2)
                * _front(p, 0.05, 0.07) * self.surf * self.below_tip)


def _propagate_bag(head: HeadMesh, d: np.ndarray) -> np.ndarray:
    """Bag and pocket vertices follow their loop's displacement, fading inward."""
    d = d.copy()
    up, lo = head.parts["mouth_upper"], head.parts["mouth_lower"]
    loop = np.concatenate([up, lo[1:-1][::-1]])
    bag = head.parts["bag"]
    n = len(loop)
    n_rings = (len(bag) - 1) // n
    for j, fade in zip(range(n_rings), (0.85, 0.6, 0.35, 0.15, 0.05)):
        d[bag[j * n:(j + 1) * n]] = fade * d[loop]
    d[bag[-1]] = 0.0
    return d


def expression_basis(head: HeadMesh, jaw: np.ndarray) -> np.ndarray:
    """(V, 3, len(EXPRESSION_NAMES)) expression blend shapes (metres per unit coefficient)."""
    c = _Ctx(head, jaw)
    p = c.v
    fr = _front(p)
    comps = {}
    lid_t = head.lid_pitch  # (2 eyes, 2 rims, n)

    def brow(s, x0, amp, rx=0.014):
        return _g(p, (s * x0, 0.026, 0.0), (rx, 0.016, 1e3)) * fr * c.surf

    for s, tag in ((1, "L"), (-1, "R")):
        d = np.zeros((c.n, 3))
        d[:, 1] = 0.005 * brow(s, 0.016, 1) + 0.0015 * _g(p, (s * 0.015, 0.05, 0), (0.02, 0.02, 1e3)) * fr
        comps[f"AU1_{tag}"] = d
        d = np.zeros((c.n, 3))
        d[:, 1] = 0.005 * brow(s, 0.045, 1, 0.013)
        comps[f"AU2_{tag}"] = d
    d = np.zeros((c.n, 3))
    for s in (1, -1):
        m = brow(s, 0.018, 1, 0.016)
        d[:, 0] += -s * 0.003 * m
        d[:, 1] += -0.0042 * m - 0.0015 * brow(s, 0.045, 1)
        d[:, 2] += 0.001 * m
    d[:, 2] += 0.0012 * _g(p, (0, 0.02, 0), (0.007, 0.01, 1e3)) * fr
    comps["AU4"] = d

    def both_eyes(side, angle_fn, rows):
        return sum(c.lid_rotation(e, side, angle_fn(e), rows) for e in range(2))

    comps["AU5"] = both_eyes("upper", lambda e: (lambda t: np.radians(9.0)), 4)
    cheek = sum(_g(p, (s * 0.038, -0.02, 0.0), (0.018, 0.016, 1e3)) for s in (1, -1)) * _front(p, 0.03, 0.06) * c.surf
    d = np.zeros((c.n, 3))
    d[:, 1] = 0.0042 * cheek
    d[:, 2] = 0.0015 * cheek
    d += both_eyes("lower", lambda e: (lambda t: np.radians(7.0)), 4)
    comps["AU6"] = d
    comps["AU7"] = (both_eyes("lower", lambda e: (lambda t: np.radians(11.0)), 3)
                    + both_eyes("upper", lambda e: (lambda t: -np.radians(6.0)), 3))
    d = np.zeros((c.n, 3))
    nose = _g(p, (0, -0.02, 0.09), (0.022, 0.022, 1e3)) * _front(p, 0.06, 0.08) * c.surf
    d[:, 1] += 0.003 * nose
    d[:, 2] += -0.001 * nose
    d[:, 1] += 0.002 * c.rows_w("upper", 5) * c.lat
    for s in (1, -1):
        d[:, 1] += -0.002 * brow(s, 0.012, 1)
        d[:, 0] += -s * 0.0015 * brow(s, 0.012, 1)
    comps["AU9"] = d
    d = np.zeros((c.n, 3))
    ul = c.rows_w("upper", 7) * (0.35 + 0.65 * np.sqrt(c.lat))
    d[:, 1] = 0.004 * ul
    d[:, 2] = 0.0012 * ul
    d[:, 1] += 0.0012 * _g(p, (0, -0.04, 0.1), (0.02, 0.01, 1e3)) * c.surf * _front(p, 0.07, 0.09) * c.below_lids
    comps["AU10"] = d
    for s, tag in ((1, "L"), (-1, "R")):
        m = c.corner(s)
        ck = _g(p, (s * 0.036, -0.032, 0), (0.016, 0.014, 1e3)) * _front(p, 0.03, 0.06) * c.surf * c.below_lids
        d = np.zeros((c.n, 3))
        d[:, 0] = s * 0.0035 * m
        d[:, 1] = 0.008 * m + 0.003 * ck
        d[:, 2] = -0.005 * m + 0.0012 * ck
        comps[f"AU12_{tag}"] = d
    m = sum(c.corner(s, 0.01, 0.01) for s in (1, -1))
    d = np.zeros((c.n, 3))
    d[:, 0] = -np.sign(p[:, 0]) * 0.001 * m
    d[:, 1] = 0.0006 * m
    d[:, 2] = -0.004 * m
    comps["AU14"] = d
    d = np.zeros((c.n, 3))
    for s in (1, -1):
        m = c.corner(s, 0.015, 0.016)
        d[:, 1] += -0.005 * m
        d[:, 2] += -0.001 * m
    comps["AU15"] = d
    d = np.zeros((c.n, 3))
    ll = c.rows_w("lower", 6) * np.sqrt(c.lat)
    d[:, 1] = -0.004 * ll
    d[:, 2] = 0.001 * ll
    comps["AU16"] = d
    d = np.zeros((c.n, 3))
    chin = _g(p, (0, -0.095, 0.06), (0.025, 0.018, 1e3)) * _front(p, 0.03, 0.05) * c.surf * c.below_tip
    lipz = (c.rows_w("lower", 5) + 0.6 * c.rows_w("upper", 3)) * np.sqrt(c.lat)
    d[:, 1] = 0.003 * chin + 0.0015 * lipz
    d[:, 2] = 0.002 * chin + 0.0022 * lipz
    comps["AU17"] = d
    lips = c.lips()
    d = np.zeros((c.n, 3))
    d[:, 0] = -0.3 * p[:, 0] * lips
    d[:, 2] = 0.005 * lips
    comps["AU18"] = d
    d = np.zeros((c.n, 3))
    for s in (1, -1):
        m = c.corner(s, 0.02, 0.016)
        d[:, 0] += s * 0.006 * m
        d[:, 1] += -0.001 * m
        d[:, 2] += -0.0015 * m
    comps["AU20"] = d
    d = np.zeros((c.n, 3))
    off_u = c.rows_w("upper", 4) * (np.nan_to_num(c.k_mouth) != 0)
    off_l = c.rows_w("lower", 4) * (np.nan_to_num(c.k_mouth) != 0)
    d[:, 0] = -0.15 * p[:, 0] * lips
    d[:, 1] = -0.0012 * off_u + 0.0012 * off_l
    d[:, 2] = -0.0015 * lips
    comps["AU23"] = d
    d = np.zeros((c.n, 3))
    d[:, 1] = -0.0015 * off_u + 0.0015 * off_l
    d[:, 2] = -0.0025 * lips
    comps["AU24"] = d
    d = np.zeros((c.n, 3))
    d[:, 1] = 0.0025 * c.rows_w("upper", 6) * c.lat ** 0.7 - 0.004 * c.rows_w("lower", 6) * c.lat ** 0.7
    comps["AU25"] = d
    a = np.radians(12.0)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    q = p - HINGE
    comps["AU26"] = jaw[:, None] * (q @ rot.T - q)
    for e, tag in ((0, "L"), (1, "R")):
        pu, pl = lid_t[e]
        close = pu - pl - np.radians(1.0)
        n_t = len(close)

        def fn(t, close=close, n_t=n_t):
            return -float(np.interp(t, np.linspace(0, 1, n_t), close if head.eye_cols[e][3] > 0 else close[::-1]))
        comps[f"AU43_{tag}"] = c.lid_rotation(e, "upper", fn, 5, taper=False)
    out = np.zeros((c.n, 3, len(EXPRESSION_NAMES)))
    rigid = np.concatenate([head.parts[f"eyeball_{e}"] for e in range(2)])
    for i, name in enumerate(EXPRESSION_NAMES):
        d = _propagate_bag(head, comps[name])
        d[rigid] = 0.0
        for e in range(2):
            d[head.parts[f"pocket_{e}"]] = 0.0
        out[:, :, i] = d
    return out


def shape_basis(head: HeadMesh, seed: int = 0) -> np.ndarray:
    """(V, 3, len(SHAPE_NAMES) + N_GENERIC_SHAPE) shape blend shapes (metres per unit coefficient)."""
    v = head.vertices
    n = len(v)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    anchor = v.copy()  # eyeballs and eye pockets move with their eye centre
    for e in range(2):
        for key in (f"eyeball_{e}", f"pocket_{e}"):
            anchor[head.parts[key]] = EYE_CENTRES[e]
    p = anchor
    fr = _front(p, 0.0, 0.04)
    comps: dict[str, np.ndarray] = {}

    def field(dx=0.0, dy=0.0, dz=0.0):
        d = np.zeros((n, 3))
        d[:, 0], d[:, 1], d[:, 2] = dx, dy, dz
        return d

    upper = smoothstep(p[:, 1], -0.05, 0.0)
    comps["head_width"] = field(dx=0.006 * p[:, 0] / 0.075 * upper)
    comps["head_depth"] = field(dz=0.006 * (p[:, 2] + 0.018) / 0.094 * upper * (p[:, 2] < 0.0) * smoothstep(-p[:, 2], 0.0, 0.03))
    comps["head_height"] = field(dy=0.006 * smoothstep(p[:, 1], 0.0, 0.1))
    low = smoothstep(-p[:, 1], 0.03, 0.1) * smoothstep(p[:, 2], -0.03, 0.02)
    comps["face_length"] = field(dy=-0.005 * low)
    fw = _g(p, (0, -0.02, 0.05), (0.1, 0.05, 0.06))
    comps["face_width"] = field(dx=0.005 * p[:, 0] / 0.06 * fw)
    jw = _g(p, (0, -0.075, 0.01), (0.1, 0.025, 0.05))
    comps["jaw_width"] = field(dx=0.005 * p[:, 0] / 0.05 * jw)
    chin = _g(p, (0, -0.093, 0.06), (0.03, 0.02, 0.03))
    comps["chin_protrusion"] = field(dz=0.004 * chin)
    comps["chin_height"] = field(dy=-0.004 * _g(p, (0, -0.1, 0.05), (0.04, 0.02, 0.04)))
    tip = _g(p, (0, -0.036, 0.108), (0.016, 0.014, 0.02))
    comps["nose_length"] = field(dy=-0.0035 * tip)
    comps["nose_width"] = field(dx=0.003 * p[:, 0] / 0.012 * _g(p, (0, -0.038, 0.095), (0.022, 0.012, 0.02)))
    comps["nose_projection"] = field(dz=0.004 * tip)
    comps["nose_bridge"] = field(dz=0.003 * _g(p, (0, -0.005, 0.09), (0.012, 0.018, 0.02)))
    cb = sum(_g(p, (s * 0.048, -0.01, 0.045), (0.02, 0.015, 0.025)) for s in (1, -1))
    comps["cheekbones"] = field(dx=0.003 * np.sign(p[:, 0]) * cb, dz=0.002 * cb)
    comps["brow_ridge"] = field(dz=0.003 * _g(p, (0, 0.027, 0.07), (0.05, 0.012, 0.025)))
    eyes = sum(_g(p, (EYE_CENTRES[e][0], 0.0, 0.055), (0.018, 0.016, 0.03)) for e in range(2))
    comps["eye_spacing"] = field(dx=0.002 * np.sign(p[:, 0]) * eyes)
    comps["eye_height"] = field(dy=0.002 * eyes)
    mouth = _g(p, (0, -0.068, 0.085), (0.04, 0.015, 0.03))
    comps["mouth_width"] = field(dx=0.003 * p[:, 0] / 0.023 * mouth)
    lips = (head.region == REGION_NAMES.index("lips")).astype(np.float64)
    rad = v - np.array([0.0, -0.07, 0.0])
    rad /= np.linalg.norm(rad, axis=1, keepdims=True)
    comps["lip_thickness"] = 0.0015 * lips[:, None] * rad
    ears = np.zeros((n, 3))
    ear_out = np.zeros((n, 3))
    for e in range(2):
        ids = head.parts[f"ear_{e}"]
        ctr = v[ids].mean(0)
        ears[ids] = 0.08 * (v[ids] - ctr)
        dist_in = np.abs(v[ids, 0] - np.sign(ctr[0]) * 0.066)
        ear_out[ids, 0] = np.sign(ctr[0]) * 0.004 * dist_in / 0.02
    comps["ear_size"] = ears
    comps["ear_protrusion"] = ear_out
    neck = smoothstep(-p[:, 1], 0.07, 0.11)
    comps["neck_width"] = field(dx=0.005 * p[:, 0] / 0.058 * neck, dz=0.004 * (p[:, 2] + 0.022) / 0.054 * neck)
    comps["forehead_slope"] = field(dz=0.004 * smoothstep(p[:, 1], 0.02, 0.09) * fr * smoothstep(p[:, 2], 0.0, 0.05))
    lc = sum(_g(p, (s * 0.045, -0.05, 0.04), (0.02, 0.025, 0.03)) for s in (1, -1))
    comps["cheek_fullness"] = field(dx=0.003 * np.sign(p[:, 0]) * lc, dz=0.001 * lc)
    rng = np.random.default_rng(seed)
    surf_ids = np.where(np.isfinite(head.theta) & (v[:, 1] > -0.11))[0]
    generic = []
    for _ in range(N_GENERIC_SHAPE):
        d = np.zeros((n, 3))
        for _b in range(4):
            ctr = v[surf_ids[rng.integers(len(surf_ids))]]
            rad_b = rng.uniform(0.02, 0.05)
            vec = rng.normal(size=3)
            vec *= 0.003 / np.linalg.norm(vec)
            for s in (1, -1):  # mirror-symmetric bumps
                cs = ctr * np.array([s, 1, 1])
                vs = vec * np.array([s, 1, 1])
                d += _g(p, cs, (rad_b, rad_b, rad_b))[:, None] * vs
        generic.append(d)
    out = np.stack([comps[name] for name in SHAPE_NAMES] + generic, axis=2)
    return out
