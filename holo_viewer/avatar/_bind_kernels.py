"""Numba fast path of the triangle binding (CPU, no autograd).

Same formulas and degenerate-face fallback as :mod:`holo_viewer.avatar.binding` (the
torch version there is the differentiable path and the float64 numpy functions are the
reference). Frames are computed in float64 per face; per-Gaussian products in float64
and stored in the output dtype. Tested against the reference in
``tests/test_avatar_binding.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["face_frames_nb", "bind_nb", "bind_subset_nb", "moved_faces_nb", "bind_cached_nb", "bind_faces_nb",
           "face_order"]


@njit(cache=True, inline="always")
def _cross(ax, ay, az, bx, by, bz):  # noqa: ANN001, ANN202
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@njit(cache=True, inline="always")
def _face_frame(verts, faces, eps, f, fr):  # noqa: ANN001, ANN202
    """Face ``f``'s packed frame into ``fr`` (17,) (:func:`face_frames_nb`'s row); returns whether it is
    degenerate."""
    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
    v0x, v0y, v0z = float(verts[i0, 0]), float(verts[i0, 1]), float(verts[i0, 2])
    v1x, v1y, v1z = float(verts[i1, 0]), float(verts[i1, 1]), float(verts[i1, 2])
    v2x, v2y, v2z = float(verts[i2, 0]), float(verts[i2, 1]), float(verts[i2, 2])
    e0x, e0y, e0z = v1x - v0x, v1y - v0y, v1z - v0z
    e2x, e2y, e2z = v2x - v0x, v2y - v0y, v2z - v0z
    l0 = math.sqrt(e0x * e0x + e0y * e0y + e0z * e0z)
    d0 = max(l0, eps)
    a0x, a0y, a0z = e0x / d0, e0y / d0, e0z / d0
    nx, ny, nz = _cross(a0x, a0y, a0z, e2x, e2y, e2z)
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    deg = l0 <= eps or ln <= eps
    if deg:
        e1x, e1y, e1z = v2x - v1x, v2y - v1y, v2z - v1z
        n0 = l0
        n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        n2 = math.sqrt(e2x * e2x + e2y * e2y + e2z * e2z)
        bx, by, bz, bl = e0x, e0y, e0z, n0
        if n1 > bl:
            bx, by, bz, bl = e1x, e1y, e1z, n1
        if n2 > bl:
            bx, by, bz, bl = e2x, e2y, e2z, n2
        if bl > eps:
            a0x, a0y, a0z = bx / bl, by / bl, bz / bl
        else:
            a0x, a0y, a0z = 1.0, 0.0, 0.0
        ax_, ay_, az_ = abs(a0x), abs(a0y), abs(a0z)
        rx, ry, rz = 1.0, 0.0, 0.0
        if ay_ < ax_ and ay_ <= az_:
            rx, ry, rz = 0.0, 1.0, 0.0
        elif az_ < ax_ and az_ < ay_:
            rx, ry, rz = 0.0, 0.0, 1.0
        nx, ny, nz = _cross(a0x, a0y, a0z, rx, ry, rz)
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    dn = max(ln, eps)
    a1x, a1y, a1z = nx / dn, ny / dn, nz / dn
    a2x, a2y, a2z = _cross(a0x, a0y, a0z, a1x, a1y, a1z)
    s = max(0.5 * (l0 + abs(a2x * e2x + a2y * e2y + a2z * e2z)), eps)
    fr[0], fr[1], fr[2] = s * a0x, s * a0y, s * a0z
    fr[3], fr[4], fr[5] = s * a1x, s * a1y, s * a1z
    fr[6], fr[7], fr[8] = s * a2x, s * a2y, s * a2z
    fr[9] = (v0x + v1x + v2x) / 3.0
    fr[10] = (v0y + v1y + v2y) / 3.0
    fr[11] = (v0z + v1z + v2z) / 3.0
    # quaternion of R = [a0 | a1 | a2]: m_ij = row i, column j
    m00, m01, m02 = a0x, a1x, a2x
    m10, m11, m12 = a0y, a1y, a2y
    m20, m21, m22 = a0z, a1z, a2z
    c0 = 1.0 + m00 + m11 + m22
    c1 = 1.0 + m00 - m11 - m22
    c2 = 1.0 - m00 + m11 - m22
    c3 = 1.0 - m00 - m11 + m22
    if c0 >= c1 and c0 >= c2 and c0 >= c3:
        qw, qx, qy, qz = c0, m21 - m12, m02 - m20, m10 - m01
    elif c1 >= c2 and c1 >= c3:
        qw, qx, qy, qz = m21 - m12, c1, m01 + m10, m02 + m20
    elif c2 >= c3:
        qw, qx, qy, qz = m02 - m20, m01 + m10, c2, m12 + m21
    else:
        qw, qx, qy, qz = m10 - m01, m02 + m20, m12 + m21, c3
    qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if qw < 0:
        qn = -qn
    fr[12], fr[13], fr[14], fr[15] = qw / qn, qx / qn, qy / qn, qz / qn
    fr[16] = math.log(s)
    return deg


@njit(cache=True, parallel=True)
def face_frames_nb(verts, faces, eps, frame, degenerate, mask):  # noqa: ANN001, ANN201
    """Per-face packed frames.

    verts (V, 3) float; faces (F, 3) int64; writes ``frame`` (F, 17) float64 =
    [s R column-major (9), centre (3), q(R) wxyz (4), log s (1)] and ``degenerate`` (F,) bool,
    for the faces where ``mask`` (F,) is True (other rows are left untouched).
    """
    nf = faces.shape[0]
    for f in prange(nf):
        if not mask[f]:
            degenerate[f] = False
            continue
        degenerate[f] = _face_frame(verts, faces, eps, f, frame[f])


@njit(cache=True, inline="always")
def _apply(fr, mu, ql, ls, k, j, out_m, out_q, out_ls):  # noqa: ANN001, ANN202
    """Local Gaussian row k (mu, ql, ls) through the packed frame ``fr`` (17,) -> output row j."""
    m0, m1, m2 = float(mu[k, 0]), float(mu[k, 1]), float(mu[k, 2])
    out_m[j, 0] = fr[0] * m0 + fr[3] * m1 + fr[6] * m2 + fr[9]
    out_m[j, 1] = fr[1] * m0 + fr[4] * m1 + fr[7] * m2 + fr[10]
    out_m[j, 2] = fr[2] * m0 + fr[5] * m1 + fr[8] * m2 + fr[11]
    aw, ax, ay, az = fr[12], fr[13], fr[14], fr[15]
    bw, bx, by, bz = float(ql[k, 0]), float(ql[k, 1]), float(ql[k, 2]), float(ql[k, 3])
    out_q[j, 0] = aw * bw - ax * bx - ay * by - az * bz
    out_q[j, 1] = aw * bx + ax * bw + ay * bz - az * by
    out_q[j, 2] = aw * by - ax * bz + ay * bw + az * bx
    out_q[j, 3] = aw * bz + ax * by - ay * bx + az * bw
    out_ls[j, 0] = ls[k, 0] + fr[16]
    out_ls[j, 1] = ls[k, 1] + fr[16]
    out_ls[j, 2] = ls[k, 2] + fr[16]


@njit(cache=True, inline="always")
def _one(frame, binding, mu, ql, ls, i, j, out_m, out_q, out_ls):  # noqa: ANN001, ANN202
    """Gaussian i (input) -> output row j."""
    _apply(frame[binding[i]], mu, ql, ls, i, j, out_m, out_q, out_ls)


@njit(cache=True, parallel=True)
def bind_nb(frame, binding, mu, ql, ls, out_m, out_q, out_ls):  # noqa: ANN001, ANN201
    """All Gaussians: local (N, 3/4/3) -> world, written into out_* (N, 3/4/3)."""
    for i in prange(binding.shape[0]):
        _one(frame, binding, mu, ql, ls, i, i, out_m, out_q, out_ls)


@njit(cache=True, parallel=True)
def bind_subset_nb(frame, binding, mu, ql, ls, index, out_m, out_q, out_ls):  # noqa: ANN001, ANN201
    """Only Gaussians ``index`` (M,) are recomputed in place in out_* (N, ...)."""
    for k in prange(index.shape[0]):
        i = index[k]
        _one(frame, binding, mu, ql, ls, i, i, out_m, out_q, out_ls)


#: faces per work item of bind_faces_nb (each item makes one 17-double frame buffer)
FACES_PER_ITEM = 256


@njit(cache=True, parallel=True)
def bind_faces_nb(verts, faces, eps, face_list, starts, gaussians, mu, ql, ls, out_m, out_q, out_ls):  # noqa: ANN001, ANN201
    """The faces ``face_list`` (F,) and the Gaussians on them, fused: each face's frame (as
    :func:`face_frames_nb` computes it) is applied at once to its Gaussians ``gaussians[starts[j]:starts[j + 1]]``
    (their output rows), whose local values are rows ``starts[j]..`` of ``mu``, ``ql``, ``ls`` (the avatar's
    rows in that order, see :func:`face_order`). The rows written equal :func:`face_frames_nb` then
    :func:`bind_subset_nb` bit for bit (the same expressions), without the (F, 17) table between them: the
    avatar's Gaussians are not ordered by face, so bind_subset_nb read that table (8 MB for the default
    head) at random."""
    nf = face_list.shape[0]
    per = FACES_PER_ITEM
    for item in prange((nf + per - 1) // per):
        fr = np.empty(17)
        for j in range(item * per, min(nf, (item + 1) * per)):
            _face_frame(verts, faces, eps, face_list[j], fr)
            for k in range(starts[j], starts[j + 1]):
                _apply(fr, mu, ql, ls, k, gaussians[k], out_m, out_q, out_ls)


def face_order(binding: np.ndarray, index: np.ndarray, mu: np.ndarray, ql: np.ndarray, ls: np.ndarray
               ) -> tuple[np.ndarray, ...]:
    """The tables of :func:`bind_faces_nb` for the Gaussians ``index`` (M,) of an avatar with ``binding``
    (N,) and local rows ``mu``, ``ql``, ``ls``: (face_list (F,) int64 increasing, starts (F + 1,) int64,
    gaussians (M,) int64: ``index`` grouped by face (stable), their local rows in that order)."""
    index = np.ascontiguousarray(index, dtype=np.int64)
    b = binding[index]
    perm = np.argsort(b, kind="stable")
    gaussians = np.ascontiguousarray(index[perm])
    face_list, counts = np.unique(b, return_counts=True)
    starts = np.zeros(face_list.size + 1, dtype=np.int64)
    np.cumsum(counts, out=starts[1:])
    return (face_list.astype(np.int64), starts, gaussians,
            *(np.ascontiguousarray(np.take(a, gaussians, axis=0)) for a in (mu, ql, ls)))


@njit(cache=True, parallel=True)
def moved_faces_nb(verts, faces, ref, tol, moved):  # noqa: ANN001, ANN201
    """moved[f] = some vertex of face f differs from ref[f] (F, 3, 3) by > tol in a coordinate;
    ref rows of moved faces are updated to the current positions. Returns nothing."""
    for f in prange(faces.shape[0]):
        m = False
        for a in range(3):
            vi = faces[f, a]
            for c in range(3):
                if abs(verts[vi, c] - ref[f, a, c]) > tol:
                    m = True
        moved[f] = m
        if m:
            for a in range(3):
                vi = faces[f, a]
                for c in range(3):
                    ref[f, a, c] = verts[vi, c]


@njit(cache=True, parallel=True)
def bind_cached_nb(frame, moved, binding, mu, ql, ls, prev_m, prev_q, prev_ls, out_m, out_q,  # noqa: ANN001
                   out_ls):  # noqa: ANN001, ANN201
    """out = recomputed for Gaussians on moved faces, else copied from prev."""
    for i in prange(binding.shape[0]):
        if moved[binding[i]]:
            _one(frame, binding, mu, ql, ls, i, i, out_m, out_q, out_ls)
        else:
            for c in range(3):
                out_m[i, c] = prev_m[i, c]
                out_ls[i, c] = prev_ls[i, c]
            for c in range(4):
                out_q[i, c] = prev_q[i, c]


def frames(verts: np.ndarray, faces: np.ndarray, eps: float, mask: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Packed (F, 17) float64 frames and (F,) degenerate flags for one mesh (rows outside ``mask`` undefined)."""
    nf = faces.shape[0]
    frame = np.empty((nf, 17), np.float64)
    deg = np.empty(nf, np.bool_)
    face_frames_nb(verts, faces, eps, frame, deg, np.ones(nf, np.bool_) if mask is None else mask)
    return frame, deg
