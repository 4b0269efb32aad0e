"""Offscreen rendering of the viewer scene (OSMesa), for ``holo-viewer snapshot``, docs and tests.

VTK picks its OpenGL window class from ``VTK_DEFAULT_OPENGL_WINDOW`` when a window is
created; :func:`osmesa_window` sets it to ``vtkOSOpenGLRenderWindow`` (software, no display
needed; apt ``libosmesa6``) only while the offscreen window is made, and restores it, so an
interactive window opened later in the same process is unaffected.
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterator

__all__ = ["osmesa_window", "offscreen_viewer"]



@contextlib.contextmanager
def osmesa_window() -> Iterator[None]:
    """Within the block, new VTK render windows are OSMesa offscreen windows (:mod:`holo_viewer.offscreen`)."""
    from ..offscreen import offscreen_window_class

    with offscreen_window_class(force_osmesa=True):
        yield


@contextlib.contextmanager
def offscreen_viewer(scene: Any, window_size: tuple[int, int] = (1600, 900), **config: Any) -> Iterator[Any]:
    """A :class:`~holo_viewer.gui.viewer.HoloViewer` rendering offscreen with OSMesa; closed on exit.

    ``scene`` is a :class:`~holo_viewer.pipeline.scene.Scene` or a Pipeline.
    """
    from .viewer import HoloViewer, ViewerConfig

    pipeline = getattr(scene, "pipeline", scene)
    frames = getattr(scene, "frames", None)
    config.setdefault("show_status", False)  # timings differ run to run; keep snapshots reproducible
    with osmesa_window():
        viewer = HoloViewer(pipeline, ViewerConfig(window_size=tuple(window_size), **config), off_screen=True,
                            frames=frames)
        viewer.open()
    try:
        yield viewer
    finally:
        viewer.close()
