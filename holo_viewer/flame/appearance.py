"""The default head's appearance at run time: the textures' data type and the material tables.

:class:`HeadAppearance` holds a head's albedo textures, triangle materials and vertex colours; the
tables say which texture each material samples, its UDIM tile and its specular. The textures are
painted at build time by :func:`holo_viewer.assets_build.texture_painter.generate_appearance` and
shipped or cached by :mod:`holo_viewer.flame.head_textures`. See docs/appearance.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..errors import InputError

__all__ = ["HeadAppearance", "AppearanceMesh", "assemble_appearance", "face_frame", "TEXTURE_SIZE",
           "EYE_TEXTURE_SIZE", "LASH_TEXTURE_SIZE", "TEXTURE_TILE", "MATERIALS",
           "MATERIAL_TEXTURE", "MATERIAL_SPECULAR", "APPEARANCE_VERSION"]

#: Bumped whenever the painting changes (cached appearances carry it).
APPEARANCE_VERSION = 3
#: Skin/hair tiles: the face tile spans ~0.3 m of surface per UV unit, so 1024 texels are ~0.3 mm,
#: the pixel footprint of the 800x960 preview at 0.95 m (0.35 mm); brow strands stay 1 texel wide.
TEXTURE_SIZE = 1024
#: Eyeball textures: one UV unit spans the ~75 mm eyeball circumference, 512 texels ~0.15 mm.
EYE_TEXTURE_SIZE = 512

#: Materials (one VTK actor each): name -> texture it samples (None: per-vertex colours).
MATERIAL_TEXTURE = {"face": "face", "lips": "face", "head": "head", "hair": "hair", "eye_left": "eye_left",
                    "eye_right": "eye_right", "lashes": "lashes", "teeth": None, "mouth": None, "other": None}
MATERIALS = tuple(MATERIAL_TEXTURE)
#: (specular, specular power) per material: wet eyes and lips glossy, hair nearly matte.
MATERIAL_SPECULAR = {"face": (0.07, 12.0), "lips": (0.25, 35.0), "head": (0.06, 12.0), "hair": (0.05, 10.0),
                     "eye_left": (1.0, 90.0), "eye_right": (1.0, 90.0), "teeth": (0.25, 30.0),
                     "mouth": (0.25, 25.0), "lashes": (0.05, 8.0), "other": (0.10, 14.0)}
#: UDIM tile of each skin/hair texture (u in [k, k+1]); eyes use the tile-0 range of their own faces.
TEXTURE_TILE = {"face": 0, "head": 1, "hair": 7, "eye_left": 0, "eye_right": 0, "lashes": 6}
#: Lash cards (tile 6): 512 texels across a card's length keep one lash ~2 texels wide.
LASH_TEXTURE_SIZE = 512

_EYE_REGIONS = ("eyeball_left", "eyeball_right", "iris", "pupil")
# linear-ish display RGB, matching the preview's REGION_COLORS scale
_SKIN = np.array([0.84, 0.63, 0.52])
_HAIR = np.array([0.20, 0.135, 0.09])
_BROW = np.array([0.13, 0.085, 0.06])
_LIP = np.array([0.72, 0.40, 0.40])
_VERTEX_COLORS = {"teeth": (0.86, 0.83, 0.74), "gums": (0.80, 0.45, 0.45), "tongue": (0.76, 0.40, 0.40),
                  "mouth_interior": (0.42, 0.14, 0.14), "lashes": (0.06, 0.045, 0.04),
                  "eye_pocket": (0.74, 0.45, 0.42), "nostrils": (0.42, 0.24, 0.21), "hair": tuple(_HAIR),
                  "brows": tuple(_BROW), "lips": tuple(_LIP), "iris": (0.33, 0.22, 0.13), "pupil": (0.02, 0.02, 0.02),
                  "eyeball_left": (0.93, 0.90, 0.86), "eyeball_right": (0.93, 0.90, 0.86)}


def face_frame(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(origin, R, mm) of the landmark face frame: local = (x - origin) @ R * mm.

    Origin: midpoint of the outer eye corners (landmarks 36, 45); +x from 36 toward 45 (the
    subject's left), +y up (orthogonalised from the chin toward the brows), +z = x cross y (out of
    the face); ``mm`` converts mesh units to millimetres taking the outer-canthal distance as 90 mm.
    """
    lm = np.asarray(landmarks, dtype=np.float64)
    x = lm[45] - lm[36]
    width = float(np.linalg.norm(x))
    if not np.isfinite(width) or width <= 0:
        raise InputError(f"landmarks: outer eye corners 36 and 45 coincide or are not finite ({lm[36]}, {lm[45]})")
    x /= width
    y = lm[17:27].mean(0) - lm[8]
    y -= x * float(x @ y)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    return 0.5 * (lm[36] + lm[45]), np.stack([x, y, z], axis=1), 90.0 / width


