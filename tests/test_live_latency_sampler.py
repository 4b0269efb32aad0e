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
