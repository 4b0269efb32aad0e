"""GPU backends on the default avatar quilt: torch on CUDA and gsplat against the CPU path.

Renders the 100k-Gaussian default avatar into the 48 framed 420x560 quilt cameras (the scene
and cameras of ``bench/render_tradeoff.py``) with every backend this machine can run on a
GPU (``gsplat`` when it imports, which is what ``auto`` picks there, and the pure-torch backend
on CUDA Gaussians), plus the CPU ``fast`` backend with all cores, and reports per backend: seconds per quilt (best of ``--repeats``, after an untimed
warm-up; the GPU is synchronised inside each backend before its timer stops, and the images
are copied back to the host as numpy, as every caller receives them), PSNR and max abs error
against the float64 reference on ``--ref-views`` views and against the fast backend on all 48.

Usage::

    python bench/render_gpu.py --json bench/results/render_gpu.json

Without CUDA it says so and exits with status 2 (nothing to measure).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.render_tradeoff import psnr, timed  # noqa: E402
from bench.scenes import default_scene, framed_cameras  # noqa: E402
from holo_viewer.errors import HoloViewerError  # noqa: E402
from holo_viewer.fileio import atomic_write  # noqa: E402
from holo_viewer.render import RenderConfig, render_views  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", required=True, help="output JSON file")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-views", type=int, default=3, help="views rendered by the float64 reference")
    args = ap.parse_args(argv)

    import torch

    if not torch.cuda.is_available():
        print("render_gpu: CUDA is not available here (torch "
              f"{torch.__version__}, cuda {torch.version.cuda}); nothing to measure", file=sys.stderr)
        return 2
    gpu = torch.cuda.get_device_name(0)
    print(f"GPU: {gpu}; torch {torch.__version__} (CUDA {torch.version.cuda}); CPU: {os.cpu_count()} cores")
    g, scene = default_scene()
    g = g.numpy()
    cams = framed_cameras(g, 48, 420, 560)
    ref_idx = np.linspace(0, len(cams) - 1, args.ref_views).round().astype(int).tolist()
    t0 = time.perf_counter()
    ref = render_views(g, cams[ref_idx], "reference").images
    t_ref = (time.perf_counter() - t0) / len(ref_idx)
    print(f"{scene}: {len(g)} Gaussians, 48 views 420x560; reference {t_ref:.1f} s per view (views {ref_idx})")

    records: list[dict] = []
    fast_imgs = None
    # the torch backend renders on the Gaussians' device: give it CUDA tensors
    for backend, gb in (("fast", g), ("gsplat", g), ("torch", g.torch(device="cuda"))):
        print(f"  {backend} ...", flush=True)
        try:
            render_views(gb, cams[:1], backend, RenderConfig())  # warm-up: CUDA context, JIT, numba cache
            r, wall, cpu = timed(gb, cams, backend, RenderConfig(), args.repeats)
        except (HoloViewerError, ImportError, RuntimeError) as exc:
            msg = str(exc).splitlines()[0][:200] if str(exc) else ""
            print(f"  {backend}: skipped ({type(exc).__name__}: {msg})")
            records.append({"backend": backend, "skipped": f"{type(exc).__name__}: {msg}"})
            continue
        if backend == "fast":
            fast_imgs = r.images
        p_ref = psnr(r.images[ref_idx], ref)
        rec = {"backend": r.backend, "config": "default", "scene": scene, "n_gaussians": len(g), "views": 48,
               "width": 420, "height": 560, "seconds_per_quilt": wall, "cpu_seconds_per_quilt": cpu,
               "psnr_db": float(p_ref.min()), "max_abs_err": float(np.abs(r.images[ref_idx] - ref).max()),
               "stage_seconds": r.timings, "device": gpu if backend != "fast" else platform.processor(),
               "threads": r.stats.get("threads")}
        if fast_imgs is not None:
            p_fast = psnr(r.images, fast_imgs)
            rec["psnr_vs_fast_db_min"] = float(p_fast.min())
            rec["max_abs_err_vs_fast"] = float(np.abs(r.images - fast_imgs).max())
        records.append(rec)
        print(f"  {r.backend}: {wall:.3f} s per quilt, {rec['psnr_db']:.1f} dB worst reference view", flush=True)
    base = next((x for x in records if x.get("backend", "").startswith("fast") and "seconds_per_quilt" in x), None)
    print(f"  {'backend':<18}{'s/quilt':>9}{'PSNR ref':>10}{'max err':>9}{'PSNR fast':>11}{'xfast':>8}")
    for x in records:
        if "seconds_per_quilt" not in x:
            continue
        if base:
            x["ratio_to_baseline"] = x["seconds_per_quilt"] / base["seconds_per_quilt"]
            x["baseline"] = f"{base['backend']} default, {base['threads']} threads"
        print(f"  {x['backend']:<18}{x['seconds_per_quilt']:>9.3f}{x['psnr_db']:>10.1f}{x['max_abs_err']:>9.4f}"
              f"{x.get('psnr_vs_fast_db_min', float('nan')):>11.1f}{x.get('ratio_to_baseline', float('nan')):>8.2f}")
    out = {"records": records, "reference_views": ref_idx, "reference_seconds_per_view": t_ref,
           "machine": {"gpu": gpu, "torch": torch.__version__, "cuda": torch.version.cuda,
                       "cpu_count": os.cpu_count()}, "repeats": args.repeats}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(args.json, "w") as f:
        json.dump(out, f, indent=1, default=float)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
