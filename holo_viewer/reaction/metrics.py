"""REACT 2023/2024 challenge metrics (docs/design.md, "REACT metrics"), vectorised.

Shapes: ``preds`` (N, K, T, D) with K generated reactions per speaker clip, ``listener_gt`` and
``speaker_gt`` (N, T, D), ``neighbour`` (N, N) 0/1 with ``neighbour[n, j] = 1`` when listener j's
reaction is appropriate for speaker clip n. For the 25-D attribute layout the DTW groups are
AUs 0:15 (weight 1/15), valence/arousal 15:17 (weight 1), expressions 17:25 (weight 1/8).

Semantics follow the official baseline code (reactmultimodalchallenge/baseline_react2023 and
baseline_react2024, metric/*.py), re-derived here:

* CCC per dimension: ``2 r s_t s_p / (s_t^2 + s_p^2 + (m_t - m_p)^2 + 1e-8)`` with population
  (ddof=0) variances and ``r`` the Pearson correlation with NaN replaced by 0 (a constant
  dimension contributes 0), clipped to [-1, 1]; averaged over dimensions.
* FRCorr: mean over speakers of the *sum over the K reactions* of the max CCC over neighbours.
* FRDist: mean over speakers of the sum over K of the min over neighbours of
  ``sum_g w_g DTW(pred[:, g], gt[:, g])``; DTW is the square root of the minimal cumulative
  squared Euclidean cost (tslearn's ``dtw``), steps (i-1, j), (i, j-1), (i-1, j-1), no window.
* FRDiv (S-MSE): per speaker the sum of squared distances between its K reactions over ordered
  pairs (flattened T*D) divided by ``K (K - 1) T D``; mean over speakers; 0 when K = 1.
* FRDvs: the same across speakers for each sample index: ``sum / (N (N - 1) K) / (T D)``.
* FRVar: variance over time with ddof=1 (``torch.var`` default), mean over everything.
* FRSyn (official TLCC): for each speaker only the *first* reaction (k = 0) is used (the
  official multiprocessing helper returns inside its loop); Pearson correlation per dimension
  at lags -(s*fps-1)..(s*fps-1) (= -49..49), averaged over dimensions; a dimension that is
  exactly constant over the overlapping window makes that lag NaN, and ``torch.argmax`` picks
  the first NaN, so a clip with a constant dimension scores ``|offset| = 49``. The result is
  ``mean |49 - argmax|``. :func:`frsyn_robust` (labelled "FRSyn*" in tables) instead ignores
  constant dimensions (nan-mean), skips all-NaN lags and uses all K reactions.

Every fast path here has a float64 reference (``*_reference``) used by the tests.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError
from ..validation import check_array
from .features import DTW_GROUPS

__all__ = [
    "ccc_official", "ccc_matrix", "frcorr", "frdist", "frdiv", "frdvs", "frvar", "frsyn", "frsyn_robust",
    "dtw", "dtw_batched", "dtw_reference", "tlcc_offset_reference", "frechet_distance", "simple_image_features",
    "ReactMetrics", "compute_metrics",
]


# ---------------------------------------------------------------------------------------------
def _check(preds, listener_gt=None, speaker_gt=None, neighbour=None):
    sizes: dict[str, int] = {}
    preds = np.asarray(check_array(preds, "preds", ("N", "K", "T", "D"), sizes=sizes), dtype=np.float64)
    out = [preds]
    if listener_gt is not None:
        out.append(np.asarray(check_array(listener_gt, "listener_gt", (None, "T", "D"), sizes=sizes),
                              dtype=np.float64))
    if speaker_gt is not None:
        out.append(np.asarray(check_array(speaker_gt, "speaker_gt", ("N", "T", "D"), sizes=sizes),
                              dtype=np.float64))
    if neighbour is not None:
        m = out[1].shape[0]
        nb = np.asarray(check_array(neighbour, "neighbour", ("N", m), sizes=sizes))
        if not np.all((nb == 0) | (nb == 1)):
            raise InputError("neighbour: expected a 0/1 matrix, found other values")
        empty = np.flatnonzero(nb.sum(axis=1) == 0)
        if empty.size:
            raise InputError(f"neighbour: rows {empty[:5].tolist()} have no appropriate reaction (all zeros)")
        out.append(nb.astype(bool))
    return out


# ---- CCC / FRCorr ------------------------------------------------------------------------------
def ccc_official(y_true: np.ndarray, y_pred: np.ndarray) -> float:
    """CCC of two (T, D) sequences averaged over D, official semantics (loop reference)."""
    y_true = np.asarray(y_true, dtype=np.float64)
    y_pred = np.asarray(y_pred, dtype=np.float64)
    vals = []
    for i in range(y_true.shape[1]):
        a, b = y_true[:, i], y_pred[:, i]
        sa, sb = np.std(a), np.std(b)
        if sa == 0 or sb == 0 or np.all(a == a[0]) or np.all(b == b[0]):
            cor = 0.0
        else:
            cor = float(np.clip(np.corrcoef(a, b)[0, 1], -1.0, 1.0))
        num = 2.0 * cor * sa * sb
        den = np.var(a) + np.var(b) + (np.mean(a) - np.mean(b)) ** 2
        vals.append(num / (den + 1e-8))
    return float(np.mean(vals))


def _centre_stats(x: np.ndarray):
    """Means, centred values, ddof-0 std and an exact-constancy mask along axis -2 (time)."""
    m = x.mean(axis=-2, keepdims=True)
    c = x - m
    s = np.sqrt((c * c).mean(axis=-2))
    const = np.all(x == x[..., :1, :], axis=-2)
    return m[..., 0, :], c, s, const


def ccc_matrix(preds: np.ndarray, gts: np.ndarray) -> np.ndarray:
    """Official CCC (mean over D) between every prediction and every ground truth.

    Parameters
    ----------
    preds : numpy.ndarray, shape (P, T, D)
    gts : numpy.ndarray, shape (M, T, D)

    Returns
    -------
    numpy.ndarray, shape (P, M), float64
    """
    preds = np.asarray(preds, dtype=np.float64)
    gts = np.asarray(gts, dtype=np.float64)
    T = preds.shape[1]
    mp, cp, sp, kp = _centre_stats(preds)
    mg, cg, sg, kg = _centre_stats(gts)
    cov = np.einsum("ptd,mtd->pmd", cp, cg, optimize=True) / T  # ddof 0
    denom_r = sp[:, None, :] * sg[None, :, :]
    ok = (~kp)[:, None, :] & (~kg)[None, :, :] & (denom_r > 0)
    r = np.where(ok, cov / np.where(ok, denom_r, 1.0), 0.0)
    r = np.clip(r, -1.0, 1.0)
    num = 2.0 * r * denom_r
    den = sp[:, None, :] ** 2 + sg[None, :, :] ** 2 + (mp[:, None, :] - mg[None, :, :]) ** 2
    return (num / (den + 1e-8)).mean(axis=-1)


def frcorr(preds: np.ndarray, listener_gt: np.ndarray, neighbour: np.ndarray) -> float:
    """FRCorr: mean_n sum_k max_{j in nb(n)} CCC(listener_gt[j], preds[n, k]) (higher is better)."""
    preds, gt, nb = _check(preds, listener_gt, neighbour=neighbour)
    N, K, T, D = preds.shape
    c = ccc_matrix(preds.reshape(N * K, T, D), gt).reshape(N, K, -1)
    c = np.where(nb[:, None, :], c, -np.inf)
    return float(c.max(axis=2).sum(axis=1).mean())


# ---- DTW / FRDist ------------------------------------------------------------------------------
def dtw_reference(a: np.ndarray, b: np.ndarray) -> float:
    """DTW of (T1, d) and (T2, d) sequences: sqrt of the min cumulative squared Euclidean cost (loops)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    n, m = a.shape[0], b.shape[0]
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            d = float(np.sum((a[i - 1] - b[j - 1]) ** 2))
            acc[i, j] = d + min(acc[i - 1, j], acc[i, j - 1], acc[i - 1, j - 1])
    return float(np.sqrt(acc[n, m]))


