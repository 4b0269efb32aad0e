"""The test suite's own machinery: torch threads per xdist worker, the slow list, the longest-files-first order."""

import json
import os
import subprocess
import sys

from conftest import ROOT, UNMEASURED_S, longest_files_first, main_thread_sched, parse_slow_list, worker_threads


def test_worker_threads_share_the_cores():
    assert worker_threads(2, 2) == 1
    assert worker_threads(16, 2) == 8
    assert worker_threads(2, 4) == 1
    assert worker_threads(None, 2) == 1


def test_conftest_sets_torch_threads_only_under_xdist():
    code = ("import os, sys; sys.path.insert(0, 'tests'); import conftest; "
            "print(os.environ.get('OMP_NUM_THREADS'), os.environ.get('MKL_NUM_THREADS'))")
    base = {k: v for k, v in os.environ.items()
            if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "PYTEST_XDIST_WORKER_COUNT")}
    want = worker_threads(os.cpu_count(), 2)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env=dict(base, PYTEST_XDIST_WORKER_COUNT="2"))
    assert out.stdout.split() == [str(want), str(want)]
    alone = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                           env=base)
    assert alone.stdout.split() == ["None", "None"]
    kept = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                          env=dict(base, PYTEST_XDIST_WORKER_COUNT="2", OMP_NUM_THREADS="3"))
    assert kept.stdout.split()[0] == "3"  # a user's own setting wins


def test_main_thread_sched_counts_a_sleep_as_neither_run_nor_wait():
    """bench/test_times.py's blocked seconds: wall minus the main thread's run time and its wait for a core. A
    sleep is blocked time whatever the load (a sleeping thread neither runs nor waits for a core), a busy loop is
    not (it runs or waits for a core)."""
    import math
    import time

    r0, d0 = main_thread_sched()
    if math.isnan(r0):
        import pytest

        pytest.skip("no /proc/self/schedstat on this kernel")
    w0 = time.perf_counter()
    time.sleep(0.2)
    wall = time.perf_counter() - w0
    r1, d1 = main_thread_sched()
    assert wall - (r1 - r0) - (d1 - d0) >= 0.15
    w0, (r0, d0) = time.perf_counter(), (r1, d1)
    while time.perf_counter() - w0 < 0.1:
        pass
    wall = time.perf_counter() - w0
    r1, d1 = main_thread_sched()
    assert wall - (r1 - r0) - (d1 - d0) < 0.05
    assert r1 - r0 > 0


def test_slow_list_lines_with_and_without_seconds():
    text = ("# header\n"
            "tests/test_a.py::test_x  # 12.5\n"
            "tests/test_a.py::test_y[1-2]\n"
            "\n"
            "tests/test_b.py::test_z # 0.7 and a remark\n"
            "tests/test_b.py::test_w  # added by hand\n")
    assert parse_slow_list(text) == {"tests/test_a.py::test_x": 12.5, "tests/test_a.py::test_y[1-2]": UNMEASURED_S,
                                     "tests/test_b.py::test_z": 0.7, "tests/test_b.py::test_w": UNMEASURED_S}


def test_longest_files_first_keeps_each_file_together_and_in_order():
    ids = ["t/a.py::1", "t/a.py::2", "t/b.py::1", "t/c.py::1", "t/c.py::2", "t/d.py::1"]
    cost = {"t/a.py::2": 1.0, "t/c.py::1": 3.0, "t/c.py::2": 0.5, "t/d.py::1": 1.0}
    order = [ids[i] for i in longest_files_first(ids, cost)]
    # c (3.5) first; a and d tie at 1.0 and keep their order; b (no listed test) last
    assert order == ["t/c.py::1", "t/c.py::2", "t/a.py::1", "t/a.py::2", "t/d.py::1", "t/b.py::1"]
    assert sorted(longest_files_first(ids, {})) == list(range(len(ids)))
    assert [ids[i] for i in longest_files_first(ids, {})] == ids


