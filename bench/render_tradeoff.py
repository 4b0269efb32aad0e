"""Run time against error for every splat backend and knob (issue 6, item 7).

For the default avatar (100k Gaussians; the shell scene of bench/scenes.py when the avatar
module is missing) and a random scene, framed by the 48 quilt cameras as the pipeline frames
a head, this measures per backend and knob setting:

* seconds per 48-view 420x560 quilt (best of 5, or 1 with --quick; wall clock) split by stage, process CPU time
  and thread count (the CPU may be shared: compare CPU time too);
* PSNR (minimum over views) and max abs error against the float64 reference on a subset of
  views (the reference takes seconds per view);
* peak memory: tracemalloc peak of numpy allocations during one render, and the growth of
  the process's peak RSS;
* slow backends (reference, vtk, torch) render only the reference views, after an untimed
  one-view warm-up; their seconds per quilt are extrapolated (x 48 / views) and marked
  ``extrapolated``.

Usage::

    python bench/render_tradeoff.py [--quick] --json bench/results/render_tradeoff.json \\
        [--plot bench/results/render_tradeoff.png]

``--quick`` (< 3 min) runs fewer knobs, one repeat and two reference views.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.scenes import default_scene, framed_cameras, random_scene  # noqa: E402
from holo_viewer.errors import HoloViewerError  # noqa: E402
from holo_viewer.fileio import atomic_path, atomic_write  # noqa: E402
from holo_viewer.render import RenderConfig, render_views  # noqa: E402
from holo_viewer.render import fast  # noqa: E402


def psnr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-view PSNR (dB) of (V, H, W, 3) images in [0, 1]."""
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2, axis=(1, 2, 3))
    return 10.0 * np.log10(1.0 / np.maximum(mse, 1e-20))


def timed(g, cams, backend: str, config: RenderConfig, repeats: int):
    """Best-of-``repeats`` render: (result of the best run, wall seconds, CPU seconds)."""
    best = None
    for _ in range(repeats):
        r = None  # hold at most the best result, as a streaming caller holds its last frame
        c0, t0 = time.process_time(), time.perf_counter()
        r = render_views(g, cams, backend, config)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if best is None or wall < best[1]:
            best = (r, wall, cpu)
    return best


def peak_memory(g, cams, backend: str, config: RenderConfig) -> tuple[float, float]:
    """(tracemalloc peak MiB of one render, peak-RSS growth MiB)."""
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    render_views(g, cams, backend, config)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20, (rss1 - rss0) / 1024.0


