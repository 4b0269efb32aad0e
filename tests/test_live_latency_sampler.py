"""bench/live_latency.py's per-thread CPU split counts the threads that lived between two samples."""
import threading
import time

from bench.live_latency import ENDED, PROCESS, ThreadCPU, _with_ended


def test_with_ended_arithmetic():
    a = {0: (PROCESS, 1.0), 11: ("MainThread", 0.5), 12: ("native workers", 0.1), -5: ("ffmpeg encoder", 2.0)}
    b = {0: (PROCESS, 1.9), 11: ("MainThread", 0.8), 13: ("native workers", 0.2), -5: ("ffmpeg encoder", 2.4)}
    out = _with_ended(a, b)
    # process +0.9 s; the sampled threads +0.3 (main) +0.2 (a new worker, from 0); thread 12 vanished: its
    # share is in ENDED with the threads never sampled; children are not the process's
    assert abs(out["MainThread"] - 0.3) < 1e-12 and abs(out["native workers"] - 0.2) < 1e-12
    assert abs(out["ffmpeg encoder"] - 0.4) < 1e-12 and abs(out[ENDED] - 0.4) < 1e-12
    assert PROCESS not in out


def _spin(seconds):
    t = time.thread_time()
    while time.thread_time() - t < seconds:
        pass


def test_short_lived_threads_are_counted():
    with ThreadCPU(period=0.2) as s:
        time.sleep(0.05)
        for _ in range(4):  # threads that start and end between two samples, as the C++ kernels' workers
            th = threading.Thread(target=_spin, args=(0.03,))
            th.start()
            th.join()
        done = time.perf_counter()
        deadline = done + 60  # a sample after the last thread ended (the period is 0.2 s; under load, later)
        while s.snaps[-1][0] <= done and time.perf_counter() < deadline:
            time.sleep(0.01)
    assert s.snaps[-1][0] > done
    _, cpu = s.between(s.snaps[0][0], s.snaps[-1][0])
    # 4 x 30 ms of CPU; a sample may catch one thread alive (its share seen is then its own name's), and
    # clock ticks are 10 ms: at least 60 ms are in ENDED (0 before the sampler counted the process)
    assert cpu.get(ENDED, 0.0) >= 0.06


def test_kernel_workers_name_the_ended_threads(monkeypatch):
    import sys
    import types

    from bench.live_latency import KERNEL_WORKERS, KernelWorkers, name_ended

    mod = types.ModuleType("fake_kernels")

    def composite(n):  # as hv::parallel_for: workers started in the call and joined before it returns
        ths = [threading.Thread(target=_spin, args=(0.03,)) for _ in range(n)]
        for th in ths:
            th.start()
        _spin(0.01)  # the caller's share
        for th in ths:
            th.join()
        return n

    mod.composite = composite
    monkeypatch.setitem(sys.modules, "fake_kernels", mod)
    with KernelWorkers(("fake_kernels", "no_such_module")) as w:
        assert mod.composite(2) == 2  # wrapped on the module, the result passed through
        _spin(0.02)  # the caller's own CPU outside a call: not the workers'
    assert mod.composite is composite  # unwrapped on exit
    assert [r[1] for r in w.rows] == ["composite"]
    named = w.between(0.0, w.rows[0][0])
    # 2 x 30 ms of the workers' thread CPU (ns clocks), plus their start and exit
    assert 0.06 <= named[KERNEL_WORKERS + "composite"] < 0.075
    assert w.between(w.rows[0][0], w.rows[0][0] + 1) == {}  # (t0, t1]
    row = w.per_kernel(0.0, w.rows[0][0], frames=2)["composite"]  # the caller's 10 ms its own, per frame
    assert row["calls_per_frame"] == 0.5 and 5.0 <= row["caller_ms"] < 7.5 and 30.0 <= row["workers_ms"] < 37.5
    out = name_ended({"MainThread": 0.5, ENDED: 0.1}, {KERNEL_WORKERS + "composite": 0.07})
    assert abs(out[ENDED] - 0.03) < 1e-12 and out[KERNEL_WORKERS + "composite"] == 0.07


def test_a_kernel_worker_caught_by_a_sample_counts_once(monkeypatch):
    """A C++ kernel's worker alive at a sample is the kernel's (ENDED, named by KernelWorkers), not a
    "native workers" thread as well: the split sums to the process's CPU (until 2026-11-29 it counted twice)."""
    import sys
    import types

    from bench.live_latency import KERNEL_WORKERS, NATIVE, KernelWorkers, name_ended

    s = ThreadCPU(period=1.0)  # sampled by hand, no sampler thread
    go = threading.Event()

    def worker():
        _spin(0.03)
        go.wait()
        _spin(0.01)

    mod = types.ModuleType("fake_kernels_caught")

    def composite():
        th = threading.Thread(target=worker)
        th.start()
        _spin(0.03)
        s.sample()  # the worker is alive and has run ~30 ms
        go.set()
        th.join()

    mod.composite = composite
    monkeypatch.setitem(sys.modules, "fake_kernels_caught", mod)
    # the worker is a Python thread: give it no name, as a std::thread has none
    monkeypatch.setattr(threading, "enumerate", lambda: [threading.main_thread()])
    with KernelWorkers(("fake_kernels_caught",)) as w:
        s.sample()
        mod.composite()
        s.sample()
    caught = {k for k, (name, _) in s.snaps[1][1].items() if name == NATIVE} - set(s.snaps[0][1])
    assert len(caught) == 1  # the sample saw it, unnamed (other threads of the test run were there before)
    assert s.mark_kernel_workers(w.calls) == caught
    t0, t1 = s.snaps[0][0], s.snaps[-1][0]
    _, cpu = s.between(t0, t1)
    out = name_ended(cpu, w.between(t0, t1))
    process = s.snaps[-1][1][0][1] - s.snaps[0][1][0][1]
    assert out.get(NATIVE, 0.0) < 0.005  # only the threads that were not the worker
    assert out[KERNEL_WORKERS + "composite"] >= 0.035
    assert abs(sum(out.values()) - process) < 0.005  # nothing counted twice


def test_mark_kernel_workers_keeps_threads_that_live_on():
    s = ThreadCPU()
    # samples every 0.1 s from 0.1 to 2.0 s; kernel calls (0.05, 0.12) and (0.15, 0.25)
    s.starts = [0.1 * i - 0.001 for i in range(1, 21)]
    s.snaps = [(0.1 * i, {9: ("MainThread", 0.0)}) for i in range(1, 21)]
    for i, (_, snap) in enumerate(s.snaps):
        snap[7] = ("native workers", 0.01 * i)  # an OpenMP pool's worker: the whole session
        if i == 0:
            snap[8] = ("native workers", 0.0)  # within the first call
        if i in (1, 2):
            snap[10] = ("native workers", 0.0)  # within the second call, lingering one sample after it
        if i == 2:
            snap[11] = ("native workers", 0.0)  # in no call
        if i >= 1:
            snap[12] = ("native workers", 0.0)  # first seen in a call, alive 1.9 s: a pool started then
    # 9: a Python thread
    assert s.mark_kernel_workers([(0.05, 0.12), (0.15, 0.25)]) == {8, 10}
