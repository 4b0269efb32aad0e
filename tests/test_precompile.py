"""Cold start (issue 33): the view-synthesis kernels compile in a second process while ``live`` loads
(holo_viewer/live/precompile.py). A stand-in child replaces the real one (which compiles for ~20 s
of CPU on an empty numba cache): the parent's calls wait for each kernel's report, get the real
kernel back, and a child that fails leaves the calls to compile as before."""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest

from holo_viewer.live import precompile
from holo_viewer.render import view_synthesis as vs


def _child(script: str) -> tuple[str, ...]:
    return (sys.executable, "-c", script)


@pytest.fixture
def cold(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(precompile, "kernels_cached", lambda: False)
    monkeypatch.delenv(precompile.ENV_VAR, raising=False)
    real = {k: getattr(vs, k) for k in precompile.KERNELS}
    yield real
    for k, v in real.items():  # whatever the test did, the module keeps its kernels
        setattr(vs, k, v)


def test_calls_wait_for_the_childs_report_then_run_the_real_kernel(cold, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(precompile.BackgroundCompile, "command", _child(
        "import time; print('_zbuffer_coef', flush=True); time.sleep(0.6); print('_zbuffer', flush=True); "
        "time.sleep(30)"))
    calls = []
    bc = precompile.BackgroundCompile(timeout_s=20)
    assert bc.started and all(getattr(vs, k) is not cold[k] for k in precompile.KERNELS)
    # the kernels the wrappers hand back, replaced by recorders (their arguments are not the point here)
    bc._real = {k: (lambda *a, _k=k: calls.append((_k, time.perf_counter()))) for k in bc._real}
    t0 = time.perf_counter()
    vs._zbuffer(1, 2)  # waits for the child's second report (~0.6 s)
    assert calls[0][0] == "_zbuffer" and calls[0][1] - t0 >= 0.3 and bc.waited_s >= 0.3
    assert getattr(vs, "_zbuffer") is not cold["_zbuffer"]  # restored to what _real held (the recorder)
    bc.close()  # stops the children; every kernel restored
    assert len(bc._procs) == len(precompile.GROUPS) and all(p.poll() is not None for p in bc._procs) and not bc._real


def test_a_failing_child_does_not_block_the_kernels(cold, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(precompile.BackgroundCompile, "command", _child("import sys; sys.exit(3)"))
    bc = precompile.BackgroundCompile(timeout_s=20)
    assert bc.started
    means = np.zeros((4, 3))
    coef = np.tile([1.0, 0.0, 0.0, 0.0, 1.0], (1, 1))
    out = vs.zbuffer_depth(means, np.ones(4), np.eye(3), 0.0, 0.6, coef, 100.0, 2.0, 0.01, 4, 4, 1.0)
    assert out.shape == (1, 4, 4) and bc.waited_s < 10 and bc.returncode == 3
    assert vs._zbuffer_coef is cold["_zbuffer_coef"]  # the real kernel again
    bc.close()
    assert all(getattr(vs, k) is cold[k] for k in precompile.KERNELS)


def test_nothing_starts_when_cached_or_switched_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(precompile, "kernels_cached", lambda: True)
    assert not precompile.BackgroundCompile().started
    monkeypatch.setattr(precompile, "kernels_cached", lambda: False)
    monkeypatch.setenv(precompile.ENV_VAR, "0")
    assert not precompile.BackgroundCompile().started
