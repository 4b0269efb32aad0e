"""Rotations, in one module: quaternions, axis-angle (Rodrigues) and covariances (pure math).

Quaternions are (w, x, y, z). Axis-angle vectors ``r`` (3,) rotate by ``|r|`` radians about
``r / |r|``. Rotation matrices act on column vectors (``x' = R x``). Functions named ``*_np``
take numpy arrays, the others torch tensors (torch is imported when one is called); all accept
any leading batch shape.

Rodrigues' formula is written with the *unnormalised* skew matrix ``K = [r]_x``::

    R = I + a(theta) K + b(theta) K @ K,   a = sin(theta) / theta,
                                          b = (1 - cos(theta)) / theta**2

so no axis has to be normalised. ``a`` and ``b`` are evaluated with their Taylor
series below a small angle, which keeps values and gradients finite (and exact to
float64 rounding) at and near ``r = 0``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from torch import Tensor

__all__ = [
    "quat_to_rotmat_np", "rotmat_to_quat_np", "quat_multiply_np", "covariance_np",
    "quat_to_rotmat", "rotmat_to_quat", "quat_multiply", "rodrigues", "rodrigues_np", "skew", "vertex_normals",
]


def quat_to_rotmat_np(q: np.ndarray) -> np.ndarray:
    """(..., 4) wxyz quaternions (normalised here) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3), dtype=q.dtype)
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotmat_to_quat_np(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit wxyz quaternions with w >= 0 (Shepperd's method)."""
    R = np.asarray(R)
    m = R.reshape(-1, 3, 3)
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4), dtype=R.dtype)
    for case in range(4):
        sel = k == case
        if not np.any(sel):
            continue
        a = m[sel]
        if case == 0:
            s = np.sqrt(np.maximum(1.0 + tr[sel], 1e-30)) * 2
            q[sel] = np.stack([0.25 * s, (a[:, 2, 1] - a[:, 1, 2]) / s, (a[:, 0, 2] - a[:, 2, 0]) / s,
                               (a[:, 1, 0] - a[:, 0, 1]) / s], axis=1)
        elif case == 1:
            s = np.sqrt(np.maximum(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2], 1e-30)) * 2
            q[sel] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, 0.25 * s, (a[:, 0, 1] + a[:, 1, 0]) / s,
                               (a[:, 0, 2] + a[:, 2, 0]) / s], axis=1)
        elif case == 2:
            s = np.sqrt(np.maximum(1.0 + a[:, 1, 1] - a[:, 0, 0] - a[:, 2, 2], 1e-30)) * 2
            q[sel] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 0, 1] + a[:, 1, 0]) / s, 0.25 * s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s], axis=1)
        else:
            s = np.sqrt(np.maximum(1.0 + a[:, 2, 2] - a[:, 0, 0] - a[:, 1, 1], 1e-30)) * 2
            q[sel] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s], axis=1)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(q[:, :1] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def quat_multiply_np(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a (x) b of (..., 4) wxyz quaternions (rotation b first, then a)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def covariance_np(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Sigma = R S S^T R^T from (N, 4) wxyz quats and (N, 3) linear scales -> (N, 3, 3)."""
    R = quat_to_rotmat_np(quats)
    M = R * np.asarray(scales)[..., None, :]
    return M @ np.swapaxes(M, -1, -2)


# ------------------------------------------------------------------------- torch
def quat_to_rotmat(q):  # noqa: ANN001, ANN201 - torch is imported lazily
    """Torch: (..., 4) wxyz quaternions (normalised here) -> (..., 3, 3)."""
    import torch

    q = q / torch.linalg.norm(q, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def rotmat_to_quat(R):  # noqa: ANN001, ANN201
    """Torch: (..., 3, 3) rotations -> (..., 4) unit wxyz quaternions with w >= 0.

    Branch-free Shepperd selection (largest of the four candidate denominators), stable for
    any rotation including 180 degree turns.
    """
    import torch

    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    cands = torch.stack([
        torch.stack([1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01], -1),
        torch.stack([m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20], -1),
        torch.stack([m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21], -1),
        torch.stack([m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22], -1),
    ], dim=-2)  # (..., 4 candidates, 4) each proportional to q * (4 q_k)
    diag = torch.stack([cands[..., 0, 0], cands[..., 1, 1], cands[..., 2, 2], cands[..., 3, 3]], -1)
    k = torch.argmax(diag, dim=-1, keepdim=True)
    best = torch.gather(cands, -2, k[..., None].expand(*k.shape[:-1], 1, 4)).squeeze(-2)
    q = best / torch.linalg.norm(best, dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


def quat_multiply(a, b):  # noqa: ANN001, ANN201
    """Torch Hamilton product a (x) b of (..., 4) wxyz quaternions."""
    import torch

    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], dim=-1)


# ------------------------------------------------------------------------- axis-angle
# Below this angle (radians) the Taylor series of a and b are used. At 1e-3 the
# neglected terms are O(theta**4)/120 ~ 1e-14, below float64 rounding of the
# leading term, and the closed forms are still accurate above it in float64.
_SMALL_ANGLE = 1e-3


def skew(r: "Tensor") -> "Tensor":
    """Skew-symmetric cross-product matrices.

    Parameters
    ----------
    r : Tensor
        Vectors, shape (..., 3).

    Returns
    -------
    Tensor
        ``K`` with ``K @ x == cross(r, x)``, shape (..., 3, 3).
    """
    import torch

    x, y, z = r.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*r.shape[:-1], 3, 3)


def _coefficients(theta2: "Tensor") -> tuple["Tensor", "Tensor"]:
    """``sin(t)/t`` and ``(1-cos(t))/t**2`` from ``t**2``, safe at ``t = 0``."""
    import torch

    small = theta2 < _SMALL_ANGLE ** 2
    # Replace small angles by 1 in the closed-form branch so that neither its value
    # nor its gradient (which torch.where still evaluates) can become NaN.
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(safe2)
    a_closed = torch.sin(theta) / theta
    b_closed = (1.0 - torch.cos(theta)) / safe2
    a_taylor = 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0
    b_taylor = 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0
    return torch.where(small, a_taylor, a_closed), torch.where(small, b_taylor, b_closed)


def rodrigues(r: "Tensor") -> "Tensor":
    """Rotation matrices from axis-angle vectors (Rodrigues' formula).

    Parameters
    ----------
    r : Tensor
        Axis-angle vectors in radians, shape (..., 3), floating point.

    Returns
    -------
    Tensor
        Rotation matrices, shape (..., 3, 3), same dtype and device as ``r``.
        Finite values and gradients for every finite ``r``, including ``r = 0``.
    """
    import torch

    theta2 = (r * r).sum(-1)
    a, b = _coefficients(theta2)
    k = skew(r)
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def rodrigues_np(r: np.ndarray) -> np.ndarray:
    """NumPy float64 version of :func:`rodrigues` (reference and tests).

    Parameters
    ----------
    r : numpy.ndarray
        Axis-angle vectors in radians, shape (..., 3).

    Returns
    -------
    numpy.ndarray
        Rotation matrices, shape (..., 3, 3), float64.
    """
    r = np.asarray(r, dtype=np.float64)
    theta2 = np.sum(r * r, axis=-1)
    small = theta2 < _SMALL_ANGLE ** 2
    safe2 = np.where(small, 1.0, theta2)
    theta = np.sqrt(safe2)
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2 ** 2 / 120.0, np.sin(theta) / theta)
    b = np.where(small, 0.5 - theta2 / 24.0 + theta2 ** 2 / 720.0, (1.0 - np.cos(theta)) / safe2)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(*r.shape[:-1], 3, 3)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit vertex normals of a triangle mesh: the area-weighted sum of the incident triangles' normals.

    Parameters
    ----------
    vertices : numpy.ndarray
        (V, 3) positions (any float dtype; computed in float64).
    faces : numpy.ndarray
        (F, 3) vertex indices, counter-clockwise seen from outside (the normal's side).

    Returns
    -------
    numpy.ndarray
        (V, 3) float64 unit normals; zero for vertices no triangle uses (or whose triangles cancel).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 x area
    # each face's normal added at its three corners: np.bincount sums per vertex (np.add.at did the same
    # in 2x the time: 13.5 -> 6 ms on the default head, the viewer's live slider step)
    corners = f.T.ravel()
    n = np.stack([np.bincount(corners, weights=np.tile(fn[:, c], 3), minlength=len(v)) for c in range(3)], axis=1)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
