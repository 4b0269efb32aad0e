"""Convert ICT Face Model Light (ICT-FaceKit, MIT) into the default head (build time only).

Input: ``ict_facekit_light.npz`` (see ``assets/ICT-FaceKit/SOURCE.md``): neutral vertices in
centimetres (+y up, +z toward the viewer), triangles with UDIM-style UVs, 57 ARKit-named expression
deltas, 100 PCA identity deltas, the 68 dlib landmarks as vertex indices. Everything here is pure numpy
(plus scipy's connected components, NNLS and k-d tree), deterministic, and runs only from
``scripts/build_default_head.py`` (or to rebuild a missing asset).

Steps (docs/default_head.md has the numbers):

1. *Geometry.* Keep the face, head and neck, mouth socket, eye sockets, gums and tongue, teeth,
   eyeballs (sclera shell + iris shell) and eyelashes; drop the lacrimal fluid, eye blend and eye
   occlusion overlays. Scale to metres so the eyeball centres (sphere fits) are 63 mm apart and move
   their midpoint to ``EYE_MIDPOINT`` (where the previous default head had it).
2. *Hair.* A shell offset along the normals over the scalp (thickness from ``HAIR_PROFILE``), its rim
   tucked 0.4 mm under the skin along a hairline (``HAIRLINE``), subdivided once, region ``hair``,
   UVs in tile 7.
3. *Regions* from the parts, the landmarks and geometry (``REGION_NAMES``).
4. *Expressions*: the AU components of ``EXPRESSION_NAMES`` as weighted sums of ICT shapes
   (``AU_TO_ICT``).
5. *Rig*: FLAME's 5 joints; the jaw's pivot and angle from a rigid fit of the lower teeth in
   ``jawOpen``, jaw weights from projecting ``jawOpen`` on that rotation, the rest of ``jawOpen``
   as jaw pose correctives; eyeballs rigid on their eye joints; a smooth neck band.
6. *Identity*: ICT's first ``N_IDENTITY`` PCA modes (scaled like the geometry) as shape components.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import nnls
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import FlameError
from ..geometry import vertex_normals
from ..flame.default_head import EXPRESSION_NAMES

__all__ = ["load_ict", "build_from_ict", "REGION_NAMES", "AU_TO_ICT", "N_IDENTITY", "EYE_MIDPOINT", "IPD",
           "KINTREE", "PARTS", "smoothstep", "HairStyle", "DEFAULT_HAIR"]

#: ICT vertex ranges (inclusive) of the parts, from the model's README.
PARTS = {
    "face": (0, 9408), "head_neck": (9409, 11247), "mouth_socket": (11248, 13293),
    "eye_socket_left": (13294, 13677), "eye_socket_right": (13678, 14061), "gums_tongue": (14062, 17038),
    "teeth": (17039, 21450), "sclera_left": (21451, 22220), "iris_left": (22221, 23020),
    "sclera_right": (23021, 23790), "iris_right": (23791, 24590), "lacrimal": (24591, 24998),
    "eye_blend": (24999, 25046), "eye_occlusion": (25047, 25350), "lashes_left": (25351, 26034),
    "lashes_right": (26035, 26718),
}
DROPPED_PARTS = ("lacrimal", "eye_blend", "eye_occlusion")
#: Region labels of the default head (``vertex_region`` indexes this tuple).
REGION_NAMES = ("skin", "scalp", "brows", "lips", "eyeball_left", "eyeball_right", "iris", "pupil", "ears",
                "mouth_interior", "eye_pocket", "neck", "nostrils", "teeth", "hair", "lashes", "tongue", "gums")
#: Eye-centre midpoint (metres) and inter-pupillary distance of the default head.
EYE_MIDPOINT = np.array([0.0, 0.0, 0.0545])
IPD = 0.063
#: Identity (shape) components kept from ICT's 100 PCA modes.
N_IDENTITY = 20
#: FLAME kinematic tree: parents then joint ids.
KINTREE = np.array([[-1, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64)
#: AU component -> {ICT shape: weight}; coefficient 1 = full intensity (FACS E). AU26 (jaw drop) is
#: ``jawOpen`` scaled to a jaw rotation of ``JAW_AU26_DEG`` (see :func:`build_from_ict`).
AU_TO_ICT: dict[str, dict[str, float]] = {
    "AU1_L": {"browInnerUp_L": 1.0}, "AU1_R": {"browInnerUp_R": 1.0},
    "AU2_L": {"browOuterUp_L": 1.0}, "AU2_R": {"browOuterUp_R": 1.0},
    "AU4": {"browDown_L": 1.5, "browDown_R": 1.5},
    "AU5": {"eyeWide_L": 1.0, "eyeWide_R": 1.0},
    "AU6": {"cheekRaiser_L": 1.0, "cheekRaiser_R": 1.0},
    "AU7": {"eyeSquint_L": 1.0, "eyeSquint_R": 1.0},
    "AU9": {"noseSneer_L": 1.0, "noseSneer_R": 1.0},
    "AU10": {"mouthUpperUp_L": 1.0, "mouthUpperUp_R": 1.0},
    "AU12_L": {"mouthSmile_L": 1.0}, "AU12_R": {"mouthSmile_R": 1.0},
    "AU14": {"mouthDimple_L": 1.0, "mouthDimple_R": 1.0},
    "AU15": {"mouthFrown_L": 1.0, "mouthFrown_R": 1.0},
    "AU16": {"mouthLowerDown_L": 1.0, "mouthLowerDown_R": 1.0},
    "AU17": {"mouthShrugLower": 1.0},
    "AU18": {"mouthPucker": 1.0},
    "AU20": {"mouthStretch_L": 1.0, "mouthStretch_R": 1.0},
    "AU23": {"mouthRollUpper": 0.35, "mouthRollLower": 0.35, "mouthPucker": 0.25},
    "AU24": {"mouthPress_L": 1.0, "mouthPress_R": 1.0},
    "AU25": {"mouthClose": -0.12},
    "AU43_L": {"eyeBlink_L": 1.0}, "AU43_R": {"eyeBlink_R": 1.0},
}
#: Hairline: (|azimuth| degrees about the vertical axis through ``HAIR_CENTRE``, 0 = front) ->
#: elevation (degrees) above which the scalp carries hair.
HAIRLINE = ((0.0, 33.0), (20.0, 32.0), (40.0, 27.0), (55.0, 21.0), (68.0, 12.0), (76.0, -4.0), (80.0, -22.0),
            (86.0, -24.0), (90.0, -14.0), (112.0, -13.0), (122.0, -18.0), (135.0, -24.0), (155.0, -32.0),
            (180.0, -35.0))
HAIR_CENTRE = np.array([0.0, 0.03, -0.01])
#: Hair thickness (metres) by elevation (degrees): thick on top, short at the nape.
HAIR_PROFILE = ((-40.0, 0.003), (-10.0, 0.006), (15.0, 0.011), (45.0, 0.017), (90.0, 0.019))
HAIR_RAMP_DEG = 14.0  # the shell grows from the hairline to full thickness over this elevation band
HAIR_TUCK = 0.0006  # the rim lies this far under the skin (no gap)
HAIR_EDGE_DEG = 1.5  # the shell leaves the skin this far (degrees) below the hairline, rising steeply


@dataclass(frozen=True)
class HairStyle:
    """A hair shell: where the scalp carries hair and how far the shell stands off it.

    ``hairline``: (|azimuth| deg, elevation deg) pairs, the lower edge of the hair (as ``HAIRLINE``);
    ``top``: the same for an upper edge (a bald crown: hair only below it), or None; ``profile``:
    (elevation deg, metres) thickness pairs (as ``HAIR_PROFILE``); ``ramp_deg``: the band over which
    the shell rises from its edge to full thickness; ``azimuth_gain``: optional (|azimuth| deg, factor)
    pairs scaling the thickness by azimuth (fuller at the back or the sides); ``hang``: below the
    head's widest level the shell hangs straight down as a curtain (long hair, a bob) instead of
    following the neck and ears in.
    """

    hairline: tuple = HAIRLINE
    profile: tuple = HAIR_PROFILE
    top: tuple | None = None
    ramp_deg: float = HAIR_RAMP_DEG
    azimuth_gain: tuple | None = None
    hang: bool = False


#: today's default head's short hair
DEFAULT_HAIR = HairStyle()
#: jawOpen motions (metres) below which the jaw corrective fades out where the jaw weight is 0
JAW_FADE = (0.0003, 0.001)
#: AU26 (jaw drop) at coefficient 1 = ``jawOpen`` scaled to this jaw rotation (degrees).
JAW_AU26_DEG = 12.0


def smoothstep(x: np.ndarray, a: float, b: float) -> np.ndarray:
    """0 below a, 1 above b, C1 smooth in between."""
    t = np.clip((np.asarray(x, dtype=np.float64) - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def load_ict(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read the ICT-FaceKit npz (float64 copies), with a clear error for a missing or wrong file."""
    p = Path(path)
    if not p.is_file():
        raise FlameError(f"{p}: ICT-FaceKit source not found (expected ict_facekit_light.npz; see "
                         f"docs/default_head.md)")
    need = {"neutral": (26719, 3), "triangles": (52220, 3), "uv": None, "triangle_uv": (52220, 3),
            "expression_names": (57,), "expression_deltas": (57, 26719, 3), "identity_deltas": None,
            "landmarks68": (68,)}
    try:
        with np.load(p, allow_pickle=False) as z:
            out = {k: np.asarray(z[k]) for k in need if k in z.files}
    except (OSError, ValueError) as exc:
        raise FlameError(f"{p}: cannot read the ICT-FaceKit npz ({exc})") from exc
    for k, shape in need.items():
        if k not in out:
            raise FlameError(f"{p}: missing key {k!r} (found {sorted(out)})")
        if shape is not None and out[k].shape != shape:
            raise FlameError(f"{p}: {k}: expected shape {shape}, found {out[k].shape}")
    return out


