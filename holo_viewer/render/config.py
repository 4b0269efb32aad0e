"""Renderer configuration and result types (shared by every backend).

Every knob that trades error for time is a field of :class:`RenderConfig`. The float64
reference honours every *semantic* knob (they define the forward pass it computes); the
implementation knobs (``tile_size``, ``num_threads``, ``kernel``, ``max_chunk_bytes``)
change only how the fast backends get there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..errors import InputError

__all__ = ["RenderConfig", "RenderResult", "KernelName"]

#: compositing kernel of the fast backend: "auto" = C++ when built, else numba
KernelName = Literal["auto", "cpp", "numba"]

#: smallest alpha threshold the fast kernels' polynomial exp covers (see fast_kernels.py)
MIN_ALPHA_THRESHOLD = 1e-5


@dataclass(frozen=True)
class RenderConfig:
    """How to render (all backends).

    Attributes
    ----------
    background : tuple of 3 float
        RGB in [0, 1] composited behind the splats with the remaining transmittance.
    alpha_threshold : float
        Skip a splat at a pixel where its alpha is below this (default 1/255, Inria). Raising it
        shrinks every splat's pixel box (fewer blends) at the cost of its faint skirt.
        Range [1e-5, 0.5].
    radius_sigmas : float
        Splat extent: a splat touches pixel centres within the square of half-size
        ``ceil(radius_sigmas * sqrt(lambda_max))`` pixels around its centre (default 3).
        Lower is faster but cuts the Gaussian's tails.
    sh_degree : int or None
        Highest SH degree evaluated (None = all the Gaussians carry). Lower is faster
        preprocessing and loses view-dependent colour.
    shared_sh : bool
        Evaluate SH once, from the mean position of all cameras (the quilt's centre), and use
        the colour in every view. Saves V-1 SH evaluations; the error grows with the view cone.
    tile_size : int
        Square tile edge in pixels for binning (fast backends; 16, the size the AVX-512 and AVX2
        row compositors take, measured best).
    cull_margin : float or None
        Frustum culling by centre, per view: a splat whose projected centre lies outside the
        image extended on every side by ``cull_margin`` times the image width (x) / height (y)
        is dropped from that view even if its footprint would reach into the image (Inria uses
        the equivalent of 0.15). None (default) = exact: only the footprint box is tested,
        nothing visible is ever culled. Smaller is faster on scenes larger than the frame.
    alpha_cap : float
        Upper bound of alpha per splat (0.99).
    t_min : float
        Early termination: a pixel stops after the splat that takes its transmittance below this
        (that splat is blended: the colour left out is < t_min, and the rule is continuous; 3DGS
        stops before it, leaving out up to T alpha, ~1e-2 for an opaque splat).
    dilation : float
        Added to the 2D covariance diagonal (pixels^2): the 3DGS low-pass filter.
    near : float or None
        Splats with view depth <= near are culled (None = the cameras' ``near``).
    num_threads : int or None
        Worker threads of the fast backend (None = all cores).
    kernel : {"auto", "cpp", "numba"}
        Compositing kernel of the fast backend ("cpp" raises RenderError when the compiled
        extension is missing).
    max_chunk_bytes : int
        Memory bound of the fast backend: views are processed in chunks whose per-view
        splat and tile-list buffers stay below this many bytes (never N x pixels).
    clip_output : bool
        Clip the final colour to [0, 1] (SH colours may exceed 1). Default True.
    """

    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    alpha_threshold: float = 1.0 / 255.0
    radius_sigmas: float = 3.0
    sh_degree: int | None = None
    shared_sh: bool = False
    tile_size: int = 16
    cull_margin: float | None = None
    alpha_cap: float = 0.99
    t_min: float = 1e-4
    dilation: float = 0.3
    near: float | None = None
    num_threads: int | None = None
    kernel: KernelName = "auto"
    max_chunk_bytes: int = 128 * 2**20
    clip_output: bool = True

    def __post_init__(self) -> None:
        bg = tuple(float(c) for c in self.background)
        if len(bg) != 3 or not all(math.isfinite(c) and 0.0 <= c <= 1.0 for c in bg):
            raise InputError(f"RenderConfig.background: expected 3 values in [0, 1], found {self.background!r}")
        object.__setattr__(self, "background", bg)
        _range("alpha_threshold", self.alpha_threshold, MIN_ALPHA_THRESHOLD, 0.5)
        _range("radius_sigmas", self.radius_sigmas, 0.5, 10.0)
        _range("alpha_cap", self.alpha_cap, 0.01, 1.0)
        _range("t_min", self.t_min, 0.0, 0.5)
        _range("dilation", self.dilation, 0.0, 100.0)
        if self.alpha_threshold > self.alpha_cap:
            raise InputError(f"RenderConfig.alpha_threshold: expected <= alpha_cap ({self.alpha_cap}), "
                             f"found {self.alpha_threshold}")
        if self.sh_degree is not None and (int(self.sh_degree) != self.sh_degree or not 0 <= self.sh_degree <= 3):
            raise InputError(f"RenderConfig.sh_degree: expected None or an integer in 0..3, found {self.sh_degree!r}")
        if int(self.tile_size) != self.tile_size or not 4 <= self.tile_size <= 64:
            raise InputError(f"RenderConfig.tile_size: expected an integer in 4..64, found {self.tile_size!r}")
        if self.cull_margin is not None:
            _range("cull_margin", self.cull_margin, 0.0, 1e6)
        if self.near is not None:
            _range("near", self.near, 0.0, 1e6, low_open=True)
        if self.num_threads is not None and (int(self.num_threads) != self.num_threads or self.num_threads < 1):
            raise InputError(f"RenderConfig.num_threads: expected None or a positive integer, "
                             f"found {self.num_threads!r}")
        if self.kernel not in ("auto", "cpp", "numba"):
            raise InputError(f"RenderConfig.kernel: expected 'auto', 'cpp' or 'numba', found {self.kernel!r}")
        if int(self.max_chunk_bytes) < 2**20:
            raise InputError(f"RenderConfig.max_chunk_bytes: expected >= 1 MiB, found {self.max_chunk_bytes}")


def _range(name: str, v: float, low: float, high: float, low_open: bool = False) -> None:
    ok = isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(float(v))
    ok = ok and (float(v) > low if low_open else float(v) >= low) and float(v) <= high
    if not ok:
        bracket = "(" if low_open else "["
        raise InputError(f"RenderConfig.{name}: expected a number in {bracket}{low}, {high}], found {v!r}")


@dataclass(frozen=True)
class RenderResult:
    """Output of every backend.

    Attributes
    ----------
    images : numpy.ndarray
        (V, H, W, 3) float32 in [0, 1], row 0 at the top, one image per camera.
    timings : dict
        Stage name -> seconds ("validate", "preprocess", "sort", "bin", "composite", "total", ...).
    stats : dict
        Counters: "n_input", "n_visible" (splats visible in at least one view),
        "mean_blends_per_pixel" where cheap, ...
    backend : str
        Name of the backend that rendered (e.g. "reference", "fast/cpp", "fast/numba").
    """

    images: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict[str, float | int] = field(default_factory=dict)
    backend: str = ""
