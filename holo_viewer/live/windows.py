"""Windows of a live session: the panel (fullscreen native image) and the desktop preview, with keys.

Both wrap :class:`holo_viewer.display.window.NativeWindow` (VTK, no Qt). ``poll()`` processes
pending window events without blocking and returns the key symbols pressed since the last call.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KeyWindow", "open_panel", "open_preview"]


class KeyWindow:
    """A :class:`NativeWindow` plus a non-blocking key queue."""

    def __init__(self, width: int, height: int, x: int = 0, y: int = 0, title: str = "holo-viewer live") -> None:
        from vtkmodules.vtkInteractionStyle import vtkInteractorStyleUser
        from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor

        from ..display.window import NativeWindow

        self.window = NativeWindow(width, height, x, y, title=title)
        self.interactor = vtkRenderWindowInteractor()
        self.interactor.SetRenderWindow(self.window.render_window)
        self.interactor.SetInteractorStyle(vtkInteractorStyleUser())
        self._keys: list[str] = []
        self.interactor.AddObserver("KeyPressEvent", lambda obj, _e: self._keys.append(obj.GetKeySym()))
        self.interactor.Initialize()
        self.shown = 0

    def show(self, image: np.ndarray) -> None:
        img = np.asarray(image)
        if img.shape[:2] != (self.window.height, self.window.width):
            from PIL import Image

            if img.dtype != np.uint8:
                img = (np.clip(img, 0, 1) * 255).astype(np.uint8)
            img = np.asarray(Image.fromarray(img).resize((self.window.width, self.window.height)))
        self.window.show(img)
        self.shown += 1

    def poll(self) -> list[str]:
        self.interactor.ProcessEvents()
        keys, self._keys = self._keys, []
        return keys

    def close(self) -> None:
        self.window.close()


def open_panel(calibration, monitor: int | None = None) -> KeyWindow:
    """Borderless window of the panel's size on the Looking Glass monitor (DisplayError if none)."""
    from ..display.window import choose_monitor, list_monitors

    w, h = int(calibration.screen_w), int(calibration.screen_h)
    mon = choose_monitor(list_monitors(), w, h, monitor)
    return KeyWindow(w, h, mon.x, mon.y, title="holo-viewer live (panel)")


def open_preview(width: int = 420, height: int = 560) -> KeyWindow:
    """The desktop preview window (one view following the tracked viewer, with the overlay)."""
    return KeyWindow(width, height, 40, 40, title="holo-viewer live (preview)")