# --------------------------------------------------------------------------- geometry helpers


def _sphere_fit(p: np.ndarray) -> tuple[np.ndarray, float]:
    a = np.c_[2.0 * p, np.ones(len(p))]
    x = np.linalg.lstsq(a, (p * p).sum(1), rcond=None)[0]
    c = x[:3]
    return c, float(np.sqrt(x[3] + c @ c))


def _eyeball_centre(p: np.ndarray) -> np.ndarray:
    """Centre of the eyeball body: a sphere fit to the sclera away from the corneal bulge."""
    c, _ = _sphere_fit(p)
    for _ in range(3):
        q = p - c
        front = q[:, 2] / np.linalg.norm(q, axis=1) > np.cos(np.radians(40.0))
        c, _ = _sphere_fit(p[~front])
    return c


def _components(n: int, f: np.ndarray) -> np.ndarray:
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)[1]


def _point_in_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule, p (N, 2), poly (M, 2) closed implicitly."""
    inside = np.zeros(len(p), bool)
    x, y = p[:, 0], p[:, 1]
    for i in range(len(poly)):
        (x0, y0), (x1, y1) = poly[i], poly[(i + 1) % len(poly)]
        cross = ((y0 > y) != (y1 > y))
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= cross & (x < xi)
    return inside


@dataclass
class _Head:
    v: np.ndarray  # (V, 3) metres
    f: np.ndarray  # (F, 3)
    uv: np.ndarray  # (U, 2)
    fuv: np.ndarray  # (F, 3)
    part: np.ndarray  # (V,) index into PART_ORDER
    expr: dict  # ICT name -> (V, 3) metres
    ident: np.ndarray  # (V, 3, K)
    landmarks: np.ndarray  # (68,) vertex ids
    eye_centres: np.ndarray  # (2, 3)


PART_ORDER = tuple(PARTS)


def _convert(ict: dict[str, np.ndarray], n_identity: int, identity: np.ndarray | None = None,
             ipd: float = IPD) -> _Head:
    n_src = ict["neutral"].shape[0]
    part = np.zeros(n_src, np.int64)
    for i, name in enumerate(PART_ORDER):
        a, b = PARTS[name]
        part[a:b + 1] = i
    keep = ~np.isin(part, [PART_ORDER.index(p) for p in DROPPED_PARTS])
    new_id = np.cumsum(keep) - 1
    tri = ict["triangles"].astype(np.int64)
    tkeep = keep[tri].all(1)
    f = new_id[tri[tkeep]]
    fuv_src = ict["triangle_uv"].astype(np.int64)[tkeep]
    used_uv = np.unique(fuv_src)
    uv_map = np.full(len(ict["uv"]), -1, np.int64)
    uv_map[used_uv] = np.arange(len(used_uv))
    uv = ict["uv"].astype(np.float64)[used_uv]
    fuv = uv_map[fuv_src]

    neutral = ict["neutral"].astype(np.float64)
    if identity is not None:  # a patient: ICT's neutral plus its identity modes (ICT units, ~1 = 1 s.d.)
        c = np.asarray(identity, np.float64).reshape(-1)
        if len(c) > len(ict["identity_deltas"]) or not np.all(np.isfinite(c)):
            raise FlameError(f"identity: expected at most {len(ict['identity_deltas'])} finite coefficients, "
                             f"found {len(c)}")
        neutral = neutral + np.einsum("k,kvc->vc", c, ict["identity_deltas"][:len(c)].astype(np.float64))
    cl = _eyeball_centre(neutral[PARTS["sclera_left"][0]:PARTS["sclera_left"][1] + 1])
    cr = _eyeball_centre(neutral[PARTS["sclera_right"][0]:PARTS["sclera_right"][1] + 1])
    s = float(ipd) / float(np.linalg.norm(cl - cr))
    mid = 0.5 * (cl + cr)
    v = (neutral - mid) * s + EYE_MIDPOINT
    eye_centres = (np.stack([cl, cr]) - mid) * s + EYE_MIDPOINT
    names = [str(x) for x in ict["expression_names"]]
    expr = {nm: ict["expression_deltas"][i].astype(np.float64)[keep] * s for i, nm in enumerate(names)}
    ident = np.moveaxis(ict["identity_deltas"][:n_identity].astype(np.float64), 0, 2)[keep] * s
    lm = new_id[ict["landmarks68"].astype(np.int64)]
    return _Head(v[keep], f, uv, fuv, part[keep], expr, ident, lm, eye_centres)


# --------------------------------------------------------------------------- hair


def _hair_angles(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    q = p - HAIR_CENTRE
    az = np.degrees(np.arctan2(q[:, 0], q[:, 2]))
    el = np.degrees(np.arctan2(q[:, 1], np.hypot(q[:, 0], q[:, 2])))
    return az, el


def hair_coverage(p: np.ndarray, style: HairStyle = DEFAULT_HAIR) -> np.ndarray:
    """(N,) elevation (degrees) of each point inside the hair's edges (> 0: under the hair)."""
    az, el = _hair_angles(p)
    a, e = np.array(style.hairline).T
    cov = el - np.interp(np.abs(az), a, e)
    if style.top is not None:
        a, e = np.array(style.top).T
        cov = np.minimum(cov, np.interp(np.abs(az), a, e) - el)
    return cov


