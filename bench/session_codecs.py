"""Lossless session video: size and encoder CPU of codecs and of a view re-layout, on real native frames.

One command: records a synthetic live session in a child process (``holo-viewer live --synthetic
--headless``, the live defaults: group frames, full-size 2048x1536 native images), or takes
``--session DIR`` (e.g. a ``live --audio --video`` session as ``bench/live_latency.py`` records one);
then encodes its displayed native frames, at the times they were shown, with each candidate through
:class:`holo_viewer.media.VideoWriter` (timed Matroska, as ``native.mkv``, one encoder thread as the
session), in ``--repeats`` rounds alternating the candidates, and reports per candidate: MB per frame,
MB per minute at 1, 2.5, 4 and 10 displayed frames/s, ffmpeg's CPU ms per frame (median of the rounds;
encode + the frame count), the CPU of the re-layout in this process, whether it decodes bit-exact (a
re-laid candidate after the inverse permutation), and the size and CPU ratios to the policy today
(libx264rgb ultrafast crf 0, one thread: the baseline, measured in the same rounds).

The **view re-layout** candidates (issue 37) permute the native image's subpixels losslessly before
encoding: each view's subpixels together, from the calibration's lens model
(:func:`holo_viewer.display.lenticular.reference_views`), sorted by (channel, view, block of
``--block-rows`` native rows, column, row), each (view, block) segment padded to the longest with its
last value; channel c of the re-laid image holds channel c's subpixels. Each view's segment of a block
row is then that view's image at about its tile's resolution (``--png`` writes one), so the encoder
sees quilt-like content instead of neighbouring subpixels of different views. The bench times the
permutation (a serial numba gather, as a live process would run it) and inverts it for the check.

``--live PAIRS`` instead runs live sessions as ``bench/live_latency.py`` does (its ``run_session``: replayed speech
+ webcam, group frames at tile scale 0.5, recording on), alternating the ``--live-candidates`` (the session video's
codec and flags swapped in for the run: ``media.CODECS["lossless"]``), and reports per run
the displayed fps, the session's CPU ms per displayed frame, the encoder's (``ffmpeg encoder``) and MB per frame.

    python bench/session_codecs.py [--seconds 12] [--session DIR] [--repeats 2] [--json bench/results/session_codecs.json]
    python bench/session_codecs.py --live 2 --json bench/results/session_codecs_live.json
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

from holo_viewer.media import CODECS as _POLICY  # noqa: E402

_FAST = _POLICY["lossless-fast"]  # live --native-codec ffvhuff
_X264 = ["-preset", "ultrafast", "-crf", "0", "-threads", "1"]
_HUFF = ["-threads", "1", "-pred"]
#: name -> VideoWriter keywords (codec, pixel format, output flags) and whether the frames are re-laid
CANDIDATES = {
    "x264rgb ultrafast (today)": {"codec": "libx264rgb", "pixelformat": "rgb24", "output_params": _X264},
    "x264rgb superfast": {"codec": "libx264rgb", "pixelformat": "rgb24",
                          "output_params": ["-preset", "superfast", "-crf", "0", "-threads", "1"]},
    "ffvhuff left": {"codec": "ffvhuff", "pixelformat": "rgb24", "output_params": [*_HUFF, "left"]},
    "ffvhuff plane (--native-codec ffvhuff)": {"codec": _FAST["codec"], "pixelformat": _FAST["pixelformat"],
                                               "output_params": ["-threads", "1", *_FAST["output_params"]]},
    "ffvhuff plane + frame tables": {"codec": "ffvhuff", "pixelformat": "rgb24",
                                        "output_params": [*_HUFF, "plane", "-context", "1"]},
    "utvideo median": {"codec": "utvideo", "pixelformat": "gbrp", "output_params": [*_HUFF, "median"]},
    "ffv1 level 3": {"codec": "ffv1", "pixelformat": "bgr0",
                     "output_params": ["-level", "3", "-g", "1", "-slices", "4", "-threads", "1"]},
    "re-laid views + x264rgb ultrafast": {"codec": "libx264rgb", "pixelformat": "rgb24", "output_params": _X264,
                                          "relaid": True},
    "re-laid views + ffvhuff plane": {"codec": "ffvhuff", "pixelformat": "rgb24", "output_params": [*_HUFF, "plane"],
                                      "relaid": True},
    "re-laid views + utvideo median": {"codec": "utvideo", "pixelformat": "gbrp",
                                       "output_params": [*_HUFF, "median"], "relaid": True},
}
BASELINE = "x264rgb ultrafast (today)"


def view_layout(view: np.ndarray, n_views: int, block_rows: int) -> np.ndarray:
    """Flat gather indices (B, n_views * M, 3) uint32 into an (H, W, 3) native image: channel c of
    output row b holds channel c's subpixels of view 0, 1, ... in native rows ``b * block_rows`` on,
    each view's sorted by (column, row) and padded to ``M`` with its last one. ``view``: (H, W, 3)
    view index of each subpixel. A permutation of every subpixel plus padding (checked)."""
    H, W, _ = view.shape
    B = -(-H // block_rows)
    rr, cc = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    per_channel = []
    for ch in range(3):
        v = view[:, :, ch].astype(np.int64)
        group = v * B + rr // block_rows
        order = np.argsort(((group * W + cc) * block_rows + rr % block_rows).ravel(), kind="stable")
        per_channel.append((order, np.bincount(group.ravel(), minlength=n_views * B).reshape(n_views, B)))
    M = max(int(cnt.max()) for _, cnt in per_channel)
    idx = np.empty((B, n_views * M, 3), np.uint32)
    for ch, (order, cnt) in enumerate(per_channel):
        start = np.concatenate([[0], np.cumsum(cnt.ravel())])[:-1].reshape(n_views, B)
        pos = start[:, :, None] + np.minimum(np.arange(M)[None, None, :], np.maximum(cnt, 1)[:, :, None] - 1)
        idx[:, :, ch] = (order[pos] * 3 + ch).transpose(1, 0, 2).reshape(B, n_views * M)
    seen = np.zeros(H * W * 3, bool)
    seen[idx.ravel()] = True
    assert seen.all(), "the layout misses subpixels"
    return idx


def _gather():
    import numba

    @numba.njit(nogil=True, cache=False)
    def gather(src, idx, out):  # pragma: no cover - compiled
        for i in range(idx.shape[0]):
            out[i] = src[idx[i]]

    return gather


def live_pairs(pairs: int, names: list[str], clip_seconds: float, cache: str) -> dict:
    """``pairs`` rounds of live sessions, one per candidate in ``names`` (alternating), recording on."""
    import live_latency as bench_live  # bench/live_latency.py (its clip and run_session)

    from holo_viewer import media
    from holo_viewer.live import loop
    from holo_viewer.pipeline.live_support import write_talking_head_clip

    clip = Path(cache) / f"clip_{clip_seconds:g}s"
    files = {"wav": clip / "speaker.wav", "video": clip / "speaker.mp4"}
    if not all(p.exists() for p in files.values()):
        write_talking_head_clip(clip, seconds=clip_seconds, n_gaussians=30_000)
    saved = media.CODECS["lossless"], loop.SESSION_VIDEO_PARAMS
    runs: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(pairs):
            for name in names:
                kw = CANDIDATES[name]
                if kw.get("relaid"):
                    raise SystemExit(f"--live-candidates: {name!r} is a re-layout (not a session codec)")
                # the session video's writer takes the codec, pixel format and flags of media.CODECS["lossless"]
                # (+ "-threads 1", which the candidates have already)
                media.CODECS["lossless"] = {"codec": kw["codec"], "pixelformat": kw["pixelformat"], "quality": None,
                                            "macro_block_size": 1, "output_params": tuple(kw["output_params"])}
                loop.SESSION_VIDEO_PARAMS = tuple(kw["output_params"])
                out = Path(tmp) / f"s{rep}_{len(runs)}"
                try:
                    r = bench_live.run_session(files, out, render=True, tile_scale=0.5, record=True)
                finally:
                    media.CODECS["lossless"], loop.SESSION_VIDEO_PARAMS = saved
                if kw["codec"] == "libx264rgb":  # x264 states its settings in the stream: lossless (qp 0), as asked
                    import re

                    with open(out / "native.mkv", "rb") as fh:
                        head = fh.read(1 << 20)
                    assert b"rc=cqp" in head and re.search(rb" qp=0\b", head), f"{name}: the session video is not lossless"
                ins = r.get("in_session", {})
                by = ins.get("cpu_ms_per_displayed_frame_by_thread", {})
                row = {"candidate": name, "round": rep, "displayed_fps": r.get("displayed_fps"),
                       "displayed_frames": r.get("displayed_frames"),
                       "load_1min": [r.get("load_1min_start"), r.get("load_1min_end")],
                       "cores_used": ins.get("cores_used"),
                       "cpu_ms_per_displayed_frame": ins.get("cpu_ms_per_displayed_frame"),
                       "encoder_cpu_ms_per_displayed_frame": by.get("ffmpeg encoder"),
                       "video_writer_cpu_ms_per_displayed_frame": by.get("video-writer"),
                       "mb_per_frame": round((out / "native.mkv").stat().st_size / 1e6 / max(r["displayed_frames"], 1), 3),
                       "by_thread": by}
                print(f"{name:30s} round {rep}: {row['displayed_fps']} fps, {row['cpu_ms_per_displayed_frame']} ms CPU a "
                      f"displayed frame, encoder {row['encoder_cpu_ms_per_displayed_frame']} ms, "
                      f"{row['mb_per_frame']} MB a frame, load {row['load_1min']}", flush=True)
                runs.append(row)
    summary = {}
    for name in names:
        rs = [r for r in runs if r["candidate"] == name]
        med = lambda k: round(float(np.median([r[k] for r in rs if r[k] is not None])), 1)  # noqa: E731
        summary[name] = {k: med(k) for k in ("displayed_fps", "cpu_ms_per_displayed_frame",
                                              "encoder_cpu_ms_per_displayed_frame", "mb_per_frame")}
    return {"runs": runs, "median": summary}


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=12.0, help="length of the recorded synthetic session")
    ap.add_argument("--session", default=None, help="a recorded session folder instead")
    ap.add_argument("--repeats", type=int, default=2, help="rounds, each encoding every candidate once (alternating)")
    ap.add_argument("--block-rows", type=int, default=8, help="native rows per block row of the re-layout")
    ap.add_argument("--only", default=None, help="';'-separated candidate names (default: all)")
    ap.add_argument("--png", default=None, help="write the first re-laid frame's first 4 views here")
    ap.add_argument("--live", type=int, default=0, metavar="PAIRS",
                    help="instead: PAIRS rounds of live sessions alternating --live-candidates (recording on)")
    ap.add_argument("--live-candidates", default=f"{BASELINE};ffvhuff plane (--native-codec ffvhuff);ffvhuff left", help="';'-separated candidate names")
    ap.add_argument("--clip-seconds", type=float, default=8.0, help="--live: the replayed clip (bench/live_latency.py's)")
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "holo_viewer_live_bench"),
                    help="--live: bench/live_latency.py's clip cache")
    ap.add_argument("--json", default="bench/results/session_codecs.json")
    args = ap.parse_args()
    if args.live:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        names = [n.strip() for n in args.live_candidates.split(";")]
        res = live_pairs(args.live, names, args.clip_seconds, args.cache)
        for name, m in res["median"].items():
            print(f"median {name:30s} {m}")
        from holo_viewer.fileio import write_json

        write_json(args.json, {"config": vars(args), "cores": os.cpu_count(),
                               "candidates": {n: CANDIDATES[n] for n in names}, **res})
        print(f"wrote {args.json}")
        return 0
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.display.lenticular import reference_views
    from holo_viewer.media import VideoWriter, read_frames

    names = [n.strip() for n in args.only.split(";")] if args.only else list(CANDIDATES)
    if BASELINE not in names:
        names.insert(0, BASELINE)
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(args.session) if args.session else Path(tmp) / "session"
        if not args.session:
            subprocess.run([sys.executable, "-m", "holo_viewer", "live", "--synthetic", "--seconds", f"{args.seconds:g}",
                            "--headless", "--out", str(session)], check=True, capture_output=True)
        with np.load(session / "tracks.npz") as z:
            times = z["display_time_s"].astype(float)
        frames = list(read_frames(session / "native.mkv"))
        assert len(frames) == len(times), (len(frames), len(times))
        H, W = frames[0].shape[:2]
        cal = DisplayCalibration.load(None)  # the live sessions' panel
        view = reference_views(cal, cal.n_views)[0]
        idx = view_layout(view, cal.n_views, args.block_rows)
        flat = idx.ravel()
        gather = _gather()
        relaid = [np.empty(idx.shape, np.uint8) for _ in frames]
        gather(frames[0].reshape(-1), flat, relaid[0].reshape(-1))  # compile
        c0 = time.process_time()
        for f, r in zip(frames, relaid):
            gather(f.reshape(-1), flat, r.reshape(-1))
        relayout_ms = 1000 * (time.process_time() - c0) / len(frames)
        if args.png:
            from PIL import Image

            Image.fromarray(relaid[0][:, :4 * (idx.shape[1] // cal.n_views)]).save(args.png)

        def unlay(r: np.ndarray) -> np.ndarray:
            out = np.empty(H * W * 3, np.uint8)
            out[flat] = r.reshape(-1)  # padding repeats a real subpixel's value: the same write
            return out.reshape(H, W, 3)

        cpu: dict[str, list[float]] = {n: [] for n in names}
        rows = {}
        for rep in range(args.repeats):
            for name in names:
                kw = dict(CANDIDATES[name])
                lay = kw.pop("relaid", False)
                src = relaid if lay else frames
                out = Path(tmp) / "c.mkv"
                load = os.getloadavg()[0]
                c0, w0 = _children_cpu(), time.perf_counter()
                with VideoWriter(out, 10.0, timed=True, what="codec test", **kw) as w:
                    for f, t in zip(src, times):
                        w.write(f, t=float(t))
                cpu[name].append(_children_cpu() - c0)
                if rep == 0:
                    size = out.stat().st_size
                    exact = all(np.array_equal(a, unlay(b) if lay else b) for a, b in zip(frames, read_frames(out)))
                    mb = size / 1e6 / len(frames)
                    rows[name] = {"mb_per_frame": round(mb, 3), **{f"mb_per_min_at_{r:g}fps": round(mb * r * 60, 1)
                                                                   for r in (1, 2.5, 4, 10)},
                                  "bit_exact": bool(exact), "relaid": bool(lay),
                                  "relayout_cpu_ms_per_frame": round(relayout_ms, 2) if lay else 0.0,
                                  "wall_s": round(time.perf_counter() - w0, 2), "load_1min": [round(load, 2)]}
                else:
                    rows[name]["load_1min"].append(round(load, 2))
                out.unlink()
    base_mb = rows[BASELINE]["mb_per_frame"]
    for name, r in rows.items():
        r["ffmpeg_cpu_ms_per_frame_rounds"] = [round(1000 * c / len(frames), 1) for c in cpu[name]]
        r["ffmpeg_cpu_ms_per_frame"] = round(float(np.median(r["ffmpeg_cpu_ms_per_frame_rounds"])), 1)
    base_ms = rows[BASELINE]["ffmpeg_cpu_ms_per_frame"]
    for r in rows.values():
        r["size_ratio_to_today"] = round(r["mb_per_frame"] / base_mb, 3)
        r["cpu_saved_ms_per_frame"] = round(base_ms - r["ffmpeg_cpu_ms_per_frame"] - r["relayout_cpu_ms_per_frame"], 1)
    print(f"\nlossless session video, {len(frames)} displayed {W}x{H} native frames ({H * W * 3 / 1e6:.1f} MB raw "
          f"each), {os.cpu_count()} cores, {args.repeats} rounds; re-layout {args.block_rows}-row blocks "
          f"{idx.shape[1]}x{idx.shape[0]}, its gather {relayout_ms:.1f} ms of CPU a frame")
    print(f"{'':38s} {'MB/frame':>9s} {'@2.5fps MB/min':>15s} {'@10':>7s} {'ffmpeg CPU ms':>14s} {'+layout':>8s} "
          f"{'saved ms':>9s} {'exact':>6s} {'size':>6s} {'load':>5s}")
    for name, r in rows.items():
        print(f"{name:38s} {r['mb_per_frame']:9.3f} {r['mb_per_min_at_2.5fps']:15.1f} {r['mb_per_min_at_10fps']:7.1f} "
              f"{r['ffmpeg_cpu_ms_per_frame']:14.1f} {r['relayout_cpu_ms_per_frame']:8.1f} "
              f"{r['cpu_saved_ms_per_frame']:9.1f} {str(r['bit_exact']):>6s} {r['size_ratio_to_today']:6.3f} "
              f"{max(r['load_1min']):5.1f}")
    result = {"config": {**vars(args), "session": args.session or f"a {args.seconds:g} s synthetic session"},
              "cores": os.cpu_count(), "frames": len(frames), "size": [W, H],
              "relayout": {"block_rows": args.block_rows, "shape": list(idx.shape),
                           "gather_cpu_ms_per_frame": round(relayout_ms, 2)},
              "candidates": CANDIDATES, "results": rows}
    from holo_viewer.fileio import write_json

    write_json(args.json, result)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
