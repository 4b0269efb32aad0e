"""Where a live group frame's CPU goes, stage by stage, and which stages run on one thread (issue 37).

The live renderer as ``holo-viewer live`` builds it (``LiveAvatarRenderer``, tile scale 0.5, the
per-view visible-Gaussian mask, mode ``auto``: a group frame with no face, every 6th view rendered,
the others warped), one frame cut into the stages of ``NativeFrameRenderer._synthesized``, each timed
by wall clock, by the calling thread's CPU (``time.thread_time``) and by the other threads' CPU
(``time.process_time`` less the caller's: numba's OpenMP workers, the C++ kernels' per-call threads,
torch's). Rounds alternate 1 and 2 render threads in one process (numba's count and the kernels'), so a
stage's *serial* part reads off its wall time at 2 threads against half its CPU at 1. The staged frame is
checked bit-identical to ``NativeFrameRenderer.frame`` first (exit 1 otherwise).

    python bench/live_stages.py [--frames 6] [--rounds 2] [--tile-scale 0.5] [--json OUT.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6, help="frames per round and thread count")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--tile-scale", type=float, default=0.5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    import numba

    from holo_viewer.display.native import views_to_native
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.pipeline.live import LIVE_T_MIN
    from holo_viewer.render import fast, view_synthesis

    r = LiveAvatarRenderer(tile_scale=args.tile_scale, visible_only=True, mode="auto")
    nr = r._live
    n_expr = int(r.pipeline.model.n_expr)

    def listener(i: int) -> dict:  # a changing face: expression and jaw every frame
        return {"expr": 0.3 * np.sin(0.3 * i + np.arange(n_expr)), "jaw_pose": np.array([0.1 * np.sin(0.2 * i), 0, 0])}

    acc: dict[str, list[float]] = {}

    def timed(name: str, fn):  # noqa: ANN001, ANN202
        w0, p0, t0 = time.perf_counter(), time.process_time(), time.thread_time()
        out = fn()
        w1, p1, t1 = time.perf_counter(), time.process_time(), time.thread_time()
        a = acc.setdefault(name, [0.0, 0.0, 0.0, 0])
        a[0] += w1 - w0
        a[1] += t1 - t0
        a[2] += (p1 - p0) - (t1 - t0)
        a[3] += 1
        return out

    def frame(i: int) -> np.ndarray:  # NativeFrameRenderer._group without faces = _synthesized, staged
        g = timed("deform", lambda: r.deform(listener(i), 0.2, ()))
        idx = nr._lod_index(g)
        step = nr.group_view_step
        src, src_cams, images, wmaps = nr._synth_buffers(step)
        cfg = nr.config.render
        n = len(g) if idx is None else idx.size
        vk = nr._source_keep(step, src, n)
        timed("project_bin_composite", lambda: fast.render(
            g, src_cams, dataclasses.replace(cfg, t_min=max(cfg.t_min, LIVE_T_MIN)), out=images, view_keep=vk,
            index=idx))

        def depth() -> None:
            gn = g.numpy()
            means, logits = np.asarray(gn.means), np.asarray(gn.opacity_logits, dtype=np.float64)
            if idx is not None:
                means, logits = means[idx], logits[idx]
            opacity = 1.0 / (1.0 + np.exp(-logits))
            view_synthesis.inverse_depth(means, opacity, nr.cameras, src, rig=nr._rig, out=wmaps, cell=nr._depth_cell)

        timed("z_buffer", depth)
        layout = (nr.calibration.cols, nr.calibration.rows)
        timed("source_tiles", lambda: views_to_native(images, layout, quilt=nr.quilt, tiles=src))
        if nr._sampled is None:
            nr.prepare_all_views()
        timed("warp_40_views", lambda: view_synthesis.warp_views(images, wmaps, src, nr._rig, quilt=nr.quilt,
                                                                   tiles=nr._tiles, pixels=nr._sampled,
                                                                   background=cfg.background))
        timed("interleave", lambda: views_to_native(None, nr.interleaver, quilt=nr.quilt, native=nr.native))
        return timed("native_copy", lambda: nr.native.copy())

    ref = nr.frame(r.deform(listener(0), 0.2, ()), None, "group").native.copy()
    if not np.array_equal(ref, frame(0)):
        print("the staged frame differs from NativeFrameRenderer.frame", file=sys.stderr)
        return 1
    rows: dict[tuple[str, int], list] = {}
    load0 = os.getloadavg()
    for _ in range(args.rounds):
        for th in (1, 2):
            r.set_render_threads(th)
            numba.set_num_threads(th)
            acc.clear()
            for i in range(args.frames):
                frame(i + 1)
            for k, (w, t, o, c) in acc.items():
                rows.setdefault((k, th), []).append((w / c, t / c, o / c))
    load1 = os.getloadavg()
    stages, total = {}, np.zeros(5)
    for k in dict.fromkeys(k for k, _ in rows):
        a, b = (np.mean(rows[(k, th)], axis=0) * 1e3 for th in (1, 2))
        row = np.array([a[1] + a[2], b[0], b[1], b[2], b[1] + b[2]])
        total += row
        stages[k] = dict(zip(("cpu_ms_1thread", "wall_ms_2threads", "caller_cpu_ms_2threads", "other_threads_cpu_ms_2threads",
                              "cpu_ms_2threads"), (round(float(x), 2) for x in row)))
        # the wall at 2 threads above half the 1-thread CPU: the stage's serial time
        stages[k]["serial_ms"] = round(float(max(0.0, row[1] - row[0] / 2)), 2)
    stages["total"] = dict(zip(("cpu_ms_1thread", "wall_ms_2threads", "caller_cpu_ms_2threads", "other_threads_cpu_ms_2threads",
                                "cpu_ms_2threads"), (round(float(x), 2) for x in total)))
    print(f"group frame stages, tile scale {args.tile_scale}, {args.frames} frames x {args.rounds} rounds per thread "
          f"count (load {load0[0]:.2f} -> {load1[0]:.2f} on {os.cpu_count()} cores); ms a frame")
    print(f"{'stage':24s} {'CPU 1 thr':>10s} {'wall 2 thr':>10s} {'caller':>8s} {'others':>8s} {'CPU 2 thr':>10s} {'serial':>8s}")
    for k, v in stages.items():
        vals = list(v.values()) + ([] if "serial_ms" in v else [max(0.0, v["wall_ms_2threads"] - v["cpu_ms_1thread"] / 2)])
        print(f"{k:24s} " + " ".join(f"{x:{w}.1f}" for x, w in zip(vals, (10, 10, 8, 8, 10, 8))))
    if args.json:
        from holo_viewer.fileio import atomic_write

        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(args.json, "w") as fh:
            json.dump({"config": vars(args), "cores": os.cpu_count(), "load": [load0[0], load1[0]],
                       "numba_threading_layer": numba.threading_layer(), "stages_ms_per_frame": stages}, fh, indent=2)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
