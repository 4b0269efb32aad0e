"""Splat renderers behind one API (:func:`render_views`).

Backends (imported lazily by name): ``reference`` (float64 oracle), ``fast`` (compiled
multi-view CPU rasterizer: C++ AVX2 kernel, numba fallback), ``vtk``, ``torch``, ``gsplat``.
"""

from .api import available_backends, render_views
from .config import RenderConfig, RenderResult

__all__ = ["render_views", "available_backends", "RenderConfig", "RenderResult"]
