"""numba kernels of the fast multi-view rasterizer (see :mod:`holo_viewer.render.fast`).

All kernels are ``cache=True`` (the first compile takes seconds; later processes load it).
Layout shared with the C++ kernel (``_cpu/splat.cpp``):

* ``rec`` (V, M, REC_STRIDE) float32 per view and visible splat in depth order, fields 0..9
  (``REC``): u, v (pixels), conic A, B, C, opacity, r, g, b, q = 2 ln(opacity / alpha_threshold)
  (the splat has alpha >= threshold where d^T conic d <= q); words 10..13 hold ``box``.
* ``box`` (V, M, 4) int32, a view of ``rec`` words ``BOX_AT..BOX_AT + 3`` (fast.py
  ``_records``: one 64-byte record per splat and view): pixel columns [x0, x1) and rows
  [y0, y1) the splat may touch: the reference's radius box intersected with the ellipse where
  alpha >= threshold and with the image (empty: x0 >= x1). The kernels also accept separate
  arrays.
* ``tile_off`` (V, n_tiles + 1) int64 and ``tile_ids`` (total,) int32: per (view, tile) the
  indices into ``rec`` of the splats whose box AND alpha >= threshold ellipse reach the tile
  (conservatively, see :func:`_band_tiles`), front to back.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["REC", "REC_STRIDE", "BOX_AT", "prep_3d", "depth_z", "prep_sorted", "project_views", "count_tiles",
           "fill_tiles", "composite"]

REC = 10
#: floats per packed record (64 bytes) and word offset of the int32 box in it (C++: same)
REC_STRIDE = 16
BOX_AT = 10
#: exp(x) for x below this is treated as exp(EXP_LO) (~2.8e-6; alpha_threshold >= 1e-5)
EXP_LO = -12.8

_SH_C0 = 0.28209479177387814
_SH_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
       -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


@nb.njit(parallel=True, cache=True)
def prep_3d(means, quats, log_scales, Wrot):  # pragma: no cover - compiled
    """Camera-frame centres (without translation) and covariances, float64.

    means (N,3), quats (N,4) wxyz, log_scales (N,3), Wrot (3,3) -> pc (N,3), cov (N,6)
    with cov = (xx, xy, xz, yy, yz, zz) of W R S S^T R^T W^T.
    """
    n = means.shape[0]
    pc = np.empty((n, 3))
    cov = np.empty((n, 6))
    for i in nb.prange(n):
        w, x, y, z = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        qn = math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / qn, x / qn, y / qn, z / qn
        R = np.empty((3, 3))
        R[0, 0] = 1 - 2 * (y * y + z * z); R[0, 1] = 2 * (x * y - w * z); R[0, 2] = 2 * (x * z + w * y)
        R[1, 0] = 2 * (x * y + w * z); R[1, 1] = 1 - 2 * (x * x + z * z); R[1, 2] = 2 * (y * z - w * x)
        R[2, 0] = 2 * (x * z - w * y); R[2, 1] = 2 * (y * z + w * x); R[2, 2] = 1 - 2 * (x * x + y * y)
        s0, s1, s2 = math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2])
        M = np.empty((3, 3))  # M = Wrot R S
        for r in range(3):
            a0 = Wrot[r, 0] * R[0, 0] + Wrot[r, 1] * R[1, 0] + Wrot[r, 2] * R[2, 0]
            a1 = Wrot[r, 0] * R[0, 1] + Wrot[r, 1] * R[1, 1] + Wrot[r, 2] * R[2, 1]
            a2 = Wrot[r, 0] * R[0, 2] + Wrot[r, 1] * R[1, 2] + Wrot[r, 2] * R[2, 2]
            M[r, 0] = a0 * s0
            M[r, 1] = a1 * s1
            M[r, 2] = a2 * s2
            pc[i, r] = Wrot[r, 0] * means[i, 0] + Wrot[r, 1] * means[i, 1] + Wrot[r, 2] * means[i, 2]
        cov[i, 0] = M[0, 0] * M[0, 0] + M[0, 1] * M[0, 1] + M[0, 2] * M[0, 2]
        cov[i, 1] = M[0, 0] * M[1, 0] + M[0, 1] * M[1, 1] + M[0, 2] * M[1, 2]
        cov[i, 2] = M[0, 0] * M[2, 0] + M[0, 1] * M[2, 1] + M[0, 2] * M[2, 2]
        cov[i, 3] = M[1, 0] * M[1, 0] + M[1, 1] * M[1, 1] + M[1, 2] * M[1, 2]
        cov[i, 4] = M[1, 0] * M[2, 0] + M[1, 1] * M[2, 1] + M[1, 2] * M[2, 2]
        cov[i, 5] = M[2, 0] * M[2, 0] + M[2, 1] * M[2, 1] + M[2, 2] * M[2, 2]
    return pc, cov


@nb.njit(parallel=True, cache=True)
def depth_z(means, Wrot):  # pragma: no cover - compiled
    """(N,) camera-frame z without translation, ``Wrot[2] . mean`` (the expression of prep_3d)."""
    n = means.shape[0]
    z = np.empty(n)
    for i in nb.prange(n):
        z[i] = Wrot[2, 0] * means[i, 0] + Wrot[2, 1] * means[i, 1] + Wrot[2, 2] * means[i, 2]
    return z


@nb.njit(parallel=True, cache=True)
def prep_sorted(order, means, quats, log_scales, opacity, colours, Wrot, pc, cov, mout, op, sh):  # pragma: no cover
    """prep_3d and the depth-ordered structure-of-arrays copies in one pass.

    For sorted position i (splat k = order[i]): pc[:, i], cov[:, i] as prep_3d computes them (same
    expressions in the same order: bit-identical), mout[:, i] = means[k], op[i] = opacity[k],
    sh[:, i] = colours[k] ((N, C) rows). Columns past len(order) are set to 0. The inputs are
    read once each, at random (prep_3d, then one gather per array, read them twice or more:
    2-3x slower on the avatar's 100k splats, measured).
    """
    m = order.shape[0]
    mp = pc.shape[1]
    c = colours.shape[1]
    for i in nb.prange(mp):
        if i >= m:
            for r in range(3):
                pc[r, i] = 0.0
                mout[r, i] = 0.0
            for r in range(6):
                cov[r, i] = 0.0
            op[i] = 0.0
            for j in range(c):
                sh[j, i] = 0.0
            continue
        k = order[i]
        w, x, y, z = quats[k, 0], quats[k, 1], quats[k, 2], quats[k, 3]
        qn = math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / qn, x / qn, y / qn, z / qn
        R00 = 1 - 2 * (y * y + z * z); R01 = 2 * (x * y - w * z); R02 = 2 * (x * z + w * y)  # noqa: E702
        R10 = 2 * (x * y + w * z); R11 = 1 - 2 * (x * x + z * z); R12 = 2 * (y * z - w * x)  # noqa: E702
        R20 = 2 * (x * z - w * y); R21 = 2 * (y * z + w * x); R22 = 1 - 2 * (x * x + y * y)  # noqa: E702
        s0, s1, s2 = math.exp(log_scales[k, 0]), math.exp(log_scales[k, 1]), math.exp(log_scales[k, 2])
        m0, m1, m2 = means[k, 0], means[k, 1], means[k, 2]
        # M = Wrot R S, row by row (prep_3d's expressions)
        a0 = Wrot[0, 0] * R00 + Wrot[0, 1] * R10 + Wrot[0, 2] * R20
        a1 = Wrot[0, 0] * R01 + Wrot[0, 1] * R11 + Wrot[0, 2] * R21
        a2 = Wrot[0, 0] * R02 + Wrot[0, 1] * R12 + Wrot[0, 2] * R22
        M00, M01, M02 = a0 * s0, a1 * s1, a2 * s2
        a0 = Wrot[1, 0] * R00 + Wrot[1, 1] * R10 + Wrot[1, 2] * R20
        a1 = Wrot[1, 0] * R01 + Wrot[1, 1] * R11 + Wrot[1, 2] * R21
        a2 = Wrot[1, 0] * R02 + Wrot[1, 1] * R12 + Wrot[1, 2] * R22
        M10, M11, M12 = a0 * s0, a1 * s1, a2 * s2
        a0 = Wrot[2, 0] * R00 + Wrot[2, 1] * R10 + Wrot[2, 2] * R20
        a1 = Wrot[2, 0] * R01 + Wrot[2, 1] * R11 + Wrot[2, 2] * R21
        a2 = Wrot[2, 0] * R02 + Wrot[2, 1] * R12 + Wrot[2, 2] * R22
        M20, M21, M22 = a0 * s0, a1 * s1, a2 * s2
        pc[0, i] = Wrot[0, 0] * m0 + Wrot[0, 1] * m1 + Wrot[0, 2] * m2
        pc[1, i] = Wrot[1, 0] * m0 + Wrot[1, 1] * m1 + Wrot[1, 2] * m2
        pc[2, i] = Wrot[2, 0] * m0 + Wrot[2, 1] * m1 + Wrot[2, 2] * m2
        cov[0, i] = M00 * M00 + M01 * M01 + M02 * M02
        cov[1, i] = M00 * M10 + M01 * M11 + M02 * M12
        cov[2, i] = M00 * M20 + M01 * M21 + M02 * M22
        cov[3, i] = M10 * M10 + M11 * M11 + M12 * M12
        cov[4, i] = M10 * M20 + M11 * M21 + M12 * M22
        cov[5, i] = M20 * M20 + M21 * M21 + M22 * M22
        mout[0, i], mout[1, i], mout[2, i] = m0, m1, m2
        op[i] = opacity[k]
        for j in range(c):
            sh[j, i] = colours[k, j]


@nb.njit(parallel=True, cache=True)
def gather_soa(a, order, out):  # pragma: no cover - compiled
    """out[j, i] = a[order[i], j]: rows of ``a`` (N, C) in ``order`` as a structure of arrays.

    out is (C, >= len(order)); columns past len(order) are left as they are. One pass over the
    ordered rows, each read once (numpy's fancy index + transpose took 25 ms for the avatar's
    inputs, single-threaded).
    """
    m = order.shape[0]
    c = a.shape[1]
    for i in nb.prange(m):
        k = order[i]
        for j in range(c):
            out[j, i] = a[k, j]


@nb.njit(inline="always", cache=True)
def _sh_basis(degree, x, y, z, basis):  # pragma: no cover - compiled
    """Fill basis[:(degree+1)^2] for the unit direction (x, y, z) (order of holo_viewer.render.sh)."""
    basis[0] = _SH_C0
    if degree >= 1:
        basis[1] = -_SH_C1 * y
        basis[2] = _SH_C1 * z
        basis[3] = -_SH_C1 * x
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        basis[4] = _C2[0] * xy
        basis[5] = _C2[1] * yz
        basis[6] = _C2[2] * (2.0 * zz - xx - yy)
        basis[7] = _C2[3] * xz
        basis[8] = _C2[4] * (xx - yy)
        if degree >= 3:
            basis[9] = _C3[0] * y * (3.0 * xx - yy)
            basis[10] = _C3[1] * xy * z
            basis[11] = _C3[2] * y * (4.0 * zz - xx - yy)
            basis[12] = _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
            basis[13] = _C3[4] * x * (4.0 * zz - xx - yy)
            basis[14] = _C3[5] * z * (xx - yy)
            basis[15] = _C3[6] * x * (xx - 3.0 * yy)


@nb.njit(parallel=True, cache=True)
def project_views(order, pc, cov, means, opacity, sh, degree, shared_rgb, use_shared, cams, width, height,
                  near, dilation, radius_sigmas, alpha_threshold, cull_margin, rec, box):  # pragma: no cover - compiled
    """Per view and splat (in depth order ``order``): 2D centre, conic, colour and pixel box.

    cams (V, 29): fx, fy, cx, cy, tx, ty, tz (world->camera translation), cam_pos xyz (world),
    clamp limits lo_x, hi_x, lo_y, hi_y of t.x/t.z and t.y/t.z (projection.clamp_limits), the
    pixel rectangle x0, x1, y0, y1 the boxes are clipped to (0, width, 0, height: the image), and a
    crossed-slit view's flag (18, 0 for a pinhole) and parameters: a, b, c, e, f (19-23), A, B
    (24, 25) and the slope of the camera position in s (26-28): each centre moves to its slice
    column xi = (a X + b Z + c) / (e Z + f) at the same depth, its covariance by that move's
    Jacobian, and its SH is seen from cam_pos + s slope, s = A + B xi
    (:mod:`holo_viewer.render.crossed_slit`).
    cull_margin < 0 disables centre culling. Writes rec (V, M, REC) and box (V, M, 4).
    Returns (M,) uint8: 1 where the splat's box is non-empty in at least one view.
    """
    m = order.shape[0]
    nv = cams.shape[0]
    seen = np.zeros(m, dtype=np.uint8)
    ln_thr = math.log(alpha_threshold)
    nk = (degree + 1) * (degree + 1)
    for k in nb.prange(m):
        i = order[k]
        any_v = 0
        basis = np.empty(16)
        op = opacity[i]
        if op < alpha_threshold:
            for v in range(nv):
                box[v, k, 0] = 0
                box[v, k, 1] = 0
                box[v, k, 2] = 0
                box[v, k, 3] = 0
            seen[k] = 0
            continue
        q = 2.0 * (math.log(op) - ln_thr)  # alpha >= thr  <=>  d^T conic d <= q
        cxx, cxy, cxz, syy, syz, szz = cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 3], cov[i, 4], cov[i, 5]
        for v in range(nv):
            fx, fy, cx, cy = cams[v, 0], cams[v, 1], cams[v, 2], cams[v, 3]
            tx = pc[i, 0] + cams[v, 4]
            ty = pc[i, 1] + cams[v, 5]
            tz = pc[i, 2] + cams[v, 6]
            sxx, sxy, sxz = cxx, cxy, cxz
            px, py, pz = cams[v, 7], cams[v, 8], cams[v, 9]
            if cams[v, 18] != 0.0:  # a crossed-slit view (the C++ project_block's SLIT, same expressions)
                a_, b_, c_, e_, f_ = cams[v, 19], cams[v, 20], cams[v, 21], cams[v, 22], cams[v, 23]
                X, Z = tx, tz
                den = e_ * Z + f_
                ok = den > 1e-9 * Z
                xi = (a_ * X + b_ * Z + c_) / den if ok else 0.0
                if ok:
                    jx = Z / den * (a_ / fx)
                    jz = ((b_ * f_ - e_ * (a_ * X + c_)) / (den * den) * Z + (xi - cx)) / fx
                    sxx = jx * jx * cxx + 2.0 * jx * jz * cxz + jz * jz * szz
                    sxy = jx * cxy + jz * syz
                    sxz = jx * cxz + jz * szz
                    tx = (xi - cx) * Z / fx
                else:
                    tx = 0.0
                    tz = -1.0
                s_ = cams[v, 24] + cams[v, 25] * xi
                px, py, pz = px + s_ * cams[v, 26], py + s_ * cams[v, 27], pz + s_ * cams[v, 28]
            box[v, k, 0] = 0
            box[v, k, 1] = 0
            box[v, k, 2] = 0
            box[v, k, 3] = 0
            if not tz > near:
                continue
            itz = 1.0 / tz
            u = fx * tx * itz + cx
            vv = fy * ty * itz + cy
            if cull_margin >= 0.0:
                if (u < -cull_margin * width or u > (1.0 + cull_margin) * width
                        or vv < -cull_margin * height or vv > (1.0 + cull_margin) * height):
                    continue
            # clamp limits of t/t.z (projection.clamp_limits), precomputed per view
            txc = min(max(tx * itz, cams[v, 10]), cams[v, 11]) * tz
            tyc = min(max(ty * itz, cams[v, 12]), cams[v, 13]) * tz
            j00 = fx * itz
            j02 = -fx * txc * itz * itz
            j11 = fy * itz
            j12 = -fy * tyc * itz * itz
            # rows of M = J: (j00, 0, j02), (0, j11, j12); S2 = M Sigma M^T
            r0x = j00 * sxx + j02 * sxz
            r0y = j00 * sxy + j02 * syz
            r0z = j00 * sxz + j02 * szz
            r1y = j11 * syy + j12 * syz
            r1z = j11 * syz + j12 * szz
            sa = r0x * j00 + r0z * j02
            b = r0y * j11 + r0z * j12
            sc = r1y * j11 + r1z * j12
            a = sa + dilation
            c = sc + dilation
            # det(S + d I) without cancellation (see projection.conic_and_radius)
            det = max(sa * sc - b * b, 0.0) + dilation * (sa + sc) + dilation * dilation
            if not det > 0.0:
                continue
            mid = 0.5 * (a + c)
            lam = mid + math.sqrt(max(mid * mid - det, 0.0))
            rad = math.ceil(radius_sigmas * math.sqrt(max(lam, 0.0)))
            hx = min(rad, math.sqrt(q * a) * 1.0001 + 1e-3)
            hy = min(rad, math.sqrt(q * c) * 1.0001 + 1e-3)
            fx0 = math.ceil(u - hx - 0.5)
            fx1 = math.floor(u + hx - 0.5) + 1.0
            fy0 = math.ceil(vv - hy - 0.5)
            fy1 = math.floor(vv + hy - 0.5) + 1.0
            x0 = int(min(max(fx0, cams[v, 14]), cams[v, 15]))  # clipped to the view's pixel rectangle
            x1 = int(min(max(fx1, cams[v, 14]), cams[v, 15]))
            y0 = int(min(max(fy0, cams[v, 16]), cams[v, 17]))
            y1 = int(min(max(fy1, cams[v, 16]), cams[v, 17]))
            if x0 >= x1 or y0 >= y1:
                continue
            box[v, k, 0] = x0
            box[v, k, 1] = x1
            box[v, k, 2] = y0
            box[v, k, 3] = y1
            any_v = 1
            rec[v, k, 0] = u
            rec[v, k, 1] = vv
            idet = 1.0 / det
            rec[v, k, 2] = c * idet
            rec[v, k, 3] = -b * idet
            rec[v, k, 4] = a * idet
            rec[v, k, 5] = op
            if use_shared:
                for ch in range(3):
                    rec[v, k, 6 + ch] = shared_rgb[i, ch]
            else:
                dx = means[i, 0] - px
                dy = means[i, 1] - py
                dz = means[i, 2] - pz
                nrm = math.sqrt(dx * dx + dy * dy + dz * dz)
                if nrm > 0.0:
                    dx, dy, dz = dx / nrm, dy / nrm, dz / nrm
                _sh_basis(degree, dx, dy, dz, basis)
                for ch in range(3):
                    acc = 0.0
                    for kk in range(nk):
                        acc += basis[kk] * sh[i, kk, ch]
                    rec[v, k, 6 + ch] = max(acc + 0.5, 0.0)
            rec[v, k, 9] = q
        seen[k] = any_v
    return seen


@nb.njit(inline="always", cache=True)
def _band_tiles(u, vv, A, B, e, Aq, kk, tile, x0, x1, ya, yb):  # pragma: no cover - compiled
    """Tile columns [t0, t1] of the tiles the alpha >= threshold ellipse of a splat reaches
    between the pixel rows ya..yb (inclusive), clipped to its box columns [x0, x1); t0 > t1 if none.

    The ellipse d^T conic d <= q (conic A, B, C) has its right-most point at dy = -kk,
    kk = B hx / C (hx = its half width); over a band of rows the right end of the chord is
    concave in dy, so its maximum is at that dy clamped to the band (mirror for the left end).
    e = B^2 - A C, Aq = A q. Widened by 0.05 px + 1e-3 relative, so every pixel the compositor
    can blend is kept. A <= 0 (degenerate): the whole box row.
    """
    j0 = x0
    j1 = x1 - 1
    if A > 0.0:
        d0 = ya + 0.5 - vv
        d1 = yb + 0.5 - vv
        dr = min(max(-kk, d0), d1)
        dl = min(max(kk, d0), d1)
        sr = math.sqrt(max(dr * dr * e + Aq, 0.0))
        sl = math.sqrt(max(dl * dl * e + Aq, 0.0))
        iA = 1.0 / A  # as the C++ binning, which computes it once per splat
        xr = u + (-B * dr + sr * 1.001) * iA + 0.05
        xl = u + (-B * dl - sl * 1.001) * iA - 0.05
        j0 = max(j0, int(math.ceil(xl - 0.5)))
        j1 = min(j1, int(math.floor(xr - 0.5)))
    if j0 > j1:
        return 1, 0
    return j0 // tile, j1 // tile


@nb.njit(inline="always", cache=True)
def _splat_conic(rec, v, k):  # pragma: no cover - compiled
    """(u, v, A, B, e, Aq, kk) of splat k in view v for :func:`_band_tiles` (A = 0: degenerate)."""
    u = float(rec[v, k, 0])
    vv = float(rec[v, k, 1])
    A = float(rec[v, k, 2])
    B = float(rec[v, k, 3])
    C = float(rec[v, k, 4])
    q = float(rec[v, k, 9])
    det = A * C - B * B
    if not (det > 0.0 and A > 0.0 and C > 0.0 and q > 0.0):
        return u, vv, 0.0, B, 0.0, 0.0, 0.0
    hx = math.sqrt(q * C / det)
    return u, vv, A, B, B * B - A * C, A * q, B * hx / C


@nb.njit(parallel=True, cache=True)
def count_tiles(rec, box, tile, tiles_x, tiles_y):  # pragma: no cover - compiled
    """(V, n_tiles + 1) int64 exclusive prefix sums of the number of splats per tile.

    A splat is listed in the tiles its alpha >= threshold ellipse reaches (per tile row, the
    ellipse's x-extent over the rows of the band, :func:`_band_tiles`), not every tile of its box.
    """
    nv, m = box.shape[0], box.shape[1]
    nt = tiles_x * tiles_y
    off = np.zeros((nv, nt + 1), dtype=np.int64)
    for v in nb.prange(nv):
        cnt = np.zeros(nt, dtype=np.int64)
        for k in range(m):
            x0, x1, y0, y1 = box[v, k, 0], box[v, k, 1], box[v, k, 2], box[v, k, 3]
            if x0 >= x1 or y0 >= y1:
                continue
            tx0, tx1 = x0 // tile, (x1 - 1) // tile
            if tx0 == tx1:  # one tile column: nothing to trim
                for ty in range(y0 // tile, (y1 - 1) // tile + 1):
                    cnt[ty * tiles_x + tx0] += 1
                continue
            u, vv, A, B, e, Aq, kk = _splat_conic(rec, v, k)
            for ty in range(y0 // tile, (y1 - 1) // tile + 1):
                t0, t1 = _band_tiles(u, vv, A, B, e, Aq, kk, tile, x0, x1, max(y0, ty * tile),
                                     min(y1, ty * tile + tile) - 1)
                for tx in range(t0, t1 + 1):
                    cnt[ty * tiles_x + tx] += 1
        s = 0
        for t in range(nt):
            off[v, t] = s
            s += cnt[t]
        off[v, nt] = s
    return off


@nb.njit(parallel=True, cache=True)
def fill_tiles(rec, box, tile, tiles_x, off, base, ids):  # pragma: no cover - compiled
    """Write splat indices per (view, tile) in depth order into ``ids`` at ``base[v] + off[v, t]``."""
    nv, m = box.shape[0], box.shape[1]
    nt = off.shape[1] - 1
    for v in nb.prange(nv):
        cur = off[v, :nt].copy()
        b = base[v]
        for k in range(m):
            x0, x1, y0, y1 = box[v, k, 0], box[v, k, 1], box[v, k, 2], box[v, k, 3]
            if x0 >= x1 or y0 >= y1:
                continue
            tx0, tx1 = x0 // tile, (x1 - 1) // tile
            if tx0 == tx1:  # one tile column: nothing to trim
                for ty in range(y0 // tile, (y1 - 1) // tile + 1):
                    t = ty * tiles_x + tx0
                    ids[b + cur[t]] = k
                    cur[t] += 1
                continue
            u, vv, A, B, e, Aq, kk = _splat_conic(rec, v, k)
            for ty in range(y0 // tile, (y1 - 1) // tile + 1):
                t0, t1 = _band_tiles(u, vv, A, B, e, Aq, kk, tile, x0, x1, max(y0, ty * tile),
                                     min(y1, ty * tile + tile) - 1)
                for tx in range(t0, t1 + 1):
                    t = ty * tiles_x + tx
                    ids[b + cur[t]] = k
                    cur[t] += 1


@nb.njit(inline="always", fastmath=True, cache=True)
def _fast_exp(x):  # pragma: no cover - compiled
    """exp(x) for x in [EXP_LO, 0] (relative error < 2e-5): Taylor degree 6 of x/32, squared 5 times."""
    y = max(x, np.float32(EXP_LO)) * np.float32(1.0 / 32.0)
    e = np.float32(1.0) + y * (np.float32(1.0) + y * np.float32(0.5) * (np.float32(1.0) + y * np.float32(1.0 / 3.0) * (
        np.float32(1.0) + y * np.float32(0.25) * (np.float32(1.0) + y * np.float32(0.2) * (
            np.float32(1.0) + y * np.float32(1.0 / 6.0))))))
    e = e * e
    e = e * e
    e = e * e
    e = e * e
    return e * e


@nb.njit(inline="always", fastmath=True, cache=True)
def _blend_row(T, R, G, B, live, p0, n, fx0, fx1, dx0, ca, lin, cst, op, cap, thr, tmin, cr, cg, cb):  # pragma: no cover
    """Blend one splat into the ``n`` pixels p0..p0+n-1 of one tile row, branch-free.

    Pixel x (0..n-1) takes part when fx0 <= x < fx1 (the splat's box); dx = x + dx0 is its
    offset from the splat centre; power = ca dx^2 + lin dx + cst. A fixed trip count of a
    whole tile row and unsigned indices (numba's negative-index wraparound blocks it) let
    LLVM vectorise the loop. Returns (blends, newly finished pixels) as float32.
    """
    one = np.float32(1.0)
    zero = np.float32(0.0)
    nfin = np.float32(0.0)
    nbl = np.float32(0.0)
    for xi in range(n):
        p = nb.uint64(p0 + xi)
        xf = np.float32(nb.int32(xi))
        dx = xf + dx0
        power = ca * dx * dx + lin * dx + cst
        alpha = min(cap, op * _fast_exp(power))
        lv = live[p]
        ok = lv if ((power <= zero) & (alpha >= thr) & (xf >= fx0) & (xf < fx1)) else zero
        tt = T[p]
        test = tt * (one - alpha)
        fin = ok if test < tmin else zero  # blended, then finished
        live[p] = lv - fin
        w = ok * alpha * tt
        R[p] += w * cr
        G[p] += w * cg
        B[p] += w * cb
        T[p] = tt - ok * (tt - test)
        nbl += ok
        nfin += fin
    return nbl, nfin


@nb.njit(parallel=True, fastmath=True, cache=True)
def composite(rec, box, off, base, ids, tile, tiles_x, tiles_y, width, height, alpha_threshold, alpha_cap,
              t_min, bg, clip, out, blends):  # pragma: no cover - compiled
    """Composite every (view, tile) front to back into ``out`` (V, H, W, 3) float32.

    Per tile row the splat's box columns are processed branch-free (vectorisable): a pixel
    blends when power <= 0, alpha >= threshold and it is not finished; it finishes (after
    blending) when the splat takes T below t_min. ``blends`` (V * n_tiles,) gets counts.
    """
    nv = rec.shape[0]
    nt = tiles_x * tiles_y
    thr = np.float32(alpha_threshold)
    cap = np.float32(alpha_cap)
    tmin = np.float32(t_min)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for job in nb.prange(nv * nt):
        v = job // nt
        t = job - v * nt
        ty = t // tiles_x
        tx = t - ty * tiles_x
        px0 = tx * tile
        py0 = ty * tile
        pw = min(tile, width - px0)
        ph = min(tile, height - py0)
        T = np.ones(tile * tile, dtype=np.float32)
        R = np.zeros(tile * tile, dtype=np.float32)
        G = np.zeros(tile * tile, dtype=np.float32)
        Bc = np.zeros(tile * tile, dtype=np.float32)
        live = np.ones(tile * tile, dtype=np.float32)  # 1 = still compositing
        n_live = pw * ph
        nbl = 0
        b = base[v]
        for e in range(off[v, t], off[v, t + 1]):
            k = ids[b + e]
            x0 = max(box[v, k, 0], px0) - px0
            x1 = min(box[v, k, 1], px0 + pw) - px0
            y0 = max(box[v, k, 2], py0) - py0
            y1 = min(box[v, k, 3], py0 + ph) - py0
            if x0 >= x1 or y0 >= y1:
                continue
            u = rec[v, k, 0] - np.float32(px0 + 0.5)
            vv = rec[v, k, 1] - np.float32(py0 + 0.5)
            ca = np.float32(-0.5) * rec[v, k, 2]
            cb = rec[v, k, 3]
            cc = np.float32(-0.5) * rec[v, k, 4]
            op = rec[v, k, 5]
            cr, cg, cbl = rec[v, k, 6], rec[v, k, 7], rec[v, k, 8]
            for y in range(y0, y1):
                dy = np.float32(y) - vv
                nb_row, nfin = _blend_row(T, R, G, Bc, live, y * tile, tile, np.float32(x0), np.float32(x1), -u,
                                          ca, -cb * dy, cc * dy * dy, op, cap, thr, tmin, cr, cg, cbl)
                nbl += int(nb_row)
                n_live -= int(nfin)
            if n_live <= 0:
                break
        for y in range(ph):
            for x in range(pw):
                p = y * tile + x
                tt = T[p]
                r = R[p] + tt * np.float32(bg[0])
                g = G[p] + tt * np.float32(bg[1])
                bb = Bc[p] + tt * np.float32(bg[2])
                if clip:
                    r = min(max(r, zero), one)
                    g = min(max(g, zero), one)
                    bb = min(max(bb, zero), one)
                out[v, py0 + y, px0 + x, 0] = r
                out[v, py0 + y, px0 + x, 1] = g
                out[v, py0 + y, px0 + x, 2] = bb
        blends[job] = nbl