_NUMBA_DTW = None


def _numba_dtw():
    global _NUMBA_DTW
    if _NUMBA_DTW is None:
        import numba

        @numba.njit(parallel=True, cache=True)
        def _tasks(PT, G, tn, tj, bounds, weights):  # pragma: no cover - compiled
            # PT (N, T1, D, K): the K reactions of each speaker in the innermost axis.
            # Task q compares all K reactions of speaker tn[q] with ground truth tj[q]; the K
            # recursions run in lockstep (the min-recursion vectorises over K). Squared distances
            # come from |a|^2 + |b|^2 - 2 a.b with the cross term as one BLAS product per frame
            # and group; where that expansion cancels (near-identical frames) the direct sum is used.
            Q = tn.shape[0]
            T1 = PT.shape[1]
            K = PT.shape[3]
            D = PT.shape[2]
            T2 = G.shape[1]
            ng = bounds.shape[0]
            out = np.zeros((Q, K))
            for q in numba.prange(Q):
                a = PT[tn[q]]
                b = G[tj[q]]
                bgs = [np.ascontiguousarray(b[:, bounds[g, 0]:bounds[g, 1]]) for g in range(ng)]
                prev = np.empty((ng, T2 + 1, K))
                cur = np.empty((ng, T2 + 1, K))
                d = np.empty((ng, K))
                for g in range(ng):
                    for k in range(K):
                        prev[g, 0, k] = 0.0
                    for j in range(1, T2 + 1):
                        for k in range(K):
                            prev[g, j, k] = np.inf
                # squared distances by expansion |a|^2 + |b|^2 - 2 a.b, the cross term as one small
                # BLAS product per (frame i, group): (T2, d_g) @ (d_g, K)
                bsq = np.zeros((ng, T2))
                for g in range(ng):
                    for j in range(T2):
                        acc = 0.0
                        for c in range(bounds[g, 0], bounds[g, 1]):
                            acc += b[j, c] * b[j, c]
                        bsq[g, j] = acc
                asq = np.zeros(K)
                for i in range(1, T1 + 1):
                    for g in range(ng):
                        s = bounds[g, 0]
                        e = bounds[g, 1]
                        ai = np.ascontiguousarray(a[i - 1, s:e, :])
                        cross = np.dot(bgs[g], ai)  # (T2, K)
                        for k in range(K):
                            acc = 0.0
                            for c in range(e - s):
                                acc += ai[c, k] * ai[c, k]
                            asq[k] = acc
                        for k in range(K):
                            cur[g, 0, k] = np.inf
                        for j in range(1, T2 + 1):
                            for k in range(K):
                                dd = asq[k] + bsq[g, j - 1] - 2.0 * cross[j - 1, k]
                                if dd < 1e-6 * (asq[k] + bsq[g, j - 1]):
                                    # near-identical frames: the expansion cancels, use the direct sum
                                    dd = 0.0
                                    for c in range(e - s):
                                        diff = ai[c, k] - b[j - 1, s + c]
                                        dd += diff * diff
                                mm = prev[g, j - 1, k]
                                if prev[g, j, k] < mm:
                                    mm = prev[g, j, k]
                                if cur[g, j - 1, k] < mm:
                                    mm = cur[g, j - 1, k]
                                cur[g, j, k] = dd + mm
                    prev, cur = cur, prev
                for k in range(K):
                    total = 0.0
                    for g in range(ng):
                        total += weights[g] * np.sqrt(prev[g, T2, k])
                    out[q, k] = total
            return out

        _NUMBA_DTW = _tasks
    return _NUMBA_DTW


