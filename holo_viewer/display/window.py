"""Borderless fullscreen VTK window on the Looking Glass monitor (no Qt; X11 / native GL).

The native image is drawn 1:1 with ``vtkImageMapper`` + ``vtkActor2D`` (no scaling, no filtering)
into a borderless window of exactly ``screenW x screenH`` pixels placed at the monitor's origin,
which is how Looking Glass apps drive the panel (100 % display scaling required). Monitors are
found with ``xrandr --listmonitors`` when available, else ``xdpyinfo`` (one screen).

Do not set ``VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow`` for this module: that selects the
offscreen OSMesa window. ``vtk`` is imported lazily.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from ..errors import DisplayError, InputError

__all__ = ["Monitor", "list_monitors", "choose_monitor", "NativeWindow", "play"]


@dataclass(frozen=True)
class Monitor:
    """A monitor's geometry in the X screen (pixels)."""

    index: int
    x: int
    y: int
    width: int
    height: int
    name: str = ""


def _run(cmd: list[str]) -> str:
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=10, check=False).stdout
    except (OSError, subprocess.SubprocessError):
        return ""


def list_monitors() -> list[Monitor]:
    """Monitors of the current X display (``$DISPLAY``); empty when none can be queried."""
    if shutil.which("xrandr"):
        out = _run(["xrandr", "--listmonitors"])
        mons = []
        for line in out.splitlines():
            m = re.match(r"\s*(\d+):\s+\S+\s+(\d+)/\d+x(\d+)/\d+\+(-?\d+)\+(-?\d+)\s+(\S+)", line)
            if m:
                i, w, h, x, y, name = m.groups()
                mons.append(Monitor(int(i), int(x), int(y), int(w), int(h), name))
        if mons:
            return mons
    if shutil.which("xdpyinfo"):
        m = re.search(r"dimensions:\s+(\d+)x(\d+) pixels", _run(["xdpyinfo"]))
        if m:
            return [Monitor(0, 0, 0, int(m.group(1)), int(m.group(2)), "screen")]
    return []


def choose_monitor(monitors: list[Monitor], width: int, height: int, index: int | None = None) -> Monitor:
    """The monitor to use: ``index`` if given, else the first whose resolution is ``width x height``.

    Raises
    ------
    DisplayError
        When ``index`` does not exist or no monitor matches (the message lists what was found).
    """
    found = ", ".join(f"#{m.index} {m.name} {m.width}x{m.height}+{m.x}+{m.y}" for m in monitors) or "none"
    if index is not None:
        for m in monitors:
            if m.index == index:
                return m
        raise DisplayError(f"--monitor {index}: no such monitor; found {found}")
    for m in monitors:
        if (m.width, m.height) == (width, height):
            return m
    raise DisplayError(f"no monitor with the calibration's resolution {width}x{height}; found {found}. "
                       "Connect the Looking Glass by HDMI, set its scaling to 100 %, or choose one with --monitor N")


