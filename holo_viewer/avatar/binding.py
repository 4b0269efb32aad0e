"""GaussianAvatars triangle binding (pure math; torch fast path, numpy float64 reference).

Each Gaussian has a parent face ``binding``, a local mean ``mu``, a local log-scale and a
local quaternion. For a face with vertices ``v0, v1, v2`` (docs/design.md, Qian et al. CVPR'24)::

    a0 = n(v1 - v0)                      (first edge direction)
    a1 = n(a0 x (v2 - v0))               (face normal)
    a2 = a0 x a1                         (in-plane, completes a right-handed frame)
    R_f = [a0 | a1 | a2]                 (columns)
    s_f = (|v1 - v0| + |a2 . (v2 - v0)|) / 2
    c_f = (v0 + v1 + v2) / 3

    x     = s_f R_f mu + c_f
    scale = exp(log_s) s_f               (log_scale_world = log_s + log s_f)
    q     = q(R_f) (x) n(q_local)

SH coefficients are not rotated (GaussianAvatars keeps them in world space).

Degenerate faces
----------------
A face is *degenerate* when its first edge is shorter than ``eps`` or its height over that
edge, ``|a0 x (v2 - v0)|``, is below ``eps`` (``eps = 1e-9`` m, below float32 resolution at
head scale): it has (near) zero area and no normal. Fallback, chosen to stay finite and
continuous enough to never produce NaN: ``a0`` is the longest of the three edges (or +x when
all three vertices coincide); the normal ``a1`` is ``n(a0 x e)`` with ``e`` the world axis
least aligned with ``a0``; ``a2 = a0 x a1``; ``s_f`` is floored at ``eps``, so the face's
Gaussians shrink to (invisible) points at its centre. Degenerate faces are counted by
:func:`face_frames` so callers can report them.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ..geometry import quat_multiply, quat_multiply_np, rotmat_to_quat, rotmat_to_quat_np

__all__ = ["DEGENERATE_EPS", "face_frames", "face_frames_np", "bind_to_world", "bind_to_world_np",
           "world_to_local_np", "face_normals"]

#: Length below which an edge or a triangle height counts as zero (metres).
DEGENERATE_EPS = 1e-9


def _fallback_axes(e_best: Tensor, eps: float) -> tuple[Tensor, Tensor]:
    """Unit a0 (..., 3) along ``e_best`` (or +x) and a unit normal a1 perpendicular to it."""
    ln = torch.linalg.norm(e_best, dim=-1, keepdim=True)
    ex = torch.zeros_like(e_best)
    ex[..., 0] = 1.0
    a0 = torch.where(ln > eps, e_best / ln.clamp_min(eps), ex)
    # world axis least aligned with a0
    k = torch.argmin(a0.abs(), dim=-1)
    ref = torch.nn.functional.one_hot(k, 3).to(a0.dtype)
    n = torch.linalg.cross(a0, ref)
    a1 = n / torch.linalg.norm(n, dim=-1, keepdim=True).clamp_min(eps)
    return a0, a1


def face_frames(vertices: Tensor, faces: Tensor, eps: float = DEGENERATE_EPS
                ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per-face rotation, scale and centre.

    Parameters
    ----------
    vertices : Tensor
        (B, V, 3) mesh vertices, metres.
    faces : Tensor
        (F, 3) int64 vertex indices.
    eps : float
        Degeneracy threshold in metres (see module docstring).

    Returns
    -------
    rot : Tensor
        (B, F, 3, 3) rotation matrices, columns ``[a0 | a1 | a2]``.
    scale : Tensor
        (B, F) face scale ``s_f`` (>= eps), metres.
    centre : Tensor
        (B, F, 3) face centroids, metres.
    degenerate : Tensor
        (B, F) bool, faces that used the fallback frame.
    """
    v0 = vertices[:, faces[:, 0]]
    v1 = vertices[:, faces[:, 1]]
    v2 = vertices[:, faces[:, 2]]
    e0 = v1 - v0
    e2 = v2 - v0
    l0 = torch.linalg.norm(e0, dim=-1, keepdim=True)
    a0 = e0 / l0.clamp_min(eps)
    n = torch.linalg.cross(a0, e2)
    ln = torch.linalg.norm(n, dim=-1, keepdim=True)
    a1 = n / ln.clamp_min(eps)
    degenerate = (l0[..., 0] <= eps) | (ln[..., 0] <= eps)
    if bool(degenerate.any()):
        e1 = v2 - v1
        edges = torch.stack([e0, e1, e2], dim=-2)  # (B, F, 3 edges, 3)
        k = torch.argmax(torch.linalg.norm(edges, dim=-1), dim=-1)
        e_best = torch.gather(edges, -2, k[..., None, None].expand(*k.shape, 1, 3)).squeeze(-2)
        f0, f1 = _fallback_axes(e_best, eps)
        d = degenerate[..., None]
        a0 = torch.where(d, f0, a0)
        a1 = torch.where(d, f1, a1)
    a2 = torch.linalg.cross(a0, a1)
    rot = torch.stack([a0, a1, a2], dim=-1)
    scale = ((l0[..., 0] + (a2 * e2).sum(-1).abs()) * 0.5).clamp_min(eps)
    centre = (v0 + v1 + v2) / 3.0
    return rot, scale, centre, degenerate


def face_normals(vertices: Tensor, faces: Tensor) -> Tensor:
    """(B, F, 3) unit face normals ``a1`` of the binding frame (fallback for degenerate faces)."""
    return face_frames(vertices, faces)[0][..., 1]


