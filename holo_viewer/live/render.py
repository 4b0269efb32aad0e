"""The one place the live loop touches the render pipeline (an adapter, so a new pipeline API is a
one-function change): face + viewer pose in, native image (and a preview view) out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

__all__ = ["LiveRenderer", "RenderedFrame"]


@dataclass
class RenderedFrame:
    """``native`` (H, W, 3) uint8 or None, ``preview`` (h, w, 3) float32 or None, ``seconds``."""

    native: np.ndarray | None
    preview: np.ndarray | None
    seconds: float


class LiveRenderer:
    """Render the default avatar for the live loop through :class:`holo_viewer.pipeline.Pipeline`.

    Parameters
    ----------
    tile_scale : float
        Quilt tile size relative to the calibration's (1 = full 420x560 tiles; smaller is faster).
    native : bool
        Compute the native (lenticular) image (the panel and the recorded video need it).
    preview : bool
        Render the one view that faces the tracked viewer (the desktop preview).
    backend : str
        Renderer backend.
    calibration : DisplayCalibration, optional
    render_threads : int, optional
        Renderer threads (default: all cores but one).
    """

    def __init__(self, tile_scale: float = 1.0, native: bool = True, preview: bool = False, backend: str = "fast",
                 calibration: Any = None, render_threads: int | None = None) -> None:
        import os

        from ..pipeline import Pipeline, ViewSettings
        from ..render.config import RenderConfig

        # leave one core to the tracker and reaction threads: rendering must never starve the stream
        threads = max(1, (os.cpu_count() or 2) - 1) if render_threads is None else int(render_threads)
        self.pipeline = Pipeline(calibration=calibration, view=ViewSettings(tile_scale=tile_scale), backend=backend,
                                 render_config=RenderConfig(num_threads=threads))
        self.native_enabled = bool(native)
        self.preview_enabled = bool(preview)

    def render(self, listener: Mapping[str, np.ndarray], pain: float, named: tuple[tuple[str, float], ...],
               viewer_angle_deg: float, viewer_distance_m: float) -> RenderedFrame:
        """One frame: FLAME arrays of one listener frame (``expr``, ``jaw_pose``, ``rotation``, ...)."""
        import time

        from ..pipeline import FaceControls

        t0 = time.perf_counter()
        p = self.pipeline
        n_expr = int(p.model.n_expr)
        expr = np.asarray(listener["expr"], dtype=np.float64)[:n_expr]
        p.set_face(FaceControls(expr=expr, jaw_pose=listener.get("jaw_pose"), rotation=listener.get("rotation"),
                                named=named, pain=float(pain)))
        p.set_view(viewer_angle=float(np.clip(viewer_angle_deg, -60, 60)),
                   viewer_distance=float(np.clip(viewer_distance_m, 0.05, 20.0)))
        native = p.native() if self.native_enabled else None
        preview = None
        if self.preview_enabled:
            # the centre view looks from the viewer's angle (the cone is centred on the viewer)
            n = len(p.cameras())
            preview = p.get("views")[n // 2] if self.native_enabled else p.render_view(n // 2)
        return RenderedFrame(native=native, preview=preview, seconds=time.perf_counter() - t0)
