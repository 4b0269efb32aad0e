"""FLAME LBS speed: ms per frame of FlameModel.forward at batch 1 and 64, float32 / float64.

Models: the embedded default head (when ``assets/default_head.npz`` exists) and a
random FLAME-sized model (5023 vertices, 300 shape + 100 expression components).
Baseline, measured in the same run: the plain vectorised float64 numpy LBS
(:func:`holo_viewer.flame.lbs.lbs_reference_np` plus numpy blend shapes) at batch 1.
``speedup`` = baseline ms per frame / ms per frame (higher is faster).
Errors: max vertex distance (m) of each configuration from the float64 numpy
reference on the same random parameters.

Usage::

    python bench/flame_speed.py [--json FILE] [--repeat N] [--device cpu|cuda] [--threads T]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from holo_viewer.fileio import atomic_write
from holo_viewer.flame.io import load_flame_arrays
from holo_viewer.flame.lbs import lbs_reference_np
from holo_viewer.flame.model import FlameModel
from holo_viewer.flame.synthetic import random_flame_arrays

ROOT = Path(__file__).resolve().parents[1]
PARENTS = (-1, 0, 1, 1, 1)


def _time(fn: Callable[[], object], repeat: int, sync: Callable[[], None]) -> list[float]:
    """Wall times (s) of ``repeat`` calls after 3 warm-up calls."""
    for _ in range(3):
        fn()
    sync()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return times


def _params(rng: np.random.Generator, b: int, n_shape: int, n_expr: int) -> dict[str, np.ndarray]:
    return {
        "shape": rng.normal(size=(b, n_shape)),
        "expr": rng.normal(size=(b, n_expr)),
        "rotation": rng.normal(scale=0.3, size=(b, 3)),
        "neck_pose": rng.normal(scale=0.3, size=(b, 3)),
        "jaw_pose": rng.normal(scale=0.3, size=(b, 3)),
        "eyes_pose": rng.normal(scale=0.3, size=(b, 6)),
        "translation": rng.normal(scale=0.05, size=(b, 3)),
    }


def _numpy_reference(arrays: dict, n_shape_file: int, n_shape: int, n_expr: int, p: dict) -> np.ndarray:
    """Float64 numpy FLAME (blend shapes + lbs_reference_np): the baseline and the accuracy reference."""
    sd = arrays["shapedirs"]
    dirs = np.concatenate([sd[:, :, :n_shape], sd[:, :, n_shape_file:n_shape_file + n_expr]], axis=2)
    coeffs = np.concatenate([p["shape"], p["expr"]], axis=1)
    v_shaped = arrays["v_template"][None] + np.einsum("vck,bk->bvc", dirs, coeffs)
    joints = np.einsum("jv,bvc->bjc", arrays["J_regressor"], v_shaped)
    b = coeffs.shape[0]
    pose = np.concatenate([p["rotation"], p["neck_pose"], p["jaw_pose"], p["eyes_pose"]], axis=1).reshape(b, 5, 3)
    verts, _ = lbs_reference_np(v_shaped, joints, pose, arrays["posedirs"], arrays["weights"], PARENTS)
    return verts + p["translation"][:, None]


def bench_model(name: str, arrays: dict, repeat: int, device: str) -> list[dict]:
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    probe = FlameModel.from_arrays(arrays, n_shape=None, n_expr=None, dtype=torch.float64)
    n_shape, n_expr = probe.n_shape, probe.n_expr
    k_total = arrays["shapedirs"].shape[2]
    n_shape_file = int(np.asarray(arrays.get("n_shape", 300 if k_total >= 300 else 0)).reshape(()))
    rng = np.random.default_rng(0)
    rows: list[dict] = []

    p1 = _params(rng, 1, n_shape, n_expr)
    base_times = _time(lambda: _numpy_reference(arrays, n_shape_file, n_shape, n_expr, p1), max(repeat // 5, 5),
                       lambda: None)
    base_ms = 1e3 * statistics.median(base_times)
    base_min = 1e3 * min(base_times)
    rows.append({"model": name, "n_vertices": probe.n_vertices, "n_shape": n_shape, "n_expr": n_expr,
                 "impl": "numpy float64 reference (baseline)", "device": "cpu", "dtype": "float64", "batch": 1,
                 "shape": "per call", "ms_per_frame": base_ms, "ms_per_frame_min": base_min, "speedup": 1.0,
                 "max_err_m": 0.0})

    for batch in (1, 64):
        p = _params(rng, batch, n_shape, n_expr)
        ref = _numpy_reference(arrays, n_shape_file, n_shape, n_expr, p)
        for dtype in (torch.float32, torch.float64):
            model = FlameModel.from_arrays(arrays, n_shape=None, n_expr=None, dtype=dtype, device=device)
            pt = {k: torch.as_tensor(v, dtype=dtype, device=device) for k, v in p.items()}
            with torch.no_grad():
                err = float(np.abs(model(**pt).vertices.double().cpu().numpy() - ref).max())
                modes = [("fixed", pt)]
                if batch == 1:
                    # a new shape tensor every call defeats the shape cache
                    shapes = [torch.as_tensor(rng.normal(size=(1, n_shape)), dtype=dtype, device=device)
                              for _ in range(8)]
                    counter = iter(range(10 ** 9))
                    modes.append(("per call", None))
                for mode, fixed in modes:
                    if fixed is not None:
                        fn = (lambda m=model, q=fixed: m(**q))
                    else:
                        fn = (lambda m=model, q=pt: m(**{**q, "shape": shapes[next(counter) % 8]}))
                    reps = repeat if batch == 1 else max(repeat // 8, 3)
                    times = _time(fn, reps, sync)
                    ms = 1e3 * statistics.median(times) / batch
                    rows.append({"model": name, "n_vertices": model.n_vertices, "n_shape": n_shape,
                                 "n_expr": n_expr, "impl": "FlameModel (torch)", "device": device,
                                 "dtype": str(dtype).replace("torch.", ""), "batch": batch, "shape": mode,
                                 "ms_per_frame": ms, "ms_per_frame_min": 1e3 * min(times) / batch,
                                 "speedup": base_ms / ms, "max_err_m": err})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=Path, default=None, help="write results as JSON")
    ap.add_argument("--repeat", type=int, default=50, help="timed calls at batch 1 (batch 64: repeat / 8)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)

    models: list[tuple[str, dict]] = []
    head = ROOT / "assets" / "default_head.npz"
    if head.exists():
        models.append(("default head", load_flame_arrays(head)))
    else:
        print(f"note: {head} not found; default head skipped", file=sys.stderr)
    models.append(("random FLAME-sized", random_flame_arrays(5023, 300, 100, seed=0, write_split=False)))

    rows: list[dict] = []
    for name, arrays in models:
        rows.extend(bench_model(name, arrays, args.repeat, args.device))

    header = f"{'model':<20} {'V':>5} {'impl':<36} {'dev':<4} {'dtype':<7} {'B':>3} {'shape':<8} " \
             f"{'ms/frame':>9} {'min':>8} {'speedup':>8} {'max err (m)':>11}"
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['model']:<20} {r['n_vertices']:>5} {r['impl']:<36} {r['device']:<4} {r['dtype']:<7} "
              f"{r['batch']:>3} {r['shape']:<8} {r['ms_per_frame']:>9.3f} {r['ms_per_frame_min']:>8.3f} "
              f"{r['speedup']:>8.1f} "
              f"{r['max_err_m']:>11.2e}")
    f32_err = {name: max(r["max_err_m"] for r in rows if r["model"] == name and r["dtype"] == "float32")
               for name, _ in models}
    for name, e in f32_err.items():
        print(f"float32 vs float64 reference, max vertex error, {name}: {e:.2e} m")

    if args.json:
        result = {
            "config": {"torch": torch.__version__, "numpy": np.__version__, "threads": torch.get_num_threads(),
                       "cpu_count": os.cpu_count(), "machine": platform.machine(), "python": platform.python_version(),
                       "device": args.device, "repeat": args.repeat,
                       "cuda": torch.cuda.get_device_name(0) if args.device == "cuda" else None,
                       "baseline": "numpy float64 reference LBS at batch 1 (same run)",
                       "timing": "median (and min) wall time per call / batch, after 3 warm-up calls; "
                                 "speedup = baseline median / median"},
            "results": rows,
            "float32_vs_float64_max_error_m": f32_err,
        }
        with atomic_write(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
