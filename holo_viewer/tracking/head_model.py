"""The 68 landmarks on the project's own head, as a function of face state (pure numpy).

Landmark embedding
------------------
Each of the 68 landmarks is a fixed point on the head mesh: a triangle index and barycentric
weights (``assets/default_head_landmarks.npz``: ``triangles`` (68,) int, ``bary`` (68, 3),
``weights`` (68,) fit weights). It was built by :func:`embed_landmarks` from the detector's own
landmarks on a front render of the neutral default avatar (``scripts/build_landmark_embedding.py``):
each 2-D landmark is back-projected onto the mesh through the render camera. Contour points
(0-16) slide along the silhouette as the head turns, so they get weight 0 except the chin
(6-10, weight 0.5).

Forward model
-------------
With AU state ``a`` (n_au,) (intensity / scale, in [0, 1]), jaw pitch ``j`` (rad), head
rotation ``r`` (axis-angle, rad) and ``T`` (3,) (the head's root joint in OpenCV camera
coordinates, metres)::

    expr = (a * scales) @ au_map.matrix
    V    = FLAME LBS of the landmark triangles' vertices (root = r, jaw = [j, 0, 0]; exact,
           with pose correctives, float64: flame.lbs.lbs_reference_np on the subset)
    X    = bary-combine(V)                                       # (68, 3) FLAME frame
    P    = F R(r) (X_local - J_root) + T,   F = diag(1, -1, -1)   # OpenCV camera frame
    x    = K P / P_z                                              # pixels

``F`` turns FLAME's frame (+y up, +z out of the face) into a camera facing the head, so
``r = 0`` is a face looking straight into the camera.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, TrackingError
from ..validation import check_array

__all__ = ["LandmarkEmbedding", "LandmarkHeadModel", "embed_landmarks", "default_embedding_path",
           "CAMERA_FROM_FLAME", "N_POSE_PARAMS"]

#: FLAME frame -> OpenCV camera frame of a camera that faces the head
CAMERA_FROM_FLAME = np.diag([1.0, -1.0, -1.0])
#: jaw pitch, rotation (3), translation (3)
N_POSE_PARAMS = 7


def default_embedding_path() -> Path:
    """``assets/default_head_landmarks.npz`` of the checkout."""
    return Path(__file__).resolve().parents[2] / "assets" / "default_head_landmarks.npz"


@dataclass(frozen=True)
class LandmarkEmbedding:
    """68 points on a mesh: ``triangles`` (68,) int64, ``bary`` (68, 3), ``weights`` (68,) >= 0."""

    triangles: np.ndarray
    bary: np.ndarray
    weights: np.ndarray

    def __post_init__(self) -> None:
        tri = np.asarray(self.triangles)
        if tri.ndim != 1 or not np.issubdtype(tri.dtype, np.integer):
            raise InputError(f"triangles: expected a 1-D integer array, found {tri.dtype} {tri.shape}")
        n = tri.shape[0]
        bary = np.asarray(check_array(self.bary, "bary", (n, 3)), dtype=np.float64)
        w = np.asarray(check_array(self.weights, "weights", (n,)), dtype=np.float64)
        if np.any(w < 0):
            raise InputError("weights: expected values >= 0")
        if np.abs(bary.sum(axis=1) - 1).max() > 1e-6:
            raise InputError("bary: expected rows summing to 1")
        object.__setattr__(self, "triangles", tri.astype(np.int64))
        object.__setattr__(self, "bary", bary)
        object.__setattr__(self, "weights", w)

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> "LandmarkEmbedding":
        """Read an embedding ``.npz`` (default: the shipped one for the default head)."""
        from ..fileio import read_npz

        p = Path(path) if path is not None else default_embedding_path()
        if not p.is_file():
            raise TrackingError(f"{p}: landmark embedding not found; build it with "
                                f"scripts/build_landmark_embedding.py")
        z = read_npz(p, TrackingError, "landmark embedding")
        missing = [k for k in ("triangles", "bary", "weights") if k not in z]
        if missing:
            raise TrackingError(f"{p}: missing keys {missing}; found {sorted(z)}")
        return cls(z["triangles"], z["bary"], z["weights"])

    def save(self, path: str | os.PathLike) -> Path:
        from ..fileio import save_npz

        return save_npz(path, triangles=self.triangles, bary=self.bary, weights=self.weights)

    def points(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(..., 68, 3) landmark positions on ``vertices`` (..., V, 3)."""
        tri = np.asarray(faces)[self.triangles]  # (68, 3)
        return np.einsum("...lkc,lk->...lc", np.asarray(vertices)[..., tri, :], self.bary)


