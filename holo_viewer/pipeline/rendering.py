"""Gaussians + cameras -> views -> quilt: the one place the renderer and the quilt tiler are called.

:func:`render_quilt` is what every producer of quilts uses (the pipeline's ``views`` and
``quilt`` stages, the GUI's thumbnail worker and sweep video, the sweep export app, the demo);
:func:`render_images` is the single-camera-set form (one view, the reaction evaluation's frontal
renders).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from ..avatar.gaussians import Gaussians
    from ..camera import Cameras
    from ..render.config import RenderConfig

__all__ = ["render_images", "tile_views", "render_quilt"]


def render_images(gaussians: "Gaussians", cameras: "Cameras", *, backend: str = "fast",
                  config: "RenderConfig | None" = None) -> np.ndarray:
    """Render ``gaussians`` from every camera.

    Parameters
    ----------
    gaussians : Gaussians
        N world Gaussians.
    cameras : Cameras
        n_views cameras (one ``Cameras`` holds a batch).
    backend : str
        A :data:`holo_viewer.render.api.BACKENDS` name or ``"auto"``.
    config : RenderConfig or None

    Returns
    -------
    numpy.ndarray
        (n_views, H, W, 3) float32 images in [0, 1], row 0 at the top.
    """
    from ..render.api import render_views

    return render_views(gaussians, cameras, backend=backend, config=config).images


def tile_views(views: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Tile float ``views`` (n_views, H, W, 3) into a (rows*H, cols*W, 3) uint8 quilt, view 0 bottom-left
    (:func:`holo_viewer.display.native.views_to_native`, quilt only)."""
    from ..display.quilt import tile_quilt

    return tile_quilt(views, cols, rows, as_uint8=True)


def render_quilt(gaussians: "Gaussians", cameras: "Cameras", cols: int, rows: int, *, backend: str = "fast",
                 config: "RenderConfig | None" = None) -> np.ndarray:
    """Render the quilt's views and tile them.

    Parameters
    ----------
    gaussians : Gaussians
        N world Gaussians.
    cameras : Cameras
        The quilt's cameras, view 0 leftmost (``display.cameras.make_quilt_cameras``).
    cols, rows : int
        Quilt layout (8 x 6 on the Portrait).
    backend, config
        Renderer choice, as :func:`render_images`.

    Returns
    -------
    numpy.ndarray
        (rows*H, cols*W, 3) uint8 quilt.
    """
    return tile_views(render_images(gaussians, cameras, backend=backend, config=config), cols, rows)
