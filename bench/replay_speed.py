"""Replay speed (issue 33): ``holo-viewer replay --quality live`` frames per second on this machine.

One command: records a synthetic session with ``holo-viewer live --synthetic --headless`` in a child
process (the live defaults: group frames, full-size tiles, the fast CPU renderer), then, in this
process:

* ``replay``: :func:`holo_viewer.live.replay.replay_session` ``quality="live"`` into a lossless timed
  mkv, split into its start (session read, renderer built and warmed: the first frame's wait) and its
  frame loop (frames/s = displayed frames over the loop's wall time; CPU seconds per frame of this
  process and of its ffmpeg children: encoding and the frame count before the rename);
* ``render only`` (the baseline, in the same run, after the replay): the same render calls without
  writing a video; ``ratio`` = replay frames/s over the baseline's;
* the error: the replayed frames against the session's ``native.mkv`` (frames identical, max
  difference in levels; bit-exact is the acceptance).

The load average is recorded beside every timing (the machine is shared). Target: >= 4 frames/s
in the frame loop on 2 cores.

    python bench/replay_speed.py [--seconds 20] [--json bench/results/replay_speed.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def record(out: Path, seconds: float) -> dict:
    """A synthetic session recorded by the live command in a child process."""
    t = time.perf_counter()
    cmd = [sys.executable, "-m", "holo_viewer", "live", "--synthetic", "--seconds", f"{seconds:g}", "--headless",
           "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"recording failed ({proc.returncode}): {proc.stderr[-2000:]}")
    meta = json.loads((out / "session.json").read_text())
    return {"command": " ".join(cmd[1:]), "wall_s": round(time.perf_counter() - t, 1),
            "displayed_frames": meta["summary"]["displayed_frames"] if "summary" in meta else None,
            "render": meta.get("render")}


def timed_replay(session: Path, out: Path) -> dict:
    """replay_session(quality="live") with its start and frame loop timed apart."""
    from holo_viewer.live import replay as R

    marks: list[tuple[float, float]] = []  # (wall, process CPU) when each frame was handed to the writer
    real = R.replay_timed_frames

    def timed(*args, **kwargs):
        for item in real(*args, **kwargs):
            marks.append((time.perf_counter(), time.process_time()))
            yield item

    load0 = os.getloadavg()
    ch0 = _children_cpu()
    w0, c0 = time.perf_counter(), time.process_time()
    R.replay_timed_frames = timed
    try:
        n = R.replay_session(session, out, quality="live")
    finally:
        R.replay_timed_frames = real
    w1, c1 = time.perf_counter(), time.process_time()
    ch1 = _children_cpu()
    loop_wall = w1 - marks[0][0]  # frame 1 rendered -> the video closed (frames 2..n, the last write, the check)
    loop_cpu = c1 - marks[0][1]
    return {"frames": n, "start_s": round(marks[0][0] - w0, 2), "start_cpu_s": round(marks[0][1] - c0, 2),
            "loop_wall_s": round(loop_wall, 2), "fps": round((n - 1) / loop_wall, 2),
            "cpu_s_per_frame": round(loop_cpu / max(n - 1, 1), 3),
            "ffmpeg_cpu_s_per_frame": round((ch1 - ch0) / n, 3), "total_s": round(w1 - w0, 2),
            "load_start": [round(x, 2) for x in load0], "load_end": [round(x, 2) for x in os.getloadavg()]}


def render_only(session: Path) -> dict:
    """The baseline: the same render calls, no video."""
    from holo_viewer.live.replay import replay_timed_frames

    load0 = os.getloadavg()
    marks = [(time.perf_counter(), time.process_time()) for _ in replay_timed_frames(session)]
    n = len(marks)
    wall, cpu = marks[-1][0] - marks[0][0], marks[-1][1] - marks[0][1]
    return {"frames": n, "fps": round((n - 1) / wall, 2), "cpu_s_per_frame": round(cpu / max(n - 1, 1), 3),
            "load_start": [round(x, 2) for x in load0], "load_end": [round(x, 2) for x in os.getloadavg()]}


def compare(a: Path, b: Path) -> dict:
    from holo_viewer.media import read_frames

    fa, fb = list(read_frames(a)), list(read_frames(b))
    same = sum(np.array_equal(x, y) for x, y in zip(fa, fb))
    diff = max((int(np.abs(x.astype(np.int16) - y).max()) for x, y in zip(fa, fb)), default=None)
    return {"frames_recorded": len(fa), "frames_replayed": len(fb), "identical": int(same), "max_diff": diff,
            "bit_exact": len(fa) == len(fb) == same}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="length of the recorded synthetic session")
    ap.add_argument("--json", default="bench/results/replay_speed.json")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "session"
        rec = record(session, args.seconds)
        rep = timed_replay(session, Path(tmp) / "replay.mkv")
        err = compare(session / "native.mkv", Path(tmp) / "replay.mkv")
        base = render_only(session)
    ratio = round(rep["fps"] / base["fps"], 2) if base["fps"] else None
    print(f"\nreplay --quality live, a {args.seconds:g} s synthetic session ({rep['frames']} displayed frames, "
          f"{os.cpu_count()} cores)")
    print(f"{'':26s} {'frames/s':>9s} {'CPU s/frame':>12s} {'ffmpeg CPU s/frame':>19s} {'load (1, 5 min)':>16s}")
    print(f"{'replay (frame loop)':26s} {rep['fps']:9.2f} {rep['cpu_s_per_frame']:12.3f} "
          f"{rep['ffmpeg_cpu_s_per_frame']:19.3f} {str(rep['load_start'][:2]):>16s}")
    print(f"{'render only (baseline)':26s} {base['fps']:9.2f} {base['cpu_s_per_frame']:12.3f} {'-':>19s} "
          f"{str(base['load_start'][:2]):>16s}")
    print(f"ratio replay / render only: {ratio}; start (read, build, warm) {rep['start_s']} s "
          f"({rep['start_cpu_s']} s CPU); whole replay {rep['total_s']} s; bit-exact against native.mkv: "
          f"{err['bit_exact']} ({err['identical']}/{err['frames_recorded']} frames, max diff {err['max_diff']})")
    result = {"config": vars(args), "cores": os.cpu_count(), "recording": rec, "replay": rep, "render_only": base,
              "ratio_replay_to_render_only": ratio, "error": err, "target_fps": 4.0}
    from holo_viewer.fileio import write_json

    write_json(args.json, result)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