def _to_local(p: np.ndarray, frame: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray:
    o, r, mm = frame
    return (np.asarray(p, dtype=np.float64) - o) @ r * mm


def _signed_dist_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) from (N, 2) points to a closed polygon."""
    a = poly
    b = np.roll(poly, -1, axis=0)
    d = np.full(len(p), np.inf)
    inside = np.zeros(len(p), bool)
    for k in range(len(a)):
        e = b[k] - a[k]
        w = p - a[k]
        t = np.clip((w @ e) / max(float(e @ e), 1e-12), 0, 1)
        d = np.minimum(d, np.linalg.norm(w - t[:, None] * e, axis=1))
        cond = ((a[k, 1] > p[:, 1]) != (b[k, 1] > p[:, 1]))
        dy = b[k, 1] - a[k, 1]
        xint = a[k, 0] + (p[:, 1] - a[k, 1]) * (b[k, 0] - a[k, 0]) / (dy if dy != 0 else 1e-12)
        inside ^= cond & (p[:, 0] < xint)
    return np.where(inside, -d, d)


@dataclass
class HeadAppearance:
    """Albedo of a head mesh: textures, the material of each triangle and per-vertex colours.

    Attributes
    ----------
    textures : dict
        Texture name (``face``, ``head``, ``hair``, ``eye_left``, ``eye_right``) -> (H, W, 3)
        float32 albedo in [0, 1] (values are multiples of 1/255: what a PNG or the GPU holds), row 0
        at the top; texel (i, j) of texture ``t`` covers u - tile(t) in [j/W, (j+1)/W],
        v in [1 - (i+1)/H, 1 - i/H].
    face_material : numpy.ndarray
        (F,) int16 index into :data:`MATERIALS`.
    faces : numpy.ndarray
        (F, 3) triangles of the mesh.
    uv, faces_uv : numpy.ndarray
        (U, 2) float32 UDIM coordinates and (F, 3) int indices (as given to the generator).
    vertex_colors : numpy.ndarray
        (V, 3) float32 albedo of every vertex (the colour of untextured materials; for textured
        ones the texture sampled at the vertex, for previews without textures).
    alpha : dict
        Texture name -> (H, W) float32 coverage in [0, 1] for the cut-out textures (``lashes``:
        individual lashes on ICT's lash cards); the renderer blends those materials.
    seed : int
        Generator seed.
    """

    textures: dict[str, np.ndarray]
    face_material: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    faces_uv: np.ndarray
    vertex_colors: np.ndarray
    alpha: dict = field(default_factory=dict)
    seed: int = 0
    version: int = APPEARANCE_VERSION
    specular: Mapping[str, tuple[float, float]] = field(default_factory=lambda: dict(MATERIAL_SPECULAR))

    def material_faces(self, name: str) -> np.ndarray:
        """Indices of the triangles of material ``name``."""
        return np.nonzero(self.face_material == MATERIALS.index(name))[0]

    def texture_uv(self, face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """(N, 2) UV of surface points (UDIM, tile offset included)."""
        fu = self.faces_uv[np.asarray(face_idx, dtype=np.int64)]
        return np.einsum("nk,nkc->nc", np.asarray(bary, dtype=np.float64), self.uv[fu].astype(np.float64))

    def albedo_at(self, face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """Albedo at surface points: bilinear texture lookup (textured materials) or interpolated
        vertex colours (the rest).

        Parameters
        ----------
        face_idx : numpy.ndarray
            (N,) triangle indices.
        bary : numpy.ndarray
            (N, 3) barycentric coordinates (rows sum to 1).

        Returns
        -------
        numpy.ndarray
            (N, 3) float32 RGB in [0, 1].
        """
        fi = np.asarray(face_idx, dtype=np.int64).reshape(-1)
        b = np.asarray(bary, dtype=np.float64).reshape(-1, 3)
        if len(fi) != len(b):
            raise InputError(f"albedo_at: {len(fi)} face indices but {len(b)} barycentric rows")
        if len(fi) and (fi.min() < 0 or fi.max() >= len(self.face_material)):
            raise InputError(f"albedo_at: face indices must lie in [0, {len(self.face_material)}), "
                             f"found [{fi.min()}, {fi.max()}]")
        out = np.einsum("nk,nkc->nc", b, self.vertex_colors[self.faces[fi]].astype(np.float64))
        mat = self.face_material[fi]
        for name, tex in MATERIAL_TEXTURE.items():
            if tex is None or tex not in self.textures:
                continue
            sel = np.nonzero(mat == MATERIALS.index(name))[0]
            if len(sel):
                out[sel] = _bilinear(self.textures[tex], self.texture_uv(fi[sel], b[sel]) - [TEXTURE_TILE[tex], 0.0])
        return out.astype(np.float32)


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup (clamped edges) at UV in [0, 1] (texel centres as in :func:`rasterize_uv`)."""
    h, w = img.shape[:2]
    x = np.clip(uv[:, 0] * w - 0.5, 0, w - 1)
    y = np.clip((1.0 - uv[:, 1]) * h - 0.5, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    im = img.astype(np.float64)
    return ((1 - fx) * (1 - fy) * im[y0, x0] + fx * (1 - fy) * im[y0, x0 + 1]
            + (1 - fx) * fy * im[y0 + 1, x0] + fx * fy * im[y0 + 1, x0 + 1])


def _materials(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, faces_uv: np.ndarray, region: np.ndarray,
               region_names: list[str], frame: tuple[np.ndarray, np.ndarray, float], lm: np.ndarray) -> np.ndarray:
    """Material index per triangle from its UDIM tile and the region labels of its corners (``lm``: the 68
    landmarks in the face frame ``frame``)."""
    tile = np.floor(uv[faces_uv].mean(1)[:, 0]).astype(np.int64)
    reg = region[faces]
    mid_x = float(frame[0] @ frame[1][:, 0])

    def rid(name):
        return region_names.index(name) if name in region_names else -1
    mat = np.full(len(faces), MATERIALS.index("other"), dtype=np.int16)

    def any_of(names):
        ids = [rid(n) for n in names if rid(n) >= 0]
        return np.isin(reg, ids).any(1) if ids else np.zeros(len(faces), bool)

    def all_of(names):
        ids = [rid(n) for n in names if rid(n) >= 0]
        return np.isin(reg, ids).all(1) if ids else np.zeros(len(faces), bool)

    eye = all_of(_EYE_REGIONS) & (tile == 0)
    mat[tile == 0] = MATERIALS.index("face")
    mat[tile == 1] = MATERIALS.index("head")
    mat[tile == 7] = MATERIALS.index("hair")
    cx = vertices[faces].mean(1) @ frame[1][:, 0]
    mat[eye & (cx < mid_x)] = MATERIALS.index("eye_right")
    mat[eye & (cx >= mid_x)] = MATERIALS.index("eye_left")
    mat[any_of(("teeth",))] = MATERIALS.index("teeth")
    mat[any_of(("gums", "tongue")) | (tile == 2)] = MATERIALS.index("mouth")
    mat[tile == 3] = MATERIALS.index("teeth")
    mat[any_of(("lashes",)) | (tile == 6)] = MATERIALS.index("lashes")
    mat[(tile >= 4) & (tile <= 5)] = MATERIALS.index("other")
    # lips: face-tile triangles inside the outer-lip landmark contour
    q = _to_local(vertices[faces].mean(1), frame)
    lips = (_signed_dist_polygon(q[:, :2], lm[48:60, :2]) < 1.0) & (q[:, 2] > lm[48:60, 2].min() - 12.0)
    mat[lips & (mat == MATERIALS.index("face"))] = MATERIALS.index("lips")
    return mat


def _check_textures(textures: Mapping[str, np.ndarray], alpha: Mapping[str, np.ndarray], size: int,
                    eye_size: int) -> tuple[dict, dict]:
    want = {"face": size, "head": size, "hair": size, "eye_left": eye_size, "eye_right": eye_size,
            "lashes": LASH_TEXTURE_SIZE}
    out = {}
    for name, side in want.items():
        if name not in textures:
            raise InputError(f"textures: missing {name!r}; expected {sorted(want)}")
        t = np.asarray(textures[name], dtype=np.float32)
        if t.shape != (side, side, 3) or not np.isfinite(t).all() or t.min() < 0 or t.max() > 1:
            raise InputError(f"textures[{name!r}]: expected ({side}, {side}, 3) values in [0, 1], found {t.shape}")
        out[name] = t
    a = {}
    for name, t in alpha.items():
        t = np.asarray(t, dtype=np.float32)
        if t.shape != out[name].shape[:2]:
            raise InputError(f"alpha[{name!r}]: expected {out[name].shape[:2]}, found {t.shape}")
        a[name] = t
    return out, a

@dataclass
class AppearanceMesh:
    """A head mesh checked and labelled for its appearance: arrays as the generator takes them, every
    vertex's region (vertices beyond ``vertex_region`` are teeth), the face frame and each triangle's
    material. Build it with :meth:`from_arrays`."""

    vertices: np.ndarray  # [V, 3] float64
    faces: np.ndarray  # [F, 3] int64
    uv: np.ndarray  # [U, 2] float64, UDIM
    faces_uv: np.ndarray  # [F, 3] int64
    landmarks: np.ndarray  # [68, 3] float64, mesh frame
    region: np.ndarray  # [V] int64 index into region_names
    region_names: list[str]
    material: np.ndarray  # [F] int16 index into MATERIALS

    @classmethod
    def from_arrays(cls, vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, faces_uv: np.ndarray,
                    vertex_region: np.ndarray, region_names: Sequence[str], landmarks: np.ndarray) -> "AppearanceMesh":
        """Check the arrays (:class:`~holo_viewer.errors.InputError` naming the field) and label the mesh."""
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        uvs = np.asarray(uv, dtype=np.float64)
        fuv = np.asarray(faces_uv, dtype=np.int64)
        lm = np.asarray(landmarks, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise InputError(f"vertices: expected finite (V, 3), found {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
            raise InputError(f"faces: expected (F, 3) indices into {len(v)} vertices, found {f.shape}")
        if fuv.shape != f.shape or (fuv.size and (fuv.min() < 0 or fuv.max() >= len(uvs))):
            raise InputError(f"faces_uv: expected {f.shape} indices into {len(uvs)} uv rows, found {fuv.shape}")
        if uvs.ndim != 2 or uvs.shape[1] != 2:
            raise InputError(f"uv: expected (U, 2), found {uvs.shape}")
        if lm.shape != (68, 3):
            raise InputError(f"landmarks: expected (68, 3) points, found {lm.shape}")
        reg0 = np.asarray(vertex_region, dtype=np.int64).reshape(-1)
        names = [str(s) for s in region_names]
        if len(reg0) > len(v):
            raise InputError(f"vertex_region: {len(reg0)} labels for {len(v)} vertices")
        region = np.full(len(v), names.index("teeth") if "teeth" in names else len(names), dtype=np.int64)
        region[: len(reg0)] = reg0
        if "teeth" not in names:
            names = names + ["teeth"]
        frame = face_frame(lm)
        mat = _materials(v, f, uvs, fuv, region, names, frame, _to_local(lm, frame))
        return cls(v, f, uvs, fuv, lm, region, names, mat)

    def appearance(self, textures: Mapping[str, np.ndarray], alpha: Mapping[str, np.ndarray] | None = None,
                   seed: int = 0, size: int = TEXTURE_SIZE, eye_size: int = EYE_TEXTURE_SIZE) -> "HeadAppearance":
        """The :class:`HeadAppearance` of this mesh with ``textures`` (shapes checked against ``size`` /
        ``eye_size``): vertex colours from the region palette, textured vertices sampled from their texture."""
        textures, alpha = _check_textures(textures, alpha or {}, size, eye_size)
        v, f, region, mat = self.vertices, self.faces, self.region, self.material

        def rid(name):
            return self.region_names.index(name) if name in self.region_names else -1

        # vertex colours: region colours, textured vertices sampled from their texture
        vcol = np.tile(_SKIN, (len(v), 1))
        for name, c in _VERTEX_COLORS.items():
            if rid(name) >= 0:
                vcol[region == rid(name)] = c
        vcol[np.unique(f[mat == MATERIALS.index("mouth")])] = _VERTEX_COLORS["gums"]
        if rid("tongue") >= 0:
            vcol[region == rid("tongue")] = _VERTEX_COLORS["tongue"]
        vcol[np.unique(f[mat == MATERIALS.index("teeth")])] = _VERTEX_COLORS["teeth"]
        vcol[np.unique(f[mat == MATERIALS.index("lashes")])] = _VERTEX_COLORS["lashes"]
        app = HeadAppearance(textures=textures, face_material=mat, faces=f, uv=self.uv.astype(np.float32),
                             faces_uv=self.faces_uv, vertex_colors=vcol.astype(np.float32), alpha=alpha, seed=int(seed))
        for name, tex in MATERIAL_TEXTURE.items():
            if tex is None or tex not in textures:
                continue
            fs = app.material_faces(name)
            if len(fs):
                corners = np.repeat(np.eye(3)[None], len(fs), axis=0).reshape(-1, 3)
                cols = app.albedo_at(np.repeat(fs, 3), corners)
                vcol[f[fs].ravel()] = cols
        app.vertex_colors = vcol.astype(np.float32)
        return app


def assemble_appearance(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, faces_uv: np.ndarray,
                        vertex_region: np.ndarray, region_names: Sequence[str], landmarks: np.ndarray,
                        textures: Mapping[str, np.ndarray], alpha: Mapping[str, np.ndarray] | None = None,
                        seed: int = 0, size: int = TEXTURE_SIZE, eye_size: int = EYE_TEXTURE_SIZE) -> HeadAppearance:
    """The appearance of a head from textures painted before (e.g. the shipped PNGs): only the materials and
    the vertex colours are computed (fast). Arguments as
    :func:`holo_viewer.assets_build.texture_painter.generate_appearance`, which paints ``textures``."""
    mesh = AppearanceMesh.from_arrays(vertices, faces, uv, faces_uv, vertex_region, region_names, landmarks)
    return mesh.appearance(textures, alpha, seed=seed, size=size, eye_size=eye_size)
