"""Build the optional C++ kernels: the fast splat renderer's and the eye slices' scatter.

Everything else about the package lives in pyproject.toml. The extension is ``optional``:
when no C++17 compiler is available the install still succeeds with a warning, and
``holo_viewer.render.fast`` and ``holo_viewer.display.slices`` fall back to their numba kernels.
"""

import platform
import sys

from setuptools import Extension, setup


def _cpu_has(flag: str) -> bool:
    """True when this (building) Linux machine's CPU reports ``flag`` in /proc/cpuinfo."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            return any(line.startswith("flags") and flag in line.split() for line in f)
    except OSError:
        return False


if sys.platform == "win32":
    args = ["/O2", "/std:c++17"]
    link = []
else:
    # -fno-math-errno, -fno-trapping-math: sqrt inlines to one instruction and the projection
    # loop (sqrt, ceil, floor) vectorises (nothing reads errno or FP traps); -ffp-contract=off:
    # the projection rounds exactly as the numba kernel (a test compares them); SIMD kernels are
    # chosen at run time by CPU feature, so the baseline stays generic, except SSE4.1 (inline
    # ceil/floor in the projection, 20% of its time) when the building CPU has it (every x86-64
    # CPU since 2011; the extension is compiled where it is installed); -fno-wrapv: undoes the
    # -fwrapv of Python's own CFLAGS (which come first), so signed index arithmetic may be assumed
    # not to overflow (the kernels never rely on wrapping): same bytes, 5-6 % less CPU in the tile
    # compositor and the interleave's row gather (measured A/B on live frames)
    args = ["-O3", "-std=c++17", "-pthread", "-fvisibility=hidden", "-fno-math-errno", "-fno-trapping-math",
            "-ffp-contract=off", "-fno-wrapv"]
    if platform.machine() in ("x86_64", "AMD64") and _cpu_has("sse4_1"):
        args.append("-msse4.1")
    link = ["-pthread"]

setup(
    ext_modules=[
        Extension(
            name,
            sources=[source],
            include_dirs=["holo_viewer/_cpu"],
            depends=["holo_viewer/_cpu/hv_common.h"],
            extra_compile_args=args,
            extra_link_args=link,
            language="c++",
            optional=True,
        )
        for name, source in (("holo_viewer.render._splat_cpp", "holo_viewer/render/_cpu/splat.cpp"),
                             ("holo_viewer.display._slices_cpp", "holo_viewer/display/_cpu/slices.cpp"))
    ]
)
