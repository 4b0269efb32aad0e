"""Shared test fixtures, and the repository root on ``sys.path`` for ``from bench.scenes import ...``.

The small random objects come from :mod:`holo_viewer.testing`; every fixture here is cheap.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # bench/ is a folder of scripts, not an installed package
    sys.path.insert(0, str(ROOT))


def worker_threads(cpus: int | None, workers: int) -> int:
    """torch's (OpenMP's, MKL's) threads per pytest-xdist worker: the cores shared out, at least one."""
    return max(1, (cpus or 1) // max(1, workers))


def _share_the_cores() -> None:
    """Under pytest-xdist, give each worker's torch its share of the cores (``OMP_NUM_THREADS``), unless set.

    Two workers on 2 cores with torch's default (a thread per core each) spin-wait for each other's cores:
    torch-heavy files took 2.3x the CPU (test_render_torch.py 14.8 vs 6.4 CPU s, two files side by side).
    Runs when conftest is imported, before any test module imports torch; numba's threads are left as they
    are (its parallel kernels' tests run them on more than one thread, and they did not spin measurably).
    """
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0") or 0)
    if workers < 1 or "torch" in sys.modules:
        return
    n = str(worker_threads(os.cpu_count(), workers))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, n)


_share_the_cores()

# `holo-viewer live` starts a nice-19 process that builds the avatar's visible-Gaussian mask for the next start
# (pipeline/live_support.build_visible_mask_later, ~30 s of CPU per avatar and tile scale). The suite's live
# sessions (in process and their children, which inherit this) start none: they would run beside the workers,
# outlive the tests that started them and fill the cache with masks no later test loads. A test of the build
# itself sets the variable back (monkeypatch.setenv).
os.environ.setdefault("HOLO_VIEWER_BACKGROUND_BUILDS", "0")


@pytest.fixture(scope="module")
def small_model():
    """A random 300-vertex FLAME-format model (8 shape, 6 expression components)."""
    from holo_viewer.testing import random_flame_model

    return random_flame_model(n_vertices=300, n_shape=8, n_expr=6, seed=1)


@pytest.fixture()
def small_avatar(small_model):
    """400 random Gaussians rigged to ``small_model``."""
    from holo_viewer.testing import random_rigged_avatar

    return random_rigged_avatar(small_model, n=400)