def knob_grid(quick: bool) -> list[tuple[str, dict]]:
    """(label, RenderConfig kwargs) for the fast backend."""
    grid = [("default", {}), ("alpha_thr=1/64", {"alpha_threshold": 1 / 64}),
            ("radius=2.5", {"radius_sigmas": 2.5}), ("sh_degree=0", {"sh_degree": 0}),
            ("shared_sh", {"shared_sh": True}), ("tile=8", {"tile_size": 8}), ("tile=32", {"tile_size": 32})]
    if not quick:
        grid += [("alpha_thr=0.05", {"alpha_threshold": 0.05}), ("radius=2", {"radius_sigmas": 2.0}),
                 ("cull_margin=0.05", {"cull_margin": 0.05}),
                 ("fastest", {"alpha_threshold": 1 / 64, "radius_sigmas": 2.5, "shared_sh": True})]
    return grid


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer knobs, 1 repeat, 2 reference views (< 3 min)")
    ap.add_argument("--json", required=True, help="output JSON file")
    ap.add_argument("--plot", help="output PNG: seconds per quilt against PSNR")
    ap.add_argument("--views", type=int, default=48)
    ap.add_argument("--width", type=int, default=420)
    ap.add_argument("--height", type=int, default=560)
    ap.add_argument("--n-random", type=int, default=None, help="Gaussians in the random scene (20k; 5k quick)")
    args = ap.parse_args(argv)
    repeats = 1 if args.quick else 5
    ref_idx = [0, args.views - 1] if args.quick else [0, args.views // 2, args.views - 1]
    n_threads = fast._threads(RenderConfig())
    print(f"CPU: {os.cpu_count()} cores ({platform.processor() or platform.machine()}), "
          f"fast backend threads {n_threads}, C++ kernel {'built' if fast.cpp_available() else 'MISSING'}; "
          f"load average {os.getloadavg()[0]:.1f} (wall times are inflated on a shared machine)")

    scenes = []
    g, name = default_scene()
    scenes.append((name, g))
    n_random = args.n_random or (5000 if args.quick else 20000)
    scenes.append((f"random{n_random // 1000}k", random_scene(n_random, degree=3, seed=0, extent=(0.08, 0.11, 0.08),
                                                              scale_range=(-7.5, -5.0))))
    records: list[dict] = []
    notes: list[str] = []
    for scene_name, g in scenes:
        g = g.numpy()
        cams = framed_cameras(g if scene_name.startswith(("default", "shell")) else scenes[0][1],
                              args.views, args.width, args.height)
        sub = cams[ref_idx]
        t0 = time.perf_counter()
        ref = render_views(g, sub, "reference").images
        t_ref = time.perf_counter() - t0
        print(f"\n== {scene_name}: {len(g)} Gaussians, {args.views} views {args.width}x{args.height}; "
              f"reference {t_ref / len(ref_idx):.1f} s per view")

        def record(backend: str, label: str, cfg: dict, r, wall: float, cpu: float, views_rendered: int,
                   mem: tuple[float, float] | None = None) -> dict:
            if views_rendered == args.views:
                imgs, want = r.images[ref_idx], ref
            else:  # rendered the first views_rendered reference views only
                imgs, want = r.images, ref[:views_rendered]
            p = psnr(imgs, want) if backend != "reference" else np.full(len(want), np.inf)
            scale = args.views / views_rendered
            rec = {"backend": r.backend or backend, "config": label, "config_kwargs": cfg, "scene": scene_name,
                   "n_gaussians": len(g), "views": args.views, "width": args.width, "height": args.height,
                   "seconds_per_quilt": wall * scale, "cpu_seconds_per_quilt": cpu * scale,
                   "extrapolated": views_rendered != args.views, "views_rendered": views_rendered,
                   "threads": r.stats.get("threads", n_threads),
                   "psnr_db": float(p.min()), "psnr_db_per_view": [float(x) for x in p],
                   "max_abs_err": float(np.abs(imgs.astype(np.float64) - want).max()),
                   "stage_seconds": {k: v * scale for k, v in r.timings.items()},
                   "mean_blends_per_pixel": r.stats.get("mean_blends_per_pixel"),
                   "peak_tracemalloc_mib": mem[0] if mem else None, "peak_rss_growth_mib": mem[1] if mem else None}
            records.append(rec)
            return rec

        from holo_viewer.render.config import RenderResult

        record("reference", "default", {}, RenderResult(images=ref, timings={"total": t_ref}, backend="reference"),
               t_ref, t_ref, len(ref_idx))
        kernels = fast.kernel_names()
        for kern in kernels:
            grid = knob_grid(args.quick) if kern == kernels[0] else [("default", {})]
            # one untimed render first: the first call of a process allocates the buffers the
            # backend keeps (and numba may load its cache); with --quick's single repeat that
            # cost went into the default, the baseline of every ratio
            render_views(g, cams, "fast", RenderConfig(kernel=kern))
            for label, kw in grid:
                cfg = RenderConfig(kernel=kern, **kw)
                r, wall, cpu = timed(g, cams, "fast", cfg, repeats if label == "default" else min(3, repeats))
                mem = peak_memory(g, cams, "fast", cfg) if label == "default" and kern == kernels[0] else None
                record("fast", label, {"kernel": kern, **kw}, r, wall, cpu, args.views, mem)
        cpp = fast._cpp()
        if cpp is not None and cpp.has_avx512() and cpp.has_avx2():  # the path CPUs without AVX-512 take
            old_mode, fast._CPP_MODE = fast._CPP_MODE, 2
            try:
                r, wall, cpu = timed(g, cams, "fast", RenderConfig(kernel="cpp"), repeats)
            finally:
                fast._CPP_MODE = old_mode
            record("fast", "AVX2 path", {"kernel": "cpp", "path": "avx2"}, r, wall, cpu, args.views)
        for other in ("vtk", "torch", "gsplat"):
            # the torch CPU compositor takes tens of seconds per view: one view in --quick
            sub_o = sub[:1] if (args.quick and other == "torch") else sub
            try:
                # untimed warm-up on one view: the first call's one-time set-up (OSMesa context,
                # shader compilation, torch start-up) must not be multiplied by the extrapolation
                render_views(g, sub_o[:1], other, RenderConfig())
                r, wall, cpu = timed(g, sub_o, other, RenderConfig(), 1)
            except (HoloViewerError, ImportError, RuntimeError) as exc:
                msg = f"{other}: skipped on {scene_name} ({type(exc).__name__}: {str(exc).splitlines()[0][:160]})"
                notes.append(msg)
                print("  " + msg)
                continue
            record(other, "default", {}, r, wall, cpu, len(sub_o))
        base = [x for x in records if x["scene"] == scene_name and x["backend"].startswith("fast")
                and x["config"] == "default"][0]
        vtk = [x for x in records if x["scene"] == scene_name and x["backend"].startswith("vtk")]
        for x in records:
            if x["scene"] == scene_name:
                x["ratio_to_baseline"] = x["seconds_per_quilt"] / base["seconds_per_quilt"]
                x["baseline"] = f"{base['backend']} default"
                if vtk:
                    x["speedup_vs_vtk"] = vtk[0]["seconds_per_quilt"] / x["seconds_per_quilt"]
        print(f"  {'backend':<16}{'config':<18}{'s/quilt':>9}{'cpu s':>8}{'PSNR dB':>9}{'max err':>9}"
              f"{'xbase':>7}  stages (s/quilt)")
        for x in records:
            if x["scene"] != scene_name:
                continue
            st = " ".join(f"{k}={v:.3f}" for k, v in x["stage_seconds"].items() if k not in ("total",))
            print(f"  {x['backend']:<16}{x['config']:<18}{x['seconds_per_quilt']:>9.3f}"
                  f"{x['cpu_seconds_per_quilt']:>8.2f}{x['psnr_db']:>9.1f}{x['max_abs_err']:>9.4f}"
                  f"{x['ratio_to_baseline']:>7.2f}  {st}{' (extrapolated)' if x['extrapolated'] else ''}")
    if not any(r["backend"].startswith("gsplat") for r in records):
        notes.append("gsplat peer baseline: not run (gsplat not importable here or no CUDA; it is in the bench extra)")
    out = {"records": records, "notes": notes, "reference_views": ref_idx, "repeats": repeats,
           "machine": {"cpu_count": os.cpu_count(), "threads": n_threads, "load_average": os.getloadavg(),
                       "cpp_kernel": fast.cpp_available()}}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(args.json, "w") as f:
        json.dump(out, f, indent=1, default=float)
    print(f"\nwrote {args.json}")
    if args.plot:
        plot(records, args.plot)
        print(f"wrote {args.plot}")
    return 0


def plot(records: list[dict], path: str) -> None:
    """Seconds per quilt (log x) against PSNR, one marker per record, one colour per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 6))
    for scene, colour in zip(sorted({r["scene"] for r in records}), ("tab:blue", "tab:orange", "tab:green")):
        rs = [r for r in records if r["scene"] == scene and np.isfinite(r["psnr_db"])]
        ax.scatter([r["seconds_per_quilt"] for r in rs], [min(r["psnr_db"], 140) for r in rs], color=colour,
                   label=scene)
        for r in rs:
            ax.annotate(f"{r['backend'].replace('fast/', '')} {r['config']}",
                        (r["seconds_per_quilt"], min(r["psnr_db"], 140)), fontsize=6, alpha=0.8)
    ax.axhline(45, color="grey", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("seconds per 48-view 420x560 quilt (log)")
    ax.set_ylabel("PSNR vs float64 reference, worst view (dB; capped at 140)")
    ax.set_title("Splat renderers: time against error")
    ax.legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