def bind_to_world(local_means: Tensor, local_quats: Tensor, local_log_scales: Tensor, binding: Tensor,
                  rot: Tensor, scale: Tensor, centre: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Local (triangle-frame) Gaussians to world space.

    Parameters
    ----------
    local_means : Tensor
        (N, 3) local means ``mu`` (units of the face scale).
    local_quats : Tensor
        (N, 4) wxyz local rotations, **already normalised**.
    local_log_scales : Tensor
        (N, 3) local log-scales.
    binding : Tensor
        (N,) int64 parent face of each Gaussian.
    rot, scale, centre : Tensor
        Face frames from :func:`face_frames`: (B, F, 3, 3), (B, F), (B, F, 3).

    Returns
    -------
    means : Tensor
        (B, N, 3) world means, metres.
    quats : Tensor
        (B, N, 4) world wxyz unit quaternions.
    log_scales : Tensor
        (B, N, 3) world log-scales.
    """
    b, f = scale.shape
    face_q = rotmat_to_quat(rot)  # (B, F, 4)
    sr = rot * scale[..., None, None]  # columns s_f a0, s_f a1, s_f a2
    packed = torch.cat([sr.transpose(-1, -2).reshape(b, f, 9), centre, face_q, scale.log()[..., None]], dim=-1)  # (B, F, 17)
    g = packed[:, binding]  # (B, N, 17)
    mu = local_means
    means = (g[..., 0:3] * mu[:, 0:1] + g[..., 3:6] * mu[:, 1:2] + g[..., 6:9] * mu[:, 2:3]) + g[..., 9:12]
    quats = quat_multiply(g[..., 12:16], local_quats.expand(b, -1, -1))
    log_scales = local_log_scales + g[..., 16:17]
    return means, quats, log_scales


# --------------------------------------------------------------------------- float64 reference
def face_frames_np(vertices: np.ndarray, faces: np.ndarray, eps: float = DEGENERATE_EPS
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Float64 reference of :func:`face_frames` for one mesh (V, 3): written face by face.

    Returns rot (F, 3, 3), scale (F,), centre (F, 3), degenerate (F,).
    """
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    nf = faces.shape[0]
    rot = np.zeros((nf, 3, 3))
    scale = np.zeros(nf)
    centre = np.zeros((nf, 3))
    degenerate = np.zeros(nf, bool)
    for i, (i0, i1, i2) in enumerate(faces):
        v0, v1, v2 = vertices[i0], vertices[i1], vertices[i2]
        e0, e2 = v1 - v0, v2 - v0
        l0 = np.linalg.norm(e0)
        a0 = e0 / max(l0, eps)
        n = np.cross(a0, e2)
        if l0 <= eps or np.linalg.norm(n) <= eps:
            degenerate[i] = True
            edges = [e0, v2 - v1, e2]
            e = edges[int(np.argmax([np.linalg.norm(x) for x in edges]))]
            a0 = e / np.linalg.norm(e) if np.linalg.norm(e) > eps else np.array([1.0, 0.0, 0.0])
            ref = np.eye(3)[int(np.argmin(np.abs(a0)))]
            n = np.cross(a0, ref)
        a1 = n / np.linalg.norm(n)
        a2 = np.cross(a0, a1)
        rot[i] = np.stack([a0, a1, a2], axis=1)
        scale[i] = max((l0 + abs(a2 @ e2)) / 2, eps)
        centre[i] = (v0 + v1 + v2) / 3
    return rot, scale, centre, degenerate


def _bound_face_frames_np(vertices: np.ndarray, faces: np.ndarray, binding: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`face_frames_np` of the faces ``binding`` uses only (each face's frame depends on that face
    alone, so the values are the same), with the binding renumbered into them: rot, scale, centre, index."""
    used, index = np.unique(np.asarray(binding), return_inverse=True)
    rot, scale, centre, _ = face_frames_np(vertices, np.asarray(faces)[used])
    return rot, scale, centre, index.reshape(-1)


def bind_to_world_np(local_means: np.ndarray, local_quats: np.ndarray, local_log_scales: np.ndarray,
                     binding: np.ndarray, vertices: np.ndarray, faces: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Float64 reference: world means (N, 3), unit quats (N, 4) and log-scales (N, 3) for one mesh."""
    rot, scale, centre, b = _bound_face_frames_np(vertices, faces, binding)
    mu = np.asarray(local_means, np.float64)
    means = scale[b, None] * np.einsum("nij,nj->ni", rot[b], mu) + centre[b]
    q = np.asarray(local_quats, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    quats = quat_multiply_np(rotmat_to_quat_np(rot[b]), q)
    log_scales = np.asarray(local_log_scales, np.float64) + np.log(scale[b])[:, None]
    return means, quats, log_scales


def world_to_local_np(means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray, binding: np.ndarray,
                      vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`bind_to_world_np`: world Gaussians on a mesh -> local (float64).

    Returns local means (N, 3), local unit quats (N, 4), local log-scales (N, 3).
    """
    rot, scale, centre, b = _bound_face_frames_np(vertices, faces, binding)
    d = np.asarray(means, np.float64) - centre[b]
    mu = np.einsum("nji,nj->ni", rot[b], d) / scale[b, None]
    fq = rotmat_to_quat_np(rot[b])
    fq_inv = fq * np.array([1.0, -1.0, -1.0, -1.0])
    q = np.asarray(quats, np.float64)
    q = quat_multiply_np(fq_inv, q / np.linalg.norm(q, axis=1, keepdims=True))
    ls = np.asarray(log_scales, np.float64) - np.log(scale[b])[:, None]
    return mu, q, ls