def _group_arrays(groups, D: int) -> tuple[np.ndarray, np.ndarray]:
    for s, e, _ in groups:
        if not (0 <= s < e <= D):
            raise InputError(f"groups: ({s}, {e}) does not fit feature dimension D={D}")
    return (np.array([[s, e] for s, e, _ in groups], dtype=np.int64),
            np.array([w for _, _, w in groups], dtype=np.float64))


def dtw_batched(preds: np.ndarray, gts: np.ndarray, tasks: np.ndarray,
                groups: tuple[tuple[int, int, float], ...] = DTW_GROUPS) -> np.ndarray:
    """Group-weighted DTW of every reaction of a speaker against one ground truth, for many tasks.

    Parameters
    ----------
    preds : numpy.ndarray, shape (N, K, T1, D)
    gts : numpy.ndarray, shape (M, T2, D)
    tasks : numpy.ndarray, shape (Q, 2) int
        Rows ``(n, m)``: compare ``preds[n, k]`` for every k with ``gts[m]``.
    groups : tuple of (start, stop, weight)
        The result is ``sum_g weight * DTW(pred[:, start:stop], gt[:, start:stop])``.

    Returns
    -------
    numpy.ndarray, shape (Q, K), float64
    """
    preds = np.asarray(preds, dtype=np.float64)
    PT = np.ascontiguousarray(preds.transpose(0, 2, 3, 1))
    G = np.ascontiguousarray(gts, dtype=np.float64)
    tasks = np.asarray(tasks, dtype=np.int64).reshape(-1, 2)
    bounds, weights = _group_arrays(groups, preds.shape[3])
    if tasks.shape[0] == 0:
        return np.zeros((0, preds.shape[1]))
    return _numba_dtw()(PT, G, np.ascontiguousarray(tasks[:, 0]), np.ascontiguousarray(tasks[:, 1]),
                        bounds, weights)


