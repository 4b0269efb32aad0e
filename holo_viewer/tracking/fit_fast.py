"""The landmark fit's Gauss-Newton steps compiled (numba): :func:`holo_viewer.tracking.fit.fit_landmarks`' fast path.

The same steps as the numpy reference (``fit_landmarks(..., fast=False)``): a forward-difference Jacobian from
n_q + 1 evaluations of :meth:`LandmarkHeadModel.project`, the damped normal equations, the clip to the bounds.
Two things differ, both rounding-level: the Jacobian's rows are evaluated from the base row plus the
parameters that changed (a finite-difference row moves one reduced parameter, i.e. one or two AUs and at
most the jaw: ~20x fewer multiply-adds than evaluating each row from scratch), and the 16x16 system is
solved by Cholesky (it is symmetric positive definite: J^T J plus a positive diagonal). Tested against the
reference (``tests/test_tracking.py``: the fitted parameters agree to 1e-7). In the live tracker the numpy
fit was ~1.1 ms of a ~4.5 ms tracked frame, numpy call overhead on 17 x 68 points (issue 37).

The model arrays are those of :class:`~holo_viewer.tracking.head_model.LandmarkHeadModel` (its folded
68-landmark form, ``_local``); :func:`model_arrays` gathers them once per model.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["model_arrays", "gauss_newton"]

_SMALL2 = 1e-3 ** 2  # holo_viewer.geometry._SMALL_ANGLE squared: Taylor terms of Rodrigues below it


def model_arrays(model) -> tuple:
    """The arrays the kernel reads from ``model`` (a LandmarkHeadModel), cached on it (read-only)."""
    arr = model.__dict__.get("_fast_arrays")
    if arr is None:
        from .head_model import CAMERA_FROM_FLAME

        n = model.n_au
        n_lm = model._lm_wsum.shape[0]
        arr = (np.ascontiguousarray(model._lm_v0.reshape(2 * n_lm * 3)),
               np.ascontiguousarray(model._lm_au.reshape(n, 2 * n_lm * 3)),
               np.ascontiguousarray(model._lm_pose.reshape(9, 2 * n_lm * 3)),
               np.ascontiguousarray(model._lm_wsum, dtype=np.float64),
               np.ascontiguousarray(model._j0[0]), np.ascontiguousarray(model._j0[2]),
               np.ascontiguousarray(model._j_au[:, 0]), np.ascontiguousarray(model._j_au[:, 2]),
               np.ascontiguousarray(CAMERA_FROM_FLAME, dtype=np.float64))
        model.__dict__["_fast_arrays"] = arr
    return arr


@numba.njit(cache=True, nogil=True)
def _rotation(r0, r1, r2, out):
    """Rodrigues (holo_viewer.geometry.rodrigues_np, with its Taylor branch) into out (3, 3)."""
    t2 = r0 * r0 + r1 * r1 + r2 * r2
    if t2 < _SMALL2:
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
    else:
        th = np.sqrt(t2)
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / t2
    k = np.zeros((3, 3))
    k[0, 1], k[0, 2], k[1, 0], k[1, 2], k[2, 0], k[2, 1] = -r2, r1, r2, -r0, -r1, r0
    for i in range(3):
        for j in range(3):
            kk = k[i, 0] * k[0, j] + k[i, 1] * k[1, j] + k[i, 2] * k[2, j]
            out[i, j] = (1.0 if i == j else 0.0) + a * k[i, j] + b * kk


@numba.njit(cache=True, nogil=True)
def _finish(vw, p, n_au, jroot, jjaw, wsum, cam, fx, fy, cx, cy, out):
    """Landmark pixels (68, 2) into ``out`` from the folded landmark sums ``vw`` (2 * 68 * 3,) of params ``p``
    and its root / jaw joints (LandmarkHeadModel._local, then points_camera and project)."""
    n_lm = wsum.shape[0]
    jaw = p[n_au]
    c, s = np.cos(jaw), np.sin(jaw)
    d = np.zeros((3, 3))
    d[1, 1], d[1, 2], d[2, 1], d[2, 2] = c - 1.0, -s, s, c - 1.0
    R = np.empty((3, 3))
    _rotation(p[n_au + 1], p[n_au + 2], p[n_au + 3], R)
    Mc = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            Mc[i, j] = cam[i, 0] * R[0, j] + cam[i, 1] * R[1, j] + cam[i, 2] * R[2, j]
    off = n_lm * 3
    pt = np.empty(3)
    for l in range(n_lm):
        rel0 = vw[off + 3 * l] - wsum[l] * jjaw[0]
        rel1 = vw[off + 3 * l + 1] - wsum[l] * jjaw[1]
        rel2 = vw[off + 3 * l + 2] - wsum[l] * jjaw[2]
        for k in range(3):
            pt[k] = vw[3 * l + k] + rel0 * d[k, 0] + rel1 * d[k, 1] + rel2 * d[k, 2] - jroot[k]
        x = Mc[0, 0] * pt[0] + Mc[0, 1] * pt[1] + Mc[0, 2] * pt[2] + p[n_au + 4]
        y = Mc[1, 0] * pt[0] + Mc[1, 1] * pt[1] + Mc[1, 2] * pt[2] + p[n_au + 5]
        z = Mc[2, 0] * pt[0] + Mc[2, 1] * pt[1] + Mc[2, 2] * pt[2] + p[n_au + 6]
        z = max(z, 1e-4)
        out[l, 0] = x / z * fx + cx
        out[l, 1] = y / z * fy + cy


@numba.njit(cache=True, nogil=True)
def _base(p, n_au, lm_v0, lm_au, lm_pose, j0r, j0j, jaur, jauj, vw, jroot, jjaw):
    """The folded landmark sums ``vw`` and the root / jaw joints of params ``p`` from scratch."""
    c, s = np.cos(p[n_au]), np.sin(p[n_au])
    for e in range(vw.shape[0]):
        vw[e] = lm_v0[e] + ((c - 1.0) * lm_pose[4, e] - s * lm_pose[5, e] + s * lm_pose[7, e]
                            + (c - 1.0) * lm_pose[8, e])
    for a in range(n_au):
        if p[a] != 0.0:
            for e in range(vw.shape[0]):
                vw[e] += p[a] * lm_au[a, e]
    for e in range(3):
        jroot[e] = j0r[e]
        jjaw[e] = j0j[e]
        for a in range(n_au):
            jroot[e] += p[a] * jaur[a, e]
            jjaw[e] += p[a] * jauj[a, e]


@numba.njit(cache=True, nogil=True)
def gauss_newton(q, prior, has_prior, M, lm, sw, reg_w, tw, lo, hi, damping, h, iterations, fx, fy, cx, cy,
                 lm_v0, lm_au, lm_pose, wsum, j0r, j0j, jaur, jauj, cam):
    """The reduced parameters after ``iterations`` damped Gauss-Newton steps from ``q`` (see fit_landmarks),
    and the landmark pixels (68, 2) of the result (for its RMS residual)."""
    nq = q.shape[0]
    n = M.shape[0]
    n_au = lm_au.shape[0]
    n_lm = lm.shape[0]
    m = 2 * n_lm
    q = q.copy()
    p0 = np.empty(n)
    pi = np.empty(n)
    vw0 = np.empty(lm_v0.shape[0])
    vwi = np.empty(lm_v0.shape[0])
    jr0, jj0, jri, jji = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    x0 = np.empty((n_lm, 2))
    xi = np.empty((n_lm, 2))
    J = np.empty((m, nq))
    r0 = np.empty(m)
    A = np.empty((nq, nq))
    g = np.empty(nq)
    L = np.empty((nq, nq))
    y = np.empty(nq)
    for _ in range(iterations):
        for i in range(n):
            acc = 0.0
            for j in range(nq):
                acc += M[i, j] * q[j]
            p0[i] = acc
        _base(p0, n_au, lm_v0, lm_au, lm_pose, j0r, j0j, jaur, jauj, vw0, jr0, jj0)
        _finish(vw0, p0, n_au, jr0, jj0, wsum, cam, fx, fy, cx, cy, x0)
        for l in range(n_lm):
            r0[2 * l] = (x0[l, 0] - lm[l, 0]) * sw[l]
            r0[2 * l + 1] = (x0[l, 1] - lm[l, 1]) * sw[l]
        for k in range(nq):  # the finite-difference row of reduced parameter k: only what it moves changes
            for i in range(n):
                acc = 0.0
                for j in range(nq):
                    acc += M[i, j] * (q[j] + h if j == k else q[j])
                pi[i] = acc
            vwi[:] = vw0
            jri[:] = jr0
            jji[:] = jj0
            for a in range(n_au):
                da = pi[a] - p0[a]
                if da != 0.0:
                    for e in range(vwi.shape[0]):
                        vwi[e] += da * lm_au[a, e]
                    for e in range(3):
                        jri[e] += da * jaur[a, e]
                        jji[e] += da * jauj[a, e]
            if pi[n_au] != p0[n_au]:
                dc = np.cos(pi[n_au]) - np.cos(p0[n_au])
                ds = np.sin(pi[n_au]) - np.sin(p0[n_au])
                for e in range(vwi.shape[0]):
                    vwi[e] += dc * (lm_pose[4, e] + lm_pose[8, e]) + ds * (lm_pose[7, e] - lm_pose[5, e])
            _finish(vwi, pi, n_au, jri, jji, wsum, cam, fx, fy, cx, cy, xi)
            for l in range(n_lm):
                J[2 * l, k] = (xi[l, 0] - x0[l, 0]) * sw[l] / h
                J[2 * l + 1, k] = (xi[l, 1] - x0[l, 1]) * sw[l] / h
        for a in range(nq):
            for b in range(a, nq):
                acc = 0.0
                for r in range(m):
                    acc += J[r, a] * J[r, b]
                A[a, b] = acc
                A[b, a] = acc
            A[a, a] += reg_w[a] + tw[a] + damping
            acc = 0.0
            for r in range(m):
                acc += J[r, a] * r0[r]
            g[a] = acc + reg_w[a] * q[a] + (tw[a] * (q[a] - prior[a]) if has_prior else 0.0)
        # Cholesky A = L L^T, then L y = -g, L^T step = y
        for i in range(nq):
            for j in range(i + 1):
                acc = A[i, j]
                for k in range(j):
                    acc -= L[i, k] * L[j, k]
                if i == j:
                    L[i, i] = np.sqrt(acc)
                else:
                    L[i, j] = acc / L[j, j]
        for i in range(nq):
            acc = -g[i]
            for k in range(i):
                acc -= L[i, k] * y[k]
            y[i] = acc / L[i, i]
        for i in range(nq - 1, -1, -1):
            acc = y[i]
            for k in range(i + 1, nq):
                acc -= L[k, i] * g[k]
            g[i] = acc / L[i, i]  # g now holds the step
        for i in range(nq):
            q[i] = min(max(q[i] + g[i], lo[i]), hi[i])
    for i in range(n):
        acc = 0.0
        for j in range(nq):
            acc += M[i, j] * q[j]
        p0[i] = acc
    _base(p0, n_au, lm_v0, lm_au, lm_pose, j0r, j0j, jaur, jauj, vw0, jr0, jj0)
    _finish(vw0, p0, n_au, jr0, jj0, wsum, cam, fx, fy, cx, cy, x0)
    return q, x0


def kernel_cached() -> bool:
    """True when numba's cache holds :func:`gauss_newton` (loading it then takes milliseconds; compiling it
    ~6 s of CPU); True too when the cache cannot be inspected (numba internals moved)."""
    import os

    try:
        return bool(os.path.exists(gauss_newton._cache._cache_file._index_path))
    except Exception:  # noqa: BLE001
        return True


def compile_kernel(model=None) -> None:
    """Compile (or load) :func:`gauss_newton` through one fit of exact landmarks of ``model`` (default: the
    default head's LandmarkHeadModel): set-up (scripts/warm_kernels.py), the live tracker's warm-up and the
    background child the live loop starts on a cold cache (``python -m holo_viewer.tracking.fit_fast``)."""
    from .fit import fit_landmarks
    from .head_model import LandmarkHeadModel

    if model is None:
        from ..flame.default_head import load_default_model
        from ..flame.expressions import default_au_map

        model = LandmarkHeadModel(load_default_model(), default_au_map())
    K = np.array([[400.0, 0.0, 240.0], [0.0, 400.0, 180.0], [0.0, 0.0, 1.0]])
    p = np.zeros(model.n_params)
    p[-1] = 0.5  # 0.5 m in front of the camera
    fit_landmarks(model, model.project(p[None], K)[0], K, fast=True)


if __name__ == "__main__":
    compile_kernel()
