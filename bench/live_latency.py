"""Live session latency on replayed inputs: speech onset -> first displayed frame reflecting it.

Renders (once, cached) a clip of the default head speaking (wav + mp4 from the synthetic speaker),
then replays it through ``LiveSession`` twice in one process:

* ``no-render``: tracker + reaction threads only (the baseline: what the stream costs alone);
* ``render``: the same plus the renderer at ``--tile-scale`` (today's fast CPU path) in the main thread,
  recording the native video as ``live`` does; then ``render_warm``: the same again in this process.

With rendering, also (issue 37): ``displayed_fps`` (displayed frames over the session's media time,
recording on, with the load average at start and end), ``visible_change_ms`` (onset to the first
displayed frame at or after the reflecting one whose native image changed by > 0.5 levels RMS
from the frame before), ``first_frame_s`` (renderer built + session started -> first frame handed
to the loop; cold in the first run, warm in the second: kernels and imports loaded, the renderer's
tables built again) and ``quit_s`` (last frame -> the session's
``run`` returned: flush and joins), and the CPU seconds of the session's process and of its ffmpeg
children (the session video's encoder, run nicer than the session on one thread, and its check
at close), also per displayed frame; ``frames_in_flight`` (the loop's renderers at once, ``holo_viewer.live.
inflight``), ``twins_ready_s`` (when the second renderer joined, after the start-up's warm-up frame) and
``display_interval_ms`` (wall time between frames shown; a frame in flight renders longer than that); ``in_session``: the same split by thread and child (main thread,
the render's native workers (numba's OpenMP worker), tracker, reaction, video writer, ffmpeg encoder and the replayed
webcam's decoder; the C++ kernels' per-call worker threads by kernel, :class:`KernelWorkers`, each counted once:
``kernel_workers_counted_twice_ms``, 0 since 2026-11-29, checks it) from the second displayed
frame to the last, start-up excluded (:class:`ThreadCPU`), ``cpp_kernels_per_displayed_frame`` (each C++ kernel's
calls and CPU a frame, its workers' and its caller's), and its
``timeline``: the cores each kept busy during the render calls and between them, and the idle ones
(:func:`busy_timeline`); ``render_call_main_thread``: each render call's wall time on the main thread
split into on a CPU, waiting for one and blocked (the GIL, the render's workers; :class:`SchedTimes`).
``--ab`` runs one frame in flight (``ab_before``) and two in flight (``ab_after``), one after the other.

Reported per run: speech-onset -> display latency (median, p95; an onset is the first 25 fps frame
whose RMS exceeds -35 dBFS after >= 0.3 s below it; a displayed frame reflects it when the reaction
window that predicted the frame had seen the onset frame), tracker ms/frame, reaction ms/window,
render ms/frame, late reaction windows (finished after their first frame was due = dropped), and
25 fps frames never displayed. ``--rss-seconds S`` adds a synthetic session of S seconds without
rendering that samples the process RSS (the 10-minute memory check: ``--rss-seconds 600``).

    python bench/live_latency.py [--seconds 8] [--tile-scale 1.0] [--render-mode auto] [--json bench/results/live_latency.json]
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def speech_onsets(wave: np.ndarray, fps: int = 25, sr: int = 16000, thresh_db: float = -35.0,
                  min_gap_s: float = 0.3) -> list[int]:
    hop = sr // fps
    n = len(wave) // hop
    rms = np.sqrt(np.mean(wave[: n * hop].reshape(n, hop).astype(np.float64) ** 2, axis=1) + 1e-12)
    loud = 20 * np.log10(rms) > thresh_db
    gap = int(min_gap_s * fps)
    return [t for t in range(gap, n) if loud[t] and not loud[t - gap:t].any()]


def onset_latency(tracks: dict, onsets: list[int], k: int) -> list[float]:
    """Seconds from each onset frame's time to the first displayed frame whose window saw it."""
    disp_t = tracks["display_time_s"]
    disp_f = tracks["display_frame"]
    out = []
    for o in onsets:
        ok = (disp_f // k) * k - 1 >= o
        if ok.any():
            out.append(float(disp_t[np.argmax(ok)] - o / 25.0))
    return out


class ThreadCPU:
    """CPU seconds per thread of this process and per ffmpeg child, sampled from /proc every ``period`` s
    (Linux), so the CPU spent between two moments of a session can be split by who spent it: the main
    thread (the render's serial part and the loop), the render's native workers (OpenMP / numba: threads
    that are not Python threads), the tracker, the reaction thread, the video writer; children by their
    role (the session video's encoder, the replayed webcam's decoder); ``ended threads``: the process's own
    CPU (``CLOCK_PROCESS_CPUTIME_ID``; /proc/self/stat until 2026-11-29) that no sampled thread holds, i.e. the C++ kernels' workers, started per call
    and gone within milliseconds (until 2026-11-28 20:05 uncounted: ~40 ms a frame, "1.5 cores busy"); with
    :class:`KernelWorkers` (:func:`name_ended`) they are named by kernel and ``ended threads`` keeps the rest
    (0-0.6 ms a frame in live sessions: nothing else ends per frame). A kernel's worker that a sample catches
    alive is not a thread of its own (:meth:`mark_kernel_workers`): until 2026-11-29 07:00 its CPU up to that
    sample counted as "native workers" *and* in its kernel's workers, 15-21 ms a displayed frame twice."""

    def __init__(self, period: float = 0.2) -> None:
        self.period = period
        self.snaps: list[tuple[float, dict]] = []  # (perf_counter, {key: (name, cpu_s)})
        self.starts: list[float] = []  # perf_counter when each sample began reading (snaps[i][0]: when it ended)
        self.transient: set[int] = set()  # tids of the kernels' per-call workers (mark_kernel_workers)
        self._names: dict[int, str] = {}
        self._roles: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-sampler", daemon=True)
        self._tck = os.sysconf("SC_CLK_TCK")
        self._fds: dict[str, int] = {}  # /proc files kept open (_read)

    def _read(self, path: str) -> str | None:
        """A /proc file's text, its file kept open and re-read (``pread``) at the next sample: ~5x less CPU a
        sample than opening it each time (the sampler's thread took ~1.6 ms a displayed frame); None once
        the thread or process is gone."""
        fd = self._fds.get(path)
        try:
            if fd is None:
                fd = self._fds[path] = os.open(path, os.O_RDONLY)
            return os.pread(fd, 4096, 0).decode()
        except OSError:
            if path in self._fds:
                os.close(self._fds.pop(path))
            return None

    def _stat(self, path: str) -> tuple[str, float] | None:
        s = self._read(path)
        if not s:
            return None
        f = s[s.rindex(")") + 2:].split()
        return s[s.index("(") + 1:s.rindex(")")], int(f[11]) + int(f[12])

    def _child_role(self, pid: int) -> str:
        if pid in self._roles:  # read once: a child that has exited has no command line left to read
            return self._roles[pid]
        role = self._read_role(pid)
        if role != "child":  # "child": maybe read between its fork and its exec; read again next time
            self._roles[pid] = role
        return role

    def _read_role(self, pid: int) -> str:
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                cmd = fh.read().split(b"\0")
        except OSError:
            return "child"
        if b"-i" in cmd and cmd[cmd.index(b"-i") + 1:cmd.index(b"-i") + 2] == [b"-"]:
            return "ffmpeg encoder"
        if b"holo_viewer.tracking.dlib_worker" in cmd:  # LiveSessionConfig.tracker_process
            return "tracker process"
        return "ffmpeg decoder" if b"rawvideo" in cmd or b"image2pipe" in cmd else "child"

    def sample(self) -> None:
        for t in threading.enumerate():
            if t.native_id is not None:
                self._names[t.native_id] = t.name
        snap, children = {}, set()
        start = time.perf_counter()
        # the whole process (its threads, also those that ended: the C++ kernels start their workers per call,
        # threads that live a few ms and are never in a sample); between() names what the tasks miss
        # in ns (the process clock, each thread's schedstat): the 50 ms intervals of busy_timeline need more than
        # /proc's 10 ms clock ticks; the children (ffmpeg's threads together) in ticks, from their stat
        snap[0] = (PROCESS, time.clock_gettime_ns(time.CLOCK_PROCESS_CPUTIME_ID) / 1e9)
        for tid in os.listdir("/proc/self/task"):
            st = self._read(f"/proc/self/task/{tid}/schedstat")
            if not st:
                continue
            name = self._names.get(int(tid))
            snap[int(tid)] = (name or NATIVE, int(st.split()[0]) / 1e9)
            children.update(int(c) for c in (self._read(f"/proc/self/task/{tid}/children") or "").split())
        for pid in children:
            st = self._stat(f"/proc/{pid}/stat")
            if st is not None:
                snap[-pid] = (self._child_role(pid), st[1] / self._tck)
        self.starts.append(start)
        self.snaps.append((time.perf_counter(), snap))

    def mark_kernel_workers(self, calls: list[tuple[float, float]], max_life_s: float = 1.0) -> set[int]:
        """Mark as the kernels' per-call workers (:attr:`transient`, then left to :data:`ENDED`, which
        :func:`name_ended` names by kernel) the threads with no Python name first seen by a sample taken
        during a kernel call (``calls``: (perf_counter start, end), :attr:`KernelWorkers.calls`) and seen
        for less than ``max_life_s`` (a joined thread may linger in /proc a moment after its call). A
        thread that lives on (numba's or torch's OpenMP worker, OpenBLAS's) is seen for the whole session
        and keeps its name. Returns the marked tids."""
        seen: dict[int, list[int]] = {}
        for i, (_, snap) in enumerate(self.snaps):
            for key, (name, _) in snap.items():
                if key > 0 and name == NATIVE:
                    seen.setdefault(key, []).append(i)
        spans = sorted(calls)
        starts = [c for c, _ in spans]
        for tid, idx in seen.items():
            read0, read1 = self.starts[idx[0]], self.snaps[idx[0]][0]  # the first sighting's read
            if self.snaps[idx[-1]][0] - read0 >= max_life_s:
                continue
            k = bisect.bisect_left(starts, read1)  # calls begun before that read ended ...
            if any(end > read0 for _, end in spans[:k]):  # ... and ended after it began
                self.transient.add(tid)
        return set(self.transient)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.sample()
            self._stop.wait(self.period)

    def __enter__(self) -> "ThreadCPU":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        for fd in self._fds.values():
            os.close(fd)
        self._fds.clear()

    def nearest(self, t: float) -> int:
        """The index of the sample nearest ``t`` (perf_counter)."""
        return min(range(len(self.snaps)), key=lambda i: abs(self.snaps[i][0] - t))

    def between(self, t0: float, t1: float) -> tuple[float, dict[str, float]]:
        """(seconds between the samples nearest t0 and t1, CPU seconds per name spent between them); a
        thread or child that ended before t1 counts up to its last sample."""
        if len(self.snaps) < 2:
            return 0.0, {}
        a, b = self.nearest(t0), self.nearest(t1)
        last: dict = {}
        for _, snap in self.snaps[a:b + 1]:
            last.update(snap)
        return self.snaps[b][0] - self.snaps[a][0], _with_ended(self.snaps[a][1], last, self.transient)


NATIVE = "native workers"  # threads of the process that Python did not start, alive across kernel calls
PROCESS = "_process"  # the sampler's key 0: the process's own CPU (every thread it ran, ended ones too)
ENDED = "ended threads"  # the process's CPU that no sampled thread holds: threads born and ended between samples


def _with_ended(a: dict, b: dict, transient=frozenset()) -> dict[str, float]:
    """CPU seconds per name from snapshot ``a`` to ``b`` (a thread new in ``b`` counts from 0), and
    :data:`ENDED`: the process's own CPU over the same span less its sampled threads' (the C++ kernels'
    per-call workers, which live a few ms, are seen in no sample, or in one: ``transient``, their tids
    (:meth:`ThreadCPU.mark_kernel_workers`), stay in ENDED)."""
    out: dict[str, float] = {}
    for key, (name, cpu) in b.items():
        if key != 0 and key not in transient:
            out[name] = out.get(name, 0.0) + cpu - (a[key][1] if key in a else 0.0)
    if 0 in a and 0 in b:
        threads = sum(cpu - (a[key][1] if key in a else 0.0) for key, (_, cpu) in b.items()
                      if key > 0 and key not in transient)
        out[ENDED] = max(0.0, b[0][1] - a[0][1] - threads)
    return out


#: the compiled kernels whose calls start worker threads of their own (hv::parallel_for: the caller and
#: n_threads - 1 std::threads, started per call and joined before it returns)
KERNEL_MODULES = ("holo_viewer.render._splat_cpp", "holo_viewer.display._slices_cpp")
KERNEL_WORKERS = "C++ workers: "  # + the kernel's name: the CPU of the threads one call of it started


class KernelWorkers:
    """Names the :data:`ENDED` CPU: wraps every function of the compiled kernels (:data:`KERNEL_MODULES`, on
    the module, so every caller's ``module.func(...)`` goes through it) and measures, around each call, the
    process's CPU less what the threads alive before the call spent (``CLOCK_PROCESS_CPUTIME_ID`` and
    ``/proc/self/task/*/schedstat``, ns): the CPU of the worker threads the call started (and joined), and
    the calling thread's own CPU in the call (its share: ``parallel_for`` runs the caller as one worker).
    Rows: (``perf_counter`` at return, kernel name, workers' CPU s, caller's CPU s). Two kernel calls at
    once (frames in flight) may see each other's workers end: their sum is right, the split approximate.
    ~0.03-0.1 ms of CPU a read, two a call (the task files are kept open and re-read): ~1 ms of the main
    thread's CPU a group frame (6 calls)."""

    def __init__(self, modules: tuple[str, ...] = KERNEL_MODULES) -> None:
        import importlib

        self.rows: list[tuple[float, str, float, float]] = []
        self.calls: list[tuple[float, float]] = []  # (perf_counter at the call, at its return) per call
        self._mods = []
        for name in modules:
            try:
                self._mods.append(importlib.import_module(name))
            except ImportError:  # not built: nothing to name
                pass
        self._saved: list[tuple[object, str, object]] = []
        self._fds: dict[str, int] = {}
        self._lock = threading.Lock()

    def _threads_ns(self, tids=None) -> tuple[int, dict[str, int]]:
        """(the process's CPU clock, {tid: CPU} of its live threads, or of those of ``tids`` still alive), ns."""
        with self._lock:
            total = time.clock_gettime_ns(time.CLOCK_PROCESS_CPUTIME_ID)
            live = {}
            for tid in os.listdir("/proc/self/task") if tids is None else tids:
                fd = self._fds.get(tid)
                if fd is None:
                    try:
                        fd = self._fds[tid] = os.open(f"/proc/self/task/{tid}/schedstat", os.O_RDONLY)
                    except OSError:  # ended since listdir
                        continue
                try:
                    live[tid] = int(os.pread(fd, 64, 0).split()[0])
                except (OSError, ValueError, IndexError):  # ended: close its file
                    os.close(self._fds.pop(tid))
            return total, live

    def _wrap(self, name: str, func):
        def call(*args, **kwargs):
            start = time.perf_counter()
            p0, t0 = self._threads_ns()
            c0 = time.thread_time_ns()
            try:
                return func(*args, **kwargs)
            finally:
                c1 = time.thread_time_ns()
                # the process's CPU in the call less what the threads alive before it spent: the threads the
                # call started (ended, or still exiting: a joined thread may linger in /proc a moment)
                p1, t1 = self._threads_ns(t0)
                before = sum(t1[tid] - c for tid, c in t0.items() if tid in t1)
                end = time.perf_counter()
                self.rows.append((end, name, max(0, p1 - p0 - before) / 1e9, (c1 - c0) / 1e9))
                self.calls.append((start, end))

        return call

    def __enter__(self) -> "KernelWorkers":
        for mod in self._mods:
            for name in dir(mod):
                func = getattr(mod, name)
                if not name.startswith("_") and callable(func):
                    self._saved.append((mod, name, func))
                    setattr(mod, name, self._wrap(name, func))
        return self

    def __exit__(self, *exc) -> None:
        for mod, name, func in self._saved:
            setattr(mod, name, func)
        self._saved.clear()
        with self._lock:
            for fd in self._fds.values():
                os.close(fd)
            self._fds.clear()

    def between(self, t0: float, t1: float) -> dict[str, float]:
        """CPU seconds of the kernels' workers per ``KERNEL_WORKERS + name``, calls returned in (t0, t1]."""
        out: dict[str, float] = {}
        for t, name, cpu, _ in self.rows:
            if t0 < t <= t1:
                out[KERNEL_WORKERS + name] = out.get(KERNEL_WORKERS + name, 0.0) + cpu
        return out

    def per_kernel(self, t0: float, t1: float, frames: int) -> dict[str, dict]:
        """Per kernel, calls returned in (t0, t1]: calls a frame, and ms of CPU a frame of its workers and of
        its callers (part of the caller's thread's CPU: MainThread with one frame in flight), largest first."""
        acc: dict[str, list] = {}
        for t, name, cpu, own in self.rows:
            if t0 < t <= t1:
                a = acc.setdefault(name, [0, 0.0, 0.0])
                a[0] += 1
                a[1] += cpu
                a[2] += own
        f = max(frames, 1)
        return {name: {"calls_per_frame": round(n / f, 2), "workers_ms": round(1000 * w / f, 1),
                       "caller_ms": round(1000 * c / f, 1), "total_ms": round(1000 * (w + c) / f, 1)}
                for name, (n, w, c) in sorted(acc.items(), key=lambda kv: -(kv[1][1] + kv[1][2]))}


def name_ended(cpu: dict[str, float], workers: dict[str, float], clamp: bool = True) -> dict[str, float]:
    """``cpu`` (per name, with :data:`ENDED`) with the kernels' workers (:meth:`KernelWorkers.between` over the
    same span) taken out of ENDED under their names; ENDED keeps the rest (threads that ended outside a
    kernel call; ``clamp``: >= 0, the sampler's clock ticks round it: a 50 ms interval of the timeline may
    go below 0, its sum over the intervals not)."""
    out = dict(cpu)
    if ENDED in out:
        named = sum(workers.values())
        out.update(workers)
        out[ENDED] = max(0.0, out[ENDED] - named) if clamp else out[ENDED] - named
    return out


def busy_timeline(sampler: "ThreadCPU", done: list[float], render_s: list[float], t0: float, t1: float,
                  cores: int, workers: "KernelWorkers | None" = None) -> dict:
    """Where the cores idle in a displayed frame's cycle: each interval between two samples of ``sampler``
    (its period, 50 ms in the render runs) within [t0, t1] counts as *in a render* when its middle lies in
    a render call of the main thread (ended at ``done[i]``, lasting ``render_s[i]``), else *between
    renders*; per part, the cores each thread / child kept busy on average (CPU seconds over wall seconds)
    and the idle cores (``cores`` minus all of them). With frames in flight the renders overlap: the
    intervals of any render count. ``workers``: the ended threads named by kernel (:func:`name_ended`)."""
    spans = sorted((d - r, d) for d, r in zip(done, render_s))
    starts = np.array([a for a, _ in spans]) if spans else np.zeros(0)
    ends = np.array([b for _, b in spans]) if spans else np.zeros(0)
    parts = {"in_render": [0.0, {}], "between_renders": [0.0, {}]}
    snaps = [sn for sn in sampler.snaps if t0 <= sn[0] <= t1]
    for (ta, a), (tb, b) in zip(snaps, snaps[1:]):
        mid = 0.5 * (ta + tb)
        inside = bool(((starts <= mid) & (mid <= ends)).any())
        part = parts["in_render" if inside else "between_renders"]
        part[0] += tb - ta
        d_ab = _with_ended(a, b, sampler.transient)
        for name, d in (d_ab if workers is None else name_ended(d_ab, workers.between(ta, tb), clamp=False)).items():
            part[1][name] = part[1].get(name, 0.0) + d
    out = {}
    for label, (wall, cpu) in parts.items():
        if wall <= 0:
            continue
        busy = {k: round(v / wall, 3) for k, v in sorted(cpu.items(), key=lambda kv: -kv[1]) if v / wall >= 0.005}
        out[label] = {"wall_s": round(wall, 2), "share_of_time": None, "cores_busy": round(sum(cpu.values()) / wall, 2),
                      "cores_idle": round(max(0.0, cores - sum(cpu.values()) / wall), 2), "by_thread": busy}
    total = sum(v["wall_s"] for v in out.values())
    for v in out.values():
        v["share_of_time"] = round(v["wall_s"] / max(total, 1e-9), 2)
    return out


def _schedstat() -> tuple[float, float]:
    """(seconds on a CPU, seconds runnable but waiting for one) of the calling thread (Linux schedstat)."""
    with open("/proc/thread-self/schedstat") as fh:
        a = fh.read().split()
    return int(a[0]) / 1e9, int(a[1]) / 1e9


class SchedTimes:
    """Wraps ``renderer.render`` (on the instance: its twins are not wrapped) to split each call's wall time
    on the calling thread into on a CPU, waiting for a CPU (another thread or process had it: load,
    the session's other threads) and *blocked* (neither: waiting for the GIL, the render's native workers
    at a barrier, a lock); Linux ``/proc/thread-self/schedstat``."""

    def __init__(self, renderer) -> None:
        self.rows: list[tuple[float, float, float]] = []  # (wall, on cpu, waiting for a cpu) per call
        try:
            _schedstat()
        except OSError:
            return
        inner = renderer.render

        def render(*args, **kwargs):
            s0, t0 = _schedstat(), time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                s1, dt = _schedstat(), time.perf_counter() - t0
                self.rows.append((dt, s1[0] - s0[0], s1[1] - s0[1]))

        renderer.render = render

    def summary(self, skip: int = 1) -> dict | None:
        """ms per render call, mean over the calls after the first ``skip``."""
        r = np.asarray(self.rows[skip:], dtype=np.float64)
        if not r.size:
            return None
        wall, cpu, rq = (float(v) for v in 1000 * r.mean(axis=0))
        return {"calls": int(len(r)), "wall_ms": round(wall, 1), "on_cpu_ms": round(cpu, 1),
                "waiting_for_cpu_ms": round(rq, 1), "blocked_ms": round(wall - cpu - rq, 1)}


class FrameTimes:
    """The live loop's ``on_frame`` callback: when each frame was shown (perf_counter, in the order shown)
    and how much its native image changed from the frame shown before it (RMS, 8-bit levels, every 4th
    pixel): when the first frame came and when a change became visible. (With frames in flight the
    frames are rendered by several renderers; they are shown, and timed here, in order.)"""

    def __init__(self) -> None:
        self.done: list[float] = []  # perf_counter when each frame was shown
        self.render_s: list[float] = []  # the render call's wall seconds (it ended just before it was shown)
        # every 4th pixel of each frame shown, uint8 (0.6 MB a native frame): the changes are computed after
        # the session, not on the loop's thread (the float RMS took ~2-3 ms of each frame's critical path)
        self._small: list[np.ndarray | None] = []
        self._change: list[float] | None = None

    def __call__(self, res) -> None:
        self._small.append(None if res.native is None else res.native[::4, ::4].copy())
        self._change = None
        self.done.append(time.perf_counter())
        self.render_s.append(float(getattr(res, "seconds", 0.0)))

    @property
    def change(self) -> list[float]:
        """RMS change of each shown native image from the one shown before it (inf for the first)."""
        if self._change is None:
            out, prev = [], None
            for cur in self._small:
                if cur is None:
                    continue
                cur = cur.astype(np.float32)
                out.append(float("inf") if prev is None else float(np.sqrt(np.mean((cur - prev) ** 2))))
                prev = cur
            self._change = out
        return self._change


#: RMS change of the native image (8-bit levels, every 4th pixel) that counts as visible
VISIBLE_RMS = 0.5


def visible_latency(tracks: dict, onsets: list[int], k: int, change: list[float]) -> list[float]:
    """Seconds from each onset to the first displayed frame at or after the one whose reaction window
    saw it (:func:`onset_latency`) whose native image changed visibly (> :data:`VISIBLE_RMS`) from
    the frame displayed before it."""
    disp_t, disp_f = tracks["display_time_s"], tracks["display_frame"]
    ch = np.asarray(change[:len(disp_t)])
    out = []
    for o in onsets:
        ok = ((disp_f // k) * k - 1 >= o)[:len(ch)] & (ch > VISIBLE_RMS)
        if ok.any():
            out.append(float(disp_t[np.argmax(ok)] - o / 25.0))
    return out


def backchannel_latency(tracks: dict, pauses: list[int], backchannels: list[int], change: list[float],
                        within_s: float = 2.0) -> list[float | None]:
    """Speech pause -> visible backchannel, with the visible-change timing of :func:`visible_latency`.

    For each pause onset frame, the first backchannel onset frame (a nod, brow raise or smile in the
    recorded listener) at or after it and within ``within_s``; then the first displayed frame at or
    after that frame whose native image changed visibly (> :data:`VISIBLE_RMS`). Returns per pause
    the seconds from the pause onset to that display, or None (no backchannel, or never shown).
    """
    disp_t, disp_f = tracks["display_time_s"], tracks["display_frame"]
    ch = np.asarray(change[:len(disp_t)])
    b = np.sort(np.asarray(backchannels, dtype=np.int64))
    out: list[float | None] = []
    for p in pauses:
        later = b[(b >= p) & (b <= p + within_s * 25)]
        ok = (disp_f[:len(ch)] >= later[0]) & (ch > VISIBLE_RMS) if later.size else np.zeros(0, bool)
        out.append(float(disp_t[np.argmax(ok)] - p / 25.0) if ok.any() else None)
    return out


def pct(x, q):
    return None if not len(x) else round(float(np.percentile(x, q)), 1)


def run_session(files: dict, out: Path, render: bool, tile_scale: float, mode: str = "auto",
                record: bool = False, in_flight: int | None = None, render_threads: int | None = None,
                threads_in_flight: int | None = None, visible_only: bool = True, tracker_process: bool = False) -> dict:
    """One replayed session; ``record``: the session writes its native video too (as ``live`` does);
    ``in_flight``: ``LiveSessionConfig.frames_in_flight`` (None: the default), ``render_threads``: the
    renderer's threads (None: all cores), ``threads_in_flight``: each renderer's threads once frames are in
    flight (``LiveSessionConfig.render_threads_in_flight``; None: the cores over the frames in flight), for
    paired A/Bs in one run (``--ab``, ``--ab-threads``); ``visible_only``: skip the Gaussians nobody sees, as
    ``holo-viewer live`` does (False: every Gaussian drawn, ``--ab-visible``'s A); ``tracker_process``:
    ``LiveSessionConfig.tracker_process`` (dlib in a child process, ``--ab-tracker``'s B)."""
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSessionConfig, LiveSession
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.reaction.audio import read_wav

    load_start = os.getloadavg()[0]
    t_start = time.perf_counter()
    cfg = LiveSessionConfig(out=str(out), tile_scale=tile_scale, write_native_video=record, flush_s=60.0,
                            render_threads_in_flight=threads_in_flight, tracker_process=tracker_process,
                            **({"frames_in_flight": int(in_flight)} if in_flight is not None else {}))
    session = LiveSession(cfg, sources.WavReplay(files["wav"]), sources.VideoReplay(files["video"]))
    renderer = LiveAvatarRenderer(tile_scale=tile_scale, mode=mode, render_threads=render_threads,
                                  visible_only=visible_only) if render else None  # True: as `holo-viewer live`
    times = FrameTimes()
    import resource

    cpu0, kids0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    sched = SchedTimes(renderer) if renderer is not None else None
    # 50 ms: the in-render / between-renders split (20 ms cost ~8 ms a frame); the C++ kernels' workers by kernel
    with ThreadCPU(period=0.05) as sampler, KernelWorkers() as workers:
        summary = session.run(renderer, on_frame=times)
    t_end = time.perf_counter()
    sampler.mark_kernel_workers(workers.calls)  # the kernels' workers a sample caught: theirs, not "native"
    cpu1, kids1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime
    ffmpeg_s = kids1.ru_utime + kids1.ru_stime - kids0.ru_utime - kids0.ru_stime
    wall = t_end - t0
    with np.load(out / "tracks.npz") as z:
        tracks = {k: z[k] for k in z.files}
    wave, _ = read_wav(files["wav"])
    onsets = speech_onsets(wave)
    lat = onset_latency(tracks, onsets, k=8)
    n = len(tracks["time_s"])
    shown = len(set(tracks["display_frame"].tolist()))

    vis = visible_latency(tracks, onsets, 8, times.change) if render else []
    timing = {}
    if render and times.done:
        pool = session.frames_in_flight
        gaps = np.diff(times.done)
        timing = {"first_frame_s": round(times.done[0] - t_start, 2),  # renderer built + session started
                  "quit_s": round(t_end - times.done[-1], 2),  # last frame -> run() returned (flush, joins)
                  "frames_in_flight": pool.n, "render_threads": render_threads,
                  "render_threads_in_flight": pool.threads_each if pool.n > 1 else None,
                  "twins_ready_s": None if pool.twins_ready_s is None else round(pool.twins_ready_s, 2),
                  # wall time between frames shown (the render_ms of a frame in flight is longer than this)
                  "display_interval_ms_median": pct(1000 * gaps, 50), "display_interval_ms_p95": pct(1000 * gaps, 95),
                  "displayed_fps": round(shown / (n / 25.0), 2), "recording": record,
                  # the render calls on the main thread: on a CPU / waiting for one / blocked (GIL, barriers)
                  "render_call_main_thread": sched.summary() if sched is not None and pool.n == 1 else None,
                  "visible_change_ms_median": pct(1000 * np.array(vis), 50),
                  "visible_change_ms_p95": pct(1000 * np.array(vis), 95), "onsets_visible": len(vis),
                  "load_1min_start": round(load_start, 2), "load_1min_end": round(os.getloadavg()[0], 2),
                  # CPU seconds (both cores) of the session's process (render, tracker, reaction, ...) and of
                  # its ffmpeg children (the session video's encoder and its verification at close)
                  "process_cpu_s": round(cpu_s, 2), "ffmpeg_cpu_s": round(ffmpeg_s, 2),
                  "process_cpu_ms_per_displayed_frame": round(1000 * cpu_s / max(shown, 1), 1),
                  "ffmpeg_cpu_ms_per_displayed_frame": round(1000 * ffmpeg_s / max(shown, 1), 1)}
        # the session itself (start-up excluded): from the second displayed frame to the last, CPU per
        # thread and per ffmpeg child, per displayed frame; cores_used: all of it over the wall time
        if len(times.done) >= 3:
            span, cpu = sampler.between(times.done[1], times.done[-1])
            ta, tb = sampler.snaps[sampler.nearest(times.done[1])][0], sampler.snaps[sampler.nearest(times.done[-1])][0]
            named = workers.between(ta, tb)
            # the kernels' workers measured around their calls beyond what the samples left unnamed: CPU that
            # would count twice (name_ended clamps ENDED at 0); ~0 since mark_kernel_workers (15-21 ms before)
            over = max(0.0, sum(named.values()) - cpu.get(ENDED, 0.0))
            cpu = name_ended(cpu, named)
            nfr = sum(1 for d in times.done[2:] if d <= sampler.snaps[-1][0])
            total = sum(cpu.values())
            timing["in_session"] = {
                "seconds": round(span, 2), "frames": nfr, "cores_used": round(total / max(span, 1e-9), 2),
                "cpu_ms_per_displayed_frame": round(1000 * total / max(nfr, 1), 1),
                "kernel_workers_counted_twice_ms": round(1000 * over / max(nfr, 1), 1),
                "cpu_ms_per_displayed_frame_by_thread": {k: round(1000 * v / max(nfr, 1), 1) for k, v in
                                                         sorted(cpu.items(), key=lambda kv: -kv[1]) if v > 0},
                # the C++ kernels' calls over the same span: their workers' CPU (above, by name) and their
                # callers' (within MainThread / the render threads above)
                "cpp_kernels_per_displayed_frame": workers.per_kernel(ta, tb, nfr),
                "cpu_s_per_session_second_by_thread": {k: round(v / max(span, 1e-9), 3) for k, v in
                                                       sorted(cpu.items(), key=lambda kv: -kv[1]) if v > 0},
                # where the cores idle: during the render calls and between them (the loop, showing, waiting)
                "timeline": busy_timeline(sampler, times.done, times.render_s, times.done[1], times.done[-1],
                                          os.cpu_count() or 1, workers)}
    return {**timing,
        "render": render, "tile_scale": tile_scale, "render_mode": mode, "wall_s": round(wall, 2), "frames": n,
        "viewer_fps": cfg.viewer_fps, "shared_vad": session._speech_gate.shares_vad,
        "frames_in_flight_asked": cfg.frames_in_flight,
        "viewer_updates": session.viewer_updates,
        "tracker_cpu_ms_median": pct(session.tracker_cpu_ms, 50),
        "tracker_cpu_s": round(float(np.sum(session.tracker_cpu_ms)) / 1000, 2),
        "onsets": len(onsets), "onsets_reflected": len(lat),
        "onset_to_display_ms_median": pct(1000 * np.array(lat), 50), "onset_to_display_ms_p95": pct(1000 * np.array(lat), 95),
        "tracker_ms_median": pct(session.tracker_ms, 50), "tracker_ms_p95": pct(session.tracker_ms, 95),
        "tracked_frames": len(session.tracker_ms),
        "reaction_ms_per_window_median": pct(session.window_ms, 50), "reaction_ms_per_window_p95": pct(session.window_ms, 95),
        "reaction_windows": len(session.window_ms), "late_reaction_windows": summary["late_reaction_windows"],
        "late_window_max_ms": summary["late_reaction_window_max_ms"],
        "render_ms_median": pct(session.render_ms, 50), "render_ms_p95": pct(session.render_ms, 95),
        "displayed_frames": shown, "frames_not_displayed": n - shown if render else None,
    }


def fit_speed(n: int = 60) -> dict:
    """ms per landmark fit (warm start and cold start) on exact model landmarks + 1 px noise."""
    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.flame.expressions import default_au_map
    from holo_viewer.tracking.fit import TrackerFitConfig, fit_landmarks, reduction
    from holo_viewer.tracking.head_model import LandmarkHeadModel

    hm = LandmarkHeadModel(load_default_model(), default_au_map())
    K = np.array([[554.0, 0, 320], [0, 554, 240], [0, 0, 1]])
    M = reduction(hm, TrackerFitConfig())
    rng = np.random.default_rng(0)
    warm, cold = [], []
    for _ in range(n):
        q = np.zeros(M.shape[1])
        na = M.shape[1] - 7
        q[:na] = rng.uniform(0, 0.5, na)
        q[na] = rng.uniform(0, 0.3)
        q[na + 1:na + 4] = np.radians(rng.uniform(-15, 15, 3))
        q[na + 4:] = [0, 0.03, 0.5]
        lm = hm.project(M @ q, K)[0] + rng.normal(0, 1, (68, 2))
        t = time.perf_counter()
        r = fit_landmarks(hm, lm, K)
        cold.append(time.perf_counter() - t)
        t = time.perf_counter()
        fit_landmarks(hm, lm + rng.normal(0, 0.5, (68, 2)), K, prev=r.params)
        warm.append(time.perf_counter() - t)
    return {"fit_ms_warm_median": round(1000 * float(np.median(warm)), 2),
            "fit_ms_warm_p95": round(1000 * float(np.percentile(warm, 95)), 2),
            "fit_ms_cold_median": round(1000 * float(np.median(cold)), 2)}


def rss_run(seconds: float, out: Path) -> dict:
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSessionConfig, LiveSession
    from holo_viewer.pipeline.live_support import SyntheticSpeaker

    syn = SyntheticSpeaker(seconds)
    session = LiveSession(LiveSessionConfig(out=str(out), flush_s=5.0), sources.ArrayAudio(syn.waveform), None, syn)
    samples = []
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            samples.append((time.perf_counter(), rss_mb()))
            stop.wait(1.0)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    session.run(None)
    stop.set()
    th.join()
    r = np.array([s[1] for s in samples])
    settle = min(len(r) - 1, 10)  # after 10 s (the first flushes, imports)
    return {"seconds": seconds, "rss_mb_after_10s": round(float(r[settle]), 1), "rss_mb_end": round(float(r[-1]), 1),
            "rss_growth_mb": round(float(r[-1] - r[settle]), 1), "rss_max_mb": round(float(r.max()), 1),
            "late_reaction_windows": session.late_windows, "reaction_windows": len(session.window_ms)}


def startup_run(cold: bool, out: Path, files: dict, frames: int = 3, fresh_caches: bool = False) -> dict:
    """``holo-viewer live --audio WAV --video MP4 --headless --frames N`` in a child process (the command
    as a user starts it on recorded inputs, full-size tiles, the face tracker warmed too): seconds from
    the process start to its "first frame shown" line, and
    quit = the last frame -> the session closed (printed by the command) + that line -> the process
    exited. ``cold``: an empty ``NUMBA_CACHE_DIR`` (every kernel compiles, as on first use). The
    panel tables (:mod:`holo_viewer.display.table_cache`) go to ``out``'s parent folder: empty for
    the first (cold) run, filled by it for the warm one. ``fresh_caches``: the kernels as set-up compiled
    them, but an empty holo_viewer cache and table folder of its own: a user's first session after
    ``make demo``'s set-up."""
    import subprocess

    env = dict(os.environ)
    if cold:
        env["NUMBA_CACHE_DIR"] = str(out / "numba_cache")
    env["HOLO_VIEWER_TABLE_CACHE"] = str(out.parent / "table_cache")
    # no nice-19 build of the visible-Gaussian mask into these throw-away folders (it would outlive the run)
    env["HOLO_VIEWER_BACKGROUND_BUILDS"] = "0"
    if fresh_caches:
        env["HOLO_VIEWER_CACHE"] = str(out / "user_cache")
        env["HOLO_VIEWER_TABLE_CACHE"] = str(out / "table_cache")
    cmd = [sys.executable, "-m", "holo_viewer", "live", "--audio", str(files["wav"]), "--video", str(files["video"]),
           "--headless", "--frames", str(frames), "--out", str(out / "session")]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    first = closed = None
    closing_s = None
    for line in proc.stdout:  # type: ignore[union-attr]
        if "first frame shown" in line:
            first = time.perf_counter() - t0
        elif line.startswith("live: closed "):
            closed, closing_s = time.perf_counter(), float(line.split()[2])
    proc.wait()
    t_exit = time.perf_counter()
    return {"cold": cold, "fresh_caches": fresh_caches, "first_frame_s": None if first is None else round(first, 2),
            "quit_s": None if closed is None else round(closing_s + t_exit - closed, 2),
            "returncode": proc.returncode, "load_1min_start": round(load, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=8.0, help="clip length")
    ap.add_argument("--tile-scale", type=float, default=1.0,
                    help="quilt tile scale (default 1: holo-viewer live's default; 0.5 renders 4x fewer pixels "
                         "at ~29 dB against the full frame, docs/live_frame.md)")
    ap.add_argument("--render-mode", default="auto", choices=("auto", "cone", "tracked", "all_views"),
                    help="the live renderer's mode (holo-viewer live --render-mode; default auto)")
    ap.add_argument("--rss-seconds", type=float, default=0.0, help="also run a synthetic session this long for RSS")
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "holo_viewer_live_bench"))
    ap.add_argument("--json", default=None)
    ap.add_argument("--ab", action="store_true", help="also one frame in flight (A) and --in-flight "
                    "frames (B, default 2), one after the other")
    ap.add_argument("--in-flight", type=int, default=None, help="LiveSessionConfig.frames_in_flight of the "
                    "render runs (default: the loop's default)")
    ap.add_argument("--render-threads", type=int, default=None, help="each renderer's threads (default: all cores)")
    ap.add_argument("--ab-threads", action="store_true", help="also the default with all cores per renderer "
                    "in flight instead of the cores over the frames in flight (row ab_threads_all)")
    ap.add_argument("--ab-visible", action="store_true", help="also every Gaussian drawn (A) against the "
                    "visible ones only (B, the default), one after the other (rows ab_visible)")
    ap.add_argument("--ab-tracker", action="store_true", help="also the face tracker's dlib in this process (A, "
                    "the default) against a child process (B, LiveSessionConfig.tracker_process), one after the other, "
                    "twice (rows ab_tracker)")
    ap.add_argument("--startup-only", action="store_true", help="only the start-up runs: the live command's first "
                    "frame cold (empty kernel cache) and warm, and its quit time")
    args = ap.parse_args()

    from holo_viewer.pipeline.live_support import write_talking_head_clip

    cache = Path(args.cache) / f"clip_{args.seconds:g}s"
    files = {"wav": cache / "speaker.wav", "video": cache / "speaker.mp4"}
    if not all(p.exists() for p in files.values()):
        print(f"rendering a {args.seconds:g} s clip of the default head speaking into {cache} ...")
        write_talking_head_clip(cache, seconds=args.seconds, n_gaussians=30_000)
    with tempfile.TemporaryDirectory() as tmp:  # the live command as a user starts it (issue 33)
        startup = [startup_run(cold, Path(tmp) / f"start{i}", files) for i, cold in enumerate((True, False))]
        # [2]: the first session after set-up (kernels compiled by scripts/setup.sh, every other cache empty)
        startup.append(startup_run(False, Path(tmp) / "start2", files, fresh_caches=True))
    print("start-up (holo-viewer live --audio --video --headless --frames 3, full-size tiles): first frame "
          f"cold {startup[0]['first_frame_s']} s (load {startup[0]['load_1min_start']}), first use after set-up "
          f"{startup[2]['first_frame_s']} s (load {startup[2]['load_1min_start']}), warm "
          f"{startup[1]['first_frame_s']} s (load {startup[1]['load_1min_start']}); quit {startup[1]['quit_s']} s")
    if args.startup_only:
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            from holo_viewer.fileio import atomic_write

            with atomic_write(args.json, "w") as fh:
                json.dump({"config": vars(args), "cores": os.cpu_count(), "startup": startup}, fh, indent=2)
            print(f"wrote {args.json}")
        return 0
    if args.render_mode in ("auto", "all_views"):  # the live frames' visible Gaussians, built (untimed) if not cached
        from holo_viewer.pipeline import Pipeline, ViewSettings
        from holo_viewer.pipeline.live_support import visible_mask

        c0 = time.process_time()
        keep = visible_mask(Pipeline(view=ViewSettings(tile_scale=args.tile_scale)))
        print(f"visible Gaussians: {int(keep.sum())} of {keep.size} ({time.process_time() - c0:.1f} s of CPU)", flush=True)
    load = os.getloadavg()
    fit = fit_speed()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        kw = {"in_flight": args.in_flight, "render_threads": args.render_threads}
        for render in (False, True):
            rows.append(run_session(files, Path(tmp) / f"s{int(render)}", render, args.tile_scale, args.render_mode,
                                    record=render, **kw))
        # the same again in this process: the renderer's tables and kernels are warm (first frame, warm)
        warm = run_session(files, Path(tmp) / "s2", True, args.tile_scale, args.render_mode, record=True, **kw)
        # --ab, paired, one after the other: one frame in flight (A, ab_before), then --in-flight frames (B,
        # ab_after, default 2)
        ab = [run_session(files, Path(tmp) / f"ab{i}", True, args.tile_scale, args.render_mode, record=True,
                          in_flight=n, render_threads=args.render_threads)
              for i, n in enumerate((1, args.in_flight or 2))] if args.ab else None
        ab_threads = run_session(files, Path(tmp) / "abt", True, args.tile_scale, args.render_mode, record=True,
                                 in_flight=args.in_flight, render_threads=args.render_threads,
                                 threads_in_flight=os.cpu_count()) if args.ab_threads else None
        abv = [run_session(files, Path(tmp) / f"abv{i}", True, args.tile_scale, args.render_mode, record=True,
                           visible_only=v, **kw) for i, v in enumerate((False, True))] if args.ab_visible else None
        abt = [run_session(files, Path(tmp) / f"abtr{i}", True, args.tile_scale, args.render_mode, record=True,
                           tracker_process=bool(i % 2), **kw) for i in range(4)] if args.ab_tracker else None
        rss = rss_run(args.rss_seconds, Path(tmp) / "rss") if args.rss_seconds > 0 else None
    base, full = rows
    ratio = (full["reaction_ms_per_window_median"] or 0) / max(base["reaction_ms_per_window_median"] or 1e-9, 1e-9)
    keys = ["onset_to_display_ms_median", "onset_to_display_ms_p95", "tracker_ms_median", "tracker_ms_p95",
            "tracked_frames", "reaction_ms_per_window_median", "reaction_ms_per_window_p95", "reaction_windows",
            "late_reaction_windows", "late_window_max_ms", "render_ms_median", "render_ms_p95", "displayed_frames", "frames_not_displayed"]
    print(f"\nlive latency, {args.seconds:g} s replayed clip, tile scale {args.tile_scale}, {args.render_mode} "
          f"(load average {load[0]:.2f} {load[1]:.2f} on {os.cpu_count()} cores)")
    print(f"{'':34s} {'no render':>12s} {'render':>12s}")
    for k in keys:
        print(f"{k:34s} {str(base[k]):>12s} {str(full[k]):>12s}")
    print(f"reaction ms/window, render vs no-render: x{ratio:.2f}")
    named = [("cold", full), ("warm", warm)] + ([("1 in flight (A)", ab[0]), (f"{args.in_flight or 2} in flight (B)", ab[1])] if ab else []) + \
        ([("all cores per renderer in flight", ab_threads)] if ab_threads else []) + \
        ([("every Gaussian (A)", abv[0]), ("visible Gaussians (B)", abv[1])] if abv else []) + \
        ([(f"tracker {'child process (B)' if i % 2 else 'in process (A)'}, pair {i // 2 + 1}", row)
          for i, row in enumerate(abt)] if abt else [])
    for name, row in named:
        print(f"{name}: {row['displayed_fps']} displayed fps with recording (load {row['load_1min_start']} -> "
              f"{row['load_1min_end']}), render {row['render_ms_median']} ms, visible change "
              f"{row['visible_change_ms_median']} ms (p95 {row['visible_change_ms_p95']}, {row['onsets_visible']} onsets), "
              f"first frame {row['first_frame_s']} s, quit {row['quit_s']} s; {row['frames_in_flight']} in flight "
              f"({row['render_threads_in_flight']} threads each) "
              f"(twins ready {row['twins_ready_s']} s), shown every {row['display_interval_ms_median']} ms "
              f"(p95 {row['display_interval_ms_p95']}); CPU per displayed frame: process "
              f"{row['process_cpu_ms_per_displayed_frame']} ms, ffmpeg {row['ffmpeg_cpu_ms_per_displayed_frame']} ms; "
              f"tracker {row['tracker_cpu_s']} CPU s over {row['tracked_frames']} frames (viewer_fps {row['viewer_fps']}, "
              f"{row['viewer_updates']} viewer updates)")
        rc = row.get("render_call_main_thread")
        if rc:
            print(f"  render calls on the main thread (ms, mean of {rc['calls']}): wall {rc['wall_ms']} = on a CPU "
                  f"{rc['on_cpu_ms']} + waiting for a CPU {rc['waiting_for_cpu_ms']} + blocked {rc['blocked_ms']}")
        ins = row.get("in_session")
        if ins:
            print(f"  in session ({ins['frames']} frames, {ins['seconds']} s, start-up excluded): "
                  f"{ins['cpu_ms_per_displayed_frame']} ms of CPU a displayed frame, {ins['cores_used']} cores busy; "
                  "by thread (ms a frame): " + ", ".join(f"{k} {v}" for k, v in
                                                          ins["cpu_ms_per_displayed_frame_by_thread"].items()))
            ck = ins.get("cpp_kernels_per_displayed_frame")
            if ck:
                print("  C++ kernels (ms a frame, workers + caller): " + ", ".join(
                    f"{k} {v['workers_ms']} + {v['caller_ms']}" for k, v in ck.items()))
            for part, v in ins.get("timeline", {}).items():
                print(f"    {part} ({v['share_of_time']:.0%} of the time): {v['cores_busy']} cores busy, "
                      f"{v['cores_idle']} idle; " + ", ".join(f"{k} {c}" for k, c in v["by_thread"].items()))
    print(f"landmark fit ms (warm median / p95, cold median): {fit['fit_ms_warm_median']} / {fit['fit_ms_warm_p95']}, "
          f"{fit['fit_ms_cold_median']}")
    if rss:
        print(f"RSS over a {rss['seconds']:g} s synthetic session: {rss['rss_mb_after_10s']} -> {rss['rss_mb_end']} MB "
              f"(growth {rss['rss_growth_mb']} MB), late windows {rss['late_reaction_windows']}/{rss['reaction_windows']}")
    from scenes import cpu_model

    result = {"config": vars(args), "load_average": load, "cores": os.cpu_count(), "cpu_model": cpu_model(),
              "no_render": base, "render": full,
              "render_warm": warm, "ab_before": ab[0] if ab else None, "ab_after": ab[1] if ab else None,
              "ab_threads_all": ab_threads, "ab_visible": abv, "ab_tracker": abt,
              "startup": startup,
              "reaction_window_ratio_render_vs_baseline": round(ratio, 2), "fit": fit, "rss": rss}
    if args.json:
        from holo_viewer.fileio import write_json

        write_json(args.json, result)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
