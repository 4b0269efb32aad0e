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