def dtw(preds: np.ndarray, gts: np.ndarray, pairs: np.ndarray,
        groups: tuple[tuple[int, int, float], ...] = DTW_GROUPS) -> np.ndarray:
    """Group-weighted DTW for (prediction, ground truth) pairs.

    Parameters
    ----------
    preds : numpy.ndarray, shape (P, T1, D)
    gts : numpy.ndarray, shape (M, T2, D)
    pairs : numpy.ndarray, shape (Q, 2) int, rows ``(p, m)``

    Returns
    -------
    numpy.ndarray, shape (Q,): ``sum_g w_g DTW(preds[p][:, g], gts[m][:, g])``.
    """
    preds = np.asarray(preds, dtype=np.float64)
    return dtw_batched(preds[:, None], gts, pairs, groups)[:, 0]


def frdist(preds: np.ndarray, listener_gt: np.ndarray, neighbour: np.ndarray,
           groups: tuple[tuple[int, int, float], ...] = DTW_GROUPS) -> float:
    """FRDist: mean_n sum_k min_{j in nb(n)} sum_g w_g DTW(preds[n, k, :, g], listener_gt[j, :, g]) (lower is better)."""
    preds, gt, nb = _check(preds, listener_gt, neighbour=neighbour)
    N, K = preds.shape[:2]
    tasks = np.argwhere(nb)
    d = dtw_batched(preds, gt, tasks, groups)  # (Q, K)
    best = np.full((N, K), np.inf)
    np.minimum.at(best, tasks[:, 0], d)
    return float(best.sum(axis=1).mean())


# ---- diversity / variance ----------------------------------------------------------------------
def frdiv(preds: np.ndarray) -> float:
    """FRDiv (S-MSE): mean over speakers of the mean squared distance between its K reactions, / (T D)."""
    (preds,) = _check(preds)
    N, K, T, D = preds.shape
    if K == 1:
        return 0.0
    x = preds.reshape(N, K, T * D)
    sq = (x * x).sum(axis=2)
    gram = np.einsum("nkf,nlf->nkl", x, x)
    dist = np.clip(sq[:, :, None] + sq[:, None, :] - 2.0 * gram, 0.0, None)
    return float((dist.sum(axis=(1, 2)) / (K * (K - 1) * T * D)).mean())


def frdvs(preds: np.ndarray) -> float:
    """FRDvs: for each sample index the mean squared distance across speakers, / (T D), averaged."""
    (preds,) = _check(preds)
    N, K, T, D = preds.shape
    if N == 1:
        return 0.0
    x = preds.transpose(1, 0, 2, 3).reshape(K, N, T * D)
    sq = (x * x).sum(axis=2)
    gram = np.einsum("knf,kmf->knm", x, x)
    dist = np.clip(sq[:, :, None] + sq[:, None, :] - 2.0 * gram, 0.0, None)
    return float(dist.sum() / (N * (N - 1) * K) / (T * D))


