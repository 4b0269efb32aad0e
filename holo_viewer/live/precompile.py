"""Cold start: compile the view-synthesis kernels in a second process while ``live`` loads.

With an empty numba cache (a clone used without ``scripts/setup.sh``, or a new ``NUMBA_CACHE_DIR``)
the live command compiled every kernel of a group frame one after the other on one core before
its first frame: 30-41 s on 2 quiet cores, of which the four kernels of
:mod:`holo_viewer.render.view_synthesis` (the z-buffer depth of the rendered views and of the eye
slices, the row extents and the warp; where the C++ warp is built, since c86ff49, that one needs no compile:
:data:`KERNELS`) were about two thirds of the compile time (measured with
numba's compile events, docs/live.md). :class:`BackgroundCompile` starts ``python -m
holo_viewer.live.precompile`` twice (the depth kernels, the warp kernels: about equal halves)
when those kernels are not cached: each child calls the module's public functions on a tiny rig, with the argument types the live renderer passes, so numba
compiles and caches the same specialisations while the parent loads the avatar, compiles the
other kernels, builds the panel tables and loads the reaction model on the other core. The
parent's first call of one of those kernels waits until the child reports it compiled (the module
attributes are wrapped until then) and then loads it from the cache. A child that fails or is too slow is
harmless: the parent compiles what is not cached, as before. Nothing is started when the kernels
are cached (every start after the first) or with ``HOLO_VIEWER_PRECOMPILE=0``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from typing import Any, Callable

__all__ = ["KERNELS", "BackgroundCompile", "kernels_cached", "compile_kernels"]

def _warp_kernels() -> tuple[str, ...]:
    """The numba kernels of the warp the live path calls: ``_row_extents`` and ``_warp_u8`` where the C++
    ones are not built (or ``view_synthesis.WARP_KERNEL`` is ``"numba"``), else none (the C++ ``row_extents``,
    ``warp_u8`` and ``warp_native`` need no compile; since 2026-11-29 the C++ ``row_extents`` too).
    Until 2026-11-28 this list named ``_warp`` (the float views' and exact path's kernel), which no live
    frame calls: it was never cached by a live session, so :func:`kernels_cached` stayed False and both
    children started at every ``live`` start (~1 s of CPU each on a warm cache, beside the parent's
    start-up on 2 cores)."""
    from ..render import view_synthesis as vs

    cpp = None if vs.WARP_KERNEL == "numba" else vs._warp_cpp()
    return (("_row_extents",) if cpp is None or not hasattr(cpp, "row_extents") else ()) + (
        ("_warp_u8",) if cpp is None else ())


#: the children: each compiles one group (about equal halves of the compile time without the C++ warp); a group
#: with nothing to compile (the warp's, where the C++ kernels are built) starts no child
GROUPS = {k: v for k, v in {"depth": ("_zbuffer_coef", "_zbuffer"), "warp": _warp_kernels()}.items() if v}

#: the view_synthesis dispatchers the children compile (module attribute names): those the default live
#: frames call (the numba ``_warp`` and ``_warp_u8`` stay reachable: they compile on their first call)
KERNELS = tuple(k for g in GROUPS.values() for k in g)

#: set to 0 to never start the children
ENV_VAR = "HOLO_VIEWER_PRECOMPILE"


def kernels_cached() -> bool:
    """True when numba's cache holds an index for each of :data:`KERNELS` (then nothing compiles
    them at start-up); True too when the cache cannot be inspected (start nothing then)."""
    from ..render import view_synthesis as vs

    try:
        return all(os.path.exists(getattr(vs, k)._cache._cache_file._index_path) for k in KERNELS)
    except Exception:  # noqa: BLE001 - numba internals moved: behave as before (no child)
        return True


def compile_kernels(groups: tuple[str, ...] = tuple(GROUPS), report: Callable[[str], None] = lambda name: None
                    ) -> None:
    """Compile the kernels of ``groups`` (:data:`GROUPS`), in the order the live renderer first calls
    them, through the functions of view_synthesis on a 3-view, 6x8-pixel rig (the argument types,
    not the sizes, select the specialisation); ``report(name)`` after each: what a child runs."""
    import numpy as np

    from ..display.calibration import DisplayCalibration
    from ..display.cameras import make_quilt_cameras
    from ..render import view_synthesis as vs

    cal = DisplayCalibration.load(None).with_quilt(3, 1, 18, 8)  # 3 views of 6x8 pixels
    cams = make_quilt_cameras(cal, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)
    rig = vs.rig_of(cams)
    rng = np.random.default_rng(0)
    means = rng.uniform(-0.05, 0.05, (64, 3))
    opacity = np.ones(64)
    V, H, W = len(cams), cams.height, cams.width
    src = vs.source_views(V, 2)  # views 0 and 2 rendered, 1 synthesized
    if "depth" in groups:
        R = np.asarray(cams.R[0], dtype=np.float64)
        coef = np.tile([1.0, 0.0, 0.0, 0.0, 1.0], (2, 1))  # the eye slices' column rows (a, b, c, e, f)
        vs.zbuffer_depth(means, opacity, R, 0.0, 0.6, coef, 100.0, H / 2, 0.01, H, W, 1.0)
        report("_zbuffer_coef")
        vs.inverse_depth(means, opacity, cams, src, rig=rig)
        report("_zbuffer")
    if "warp" in groups and "warp" in GROUPS:
        wmaps = np.full((src.size, H, W), 1.0 / 0.6, dtype=np.float32)  # (not from _zbuffer: the other group's)
        images = rng.uniform(0, 1, (src.size, H, W, 3)).astype(np.float32)
        if "_row_extents" in GROUPS["warp"]:
            vs._row_extents(images, wmaps, np.zeros(3, np.float32), np.empty((src.size, H, 2), np.int64),
                            np.empty((src.size, H, 2), np.float64))  # as warp_views calls it
            report("_row_extents")
        quilt = np.zeros((cal.quilt_height, cal.quilt_width, 3), np.uint8)
        tiles = np.array([[0, k * W] for k in range(V)], dtype=np.int64)
        pixels = vs.sampled_columns(np.ones((V, H, W), dtype=bool))
        if "_warp_u8" in GROUPS["warp"]:  # the numba warp of the quilt path (else the C++ one: nothing to compile)
            vs.warp_views(images, wmaps, src, rig, quilt=quilt, tiles=tiles, pixels=pixels)  # as live calls it
            report("_warp_u8")


class BackgroundCompile:
    """Start one child per :data:`GROUPS` entry when :data:`KERNELS` are not cached; until its child
    has compiled a kernel, calling it (through :mod:`~holo_viewer.render.view_synthesis`'s
    functions) first waits for it (each kernel as soon as its child reports it, so the parent's
    later steps overlap the children's later compiles). ``started``: whether children were
    started; ``waited_s``: the seconds the parent's calls waited; ``returncode``: the first
    non-zero exit status of a child (else 0, None while running); :meth:`close` restores the
    kernels and stops a child still running."""

    #: a child's command, its group appended (it prints each kernel's name once compiled and cached)
    command: tuple[str, ...] = (sys.executable, "-m", __name__)

    def __init__(self, timeout_s: float = 180.0) -> None:
        self.timeout_s = float(timeout_s)
        self.started = False
        self.waited_s = 0.0
        self.returncode: int | None = None
        self._procs: list[subprocess.Popen] = []
        self._cond = threading.Condition()
        self._done: set[str] = set()
        self._alive: set[str] = set()  # the groups whose child still runs
        self._real: dict[str, Any] = {}
        if os.environ.get(ENV_VAR, "1") == "0" or kernels_cached():
            return
        for group in GROUPS:
            try:
                proc = subprocess.Popen([*self.command, group], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=subprocess.DEVNULL, text=True)
            except OSError:
                break
            self._procs.append(proc)
            self._alive.add(group)
            threading.Thread(target=self._read, args=(proc, group), name=f"precompile-{group}", daemon=True).start()
        self.started = bool(self._procs)
        if not self.started:
            return
        from ..render import view_synthesis as vs

        for name in KERNELS:
            self._real[name] = getattr(vs, name)
            setattr(vs, name, self._waiting(name))

    def _read(self, proc: subprocess.Popen, group: str) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with self._cond:
                self._done.add(line.strip())
                self._cond.notify_all()
        code = proc.wait()
        with self._cond:
            self.returncode = code if self.returncode in (None, 0) else self.returncode
            self._alive.discard(group)
            self._cond.notify_all()

    def _waiting(self, name: str) -> Callable:
        group = next(g for g, names in GROUPS.items() if name in names)

        def call(*args: Any, **kwargs: Any) -> Any:
            t = time.perf_counter()
            with self._cond:  # its child compiled it, exited (failed: compile here), or is too slow
                self._cond.wait_for(lambda: name in self._done or group not in self._alive, timeout=self.timeout_s)
            self.waited_s += time.perf_counter() - t
            real = self._restore(name)
            return real(*args, **kwargs)

        return call

    def _restore(self, name: str) -> Any:
        from ..render import view_synthesis as vs

        real = self._real.pop(name, None)
        if real is not None:
            setattr(vs, name, real)
        return real if real is not None else getattr(vs, name)

    def close(self) -> None:
        """Restore every kernel; stop a child that still runs (what it did not cache compiles here)."""
        for name in list(self._real):
            self._restore(name)
        for proc in self._procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


if __name__ == "__main__":
    compile_kernels(tuple(sys.argv[1:]) or tuple(GROUPS), lambda name: print(name, flush=True))
