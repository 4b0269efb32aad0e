"""Lossless session video size (issue 33): libx264rgb crf 0 presets against FFV1, on real native frames.

One command: records a synthetic live session in a child process (``holo-viewer live --synthetic
--headless``, the live defaults: group frames, full-size 2048x1536 native images), or takes
``--session DIR``; then encodes its displayed native frames, at the times they were shown, with each
candidate through :class:`holo_viewer.media.VideoWriter` (timed Matroska, as ``native.mkv``), and
reports per candidate: MB per frame, MB per minute at 1, 2.5 and 4 displayed frames/s (the CPU live
loop shows 1-3, replay's target is 4), ffmpeg's CPU seconds per frame (encode + the frame count),
whether it decodes bit-exact, and the size ratio to the policy today (libx264rgb ultrafast crf 0,
the baseline, measured in the same run).

    python bench/session_codecs.py [--seconds 12] [--session DIR] [--json bench/results/session_codecs.json]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: name -> VideoWriter keywords (codec, pixel format, output flags)
CANDIDATES = {
    "x264rgb ultrafast (today)": {"codec": "libx264rgb", "pixelformat": "rgb24",
                                  "output_params": ["-preset", "ultrafast", "-crf", "0"]},
    "x264rgb superfast": {"codec": "libx264rgb", "pixelformat": "rgb24",
                          "output_params": ["-preset", "superfast", "-crf", "0"]},
    "x264rgb veryfast": {"codec": "libx264rgb", "pixelformat": "rgb24",
                         "output_params": ["-preset", "veryfast", "-crf", "0"]},
    "x264rgb medium": {"codec": "libx264rgb", "pixelformat": "rgb24", "output_params": ["-preset", "medium", "-crf", "0"]},
    "ffv1 level 3": {"codec": "ffv1", "pixelformat": "bgr0", "output_params": ["-level", "3", "-g", "1", "-slices", "4"]},
}


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=12.0, help="length of the recorded synthetic session")
    ap.add_argument("--session", default=None, help="a recorded session folder instead")
    ap.add_argument("--json", default="bench/results/session_codecs.json")
    args = ap.parse_args()
    from holo_viewer.media import VideoWriter, read_frames

    with tempfile.TemporaryDirectory() as tmp:
        session = Path(args.session) if args.session else Path(tmp) / "session"
        if not args.session:
            subprocess.run([sys.executable, "-m", "holo_viewer", "live", "--synthetic", "--seconds", f"{args.seconds:g}",
                            "--headless", "--out", str(session)], check=True, capture_output=True)
        with np.load(session / "tracks.npz") as z:
            times = z["display_time_s"].astype(float)
        frames = list(read_frames(session / "native.mkv"))
        assert len(frames) == len(times), (len(frames), len(times))
        rows = {}
        for name, kw in CANDIDATES.items():
            out = Path(tmp) / "c.mkv"
            load = os.getloadavg()[0]
            c0, w0 = _children_cpu(), time.perf_counter()
            with VideoWriter(out, 10.0, timed=True, what="codec test", **kw) as w:
                for f, t in zip(frames, times):
                    w.write(f, t=float(t))
            cpu = _children_cpu() - c0
            size = out.stat().st_size
            exact = all(np.array_equal(a, b) for a, b in zip(frames, read_frames(out)))
            mb = size / 1e6 / len(frames)
            rows[name] = {"mb_per_frame": round(mb, 3), **{f"mb_per_min_at_{r:g}fps": round(mb * r * 60, 1)
                                                           for r in (1, 2.5, 4)},
                          "ffmpeg_cpu_s_per_frame": round(cpu / len(frames), 3),
                          "wall_s": round(time.perf_counter() - w0, 2), "bit_exact": bool(exact),
                          "load_1min": round(load, 2)}
            out.unlink()
    base = rows["x264rgb ultrafast (today)"]["mb_per_frame"]
    for r in rows.values():
        r["size_ratio_to_today"] = round(r["mb_per_frame"] / base, 3)
    h, w_ = frames[0].shape[:2]
    print(f"\nlossless session video, {len(frames)} displayed {w_}x{h} native frames ({2 * (h * w_ * 3) / 2e6:.1f} MB "
          f"raw each), {os.cpu_count()} cores")
    print(f"{'':28s} {'MB/frame':>9s} {'MB/min @1':>10s} {'@2.5':>7s} {'@4 fps':>7s} {'ffmpeg CPU s/fr':>16s} "
          f"{'exact':>6s} {'ratio':>6s} {'load':>5s}")
    for name, r in rows.items():
        print(f"{name:28s} {r['mb_per_frame']:9.3f} {r['mb_per_min_at_1fps']:10.1f} {r['mb_per_min_at_2.5fps']:7.1f} "
              f"{r['mb_per_min_at_4fps']:7.1f} {r['ffmpeg_cpu_s_per_frame']:16.3f} {str(r['bit_exact']):>6s} "
              f"{r['size_ratio_to_today']:6.3f} {r['load_1min']:5.1f}")
    result = {"config": vars(args), "cores": os.cpu_count(), "frames": len(frames), "size": [w_, h],
              "candidates": CANDIDATES, "results": rows}
    from holo_viewer.fileio import write_json

    write_json(args.json, result)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
