"""Linear blend skinning of FLAME (docs/design.md section 4), torch fast path and numpy reference.

Pure math, no I/O. With ``J`` joints (FLAME: 5; 0 global, 1 neck, 2 jaw, 3/4 eyes)
and parents ``p(k)``::

    R_k = Rodrigues(theta_k)
    v_posed = v_shaped + posedirs . vec(R_1 - I, ..., R_{J-1} - I)
    G_k = G_p(k) [R_k | J_k - J_p(k)]          (G_0 = [R_0 | J_0])
    A_k = G_k - [0 | G_k J_k]
    v = sum_k w_vk A_k [v_posed; 1]

``vec`` is row-major, so pose feature ``9 (k - 1) + 3 i + j`` is ``(R_k - I)[i, j]``,
matching the FLAME / SMPL ``posedirs`` layout (V, 3, 9 (J - 1)).

The torch path keeps each transform as a rotation block and a translation (no 4x4
homogeneous products) and blends all vertices with one matmul. The numpy reference
:func:`lbs_reference_np` is the same formula written plainly in float64.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch import Tensor

from ..geometry import rodrigues, rodrigues_np

__all__ = ["lbs", "lbs_reference_np", "pose_feature"]


def pose_feature(rot: Tensor) -> Tensor:
    """Pose-corrective feature ``vec(R_1 - I, ..., R_{J-1} - I)``.

    Parameters
    ----------
    rot : Tensor
        Rotation matrices of all joints, shape (B, J, 3, 3).

    Returns
    -------
    Tensor
        Shape (B, 9 (J - 1)).
    """
    eye = torch.eye(3, dtype=rot.dtype, device=rot.device)
    return (rot[:, 1:] - eye).reshape(rot.shape[0], -1)


def lbs(
    v_shaped: Tensor,
    joints: Tensor,
    pose: Tensor,
    posedirs: Tensor,
    weights: Tensor,
    parents: Sequence[int],
) -> tuple[Tensor, Tensor]:
    """Pose shaped vertices by linear blend skinning.

    Parameters
    ----------
    v_shaped : Tensor
        Shaped rest vertices, shape (B, V, 3), metres.
    joints : Tensor
        Rest joint locations, shape (B, J, 3), metres (``J_regressor @ v_shaped``).
    pose : Tensor
        Axis-angle rotation of each joint relative to its parent, shape (B, J, 3), radians.
    posedirs : Tensor
        Pose-corrective blend shapes, flattened, shape (9 (J - 1), V * 3).
    weights : Tensor
        Skinning weights, shape (V, J).
    parents : sequence of int
        Parent of each joint, ``parents[0] == -1``, ``parents[k] < k``.

    Returns
    -------
    vertices : Tensor
        Posed vertices, shape (B, V, 3).
    posed_joints : Tensor
        Posed joint locations, shape (B, J, 3).
    """
    b, v = v_shaped.shape[0], v_shaped.shape[1]
    n_joints = len(parents)
    rot = rodrigues(pose)  # (B, J, 3, 3)
    v_posed = v_shaped + (pose_feature(rot) @ posedirs).view(b, v, 3)

    # Chain: world rotation Rw_k and world translation tw_k of G_k.
    rw: list[Tensor] = [rot[:, 0]]
    tw: list[Tensor] = [joints[:, 0]]
    for k in range(1, n_joints):
        p = parents[k]
        rel = (joints[:, k] - joints[:, p]).unsqueeze(-1)  # (B, 3, 1)
        rw.append(rw[p] @ rot[:, k])
        tw.append((rw[p] @ rel).squeeze(-1) + tw[p])
    g_rot = torch.stack(rw, dim=1)  # (B, J, 3, 3)
    g_t = torch.stack(tw, dim=1)  # (B, J, 3)
    # A_k = [Rw_k | tw_k - Rw_k J_k]
    a_t = g_t - (g_rot @ joints.unsqueeze(-1)).squeeze(-1)
    a = torch.cat([g_rot.reshape(b, n_joints, 9), a_t], dim=-1)  # (B, J, 12)
    blended = torch.matmul(weights, a)  # (B, V, 12)
    r = blended[..., :9].reshape(b, v, 3, 3)
    verts = (r @ v_posed.unsqueeze(-1)).squeeze(-1) + blended[..., 9:]
    return verts, g_t


def lbs_reference_np(
    v_shaped: np.ndarray,
    joints: np.ndarray,
    pose: np.ndarray,
    posedirs: np.ndarray,
    weights: np.ndarray,
    parents: Sequence[int],
) -> tuple[np.ndarray, np.ndarray]:
    """Float64 numpy LBS written plainly with 4x4 homogeneous transforms (the reference).

    Parameters are those of :func:`lbs` as numpy arrays, except ``posedirs`` in the
    file layout (V, 3, 9 (J - 1)).

    Returns
    -------
    vertices : numpy.ndarray
        (B, V, 3) float64.
    posed_joints : numpy.ndarray
        (B, J, 3) float64.
    """
    v_shaped = np.asarray(v_shaped, np.float64)
    joints = np.asarray(joints, np.float64)
    b, v = v_shaped.shape[:2]
    n_joints = len(parents)
    rot = rodrigues_np(pose)  # (B, J, 3, 3)
    feat = (rot[:, 1:] - np.eye(3)).reshape(b, -1)
    v_posed = v_shaped + np.einsum("vcp,bp->bvc", np.asarray(posedirs, np.float64), feat)
    g = np.zeros((b, n_joints, 4, 4))
    for k in range(n_joints):
        local = np.zeros((b, 4, 4))
        local[:, :3, :3] = rot[:, k]
        local[:, 3, 3] = 1.0
        if parents[k] < 0:
            local[:, :3, 3] = joints[:, k]
            g[:, k] = local
        else:
            local[:, :3, 3] = joints[:, k] - joints[:, parents[k]]
            g[:, k] = g[:, parents[k]] @ local
    a = g.copy()
    a[:, :, :3, 3] -= np.einsum("bkij,bkj->bki", g[:, :, :3, :3], joints)
    t = np.einsum("vk,bkij->bvij", np.asarray(weights, np.float64), a)
    homo = np.concatenate([v_posed, np.ones((b, v, 1))], axis=-1)
    verts = np.einsum("bvij,bvj->bvi", t, homo)[..., :3]
    return verts, g[:, :, :3, 3].copy()
