"""The X screen the viewer opens on: is it reachable, how large is it, what window fits it.

Plain libX11 through ctypes (no VTK window is made), so ``holo-viewer view`` can say why it cannot
open a window in one line, and size its window to the screen before VTK maps it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

import sys
import time
from typing import Any, Callable, TypeVar

from ..errors import DisplayError, InputError

__all__ = ["DEFAULT_WINDOW", "x_screen_size", "window_size_for_screen", "require_x_window", "open_window",
           "XInputWait", "x_input_wait"]

T = TypeVar("T")

#: the window size when the screen size is unknown (offscreen, no libX11)
DEFAULT_WINDOW: tuple[int, int] = (1400, 800)
#: the largest default window: more pixels cost frame time with software OpenGL, not legibility
MAX_WINDOW: tuple[int, int] = (1600, 960)


def x_screen_size(display: str | None = None) -> tuple[int, int] | None:
    """(width, height) in pixels of the default screen of X display ``display`` (default ``$DISPLAY``).

    Returns None when libX11 is not found; raises OSError naming the display when it cannot be opened
    (not set, nothing listening, or the server refused the connection).
    """
    display = os.environ.get("DISPLAY", "") if display is None else display
    if not display:
        raise OSError("no X display (DISPLAY is not set)")
    lib = ctypes.util.find_library("X11")
    if lib is None:
        return None
    x11 = ctypes.CDLL(lib)
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    x11.XDefaultScreen.argtypes = [ctypes.c_void_p]
    x11.XDisplayWidth.argtypes = [ctypes.c_void_p, ctypes.c_int]
    x11.XDisplayHeight.argtypes = [ctypes.c_void_p, ctypes.c_int]
    handle = x11.XOpenDisplay(display.encode())
    if not handle:
        raise OSError(f"cannot open the X display DISPLAY={display}")
    try:
        screen = x11.XDefaultScreen(handle)
        return int(x11.XDisplayWidth(handle, screen)), int(x11.XDisplayHeight(handle, screen))
    finally:
        x11.XCloseDisplay(handle)


def window_size_for_screen(screen: tuple[int, int] | None) -> tuple[int, int]:
    """The default window (width, height) for a screen of ``screen`` pixels (None: :data:`DEFAULT_WINDOW`).

    94 % of the width and 86 % of the height (room for a panel bar and the title bar), at most
    :data:`MAX_WINDOW`; the layout stays readable down to 800 x 450.
    """
    if screen is None:
        return DEFAULT_WINDOW
    sw, sh = int(screen[0]), int(screen[1])
    if sw <= 0 or sh <= 0:
        raise InputError(f"screen size: expected positive width and height, found {sw} x {sh}")
    return min(int(sw * 0.94), MAX_WINDOW[0]), min(int(sh * 0.86), MAX_WINDOW[1])


def require_x_window(ren_win: Any) -> None:
    """Raise DisplayError (one line) unless VTK made an X window for ``ren_win`` on Linux.

    When the X server refuses VTK's connection (a busy virtual server refuses some), VTK falls back to
    an EGL offscreen window that no X input reaches; pyvista then fails later, deep in its event
    processing, with ``MismatchedInteractorError``. This check says so at once.
    """
    if not sys.platform.startswith("linux"):
        return
    cls = type(ren_win).__name__
    if cls == "vtkXOpenGLRenderWindow":
        return
    display = os.environ.get("DISPLAY", "")
    raise DisplayError(f"view: the X server at DISPLAY={display} refused VTK's window (VTK made a {cls} instead, "
                       "which gets no X input); try again, or render without a display: holo-viewer snapshot")


def open_window(make: Callable[[], T], tries: int = 3) -> T:
    """``make()`` a window, trying again when the X server refused VTK's connection (a busy server
    refuses a few); the last refusal's one-line DisplayError goes to the caller."""
    for attempt in range(tries):
        try:
            return make()
        except DisplayError:
            if attempt == tries - 1:
                raise
            time.sleep(0.2)
    raise AssertionError("unreachable")


class XInputWait:
    """Sleep until the X connection of a VTK window has input, a wake-up file descriptor is written, or a
    timeout passes: the event loop's idle wait, so that an X event (a drag step) or a finished splat image
    is handled at once instead of after a fixed sleep.

    Xlib may already hold events read from the socket (during a frame's GLX round trips): ``XPending``
    (non-blocking) is asked first, and only an empty queue waits in ``select`` on the socket."""

    def __init__(self, display: int) -> None:
        x11 = ctypes.CDLL(ctypes.util.find_library("X11") or "libX11.so.6")
        x11.XConnectionNumber.argtypes = [ctypes.c_void_p]
        x11.XPending.argtypes = [ctypes.c_void_p]
        self._x11, self._display = x11, ctypes.c_void_p(display)
        self.fd = int(x11.XConnectionNumber(self._display))

    def wait(self, timeout: float, wake_fds: tuple[int, ...] = ()) -> bool:
        """Block at most ``timeout`` seconds; True when X input or a wake-up arrived (wake-ups are read)."""
        import select

        if self._x11.XPending(self._display) > 0:
            return True
        ready, _, _ = select.select([self.fd, *wake_fds], [], [], max(0.0, timeout))
        for fd in ready:
            if fd != self.fd:
                try:
                    os.read(fd, 4096)
                except BlockingIOError:
                    pass
        return bool(ready)


def x_input_wait(ren_win: Any) -> XInputWait | None:
    """An :class:`XInputWait` on ``ren_win``'s X connection, or None (not an X window, no libX11)."""
    if ren_win is None or not ren_win.IsA("vtkXOpenGLRenderWindow") or ren_win.GetOffScreenRendering():
        return None
    try:
        display = int(str(ren_win.GetGenericDisplayId()).split("_")[1], 16)
        if not display:
            return None
        return XInputWait(display)
    except (IndexError, ValueError, OSError, AttributeError):
        return None