def test_write_slow_list_merges_lines_it_did_not_measure(tmp_path):
    from bench.test_times import write_slow_list

    path = tmp_path / "slow_tests.txt"
    path.write_text("# old header\n"
                    "tests/test_a.py::test_old_now_fast\n"
                    "tests/test_b.py::test_added_by_hand  # 2.0\n"
                    "tests/test_c.py::test_file_not_run\n"
                    "tests/test_a.py::test_cheap  # 4.0 by hand: alone it starts the cluster\n")
    rows = [{"file": "tests/test_a.py", "tests": {"tests/test_a.py::test_cheap": [0.1, 0.1],
                                                  "tests/test_a.py::test_old_now_fast": [0.2, 0.2],
                                                  "tests/test_a.py::test_costly": [3.0, 2.5]}}]
    names = write_slow_list(path, rows, 0.5)
    listed = parse_slow_list(path.read_text())
    assert listed == {"tests/test_a.py::test_costly": 2.5, "tests/test_b.py::test_added_by_hand": 2.0,
                      "tests/test_c.py::test_file_not_run": UNMEASURED_S, "tests/test_a.py::test_cheap": 4.0}
    assert sorted(names) == sorted(listed)
    assert not list(tmp_path.glob("*.tmp"))


def _make_vars_and_recipes() -> tuple[dict[str, str], dict[str, str]]:
    """The Makefile's ``NAME ?= / := value`` lines and each target's recipe (its lines joined)."""
    import re

    values, recipes, target = {}, {}, None
    for ln in (ROOT / "Makefile").read_text().splitlines():
        if m := re.match(r"^([A-Z_]+)\s*[?:]?=\s*(.*)$", ln):
            values[m.group(1)] = m.group(2)
            target = None
        elif m := re.match(r"^([a-z][a-z-]*):", ln):
            target = m.group(1)
            recipes[target] = ""
        elif ln.startswith("\t") and target:
            recipes[target] += ln + "\n"
    return values, recipes


def test_make_test_keeps_the_file_order_of_conftest():
    """--dist loadfile's default reorder (by number of tests) would undo longest_files_first; both make
    targets run whole files on their workers: make test on JOBS (2: a third worker was slower in a
    quiet fresh clone), make test-fast on FAST_JOBS (2)."""
    values, recipes = _make_vars_and_recipes()
    assert "--dist loadfile" in values["XDIST_OPTS"] and "--no-loadscope-reorder" in values["XDIST_OPTS"]
    assert values["XDIST"] == "-n $(JOBS) $(XDIST_OPTS)" and values["JOBS"] == "2"
    assert "$(XDIST)" in recipes["test"] and "-m \"not slow\"" not in recipes["test"]
    assert "-n $(FAST_JOBS) $(XDIST_OPTS)" in recipes["test-fast"] and values["FAST_JOBS"] == "2"


def test_the_shipped_slow_list_parses_and_names_existing_files():
    listed = parse_slow_list((ROOT / "tests" / "slow_tests.txt").read_text())
    assert listed
    missing = sorted({n.split("::", 1)[0] for n in listed if not (ROOT / n.split("::", 1)[0]).is_file()})
    assert not missing, f"tests/slow_tests.txt names files that do not exist: {missing}"
    json.dumps(listed)  # plain str -> float


def test_warm_kernels_steps_run(monkeypatch):
    """scripts/warm_kernels.py reports and skips a failing step (set-up must not fail on it), so a step broken by
    an API change would silently stop warming its kernels: the cheap steps must run here (their kernels are
    cached by then). The default-pipeline and live-frame steps run the paths most tests run anyway."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("warm_kernels", ROOT / "scripts" / "warm_kernels.py")
    warm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(warm)
    steps = dict(warm.STEPS)
    assert {"default pipeline", "interleaver", "live frames", "avatars", "differentiable renderer",
            "reaction metrics", "visibility", "viewer normals"} <= set(steps)
    for name in ("avatars", "differentiable renderer", "reaction metrics"):
        steps[name]()


def test_the_suite_starts_no_background_mask_builds(monkeypatch):
    """conftest sets HOLO_VIEWER_BACKGROUND_BUILDS=0: `holo-viewer live` in a test (and its children) starts no
    nice-19 visible-mask build (~30 s of CPU each, outliving the test); with the variable at 1 it would."""
    from holo_viewer.pipeline import live_support

    started = []
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: started.append(a[0]))
    monkeypatch.setattr(live_support, "_later", set())
    monkeypatch.delenv("HOLO_VIEWER_TABLE_CACHE", raising=False)
    assert os.environ.get("HOLO_VIEWER_BACKGROUND_BUILDS") == "0"
    assert not live_support.build_visible_mask_later("default", 0.125) and not started
    monkeypatch.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "1")  # the variable is what stops it: the test can fail
    assert live_support.build_visible_mask_later("default", 0.125)
    assert len(started) == 1 and started[0][-2:] == ["default", "0.125"]
