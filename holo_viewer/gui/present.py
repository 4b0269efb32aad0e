"""Copy only the panels a frame drew to the X window (partial present).

VTK (9.x) renders into its own framebuffer, copies it to a display framebuffer and then, at the end
of every frame, blits the *whole* display framebuffer into the window's back buffer and swaps. With
software OpenGL (Mesa llvmpipe under Xvfb) that last blit is most of a frame that draws one panel:
~18 ms CPU of a ~21 ms scene-only frame at 1600 x 928 (the swap itself is ~0.2 ms; Xvfb does the copy
in its own process). :class:`RegionPresenter` turns VTK's blit to the window off
(``SetFrameBlitModeToNoBlit``) and, after each frame, blits only the rectangle of the panels drawn
from the display framebuffer into the back buffer (``vtkOpenGLRenderWindow.BlitDisplayFramebuffer``)
and copies that rectangle to the window with ``glXCopySubBufferMESA`` (GLX_MESA_copy_sub_buffer,
which Mesa's software GLX has). VTK's own swap still runs and shows the back buffer, which always
holds the last complete picture.

The display framebuffer (what :meth:`HoloViewer.read_pixels` and screenshots read) is unchanged by
this; the window shows the same pixels (``tests/test_gui.py::test_partial_present_window_matches_
the_framebuffer`` reads the X window back with ``XGetImage``). Where the extension is missing (another
GLX driver, EGL, offscreen) :func:`region_presenter` returns None and VTK presents the whole frame as
before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import Any

__all__ = ["RegionPresenter", "region_presenter", "x_window_pixels"]

_GL_COLOR_BUFFER_BIT = 0x4000
_GL_NEAREST = 0x2600
_COPY_SUB = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                             ctypes.c_int)


def _pointer(vtk_id: Any) -> int:
    """The address in a VTK ``'_000055d0c0a1b2c0_p_void'`` id string."""
    return int(str(vtk_id).split("_")[1], 16)


class RegionPresenter:
    """Presents rectangles of a ``vtkXOpenGLRenderWindow``'s display framebuffer (see the module)."""

    def __init__(self, ren_win: Any, copy_sub: Any, display: int, window: int) -> None:
        self.ren_win = ren_win
        self._copy_sub = copy_sub
        self._display = display
        self._window = window
        ren_win.SetFrameBlitModeToNoBlit()
        self.presented = 0  # rectangles presented (tests)

    def present(self, box: tuple[int, int, int, int] | None = None) -> None:
        """Copy ``box`` = (x0, y0, x1, y1) (inclusive display pixels, y from the bottom; None: the whole
        window) of the last frame to the window. Call right after ``ren_win.Render()``."""
        W, H = self.ren_win.GetSize()
        x0, y0, x1, y1 = (0, 0, W - 1, H - 1) if box is None else box
        x0, y0 = max(0, int(x0)), max(0, int(y0))
        w, h = min(W, int(x1) + 1) - x0, min(H, int(y1) + 1) - y0
        if w <= 0 or h <= 0:
            return
        self.ren_win.MakeCurrent()
        self.ren_win.BlitDisplayFramebuffer(0, x0, y0, w, h, x0, y0, w, h, _GL_COLOR_BUFFER_BIT, _GL_NEAREST)
        self._copy_sub(self._display, self._window, x0, y0, w, h)
        self.presented += 1

    def close(self) -> None:
        """Back to VTK's whole-frame present (the render window may outlive the viewer's use of it)."""
        self.ren_win.SetFrameBlitModeToBlitToHardware()


def region_presenter(ren_win: Any) -> RegionPresenter | None:
    """A :class:`RegionPresenter` for ``ren_win``, or None where it cannot work (not a GLX window, no
    libGL, no ``glXCopySubBufferMESA``): VTK then presents every frame whole, as before."""
    if ren_win is None or not ren_win.IsA("vtkXOpenGLRenderWindow") or ren_win.GetOffScreenRendering():
        return None
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("GL") or "libGL.so.1")
        gpa = lib.glXGetProcAddressARB
    except (OSError, AttributeError):
        return None
    gpa.restype = ctypes.c_void_p
    gpa.argtypes = [ctypes.c_char_p]
    addr = gpa(b"glXCopySubBufferMESA")
    if not addr:
        return None
    try:
        display, window = _pointer(ren_win.GetGenericDisplayId()), _pointer(ren_win.GetGenericWindowId())
    except (IndexError, ValueError):
        return None
    if not display or not window:
        return None
    query = lib.glXQueryExtensionsString  # glXGetProcAddress answers any name: the driver must list it
    query.restype = ctypes.c_char_p
    query.argtypes = [ctypes.c_void_p, ctypes.c_int]
    if b"GLX_MESA_copy_sub_buffer" not in (query(display, 0) or b"").split():
        return None
    return RegionPresenter(ren_win, _COPY_SUB(addr), display, window)


def x_window_pixels(ren_win: Any) -> Any:
    """(H, W, 3) uint8 pixels of the X window itself, top row first (``XGetImage``; tests), or None."""
    import numpy as np

    try:
        x11 = ctypes.CDLL(ctypes.util.find_library("X11") or "libX11.so.6")
    except OSError:
        return None
    x11.XGetImage.restype = ctypes.c_void_p
    x11.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int, ctypes.c_uint,
                              ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
    x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
    display, window = _pointer(ren_win.GetGenericDisplayId()), _pointer(ren_win.GetGenericWindowId())
    W, H = ren_win.GetSize()
    x11.XSync(display, 0)
    img = x11.XGetImage(display, window, 0, 0, W, H, 0xFFFFFFFF, 2)  # ZPixmap
    if not img:
        return None
    # XImage: int width, height, xoffset, format; char *data; int byte_order, bitmap_unit, bitmap_bit_order,
    # bitmap_pad, depth, bytes_per_line, bits_per_pixel
    data = ctypes.cast(img + 16, ctypes.POINTER(ctypes.c_void_p))[0]
    bpl = ctypes.cast(img + 44, ctypes.POINTER(ctypes.c_int))[0]
    bpp = ctypes.cast(img + 48, ctypes.POINTER(ctypes.c_int))[0]
    if bpp != 32:
        return None
    buf = ctypes.string_at(data, bpl * H)
    x11.XFree.argtypes = [ctypes.c_void_p]
    x11.XFree(data)
    x11.XFree(img)
    return np.frombuffer(buf, np.uint8).reshape(H, bpl // 4, 4)[:, :W, 2::-1].copy()
