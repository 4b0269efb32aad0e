"""holo_viewer: talking-face Gaussian avatars as live holograms on Looking Glass displays.

Importing the package is cheap: it loads no vtk, pyvista, open3d, usb or torch-heavy
modules. Subpackages (data flow, docs/design.md section 2):

``flame``     FLAME head model (LBS), the embedded default head, expressions and pain
``avatar``    3D Gaussians, PLY I/O, triangle-bound (rigged) and blend-shape avatars
``render``    splat renderers: float64 reference, fast multi-view CPU, VTK/OSMesa
``display``   Looking Glass calibration, multi-view cameras, quilts, lenticular interleave
``reaction``  listener-reaction generator, REACT metrics, baselines
``pipeline``  the one place that chains the stages (stage table, caching, streaming, render_quilt)
``commands``  one module per ``holo-viewer`` subcommand; ``gui`` the PyVista viewer; ``batch`` render-batch

Shared base modules: ``errors``, ``validation``, ``fileio``, ``geometry`` (rotations), ``camera``,
``images`` (float -> uint8), ``cache`` (the cache folder), ``offscreen`` (offscreen VTK windows),
``testing`` (small random models and avatars for tests).
"""

__version__ = "0.1.0"

import os as _os

# OpenMP worker threads (numba's "omp" threading layer, torch) sleep between parallel regions
# instead of spinning: the compiled C++ kernels run their own threads right after numba's
# regions, and a live session shares the cores with its tracker and reaction threads. Spinning
# workers took a core from them (tracked live frame on 2 cores: 60-65 ms median against 62-73 ms,
# the slices scatter 18 against 20-22 ms, measured in alternating runs). An explicit setting wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from .errors import HoloViewerError  # noqa: E402

__all__ = ["__version__", "HoloViewerError"]
