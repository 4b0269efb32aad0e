"""How the CPU live frame scales with threads (and with numba's threading layer).

The full quilt and a tracked frame (1 cm margin) of the default avatar with ``num_threads`` = 1,
2, 4, ... up to the machine's CPUs, each in a fresh process per threading layer (``omp`` as numba
picks it, ``workqueue``, and ``omp`` with ``OMP_WAIT_POLICY=passive``: numba's OpenMP workers
otherwise spin after a parallel region while the C++ kernels' own threads run). Per run: median
wall seconds per frame, CPU seconds per frame, speed-up against 1 thread of the same layer, and
the max abs difference of the views against the 1-thread render (the kernels are deterministic:
0 expected).

Why: on a lent 16-CPU GPU machine the full quilt took 0.38 s and 4.6 CPU seconds per frame, against
0.45 s and 0.86 CPU seconds on the 2-core VM (docs/live_frame.md); this separates the thread
count, the threading layer and the machine.

Usage::

    python bench/cpu_scaling.py [--threads 1,2,4] [--frames 4] [--json bench/results/cpu_scaling.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

LAYERS = {"omp": {}, "omp-passive": {"OMP_WAIT_POLICY": "passive"}, "workqueue": {"NUMBA_THREADING_LAYER": "workqueue"}}


def child(threads: list[int], frames: int, views_out: str) -> dict:
    """Runs in a fresh process: every thread count with this process's threading layer."""
    import numba

    from bench.live_frame import frames_of_animation
    from holo_viewer.display.eyes import TrackedViewer
    from holo_viewer.pipeline import Pipeline
    from holo_viewer.pipeline.live import NativeFrameConfig, NativeFrameRenderer
    from holo_viewer.render import RenderConfig

    pipe = Pipeline()
    cams, cal = pipe.cameras(), pipe.calibration
    anim = frames_of_animation(pipe, frames + 1)
    out = {}
    first = None
    for n in threads:
        cfg = NativeFrameConfig(render=RenderConfig(num_threads=n))
        rec = {}
        for mode in ("full_quilt", "tracked"):
            live = NativeFrameRenderer(cal, cams, cfg)
            viewer = TrackedViewer(0.0, 0.6) if mode == "tracked" else None
            live.frame(anim[0], viewer, mode)  # warm-up; the first tracked frame renders everything
            secs = []
            c0 = time.process_time()
            for k in range(1, frames + 1):
                v = TrackedViewer(-4.0 + 8.0 * k / frames, 0.6) if mode == "tracked" else None
                secs.append(live.frame(anim[k], v, mode).seconds)
            rec[mode] = {"seconds_per_frame": float(np.median(secs)),
                         "cpu_seconds_per_frame": (time.process_time() - c0) / frames}
            if mode == "full_quilt":
                if first is None:
                    first = live.views.copy()
                    np.save(views_out, first)
                rec["max_abs_vs_1_thread"] = float(np.abs(live.views - first).max())
        out[str(n)] = rec
    return {"threading_layer": numba.threading_layer(), "runs": out}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", default=None, help="comma-separated thread counts (default 1, 2, 4, ... CPUs)")
    ap.add_argument("--frames", type=int, default=4, help="timed frames per mode and thread count")
    ap.add_argument("--layers", default=",".join(LAYERS), help=f"threading layers ({', '.join(LAYERS)})")
    ap.add_argument("--json", default="bench/results/cpu_scaling.json", help="output JSON file")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    cpus = os.cpu_count() or 1
    if args.threads:
        threads = sorted({int(t) for t in args.threads.split(",")})
    else:
        threads = [1]
        while threads[-1] * 2 <= cpus:
            threads.append(threads[-1] * 2)
        if threads[-1] != cpus:
            threads.append(cpus)
    if args.child:  # inside the fresh process
        print(json.dumps(child(threads, args.frames, args.child)))
        return 0
    from holo_viewer.fileio import atomic_write

    layers = [x for x in args.layers.split(",") if x]
    bad = [x for x in layers if x not in LAYERS]
    if bad:
        print(f"error: --layers: expected some of {', '.join(LAYERS)}, found {', '.join(bad)}", file=sys.stderr)
        return 2
    t_run = time.perf_counter()
    records = []
    ref_views = None
    print(f"{cpus} CPUs, threads {threads}, {args.frames} frames per mode")
    print(f"{'layer':<12} {'threads':>7} {'full s':>8} {'cpu s':>7} {'x 1 thr':>8} {'tracked s':>10} {'cpu s':>7} "
          f"{'x 1 thr':>8} {'max |dv|':>9}")
    for layer in layers:
        env = dict(os.environ, **LAYERS[layer])
        views_file = f"/tmp/cpu_scaling_{os.getpid()}_{layer}.npy"
        res = subprocess.run([sys.executable, __file__, "--child", views_file, "--threads",
                              ",".join(map(str, threads)), "--frames", str(args.frames)],
                             env=env, capture_output=True, text=True, cwd=ROOT)
        if res.returncode != 0:
            print(f"{layer}: failed:\n{res.stderr[-2000:]}", file=sys.stderr)
            records.append({"layer": layer, "failed": res.stderr[-2000:]})
            continue
        got = json.loads(res.stdout.strip().splitlines()[-1])
        views = np.load(views_file)
        os.remove(views_file)
        if ref_views is None:
            ref_views = views
        across = float(np.abs(views - ref_views).max())
        base = got["runs"][str(threads[0])]
        for n in threads:
            r = got["runs"][str(n)]
            f, t = r["full_quilt"], r["tracked"]
            rec = {"layer": layer, "numba_threading_layer": got["threading_layer"], "threads": n,
                   "full_quilt_seconds": f["seconds_per_frame"], "full_quilt_cpu_seconds": f["cpu_seconds_per_frame"],
                   "full_quilt_speedup": base["full_quilt"]["seconds_per_frame"] / f["seconds_per_frame"],
                   "tracked_seconds": t["seconds_per_frame"], "tracked_cpu_seconds": t["cpu_seconds_per_frame"],
                   "tracked_speedup": base["tracked"]["seconds_per_frame"] / t["seconds_per_frame"],
                   "max_abs_vs_1_thread": r["max_abs_vs_1_thread"], "max_abs_vs_first_layer": across}
            records.append(rec)
            print(f"{layer:<12} {n:>7} {rec['full_quilt_seconds']:>8.3f} {rec['full_quilt_cpu_seconds']:>7.2f} "
                  f"{rec['full_quilt_speedup']:>8.2f} {rec['tracked_seconds']:>10.3f} {rec['tracked_cpu_seconds']:>7.2f} "
                  f"{rec['tracked_speedup']:>8.2f} {max(rec['max_abs_vs_1_thread'], across):>9.1e}", flush=True)
    result = {"benchmark": "cpu_scaling", "machine": {"cpus": cpus, "platform": platform.platform(),
                                                      "processor": platform.processor()},
              "frames": args.frames, "seconds_total": time.perf_counter() - t_run, "records": records}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(args.json, "w") as fh:
        json.dump(result, fh, indent=1)
    print(f"wrote {args.json} ({result['seconds_total']:.0f} s)")
    return 0 if all("failed" not in r for r in records) else 1


if __name__ == "__main__":
    sys.exit(main())