def hair_thickness(p: np.ndarray, style: HairStyle = DEFAULT_HAIR) -> np.ndarray:
    """Signed offset (metres) of the hair shell over a scalp point (negative = tucked under the skin)."""
    az, el = _hair_angles(p)
    a, t = np.array(style.profile).T
    full = np.interp(el, a, t)
    if style.azimuth_gain is not None:
        a, g = np.array(style.azimuth_gain).T
        full = full * np.interp(np.abs(az), a, g)
    x = np.clip((hair_coverage(p, style) + HAIR_EDGE_DEG) / style.ramp_deg, 0.0, 1.0)
    ramp = 1.0 - (1.0 - x) ** 2  # steep at the hairline (a crisp edge, no z-fighting band), flat on top
    return -HAIR_TUCK + (full + HAIR_TUCK) * ramp


def _hang(pos: np.ndarray, coverage: np.ndarray, n_az: int = 72, n_y: int = 64) -> np.ndarray:
    """Hair below the widest level falls straight: each point moves out horizontally (about the vertical
    axis through ``HAIR_CENTRE``) to the largest radius of the shell above it at its azimuth (a
    running maximum from the top over azimuth/height bins, averaged over 5 neighbouring azimuths),
    behind the ears only, and easing back onto the skin over the last 2.5 degrees before the hair's edge
    (``coverage``), so the curtain's edges close onto the head."""
    d = pos[:, [0, 2]] - HAIR_CENTRE[[0, 2]]
    r = np.hypot(d[:, 0], d[:, 1])
    az = np.arctan2(d[:, 0], d[:, 1])
    ab = np.floor((az + np.pi) / (2 * np.pi) * n_az).astype(np.int64) % n_az
    y = pos[:, 1]
    yb = np.clip(np.floor((y - y.min()) / max(np.ptp(y), 1e-9) * n_y).astype(np.int64), 0, n_y - 1)
    grid = np.zeros((n_az, n_y))
    np.maximum.at(grid, (ab, yb), r)
    top_down = np.maximum.accumulate(grid[:, ::-1], axis=1)[:, ::-1]
    top_down = sum(np.roll(top_down, k, axis=0) for k in range(-2, 3)) / 5.0
    # only behind the ears (the face and the hairline in front keep to the head)
    w = smoothstep(np.degrees(np.abs(az)), 95.0, 115.0) * smoothstep(coverage, 0.0, 2.5)
    r_new = r + w * np.maximum(top_down[ab, yb] - r, 0.0)
    scale = r_new / np.maximum(r, 1e-9)
    out = pos.copy()
    out[:, 0] = HAIR_CENTRE[0] + d[:, 0] * scale
    out[:, 2] = HAIR_CENTRE[2] + d[:, 1] * scale
    return out