def embed_landmarks(landmarks2d: np.ndarray, world_to_cam: np.ndarray, K: np.ndarray, vertices: np.ndarray,
                    faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-project 2-D landmarks onto a mesh seen by a pinhole camera.

    For each landmark, every triangle whose projection contains the pixel is intersected and
    the nearest one (smallest camera depth) wins; a landmark outside every triangle goes to the
    nearest projected vertex's triangle (barycentrics clipped to the triangle).

    Parameters
    ----------
    landmarks2d : numpy.ndarray, shape (L, 2)    pixel x, y
    world_to_cam : numpy.ndarray, shape (4, 4)   OpenCV convention
    K : numpy.ndarray, shape (3, 3)
    vertices : numpy.ndarray, shape (V, 3)
    faces : numpy.ndarray, shape (F, 3)

    Returns
    -------
    triangles : numpy.ndarray, shape (L,) int64
    bary : numpy.ndarray, shape (L, 3)   perspective-correct barycentrics on the 3-D triangle
    """
    lm = np.asarray(check_array(landmarks2d, "landmarks2d", ("L", 2)), dtype=np.float64)
    v = np.asarray(check_array(vertices, "vertices", ("V", 3)), dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    pc = v @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    if np.any(pc[:, 2] <= 1e-6):
        raise InputError("vertices: every vertex must lie in front of the camera")
    px = (pc[:, :2] / pc[:, 2:3]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    a, b, c = px[f[:, 0]], px[f[:, 1]], px[f[:, 2]]  # (F, 2)
    e1, e2 = b - a, c - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.abs(det) > 1e-12
    tris = np.empty(len(lm), np.int64)
    bary = np.empty((len(lm), 3))
    for i, p in enumerate(lm):
        d = p - a
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]) / det
            w = (e1[:, 0] * d[:, 1] - e1[:, 1] * d[:, 0]) / det
        inside = ok & (u >= 0) & (w >= 0) & (u + w <= 1)
        idx = np.nonzero(inside)[0]
        if idx.size:
            # screen-space barycentrics -> 3-D point by interpolating 1/z (perspective-correct)
            l0 = 1 - u[idx] - w[idx]
            inv = l0 / pc[f[idx, 0], 2] + u[idx] / pc[f[idx, 1], 2] + w[idx] / pc[f[idx, 2], 2]
            k = int(np.argmax(inv))  # nearest surface along the ray
            t = idx[k]
            bw = np.array([l0[k] / pc[f[t, 0], 2], u[t] / pc[f[t, 1], 2], w[t] / pc[f[t, 2], 2]]) / inv[k]
        else:  # in a hole of the projection: the nearest-in-depth triangle among the closest on screen
            dist = np.linalg.norm((a + b + c) / 3 - p, axis=1)
            near = np.nonzero(dist <= dist.min() + 3.0)[0]
            t = int(near[np.argmin(pc[f[near]].mean(axis=1)[:, 2])])
            bw = np.full(3, 1 / 3)
        tris[i] = t
        bary[i] = bw / bw.sum()
    return tris, bary


class LandmarkHeadModel:
    """Projected 68 landmarks of a FLAME-format head as a function of the tracked parameters.

    Parameters
    ----------
    model : FlameModel
        The head (the default head; must share its AU map with ``au_map``).
    au_map : AUMap
        AU intensities -> expression coefficients.
    embedding : LandmarkEmbedding, optional
        Default: the shipped embedding of the default head.

    Attributes
    ----------
    n_au : int
    n_params : int
        ``n_au + 7``: AU state, jaw pitch, rotation (3), translation (3).
    """

    def __init__(self, model: Any, au_map: Any, embedding: LandmarkEmbedding | None = None) -> None:
        from ..reaction.features import au_scales

        emb = embedding if embedding is not None else LandmarkEmbedding.load()
        faces = model.faces.cpu().numpy().astype(np.int64)
        if emb.triangles.max() >= len(faces):
            raise TrackingError(f"landmark embedding: triangle {int(emb.triangles.max())} outside the model's "
                                f"{len(faces)} faces")
        self.embedding = emb
        self.au_names = tuple(au_map.names)
        self.n_au = len(self.au_names)
        self.n_params = self.n_au + N_POSE_PARAMS
        tri = faces[emb.triangles]  # (68, 3)
        self._verts, inverse = np.unique(tri.ravel(), return_inverse=True)
        self._tri_local = inverse.reshape(tri.shape)  # (68, 3) indices into the subset
        n_v = int(model.n_vertices)
        sel = self._verts
        n_expr = int(model.n_expr)
        v_t = model.v_template.cpu().double().numpy().reshape(n_v, 3)[sel]
        e_dirs = model.expr_dirs.cpu().double().numpy().reshape(n_expr, n_v, 3)[:, sel]
        m = np.asarray(au_map.matrix, dtype=np.float64)[:, :n_expr] * au_scales(self.au_names)[:, None]
        self._v0 = v_t                                   # (Vs, 3)
        self._v_au = np.einsum("ae,evc->avc", m, e_dirs)  # (n_au, Vs, 3) per unit AU state
        self._j0 = model.j_template.cpu().double().numpy()  # (J, 3)
        self._j_au = np.einsum("ae,ejc->ajc", m, model.j_expr_dirs.cpu().double().numpy().reshape(n_expr, -1, 3))
        posedirs = model.posedirs.cpu().double().numpy()  # (P, V*3)
        self._posedirs = posedirs.reshape(posedirs.shape[0], n_v, 3)[:, sel].transpose(1, 2, 0)  # (Vs, 3, P)
        self._weights = model.lbs_weights.cpu().double().numpy()[sel]
        self._parents = tuple(model.parents)
        self.root_rest = self._j0[0].copy()
        n_j = len(self._parents)
        if n_j < 3 or self._parents[1] != 0 or self._parents[2] != 1:
            raise TrackingError(f"landmark model: expected FLAME's kinematic tree (root, neck, jaw, eyes), found "
                                f"parents {self._parents}")
        self._posedirs_jaw = self._posedirs[:, :, 9:18]  # pose feature block of joint 2 (the jaw)
        self._posedirs_jaw_flat = np.ascontiguousarray(self._posedirs_jaw.transpose(2, 0, 1).reshape(9, -1))
        self._w_jaw = self._weights[:, 2]
        self.weights = emb.weights.copy()
        # the same model folded into the 68 landmarks (issue 37: the fit evaluates it ~17 times a step): the
        # landmarks are fixed barycentric combinations B of the vertices and the jaw's LBS is linear in them for
        # a given rotation, so B (v' + w (v' - J) D^T) = B v' + (B diag(w) v' - (B w) J^T) D^T, with v' the shaped
        # and jaw-corrected vertices (tested against the per-vertex form and the float64 LBS reference)
        n_lm, n_vs = self._tri_local.shape[0], self._v0.shape[0]
        bm = np.zeros((n_lm, n_vs))
        np.add.at(bm, (np.repeat(np.arange(n_lm), 3), self._tri_local.ravel()), emb.bary.ravel())
        bw = bm * self._w_jaw[None]
        pj = self._posedirs_jaw.transpose(2, 0, 1)  # (9, Vs, 3)
        self._lm_v0 = np.stack([bm @ self._v0, bw @ self._v0]).reshape(1, 2, n_lm * 3)  # (1, 2, 204)
        self._lm_au = np.stack([np.einsum("lv,avc->alc", bm, self._v_au), np.einsum("lv,avc->alc", bw, self._v_au)],
                               axis=1).reshape(self.n_au, 2 * n_lm * 3)  # (n_au, 2 * 204)
        self._lm_pose = np.stack([np.einsum("lv,pvc->plc", bm, pj), np.einsum("lv,pvc->plc", bw, pj)],
                                 axis=1).reshape(9, 2 * n_lm * 3)  # (9, 2 * 204)
        self._lm_wsum = bw.sum(axis=1)  # (68,) B w

    # ---------------------------------------------------------------------------------------
    def split(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(aus (..., n_au), jaw pitch (...,), rotation (..., 3), translation (..., 3))."""
        p = np.asarray(params, dtype=np.float64)
        n = self.n_au
        return p[..., :n], p[..., n], p[..., n + 1:n + 4], p[..., n + 4:n + 7]

    def points_flame_reference(self, params: np.ndarray) -> np.ndarray:
        """(B, 68, 3) landmarks in the FLAME frame, through the float64 LBS reference (slow, exact)."""
        from ..flame.lbs import lbs_reference_np

        p = np.atleast_2d(np.asarray(params, dtype=np.float64))
        aus, jaw, rot, _ = self.split(p)
        b = p.shape[0]
        v_shaped = self._v0[None] + np.einsum("ba,avc->bvc", aus, self._v_au)
        joints = self._j0[None] + np.einsum("ba,ajc->bjc", aus, self._j_au)
        pose = np.zeros((b, len(self._parents), 3))
        pose[:, 0] = rot
        pose[:, 2, 0] = jaw
        verts, _ = lbs_reference_np(v_shaped, joints, pose, self._posedirs, self._weights, self._parents)
        return np.einsum("blkc,lk->blc", verts[:, self._tri_local], self.embedding.bary)

    def _local(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Landmarks with the root unrotated (B, 68, 3) and the root joint (B, 3).

        :meth:`_local_vertices` folded into the landmarks (``__init__``): the same numbers to rounding, on
        (68, 3) arrays instead of the triangles' vertices and without the gather (issue 37: ~3x less CPU).
        """
        n = self.n_au
        b = p.shape[0]
        aus, jaw = p[:, :n], p[:, n]
        joints = (self._j0.reshape(1, -1) + aus @ self._j_au.reshape(n, -1)).reshape(b, -1, 3)
        c, s = np.cos(jaw), np.sin(jaw)
        d = np.zeros((b, 3, 3))  # R_jaw - I for a rotation about x by the jaw pitch
        d[:, 1, 1], d[:, 1, 2], d[:, 2, 1], d[:, 2, 2] = c - 1.0, -s, s, c - 1.0
        vw = (self._lm_v0 + (aus @ self._lm_au + d.reshape(b, 9) @ self._lm_pose).reshape(b, 2, -1)).reshape(b, 2, -1, 3)
        rel = vw[:, 1] - self._lm_wsum[None, :, None] * joints[:, None, 2]
        return vw[:, 0] + rel @ d.transpose(0, 2, 1), joints[:, 0]

    def _local_vertices(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_local` on the landmark triangles' vertices, then combined (the form it is tested against).

        With root, neck and eye joints at rest (identity), LBS reduces to the jaw alone:
        ``v = v' + w_jaw (R_jaw - I)(v' - J_jaw)`` with ``v' = v_shaped + posedirs_jaw vec(R_jaw - I)``.
        """
        aus, jaw, _, _ = self.split(p)
        b = p.shape[0]
        n_vs = self._v0.shape[0]
        # matmuls rather than einsum: this runs n_params + 1 times per Gauss-Newton step
        v = (self._v0.reshape(1, -1) + aus @ self._v_au.reshape(self.n_au, -1)).reshape(b, n_vs, 3)
        joints = (self._j0.reshape(1, -1) + aus @ self._j_au.reshape(self.n_au, -1)).reshape(b, -1, 3)
        c, s = np.cos(jaw), np.sin(jaw)
        d = np.zeros((b, 3, 3))  # R_jaw - I for a rotation about x by the jaw pitch
        d[:, 1, 1], d[:, 1, 2], d[:, 2, 1], d[:, 2, 2] = c - 1.0, -s, s, c - 1.0
        v = v + (d.reshape(b, 9) @ self._posedirs_jaw_flat).reshape(b, n_vs, 3)
        rel = v - joints[:, None, 2]
        v = v + self._w_jaw[None, :, None] * (rel @ d.transpose(0, 2, 1))
        pts = (v[:, self._tri_local] * self.embedding.bary[None, :, :, None]).sum(axis=2)
        return pts, joints[:, 0]

    def points_flame(self, params: np.ndarray) -> np.ndarray:
        """(B, 68, 3) landmarks in the FLAME frame for ``params`` (B, n_params) (translation ignored).

        Fast path: the jaw-only LBS of :meth:`_local`, then the root rotation as a rigid motion
        about the root joint (exact: FLAME's pose correctives exclude the root). Tested against
        :meth:`points_flame_reference`.
        """
        from ..geometry import rodrigues_np

        p = np.atleast_2d(np.asarray(params, dtype=np.float64))
        pts, root = self._local(p)
        R = rodrigues_np(self.split(p)[2])  # (B, 3, 3)
        return (pts - root[:, None]) @ R.transpose(0, 2, 1) + root[:, None]

    def points_camera(self, params: np.ndarray) -> np.ndarray:
        """(B, 68, 3) landmarks in OpenCV camera coordinates: ``F R (X - J_root) + T``."""
        from ..geometry import rodrigues_np

        p = np.atleast_2d(np.asarray(params, dtype=np.float64))
        pts, root = self._local(p)
        M = CAMERA_FROM_FLAME[None] @ rodrigues_np(self.split(p)[2])
        return (pts - root[:, None]) @ M.transpose(0, 2, 1) + self.split(p)[3][:, None, :]

    def project(self, params: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(B, 68, 2) pixel coordinates for ``params`` (B, n_params) and intrinsics ``K`` (3, 3)."""
        pc = self.points_camera(params)
        z = np.maximum(pc[..., 2:3], 1e-4)
        return pc[..., :2] / z * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
