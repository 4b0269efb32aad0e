"""Build time: paints the default head's albedo textures and colours from the rest mesh.

Pure numpy, no I/O, deterministic from a seed. :func:`generate_appearance` takes the rest mesh
(vertices, triangles, UDIM-style ``uv`` / ``faces_uv``, region labels and the 68 landmarks as 3-D
points) and paints:

* ``face`` (UDIM tile 0) and ``head`` (tile 1): skin with tone variation, cheek/nose/ear redness, a
  darker periorbital area, pores, fine wrinkles, forehead lines and crow's feet, lips with a crisp
  vermilion border and lip lines, brows as many thin strands, hair at the hairline and over the scalp
  (the mouth socket and eye pockets of tile 1 get their own colours);
* ``hair`` (tile 7): strands radiating from the crown with per-strand colour, darker roots;
* ``eye_left`` / ``eye_right``: sclera with faint vessels, iris with limbal ring and radial
  fibres, black pupil, painted by the 3-D angle from each eye's optical axis (the eyeballs'
  UVs overlap the face tile, so each eye gets its own image);
* per-vertex colours for the rest (teeth, gums, tongue, mouth interior, lashes).

Every texture is painted as a function of 3-D position: each texture's triangles are rasterised in
UV space (barycentric interpolation) into a position map and a region map, and the paint functions
work on the positions in a face frame built from the landmarks (millimetres, +x toward the subject's
left, +y up, +z out of the face), so the tiles meet without seams and the result does not depend on
the mesh's units. See docs/appearance.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..geometry import vertex_normals
from ..flame.appearance import (_BROW, _HAIR, _LIP, _SKIN, _VERTEX_COLORS, EYE_TEXTURE_SIZE, LASH_TEXTURE_SIZE,
                                MATERIAL_TEXTURE, MATERIALS, TEXTURE_SIZE, TEXTURE_TILE, AppearanceMesh, HeadAppearance,
                                _signed_dist_polygon, _to_local, assemble_appearance, face_frame)

__all__ = ["generate_appearance", "rasterize_uv", "face_frame", "eye_axis", "Look", "DEFAULT_LOOK"]


@dataclass(frozen=True)
class Look:
    """Who the skin, hair and eyes belong to (a patient: docs/patients.md); the defaults paint the
    default head. Colours are linear-ish albedo in [0, 1].

    ``skin``: base skin albedo (by Fitzpatrick type); ``redness``: scale of the cheek/nose/ear flush
    (less visible on dark skin); ``periorbital``: scale of the darker skin around the eyes; ``beard``:
    the cool shadow of shaved stubble (0 for a woman); ``lip``: lip albedo; ``hair`` / ``brow``: hair
    and brow colours; ``grey``: fraction of white strands in hair and brows; ``brow_grey``: the brows'
    own white fraction when given (brows often grey later than the hair, and a white brow on pale skin
    is lost to a landmark detector that a clinician's eye is not); ``brow_density``: brow
    strands relative to 1400 a brow; ``age``: 0 young .. 1 old: deeper forehead lines and crow's
    feet, nasolabial and marionette folds, under-eye lines, age spots, coarser texture;
    ``iris`` / ``iris_outer``: iris colours at the pupil and at the limbus.

    Dark hair on the panel's black (docs/patients.md "Dark hair"): ``sheen``: strength of the baked
    primary highlight of the strands (Kajiya-Kay: bright where the strand tangent is perpendicular to
    the half-vector of the previews' key light and a frontal view; a slightly cool, uncoloured
    reflection, with a weaker warm secondary band toward the tips, broken up by clumps);
    ``strand_var``: extra strand-to-strand value variation (a share of lighter strands);
    ``rim``: value lifted where the hair turns away from a frontal view (flyaways catching light at
    the silhouette). All 0 (the default) paint exactly the earlier hair.

    ``hair_value``: the hair shell's texture (base and white strands alike) scaled by this; the hair
    painted on the skin and scalp textures keeps its value (1, the default, paints exactly the earlier
    hair). A lever for helen's fidelity, measured but set by no recipe yet: her near-white hair against the
    panel's black puts half her fitted avatar's error on its outline (docs/avatar_fit.md "A greyer helen").
    """

    skin: tuple = tuple(_SKIN)
    redness: float = 1.0
    periorbital: float = 1.0
    beard: float = 1.0
    lip: tuple = tuple(_LIP)
    hair: tuple = tuple(_HAIR)
    brow: tuple = tuple(_BROW)
    grey: float = 0.0
    brow_grey: float | None = None
    brow_density: float = 1.0
    age: float = 0.0
    iris: tuple = (0.36, 0.25, 0.14)
    iris_outer: tuple = (0.24, 0.20, 0.14)
    sheen: float = 0.0
    strand_var: float = 0.0
    rim: float = 0.0
    hair_value: float = 1.0


DEFAULT_LOOK = Look()

#: the previews' key light (``flame.preview.add_key_lights``: camera direction + 0.6 up + 0.5 toward
#: the subject's right) and a frontal view, in the face frame; the hair sheen is baked for them
_KEY_LIGHT = np.array([-0.5, 0.6, 1.0]) / np.linalg.norm([-0.5, 0.6, 1.0])
_VIEW = np.array([0.0, 0.0, 1.0])
#: Kajiya-Kay exponents of the primary (R) and secondary (TRT) highlights and their tangents' shifts
#: along the normal (the cuticle's tilt moves R toward the root, TRT toward the tip: Marschner et al.
#: 2003); R's shift (about 14 deg) puts the band over the upper front of the head, as the key light does
_SHEEN_POWER = (60.0, 14.0)
_SHEEN_SHIFT = (-0.25, 0.14)
#: neighbour averagings of the normals the sheen is baked with (the shell's ribs would streak it)
_SHEEN_SMOOTH = 6
#: the primary highlight's colour: the light's, a little cool against the warm pigment
_SHEEN_COLOUR = np.array([0.86, 0.90, 0.97])




# ============================================================================== noise
def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Uniform [0, 1) per integer lattice point (wrapping uint64 arithmetic)."""
    with np.errstate(over="ignore"):
        h = (ix.astype(np.uint64) * np.uint64(0x9E3779B185EBCA87)) ^ \
            (iy.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F))
        h ^= iz.astype(np.uint64) * np.uint64(0x165667B19E3779F9)
        h ^= np.uint64((seed * 0x27D4EB2F165667C5) & 0xFFFFFFFFFFFFFFFF)
        h ^= h >> np.uint64(29)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(32)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def _vnoise(p: np.ndarray, seed: int) -> np.ndarray:
    """3-D value noise in [0, 1] at (N, 3) points (unit lattice, smoothstep interpolation)."""
    p = np.asarray(p, dtype=np.float64)
    i = np.floor(p)
    f = p - i
    i = i.astype(np.int64)
    w = f * f * (3.0 - 2.0 * f)
    out = np.zeros(len(p))
    for dx in (0, 1):
        wx = w[:, 0] if dx else 1.0 - w[:, 0]
        for dy in (0, 1):
            wy = w[:, 1] if dy else 1.0 - w[:, 1]
            for dz in (0, 1):
                wz = w[:, 2] if dz else 1.0 - w[:, 2]
                out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def _fbm(p: np.ndarray, seed: int, octaves: int = 4) -> np.ndarray:
    """Fractal value noise, zero mean, roughly in [-0.5, 0.5]."""
    out = np.zeros(len(p))
    amp, total = 1.0, 0.0
    for o in range(octaves):
        out += amp * (_vnoise(p * (2.0 ** o) + 17.3 * o, seed + 101 * o) - 0.5)
        total += amp
        amp *= 0.5
    return out / total


