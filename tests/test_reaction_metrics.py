"""REACT metrics: hand-computed cases, fast paths against loop references, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.errors import InputError
from holo_viewer.reaction import metrics as M
from holo_viewer.reaction.features import DTW_GROUPS


# ---- hand-computed cases -------------------------------------------------------------------------
def test_ccc_and_frcorr_by_hand():
    # dim 0: truth [1,2,3], prediction [2,3,4]: cov0 = 2/3, var0 = 2/3 each, mean gap 1
    #        CCC = 2 (2/3) / (2/3 + 2/3 + 1) = (4/3) / (7/3) = 4/7
    # dim 1: constant prediction -> r = 0 -> CCC 0;  mean over dims = 2/7
    gt = np.array([[[1.0, 5.0], [2.0, 6.0], [3.0, 4.0]]])  # (1, 3, 2)
    pred = np.array([[2.0, 0.5], [3.0, 0.5], [4.0, 0.5]])
    assert M.ccc_official(gt[0], pred) == pytest.approx(2.0 / 7.0, abs=1e-8)
    preds = np.stack([pred, pred])[None]  # N=1, K=2
    # FRCorr sums over the K reactions: 2 * 2/7
    assert M.frcorr(preds, gt, np.ones((1, 1))) == pytest.approx(4.0 / 7.0, abs=1e-8)


def test_frcorr_takes_max_over_neighbours_only():
    t = np.arange(5.0)
    gt = np.stack([t, -t, t[::-1] ** 2])[:, :, None]  # 3 listeners, D=1
    preds = np.stack([t, t, t])[:, None, :, None]  # K=1: every prediction equals listener 0
    nb = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 1]])
    # speaker 0: own neighbour is identical -> CCC = 2 var / (2 var + 1e-8) ~ 1
    # speaker 1: only neighbour is -t: var 2 each, cov -2, means 2 and -2 -> -4 / (2 + 2 + 16) = -0.2
    # speaker 2: best of all three = ~1
    var = t.var()
    c1 = 2 * var / (2 * var + 1e-8)
    assert M.frcorr(preds, gt, nb) == pytest.approx((c1 - 0.2 + c1) / 3, abs=1e-9)


def test_dtw_by_hand():
    # a = [0, 1, 2], b = [0, 2]: min cumulative squared cost 1 -> DTW = 1
    assert M.dtw_reference(np.array([[0.0], [1.0], [2.0]]), np.array([[0.0], [2.0]])) == pytest.approx(1.0)
    # dim 0: a=[0,1,2], b=[0,2,2] -> cost 1 -> DTW 1;  dim 1: a=[1,1,1], b=[1,1,3] -> cost 4 -> DTW 2
    a = np.array([[0.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    b = np.array([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0]])
    groups = ((0, 1, 1.0), (1, 2, 0.5))
    got = M.dtw(a[None], b[None], np.array([[0, 0]]), groups)
    assert got[0] == pytest.approx(1.0 * 1.0 + 0.5 * 2.0)
    # FRDist: one speaker, K = 2 identical reactions -> sum over K = 2 * 2
    assert M.frdist(np.stack([a, a])[None], b[None], np.ones((1, 1)), groups) == pytest.approx(4.0)


def test_frdist_min_over_neighbours_and_official_groups():
    rng = np.random.default_rng(1)
    gt = rng.random((3, 6, 25))
    preds = np.repeat(gt[:, None], 2, axis=1).copy()
    nb = np.array([[1, 0, 0], [0, 1, 1], [0, 0, 1]])
    assert M.frdist(preds, gt, nb) == pytest.approx(0.0, abs=1e-12)  # own GT is a neighbour: distance 0
    assert DTW_GROUPS == ((0, 15, 1 / 15), (15, 17, 1.0), (17, 25, 1 / 8))
    nb2 = np.array([[0, 1, 0], [1, 0, 0], [1, 0, 0]])
    expect = np.mean([2 * sum(w * M.dtw_reference(gt[n][:, s:e], gt[j][:, s:e]) for s, e, w in DTW_GROUPS)
                      for n, j in ((0, 1), (1, 0), (2, 0))])
    assert M.frdist(preds, gt, nb2) == pytest.approx(expect, rel=1e-10)


def test_frdiv_frdvs_frvar_by_hand():
    # FRDiv: N=1, K=2, T=1, D=2: reactions [0,0] and [1,1]: ordered pairs sum 2+2=4, / (2*1*1*2) = 1
    preds = np.array([[[[0.0, 0.0]], [[1.0, 1.0]]]])
    assert M.frdiv(preds) == pytest.approx(1.0)
    assert M.frdiv(preds[:, :1]) == 0.0  # K = 1: 0 as in the official code
    # FRDvs: N=2, K=1: across speakers the same numbers -> 4 / (2*1*1) / 2 = 1
    assert M.frdvs(preds.transpose(1, 0, 2, 3)) == pytest.approx(1.0)
    # FRVar: [1, 2, 3] over time, ddof=1 -> 1
    assert M.frvar(np.array([1.0, 2.0, 3.0]).reshape(1, 1, 3, 1)) == pytest.approx(1.0)


def _lagged_pair(lag: int, T: int = 120, D: int = 3, seed: int = 0):
    rng = np.random.default_rng(seed)
    base = np.cumsum(rng.standard_normal((T + 10, D)), axis=0)
    speaker = base[10:]
    pred = base[10 - lag:T + 10 - lag]  # pred[t] = speaker[t - lag]
    return pred, speaker


def test_frsyn_by_hand_lag_first_sample_and_constant_dimension():
    pred3, sp = _lagged_pair(3)
    pred7, _ = _lagged_pair(7)
    preds = np.stack([pred3, pred7])[None]  # K=2: lags 3 and 7
    # official: only the first reaction counts -> 3
    assert M.frsyn(preds, sp[None]) == pytest.approx(3.0)
    # robust: all K -> (3 + 7) / 2
    assert M.frsyn_robust(preds, sp[None]) == pytest.approx(5.0)
    # a constant dimension: every lag is NaN, torch.argmax picks index 0 -> |49 - 0| = 49
    pc = preds.copy()
    pc[..., 1] = 0.25
    assert M.frsyn(pc, sp[None]) == pytest.approx(49.0)
    assert M.frsyn_robust(pc, sp[None]) == pytest.approx(5.0)  # the constant dimension is ignored
    assert M.tlcc_offset_reference(pc[0, 0], sp) == 49.0


def test_frechet_by_hand():
    # means 1 and 2 -> 1; variances (ddof 1) 2 and 2 -> 2 + 2 - 2 sqrt(4) = 0
    assert M.frechet_distance(np.array([[0.0], [2.0]]), np.array([[1.0], [3.0]])) == pytest.approx(1.0)
    x = np.random.default_rng(0).random((50, 4))
    assert M.frechet_distance(x, x) == pytest.approx(0.0, abs=1e-9)


# ---- fast paths against the references on random inputs -----------------------------------------
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fast_paths_match_references(dtype):
    rng = np.random.default_rng(3)
    N, K, T, D = 4, 3, 56, 25
    p = rng.random((N, K, T, D)).astype(dtype)
    g = rng.random((N, T, D)).astype(dtype)
    s = rng.random((N, T, D)).astype(dtype)
    p[0, 0, :, 3] = 0.5  # constant dims exercise the NaN / zero-correlation rules
    g[1, :, 4] = 0.0
    s[2, :, 5] = 1.0
    nb = (rng.random((N, N)) < 0.5).astype(int)
    np.fill_diagonal(nb, 1)
    p64, g64, s64 = p.astype(np.float64), g.astype(np.float64), s.astype(np.float64)
    ref = np.mean([sum(max(M.ccc_official(g64[j], p64[n, k]) for j in np.flatnonzero(nb[n])) for k in range(K))
                   for n in range(N)])
    assert M.frcorr(p, g, nb) == pytest.approx(ref, rel=1e-10, abs=1e-12)

    def dref(a, b):
        return sum(w * M.dtw_reference(a[:, s_:e], b[:, s_:e]) for s_, e, w in DTW_GROUPS)
    ref = np.mean([sum(min(dref(p64[n, k], g64[j]) for j in np.flatnonzero(nb[n])) for k in range(K))
                   for n in range(N)])
    assert M.frdist(p, g, nb) == pytest.approx(ref, rel=1e-10)
    ref = np.mean([M.tlcc_offset_reference(p64[n, 0], s64[n]) for n in range(N)])
    assert M.frsyn(p, s) == pytest.approx(ref)
    ref = np.nanmean([M.tlcc_offset_reference(p64[n, k], s64[n], robust=True) for n in range(N) for k in range(K)])
    assert M.frsyn_robust(p, s) == pytest.approx(ref)
    x = p64.reshape(N, K, -1)
    ref = np.mean([sum(((x[n, a] - x[n, b]) ** 2).sum() for a in range(K) for b in range(K)) / (K * (K - 1) * T * D)
                   for n in range(N)])
    assert M.frdiv(p) == pytest.approx(ref, rel=1e-9)
    y = p64.transpose(1, 0, 2, 3).reshape(K, N, -1)
    ref = sum(((y[k, a] - y[k, b]) ** 2).sum() for k in range(K) for a in range(N) for b in range(N))
    assert M.frdvs(p) == pytest.approx(ref / (N * (N - 1) * K) / (T * D), rel=1e-9)
    assert M.frvar(p) == pytest.approx(np.mean(np.var(p64, axis=2, ddof=1)), rel=1e-10)


def test_simple_image_features_shape_and_sensitivity():
    rng = np.random.default_rng(0)
    imgs = rng.random((3, 16, 12, 3))
    f = M.simple_image_features(imgs)
    assert f.shape == (3, 86)
    assert not np.allclose(f[0], f[1])


# ---- bad inputs --------------------------------------------------------------------------------------
def test_bad_inputs_raise_clear_errors():
    p = np.zeros((2, 2, 60, 25))
    g = np.zeros((2, 60, 25))
    with pytest.raises(InputError, match="preds"):
        M.frdiv(np.zeros((2, 60, 25)))
    with pytest.raises(InputError, match="listener_gt"):
        M.frcorr(p, np.zeros((2, 59, 25)), np.eye(2))
    bad = p.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        M.frvar(bad)
    with pytest.raises(InputError, match="neighbour"):
        M.frdist(p, g, np.zeros((2, 2)))
    with pytest.raises(InputError, match="neighbour"):
        M.frcorr(p, g, np.eye(3))
    with pytest.raises(InputError, match="FRSyn needs"):
        M.frsyn(np.zeros((1, 1, 40, 25)), np.zeros((1, 40, 25)))


@pytest.mark.slow
def test_frrea_renders_frames_and_separates_sets():
    from holo_viewer.pipeline import FaceStateRenderer
    from holo_viewer.reaction.frrea import frrea

    r = FaceStateRenderer(size=32, n_gaussians=5000)
    S = r.state_dim
    rng = np.random.default_rng(0)
    calm = np.zeros((6, S))
    calm[:, :S - 6] = 0.05 * rng.random((6, S - 6))
    wild = np.zeros((6, S))
    wild[:, :S - 6] = rng.random((6, S - 6))
    wild[:, S - 3:] = rng.normal(0, 0.25, (6, 3))
    imgs = r.render(wild[:2])
    assert imgs.shape == (2, 32, 32, 3) and 0.0 < imgs.mean() < 1.0
    same = frrea(calm, calm[::-1], r, n_frames=6)
    diff = frrea(calm, wild, r, n_frames=6)
    assert same == pytest.approx(0.0, abs=1e-6)  # the same frames in another order
    assert diff > 1e-3
