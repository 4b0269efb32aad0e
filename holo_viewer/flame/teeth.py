"""Teeth added to a FLAME-format head the way GaussianAvatars adds them.

Pure numpy, no I/O. Two slabs (upper and lower teeth) are built behind the lips
from two ordered rings of lip vertices (``n`` anchors across the mouth, upper and
lower lip, left to right in the same order). With FLAME's 15-vertex outer lip
rings this gives GaussianAvatars' 120 vertices and 168 faces, in the same vertex
and face order (so Gaussians bound to teeth faces of a GaussianAvatars PLY land on
the same triangles):

* 8 rows of ``n`` vertices: upper root, lower root, upper edge, lower edge,
  upper root back, upper edge back, lower root back, lower edge back;
* 6 quad strips, 2 (n - 1) triangles each: upper front, upper back, upper
  bottom, lower front, lower back, lower top.

Geometry (``d`` = mean upper-to-lower lip distance, +y up, +z out of the face):
the mid line lies between the lips at their mean height, ``1.5 d`` behind them;
edges are ``0.1 d`` above / below it (the lower row ``0.4 d`` further back), roots
``2 d`` above / below the edges, and each slab is ``d`` thick.
Skinning: upper teeth follow the neck joint (1), lower teeth the jaw (2); shape
blend shapes are the mean of the two lip anchors' (expression ones zero); no
pose correctives; no influence on the joint regressor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TeethGeometry", "build_teeth", "FLAME_LIP_UPPER", "FLAME_LIP_LOWER", "NECK_JOINT", "JAW_JOINT"]

#: FLAME (5023 vertices) outer lip ring, upper lip, ordered across the mouth
#: (the ``lip_outside_ring_upper`` region GaussianAvatars uses).
FLAME_LIP_UPPER = (1713, 1715, 1716, 1735, 1696, 1694, 1657, 3543, 2774, 2811, 2813, 2850, 2833, 2832, 2830)
#: FLAME outer lip ring, lower lip, same order (``lip_outside_ring_lower``).
FLAME_LIP_LOWER = (1576, 1577, 1773, 1774, 1795, 1802, 1865, 3503, 2948, 2905, 2898, 2881, 2880, 2713, 2712)

NECK_JOINT = 1
JAW_JOINT = 2

# Row indices of the 8 rows of teeth vertices.
_UR, _LR, _UE, _LE, _URB, _UEB, _LRB, _LEB = range(8)
_UPPER_ROWS = (_UR, _UE, _URB, _UEB)
_LOWER_ROWS = (_LR, _LE, _LRB, _LEB)

# Triangulation of each strip: for quad column i (between columns i and i + 1),
# two triangles before the middle column and two after it (the diagonal flips at
# the middle so the slab is mirror-symmetric). Entries are (row, column offset).
_Tri = tuple[tuple[int, int], tuple[int, int], tuple[int, int]]
_STRIPS: tuple[tuple[tuple[_Tri, _Tri], tuple[_Tri, _Tri]], ...] = (
    # upper front: root row to edge row
    ((((_UR, 0), (_UE, 1), (_UE, 0)), ((_UR, 0), (_UR, 1), (_UE, 1))),
     (((_UR, 0), (_UR, 1), (_UE, 0)), ((_UR, 1), (_UE, 1), (_UE, 0)))),
    # upper back
    ((((_URB, 0), (_UEB, 0), (_UEB, 1)), ((_URB, 0), (_UEB, 1), (_URB, 1))),
     (((_URB, 0), (_UEB, 0), (_URB, 1)), ((_URB, 1), (_UEB, 0), (_UEB, 1)))),
    # upper bottom (biting edge)
    ((((_UEB, 0), (_UE, 0), (_UEB, 1)), ((_UEB, 1), (_UE, 0), (_UE, 1))),
     (((_UEB, 0), (_UE, 0), (_UE, 1)), ((_UEB, 0), (_UE, 1), (_UEB, 1)))),
    # lower front
    ((((_LE, 0), (_LE, 1), (_LR, 0)), ((_LE, 1), (_LR, 1), (_LR, 0))),
     (((_LE, 0), (_LR, 1), (_LR, 0)), ((_LE, 0), (_LE, 1), (_LR, 1)))),
    # lower back
    ((((_LRB, 0), (_LEB, 1), (_LEB, 0)), ((_LRB, 0), (_LRB, 1), (_LEB, 1))),
     (((_LRB, 0), (_LRB, 1), (_LEB, 0)), ((_LRB, 1), (_LEB, 1), (_LEB, 0)))),
    # lower top (biting edge)
    ((((_LEB, 0), (_LEB, 1), (_LE, 0)), ((_LEB, 1), (_LE, 1), (_LE, 0))),
     (((_LEB, 0), (_LE, 1), (_LE, 0)), ((_LEB, 0), (_LEB, 1), (_LE, 1)))),
)


@dataclass(frozen=True)
class TeethGeometry:
    """Arrays to append to a FLAME-format model.

    Attributes
    ----------
    vertices : numpy.ndarray
        (8 n, 3) float64 rest positions, metres.
    faces : numpy.ndarray
        (12 (n - 1), 3) int64, indices into the *full* vertex list (base + teeth).
    upper : numpy.ndarray
        (4 n,) int64 full indices of the upper-teeth vertices.
    lower : numpy.ndarray
        (4 n,) int64 full indices of the lower-teeth vertices.
    shapedirs : numpy.ndarray
        (8 n, 3, K) float64 blend shapes (shape part copied from the lips, expression zero).
    weights : numpy.ndarray
        (8 n, J) float64 skinning weights (one-hot neck / jaw).
    """

    vertices: np.ndarray
    faces: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    shapedirs: np.ndarray
    weights: np.ndarray


def _strip_faces(n: int) -> np.ndarray:
    """Triangles of the 6 strips in row/column form, (12 (n - 1), 3) with entries row * n + col."""
    mid = n // 2
    faces = []
    for lo, hi in _STRIPS:
        for i in range(n - 1):
            for tri in (lo if i < mid else hi):
                faces.append([row * n + i + dc for row, dc in tri])
    return np.asarray(faces, dtype=np.int64)


def build_teeth(
    v_template: np.ndarray,
    shapedirs: np.ndarray,
    n_shape: int,
    n_joints: int,
    anchor_upper: np.ndarray,
    anchor_lower: np.ndarray,
) -> TeethGeometry:
    """Build the teeth for a model from its lip anchor vertices.

    Parameters
    ----------
    v_template : numpy.ndarray
        (V, 3) rest vertices of the base model, metres.
    shapedirs : numpy.ndarray
        (V, 3, K) blend shapes of the base model; the first ``n_shape`` are shape
        components (copied to the teeth), the rest expression (zero for the teeth).
    n_shape : int
        Number of shape components at the front of ``shapedirs``.
    n_joints : int
        Number of joints J (the weights get J columns).
    anchor_upper, anchor_lower : numpy.ndarray
        (n,) vertex indices of the upper and lower lip, ordered across the mouth, n >= 2.

    Returns
    -------
    TeethGeometry
    """
    up = np.asarray(anchor_upper, dtype=np.int64)
    lo = np.asarray(anchor_lower, dtype=np.int64)
    n = up.shape[0]
    n_base = v_template.shape[0]
    lip_u = v_template[up].astype(np.float64)
    lip_l = v_template[lo].astype(np.float64)
    d = float(np.linalg.norm(lip_u - lip_l, axis=-1).mean())
    ey = np.array([0.0, d, 0.0])
    ez = np.array([0.0, 0.0, d])

    mid = 0.5 * (lip_u + lip_l)
    mid[:, 1] = mid[:, 1].mean()
    mid[:, 2] -= 1.5 * d
    upper_edge = mid + 0.1 * ey
    upper_root = upper_edge + 2.0 * ey
    lower_edge = mid - 0.1 * ey - 0.4 * ez
    lower_root = lower_edge - 2.0 * ey
    back = -1.0 * ez  # slab thickness d
    rows = [upper_root, lower_root, upper_edge, lower_edge,
            upper_root + back, upper_edge + back, lower_root + back, lower_edge + back]
    vertices = np.concatenate(rows, axis=0)

    faces = _strip_faces(n) + n_base
    col = np.arange(n)
    upper = np.concatenate([n_base + r * n + col for r in _UPPER_ROWS])
    lower = np.concatenate([n_base + r * n + col for r in _LOWER_ROWS])

    k = shapedirs.shape[2]
    td = np.zeros((8 * n, 3, k), dtype=np.float64)
    lip_dirs = 0.5 * (shapedirs[up, :, :n_shape] + shapedirs[lo, :, :n_shape])
    td[:, :, :n_shape] = np.tile(lip_dirs, (8, 1, 1))

    weights = np.zeros((8 * n, n_joints), dtype=np.float64)
    weights[upper - n_base, NECK_JOINT] = 1.0
    weights[lower - n_base, JAW_JOINT] = 1.0
    return TeethGeometry(vertices=vertices, faces=faces, upper=upper, lower=lower,
                         shapedirs=td, weights=weights)
