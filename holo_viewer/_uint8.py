"""The compiled pass of :func:`holo_viewer.images.to_uint8` (kept apart so that importing
``holo_viewer.images`` does not import numba)."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["to_uint8_rows"]


@numba.njit(parallel=True, cache=True, error_model="numpy")
def to_uint8_rows(a, out):  # pragma: no cover - compiled
    """(H, L) float -> uint8 into out (rows contiguous); returns the rows with a refused value.
    Straight-line over each row (the check an integer OR, NaN sent to 0 by a select), so that
    it vectorises."""
    H, L = a.shape
    bad = np.zeros(H, dtype=np.uint8)
    k = a.dtype.type(255.0)
    lo, hi, big = a.dtype.type(0.0), a.dtype.type(255.0), a.dtype.type(np.inf)
    for y in numba.prange(H):
        flag = np.uint8(0)
        for i in range(L):
            v = a[y, i] * k
            flag |= np.uint8(not (v * v < big))  # NaN, +-inf, or a square that overflows
            v = np.rint(v)
            v = v if v > lo else lo  # NaN -> 0 (refused anyway)
            v = v if v < hi else hi
            out[y, i] = np.uint8(v)
        bad[y] = flag
    return int(bad.sum())
