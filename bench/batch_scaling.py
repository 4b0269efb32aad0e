"""Batch rendering throughput: jobs/s and frames/s in-process and on a local Ray with 1 and 2 workers,
Ray's per-task overhead, and what N nodes should give.

Runs one synthetic manifest (``--jobs`` still clips of ``--frames`` frames of the default avatar,
each frame a different pain level, quilt mp4 output) three or more ways into fresh folders:

* ``in-process``: the baseline (no Ray), one renderer thread;
* ``ray w=1``: one Ray worker, one thread (the baseline plus Ray's overhead);
* ``ray w=2``: two Ray workers, one thread each (this machine has 2 cores);
* ``ray w=1 t=2``: one Ray worker with two renderer threads (``--threads-per-worker 2``);

and measures Ray's overhead alone: the round trip of an empty task (sequential: latency; 200 at
once: throughput), and of a task returning 1 MB (a chunk's segment is ~0.1-2 MB).

Prints a table and writes JSON (``--json``): config, wall seconds, jobs/s, frames/s, speed-up
over the in-process baseline measured in the same run, the per-frame render cost, the driver's
per-frame cost, and the N-node projection (see docs/batch.md for the model).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

PROD_CHUNK = 25  # the default --chunk-frames


def ray_overhead(n: int = 200) -> dict[str, float]:
    import ray

    @ray.remote(num_cpus=1)
    def noop(x=None):
        return x

    @ray.remote(num_cpus=1)
    def megabyte():
        return b"\0" * (1 << 20)

    ray.get([noop.remote() for _ in range(4)])  # workers up
    t = time.perf_counter()
    for _ in range(50):
        ray.get(noop.remote())
    latency = (time.perf_counter() - t) / 50
    t = time.perf_counter()
    ray.get([noop.remote() for _ in range(n)])
    throughput = (time.perf_counter() - t) / n
    t = time.perf_counter()
    for _ in range(20):
        ray.get(megabyte.remote())
    mb = (time.perf_counter() - t) / 20
    return {"task_latency_s": latency, "task_seconds_at_throughput": throughput, "task_1mb_result_s": mb}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=4)
    ap.add_argument("--frames", type=int, default=6, help="frames per job")
    ap.add_argument("--chunk-frames", type=int, default=3)
    ap.add_argument("--tile-scale", type=float, default=1.0, help="1.0 = the full 3360x3360 quilt")
    ap.add_argument("--quick", action="store_true", help="tile scale 0.25, 2 jobs of 4 frames")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    if args.quick:
        args.tile_scale, args.jobs, args.frames, args.chunk_frames = 0.25, 2, 4, 2

    from holo_viewer.batch import InProcessExecutor, RayExecutor, run_batch

    tmp = Path(tempfile.mkdtemp(prefix="batch_scaling_"))
    manifest = tmp / "m.jsonl"
    with open(manifest, "w") as fh:
        for j in range(args.jobs):
            # distinct jobs (distinct hashes) of the same cost
            fh.write(json.dumps({"id": f"clip{j}", "frames": args.frames, "pain": round(0.3 + 0.1 * j, 3),
                                 "scenario": "rising", "expressions": {"smile": 0.5},
                                 "tile_scale": args.tile_scale, "outputs": ["quilt_mp4"]}) + "\n")
    load = os.getloadavg()

    # warm the caches (default avatar file cache, numba kernels) outside the timed runs
    warm = tmp / "warm.jsonl"
    warm.write_text(json.dumps({"frames": 1, "tile_scale": args.tile_scale}) + "\n")
    run_batch(warm, tmp / "warm", InProcessExecutor(1), progress=False)

    rows = []

    def timed(name: str, executor, **extra) -> dict:
        out = tmp / name.replace(" ", "_").replace("=", "")
        t = time.perf_counter()
        s = run_batch(manifest, out, executor, chunk_frames=args.chunk_frames, progress=False)
        wall = time.perf_counter() - t
        assert all(j.status == "done" for j in s.jobs), [j.error for j in s.jobs]
        render = sum(j.render_seconds or 0.0 for j in s.jobs)
        n = s.frames_rendered
        row = dict(config=name, wall_s=wall, jobs_per_s=len(s.jobs) / wall, frames_per_s=n / wall,
                   render_s_per_frame=render / n, driver_s_per_frame=s.driver_seconds / n, frames=n, **extra)
        rows.append(row)
        shutil.rmtree(out, ignore_errors=True)
        return row

    ip = InProcessExecutor(1)
    # the in-process baseline reuses this process's loaded scene: its first run pays no avatar load,
    # like a Ray worker after its first chunk; run it warm to get the per-frame cost
    timed("in-process", ip)

    import ray

    t = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="WARNING")
    ray_start = time.perf_counter() - t
    overhead = ray_overhead()
    timed("ray w=1 (cold)", RayExecutor(workers=1, threads=1), includes="worker start + avatar load")
    timed("ray w=2 (cold)", RayExecutor(workers=2, threads=1), includes="worker start + avatar load")
    # again with warm workers (Ray keeps them, with their loaded scene): what a long batch sees
    timed("ray w=1", RayExecutor(workers=1, threads=1))
    timed("ray w=2", RayExecutor(workers=2, threads=1))
    timed("ray w=1 t=2", RayExecutor(workers=1, threads=2))  # the same 2 cores as threads of one worker
    ray.shutdown()
    shutil.rmtree(tmp, ignore_errors=True)

    base = rows[0]["frames_per_s"]
    for r in rows:
        r["speedup"] = r["frames_per_s"] / base

    # N-node projection: each worker renders at the per-frame cost measured with one warm worker
    # (it had a core to itself) plus Ray's per-task overhead spread over a chunk; the driver writes
    # each chunk and joins each job at its measured per-chunk cost (this run's chunks are short, so
    # spreading that over a production chunk of PROD_CHUNK frames overestimates it: the join is per job).
    c = next(r for r in rows if r["config"] == "ray w=1")["render_s_per_frame"]
    n_chunks = args.jobs * -(-args.frames // args.chunk_frames)
    d_chunk = max(r["driver_s_per_frame"] * r["frames"] for r in rows[1:]) / n_chunks
    o = overhead["task_1mb_result_s"]
    projection = []
    for f in (args.chunk_frames, PROD_CHUNK):
        per_frame_worker = c + o / f
        d = d_chunk / f
        for nodes in (1, 2, 4, 8, 16, 32, 64):
            for cores in (2, 16):
                workers = nodes * cores
                fps = min(workers / per_frame_worker, 1.0 / d)
                projection.append(dict(chunk_frames=f, nodes=nodes, cores_per_node=cores, workers=workers,
                                       frames_per_s=fps, driver_bound=fps < workers / per_frame_worker))

    print(f"\nbatch scaling: {args.jobs} jobs x {args.frames} frames, tile_scale {args.tile_scale}, "
          f"chunks of {args.chunk_frames}; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} "
          f"({os.cpu_count()} CPUs)")
    print(f"{'config':<24} {'wall s':>8} {'jobs/s':>8} {'frames/s':>9} {'render s/frame':>15} "
          f"{'driver s/frame':>15} {'x in-process':>13}")
    for r in rows:
        print(f"{r['config']:<24} {r['wall_s']:8.2f} {r['jobs_per_s']:8.3f} {r['frames_per_s']:9.3f} "
              f"{r['render_s_per_frame']:15.3f} {r['driver_s_per_frame']:15.4f} {r['speedup']:13.2f}")
    print(f"\nRay: start {ray_start:.1f} s; empty task {overhead['task_latency_s'] * 1e3:.2f} ms round trip, "
          f"{overhead['task_seconds_at_throughput'] * 1e3:.2f} ms each at throughput; 1 MB result "
          f"{overhead['task_1mb_result_s'] * 1e3:.2f} ms")
    print(f"projection: render {c:.3f} s/frame/worker (1 warm worker), Ray task {o * 1e3:.1f} ms per chunk, "
          f"driver {d_chunk * 1e3:.1f} ms per chunk:")
    print(f"  {'nodes x cores':<14} " + " ".join(f"{f'{f}-frame chunks':>18}" for f in (args.chunk_frames, PROD_CHUNK)))
    for nodes in (1, 2, 4, 8, 16, 32, 64):
        for cores in (2, 16):
            cells = [p for p in projection if p["nodes"] == nodes and p["cores_per_node"] == cores]
            print(f"  {f'{nodes} x {cores}':<14} " + " ".join(
                f"{p['frames_per_s']:10.1f} fr/s{' D' if p['driver_bound'] else '  '}" for p in cells))
    print("  (D = bound by the driver writing and joining)")
    record = {"config": vars(args), "load_average": load, "cpus": os.cpu_count(), "machine": platform.platform(),
              "ray": ray.__version__, "ray_start_s": ray_start, "ray_overhead": overhead, "rows": rows,
              "projection": projection,
              "render_s_per_frame_one_worker": c, "driver_s_per_chunk": d_chunk,
              "model": "frames/s = min(workers / (render_s_per_frame + task_overhead / chunk_frames), "
                       "chunk_frames / driver_s_per_chunk)"}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(record, indent=2))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
