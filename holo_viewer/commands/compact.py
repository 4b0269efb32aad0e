"""``holo-viewer compact``: shrink finished sessions' ``native.mkv`` from FFVHuff to x264 (issue 37).

``live --native-codec ffvhuff`` records the session video for less CPU a frame than x264rgb crf 0 at ~1.9x
the disk; ``compact`` wins the disk back offline, when the CPU is free: it re-encodes ``native.mkv`` to the
lossless policy (:data:`holo_viewer.media.CODECS` ``"lossless"``, libx264rgb crf 0, all threads), keeping
every frame's timestamp and duration (the timed Matroska's packets: ffmpeg ``-copyts``, passthrough, a
1 ms time base), then checks the copy against the original before it replaces it:

* the same packets' times: every frame's dts, pts and duration (a stream copy, no decoding),
* the same frames, bit-exact, frame by frame (:func:`holo_viewer.media.read_frames` of both).

Only then the copy is renamed over the original (temp + rename, :func:`holo_viewer.fileio.atomic_path`)
and ``session.json`` gains a ``compacted`` record (codecs and sizes before and after). Anything else
(ffmpeg failing, a decoding error in the original, another frame count, another time, another pixel)
leaves the original untouched and names the file and the first differing frame. A session already in
x264 is left as it is. A session still being written (its writer holds the lock on a temporary in the
folder, ``.native.XXXXXXXX.tmp.mkv``) is refused.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

__all__ = ["add_arguments", "run", "compact_session", "session_busy"]

#: ffmpeg's decoder name of each session-video codec -> what session.json records
_CODEC_NAMES = {"ffvhuff": "ffvhuff", "h264": "libx264rgb crf 0"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``compact``."""
    parser.add_argument("sessions", nargs="+", metavar="SESSION", help="session folders written by `holo-viewer "
                        "live` (native.mkv in FFVHuff: re-encoded to x264rgb crf 0, verified bit-exact, replaced)")
    parser.add_argument("--threads", type=int, default=0, metavar="N",
                        help="ffmpeg threads (default 0: all cores; compaction runs offline)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    """Compact each session in turn; returns 0, or 1 if any failed (each failure is printed, the rest go on)."""
    failed = 0
    for folder in args.sessions:
        try:
            rec = compact_session(folder, threads=args.threads, progress=not args.no_progress)
        except Exception as exc:  # noqa: BLE001 - reported per session, the others still run
            from ..errors import HoloViewerError

            if not isinstance(exc, HoloViewerError):
                raise
            print(f"holo-viewer compact: error: {exc}", file=sys.stderr)
            failed += 1
            continue
        if rec.get("skipped"):
            print(f"{folder}: {rec['skipped']}; left as it is")
        else:
            print(f"{folder}: native.mkv {rec['codec_before']} -> {rec['codec_after']}: {rec['bytes_before'] / 1e6:.1f} "
                  f"-> {rec['bytes_after'] / 1e6:.1f} MB ({rec['bytes_after'] / rec['bytes_before']:.2f}x), "
                  f"{rec['frames']} frames verified bit-exact, {rec['cpu_s']:.1f} s CPU"
                  + (f" ({rec['cpu_s_per_session_minute']:.0f} s a session minute)"
                     if rec["cpu_s_per_session_minute"] is not None else ""))
    return 1 if failed else 0


def session_busy(folder: Path) -> list[Path]:
    """Temporaries in ``folder`` whose writer is alive (holds their lock): the live writer's ``native.mkv``,
    ``session.json`` or ``tracks.npz`` (or another ``compact``) while the session is being written."""
    from ..fileio import _try_lock

    pattern = re.compile(r"\.[^/]+\.[A-Za-z0-9_]{8}\.tmp\.\w+")
    busy = []
    for name in sorted(os.listdir(folder)):
        if not pattern.fullmatch(name):
            continue
        try:
            fd = os.open(folder / name, os.O_RDONLY)
        except OSError:
            continue  # gone meanwhile (renamed into place)
        try:
            if not _try_lock(fd):
                busy.append(folder / name)
        finally:
            os.close(fd)
    return busy


def video_codec(path: Path) -> str:
    """The codec ffmpeg names for the first video stream of ``path`` (``ffvhuff``, ``h264``, ...)."""
    from .. import media
    from ..errors import InputError

    err = subprocess.run([media.ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", os.fspath(path)],
                         capture_output=True, text=True, errors="replace").stderr
    m = re.search(r"Stream #\S+: Video: (\w+)", err)
    if m is None:
        last = (err.strip().splitlines() or ["no message"])[-1][:300]
        raise InputError(f"{path}: expected a video, found none ({last})")
    return m.group(1)


def packet_times(path: Path) -> tuple[str, list[tuple[int, int, int]]]:
    """(time base, [(dts, pts, duration)] of each video packet) of ``path``, by a stream copy (no decoding)."""
    from .. import media
    from ..errors import InputError

    proc = subprocess.run([media.ffmpeg_exe(), "-hide_banner", "-nostdin", "-loglevel", "error", "-copyts", "-i",
                           os.fspath(path), "-map", "0:v:0", "-c", "copy", "-f", "framecrc", "-"],
                          capture_output=True, text=True, errors="replace")
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1][:300]
        raise InputError(f"{path}: cannot read the video's packets ({last})")
    tb = next((ln.split(":", 1)[1].strip() for ln in proc.stdout.splitlines() if ln.startswith("#tb 0")), "?")
    rows = []
    for ln in proc.stdout.splitlines():
        if ln and not ln.startswith("#"):
            f = [x.strip() for x in ln.split(",")]
            rows.append((int(f[1]), int(f[2]), int(f[3])))
    return tb, rows


def compact_session(folder: str | os.PathLike, *, threads: int = 0, progress: bool = False) -> dict[str, Any]:
    """Re-encode a finished session's FFVHuff ``native.mkv`` to x264rgb crf 0, verify, replace (module doc).

    Returns the record added to ``session.json`` (``compacted``), or ``{"skipped": why}`` for a video
    already in x264.

    Raises
    ------
    InputError
        Not a folder, not a session, a session still being written, no ``native.mkv``, another codec.
    ExportError
        ffmpeg failed, or the copy differs from the original (the file and the first differing frame are
        named); the original is unchanged.
    """
    import numpy as np
    from tqdm import tqdm

    from .. import media
    from ..errors import ExportError, InputError
    from ..fileio import atomic_path, atomic_write, read_json
    from ..live.session import NATIVE_VIDEO, load_session

    p = Path(folder)
    if not p.exists():
        raise InputError(f"{p}: no such session folder")
    if not p.is_dir():
        raise InputError(f"{p}: expected a session folder, found a file")
    busy = session_busy(p)
    if busy:
        raise InputError(f"{p}: the session is still being written ({busy[0].name} is held by its writer); "
                         f"compact it after the session has ended")
    meta, _ = load_session(p)  # a session folder (session.json, tracks.npz), readable
    ended = meta.get("end_s") is not None  # set when the live loop ends, before the video is closed
    video = p / NATIVE_VIDEO
    if not video.is_file():
        raise InputError(f"{video}: expected the session video, found no file (" + (
            "recorded without it)" if ended else "session.json has no end_s: the session is still starting or was "
            "killed before its end)"))
    codec = video_codec(video)
    if codec == "h264":
        return {"skipped": "native.mkv is already x264 (lossless, the small one)"}
    if codec != "ffvhuff":
        raise InputError(f"{video}: expected an FFVHuff (or x264) session video, found {codec}")
    if not ended:  # the live loop writes session.json once more after it renames native.mkv into place
        raise InputError(f"{p / 'session.json'}: end_s: expected the session's end, found none (the session is "
                         f"still being written); compact it after the session has ended")
    tb, times = packet_times(video)
    n = len(times)
    before = video.stat().st_size
    policy = media.CODECS["lossless"]
    t0 = time.process_time()
    cpu0 = os.times()
    with atomic_path(video) as tmp:
        # -xerror: a decoding error in the original stops ffmpeg instead of dropping or concealing a frame
        cmd = [media.ffmpeg_exe(), "-hide_banner", "-nostdin", "-loglevel", "error", "-xerror", "-y", "-copyts",
               "-i", os.fspath(video), "-map", "0:v:0", "-fps_mode", "passthrough", "-enc_time_base", "1:1000",
               "-an", "-c:v", policy["codec"], "-pix_fmt", policy["pixelformat"], *policy["output_params"],
               "-threads", str(int(threads)), *_extra_output_params(), "-progress", "pipe:1", "-nostats",
               "-f", "matroska", os.fspath(tmp)]
        bar = tqdm(total=n, disable=not progress, desc=f"compact {p.name}", unit="frame")
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace")
        done = 0
        assert proc.stdout is not None and proc.stderr is not None
        for line in proc.stdout:
            if line.startswith("frame="):
                k = int(line.split("=", 1)[1].strip() or 0)
                bar.update(k - done)
                done = k
        err = proc.stderr.read()
        code = proc.wait()
        bar.close()
        if code != 0:
            last = (err.strip().splitlines() or ["no message"])[-1][:300]
            raise ExportError(f"{video}: cannot compact the session video: ffmpeg exited with status {code} ({last}); "
                              f"the original is unchanged")
        tb2, times2 = packet_times(tmp)
        if len(times2) != n:
            raise ExportError(f"{video}: the compacted copy holds {len(times2)} frames, the original {n}; "
                              f"the original is unchanged")
        if tb2 != tb:
            raise ExportError(f"{video}: the compacted copy's time base is {tb2}, the original's {tb}; "
                              f"the original is unchanged")
        for i, (a, b) in enumerate(zip(times, times2)):
            if a != b:
                raise ExportError(f"{video}: frame {i}: the compacted copy's (dts, pts, duration) {b} differ from the "
                                  f"original's {a} (time base {tb}); the original is unchanged")
        bar = tqdm(total=n, disable=not progress, desc=f"verify {p.name}", unit="frame")
        old, new = media.read_frames(video), media.read_frames(tmp)
        i = 0
        try:
            for i in range(n + 1):
                a, b = next(old, None), next(new, None)
                if a is None and b is None:
                    break
                if a is None or b is None:
                    raise ExportError(f"{video}: frame {i}: {'the original' if a is None else 'the compacted copy'} "
                                      f"ends there (decoded frames); the original is unchanged")
                if not np.array_equal(a, b):
                    diff = np.argwhere(np.any(a != b, axis=2))
                    raise ExportError(f"{video}: frame {i}: the compacted copy differs from the original in "
                                      f"{len(diff)} pixels (first at row {diff[0][0]}, column {diff[0][1]}); "
                                      f"the original is unchanged")
                bar.update(1)
        finally:
            old.close()
            new.close()
            bar.close()
        if i != n:
            raise ExportError(f"{video}: {i} frames decoded of {n} packets; the original is unchanged")
        after = tmp.stat().st_size
    cpu1 = os.times()
    cpu_s = (time.process_time() - t0) + (cpu1.children_user - cpu0.children_user) + (
        cpu1.children_system - cpu0.children_system)
    meta = read_json(p / "session.json", InputError, "session metadata")
    end_s = meta.get("end_s")
    rec = {"codec_before": _CODEC_NAMES[codec], "codec_after": _CODEC_NAMES["h264"], "bytes_before": int(before),
           "bytes_after": int(after), "frames": n, "verified": "bit-exact, same packet times",
           "cpu_s": round(cpu_s, 2),
           "cpu_s_per_session_minute": round(60 * cpu_s / end_s, 1) if isinstance(end_s, (int, float)) and end_s > 0
           else None, "at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    meta["compacted"] = rec
    with atomic_write(p / "session.json", "w") as fh:
        json.dump(meta, fh, indent=2)
    return rec


def _extra_output_params() -> list[str]:
    """More ffmpeg output flags of the re-encode (none; a test adds a filter that changes a frame)."""
    return []
