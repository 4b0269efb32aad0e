"""Speed of the REACT metrics at challenge size: N=100 speakers, K=10 reactions, T=750 frames, D=25.

The neighbour matrix has the diagonal plus ``--neighbours - 1`` random appropriate listeners per
row (FRDist cost grows linearly with the number of ones: N*K*ones DTWs of 750 x 750 per group).
Error column: the fast path against the float64 loop references on a subset (T=60).
Baseline (same run): the loop-reference DTW of one (reaction, listener) pair at T=750, scaled to
the full FRDist workload, so ``ratio`` = reference estimate / fast time.

Usage: python bench/react_metrics_speed.py [--n 100 --k 10 --t 750 --neighbours 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from holo_viewer.fileio import atomic_write
from holo_viewer.reaction import metrics as M
from holo_viewer.reaction.features import DTW_GROUPS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--k", type=int, default=10)
    ap.add_argument("--t", type=int, default=750)
    ap.add_argument("--neighbours", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    N, K, T, D = args.n, args.k, args.t, 25
    preds = rng.random((N, K, T, D))
    gt = rng.random((N, T, D))
    sp = rng.random((N, T, D))
    nb = np.eye(N, dtype=np.int8)
    for i in range(N):
        nb[i, rng.choice(N, args.neighbours - 1, replace=False)] = 1
    # compile outside the timing
    M.frdist(preds[:2, :2, :60], gt[:2, :60], np.ones((2, 2)))
    M.frsyn(preds[:2, :2, :60], sp[:2, :60])
    rows = []
    for name, fn in (("FRCorr", lambda: M.frcorr(preds, gt, nb)), ("FRDist", lambda: M.frdist(preds, gt, nb)),
                     ("FRDiv", lambda: M.frdiv(preds)), ("FRVar", lambda: M.frvar(preds)),
                     ("FRDvs", lambda: M.frdvs(preds)), ("FRSyn", lambda: M.frsyn(preds, sp)),
                     ("FRSyn*", lambda: M.frsyn_robust(preds, sp))):
        t0, c0 = time.perf_counter(), time.process_time()
        val = fn()
        rows.append({"metric": name, "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
                     "value": val})
    total = sum(r["seconds"] for r in rows)
    # error vs references on a subset
    n, k, t = 3, 2, 60
    p, g, s = preds[:n, :k, :t], gt[:n, :t], sp[:n, :t]
    nbs = nb[:n, :n] | np.eye(n, dtype=np.int8)

    def dref(a, b):
        return sum(w * M.dtw_reference(a[:, s_:e], b[:, s_:e]) for s_, e, w in DTW_GROUPS)
    ref = np.mean([sum(min(dref(p[i, j], g[m]) for m in np.flatnonzero(nbs[i])) for j in range(k)) for i in range(n)])
    err_dtw = abs(M.frdist(p, g, nbs) - ref) / ref
    ref = np.mean([sum(max(M.ccc_official(g[m], p[i, j]) for m in np.flatnonzero(nbs[i])) for j in range(k))
                   for i in range(n)])
    err_ccc = abs(M.frcorr(p, g, nbs) - ref)
    # baseline: loop-reference DTW of one pair at full T (one group), scaled
    t0 = time.perf_counter()
    M.dtw_reference(preds[0, 0, :, 15:17], gt[0, :, 15:17])
    ref_pair = time.perf_counter() - t0
    ref_total = ref_pair * len(DTW_GROUPS) * int(nb.sum()) * K
    fr = next(r for r in rows if r["metric"] == "FRDist")
    print(f"N={N} K={K} T={T} D={D}, {int(nb.sum())} neighbour pairs ({int(nb.sum()) * K} DTWs x 3 groups)")
    print(f"{'metric':<8} {'seconds':>9} {'cpu s':>8} {'value':>12}")
    for r in rows:
        print(f"{r['metric']:<8} {r['seconds']:>9.2f} {r['cpu_seconds']:>8.2f} {r['value']:>12.4f}")
    print(f"{'total':<8} {total:>9.2f}")
    print(f"error vs loop reference (T={t}): FRDist rel {err_dtw:.1e}, FRCorr abs {err_ccc:.1e}")
    print(f"loop-reference DTW estimate for FRDist: {ref_total:.0f} s -> ratio {ref_total / fr['seconds']:.0f}x")
    if args.json:
        out = {"config": {"N": N, "K": K, "T": T, "D": D, "neighbours_per_row": args.neighbours,
                          "neighbour_ones": int(nb.sum())},
               "results": rows, "total_seconds": total,
               "error": {"frdist_rel": err_dtw, "frcorr_abs": err_ccc, "subset": [n, k, t]},
               "baseline": {"reference_dtw_pair_seconds": ref_pair, "reference_frdist_estimate_seconds": ref_total,
                            "ratio": ref_total / fr["seconds"]}}
        with atomic_write(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