def _noise1(x: np.ndarray, seed: int) -> np.ndarray:
    """1-D value noise in [0, 1] (smooth between integer cells)."""
    i = np.floor(x)
    f = x - i
    i = i.astype(np.int64)
    w = f * f * (3.0 - 2.0 * f)
    z = np.zeros_like(i)
    return (1.0 - w) * _hash(i, z, z, seed) + w * _hash(i + 1, z, z, seed)


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((np.asarray(x, dtype=np.float64) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# ============================================================================== geometry helpers
def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)


def _smoothed_normals(v: np.ndarray, f: np.ndarray, iterations: int = 0) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals (:func:`holo_viewer.geometry.vertex_normals`), averaged over
    neighbours ``iterations`` times (smooth over the hair shell's ribs, for the baked sheen)."""
    n = _unit(vertex_normals(v, f))
    for _ in range(iterations):
        acc = n.copy()
        for a, b in ((0, 1), (1, 2), (2, 0), (1, 0), (2, 1), (0, 2)):
            np.add.at(acc, f[:, a], n[f[:, b]])
        n = _unit(acc)
    return n


def _cyl(q: np.ndarray, radius: float = 75.0) -> np.ndarray:
    """(arc-length across the face, height) in mm on a vertical cylinder around the head."""
    return np.stack([radius * np.arctan2(q[:, 0], q[:, 2] + radius), q[:, 1]], axis=1)


def rasterize_uv(uv_corners: np.ndarray, size: int,
                 offset: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise triangles given in UV into a ``size`` x ``size`` image.

    Texel (row i, col j) has its centre at u = offset_u + (j + 0.5) / size, v = offset_v + 1 - (i + 0.5) / size
    (row 0 at the top, v up). A texel is covered when its centre lies inside a triangle (edges
    included, tolerance 1e-9); where triangles overlap the one with the higher index wins.

    Parameters
    ----------
    uv_corners : numpy.ndarray
        (T, 3, 2) UV of each triangle's corners.
    size : int
        Image side in texels.
    offset : (float, float)
        UV of the image's lower-left corner (the UDIM tile origin).

    Returns
    -------
    (tri, bary) : numpy.ndarray
        (size, size) int64 triangle index per texel (-1: uncovered) and (size, size, 3) float64
        barycentric coordinates of the texel centre.
    """
    t = (np.asarray(uv_corners, dtype=np.float64) - np.asarray(offset, dtype=np.float64)) * size
    # pixel coordinates: x = u * size - 0.5 (column), y = (1 - v) * size - 0.5 (row)
    px = t[..., 0] - 0.5
    py = size - t[..., 1] - 0.5
    tri = np.full((size, size), -1, dtype=np.int64)
    bary = np.zeros((size, size, 3))
    if len(t) == 0:
        return tri, bary
    x0 = np.clip(np.ceil(px.min(1) - 1e-9), 0, size - 1).astype(np.int64)
    x1 = np.clip(np.floor(px.max(1) + 1e-9), 0, size - 1).astype(np.int64)
    y0 = np.clip(np.ceil(py.min(1) - 1e-9), 0, size - 1).astype(np.int64)
    y1 = np.clip(np.floor(py.max(1) + 1e-9), 0, size - 1).astype(np.int64)
    bw = np.maximum(x1 - x0 + 1, 0)
    bh = np.maximum(y1 - y0 + 1, 0)
    ok = (px.max(1) >= -0.5) & (px.min(1) <= size - 0.5) & (py.max(1) >= -0.5) & (py.min(1) <= size - 0.5)
    area = (px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (px[:, 2] - px[:, 0]) * (py[:, 1] - py[:, 0])
    ok &= np.abs(area) > 1e-12
    # bucket triangles by bounding-box size so each batch is a dense (n, bh, bw) grid
    big = np.maximum(bw, bh)
    cand_pix, cand_tri, cand_bary = [], [], []
    for lo_side, side in ((0, 2), (2, 4), (4, 8), (8, 16), (16, 32), (32, 64), (64, 128), (128, 1 << 30)):
        sel = np.nonzero(ok & (big > lo_side) & (big <= side))[0]
        if len(sel) == 0:
            continue
        mw, mh = int(bw[sel].max()), int(bh[sel].max())
        for start in range(0, len(sel), max(1, 4_000_000 // max(mw * mh, 1))):
            s = sel[start:start + max(1, 4_000_000 // max(mw * mh, 1))]
            gx = x0[s, None, None] + np.arange(mw)[None, None, :]
            gy = y0[s, None, None] + np.arange(mh)[None, :, None]
            gx, gy = np.broadcast_arrays(gx, gy)
            ax, ay = px[s, 0, None, None], py[s, 0, None, None]
            e1x, e1y = (px[s, 1] - px[s, 0])[:, None, None], (py[s, 1] - py[s, 0])[:, None, None]
            e2x, e2y = (px[s, 2] - px[s, 0])[:, None, None], (py[s, 2] - py[s, 0])[:, None, None]
            dx, dy = gx - ax, gy - ay
            a = area[s][:, None, None]
            b1 = (dx * e2y - dy * e2x) / a
            b2 = (e1x * dy - e1y * dx) / a
            b0 = 1.0 - b1 - b2
            inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
            inside &= (gx <= x1[s, None, None]) & (gy <= y1[s, None, None])
            k, r, c = np.nonzero(inside)
            cand_pix.append(gy[k, r, c] * size + gx[k, r, c])
            cand_tri.append(s[k])
            cand_bary.append(np.stack([b0[k, r, c], b1[k, r, c], b2[k, r, c]], axis=-1))
    if cand_pix:
        pix = np.concatenate(cand_pix)
        tid = np.concatenate(cand_tri)
        bar = np.concatenate(cand_bary)
        order = np.lexsort((-tid, pix))  # per texel, the highest triangle index first
        pix, tid, bar = pix[order], tid[order], bar[order]
        first = np.r_[True, pix[1:] != pix[:-1]]
        tri.reshape(-1)[pix[first]] = tid[first]
        bary.reshape(-1, 3)[pix[first]] = bar[first]
    return tri, bary


def _dilate(img: np.ndarray, mask: np.ndarray, passes: int = 8) -> np.ndarray:
    """Fill uncovered texels near the covered ones with the mean of covered neighbours (no seams
    bleeding background into bilinear/mipmapped lookups), then the rest with the mean colour."""
    img = img.copy()
    m = mask.copy()
    for _ in range(passes):
        acc = np.zeros_like(img)
        cnt = np.zeros(m.shape)
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)):
            sm = np.roll(np.roll(m, dy, 0), dx, 1)
            acc += np.roll(np.roll(img, dy, 0), dx, 1) * sm[..., None]
            cnt += sm
        grow = (~m) & (cnt > 0)
        img[grow] = acc[grow] / cnt[grow][:, None]
        m = m | grow
    if m.any():
        img[~m] = img[m].mean(0)
    return img


def _smooth_indicator(ind: np.ndarray, faces: np.ndarray, iterations: int) -> np.ndarray:
    c = ind.astype(np.float64)
    n = len(c)
    for _ in range(iterations):
        acc = c.copy()
        cnt = np.ones(n)
        for a, b in ((0, 1), (1, 2), (2, 0), (1, 0), (2, 1), (0, 2)):
            np.add.at(acc, faces[:, a], c[faces[:, b]])
            np.add.at(cnt, faces[:, a], 1.0)
        c = acc / cnt
    return c




# ============================================================================== painting
class _Painter:
    """Shared state of one generation: mesh, frame, landmarks in the frame, soft region maps."""

    def __init__(self, vertices, faces, region, region_names, landmarks, seed, look: Look = DEFAULT_LOOK):
        self.look = look
        self.v = vertices
        self.f = faces
        self.region = region
        self.names = list(region_names)
        self.seed = int(seed)
        self.frame = face_frame(landmarks)
        self.lm = _to_local(landmarks, self.frame)
        self.soft = {}

    def rid(self, name: str) -> int:
        return self.names.index(name) if name in self.names else -1

    def soft_region(self, names: Sequence[str], iterations: int = 3) -> np.ndarray:
        """Per-vertex indicator of ``names`` smoothed over the mesh (soft borders)."""
        key = (tuple(names), iterations)
        if key not in self.soft:
            ids = [self.rid(n) for n in names if self.rid(n) >= 0]
            ind = np.isin(self.region, ids) if ids else np.zeros(len(self.region), bool)
            self.soft[key] = _smooth_indicator(ind, self.f, iterations) if ids else ind.astype(np.float64)
        return self.soft[key]

    # ---------------------------------------------------------------- skin
    def skin(self, q: np.ndarray, soft: Mapping[str, np.ndarray], brow_map) -> np.ndarray:
        """Skin albedo at local points q (N, 3) mm; ``soft`` per-point soft region weights."""
        s = self.seed
        lm = self.lm
        n = len(q)
        L = self.look
        col = np.tile(np.asarray(L.skin, np.float64), (n, 1))
        # large-scale tone and mottling
        tone = _fbm(q / 45.0, s + 1, 3)
        col *= (1.0 + 0.10 * tone)[:, None]
        mott = _fbm(q / 7.0, s + 2, 3)
        col *= (1.0 + np.array([0.05, 0.07, 0.07]) * mott[:, None])
        # redness: cheeks, nose, ears, chin
        red = np.zeros(n)
        for side in ((2, 31, 41), (14, 35, 46)):
            c = lm[list(side)].mean(0)
            red += 0.8 * np.exp(-np.sum((q - c) ** 2, axis=1) / (2 * 16.0 ** 2))
        red += 0.45 * np.exp(-np.sum((q - lm[30]) ** 2, axis=1) / (2 * 8.0 ** 2))
        for k in (31, 35):
            red += 0.45 * np.exp(-np.sum((q - lm[k]) ** 2, axis=1) / (2 * 6.0 ** 2))
        red += 0.35 * np.exp(-np.sum((q - lm[8] - [0, 6, 0]) ** 2, axis=1) / (2 * 12.0 ** 2))
        red += 0.8 * soft.get("ears", 0.0)
        red *= 1.0 + 0.5 * _fbm(q / 4.0, s + 3, 2)
        red = np.clip(red, 0, 1.2)
        col *= (1.0 - red[:, None] * (L.redness * np.array([0.02, 0.17, 0.14])))
        # periorbital: slightly darker, cooler, most below the eyes
        for eye in (range(36, 42), range(42, 48)):
            c = lm[list(eye)].mean(0)
            d = q - c
            w = np.exp(-(d[:, 0] ** 2 / (2 * 15.0 ** 2) + (d[:, 1] + 5.0) ** 2 / (2 * 9.0 ** 2)))
            col *= (1.0 - w[:, None] * (L.periorbital * np.array([0.10, 0.13, 0.10])))
        # subtle beard shadow on the upper lip, chin and jaw (below the mouth corners' level)
        jaw = _smoothstep(lm[33, 1] + 2.0, lm[33, 1] - 6.0, q[:, 1])
        jaw = jaw * _smoothstep(lm[8, 1] - 25.0, lm[8, 1] - 5.0, q[:, 1])
        jaw *= _smoothstep(-40.0, -15.0, q[:, 2] - lm[8, 2] + 50.0) * _smoothstep(70.0, 50.0, np.abs(q[:, 0]))
        jaw *= 1.0 - soft.get("lips_mask", 0.0)
        col *= (1.0 - (0.06 * L.beard) * jaw[:, None] * np.array([1.0, 0.9, 0.75]))
        # pores: small dark dots, denser on nose and cheeks
        pore_density = 0.5 + 0.5 * np.clip(red, 0, 1)
        pn = _vnoise(q / 0.55, s + 4)
        pores = _smoothstep(0.70, 0.92, pn) * pore_density
        col *= (1.0 - 0.09 * pores)[:, None]
        col *= (1.0 + 0.025 * (_vnoise(q / 0.25, s + 5) - 0.5))[:, None]
        # fine crossing micro-wrinkles (skin relief lines)
        w1 = np.abs(np.sin((q[:, 0] + q[:, 1] + 2.0 * _fbm(q / 3.0, s + 6, 2)) * 2.2))
        w2 = np.abs(np.sin((q[:, 0] - q[:, 1] + 2.0 * _fbm(q / 3.0, s + 7, 2)) * 2.6))
        micro = _smoothstep(0.15, 0.0, np.minimum(w1, w2))
        col *= (1.0 - (0.035 * (1.0 + 1.5 * L.age)) * micro)[:, None]
        cy = _cyl(q)
        # forehead lines (horizontal, broken)
        brow_top = max(lm[17:27, 1].max(), 0.0)
        fore = _smoothstep(brow_top + 6.0, brow_top + 12.0, q[:, 1])
        fore = fore * _smoothstep(brow_top + 48.0, brow_top + 35.0, q[:, 1])
        fore *= _smoothstep(55.0, 35.0, np.abs(cy[:, 0])) * _smoothstep(-40.0, -10.0, q[:, 2])
        wob = _fbm(np.c_[cy[:, 0] / 25.0, q[:, 1] / 25.0, np.zeros(n)], s + 8, 2)
        yy = q[:, 1] + 2.5 * wob * 2.0 + 0.0015 * cy[:, 0] ** 2
        ph = (yy - brow_top) / 8.5
        dist = (ph - np.round(ph)) * 8.5
        seg = _smoothstep(0.3, 0.6, _vnoise(np.c_[cy[:, 0] / 22.0, np.round(ph), np.zeros(n)], s + 9))
        lines = np.exp(-(dist / 0.8) ** 2) * fore * seg
        col *= (1.0 - (0.045 * (1.0 + 3.0 * L.age)) * lines)[:, None]
        # crow's feet: radial lines from the lateral eye corners
        for k, sgn in ((36, -1.0), (45, 1.0)):
            corner = _cyl(lm[k:k + 1])[0] + [sgn * 4.0, 0.0]
            d = cy - corner
            r = np.hypot(d[:, 0], d[:, 1])
            ang = np.arctan2(d[:, 1], sgn * d[:, 0])  # 0 = straight lateral
            region = _smoothstep(5.0, 9.0, r) * _smoothstep(24.0, 15.0, r) * _smoothstep(0.9, 0.5, np.abs(ang))
            region *= (sgn * d[:, 0] > 0)
            spacing = 0.16
            pa = (ang + 0.25 * _fbm(np.c_[r / 6.0, ang, np.zeros(n)], s + 10, 2)) / spacing
            dd = (pa - np.round(pa)) * spacing * r
            crow = np.exp(-(dd / 0.4) ** 2) * region
            col *= (1.0 - (0.07 * (1.0 + 2.5 * L.age)) * crow)[:, None]
        if L.age > 0:
            col = self.age_marks(q, col)
        # lips
        col = self.lips(q, col)
        # brows: strands over a faint shadow
        if brow_map is not None:
            dens, shade = brow_map(cy)
            col *= (1.0 - 0.10 * shade)[:, None]
            a = 1.0 - np.exp(-3.0 * dens)
            col = col * (1.0 - a[:, None]) + (self.brow_rgb(cy)[:, :] * (0.85 + 0.3 * shade[:, None])) * a[:, None]
        return col

    def brow_rgb(self, cy: np.ndarray) -> np.ndarray:
        """(N, 3) brow strand colour: the brow colour, a ``brow_grey`` (else ``grey``) share of white hairs."""
        brow = np.asarray(self.look.brow, np.float64)
        grey = self.look.grey if self.look.brow_grey is None else float(self.look.brow_grey)
        if grey <= 0:
            return np.broadcast_to(brow[None, :], (len(cy), 3))
        hair_id = _noise1(cy[:, 0] / 0.25 + 3.0 * _noise1(cy[:, 1] / 2.0, self.seed + 31), self.seed + 32)
        white = _smoothstep(1.0 - grey - 0.05, 1.0 - grey + 0.05, hair_id)[:, None]
        return brow[None, :] * (1 - white) + np.array([0.62, 0.60, 0.57])[None, :] * white

    def age_marks(self, q: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Folds and marks of an older face (scaled by ``look.age``): nasolabial and marionette folds,
        lines under the eyes, sparse age spots."""
        lm, s, a = self.lm, self.seed, self.look.age

        def fold(p0, p1, width, depth):
            d = p1 - p0
            t = np.clip(((q[:, :2] - p0) @ d) / (d @ d), 0.0, 1.0)
            dist = np.linalg.norm(q[:, :2] - (p0 + t[:, None] * d), axis=1)
            front = _smoothstep(-25.0, -10.0, q[:, 2] - lm[30, 2])
            prof = np.exp(-(dist / width) ** 2) * np.sin(np.pi * np.clip(t, 0.02, 0.98)) ** 0.5 * front
            # a dark crease with a light ridge on its outer side (the cheek fold)
            return prof * depth

        for sgn, ala, corner in ((-1, 31, 48), (1, 35, 54)):
            p0 = lm[ala, :2] + [sgn * 3.0, 2.0]
            p1 = lm[corner, :2] + [sgn * 4.0, -6.0]
            col *= (1.0 - a * fold(p0, p1, 1.8, 0.32) * (1 + 0.3 * _fbm(q / 3.0, s + 90, 2)))[:, None]
            col *= (1.0 + a * fold(p0 + [sgn * 3.5, 0], p1 + [sgn * 3.5, 0], 2.5, 0.06))[:, None]
            m0 = lm[corner, :2] + [sgn * 1.0, -2.0]
            m1 = m0 + [sgn * 3.0, -15.0]
            col *= (1.0 - a * fold(m0, m1, 1.3, 0.24))[:, None]
        for eye in (range(36, 42), range(42, 48)):
            c = lm[list(eye)].mean(0)
            d = q - c
            for k, off in enumerate((6.0, 9.5)):
                arc = d[:, 1] + off - 0.012 * d[:, 0] ** 2
                w = np.exp(-(arc / 0.6) ** 2) * _smoothstep(16.0, 8.0, np.abs(d[:, 0])) * (d[:, 2] > -15)
                col *= (1.0 - a * (0.10 - 0.03 * k) * w)[:, None]
        spots = _smoothstep(0.78, 0.9, _fbm(q / 2.2, s + 91, 2) * 0.5 + 0.5) \
            * _smoothstep(0.4, 0.7, _vnoise(q / 25.0, s + 92))
        col *= (1.0 - a * 0.18 * spots[:, None] * np.array([0.8, 1.0, 1.15]))
        col *= (1.0 + a * 0.04 * (_vnoise(q / 1.2, s + 93) - 0.5))[:, None]
        return col

    def lips(self, q: np.ndarray, col: np.ndarray) -> np.ndarray:
        lm = self.lm
        d_outer = _signed_dist_polygon(q[:, :2], lm[48:60, :2])  # < 0 inside
        near = q[:, 2] > lm[48:60, 2].min() - 12.0
        inside = _smoothstep(0.35, -0.35, d_outer) * near
        self.lip_weight = inside
        n = len(q)
        lipc = np.tile(np.asarray(self.look.lip, np.float64), (n, 1))
        lipc = lipc * (1.0 + 0.06 * _fbm(q / 3.0, self.seed + 20, 2))[:, None]
        # darker, wetter toward the inner contour
        d_inner = _signed_dist_polygon(q[:, :2], lm[60:68, :2])
        lipc *= (1.0 - 0.18 * _smoothstep(3.0, 0.0, d_inner))[:, None]
        # vertical lip lines
        xx = q[:, 0] + 1.2 * _fbm(q / 4.0, self.seed + 21, 2)
        ph = xx / 1.6
        dist = (ph - np.round(ph)) * 1.6
        broken = _vnoise(np.c_[np.round(ph), q[:, 1] / 3.0, np.zeros(n)], self.seed + 22)
        ll = np.exp(-(dist / 0.28) ** 2) * _smoothstep(0.4, 0.8, broken)
        lipc *= (1.0 - 0.10 * ll)[:, None]
        # white roll: a thin lighter band just outside the vermilion border
        roll = np.exp(-((d_outer - 0.7) / 0.45) ** 2) * near
        col = col * (1.0 + 0.07 * roll)[:, None]
        return col * (1.0 - inside[:, None]) + lipc * inside[:, None]

    # ---------------------------------------------------------------- brows
    def brow_map(self):
        """A density/shade sampler of brow strands in cylinder coordinates (strands splatted on a
        0.1 mm grid, blurred to the texel footprint)."""
        lm = self.lm
        rng = np.random.default_rng(self.seed + 30)
        res = 0.1
        cyl_lm = _cyl(lm)
        lo = cyl_lm[17:27].min(0) - [14.0, 16.0]
        hi = cyl_lm[17:27].max(0) + [14.0, 14.0]
        shape = (int(np.ceil((hi[1] - lo[1]) / res)) + 1, int(np.ceil((hi[0] - lo[0]) / res)) + 1)
        dens = np.zeros(shape)
        shade = np.zeros(shape)
        for pts in (cyl_lm[21:16:-1], cyl_lm[22:27]):  # medial -> lateral
            seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
            s_cum = np.r_[0.0, np.cumsum(seg)]
            length = s_cum[-1] + 3.0
            # extend 3 mm medially
            med_dir = (pts[0] - pts[1]) / np.linalg.norm(pts[0] - pts[1])
            pts = np.vstack([pts[0] + 3.0 * med_dir, pts])
            s_cum = np.r_[0.0, s_cum + 3.0]

            def curve(t):
                s_ = np.asarray(t) * length
                return np.stack([np.interp(s_, s_cum, pts[:, 0]), np.interp(s_, s_cum, pts[:, 1])], axis=-1)

            def tangent(t):
                dt = 1e-3
                d = curve(np.minimum(t + dt, 1.0)) - curve(np.maximum(t - dt, 0.0))
                return d / np.linalg.norm(d, axis=-1, keepdims=True)

            n_strands = int(round(1400 * self.look.brow_density))
            t = rng.random(n_strands) ** 1.15
            s = np.clip(rng.normal(0.0, 0.45, n_strands), -1.0, 1.0)
            half = 5.0 - 2.8 * t  # half thickness mm
            tg = tangent(t)
            nrm = np.stack([-tg[:, 1], tg[:, 0]], axis=-1)
            nrm *= np.sign(nrm[:, 1:2] + 1e-12)  # upward
            root = curve(t) + nrm * ((s * half) - 2.0)[:, None]
            # growth angle from the lateral tangent (positive = upward)
            body = _smoothstep(0.08, 0.38, t)
            lateral = 18.0 - 32.0 * np.clip(s, -1, 1) * 0.5 - 22.0 * _smoothstep(0.55, 1.0, t)
            ang = np.radians((1 - body) * 78.0 + body * lateral)
            ang += np.radians(rng.normal(0.0, 7.0, n_strands))
            ln = (5.0 + 3.5 * body) * rng.uniform(0.75, 1.2, n_strands)
            bend = np.radians(rng.uniform(-30.0, -5.0, n_strands))  # curls toward the tail
            dark = rng.uniform(0.7, 1.25, n_strands)
            m = 48
            u = np.linspace(0.0, 1.0, m)
            a = ang[:, None] + bend[:, None] * u[None, :]
            dirs = tg[:, None, :] * np.cos(a)[..., None] + nrm[:, None, :] * np.sin(a)[..., None]
            step = (ln / (m - 1))[:, None, None]
            path = root[:, None, :] + np.cumsum(dirs * step, axis=1) - dirs[:, :1] * step
            taper = (1.0 - 0.6 * u)[None, :] * dark[:, None]
            gx = (path[..., 0] - lo[0]) / res
            gy = (path[..., 1] - lo[1]) / res
            _splat(dens, gx.ravel(), gy.ravel(), np.broadcast_to(taper, gx.shape).ravel() * 0.5)
            # faint shadow of the brow body
            rt = curve(np.linspace(0, 1, 200))
            tt = np.linspace(0, 1, 200)
            tg2 = tangent(tt)
            nr2 = np.stack([-tg2[:, 1], tg2[:, 0]], axis=-1)
            nr2 *= np.sign(nr2[:, 1:2] + 1e-12)
            for off in np.linspace(-1, 1, 9):
                pp = rt + nr2 * (off * (5.0 - 2.8 * tt) - 1.0)[:, None]
                _splat(shade, (pp[:, 0] - lo[0]) / res, (pp[:, 1] - lo[1]) / res, np.full(200, 1.0))
        dens = _blur(dens, 1.2)
        shade = _blur(shade, 25.0)
        shade /= max(shade.max(), 1e-9)

        def sample(cy):
            x = (cy[:, 0] - lo[0]) / res
            y = (cy[:, 1] - lo[1]) / res
            inside = (x >= 0) & (x <= shape[1] - 1) & (y >= 0) & (y <= shape[0] - 1)
            d = np.zeros(len(cy))
            sh = np.zeros(len(cy))
            if inside.any():
                d[inside] = _bilinear_grid(dens, x[inside], y[inside])
                sh[inside] = _bilinear_grid(shade, x[inside], y[inside])
            return d, sh

        return sample

    # ---------------------------------------------------------------- hair
    def hair_color(self, q: np.ndarray, crown: np.ndarray, axis: np.ndarray,
                   uv: np.ndarray | None = None, normal: np.ndarray | None = None,
                   tangent: np.ndarray | None = None) -> np.ndarray:
        """Hair strands combed away from the crown, per-strand colour, clumps, darker roots.

        The strand index runs with the azimuth about the crown axis: from the hair shell's own
        UVs when given (tile 7: u from the crown toward the hairline, v = |azimuth| / pi, so the
        strands follow the shell's comb direction), else from the 3-D position (the scalp).
        ``normal`` / ``tangent``: (N, 3) unit surface normals and strand directions in the face
        frame, needed when the look has ``sheen`` or ``rim`` (:meth:`hair_sheen`).
        """
        s = self.seed
        n = len(q)
        if uv is not None:
            az = uv[:, 1] * np.pi
            polar = 150.0 * uv[:, 0]  # ~mm from the crown along the comb direction
        else:
            e1 = np.cross(axis, [1.0, 0.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(axis, e1)
            d = q - crown
            polar = np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)
            az = np.abs(np.arctan2(d @ e2, d @ e1))
        warp = 0.03 * _fbm(q / 30.0, s + 40, 3)
        strand = (az + warp) / np.pi * 2000.0
        c1 = _noise1(strand, s + 41)
        c3 = _noise1(strand * 2.7 + 5.0, s + 46)
        c2 = _noise1(strand * 0.06 + 11.0, s + 42)  # clumps of ~15 strands
        lum = 0.6 + 0.3 * c1 + 0.15 * c3
        lum *= 0.82 + 0.3 * c2
        lum *= 1.0 + 0.15 * _fbm(np.c_[strand / 40.0, polar / 20.0, np.zeros(n)], s + 43, 2)
        col = np.asarray(self.look.hair, np.float64)[None, :] * lum[:, None]
        warm = _noise1(strand * 0.5 + 3.0, s + 44)
        col *= (1.0 + 0.15 * (warm - 0.5))[:, None] * np.array([1.04, 1.0, 0.94])
        if self.look.grey > 0:  # white strands: each strand white or not (fine streaks), slightly yellowed
            k = np.floor(strand).astype(np.int64)
            white = (_hash(k, np.zeros_like(k), np.full_like(k, 7), s + 47) < self.look.grey).astype(np.float64)
            col = col * (1 - white[:, None]) + np.array([0.74, 0.72, 0.68])[None, :] * lum[:, None] * white[:, None]
        if self.look.strand_var > 0:  # a share of lighter strands (each strand lighter or not) and clumps
            k = np.floor(strand).astype(np.int64)
            light = _hash(k, np.zeros_like(k), np.full_like(k, 9), s + 48)
            col *= (1.0 + self.look.strand_var * (_smoothstep(0.55, 1.0, light) + 0.5 * (c2 - 0.5)))[:, None]
        # darker roots near the crown whorl
        col *= (0.6 + 0.4 * _smoothstep(0.0, 30.0, polar))[:, None]
        if (self.look.sheen > 0 or self.look.rim > 0) and normal is not None and tangent is not None:
            col = col + self.hair_sheen(normal, tangent, c1, c2, polar)
        return col

    def hair_shell_color(self, q: np.ndarray, crown: np.ndarray, axis: np.ndarray, uv: np.ndarray,
                         normal: np.ndarray | None = None, tangent: np.ndarray | None = None) -> np.ndarray:
        """The hair shell's texture: :meth:`hair_color` times the look's ``hair_value`` (the hair painted on
        the skin and scalp textures keeps :meth:`hair_color`'s value)."""
        col = self.hair_color(q, crown, axis, uv, normal, tangent)
        return col if self.look.hair_value == 1.0 else col * float(self.look.hair_value)

    def hair_sheen(self, n: np.ndarray, t: np.ndarray, c1: np.ndarray, c2: np.ndarray,
                   polar: np.ndarray) -> np.ndarray:
        """(N, 3) light added to the hair albedo by the look's ``sheen`` and ``rim`` (see :class:`Look`).

        Kajiya-Kay's strand highlight, ``sin(T, H) ** p``, for the key light and a frontal view, on
        the tangent tilted along the normal (the primary reflection toward the root, the secondary,
        coloured by the pigment, toward the tip); each visible only where the key light reaches
        the surface and the view sees it; clumps (``c2``) and single strands (``c1``) catch it
        unevenly. The rim term lifts the value where the surface turns away from the view.
        """
        look = self.look
        h = _KEY_LIGHT + _VIEW
        h = h / np.linalg.norm(h)
        lit = _smoothstep(-0.05, 0.35, n @ _KEY_LIGHT) * _smoothstep(-0.1, 0.25, n @ _VIEW)
        catch = (0.45 + 0.8 * c2) * (0.7 + 0.6 * c1)
        hair = np.asarray(look.hair, np.float64)
        pigment = hair / max(float(hair.max()), 1e-9)
        out = np.zeros((len(n), 3))
        for power, shift, colour, gain in ((_SHEEN_POWER[0], _SHEEN_SHIFT[0], _SHEEN_COLOUR, 1.0),
                                           (_SHEEN_POWER[1], _SHEEN_SHIFT[1], 0.5 * pigment, 0.35)):
            ts = t + shift * n
            ts /= np.maximum(np.linalg.norm(ts, axis=1, keepdims=True), 1e-12)
            sin_th = np.sqrt(np.clip(1.0 - (ts @ h) ** 2, 0.0, 1.0))
            out += (look.sheen * gain * lit * catch * sin_th ** power)[:, None] * colour[None, :]
        if look.rim > 0:
            edge = _smoothstep(0.45, 0.9, 1.0 - np.abs(n @ _VIEW))
            out += (look.rim * edge * (0.6 + 0.5 * c1))[:, None] * (0.5 * (pigment + 1.0))[None, :]
        return out * (0.6 + 0.4 * _smoothstep(0.0, 30.0, polar))[:, None]

    def hair_coverage(self, q: np.ndarray, scalp_soft: np.ndarray | None) -> np.ndarray:
        """Hair coverage on the skin tiles: from the scalp labels where there are any, else from a
        hairline on the forehead, temples and nape; individual hairs fray the edge."""
        lm = self.lm
        if scalp_soft is not None:
            base = scalp_soft
            edge = 0.18
        else:
            # a hairline around the head by azimuth (0 = the face, 180 = the back of the head)
            brow_top = lm[17:27, 1].max()
            ear_top = lm[0, 1] + 22.0
            phi = np.degrees(np.abs(np.arctan2(q[:, 0], q[:, 2] + 95.0)))
            hl = np.interp(phi, [0.0, 35.0, 60.0, 80.0, 100.0, 125.0, 180.0],
                           [brow_top + 55.0, brow_top + 50.0, brow_top + 38.0, ear_top + 6.0, ear_top, lm[8, 1] + 15.0,
                            lm[8, 1] + 10.0])
            base = _smoothstep(hl - 3.0, hl + 3.0, q[:, 1])
            edge = 0.25
        fray = _noise1((_cyl(q)[:, 0] + 0.3 * q[:, 1]) / 0.35, self.seed + 45) - 0.5
        return _smoothstep(0.5 - edge, 0.5 + edge, base + 0.35 * fray * (1 - np.abs(2 * base - 1)))

    # ---------------------------------------------------------------- eyes
    def eye_color(self, q: np.ndarray, centre: np.ndarray, axis: np.ndarray, iris_angle: float,
                  side: int) -> np.ndarray:
        s = self.seed + 60 + side
        n = len(q)
        d = q - centre
        r = np.linalg.norm(d, axis=1)
        cosang = np.clip((d @ axis) / np.maximum(r, 1e-12), -1, 1)
        theta = np.arccos(cosang)
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        psi = np.arctan2(d @ e2, d @ e1)
        rho = theta / iris_angle  # 1 at the limbus
        # sclera: warm white, pinker and vessel-laced away from the cornea
        col = np.tile(np.array([0.93, 0.90, 0.86]), (n, 1))
        col *= (1.0 - 0.06 * _smoothstep(1.3, 3.0, rho))[:, None] * np.array([1.0, 0.96, 0.95])
        ridge = 1.0 - np.abs(2.0 * _fbm(q / 2.5, s, 3))
        vessels = _smoothstep(0.955, 0.995, ridge) * _smoothstep(1.3, 2.6, rho)
        col = col * (1 - 0.35 * vessels[:, None]) + np.array([0.75, 0.28, 0.25]) * 0.35 * vessels[:, None]
        # iris
        pupil = 0.36
        fib = _noise1((psi / (2 * np.pi)) * 160.0 + 3.0 * rho, s + 1)
        fib2 = _noise1((psi / (2 * np.pi)) * 45.0 + 40.0, s + 2)
        base = np.asarray(self.look.iris, np.float64)
        outer = np.asarray(self.look.iris_outer, np.float64)
        t = _smoothstep(pupil, 1.0, rho)[:, None]
        iris = base * (1 - t) + outer * t
        iris = iris * (0.75 + 0.5 * fib[:, None] * (0.7 + 0.3 * fib2[:, None]))
        collar = np.exp(-((rho - 0.52) / 0.07) ** 2)
        iris *= (1.0 + 0.25 * collar)[:, None]
        limbal = _smoothstep(0.78, 0.98, rho)
        iris *= (1.0 - 0.65 * limbal)[:, None]
        w_iris = _smoothstep(1.03, 0.99, rho)[:, None]
        col = col * (1 - w_iris) + iris * w_iris
        w_pupil = _smoothstep(pupil + 0.02, pupil - 0.02, rho)[:, None]
        col = col * (1 - w_pupil) + np.array([0.015, 0.015, 0.018]) * w_pupil
        return col


def _lash_alpha(u: np.ndarray, t: np.ndarray, lower: np.ndarray, size: int, seed: int) -> np.ndarray:
    """Coverage of individual lashes on a card: ``u`` along the lid (UV), ``t`` in [0, 1] from
    root to tip, ``lower`` True on the lower lid (shorter, sparser lashes). Lashes every ~5
    texels, jittered, curling, tapering, of random length."""
    spacing = 5.0
    xp = u * size / spacing
    out = np.zeros(len(u))
    t = np.where(lower, t / 0.45, t)
    for layer, shift in ((0, 0.0), (1, 0.5)):
        k = np.floor(xp + shift)
        h = _hash(k.astype(np.int64), np.full(len(k), layer), np.zeros(len(k), np.int64), seed)
        h2 = _hash(k.astype(np.int64), np.full(len(k), layer), np.ones(len(k), np.int64), seed)
        centre = (k + 0.5 - shift + 0.6 * (h - 0.5)) * spacing + (h2 - 0.5) * 6.0 * t ** 1.5
        dist = np.abs(u * size - centre)
        half = 1.1 * (1.0 - 0.65 * t)
        length = 0.55 + 0.45 * h2
        a = np.clip(half + 0.5 - dist, 0.0, 1.0) * _smoothstep(length, length - 0.08, t)
        out = np.maximum(out, a * (0.85 if layer else 1.0) * np.where(lower & (h > 0.55), 0.0, 1.0))
    return out


def _splat(grid: np.ndarray, x: np.ndarray, y: np.ndarray, w: np.ndarray) -> None:
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    h, wd = grid.shape
    for dx, dy, ww in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        xi, yi = x0 + dx, y0 + dy
        ok = (xi >= 0) & (xi < wd) & (yi >= 0) & (yi < h)
        np.add.at(grid, (yi[ok], xi[ok]), (w * ww)[ok])


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    out = np.array([np.convolve(row, k, mode="same") for row in img])
    out = np.array([np.convolve(col, k, mode="same") for col in out.T]).T
    return out


def _bilinear_grid(g: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    h, w = g.shape
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    fx, fy = x - x0, y - y0
    return ((1 - fx) * (1 - fy) * g[y0, x0] + fx * (1 - fy) * g[y0, x0 + 1]
            + (1 - fx) * fy * g[y0 + 1, x0] + fx * fy * g[y0 + 1, x0 + 1])


def _components(faces: np.ndarray) -> np.ndarray:
    """Connected-component label (0..C-1) per triangle (triangles sharing a vertex are connected)."""
    verts, inv = np.unique(faces.ravel(), return_inverse=True)
    tri = inv.reshape(-1, 3)
    label = np.arange(len(verts))
    while True:
        m = label[tri].min(1)
        new = label.copy()
        for k in range(3):
            np.minimum.at(new, tri[:, k], m)
        new = new[new]  # pointer jumping
        if np.array_equal(new, label):
            break
        label = new
    return np.unique(label[tri[:, 0]], return_inverse=True)[1]


def _sphere_fit(p: np.ndarray) -> tuple[np.ndarray, float]:
    a = np.c_[2 * p, np.ones(len(p))]
    b = (p ** 2).sum(1)
    sol = np.linalg.lstsq(a, b, rcond=None)[0]
    c = sol[:3]
    return c, float(np.sqrt(sol[3] + c @ c))


def eye_axis(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(centre, optical axis, limbus half-angle in radians) of one eyeball from its vertices.

    A sphere is fitted to the vertices; the cornea is the cap that bulges out of it: the axis is
    the mean direction of the 6 % of the front half's vertices farthest from the centre (in
    the face frame, +z forward), and the limbus is the
    largest angle from the axis at which the surface still stands 12 % of the bulge's height
    above the sclera (the 90th percentile of the radius 35 to 70 degrees from the axis: inner
    shells such as ICT's iris mesh do not lower it), searched within 60 degrees of the axis and
    only over the cap raised all the way from the axis (the raised vertices' angles up to the first
    gap wider than :data:`_LIMBUS_GAP_DEG`). Without that last condition a bump of an
    identity's eyeball far out on the sclera counted as cornea: on four of the six patients' eyes
    (amara's left; james, kwame, rafael) the limbus came out 56-59 degrees, an iris over most of
    the visible eye (docs/face_realism.md). Region labels are not needed (ICT's iris mesh lies
    inside the sclera+cornea shell).
    """
    q = np.asarray(points, dtype=np.float64)
    centre, _ = _sphere_fit(q)
    r = np.linalg.norm(q - centre, axis=1)
    outer = r >= 0.97 * np.percentile(r, 75)  # drop inner shells (ICT's iris mesh), refit
    centre, _ = _sphere_fit(q[outer])
    r = np.linalg.norm(q - centre, axis=1)
    front = (q - centre)[:, 2] > 0  # the face frame's +z: the eye looks forward
    far = front & (r >= np.percentile(r[front], 94)) if front.any() else r >= np.percentile(r, 97)
    axis = (q[far] - centre).mean(0)
    axis /= np.linalg.norm(axis)
    theta = np.arccos(np.clip(((q - centre) @ axis) / np.maximum(r, 1e-12), -1, 1))
    side = (theta > np.radians(35)) & (theta < np.radians(70))
    base = float(np.percentile(r[side] if side.any() else r, 90))
    bulge = r[far].mean() - base
    cornea = (r > base + 0.12 * bulge) & (theta < np.radians(60))
    if bulge <= 1e-6 * max(base, 1e-12) or not cornea.any():  # a plain sphere: a 12 mm iris on a 24 mm eyeball
        return centre, np.array([0.0, 0.0, 1.0]), float(np.arcsin(0.5))
    # the cap raised all the way from the axis: the raised vertices' angles up to the first gap wider
    # than _LIMBUS_GAP_DEG (a bump of the sclera far out is not cornea)
    t = np.sort(theta[cornea])
    gap = np.nonzero(np.diff(t) > np.radians(_LIMBUS_GAP_DEG))[0]
    return centre, axis, float(t[gap[0]] if len(gap) else t[-1])


#: :func:`eye_axis`: raised vertices farther than this (degrees, from the axis) beyond the cap are not cornea
_LIMBUS_GAP_DEG = 7.0


# ============================================================================== the generator
def _paint(p: _Painter, mesh: AppearanceMesh, size: int, eye_size: int) -> tuple[dict, dict]:
    """Paint every texture of ``mesh`` (see the module docstring): skin/hair tiles ``size`` texels square,
    eyes ``eye_size``, lashes :data:`LASH_TEXTURE_SIZE`; (textures, alpha) as float32 multiples of 1/255."""
    v, f, uvs, fuv = mesh.vertices, mesh.faces, mesh.uv, mesh.faces_uv
    region, mat, seed = mesh.region, mesh.material, p.seed
    brow = p.brow_map()
    has_scalp = p.rid("scalp") >= 0 and (region == p.rid("scalp")).any()
    soft_names = {"ears": ("ears",), "scalp": ("scalp",), "mouth_interior": ("mouth_interior",),
                  "eye_pocket": ("eye_pocket",), "nostrils": ("nostrils",)}
    soft_v = {k: p.soft_region(n, 3) for k, n in soft_names.items()}
    # crown: top of the skull, a little behind the face
    q_all = _to_local(v, p.frame)
    top = q_all[:, 1].max()
    crown = np.array([0.0, top - 8.0, q_all[:, 2].min() * 0.35])
    axis = np.array([0.0, 1.0, -0.35])
    axis /= np.linalg.norm(axis)
    shine = p.look.sheen > 0 or p.look.rim > 0
    n_all = _smoothed_normals(q_all, f, _SHEEN_SMOOTH) if shine else None
    head_centre = np.array([0.0, 10.0, -90.0])  # mm, the face frame: inside the skull, behind the eyes

    textures: dict[str, np.ndarray] = {}
    for tex in ("face", "head", "hair"):
        sel = np.nonzero(np.isin(mat, [MATERIALS.index(m) for m, t in MATERIAL_TEXTURE.items() if t == tex]))[0]
        if shine and tex == "hair":  # layers sharing texels: the outermost (the one seen) is rasterised last
            rad = np.linalg.norm(q_all[f[sel]].mean(1) - head_centre, axis=1)
            sel = sel[np.lexsort((np.arange(len(sel)), rad))]
        tri, bary = rasterize_uv(uvs[fuv[sel]], size, (TEXTURE_TILE[tex], 0.0))
        mask = tri >= 0
        ft = f[sel[tri[mask]]]
        b = bary[mask]
        pos = np.einsum("nk,nkc->nc", b, v[ft])
        q = _to_local(pos, p.frame)
        soft = {k: np.einsum("nk,nk->n", b, sv[ft]) for k, sv in soft_v.items()}
        nrm = tan = None
        if shine:
            nrm = _unit(np.einsum("nk,nkc->nc", b, n_all[ft]))
            # the shell's inner layer shares the outer one's texels: shade them as seen from outside the head
            nrm *= np.where(np.einsum("nc,nc->n", nrm, q - head_centre) < 0, -1.0, 1.0)[:, None]
            tan = q - crown  # combed away from the crown (on the hanging curtain: down the curtain)
            tan = _unit(tan - np.einsum("nc,nc->n", tan, nrm)[:, None] * nrm)
        if tex == "hair":
            ii, jj = np.nonzero(mask)
            col = p.hair_shell_color(q, crown, axis, np.c_[(jj + 0.5) / size, 1.0 - (ii + 0.5) / size], nrm, tan)
        else:
            col = p.skin(q, soft, brow)
            hc = p.hair_coverage(q, soft["scalp"] if has_scalp else None)
            col = col * (1 - hc[:, None]) + p.hair_color(q, crown, axis, None, nrm, tan) * 0.8 * hc[:, None]
            for name, w in (("mouth_interior", 1.0), ("eye_pocket", 0.8), ("nostrils", 0.7)):
                c = np.asarray(_VERTEX_COLORS[name])
                ww = np.clip(soft[name] * w, 0, 1)[:, None]
                col = col * (1 - ww) + c * (1.0 + 0.1 * _fbm(q / 2.0, seed + 70, 2))[:, None] * ww
        img = np.zeros((size, size, 3))
        img[mask] = col
        textures[tex] = img if not mask.any() else _dilate(img, mask)

    # eyes
    eye_spheres = []
    for name in ("eye_left", "eye_right"):
        sel = np.nonzero(mat == MATERIALS.index(name))[0]
        img = np.zeros((eye_size, eye_size, 3))
        if len(sel):
            q_eye = _to_local(v[np.unique(f[sel])], p.frame)
            centre, axis_e, iris_angle = eye_axis(q_eye)
            eye_spheres.append((centre, float(np.percentile(np.linalg.norm(q_eye - centre, axis=1), 75))))
            # shells may share UVs (ICT's iris mesh lies inside the sclera+cornea shell with the same
            # layout): rasterise inner connected pieces first so the visible, outermost shell owns each texel
            comp = _components(f[sel])
            rad = np.linalg.norm(_to_local(v[f[sel]].mean(1), p.frame) - centre, axis=1)
            comp_rad = np.array([rad[comp == c].mean() for c in range(comp.max() + 1)])
            sel = sel[np.lexsort((np.arange(len(sel)), comp_rad[comp]))]
            tri, bary = rasterize_uv(uvs[fuv[sel]], eye_size, (0.0, 0.0))
            mask = tri >= 0
            pos = np.einsum("nk,nkc->nc", bary[mask], v[f[sel[tri[mask]]]])
            col = p.eye_color(_to_local(pos, p.frame), centre, axis_e, iris_angle, 0 if name == "eye_left" else 1)
            img[mask] = col
            img = _dilate(img, mask)
        textures[name] = img
    # lash cards: dark strands, root at the lid margin (nearest the eyeball), tip away from it
    alpha: dict[str, np.ndarray] = {}
    sel = np.nonzero(mat == MATERIALS.index("lashes"))[0]
    if len(sel):
        tri, bary = rasterize_uv(uvs[fuv[sel]], LASH_TEXTURE_SIZE, (TEXTURE_TILE["lashes"], 0.0))
        mask = tri >= 0
        pos = _to_local(np.einsum("nk,nkc->nc", bary[mask], v[f[sel[tri[mask]]]]), p.frame)
        dist = np.full(len(pos), np.inf)
        lower = np.zeros(len(pos), bool)
        for c, rad in eye_spheres:
            de = np.linalg.norm(pos - c, axis=1) - rad
            lower = np.where(de < dist, pos[:, 1] < c[1], lower)
            dist = np.minimum(dist, de)
        dist = np.maximum(dist, 0.0)
        t = np.clip(dist / max(float(np.percentile(dist, 97)), 1e-9), 0, 1)
        cols = np.tile(np.asarray(_VERTEX_COLORS["lashes"]), (len(pos), 1))
        img = np.zeros((LASH_TEXTURE_SIZE, LASH_TEXTURE_SIZE, 3))
        img[mask] = cols
        textures["lashes"] = _dilate(img, mask, 2)
        ua = np.zeros((LASH_TEXTURE_SIZE, LASH_TEXTURE_SIZE))
        jj = np.nonzero(mask)[1]
        ua[mask] = _lash_alpha((jj + 0.5) / LASH_TEXTURE_SIZE, t, lower, LASH_TEXTURE_SIZE, seed + 80)
        alpha["lashes"] = (np.round(ua * 255) / 255).astype(np.float32)
    else:
        textures["lashes"] = np.zeros((LASH_TEXTURE_SIZE, LASH_TEXTURE_SIZE, 3))
    textures = {k: (np.round(np.clip(t, 0, 1) * 255) / 255).astype(np.float32) for k, t in textures.items()}

    return textures, alpha


def generate_appearance(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, faces_uv: np.ndarray,
                        vertex_region: np.ndarray, region_names: Sequence[str], landmarks: np.ndarray,
                        seed: int = 0, size: int = TEXTURE_SIZE, eye_size: int = EYE_TEXTURE_SIZE,
                        textures: Mapping[str, np.ndarray] | None = None,
                        alpha: Mapping[str, np.ndarray] | None = None, look: Look = DEFAULT_LOOK) -> HeadAppearance:
    """Paint the head's albedo (see the module docstring).

    Parameters
    ----------
    vertices : numpy.ndarray
        (V, 3) rest positions (any unit; the face frame rescales to millimetres).
    faces : numpy.ndarray
        (F, 3) triangles.
    uv, faces_uv : numpy.ndarray
        (U, 2) UDIM texture coordinates (tile k = floor(u)) and (F, 3) indices into ``uv``.
    vertex_region : numpy.ndarray
        (V0,) region label per vertex (V0 <= V; vertices beyond are teeth), indices into ``region_names``.
    region_names : sequence of str
        Region names (skin, scalp, brows, lips, eyeball_left, eyeball_right, iris, pupil, ears,
        mouth_interior, eye_pocket, neck, nostrils, teeth, hair, lashes, gums, tongue; others are skin).
    landmarks : numpy.ndarray
        (68, 3) landmark positions in dlib's 68-point order, same frame as ``vertices``.
    seed : int
        Noise and strand seed.
    size, eye_size : int
        Texture sides (skin/hair tiles, eyes).
    textures, alpha : dict, optional
        Textures painted before (e.g. loaded from the shipped PNGs): only the materials and the
        vertex colours are computed (fast); shapes are checked against ``size`` / ``eye_size``.
    look : Look
        Skin, hair and eye colours and age (a patient's; default: the default head's).

    Returns
    -------
    HeadAppearance
    """
    if textures is not None:
        return assemble_appearance(vertices, faces, uv, faces_uv, vertex_region, region_names, landmarks, textures,
                                   alpha, seed=seed, size=size, eye_size=eye_size)
    mesh = AppearanceMesh.from_arrays(vertices, faces, uv, faces_uv, vertex_region, region_names, landmarks)
    p = _Painter(mesh.vertices, mesh.faces, mesh.region, mesh.region_names, mesh.landmarks, seed, look)
    painted, painted_alpha = _paint(p, mesh, size, eye_size)
    return mesh.appearance(painted, painted_alpha, seed=seed, size=size, eye_size=eye_size)
