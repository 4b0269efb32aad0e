"""One offscreen-VTK policy: how the baseline renderer, the mesh preview and snapshots get a window.

VTK picks its OpenGL window class from ``VTK_DEFAULT_OPENGL_WINDOW`` when a render window is
*created*. The policy, the same everywhere:

* without a display (no ``DISPLAY`` / ``WAYLAND_DISPLAY``), or when ``force_osmesa`` is asked,
  the OSMesa window (``vtkOSOpenGLRenderWindow``; software, apt ``libosmesa6``) is chosen;
* a choice the user made (the variable already set, e.g. ``vtkEGLRenderWindow``) wins unless
  ``force_osmesa``;
* the variable is set only while the window is created and restored right after, so nothing
  changes for the rest of the process (an interactive GUI window opened later is unaffected).

VTK itself is imported by the callers (lazily); this module imports nothing heavy.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any, Callable, Iterator

from .errors import RenderError

__all__ = ["WINDOW_ENV", "uses_display", "offscreen_window_class", "new_offscreen_window"]

#: environment variable that picks VTK's OpenGL window class at ``vtkRenderWindow()``
WINDOW_ENV = "VTK_DEFAULT_OPENGL_WINDOW"
OSMESA = "vtkOSOpenGLRenderWindow"


def uses_display() -> bool:
    """True when an X11 or Wayland display is in use (then VTK's default window works)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@contextlib.contextmanager
def offscreen_window_class(force_osmesa: bool = False) -> Iterator[str | None]:
    """Within the block, new VTK render windows follow the policy above; yields the class chosen (None: VTK's default)."""
    old = os.environ.get(WINDOW_ENV)
    if force_osmesa or (old is None and not uses_display()):
        os.environ[WINDOW_ENV] = OSMESA
    try:
        yield os.environ.get(WINDOW_ENV)
    finally:
        if old is None:
            os.environ.pop(WINDOW_ENV, None)
        else:
            os.environ[WINDOW_ENV] = old


def new_offscreen_window(render_window_class: Callable[[], Any], width: int, height: int, *,
                         force_osmesa: bool = False, multisamples: int | None = 0, what: str = "VTK") -> Any:
    """An offscreen VTK render window of ``width`` x ``height`` (the policy of this module).

    Parameters
    ----------
    render_window_class : callable
        ``vtkRenderWindow`` (the caller imports VTK).
    width, height : int
        Pixels.
    force_osmesa : bool
        Use OSMesa even with a display.
    multisamples : int or None
        ``SetMultiSamples`` value (None: VTK's default).
    what : str
        Named in the error message.

    Raises
    ------
    RenderError
        When no offscreen OpenGL context can be created (with how to get one).
    """
    with offscreen_window_class(force_osmesa) as chosen:
        rw = render_window_class()
    rw.SetOffScreenRendering(1)
    if multisamples is not None:
        rw.SetMultiSamples(int(multisamples))
    rw.SetSize(int(width), int(height))
    if not rw.SupportsOpenGL():
        raise RenderError(f"{what}: no usable offscreen OpenGL context ({chosen or rw.GetClassName()}); install "
                          f"OSMesa (apt-get install libosmesa6) or set {WINDOW_ENV}=vtkEGLRenderWindow")
    return rw