def frvar(preds: np.ndarray) -> float:
    """FRVar: variance over time (ddof=1) of every reaction and dimension, averaged."""
    (preds,) = _check(preds)
    if preds.shape[2] < 2:
        raise InputError(f"preds: FRVar needs T >= 2 frames, found T={preds.shape[2]}")
    return float(preds.var(axis=2, ddof=1).mean())


# ---- FRSyn (TLCC) ------------------------------------------------------------------------------
def _shift(x, y, lag):
    if lag > 0:
        return x[lag:], y[:-lag]
    if lag < 0:
        return x[:lag], y[-lag:]
    return x, y


def tlcc_offset_reference(pred: np.ndarray, speaker: np.ndarray, seconds: float = 2.0, fps: int = 25,
                          robust: bool = False) -> float:
    """|offset| in frames of the peak lagged correlation of two (T, D) sequences (loop reference).

    ``robust=False``: official semantics (a NaN lag wins argmax). ``robust=True``: constant
    dimensions are ignored; lags where every dimension is constant are skipped; NaN when none remain.
    """
    pred = np.asarray(pred, dtype=np.float64)
    speaker = np.asarray(speaker, dtype=np.float64)
    max_lag = int(seconds * fps - 1)
    rs = []
    for lag in range(-max_lag, max_lag + 1):
        vals = []
        for d in range(pred.shape[1]):
            a, b = _shift(pred[:, d], speaker[:, d], lag)
            if np.all(a == a[0]) or np.all(b == b[0]):
                vals.append(np.nan)
            else:
                vals.append(float(np.clip(np.corrcoef(a, b)[0, 1], -1, 1)))
        vals = np.asarray(vals)
        if robust:
            rs.append(np.nan if np.all(np.isnan(vals)) else float(np.nanmean(vals)))
        else:
            rs.append(float(np.mean(vals)))
    rs = np.asarray(rs)
    if robust:
        if np.all(np.isnan(rs)):
            return float("nan")
        idx = int(np.nanargmax(rs))
    else:
        rs32 = rs.astype(np.float32)
        nan = np.flatnonzero(np.isnan(rs32))
        idx = int(nan[0]) if nan.size else int(np.argmax(rs32))
    return float(abs(len(rs) // 2 - idx))


_NUMBA_TLCC = None


def _numba_tlcc():
    global _NUMBA_TLCC
    if _NUMBA_TLCC is None:
        import numba

        @numba.njit(parallel=True, cache=True)
        def _corr(X, Y, max_lag):  # pragma: no cover - compiled
            # X (S, T, D) predictions, Y (S, T, D) speakers -> r (S, 2*max_lag+1, D), NaN where constant
            S, T, D = X.shape
            L = 2 * max_lag + 1
            out = np.empty((S, L, D))
            for s in numba.prange(S):
                for d in range(D):
                    x = X[s, :, d]
                    y = Y[s, :, d]
                    cx = np.zeros(T + 1)
                    cy = np.zeros(T + 1)
                    chx = np.zeros(T + 1, dtype=np.int64)  # number of value changes up to t
                    chy = np.zeros(T + 1, dtype=np.int64)
                    for t in range(T):
                        cx[t + 1] = cx[t] + x[t]
                        cy[t + 1] = cy[t] + y[t]
                        chx[t + 1] = chx[t] + (1 if (t > 0 and x[t] != x[t - 1]) else 0)
                        chy[t + 1] = chy[t] + (1 if (t > 0 and y[t] != y[t - 1]) else 0)
                    for li in range(L):
                        lag = li - max_lag
                        if lag >= 0:
                            x0, y0, n = lag, 0, T - lag
                        else:
                            x0, y0, n = 0, -lag, T + lag
                        if n < 2 or chx[x0 + n] - chx[x0 + 1] == 0 or chy[y0 + n] - chy[y0 + 1] == 0:
                            out[s, li, d] = np.nan
                            continue
                        sx = cx[x0 + n] - cx[x0]
                        sy = cy[y0 + n] - cy[y0]
                        mx = sx / n
                        my = sy / n
                        sxy = 0.0
                        vx = 0.0
                        vy = 0.0
                        for t in range(n):
                            ax = x[x0 + t] - mx
                            ay = y[y0 + t] - my
                            sxy += ax * ay
                            vx += ax * ax
                            vy += ay * ay
                        r = sxy / np.sqrt(vx * vy)
                        out[s, li, d] = min(1.0, max(-1.0, r))
            return out

        _NUMBA_TLCC = _corr
    return _NUMBA_TLCC


def _tlcc_r(preds_s: np.ndarray, speakers_s: np.ndarray, seconds: float, fps: int) -> np.ndarray:
    max_lag = int(seconds * fps - 1)
    T = preds_s.shape[1]
    if T <= max_lag + 1:
        raise InputError(f"preds: FRSyn needs T > {max_lag + 1} frames for lags up to {max_lag}, found T={T}")
    return _numba_tlcc()(np.ascontiguousarray(preds_s, dtype=np.float64),
                         np.ascontiguousarray(speakers_s, dtype=np.float64), max_lag)


def frsyn(preds: np.ndarray, speaker_gt: np.ndarray, seconds: float = 2.0, fps: int = 25) -> float:
    """FRSyn, official: mean |offset| (frames) of the peak time-lagged cross-correlation, first reaction only.

    A lag where any dimension is exactly constant over the overlapping window is NaN, and the
    first NaN lag wins (``torch.argmax`` semantics) -- e.g. a constant dimension gives 49.
    Lower is better.
    """
    preds, sp = _check(preds, None, speaker_gt)
    r = _tlcc_r(preds[:, 0], sp, seconds, fps)  # (N, L, D)
    rs = r.mean(axis=2).astype(np.float32)  # NaN propagates like torch.mean
    L = rs.shape[1]
    isnan = np.isnan(rs)
    idx = np.where(isnan.any(axis=1), isnan.argmax(axis=1), np.argmax(np.where(isnan, -np.inf, rs), axis=1))
    return float(np.abs(L // 2 - idx).mean())


def frsyn_robust(preds: np.ndarray, speaker_gt: np.ndarray, seconds: float = 2.0, fps: int = 25) -> float:
    """FRSyn* (NaN-robust, all K): constant dimensions ignored, all-NaN lags skipped, mean over N*K.

    Reactions without any defined lag are left out; NaN if none is defined.
    """
    preds, sp = _check(preds, None, speaker_gt)
    N, K, T, D = preds.shape
    r = _tlcc_r(preds.reshape(N * K, T, D), np.repeat(sp, K, axis=0), seconds, fps)
    valid = ~np.isnan(r)
    cnt = valid.sum(axis=2)
    rs = np.where(cnt > 0, np.where(valid, r, 0.0).sum(axis=2) / np.maximum(cnt, 1), -np.inf)
    L = rs.shape[1]
    ok = np.isfinite(rs).any(axis=1)
    if not ok.any():
        return float("nan")
    idx = np.argmax(rs[ok], axis=1)
    return float(np.abs(L // 2 - idx).mean())


# ---- FRRea helpers -----------------------------------------------------------------------------
def frechet_distance(feats_a: np.ndarray, feats_b: np.ndarray) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets (the FID formula).

    ``|mu_a - mu_b|^2 + tr(S_a + S_b - 2 (S_a S_b)^(1/2))`` with covariances ddof=1;
    ``tr((S_a S_b)^(1/2))`` is computed as the sum of square roots of the eigenvalues of the
    symmetric PSD matrix ``S_a^(1/2) S_b S_a^(1/2)``.

    Parameters
    ----------
    feats_a : numpy.ndarray, shape (n, F), n >= 2
    feats_b : numpy.ndarray, shape (m, F), m >= 2
    """
    sizes: dict[str, int] = {}
    a = np.asarray(check_array(feats_a, "feats_a", (None, "F"), sizes=sizes), dtype=np.float64)
    b = np.asarray(check_array(feats_b, "feats_b", (None, "F"), sizes=sizes), dtype=np.float64)
    if a.shape[0] < 2 or b.shape[0] < 2:
        raise InputError(f"feats: need at least 2 samples per set for a covariance, found {a.shape[0]} and {b.shape[0]}")
    mu_a, mu_b = a.mean(axis=0), b.mean(axis=0)
    sa = np.atleast_2d(np.cov(a, rowvar=False))
    sb = np.atleast_2d(np.cov(b, rowvar=False))
    w, v = np.linalg.eigh(sa)
    ra = (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T
    m = ra @ sb @ ra
    ev = np.linalg.eigvalsh(0.5 * (m + m.T))
    tr_sqrt = float(np.sqrt(np.clip(ev, 0.0, None)).sum())
    diff = mu_a - mu_b
    return float(diff @ diff + np.trace(sa) + np.trace(sb) - 2.0 * tr_sqrt)


def simple_image_features(images: np.ndarray) -> np.ndarray:
    """A small hand-made image descriptor for FRRea (NOT Inception: no learned features).

    Per image (float RGB in [0, 1], shape (H, W, 3)): the mean colour of a 4 x 4 grid of cells
    (48 values), an 8-bin gradient-orientation histogram weighted by gradient magnitude for each
    of 2 x 2 cells of the grey image (32 values), and the per-channel mean and standard
    deviation (6 values): 86 features.

    Parameters
    ----------
    images : numpy.ndarray, shape (B, H, W, 3), H and W >= 4

    Returns
    -------
    numpy.ndarray, shape (B, 86), float64
    """
    x = np.asarray(check_array(images, "images", ("B", "H", "W", 3)), dtype=np.float64)
    B, H, W, _ = x.shape
    if H < 4 or W < 4:
        raise InputError(f"images: expected H, W >= 4, found {(H, W)}")
    feats = []
    hs = np.linspace(0, H, 5).astype(int)
    ws = np.linspace(0, W, 5).astype(int)
    grid = np.stack([x[:, hs[i]:hs[i + 1], ws[j]:ws[j + 1]].mean(axis=(1, 2)) for i in range(4) for j in range(4)], 1)
    feats.append(grid.reshape(B, -1))
    g = x.mean(axis=3)
    gy, gx = np.gradient(g, axis=(1, 2))
    mag = np.hypot(gx, gy)
    ang = np.mod(np.arctan2(gy, gx), np.pi)
    bins = np.minimum((ang / np.pi * 8).astype(int), 7)
    h2 = [0, H // 2, H]
    w2 = [0, W // 2, W]
    for i in range(2):
        for j in range(2):
            bb = bins[:, h2[i]:h2[i + 1], w2[j]:w2[j + 1]].reshape(B, -1)
            mm = mag[:, h2[i]:h2[i + 1], w2[j]:w2[j + 1]].reshape(B, -1)
            hist = np.stack([(mm * (bb == k)).sum(axis=1) for k in range(8)], 1) / bb.shape[1]
            feats.append(hist)
    feats.append(x.mean(axis=(1, 2)))
    feats.append(x.std(axis=(1, 2)))
    return np.concatenate(feats, axis=1)


# ---- all together ------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReactMetrics:
    """The seed paper's Table 1 columns (FRRea None when not computed) plus the robust FRSyn*."""

    frcorr: float
    frdist: float
    frdiv: float
    frvar: float
    frdvs: float
    frsyn: float
    frsyn_robust: float
    frrea: float | None = None

    def to_dict(self) -> dict[str, float | None]:
        """Plain dict (JSON-ready)."""
        return asdict(self)


def compute_metrics(preds: np.ndarray, listener_gt: np.ndarray, speaker_gt: np.ndarray,
                    neighbour: np.ndarray) -> ReactMetrics:
    """Every REACT metric of one method on one split (see the module docstring)."""
    return ReactMetrics(
        frcorr=frcorr(preds, listener_gt, neighbour),
        frdist=frdist(preds, listener_gt, neighbour),
        frdiv=frdiv(preds),
        frvar=frvar(preds),
        frdvs=frdvs(preds),
        frsyn=frsyn(preds, speaker_gt),
        frsyn_robust=frsyn_robust(preds, speaker_gt),
    )