class NativeWindow:
    """A borderless window showing native images pixel for pixel.

    Parameters
    ----------
    width, height : int
        Window size in pixels (the calibration's screenW x screenH).
    x, y : int
        Window position (the monitor's origin).
    title : str
        Window title.
    """

    def __init__(self, width: int, height: int, x: int = 0, y: int = 0, title: str = "holo-viewer") -> None:
        if os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "").startswith("vtkOS"):
            raise DisplayError("VTK_DEFAULT_OPENGL_WINDOW selects an offscreen window; unset it to open the "
                               "fullscreen Looking Glass window")
        if not os.environ.get("DISPLAY") and os.name == "posix" and not os.uname().sysname == "Darwin":
            raise DisplayError("no X display ($DISPLAY is not set); the fullscreen window needs one")
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkCommonDataModel import vtkImageData
        from vtkmodules.vtkRenderingCore import vtkActor2D, vtkImageMapper, vtkRenderer, vtkRenderWindow
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the GL window factory)

        self._numpy_to_vtk = numpy_to_vtk
        self.width, self.height = int(width), int(height)
        self.image = vtkImageData()
        self.image.SetDimensions(self.width, self.height, 1)
        self._buf = np.zeros((self.height, self.width, 3), dtype=np.uint8)
        self._set_scalars(self._buf)
        mapper = vtkImageMapper()
        mapper.SetInputData(self.image)
        mapper.SetColorWindow(255.0)
        mapper.SetColorLevel(127.5)
        actor = vtkActor2D()
        actor.SetMapper(mapper)
        actor.SetPosition(0, 0)
        ren = vtkRenderer()
        ren.SetBackground(0.0, 0.0, 0.0)
        ren.AddViewProp(actor)
        rw = vtkRenderWindow()
        rw.SetBorders(False)
        rw.SetWindowName(title)
        rw.SetSize(self.width, self.height)
        rw.SetPosition(int(x), int(y))
        rw.AddRenderer(ren)
        rw.SetMultiSamples(0)
        self.render_window, self.renderer, self.mapper = rw, ren, mapper

    def _set_scalars(self, rgb_top_down: np.ndarray) -> None:
        flat = np.ascontiguousarray(rgb_top_down[::-1]).reshape(-1, 3)  # VTK rows start at the bottom
        self._keep = flat
        arr = self._numpy_to_vtk(flat, deep=False)
        arr.SetName("rgb")
        self.image.GetPointData().SetScalars(arr)
        self.image.Modified()

    def show(self, native: np.ndarray) -> None:
        """Display an (height, width, 3) uint8 (or float [0, 1]) native image and render."""
        img = np.asarray(native)
        if img.shape != (self.height, self.width, 3):
            raise InputError(f"native: expected shape ({self.height}, {self.width}, 3), found {img.shape}")
        if img.dtype != np.uint8:
            from ..images import to_uint8

            img = to_uint8(np.asarray(img, dtype=np.float64), name="native")
        self._set_scalars(img)
        self.render_window.Render()

    def screenshot(self) -> np.ndarray:
        """(height, width, 3) uint8 copy of the window's front buffer."""
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkRenderingCore import vtkWindowToImageFilter

        f = vtkWindowToImageFilter()
        f.SetInput(self.render_window)
        f.SetInputBufferTypeToRGB()
        f.ReadFrontBufferOff()
        f.Update()
        out = f.GetOutput()
        w, h, _ = out.GetDimensions()
        arr = vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, -1)[::-1, :, :3]
        return np.ascontiguousarray(arr)

    def close(self) -> None:
        self.render_window.Finalize()


def play(window: NativeWindow, frames: Callable[[], Iterator[np.ndarray]], fps: float = 30.0, loop: bool = False,
         max_frames: int | None = None) -> int:
    """Show frames from ``frames()`` at ``fps`` until done (or forever with ``loop``); q/Esc quits.

    A single still image stays up until q/Esc (or ``max_frames``). Returns the frames shown.
    """
    from vtkmodules.vtkRenderingCore import vtkRenderWindowInteractor
    from vtkmodules.vtkInteractionStyle import vtkInteractorStyleUser

    iren = vtkRenderWindowInteractor()
    iren.SetRenderWindow(window.render_window)
    iren.SetInteractorStyle(vtkInteractorStyleUser())
    state = {"it": frames(), "shown": 0, "done": False}

    def next_frame(*_args) -> None:
        if state["done"]:
            return
        try:
            img = next(state["it"])
        except StopIteration:
            if loop:
                state["it"] = frames()
                try:
                    img = next(state["it"])
                except StopIteration:
                    state["done"] = True
                    return
            else:
                state["done"] = True
                return
        window.show(img)
        state["shown"] += 1
        if max_frames is not None and state["shown"] >= max_frames:
            iren.TerminateApp()

    def on_key(obj, _event) -> None:
        if obj.GetKeySym() in ("q", "Q", "Escape"):
            iren.TerminateApp()

    iren.AddObserver("KeyPressEvent", on_key)
    iren.AddObserver("TimerEvent", next_frame)
    iren.Initialize()
    next_frame()
    if max_frames is not None and state["shown"] >= max_frames:
        return state["shown"]
    iren.CreateRepeatingTimer(max(1, int(round(1000.0 / fps))))
    iren.Start()
    return state["shown"]
