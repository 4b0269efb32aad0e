"""The one rendering entry point: ``render_views(gaussians, cameras, backend, config)``.

Backends are modules of :mod:`holo_viewer.render` imported lazily by name; each exposes
``render(gaussians, cameras, config) -> RenderResult``.
"""

from __future__ import annotations

import importlib
import time
from typing import Literal

import numpy as np

from ..avatar.gaussians import Gaussians
from ..camera import Cameras
from ..errors import InputError, RenderError
from .config import RenderConfig, RenderResult

__all__ = ["render_views", "available_backends", "BACKENDS", "BackendName", "validate_inputs"]

BackendName = Literal["reference", "fast", "vtk", "torch", "gsplat", "auto"]

#: backend name -> module under holo_viewer.render
BACKENDS = {
    "reference": "reference",
    "fast": "fast",
    "vtk": "vtk_backend",
    "torch": "torch_backend",
    "gsplat": "gsplat_backend",
}

#: log-scales above this (scale e^50 m) overflow the covariance; rejected as bad input
MAX_LOG_SCALE = 50.0


def _load(name: str):  # noqa: ANN202
    try:
        return importlib.import_module(f"holo_viewer.render.{BACKENDS[name]}")
    except ImportError as exc:
        raise RenderError(f"backend {name!r}: cannot import holo_viewer.render.{BACKENDS[name]} ({exc})") from exc


def _auto_backend(config: RenderConfig) -> str:
    """gsplat where it runs (CUDA, gsplat importable) and honours ``config``, else fast."""
    from . import gsplat_backend

    try:
        gsplat_backend.check_config(config)
    except RenderError:
        return "fast"
    return "gsplat" if gsplat_backend.is_available() else "fast"


def available_backends() -> list[str]:
    """Names of the backends whose modules import here (checked lazily, not cached).

    "gsplat" additionally needs CUDA; "auto" is always available.
    """
    out = []
    for name, mod in BACKENDS.items():
        try:
            m = importlib.import_module(f"holo_viewer.render.{mod}")
        except ImportError:
            continue
        check = getattr(m, "is_available", None)
        if check is not None and not check():
            continue
        out.append(name)
    return out + ["auto"]


def validate_inputs(gaussians: Gaussians, cameras: Cameras) -> None:
    """Raise InputError for bad inputs: wrong types, NaN/inf, zero quaternions, overflowing scales."""
    if not isinstance(gaussians, Gaussians):
        raise InputError(f"gaussians: expected holo_viewer.avatar.Gaussians, found {type(gaussians).__name__}")
    if not isinstance(cameras, Cameras):
        raise InputError(f"cameras: expected holo_viewer.camera.Cameras, found {type(cameras).__name__}")
    gaussians.validate(context="render_views")
    ls = Gaussians._np(gaussians.log_scales)
    if ls.size and float(ls.max()) > MAX_LOG_SCALE:
        i = int(np.argmax(ls.max(axis=1)))
        raise InputError(f"render_views: log_scales: expected <= {MAX_LOG_SCALE} (scale e^{MAX_LOG_SCALE} m), "
                         f"found {float(ls.max()):.4g} at Gaussian {i}")


def render_views(gaussians: Gaussians, cameras: Cameras, backend: BackendName = "fast",
                 config: RenderConfig | None = None) -> RenderResult:
    """Render ``gaussians`` into every camera of ``cameras``.

    Parameters
    ----------
    gaussians : Gaussians
        N Gaussians (numpy or torch fields); validated here (NaN/inf -> InputError). With
        N = 0 every view is the background (any backend).
    cameras : Cameras
        V cameras of one image size (OpenCV conventions, see :mod:`holo_viewer.camera`).
    backend : {"fast", "reference", "vtk", "torch", "gsplat", "auto"}
        "auto" = gsplat when it imports, CUDA works and the config is one gsplat honours,
        else fast. (On an H100 machine gsplat renders the avatar quilt in 0.18 s, the fast CPU
        backend in 0.42-0.45 s on its 16 cores, the pure-torch backend on CUDA in 6 s:
        bench/render_gpu.py.)
    config : RenderConfig, optional
        Knobs (defaults: docs/design.md's forward pass).

    Returns
    -------
    RenderResult
        ``images`` (V, H, W, 3) float32 in [0, 1], row 0 at the top; ``timings`` per stage
        (seconds, including "validate" and "total"); ``stats``; ``backend``.

    Raises
    ------
    InputError
        Bad inputs or an unknown backend name.
    RenderError
        The backend cannot run here (missing module, no CUDA for gsplat, ...).
    """
    t0 = time.perf_counter()
    config = RenderConfig() if config is None else config
    if not isinstance(config, RenderConfig):
        raise InputError(f"config: expected RenderConfig, found {type(config).__name__}")
    if backend == "auto":
        backend = _auto_backend(config)
    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {sorted(BACKENDS) + ['auto']}, found {backend!r}")
    validate_inputs(gaussians, cameras)
    t1 = time.perf_counter()
    if len(gaussians) == 0:  # an empty scene is the background in every view, whatever the backend
        images = np.empty((len(cameras), cameras.height, cameras.width, 3), dtype=np.float32)
        images[...] = np.asarray(config.background, dtype=np.float32)
        return RenderResult(images=images, timings={"validate": t1 - t0, "total": time.perf_counter() - t0},
                            stats={"n_input": 0, "n_visible": 0}, backend=backend)
    module = _load(backend)
    result = module.render(gaussians, cameras, config)
    timings = {"validate": t1 - t0, **result.timings}
    timings["total"] = time.perf_counter() - t0
    return RenderResult(images=result.images, timings=timings, stats=result.stats, backend=result.backend)