@contextlib.contextmanager
def _xvfb(screen: str = "1920x1080x24") -> Iterator[str]:
    """Run ``Xvfb`` on a free display with one ``screen`` (WxHxDEPTH); yields ``":N"``.

    Skips the test when Xvfb is missing or does not start. ``-displayfd``: Xvfb picks the display
    and writes its number once it accepts connections, so parallel runs never collide. ``-noreset``: by
    default Xvfb resets itself whenever its last client disconnects, and a client that connects while it
    does (a test's ``xdpyinfo`` exits and the same process's VTK window connects next) is dropped before
    its connection is answered ("unable to open display", VTK's "bad X server connection"): under load 18,
    16 of 300 back-to-back ``xdpyinfo`` runs were refused, 0 of 300 with the flag (xorg/xserver issue 1102).
    """
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb); this test needs an X server")
    rfd, wfd = os.pipe()
    proc = subprocess.Popen([exe, "-displayfd", str(wfd), "-screen", "0", screen, "-nolisten", "tcp", "-noreset"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, pass_fds=(wfd,))
    os.close(wfd)
    buf = b""
    deadline = time.time() + 20
    while time.time() < deadline and not buf.endswith(b"\n"):
        ready, _, _ = select.select([rfd], [], [], 0.2)
        if ready:
            chunk = os.read(rfd, 64)
            if not chunk:
                break
            buf += chunk
        if proc.poll() is not None:
            break
    os.close(rfd)
    if not buf.strip().isdigit():
        proc.kill()
        pytest.skip(f"Xvfb did not start (exit code {proc.poll()})")
    try:
        yield f":{int(buf.strip())}"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture(scope="session")
def xvfb_server():
    """``with xvfb_server("1536x2048x24") as display:`` runs a virtual X server for that block."""
    return _xvfb



# ------------------------------------------------------------------ the slow marker from tests/slow_tests.txt
#: CPU seconds counted for a listed test whose line gives none (a line added by hand without a measurement)
UNMEASURED_S = 1.0


def parse_slow_list(text: str) -> dict[str, float]:
    """``{node id: CPU seconds}`` from tests/slow_tests.txt: one node id a line, optionally ``# 12.3`` after it
    (its CPU seconds with its file run alone; :data:`UNMEASURED_S` without); ``#`` lines are comments."""
    out: dict[str, float] = {}
    for ln in text.splitlines():
        node, _, comment = ln.partition("#")
        node = node.strip()
        if not node:
            continue
        word = comment.strip().split(" ", 1)[0]
        try:
            out[node] = float(word)
        except ValueError:
            out[node] = UNMEASURED_S
    return out


def _slow_list() -> dict[str, float]:
    path = Path(__file__).with_name("slow_tests.txt")
    return parse_slow_list(path.read_text()) if path.is_file() else {}


def longest_files_first(nodeids: list[str], cost: dict[str, float]) -> list[int]:
    """The order (indices into ``nodeids``) that runs whole files by their listed tests' CPU, the costliest
    first; a file keeps its own order, files of equal cost keep theirs. Under ``--dist loadfile`` a worker
    takes the next file when it is free, so the long files start first and the short ones fill in at the
    end: the two workers finish within a short file of each other (make test passes --no-loadscope-reorder,
    whose default orders files by their number of tests instead)."""
    per_file: dict[str, float] = {}
    first: dict[str, int] = {}
    for i, n in enumerate(nodeids):
        f = n.split("::", 1)[0]
        first.setdefault(f, i)
        per_file[f] = per_file.get(f, 0.0) + cost.get(n, 0.0)
    return sorted(range(len(nodeids)), key=lambda i: (-per_file[nodeids[i].split("::", 1)[0]],
                                                        first[nodeids[i].split("::", 1)[0]], i))


def pytest_collection_modifyitems(config, items):
    """Tests listed in tests/slow_tests.txt (written by ``bench/test_times.py --write-slow``: the tests that took
    more than 0.5 s of CPU) get the ``slow`` marker, like those marked in their files: ``make test-fast``
    (``-m "not slow"``) leaves them out, ``make test`` runs them. Then the files are ordered by
    :func:`longest_files_first` (every worker collects the same order, as pytest-xdist requires)."""
    slow = _slow_list()
    for item in items:
        if item.nodeid in slow:
            item.add_marker(pytest.mark.slow)
    order = longest_files_first([item.nodeid for item in items], slow)
    items[:] = [items[i] for i in order]


# ------------------------------------------------------------------ per-test CPU times (bench/test_times.py)
_TIMES_PATH = os.environ.get("HOLO_TEST_TIMES")
_times: dict[str, list[float]] = {}


def main_thread_sched() -> tuple[float, float]:
    """(seconds run, seconds waited for a core while runnable) of this process's main thread, from
    ``/proc/self/schedstat``; (nan, nan) where the kernel does not provide it."""
    try:
        run_ns, delay_ns = Path("/proc/self/schedstat").read_text().split()[:2]
        return int(run_ns) / 1e9, int(delay_ns) / 1e9
    except (OSError, ValueError):
        return float("nan"), float("nan")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With ``$HOLO_TEST_TIMES`` set, record each test's wall and CPU seconds (set-up, call and tear-down;
    CPU = this process's threads plus the children it waited for), then the main thread's seconds blocked
    (wall minus its run time and its wait for a core: sleeping, polling with a timeout, waiting for a
    child or another thread; on a busy machine a child's own wait for a core counts here too)."""
    if not _TIMES_PATH:
        yield
        return
    import resource

    def cpu() -> float:
        own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime

    w0, c0, (r0, d0) = time.perf_counter(), cpu(), main_thread_sched()
    yield
    wall, (r1, d1) = time.perf_counter() - w0, main_thread_sched()
    _times[item.nodeid] = [wall, cpu() - c0, max(0.0, wall - (r1 - r0) - (d1 - d0))]


def pytest_sessionfinish(session, exitstatus):
    if _TIMES_PATH and _times:
        import json

        worker = os.environ.get("PYTEST_XDIST_WORKER")  # under xdist each worker writes its own file
        Path(_TIMES_PATH + (f".{worker}" if worker else "")).write_text(json.dumps(_times, indent=0))
