"""Build the optional C++ tile compositor of the fast splat renderer.

Everything else about the package lives in pyproject.toml. The extension is ``optional``:
when no C++17 compiler is available the install still succeeds with a warning, and
``holo_viewer.render.fast`` falls back to its numba kernel.
"""

import sys

from setuptools import Extension, setup

if sys.platform == "win32":
    args = ["/O2", "/std:c++17"]
    link = []
else:
    args = ["-O3", "-std=c++17", "-pthread", "-fvisibility=hidden"]
    link = ["-pthread"]

setup(
    ext_modules=[
        Extension(
            "holo_viewer.render._splat_cpp",
            sources=["holo_viewer/render/_cpu/splat.cpp"],
            extra_compile_args=args,
            extra_link_args=link,
            language="c++",
            optional=True,
        )
    ]
)
