"""VTK building blocks of the window: text actors, image panels, slider records, the mouse style,
the theme, and :func:`scale_cameras` (preview and thumbnail sizes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..display.quilt import to_uint8
from .viewer_config import ViewerConfig
from .scene import image_plane

__all__ = ["scale_cameras", "UpdateTimings"]


def scale_cameras(cameras: Any, scale: float) -> Any:
    """The same cameras rendering ``scale`` x the image size (intrinsics scaled alike)."""
    from ..camera import Cameras

    W = max(4, int(round(cameras.width * scale)))
    H = max(4, int(round(cameras.height * scale)))
    sx, sy = W / cameras.width, H / cameras.height
    K = cameras.K.copy()
    K[:, 0, :] *= sx
    K[:, 1, :] *= sy
    return Cameras(cameras.world_to_cam, K, W, H, cameras.near, cameras.far)


def _font_px(window_h: int) -> int:
    """Text size in pixels for a window ``window_h`` high (13 px at 450, 16 px at 800 and above)."""
    return int(np.clip(round(window_h / 50), 13, 16))


def _text_actor(text: str, size: int, color: str = "white", *, justify: str = "left", vjust: str = "bottom",
                mono: bool = False, background: float = 0.0) -> Any:
    """A 2D text actor placed in normalized viewport coordinates, ``size`` pixels high."""
    import pyvista as pv
    import vtk

    a = vtk.vtkTextActor()
    a.SetInput(text)
    a.SetTextScaleModeToNone()
    a.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
    tp = a.GetTextProperty()
    tp.SetFontSize(size)
    tp.SetColor(pv.Color(color).float_rgb)
    tp.SetJustification({"left": 0, "center": 1, "right": 2}[justify])
    tp.SetVerticalJustification({"bottom": 0, "center": 1, "top": 2}[vjust])
    if mono:
        tp.SetFontFamilyToCourier()
    if background:
        tp.SetBackgroundColor(0.05, 0.06, 0.08)
        tp.SetBackgroundOpacity(background)
    a.PickableOff()
    return a


class _ImagePanel:
    """An image on a textured quad in its own renderer (parallel projection), below a title.

    The panel takes no mouse or key input (the viewer's interactor style ignores it)."""

    def __init__(self, plotter: Any, subplot: tuple[int, int], title: str, font: int) -> None:
        self.plotter = plotter
        self.subplot = subplot
        self.actor: Any = None
        self.shape: tuple[int, int] | None = None
        self.image: np.ndarray | None = None
        plotter.subplot(*subplot)
        self.renderer = plotter.renderer
        plotter.set_background("black", all_renderers=False)
        self.renderer.SetInteractive(False)
        self.title = _text_actor(title, font, vjust="top")
        self.title.SetPosition(0.02, 0.985)
        self.renderer.AddViewProp(self.title)
        self.message = _text_actor("", font, "#c8c8c8", justify="center", vjust="center")
        self.message.SetPosition(0.5, 0.5)
        self.renderer.AddViewProp(self.message)

    def set_title(self, text: str) -> None:
        self.title.SetInput(text)

    def set_message(self, text: str) -> None:
        self.message.SetInput(text)

    def set_font(self, size: int) -> None:
        self.title.GetTextProperty().SetFontSize(size)
        self.message.GetTextProperty().SetFontSize(size)
        if self.shape is not None:
            self.fit()

    def update(self, image: np.ndarray) -> None:
        import pyvista as pv

        img = to_uint8(np.asarray(image))
        self.image = img
        h, w = img.shape[:2]
        self.plotter.subplot(*self.subplot)
        tex = pv.Texture(np.ascontiguousarray(img))  # pyvista maps row 0 to the top of the quad
        if self.actor is None or self.shape != (h, w):
            if self.actor is not None:
                self.plotter.remove_actor(self.actor, render=False)
            self.actor = self.plotter.add_mesh(image_plane(w / h, 1.0), texture=tex, lighting=False,
                                               reset_camera=False, name=f"panel{self.subplot}")
            self.shape = (h, w)
            self.renderer.GetActiveCamera().ParallelProjectionOn()
            self.fit()
        else:
            self.actor.texture = tex

    def fit(self) -> None:
        """Fit the image (height 1, width w/h) into the viewport below the title line."""
        if self.shape is None:
            return
        h, w = self.shape
        x0, y0, x1, y1 = self.renderer.GetViewport()
        W, H = self.plotter.window_size
        vw, vh = max((x1 - x0) * W, 1.0), max((y1 - y0) * H, 1.0)
        title_px = 1.7 * self.title.GetTextProperty().GetFontSize()
        avail = max(vh - title_px, 0.3 * vh)
        s = 0.98 * min(vw / (w / h), avail)  # pixels per world unit
        cam = self.renderer.GetActiveCamera()
        cam.SetParallelScale(vh / (2.0 * s))
        dy = (vh - avail) / 2.0 / s  # move the image down by half the title band
        cam.SetFocalPoint(0.0, dy, 0.0)
        cam.SetPosition(0.0, dy, 5.0)
        cam.SetViewUp(0.0, 1.0, 0.0)
        self.renderer.ResetCameraClippingRange()


@dataclass
class UpdateTimings:
    """Milliseconds from a slider event to each part of the scene being drawn; None = not measured yet."""

    live_ms: float | None = None
    live_cpu_ms: float | None = None  # CPU (all the process's threads) of the last live step's update + frame
    mesh_ms: float | None = None
    preview_ms: float | None = None
    thumbnail_ms: float | None = None
    frame_ms: float | None = None
    splat_ms: float | None = None  # full-resolution splat image of the scene camera
    splat_drag_ms: float | None = None  # reduced splat image while the camera is dragged
    stages: dict[str, float | None] = field(default_factory=dict)


def _ms(v: float | None) -> str:
    return "-" if v is None or v != v else f"{v:.0f} ms"


@dataclass
class _Slider:
    key: str
    title: str
    rng: tuple[float, float]
    fmt: str
    live: Callable[[float], None] | None  # while dragging
    release: Callable[[float], None]  # on release
    group: str
    widget: Any = None
    label: Any = None
    value_text: Any = None
    aliases: tuple[str, ...] = ()

    @property
    def entry_name(self) -> str:
        """The name typed in the value entry and shown in its hints and errors: the AU code of an
        expression slider (``au9``), else the key (``pain``)."""
        return self.aliases[0] if self.key.startswith("expr") and self.aliases else self.key

    @property
    def value(self) -> float:
        return float(self.widget.GetRepresentation().GetValue())

    def set_value(self, v: float) -> None:
        self.widget.GetRepresentation().SetValue(float(v))
        self.value_text.SetInput(self.fmt % self.value)


def _scene_only_style(interactor: Any, scene_renderer: Any,
                      on_click: Callable[[int, int], None] | None = None) -> Any:
    """Trackball camera style that moves the 3D scene only and ignores VTK's built-in keys.

    Button presses and wheel turns outside the scene renderer are dropped (the image panels
    cannot be tilted or zoomed); releases always end the current interaction; ``CharEvent``
    (VTK's w/s/3/e/q/f/p/r/j/t/u/c/a keys) does nothing. A left press and release in the scene
    at most 3 pixels apart is a click: ``on_click(x, y)`` (display pixels, y from the bottom).
    """
    import vtk

    style = vtk.vtkInteractorStyleTrackballCamera()

    def in_scene() -> bool:
        x, y = interactor.GetEventPosition()
        return bool(scene_renderer.IsInViewport(x, y))

    pressed: list[tuple[int, int]] = []

    def forward(method: str, only_in_scene: bool) -> Callable:
        def cb(obj: Any, _event: str) -> None:
            if only_in_scene and not in_scene():
                return
            if only_in_scene:
                obj.SetCurrentRenderer(scene_renderer)
            if method == "OnLeftButtonDown":
                pressed[:] = [tuple(interactor.GetEventPosition())]
            getattr(obj, method)()
            if method == "OnLeftButtonUp" and pressed and on_click is not None:
                (x0, y0), (x, y) = pressed.pop(), interactor.GetEventPosition()
                if abs(x - x0) <= 3 and abs(y - y0) <= 3:
                    on_click(int(x), int(y))
        return cb

    for event, method, scene_only in (
            ("LeftButtonPressEvent", "OnLeftButtonDown", True), ("LeftButtonReleaseEvent", "OnLeftButtonUp", False),
            ("MiddleButtonPressEvent", "OnMiddleButtonDown", True),
            ("MiddleButtonReleaseEvent", "OnMiddleButtonUp", False),
            ("RightButtonPressEvent", "OnRightButtonDown", True),
            ("RightButtonReleaseEvent", "OnRightButtonUp", False),
            ("MouseWheelForwardEvent", "OnMouseWheelForward", True),
            ("MouseWheelBackwardEvent", "OnMouseWheelBackward", True)):
        style.AddObserver(event, forward(method, scene_only))
    style.AddObserver("CharEvent", lambda *_: None)  # an observer replaces OnChar: no built-in keys
    return style


def _theme(config: ViewerConfig) -> Any:
    """A copy of pyvista's global theme with our anti-aliasing settings (the global one is left alone)."""
    import copy

    import pyvista as pv

    theme = copy.deepcopy(pv.global_theme)
    theme.multi_samples = int(config.multi_samples)
    theme.anti_aliasing = None
    theme.depth_peeling.enabled = False
    return theme

