"""Numba kernel of the sparse blend-shape product (see :mod:`holo_viewer.avatar.blendshape`)."""

from __future__ import annotations

from numba import njit, prange

__all__ = ["blend_nb"]


@njit(cache=True, parallel=True)
def blend_nb(base, ptr, comp, vals, coeffs, out_m, out_q, out_ls):  # noqa: ANN001, ANN201
    """out[i] = base[i] + sum_{p in ptr[i]:ptr[i+1]} coeffs[comp[p]] vals[p], split into (3, 4, 3)."""
    n = base.shape[0]
    for i in prange(n):
        a0, a1, a2, a3, a4 = base[i, 0], base[i, 1], base[i, 2], base[i, 3], base[i, 4]
        a5, a6, a7, a8, a9 = base[i, 5], base[i, 6], base[i, 7], base[i, 8], base[i, 9]
        for p in range(ptr[i], ptr[i + 1]):
            w = coeffs[comp[p]]
            if w != 0.0:
                v = vals[p]
                a0 += w * v[0]
                a1 += w * v[1]
                a2 += w * v[2]
                a3 += w * v[3]
                a4 += w * v[4]
                a5 += w * v[5]
                a6 += w * v[6]
                a7 += w * v[7]
                a8 += w * v[8]
                a9 += w * v[9]
        out_m[i, 0], out_m[i, 1], out_m[i, 2] = a0, a1, a2
        out_q[i, 0], out_q[i, 1], out_q[i, 2], out_q[i, 3] = a3, a4, a5, a6
        out_ls[i, 0], out_ls[i, 1], out_ls[i, 2] = a7, a8, a9