def _subdivide(f: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint subdivision: new faces and (E, 2) parent vertex pairs of the new midpoints."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.reshape(3, -1).T + n_vertices  # midpoint ids of edges (01, 12, 20)
    a, b, c = f.T
    m01, m12, m20 = inv.T
    nf = np.concatenate([np.c_[a, m01, m20], np.c_[m01, b, m12], np.c_[m20, m12, c], np.c_[m01, m12, m20]])
    return nf, uniq


def _hair(h: _Head, skin_parts: np.ndarray, style: HairStyle = DEFAULT_HAIR) -> dict[str, np.ndarray]:
    """The hair shell: parent vertices, subdivision, offsets, UVs."""
    cov = hair_coverage(h.v, style)
    skin_v = skin_parts[h.part]
    # every skin triangle with a corner where the shell rises: the patch's rim then lies where the
    # shell is tucked under the skin
    under = skin_v & (cov > -HAIR_EDGE_DEG)
    ft = h.f[skin_v[h.f].all(1) & under[h.f].any(1)]
    ids = np.unique(ft)
    local = np.full(len(h.v), -1, np.int64)
    local[ids] = np.arange(len(ids))
    f0 = local[ft]
    f1, pairs = _subdivide(f0, len(ids))
    # interpolation matrix rows: parent vertices (identity) then edge midpoints (0.5, 0.5)
    n1 = len(ids) + len(pairs)
    rows = np.concatenate([np.arange(len(ids)), np.repeat(np.arange(len(ids), n1), 2)])
    cols = np.concatenate([ids, ids[pairs.reshape(-1)]])
    vals = np.concatenate([np.ones(len(ids)), np.full(2 * len(pairs), 0.5)])
    interp = coo_matrix((vals, (rows, cols)), shape=(n1, len(h.v))).tocsr()
    base = interp @ h.v
    nrm_all = vertex_normals(h.v, h.f[skin_v[h.f].all(1)])
    nrm = interp @ nrm_all
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    pos = base + hair_thickness(base, style)[:, None] * nrm
    if style.hang:
        pos = _hang(pos, hair_coverage(base, style))
    # UVs in tile 7: u along the comb direction (crown -> hairline), v = |azimuth about the crown| / pi
    pole = np.array([0.0, 1.0, -0.35])
    pole /= np.linalg.norm(pole)
    q = base - HAIR_CENTRE
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    theta = np.arccos(np.clip(q @ pole, -1, 1))
    ex = np.array([1.0, 0.0, 0.0])
    ez = np.cross(ex, pole)  # toward the front, perpendicular to the pole
    phi = np.arctan2(q @ ex, q @ ez)
    u = 7.01 + 0.98 * theta / theta.max()
    vv = 0.01 + 0.98 * np.abs(phi) / np.pi
    return {"interp": interp, "faces": f1, "vertices": pos, "uv": np.c_[u, vv],
            "coverage": hair_coverage(base, style)}


# --------------------------------------------------------------------------- regions


def _regions(h: _Head, hair_cov: np.ndarray) -> np.ndarray:
    v, p = h.v, h.part
    po = {nm: i for i, nm in enumerate(PART_ORDER)}
    R = {nm: i for i, nm in enumerate(REGION_NAMES)}
    reg = np.full(len(v), R["skin"], np.int64)
    skin = np.isin(p, [po["face"], po["head_neck"]])
    lm = v[h.landmarks]
    # neck: below the jaw line (landmarks 3..13 at the front, the ear-lobe level at the back)
    jaw_y = np.interp(v[:, 0], lm[3:14, 0], lm[3:14, 1])
    neck = skin & (((v[:, 2] > 0.0) & (v[:, 1] < jaw_y - 0.004) & (np.abs(v[:, 0]) < 0.06))
                   | (v[:, 1] < -0.1 + 0.25 * np.minimum(v[:, 2], 0.0))
                   | ((v[:, 2] <= 0.0) & (v[:, 1] < -0.07)))
    reg[neck] = R["neck"]
    reg[skin & (hair_cov > 0.0)] = R["scalp"]
    # ears: the skin sticking out more than 2.5 mm from a quadratic fit of the side of the head
    # around them (fitted to a ring of skin outside the ear's ellipse)
    ear = np.zeros(len(v), bool)
    for sgn in (1.0, -1.0):
        side = skin & (sgn * v[:, 0] > 0.04)
        q = ((v[:, 1] - EAR_CENTRE[1]) / EAR_RADII[0]) ** 2 + ((v[:, 2] - EAR_CENTRE[2]) / EAR_RADII[1]) ** 2
        ring = side & (q > 1.0) & (q < 2.6) & (sgn * v[:, 0] > 0.055)
        yy, zz = v[:, 1] - EAR_CENTRE[1], v[:, 2] - EAR_CENTRE[2]
        basis = np.c_[np.ones(len(v)), yy, zz, yy * yy, zz * zz, yy * zz]
        coef = np.linalg.lstsq(basis[ring], sgn * v[ring, 0], rcond=None)[0]
        ear |= side & (q < 1.0) & (sgn * v[:, 0] > basis @ coef + 0.0025)
    reg[ear] = R["ears"]
    front = (p == po["face"]) & (v[:, 2] > 0.03)
    # brows: a tapered band along a quadratic fitted through the brow landmarks (17-21, 22-26), which
    # lie on the brow's upper half: 9 mm tall at the head (medial), 3 mm at the tail, rounded ends
    for ids in (np.arange(17, 22), np.arange(22, 27)):
        bx, by = np.abs(lm[ids, 0]), lm[ids, 1]
        coef = np.polyfit(bx, by, 2)
        x_med, x_lat = bx.min() - 0.002, bx.max() + 0.002
        ax = np.abs(v[:, 0])
        t = (ax - x_med) / (x_lat - x_med)
        cap = np.sqrt(np.clip(t / 0.08, 0, 1)) * np.sqrt(np.clip((1 - t) / 0.2, 0, 1))
        half = (0.0045 * (1 - t) + 0.0015 * t) * cap
        centre = np.polyval(coef, ax) - 0.0015 - 0.001 * (1 - t)
        same_side = np.sign(v[:, 0]) == np.sign(lm[ids[0], 0])
        reg[front & same_side & (t > 0) & (t < 1) & (np.abs(v[:, 1] - centre) < half)] = R["brows"]
    # lips: the face surface inside the outer lip contour (48..59)
    lips = (p == po["face"]) & _point_in_polygon(v[:, :2], lm[48:60, :2]) & (v[:, 2] > lm[48, 2] - 0.012)
    lips[h.landmarks[48:68]] = True  # the contour itself
    reg[lips] = R["lips"]
    # nostrils: the walls of the openings: above the nose's underside (subnasale + 1.5 mm), between
    # the alar bases, not facing forward, facing toward the nostril's axis (or down, beside the columella)
    nrm = vertex_normals(v, h.f)
    sx = np.sign(v[:, 0])
    xc = 0.5 * (abs(lm[31, 0]) + abs(lm[32, 0]))
    inward = ((sx * v[:, 0] - xc) * sx * nrm[:, 0] < 0.0) | ((nrm[:, 1] < -0.3) & (np.abs(v[:, 0]) > 0.0035))
    nos = ((p == po["face"]) & (np.abs(v[:, 0]) < abs(lm[31, 0]) + 0.002) & (v[:, 1] > lm[33, 1] + 0.0015)
           & (v[:, 1] < lm[33, 1] + 0.014) & (v[:, 2] < lm[30, 2] - 0.006) & (v[:, 2] > lm[31, 2] - 0.025)
           & (nrm[:, 2] < 0.35) & inward)
    reg[nos] = R["nostrils"]
    reg[p == po["mouth_socket"]] = R["mouth_interior"]
    reg[np.isin(p, [po["eye_socket_left"], po["eye_socket_right"]])] = R["eye_pocket"]
    reg[p == po["teeth"]] = R["teeth"]
    reg[np.isin(p, [po["lashes_left"], po["lashes_right"]])] = R["lashes"]
    gt = p == po["gums_tongue"]
    reg[gt] = R["gums"]
    reg[gt & _tongue_mask(h)] = R["tongue"]
    for e, (sc, ir) in enumerate((("sclera_left", "iris_left"), ("sclera_right", "iris_right"))):
        c = h.eye_centres[e]
        ids = np.where(np.isin(p, [po[sc], po[ir]]))[0]
        q = v[ids] - c
        ang = np.degrees(np.arccos(np.clip(q[:, 2] / np.linalg.norm(q, axis=1), -1, 1)))
        lab = np.full(len(ids), R["eyeball_left" if e == 0 else "eyeball_right"])
        lab[ang < IRIS_HALF_ANGLE] = R["iris"]
        lab[ang < PUPIL_HALF_ANGLE] = R["pupil"]
        reg[ids] = lab
    return reg


EAR_CENTRE = np.array([0.072, -0.02, -0.03])  # (|x|, y, z) and the (y, z) radii of the ear's ellipse
EAR_RADII = np.array([0.04, 0.03])
IRIS_HALF_ANGLE = 23.0
PUPIL_HALF_ANGLE = 8.5


def _tongue_mask(h: _Head) -> np.ndarray:
    """Gums-and-tongue vertices of the tongue (and the floor of the mouth under it).

    That part is one connected mesh; its UV islands separate the pieces. The tongue's islands span
    the midline, reach back behind the teeth (z < 2 cm) and move with ``jawOpen``; the gums' and the
    palate's do not (the palate and the uvula stay with the skull, the gums hug the teeth).
    """
    gt = h.part == PART_ORDER.index("gums_tongue")
    fsel = gt[h.f].all(1)
    island = _components(len(h.uv), h.fuv[fsel])[h.fuv[fsel][:, 0]]
    out = np.zeros(len(h.v), bool)
    move = np.linalg.norm(h.expr["jawOpen"], axis=1)
    for c in np.unique(island):
        vids = np.unique(h.f[fsel][island == c])
        p = h.v[vids]
        if p[:, 0].min() < -0.01 and p[:, 0].max() > 0.01 and p[:, 2].min() < 0.02 and move[vids].mean() > 0.001:
            out[vids] = True
    return out


# --------------------------------------------------------------------------- rig


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _fit_jaw(p0: np.ndarray, p1: np.ndarray) -> tuple[float, np.ndarray]:
    """Angle (about +x) and pivot of the planar rigid motion (y, z) taking p0 to p1."""
    a, b = p0[:, 1:], p1[:, 1:]
    ca, cb = a.mean(0), b.mean(0)
    h = (a - ca).T @ (b - cb)
    ang = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r2 = _rot_x(ang)[1:, 1:]
    t = cb - r2 @ ca
    piv = np.linalg.solve(np.eye(2) - r2, t)
    return float(ang), np.array([0.0, piv[0], piv[1]])


def _convex_weights(points: np.ndarray, target: np.ndarray, lam: float = 10.0) -> np.ndarray:
    a = np.vstack([points.T, lam * np.ones((1, len(points)))])
    b = np.concatenate([target, [lam]])
    x, res = nnls(a, b)
    if res > 1e-9:
        raise RuntimeError(f"default head: joint {target} is not inside its regressor vertices (res {res:.2e})")
    return x


def _mirror_map(v: np.ndarray) -> np.ndarray:
    tree = cKDTree(v)
    d, j = tree.query(v * np.array([-1.0, 1.0, 1.0]))
    return np.where(d < 1e-6, j, np.arange(len(v)))


def _regressor_row(v: np.ndarray, cand: np.ndarray, target: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    row = np.zeros(len(v))
    row[cand] = _convex_weights(v[cand], target)
    if abs(target[0]) < 1e-12:  # symmetrise (the mirrored combination is exact too)
        sym = np.zeros(len(v))
        np.add.at(sym, mirror, row)
        row = 0.5 * (row + sym)
    return row


# --------------------------------------------------------------------------- build


def build_from_ict(ict: dict[str, np.ndarray], n_identity: int = N_IDENTITY, identity: np.ndarray | None = None,
                   ipd: float = IPD, hair: HairStyle = DEFAULT_HAIR) -> dict[str, np.ndarray]:
    """The default head's arrays (float64 / int64) from the ICT arrays of :func:`load_ict`.

    ``identity`` (ICT identity-mode coefficients added to ICT's neutral), ``ipd`` (metres between the
    eyeball centres) and ``hair`` make a patient's head (docs/patients.md); the defaults give the
    default head.
    """
    h = _convert(ict, n_identity, identity, ipd)
    po = {nm: i for i, nm in enumerate(PART_ORDER)}
    skin_parts = np.zeros(len(PART_ORDER), bool)
    skin_parts[[po["face"], po["head_neck"]]] = True
    n0 = len(h.v)

    # ---- expressions (per AU component), eyeballs rigid
    eyeball = np.isin(h.part, [po[k] for k in ("sclera_left", "iris_left", "sclera_right", "iris_right")])
    expr = np.zeros((n0, 3, len(EXPRESSION_NAMES)))
    for i, name in enumerate(EXPRESSION_NAMES):
        for shape, w in AU_TO_ICT.get(name, {}).items():
            expr[:, :, i] += w * h.expr[shape]
    expr[eyeball] = 0.0

    # ---- jaw: rigid fit of the lower teeth in jawOpen
    teeth = h.part == po["teeth"]
    comp = _components(n0, h.f[teeth[h.f].all(1)])
    tid = np.where(teeth)[0]
    jaw_open = h.expr["jawOpen"]
    moving = np.linalg.norm(jaw_open[tid], axis=1) > 0.5 * np.linalg.norm(jaw_open[tid], axis=1).max()
    lower_teeth = np.zeros(n0, bool)
    for c in np.unique(comp[tid[moving]]):
        lower_teeth[tid[comp[tid] == c]] = True
    ang, pivot = _fit_jaw(h.v[lower_teeth], h.v[lower_teeth] + jaw_open[lower_teeth])
    if ang < 0:
        raise RuntimeError(f"default head: jawOpen rotates the lower teeth by {np.degrees(ang):.1f} deg (expected > 0)")
    rot = _rot_x(ang)
    rigid = (h.v - pivot) @ rot.T + pivot - h.v  # full-jaw motion at the jawOpen angle
    rr = np.einsum("vc,vc->v", rigid, rigid)
    w_jaw = np.clip(np.einsum("vc,vc->v", jaw_open, rigid) / (rr + 0.002 ** 2), 0.0, 1.0)
    gt = h.part == po["gums_tongue"]
    w_jaw[eyeball] = 0.0
    w_jaw[teeth] = lower_teeth[teeth].astype(float)
    gmove = np.linalg.norm(jaw_open, axis=1) > 0.5 * np.sqrt(rr)
    w_jaw[gt] = np.where(gmove[gt], np.maximum(w_jaw[gt], 0.0), 0.0)
    w_jaw[gt & (w_jaw > 0.5)] = 1.0
    w_jaw[np.isin(h.part, [po["lashes_left"], po["lashes_right"], po["eye_socket_left"], po["eye_socket_right"]])] = 0.0
    w_jaw[w_jaw < 0.02] = 0.0

    # ---- neck / root split and the skinning weights
    root = np.array([0.0, -0.175, -0.02])
    neck_j = np.array([0.0, -0.07, -0.025])
    jaw_j = pivot
    s_neck = h.v[:, 1] + 0.35 * (h.v[:, 2] + 0.02)
    head_share = smoothstep(s_neck, -0.165, -0.095)
    weights = np.zeros((n0, 5))
    jw = np.minimum(w_jaw, head_share)
    weights[:, 0] = 1.0 - head_share
    weights[:, 2] = jw
    weights[:, 1] = head_share - jw
    for e, key in enumerate(("left", "right")):
        ids = np.isin(h.part, [po[f"sclera_{key}"], po[f"iris_{key}"]])
        weights[ids] = 0.0
        weights[ids, 3 + e] = 1.0

    # ---- jaw correctives: what jawOpen does beyond the skinned rotation, per unit sin(angle)
    a_mat = np.eye(3)[None] + jw[:, None, None] * (rot - np.eye(3))[None]
    b_vec = jw[:, None] * (pivot - rot @ pivot)[None]
    target = h.v + jaw_open
    corr = np.linalg.solve(a_mat, (target - b_vec)[:, :, None])[:, :, 0] - h.v
    corr[eyeball | teeth] = 0.0  # rigid parts (the lower teeth: residual of the rigid fit, < 0.3 mm)
    # where jw = 0 (e.g. the throat) the corrective is jawOpen's own motion, faded out below 1 mm so the
    # jaw leaves the upper face alone (ICT's jawOpen stretches the skin up to the brows by < 0.3 mm)
    move = np.linalg.norm(jaw_open, axis=1)
    corr[jw == 0.0] *= smoothstep(move[jw == 0.0], JAW_FADE[0], JAW_FADE[1])[:, None]
    posedirs = np.zeros((n0, 3, 36))
    posedirs[:, :, 9 + 7] = 0.5 * corr / np.sin(ang)
    posedirs[:, :, 9 + 5] = -0.5 * corr / np.sin(ang)

    # ---- AU26 = jawOpen scaled to a jaw rotation of JAW_AU26_DEG (a blend shape, linear)
    expr[:, :, EXPRESSION_NAMES.index("AU26")] = np.radians(JAW_AU26_DEG) / ang * jaw_open
    expr[eyeball] = 0.0

    # ---- hair shell
    style = hair
    hair = _hair(h, skin_parts, style)
    interp = hair["interp"]
    n_h = interp.shape[0]

    def ext(a: np.ndarray) -> np.ndarray:  # append the hair rows (interpolated from the scalp)
        flat = a.reshape(n0, -1)
        return np.concatenate([flat, interp @ flat]).reshape((n0 + n_h,) + a.shape[1:])

    v_all = np.concatenate([h.v, hair["vertices"]])
    weights = ext(weights)
    weights /= weights.sum(1, keepdims=True)
    posedirs = ext(posedirs)
    expr = ext(expr)
    ident = ext(h.ident)
    # identity: eyeballs translate rigidly with their centre
    for e, key in enumerate(("left", "right")):
        ids = np.where(np.isin(h.part, [po[f"sclera_{key}"], po[f"iris_{key}"]]))[0]
        ident[ids] = ident[ids].mean(0, keepdims=True)
    faces = np.concatenate([h.f, hair["faces"] + n0])
    n_uv0 = len(h.uv)
    uv = np.concatenate([h.uv, hair["uv"]])
    faces_uv = np.concatenate([h.fuv, hair["faces"] + n_uv0])

    region = np.concatenate([_regions(h, hair_coverage(h.v, style)), np.full(n_h, REGION_NAMES.index("hair"))])

    # ---- joint regressor
    mirror = _mirror_map(v_all)
    jr = np.zeros((5, len(v_all)))
    surf = np.where(np.isin(np.concatenate([h.part, np.full(n_h, -1)]), [po["face"], po["head_neck"]]))[0]
    for j, t in enumerate((root, neck_j, jaw_j)):
        slab = surf[np.abs(v_all[surf, 1] - t[1]) < 0.01]
        jr[j] = _regressor_row(v_all, slab, t, mirror)
    for e, key in enumerate(("left", "right")):
        ids = np.where(h.part == po[f"sclera_{key}"])[0]
        jr[3 + e] = _regressor_row(v_all, ids, h.eye_centres[e], mirror)

    return {
        "v_template": v_all,
        "shapedirs": np.concatenate([ident, expr], axis=2),
        "posedirs": posedirs,
        "J_regressor": jr,
        "weights": weights,
        "kintree_table": KINTREE.copy(),
        "f": faces.astype(np.int64),
        "n_shape": np.array(ident.shape[2], dtype=np.int64),
        "n_expr": np.array(len(EXPRESSION_NAMES), dtype=np.int64),
        "expression_names": np.array(EXPRESSION_NAMES),
        "shape_names": np.array([f"ict_identity_{i:03d}" for i in range(ident.shape[2])]),
        "holo_viewer_default_head": np.array(1, dtype=np.int64),
        "has_teeth": np.array(1, dtype=np.int64),
        "vertex_region": region.astype(np.int64),
        "region_names": np.array(REGION_NAMES),
        "uv": uv,
        "faces_uv": faces_uv.astype(np.int64),
        "landmark_vertices": h.landmarks.astype(np.int64),
        "jaw_open_angle": np.array(ang),
    }


