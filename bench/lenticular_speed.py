"""Lenticular interleave speed: quilt (3360x3360) -> native (1536x2048) with the fixture calibration.

Prints a table and optionally writes JSON (--json FILE): per method the best and median of N runs
(ms), max abs error against the float64 reference, and the speed ratio to the float64 reference
measured in the same run. The CPU may be shared: the best of N is the figure to quote.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from holo_viewer.display.calibration import DisplayCalibration
from holo_viewer.display.lenticular import Interleaver, interleave_reference


def _time(fn, repeats):
    fn()  # warm-up (numba compile / caches)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return min(ts), float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--calibration", default=None, help="visual.json (default: shipped Portrait)")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    cal = DisplayCalibration.load(args.calibration)
    rng = np.random.default_rng(0)
    shape = (cal.quilt_height, cal.quilt_width, 3)
    q8 = rng.integers(0, 256, shape, dtype=np.uint8)
    qf = q8.astype(np.float32) / 255.0
    rows = []
    t = time.perf_counter()
    ref = {m: interleave_reference(q8, cal, mode=m) for m in ("nearest", "blend")}
    t_ref = (time.perf_counter() - t) / 2
    rows.append(dict(method="float64 reference", mode="nearest", dtype="uint8", best_ms=t_ref * 1e3,
                     median_ms=t_ref * 1e3, max_err=0.0))
    for mode in ("nearest", "blend"):
        for backend in ("numba", "numpy"):
            t = time.perf_counter()
            il = Interleaver(cal, shape, mode=mode, backend=backend)
            pre = time.perf_counter() - t
            for q, dt in ((q8, "uint8"), (qf, "float32")):
                out = np.empty(il.shape, q.dtype)
                best, med = _time(lambda: il(q, out), args.repeats)
                scale = 1.0 if dt == "uint8" else 255.0
                err = float(np.abs(out.astype(np.float64) * scale - ref[mode]).max())
                rows.append(dict(method=f"Interleaver[{backend}]", mode=mode, dtype=dt, best_ms=best * 1e3,
                                 median_ms=med * 1e3, max_err=err, precompute_s=pre))
    for r in rows:
        r["speedup_vs_reference"] = t_ref * 1e3 / r["best_ms"]
    print(f"quilt {shape[1]}x{shape[0]} -> native {cal.screen_w}x{cal.screen_h}, {cal.n_views} views, "
          f"{os.cpu_count()} CPUs, best of {args.repeats}")
    print(f"{'method':24s} {'mode':8s} {'dtype':8s} {'best ms':>8s} {'median ms':>10s} {'max err':>8s} {'x ref':>7s}")
    for r in rows:
        print(f"{r['method']:24s} {r['mode']:8s} {r['dtype']:8s} {r['best_ms']:8.1f} {r['median_ms']:10.1f} "
              f"{r['max_err']:8.3g} {r['speedup_vs_reference']:7.0f}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"config": {"quilt": list(shape), "native": [cal.screen_h, cal.screen_w],
                                                          "views": cal.n_views, "repeats": args.repeats,
                                                          "cpus": os.cpu_count(), "machine": platform.processor()},
                                               "baseline": "float64 reference", "results": rows}, indent=2))


if __name__ == "__main__":
    main()
