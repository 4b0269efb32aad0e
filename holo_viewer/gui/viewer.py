"""Interactive inspection viewer (PyVista/VTK, no Qt): mesh, Gaussians, cameras, sliders, preview.

Layout of the window (``pyvista.Plotter`` with three renderers)::

    +-----------+--------------------------+-----------------+
    | sliders   | 3D scene: FLAME mesh,    | selected view   |
    | face      | Gaussian ellipsoids,     | (fast renderer) |
    | cameras   | 48 numbered cameras and  +-----------------+
    | Gaussians | frusta, focal plane      | quilt thumbnail |
    +-----------+--------------------------+-----------------+

Input. Only the 3D scene takes the mouse (rotate, pan, zoom); the image panels are pictures.
Every key is ours (:data:`KEYS`, shown by ``h``): VTK's and PyVista's built-in keys (``w``/``s``
wireframe, ``3`` stereo, ``e`` quit, ``f``/``p``/``r``/``v`` camera and picking, ``i`` widget
activation, ``Up``/``Down``/``+``/``-`` zoom) are switched off.

Sliders. Face and camera sliders act *while dragging* (the mesh or the frusta follow the knob;
a mesh update is one LBS and one frame), the Gaussians, the preview and the quilt thumbnail
follow on *release*. ``Return`` types a value, ``0`` resets the face to neutral.

Event loop. :meth:`HoloViewer.run` drives VTK from Python: process the pending X events,
apply the newest live slider value, collect background results (thumbnail quilt from a worker
process, exports from a worker thread), render once if anything changed, sleep a few ms. So the
window never waits for an export, and renders requested by several events are coalesced.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..display.quilt import to_uint8
from ..errors import HoloViewerError, InputError
from ..pipeline import FaceControls, Pipeline, apply_frame
from .background import BackgroundJobs, Job
from .scene import (GLYPH_COLOR_MODES, au_label, focal_plane_polydata, frusta_arrays, glyph_colors, glyph_polydata,
                    glyph_selection, image_plane, mesh_polydata, scene_bounds, view_colors)

__all__ = ["ViewerConfig", "HoloViewer", "HELP_TEXT", "KEYS", "scale_cameras", "UpdateTimings"]

#: every key the window answers to: (X keysym, how the help shows it, what it does)
KEYS: tuple[tuple[str, str, str], ...] = (
    ("h", "h", "this help on / off"),
    ("q", "q", "quit (waits for running exports)"),
    ("m", "m", "FLAME mesh on / off"),
    ("l", "l", "mesh wireframe on / off"),
    ("g", "g", "Gaussian ellipsoids on / off"),
    ("c", "c", "ellipsoid colour: own / opacity / size"),
    ("o", "o", "cameras, frusta, focal plane on / off"),
    ("r", "r", "camera: back to head + all cameras"),
    ("z", "z", "camera: close-up of the head"),
    ("0", "0", "face back to neutral"),
    ("Left", "<- ->", "previous / next view"),
    ("Right", "", ""),
    ("Return", "Return", "type a value (pain 0.6), Esc cancels"),
    ("k", "k", "export the quilt PNG"),
    ("n", "n", "export the native (lenticular) PNG"),
    ("x", "x", "export an expression-sweep mp4"),
    ("i", "i", "save a screenshot PNG"),
)

MOUSE_HELP = (
    ("left drag", "rotate"), ("shift + left drag", "pan"), ("ctrl + left drag", "spin"),
    ("right drag, wheel", "zoom"), ("middle drag", "pan"),
)


def _help_text() -> str:
    lines = ["keys"]
    lines += [f" {shown:<7}{what}" for _, shown, what in KEYS if shown]
    lines += ["mouse (3D scene only)"]
    lines += [f" {k:<18}{v}" for k, v in MOUSE_HELP]
    lines += ["face, camera, view sliders act while dragging;", "Gaussians, preview, quilt on release"]
    return "\n".join(lines)


HELP_TEXT = _help_text()


@dataclass(frozen=True)
class ViewerConfig:
    """Viewer settings.

    Attributes
    ----------
    window_size : (int, int)
        Window width, height in pixels (the layout stays readable down to 800 x 450).
    n_expr_sliders : int
        Number of expression-component sliders: the components named ``expr_names`` when the model
        names its components (the default head: action units, range 0..1.5), else the first ones
        (range +-``expr_range`` standard deviations).
    max_glyphs : int
        Gaussians drawn as ellipsoids (a deterministic random subset keeps it interactive);
        ``holo-viewer view`` and ``snapshot`` use this default.
    glyph_sigmas : float
        Ellipsoid radius in standard deviations.
    glyph_min_opacity : float
        Only Gaussians at least this opaque are drawn (faint ones read as dark speckles).
    glyph_color : str
        ``"colour"`` (own DC colour), ``"opacity"`` or ``"size"`` (:func:`~.scene.glyph_colors`).
    glyph_subdivisions : int
        Icosphere subdivisions of each ellipsoid (0: 20 triangles; software OpenGL pays per triangle).
    preview_scale, thumbnail_scale : float
        Size of the preview view and of the thumbnail quilt's tiles relative to the quilt tile.
    auto_thumbnail : bool
        Re-render the thumbnail quilt after every slider release.
    live_sliders : bool
        Face and camera sliders update the mesh / frusta while dragging (else on release only).
    sweep_frames, sweep_scale, sweep_fps : int, float, float
        Frames, tile scale and frame rate of the expression-sweep video.
    out_dir : str
        Folder of exports.
    show_status : bool
        Show the status line (timings, exports); snapshots leave it out to stay reproducible.
    multi_samples : int
        MSAA samples (pyvista's default 8 costs ~3x per frame with software OpenGL; 0 = off).
    """

    window_size: tuple[int, int] = (1400, 800)
    n_expr_sliders: int = 4
    expr_names: tuple[str, ...] = ("AU2_L", "AU4", "AU9", "AU20")
    expr_range: float = 2.0
    max_glyphs: int = 2500
    glyph_sigmas: float = 1.5
    glyph_min_opacity: float = 0.5
    glyph_color: str = "colour"
    glyph_subdivisions: int = 0
    preview_scale: float = 0.4
    thumbnail_scale: float = 0.125
    auto_thumbnail: bool = True
    live_sliders: bool = True
    sweep_frames: int = 16
    sweep_scale: float = 0.5
    sweep_fps: float = 8.0
    out_dir: str = "holo_viewer_out"
    title: str = "holo-viewer  (press h for help)"
    show_status: bool = True
    multi_samples: int = 0

    def __post_init__(self) -> None:
        if self.glyph_color not in GLYPH_COLOR_MODES:
            raise InputError(f"glyph_color: expected one of {GLYPH_COLOR_MODES}, found {self.glyph_color!r}")
        if not 0.0 <= self.glyph_min_opacity < 1.0:
            raise InputError(f"glyph_min_opacity: expected in [0, 1), found {self.glyph_min_opacity}")
        if not self.glyph_sigmas > 0 or self.max_glyphs < 1:
            raise InputError(f"max_glyphs >= 1 and glyph_sigmas > 0 expected, found {self.max_glyphs}, "
                             f"{self.glyph_sigmas}")


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
    mesh_ms: float | None = None
    preview_ms: float | None = None
    thumbnail_ms: float | None = None
    frame_ms: float | None = None
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
    def value(self) -> float:
        return float(self.widget.GetRepresentation().GetValue())

    def set_value(self, v: float) -> None:
        self.widget.GetRepresentation().SetValue(float(v))
        self.value_text.SetInput(self.fmt % self.value)


class HoloViewer:
    """The inspection window around a :class:`~holo_viewer.pipeline.Pipeline`.

    Parameters
    ----------
    pipeline : Pipeline
        Supplies the mesh, Gaussians (optional: ``pipeline.avatar`` may be None), cameras,
        preview views and exports.
    config : ViewerConfig
    off_screen : bool
        Render into an offscreen buffer (snapshots, tests).
    frames : list of dict, optional
        A FLAME sequence (:func:`~holo_viewer.pipeline.flame_sequence_frames`): adds a frame slider.
    """

    def __init__(self, pipeline: Pipeline, config: ViewerConfig | None = None, *, off_screen: bool = False,
                 frames: list[dict[str, np.ndarray]] | None = None) -> None:
        import pyvista as pv

        self.pipeline = pipeline
        self.frames = frames
        self._frame_base = pipeline.face
        self.config = config or ViewerConfig()
        self.off_screen = off_screen
        self.selected_view = len(pipeline.cameras()) // 2
        self.show_mesh = True
        self.wireframe = False
        self.show_gaussians = pipeline.avatar is not None
        self.show_frusta = True
        self.show_help = False
        self.glyph_count = int(self.config.max_glyphs)
        self.glyph_sigmas = float(self.config.glyph_sigmas)
        self.glyph_min_opacity = float(self.config.glyph_min_opacity)
        self.glyph_color = self.config.glyph_color
        self.timings = UpdateTimings()
        self.exports: list[Path] = []
        self.errors: list[str] = []
        self.sliders: dict[str, Any] = {}  # key -> vtkSliderWidget
        self._specs: dict[str, _Slider] = {}
        self._glyph_index: np.ndarray | None = None
        self._thumb_key: tuple | None = None
        self._building = True
        self._opened = False
        self._looping = False
        self._quit = False
        self._dirty = False
        self._worker: Any = None
        self._jobs = BackgroundJobs()
        self._thumb_pending_key: tuple | None = None
        self._thumb_started = 0.0
        self._in_events = False
        self._last_job_line = ""
        self._live: dict[str, tuple[float, float]] = {}  # slider key -> (value, event time)
        self._released: list[_Slider] = []  # sliders released during this loop turn's events
        self._thumb_wanted = False
        self._entry: str | None = None  # the value being typed after Return
        self._message = ""
        self._releasing = ""  # key of the slider whose release is being handled
        self._size: tuple[int, int] = tuple(self.config.window_size)
        self._font = _font_px(self._size[1])

        self.plotter = pv.Plotter(shape=(2, 3), groups=[(np.s_[:], 0), (np.s_[:], 1)],
                                  col_weights=[1.15, 2.4, 1.2], window_size=list(self.config.window_size),
                                  off_screen=off_screen, title=self.config.title, border=False,
                                  theme=_theme(self.config))
        self._build()
        self._building = False

    # ================================================================== building
    @property
    def faces(self) -> np.ndarray:
        return self.pipeline.model.faces.detach().cpu().numpy()

    def _build(self) -> None:
        p = self.plotter
        pipe = self.pipeline
        F = self._font
        # ---- 3D scene
        p.subplot(0, 1)
        self.scene_renderer = p.renderer
        p.set_background("#1e2127", top="#3a4150", all_renderers=False)
        self.mesh = mesh_polydata(pipe.mesh(), self.faces)
        self.mesh_actor = p.add_mesh(self.mesh, color="#e8c4a8", smooth_shading=True, specular=0.2,
                                     name="mesh", reset_camera=False)
        # smooth shading makes pyvista draw a copy with normals: update that one
        self.mesh = self.mesh_actor.mapper.dataset
        self.glyphs = None
        self.glyph_actor = None
        if pipe.avatar is not None:
            self._update_glyphs()
        self._add_cameras()
        self.axes_actor = p.add_axes(interactive=False, line_width=2, labels_off=False)
        self.status = _text_actor("", F - 1, "white", justify="right", background=0.55)
        self.status.SetPosition(0.99, 0.01)
        self.scene_renderer.AddViewProp(self.status)
        self.hint = _text_actor("h  help", F, "#ffe680", vjust="top", background=0.55)
        self.hint.SetPosition(0.01, 0.99)
        self.scene_renderer.AddViewProp(self.hint)
        self.help_actor = _text_actor(HELP_TEXT, F - 1, "#ffe680", vjust="top", mono=True, background=0.8)
        self.help_actor.SetPosition(0.01, 0.99)
        self.help_actor.SetVisibility(self.show_help)
        self.scene_renderer.AddViewProp(self.help_actor)
        self.entry_actor = _text_actor("", F, "#9fe7ff", vjust="bottom", background=0.8)
        self.entry_actor.SetPosition(0.01, 0.12)
        self.scene_renderer.AddViewProp(self.entry_actor)
        self.reset_camera()
        # ---- image panels
        self.preview_panel = _ImagePanel(p, (0, 2), "selected view", F)
        self.thumb_panel = _ImagePanel(p, (1, 2), "quilt", F)
        cal = pipe.calibration
        self.thumb_panel.set_title(f"quilt {cal.cols}x{cal.rows} (0 bottom left)")
        if pipe.avatar is None:
            why = "no Gaussian avatar\n(--avatar none: mesh only)\nnothing to render here"
            self.preview_panel.set_message(why)
            self.thumb_panel.set_message(why)
        self._update_preview_title()
        # ---- sliders
        p.subplot(0, 0)
        self.slider_renderer = p.renderer
        p.set_background("#15171b", all_renderers=False)
        self._add_sliders()
        p.subplot(0, 1)
        self._update_preview()
        if self.config.auto_thumbnail:
            self._update_thumbnail(wait=True)
        self._update_status()

    def _default_camera_bounds(self) -> tuple[float, ...]:
        cams = self.pipeline.cameras()
        centre, _ = self.pipeline.get("framing")
        corners = frusta_arrays(cams[[0, len(cams) - 1]], centre)[0]
        return scene_bounds(self.pipeline.mesh(), cams.positions, corners, pad=0.02)

    def reset_camera(self) -> None:
        """Frame the head and all the quilt cameras, seen from the right and above (key ``r``)."""
        self._frame(self._default_camera_bounds(), (1.0, 0.7, 0.45), 1.05)

    def head_closeup(self) -> None:
        """Frame the head only, seen from the front right (key ``z``)."""
        self._frame(scene_bounds(self.pipeline.mesh(), pad=0.0), (0.45, 0.2, 1.0), 1.5)

    def _frame(self, b: tuple[float, ...], direction: tuple[float, float, float], zoom: float) -> None:
        ren = self.scene_renderer
        focal = np.array([(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2])
        cam = ren.GetActiveCamera()
        direction = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
        cam.SetFocalPoint(*focal)
        cam.SetPosition(*(focal + direction))
        cam.SetViewUp(0.0, 1.0, 0.0)
        cam.SetViewAngle(30.0)
        ren.ResetCamera(*b)  # keeps the direction, fits the bounding sphere
        cam.Zoom(zoom)  # the bounding sphere is loose around a flat box
        ren.ResetCameraClippingRange()
        ren.camera_set = True
        self._render()

    def _add_cameras(self) -> None:
        """The 48 frusta (colour = view, legend), numbered camera centres, selected frustum, focal plane."""
        import pyvista as pv
        import vtk

        p = self.plotter
        p.subplot(0, 1)
        cams = self.pipeline.cameras()
        centre, _ = self.pipeline.get("framing")
        V = len(cams)
        pts, lines, vid = frusta_arrays(cams, centre)
        cols = view_colors(V)
        # every view's frustum would be a solid fan (the sheared frusta share the focal rectangle):
        # draw every 6th and the last, plus all 48 camera centres; the selected one is drawn apart
        drawn = np.isin(vid, np.unique(np.r_[np.arange(0, V, 6), V - 1]))
        lines, vid = lines[drawn], vid[drawn]
        cells = np.hstack([np.full((lines.shape[0], 1), 2, dtype=np.int64), lines]).ravel()
        self.frusta = pv.PolyData(pts, lines=cells)
        self.frusta.cell_data["rgb"] = (cols[vid] * 255).astype(np.uint8)
        self.frusta_actor = p.add_mesh(self.frusta, scalars="rgb", rgb=True, line_width=1.0,
                                       name="frusta", reset_camera=False, lighting=False)
        self.frusta = self.frusta_actor.mapper.dataset  # update what VTK draws
        self.camera_points = pv.PolyData(cams.positions.copy())
        self.camera_points.point_data["rgb"] = (cols * 255).astype(np.uint8)
        self.camera_actor = p.add_mesh(self.camera_points, scalars="rgb", rgb=True, point_size=11,
                                       render_points_as_spheres=True, name="cameras", reset_camera=False,
                                       lighting=False)
        self.camera_points = self.camera_actor.mapper.dataset
        sel = self._frustum_points(pts, self.selected_view)
        local = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]])
        self.selected = pv.PolyData(sel, lines=np.hstack([np.full((8, 1), 2), local]).ravel())
        self.selected_actor = p.add_mesh(self.selected, color="white", line_width=4.0, name="selected",
                                         reset_camera=False, lighting=False)
        self.selected = self.selected_actor.mapper.dataset
        self.focal_actor = p.add_mesh(focal_plane_polydata(cams, centre), color="#5fa8ff", style="wireframe",
                                      line_width=2.0, name="focal", reset_camera=False, lighting=False)
        # numbers at a few cameras (colour-keyed) and at the selected one
        self._numbered = sorted({0, V // 4, V // 2, (3 * V) // 4, V - 1})
        self.camera_labels = []
        for i in self._numbered:  # 2D text anchored at a world point: drawn on top, never hidden
            lab = _text_actor(str(i), self._font, "white", justify="center")
            lab.GetTextProperty().SetColor(*cols[i])
            lab.GetTextProperty().BoldOn()
            lab.GetTextProperty().ShadowOn()
            lab.GetPositionCoordinate().SetCoordinateSystemToWorld()
            self.scene_renderer.AddViewProp(lab)
            self.camera_labels.append(lab)
        self.selected_label = _text_actor("", self._font + 1, "white", justify="center")
        self.selected_label.GetTextProperty().BoldOn()
        self.selected_label.GetTextProperty().ShadowOn()
        self.selected_label.GetPositionCoordinate().SetCoordinateSystemToWorld()
        self.scene_renderer.AddViewProp(self.selected_label)
        # legend: view index -> colour
        lut = vtk.vtkLookupTable()
        lut.SetNumberOfTableValues(V)
        for i in range(V):
            lut.SetTableValue(i, *cols[i], 1.0)
        lut.SetTableRange(0, V - 1)
        lut.Build()
        self.legend = vtk.vtkScalarBarActor()
        self.legend.SetLookupTable(lut)
        self.legend.SetTitle("view")
        self.legend.SetNumberOfLabels(5)
        self.legend.SetLabelFormat("%.0f")
        self.legend.SetOrientationToVertical()
        self.legend.SetBarRatio(0.35)
        self.legend.UnconstrainedFontSizeOn()
        for t in (self.legend.GetTitleTextProperty(), self.legend.GetLabelTextProperty()):
            t.SetFontSize(self._font - 1)
            t.ItalicOff()
            t.ShadowOff()
            t.BoldOff()
        self.legend.GetPositionCoordinate().SetCoordinateSystemToNormalizedViewport()
        self.legend.SetPosition(0.935, 0.3)
        self.legend.SetWidth(0.06)
        self.legend.SetHeight(0.45)
        self.scene_renderer.AddViewProp(self.legend)
        self._place_camera_labels()
        self._camera_actors = (self.frusta_actor, self.camera_actor, self.selected_actor, self.focal_actor,
                               self.legend, self.selected_label, *self.camera_labels)
        for a in self._camera_actors:
            a.SetVisibility(self.show_frusta)

    @staticmethod
    def _frustum_points(points: np.ndarray, view: int) -> np.ndarray:
        return points[5 * view: 5 * view + 5]

    def _place_camera_labels(self) -> None:
        cams = self.pipeline.cameras()
        pos = cams.positions
        lift = np.array([0.0, 0.025, 0.0])
        for lab, i in zip(self.camera_labels, self._numbered):
            lab.GetPositionCoordinate().SetValue(*(pos[i] + lift))
            lab.SetVisibility(self.show_frusta and i != self.selected_view)
        self.selected_label.SetInput(f"view {self.selected_view}")
        self.selected_label.GetPositionCoordinate().SetValue(*(pos[self.selected_view] + lift))

    def _slider_specs(self) -> list[_Slider]:
        pipe, cfg = self.pipeline, self.config
        names = list(pipe.model.expression_names or [])
        chosen = [names.index(n) for n in cfg.expr_names if n in names] if names else []
        if not chosen:
            chosen = list(range(min(cfg.n_expr_sliders, int(pipe.model.n_expr))))
        rng = (0.0, 1.5) if getattr(pipe.model, "is_default_head", False) else (-cfg.expr_range, cfg.expr_range)
        face = self._face_release
        specs: list[_Slider] = []
        if self.frames is not None and len(self.frames) > 1:
            specs.append(_Slider("frame", "sequence frame", (0, len(self.frames) - 1), "%.0f",
                                 self._live_face, face, "face"))
        for i in chosen[: cfg.n_expr_sliders]:
            name = names[i] if i < len(names) else ""
            title = au_label(name) if name else f"expression {i}"
            aliases = (name.lower(), name.split("_")[0].lower()) if name else ()
            specs.append(_Slider(f"expr{i}", title, rng, "%.2f", self._live_face, face, "face", aliases=aliases))
        try:
            pipe.au_map  # noqa: B018 - smile and pain need the model's action-unit map
            specs.append(_Slider("smile", "smile (AU6 + AU12)", (0.0, 1.0), "%.2f", self._live_face, face, "face"))
        except HoloViewerError:
            pass
        specs.append(_Slider("jaw", "jaw opening (rad)", (0.0, 0.5), "%.2f", self._live_face, face, "face"))
        if "smile" in [s.key for s in specs]:
            specs.append(_Slider("pain", "pain (PSPI face)", (0.0, 1.0), "%.2f", self._live_face, face, "face"))
        specs += [
            _Slider("angle", "viewer angle (deg)", (-30.0, 30.0), "%+.1f", self._live_view, self._view_release,
                    "cameras", aliases=("alpha",)),
            _Slider("distance", "viewer distance (m)", (0.3, 1.5), "%.2f", self._live_view, self._view_release,
                    "cameras"),
            _Slider("cone", "view cone (deg)", (10.0, 60.0), "%.1f", self._live_view, self._view_release,
                    "cameras"),
            _Slider("view", "selected view", (0, len(pipe.cameras()) - 1), "%.0f", self._live_select,
                    lambda v: self.select_view(int(round(v))), "cameras"),
        ]
        if pipe.avatar is not None:
            n = len(pipe.avatar)
            specs += [
                _Slider("glyphs", "ellipsoids drawn", (min(100, n), max(min(20000, n), min(100, n) + 1)), "%.0f",
                        None, lambda v: self.set_glyphs(count=int(round(v))), "Gaussians", aliases=("count",)),
                _Slider("sigmas", "ellipsoid size (sigma)", (0.5, 3.0), "%.2f", None,
                        lambda v: self.set_glyphs(sigmas=v), "Gaussians", aliases=("sigma",)),
                _Slider("min_opacity", "min. opacity drawn", (0.0, 0.95), "%.2f", None,
                        lambda v: self.set_glyphs(min_opacity=v), "Gaussians", aliases=("opacity",)),
            ]
        return specs

    def _slider_value(self, key: str) -> float:
        f, v = self.pipeline.face, self.pipeline.view
        if key.startswith("expr"):
            i = int(key[4:])
            return float(f.expr[i]) if i < f.expr.shape[0] else 0.0
        cal = self.pipeline.calibration
        return {
            "frame": 0.0, "smile": dict(f.named).get("smile", 0.0), "jaw": float(f.jaw_pose[0]),
            "pain": float(f.pain), "angle": float(v.viewer_angle),
            "distance": float(v.viewer_distance or 0.65), "cone": float(v.view_cone or cal.view_cone),
            "view": float(self.selected_view), "glyphs": float(self.glyph_count), "sigmas": self.glyph_sigmas,
            "min_opacity": self.glyph_min_opacity,
        }[key]

    def _add_sliders(self) -> None:
        import vtk

        ren = self.slider_renderer
        iren = self.plotter.iren.interactor if self.plotter.iren is not None else None
        for spec in self._slider_specs():
            rep = vtk.vtkSliderRepresentation2D()
            rep.SetMinimumValue(spec.rng[0])
            rep.SetMaximumValue(spec.rng[1])
            rep.SetValue(float(np.clip(self._slider_value(spec.key), *spec.rng)))
            rep.ShowSliderLabelOff()
            rep.SetTitleText("")
            for c in (rep.GetPoint1Coordinate(), rep.GetPoint2Coordinate()):
                c.SetCoordinateSystemToNormalizedViewport()
            rep.SetSliderLength(0.035)
            rep.SetSliderWidth(0.02)
            rep.SetTubeWidth(0.006)
            rep.SetEndCapLength(0.0)
            rep.SetEndCapWidth(0.0)
            rep.GetTubeProperty().SetColor(0.45, 0.47, 0.52)
            rep.GetSliderProperty().SetColor(0.85, 0.87, 0.9)
            rep.GetSelectedProperty().SetColor(1.0, 0.8, 0.3)
            w = vtk.vtkSliderWidget()
            w.SetRepresentation(rep)
            w.SetAnimationModeToJump()
            w.KeyPressActivationOff()  # VTK's default 'i' would hide the slider
            w.SetCurrentRenderer(ren)
            rep.SetRenderer(ren)
            spec.widget = w
            spec.label = _text_actor(spec.title, self._font, "#d8dce3")
            spec.value_text = _text_actor(spec.fmt % rep.GetValue(), self._font, "#ffffff", justify="right")
            ren.AddViewProp(spec.label)
            ren.AddViewProp(spec.value_text)
            if iren is not None:
                w.SetInteractor(iren)
                w.AddObserver("InteractionEvent", lambda o, e, s=spec: self._on_slider_move(s))
                w.AddObserver("EndInteractionEvent", lambda o, e, s=spec: self._on_slider_release(s))
                w.EnabledOn()
            else:  # offscreen without an interactor: draw the representation only
                rep.BuildRepresentation()
                ren.AddViewProp(rep)
            self._specs[spec.key] = spec
            self.sliders[spec.key] = w
        self._headers = {g: _text_actor(g, self._font, "#8fb8ff") for g in dict.fromkeys(s.group for s in
                                                                                         self._specs.values())}
        for a in self._headers.values():
            ren.AddViewProp(a)
        self._update_glyph_header()
        self._layout_sliders()

    def _layout_sliders(self) -> None:
        """Place titles, values and sliders for the current window height (one slot per slider)."""
        specs = list(self._specs.values())
        groups = list(self._headers)
        W, H = self.plotter.window_size
        rows = len(specs) + 0.7 * len(groups) + 0.3
        slot = 1.0 / rows
        y = 1.0 - 0.25 * slot
        current = None
        F = min(self._font, int(0.47 * slot * H))
        for s in specs:
            if s.group != current:
                current = s.group
                h = self._headers[current]
                h.GetTextProperty().SetFontSize(F)
                h.GetTextProperty().BoldOn()
                h.SetPosition(0.04, y - 0.62 * slot)
                y -= 0.7 * slot
            s.label.GetTextProperty().SetFontSize(F)
            s.value_text.GetTextProperty().SetFontSize(F)
            s.label.SetPosition(0.05, y - 0.48 * slot)
            rep = s.widget.GetRepresentation()
            yy = y - 0.76 * slot
            s.value_text.GetTextProperty().SetVerticalJustificationToCentered()
            s.value_text.SetPosition(0.97, yy)
            rep.GetPoint1Coordinate().SetValue(0.07, yy)
            rep.GetPoint2Coordinate().SetValue(0.76, yy)
            y -= slot

    def _on_slider_move(self, spec: _Slider) -> None:
        spec.value_text.SetInput(spec.fmt % spec.value)
        if self._building:
            return
        if spec.live is not None and self.config.live_sliders:
            self._live[spec.key] = (spec.value, time.perf_counter())
        self._dirty = True

    def _on_slider_release(self, spec: _Slider) -> None:
        if self._building:
            return
        self._live.pop(spec.key, None)
        spec.value_text.SetInput(spec.fmt % spec.value)
        if self._in_events:  # applied by step() once the events are processed: one frame, no extra render
            if spec not in self._released:
                self._released.append(spec)
            return
        self._apply_release(spec)

    def _apply_release(self, spec: _Slider) -> None:
        self._releasing = spec.key
        self._guarded(spec.release, spec.value)

    def _guarded(self, fn: Callable, *args: Any) -> Any:
        """Run a callback; our errors go to the status line instead of killing the event loop."""
        try:
            return fn(*args)
        except HoloViewerError as exc:
            self._show_error(str(exc))
        return None

    def _show_error(self, text: str) -> None:
        self.errors.append(text)
        self._message = f"error: {text}"
        self._update_status()
        self._render()

    # ================================================================== slider actions
    def _face_from_sliders(self, key: str, value: float) -> FaceControls:
        f = self.pipeline.face
        if key == "frame":
            return apply_frame(self._frame_base, self.frames[int(round(value))])
        if key.startswith("expr"):
            return f.with_expr_component(int(key[4:]), value)
        if key == "smile":
            return f.with_named("smile", value)
        if key == "jaw":
            return f.replace(jaw_pose=np.array([value, *np.asarray(f.jaw_pose)[1:]]))
        if key == "pain":
            return f.replace(pain=value)
        raise InputError(f"slider {key!r}: not a face slider")

    def _mesh_for(self, face: FaceControls) -> np.ndarray:
        """Set the pipeline's face and compute its mesh; a face the model cannot make is undone."""
        old = self.pipeline.face
        self.pipeline.set_face(face)
        try:
            (verts,), _ = self.pipeline.compute("mesh")
        except HoloViewerError:
            self.pipeline.set_face(old)
            raise
        return verts

    def _live_face(self, key: str, value: float, t0: float) -> None:
        self._set_mesh_points(self._mesh_for(self._face_from_sliders(key, value)))
        if self.glyph_actor is not None:
            self.glyph_actor.SetVisibility(False)  # stale until release
        self._render_now()
        self.timings.live_ms = (time.perf_counter() - t0) * 1e3

    def _face_release(self, value: float, key: str | None = None) -> None:
        key = key or self._releasing
        self.set_face(self._face_from_sliders(key, value))

    def _view_changes(self, key: str, value: float) -> dict[str, float]:
        return {"angle": {"viewer_angle": value}, "distance": {"viewer_distance": value},
                "cone": {"view_cone": value}}[key]

    def _live_view(self, key: str, value: float, t0: float) -> None:
        self.pipeline.set_view(**self._view_changes(key, value))
        self._refresh_cameras()
        self._render_now()
        self.timings.live_ms = (time.perf_counter() - t0) * 1e3

    def _view_release(self, value: float, key: str | None = None) -> None:
        key = key or self._releasing
        self.set_view(**self._view_changes(key, value))

    def _live_select(self, key: str, value: float, t0: float) -> None:
        self._move_selection(int(round(value)))
        self._render_now()
        self.timings.live_ms = (time.perf_counter() - t0) * 1e3

    def _apply_live(self) -> None:
        """Apply the newest value of each slider being dragged (one update per loop turn)."""
        if not self._live:
            return
        pending, self._live = self._live, {}
        for key, (value, t0) in pending.items():
            spec = self._specs[key]
            self._guarded(spec.live, key, value, t0)
        self._update_status()

    # ================================================================== updates
    def set_face(self, face: FaceControls) -> None:
        """Apply new face controls: mesh now, then Gaussians and preview, then thumbnail."""
        t0 = time.perf_counter()
        self._set_mesh_points(self._mesh_for(face))
        # the glyphs are stale until the Gaussians are recomputed: leave them out of this frame,
        # which halves its cost with software OpenGL
        if self.glyph_actor is not None:
            self.glyph_actor.SetVisibility(False)
        self._render_now()
        self.timings.mesh_ms = (time.perf_counter() - t0) * 1e3
        self._after_change(t0)

    def _set_mesh_points(self, verts: np.ndarray) -> None:
        self.mesh.points[:] = verts
        if "Normals" in self.mesh.point_data:
            from ..geometry import vertex_normals

            self.mesh.point_data["Normals"][:] = vertex_normals(verts, self.faces)
        self.mesh.Modified()

    def set_view(self, **changes: Any) -> None:
        """Apply new view settings (viewer angle, distance, view cone): cameras, preview, thumbnail."""
        t0 = time.perf_counter()
        self.pipeline.set_view(**changes)
        self._refresh_cameras()
        self._render_now()
        self.timings.mesh_ms = (time.perf_counter() - t0) * 1e3
        self._after_change(t0)

    def select_view(self, index: int) -> None:
        """Highlight view ``index`` (the frusta are not rebuilt) and render it in the preview panel."""
        t0 = time.perf_counter()
        self._move_selection(index)
        self._render_now()
        self.timings.mesh_ms = (time.perf_counter() - t0) * 1e3
        self._update_preview()
        self._render_now()
        self.timings.preview_ms = (time.perf_counter() - t0) * 1e3
        self._update_status()

    def _move_selection(self, index: int) -> None:
        n = len(self.pipeline.cameras())
        if not 0 <= index < n:
            raise InputError(f"selected view: expected 0..{n - 1}, found {index}")
        self.selected_view = int(index)
        self.selected.points[:] = self._frustum_points(np.asarray(self.frusta.points), self.selected_view)
        self.selected.Modified()
        self._place_camera_labels()
        self._update_preview_title()
        spec = self._specs.get("view")
        if spec is not None and int(round(spec.value)) != index:
            spec.set_value(index)

    def _after_change(self, t0: float) -> None:
        if self.pipeline.avatar is not None:
            self._update_glyphs()
            self.glyph_actor.SetVisibility(self.show_gaussians and self._glyph_index.size > 0)
            self._update_preview()
            self.timings.stages = self.pipeline.last_timings.as_dict()
            self._update_status()
            self._render_now()
            self.timings.preview_ms = (time.perf_counter() - t0) * 1e3
            self._update_status()
            if self.config.auto_thumbnail:
                if self._looping:
                    self._thumb_wanted = True  # submitted at the start of the next loop turn
                else:
                    self._update_thumbnail()
        else:
            self._update_status()
            self._render()

    def _refresh_cameras(self) -> None:
        """Move the frusta, camera points, labels and focal plane to the pipeline's cameras (in place)."""
        cams = self.pipeline.cameras()
        centre, _ = self.pipeline.get("framing")
        pts, _, _ = frusta_arrays(cams, centre)
        self.frusta.points[:] = pts
        self.frusta.Modified()
        self.camera_points.points[:] = cams.positions
        self.camera_points.Modified()
        self.selected.points[:] = self._frustum_points(pts, self.selected_view)
        self.selected.Modified()
        fp = focal_plane_polydata(cams, centre)
        ds = self.focal_actor.mapper.dataset
        ds.points[:] = np.asarray(fp.points)
        ds.Modified()
        self._place_camera_labels()
        self._update_preview_title()

    def set_glyphs(self, *, count: int | None = None, sigmas: float | None = None, min_opacity: float | None = None,
                   color: str | None = None) -> None:
        """Change how the Gaussians are drawn: how many, their size in sigmas, the least opacity drawn,
        and the colour mode (``"colour"``, ``"opacity"``, ``"size"``)."""
        if count is not None:
            if count < 1:
                raise InputError(f"ellipsoid count: expected >= 1, found {count}")
            self.glyph_count = int(count)
            self._glyph_index = None
        if sigmas is not None:
            if not sigmas > 0:
                raise InputError(f"ellipsoid size: expected > 0 sigma, found {sigmas}")
            self.glyph_sigmas = float(sigmas)
        if min_opacity is not None:
            if not 0.0 <= min_opacity < 1.0:
                raise InputError(f"min. opacity: expected in [0, 1), found {min_opacity}")
            self.glyph_min_opacity = float(min_opacity)
            self._glyph_index = None
        if color is not None:
            if color not in GLYPH_COLOR_MODES:
                raise InputError(f"ellipsoid colour: expected one of {GLYPH_COLOR_MODES}, found {color!r}")
            self.glyph_color = color
        if self.pipeline.avatar is None:
            return
        self._update_glyphs()
        self._update_glyph_header()
        self._update_status()
        self._render()

    def cycle_glyph_color(self) -> None:
        """Next ellipsoid colour mode (key ``c``); the status line says how to read it."""
        modes = GLYPH_COLOR_MODES
        self.set_glyphs(color=modes[(modes.index(self.glyph_color) + 1) % len(modes)])
        self._set_status({"colour": "ellipsoid colour: each Gaussian's own (DC) colour",
                          "opacity": "ellipsoid colour: opacity (viridis: dark blue transparent, yellow opaque)",
                          "size": "ellipsoid colour: largest sigma (plasma: dark small, yellow large)"}[self.glyph_color])
        self._render()

    def _update_glyph_header(self) -> None:
        h = getattr(self, "_headers", {}).get("Gaussians")
        if h is not None:
            n = 0 if self._glyph_index is None else self._glyph_index.size
            h.SetInput(f"Gaussians ({n}, {self.glyph_color})")

    def _update_glyphs(self) -> None:
        g = self.pipeline.gaussians()
        if self._glyph_index is None or self._glyph_index.max(initial=-1) >= len(g):
            op = g.opacities.detach().cpu().numpy() if g.is_torch else g.opacities
            self._glyph_index = glyph_selection(op, self.glyph_count, self.glyph_min_opacity)
        idx = self._glyph_index
        if idx.size == 0:
            if self.glyph_actor is not None:
                self.glyph_actor.SetVisibility(False)
            self._update_glyph_header()
            return
        poly = glyph_polydata(g, idx, sigmas=self.glyph_sigmas, subdivisions=self.config.glyph_subdivisions,
                              color_mode=self.glyph_color)
        if self.glyphs is None:
            self.plotter.subplot(0, 1)
            self.glyphs = poly
            self.glyph_actor = self.plotter.add_mesh(self.glyphs, scalars="rgb", rgb=True, name="glyphs",
                                                     reset_camera=False, smooth_shading=False, ambient=0.35,
                                                     diffuse=0.7)
            self.glyphs = self.glyph_actor.mapper.dataset
        elif self.glyphs.n_points == poly.n_points:
            self.glyphs.points[:] = poly.points
            self.glyphs.point_data["rgb"][:] = poly.point_data["rgb"]
            self.glyphs.Modified()
        else:
            self.glyphs.copy_from(poly)
            self.glyphs.Modified()
        self.glyph_actor.SetVisibility(self.show_gaussians)
        self._update_glyph_header()

    def _preview_cameras(self) -> Any:
        return scale_cameras(self.pipeline.cameras(), self.config.preview_scale)

    def _view_angle(self, index: int) -> float:
        """Algorithm 1's alpha of view ``index`` in degrees (plus the viewer angle)."""
        n = len(self.pipeline.cameras())
        cone = self.pipeline.view.view_cone or self.pipeline.calibration.view_cone
        return (index / max(n - 1, 1) - 0.5) * cone + self.pipeline.view.viewer_angle

    def _update_preview_title(self) -> None:
        if not hasattr(self, "preview_panel"):
            return
        n = len(self.pipeline.cameras())
        self.preview_panel.set_title(f"view {self.selected_view}/{n - 1} "
                                     f"({self._view_angle(self.selected_view):+.1f} deg)")

    def _update_preview(self) -> None:
        if self.pipeline.avatar is None:
            return
        img = self.pipeline.render_view(self.selected_view, cameras=self._preview_cameras())
        self.preview_panel.update(img)

    def render_thumbnail(self) -> np.ndarray:
        """(rows*h, cols*w, 3) uint8 quilt at ``thumbnail_scale`` of the current Gaussians (blocking)."""
        from .thumbnail_worker import render_thumbnail

        pipe = self.pipeline
        return render_thumbnail(pipe.gaussians(), scale_cameras(pipe.cameras(), self.config.thumbnail_scale),
                                pipe.backend, pipe.render_config, pipe.calibration.cols, pipe.calibration.rows)

    def _update_thumbnail(self, wait: bool = False) -> None:
        """Start rendering the thumbnail quilt in the worker process (the window stays responsive);
        :meth:`poll_thumbnail` shows it when done. ``wait`` blocks until it is shown."""
        if self.pipeline.avatar is None:
            return
        key = (self.pipeline.stage_version("gaussians"), self.pipeline.stage_version("cameras"))
        if key != self._thumb_key and key != self._thumb_pending_key:
            pipe = self.pipeline
            args = (pipe.gaussians().numpy(), scale_cameras(pipe.cameras(), self.config.thumbnail_scale),
                    pipe.backend, pipe.render_config, pipe.calibration.cols, pipe.calibration.rows)
            if self._worker is None:
                from .thumbnail_worker import ThumbnailWorker

                self._worker = ThumbnailWorker()
            self._worker.submit(key, args)
            self._thumb_pending_key = key
            self._thumb_started = time.perf_counter()
        if wait:
            while self.poll_thumbnail(wait=True) and self._worker is not None and self._worker.busy:
                pass

    def poll_thumbnail(self, wait: bool = False) -> bool:
        """Show the newest finished thumbnail quilt (``wait``: block for the running job). True if shown."""
        if self._worker is None:
            return False
        done = self._worker.poll(wait=wait)
        if done is None:
            return False
        key, img = done
        self.thumb_panel.update(img)
        self._thumb_key = key
        self._render_now()
        if key == self._thumb_pending_key:
            self._thumb_pending_key = None
            self.timings.thumbnail_ms = (time.perf_counter() - self._thumb_started) * 1e3
        self._update_status()
        self._render()
        return True

    # ================================================================== status
    def _update_status(self) -> None:
        if not self.config.show_status:
            self.status.SetInput("")
            return
        t = self.timings
        f = self.pipeline.face
        fps = "" if not t.frame_ms else f" ({1000.0 / t.frame_ms:.0f} fps)"
        lines = [f"view {self.selected_view}   pain {f.pain:.2f}   frame {_ms(t.frame_ms)}{fps}",
                 f"drag {_ms(t.live_ms)}   release: mesh {_ms(t.mesh_ms)}, preview {_ms(t.preview_ms)}, "
                 f"quilt {_ms(t.thumbnail_ms)}"]
        busy = self._jobs.status_line()
        if busy:
            lines.append(busy)
        if self._message:  # wrapped to the scene's width, at most 3 lines (errors can be long)
            import textwrap

            x0, _, x1, _ = self.scene_renderer.GetViewport()
            chars = max(30, int((x1 - x0) * self._size[0] / (0.6 * self._font)))
            wrapped = textwrap.wrap(self._message, chars)
            lines += wrapped[:3] + (["..."] if len(wrapped) > 3 else [])
        self.status.SetInput("\n".join(lines))

    def _set_status(self, text: str) -> None:
        self._message = text
        self._update_status()

    # ================================================================== toggles and keys
    def toggle_mesh(self) -> None:
        self.show_mesh = not self.show_mesh
        self.mesh_actor.SetVisibility(self.show_mesh)
        self._render()

    def toggle_wireframe(self) -> None:
        self.wireframe = not self.wireframe
        prop = self.mesh_actor.GetProperty()
        prop.SetRepresentationToWireframe() if self.wireframe else prop.SetRepresentationToSurface()
        self._render()

    def toggle_gaussians(self) -> None:
        if self.glyph_actor is None:
            self._set_status("no Gaussian avatar to draw (--avatar none)")
            self._render()
            return
        self.show_gaussians = not self.show_gaussians
        self.glyph_actor.SetVisibility(self.show_gaussians)
        self._render()

    def toggle_frusta(self) -> None:
        self.show_frusta = not self.show_frusta
        for a in self._camera_actors:
            a.SetVisibility(self.show_frusta)
        self._place_camera_labels()
        self._render()

    def toggle_help(self) -> None:
        self.show_help = not self.show_help
        self.help_actor.SetVisibility(self.show_help)
        self.hint.SetVisibility(not self.show_help)
        self._render()

    def step_view(self, delta: int) -> None:
        n = len(self.pipeline.cameras())
        self.select_view(int(np.clip(self.selected_view + delta, 0, n - 1)))

    def reset_face(self) -> None:
        """Expression, jaw, smile and pain back to zero (neutral face); sliders follow."""
        f = self.pipeline.face
        base = self._frame_base if self.frames else f
        neutral = base.replace(expr=np.zeros_like(np.asarray(f.expr)), jaw_pose=np.zeros(3), named=(), pain=0.0)
        self.set_face(neutral)
        self._sync_sliders()

    def _sync_sliders(self) -> None:
        for key, spec in self._specs.items():
            if key != "frame":
                spec.set_value(float(np.clip(self._slider_value(key), *spec.rng)))
        self._render()

    def quit(self) -> None:
        self._quit = True

    def _key_actions(self) -> dict[str, Callable[[], Any]]:
        return {"h": self.toggle_help, "q": self.quit, "m": self.toggle_mesh, "l": self.toggle_wireframe,
                "g": self.toggle_gaussians, "c": self.cycle_glyph_color, "o": self.toggle_frusta,
                "r": self.reset_camera, "z": self.head_closeup, "0": self.reset_face, "Left": lambda: self.step_view(-1),
                "Right": lambda: self.step_view(1), "Return": self.start_entry, "KP_Enter": self.start_entry,
                "k": self.export_quilt, "n": self.export_native, "x": self.export_sweep_video,
                "i": self.save_screenshot}

    def press_key(self, keysym: str, char: str = "") -> None:
        """Handle one key press (what the window does for a real key; tests may call it directly)."""
        if self._entry is not None:
            self._entry_key(keysym, char)
            return
        action = self._key_actions().get(keysym)
        if action is not None:
            self._guarded(action)

    def _on_key(self, obj: Any, _event: str) -> None:
        code = obj.GetKeyCode()
        self.press_key(obj.GetKeySym() or "", code if isinstance(code, str) else "")

    # ---- value entry
    def start_entry(self) -> None:
        """Start typing a value: ``NAME VALUE`` (e.g. ``pain 0.6``, ``au9 1``, ``view 30``), Return applies."""
        self._entry = ""
        self._show_entry()

    def _show_entry(self) -> None:
        if self._entry is None:
            self.entry_actor.SetInput("")
            self.entry_actor.SetVisibility(False)
        else:
            names = ", ".join(list(self._specs)[:6]) + ", ..."
            self.entry_actor.SetInput(f"set: {self._entry}_\n(NAME VALUE, e.g. pain 0.6; {names}; Esc cancels)")
            self.entry_actor.SetVisibility(True)
        self._render()

    def _entry_key(self, keysym: str, char: str) -> None:
        if keysym == "Escape":
            self._entry = None
        elif keysym in ("Return", "KP_Enter"):
            text, self._entry = self._entry, None
            self._show_entry()
            self._guarded(self.apply_entry, text)
            return
        elif keysym == "BackSpace":
            self._entry = self._entry[:-1]
        elif char and (char.isalnum() or char in " ._-+"):
            self._entry += char
        self._show_entry()

    def find_slider(self, name: str) -> str:
        """The slider key for ``name``: a key (``pain``), an AU code (``au9``) or a title prefix."""
        n = name.strip().lower()
        if n in self._specs:
            return n
        for key, s in self._specs.items():
            if n in s.aliases:
                return key
        hits = [k for k, s in self._specs.items() if s.title.lower().startswith(n)]
        if len(hits) == 1:
            return hits[0]
        raise InputError(f"value entry: no slider named {name!r} (expected one of {', '.join(self._specs)}, "
                         f"or an AU code like au9)")

    def apply_entry(self, text: str) -> None:
        """Set a slider from typed text ``"NAME VALUE"`` as if it had been dragged and released there."""
        parts = text.replace("=", " ").split()
        if len(parts) != 2:
            raise InputError(f"value entry: expected 'NAME VALUE' (e.g. pain 0.6), found {text!r}")
        key = self.find_slider(parts[0])
        try:
            value = float(parts[1])
        except ValueError:
            raise InputError(f"value entry: {parts[1]!r} is not a number") from None
        spec = self._specs[key]
        lo, hi = spec.rng
        if not lo <= value <= hi:
            raise InputError(f"{spec.title}: expected {spec.fmt % lo}..{spec.fmt % hi}, found {parts[1]}")
        spec.set_value(value)
        self._on_slider_release(spec)

    # ================================================================== exports (worker thread)
    def _out(self, name: str) -> Path:
        out = Path(self.config.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        return out / name

    def _stamp(self) -> str:
        return time.strftime("%Y%m%d-%H%M%S") + f"-{len(self.exports) + len(self._jobs.pending):03d}"

    def _record(self, path: Path) -> Path:
        self.exports.append(path)
        self._set_status(f"wrote {path}")
        self._render()
        return path

    def _export_pipeline(self) -> Pipeline:
        """A pipeline of its own for a worker thread (same model, avatar and settings; own caches)."""
        pipe = self.pipeline
        if pipe.avatar is None:
            raise InputError("export: no Gaussian avatar (--avatar none shows the mesh only); nothing to render")
        try:
            au_map = pipe.au_map
        except HoloViewerError:
            au_map = None
        return Pipeline(model=pipe.model, avatar=pipe.avatar, calibration=pipe.calibration, face=pipe.face,
                        view=pipe.view, backend=pipe.backend, render_config=pipe.render_config, au_map=au_map)

    def _submit(self, label: str, fn: Callable[[Job], Path]) -> Job:
        job = self._jobs.submit(label, fn)
        self._update_status()
        self._render()
        return job

    def export_quilt(self) -> Job:
        """Write the full-resolution quilt PNG (``*_qs8x6a0.75.png``) in the background."""
        from ..display.quilt import quilt_filename
        from ..fileio import save_image

        pipe = self._export_pipeline()
        cal = pipe.calibration
        path = self._out(quilt_filename(f"view-{self._stamp()}", cal.cols, cal.rows, cal.aspect))

        def work(job: Job) -> Path:
            save_image(path, _export_image(pipe, job, native=False))
            return path
        return self._submit("exporting quilt", work)

    def export_native(self) -> Job:
        """Write the native (lenticular) PNG for the pipeline's calibration in the background."""
        from ..fileio import save_image

        pipe = self._export_pipeline()
        path = self._out(f"view-{self._stamp()}_native.png")

        def work(job: Job) -> Path:
            save_image(path, _export_image(pipe, job, native=True))
            return path
        return self._submit("exporting native image", work)

    def export_sweep_video(self) -> Job:
        """Write an mp4 of quilts sweeping smile 0 -> 1 -> 0 at the current pain (tiles at ``sweep_scale``),
        in the background. Models without an action-unit map sweep their first expression component."""
        from ..display.export import write_quilt_video
        from ..display.quilt import quilt_filename
        from .thumbnail_worker import render_thumbnail

        cfg = self.config
        pipe = self._export_pipeline()
        cal = pipe.calibration
        path = self._out(quilt_filename(f"sweep-{self._stamp()}", cal.cols, cal.rows, cal.aspect, suffix=".mp4"))
        base = pipe.face
        weights = np.sin(np.linspace(0.0, np.pi, max(2, cfg.sweep_frames)))
        try:
            pipe.au_map  # noqa: B018 - named expressions need the model's action-unit map

            def sweep(w: float) -> FaceControls:
                return base.with_named("smile", w)
        except HoloViewerError:  # a FLAME model without an AU map: sweep its first component
            def sweep(w: float) -> FaceControls:
                return base.with_expr_component(0, cfg.expr_range * w)

        def work(job: Job) -> Path:
            cams = scale_cameras(pipe.cameras(), cfg.sweep_scale)

            def frames() -> Any:
                for k, w in enumerate(weights):
                    pipe.set_face(sweep(float(w)))
                    yield render_thumbnail(pipe.gaussians(), cams, pipe.backend, pipe.render_config, cal.cols,
                                           cal.rows)
                    job.progress(k + 1, len(weights), "frames")

            job.progress(0, len(weights), "frames")
            write_quilt_video(path, frames(), fps=cfg.sweep_fps, total=len(weights), preset="veryfast",
                              progress=False)
            return path
        return self._submit("exporting sweep video", work)

    def _collect_jobs(self) -> None:
        for job in self._jobs.finished():
            if job.error is not None:
                msg = str(job.error) if isinstance(job.error, HoloViewerError) else \
                    f"{type(job.error).__name__}: {job.error}"
                self._show_error(f"{job.label} failed: {msg}")
            else:
                self._record(job.result)
        if self._jobs.pending:
            line = self._jobs.status_line()
            if line != self._last_job_line:
                self._last_job_line = line
                self._update_status()
                self._dirty = True

    def wait_exports(self, timeout: float | None = None) -> list[Path]:
        """Block until the running and queued exports are written; returns every export so far."""
        self._jobs.wait(timeout)
        self._collect_jobs()
        return list(self.exports)

    def screenshot(self) -> np.ndarray:
        """(H, W, 3) uint8 image of the whole window."""
        img = self.plotter.screenshot(None, return_img=True)
        return np.asarray(img)[..., :3]

    def save_screenshot(self, path: str | Path | None = None) -> Path:
        from ..fileio import save_image

        target = Path(path) if path is not None else self._out(f"screenshot-{self._stamp()}.png")
        save_image(target, self.screenshot())
        return self._record(target)

    # ================================================================== rendering and the loop
    def _render(self) -> None:
        """Ask for a frame: drawn at the end of this loop turn (at once outside the loop)."""
        if self._looping:
            self._dirty = True
        elif self._opened or self.off_screen:
            self._render_now()

    def _render_now(self) -> None:
        if self._building and not self._opened:
            return
        self._update_status()  # shows the previous frame's time
        t0 = time.perf_counter()
        self.plotter.ren_win.Render()
        self.timings.frame_ms = (time.perf_counter() - t0) * 1e3
        self._dirty = False

    def _check_resize(self) -> None:
        size = tuple(self.plotter.ren_win.GetSize())
        if size == self._size or min(size) <= 0:
            return
        self._size = size
        self._font = _font_px(size[1])
        self._layout_sliders()
        for a in (self.hint, self.entry_actor):
            a.GetTextProperty().SetFontSize(self._font)
        self.help_actor.GetTextProperty().SetFontSize(self._font - 1)
        self.status.GetTextProperty().SetFontSize(self._font - 1)
        for panel in (self.preview_panel, self.thumb_panel):
            panel.set_font(self._font)
        self._dirty = True

    def open(self) -> None:
        """Map the window and draw it without entering the event loop (tests, scripted use)."""
        if not self._opened:
            self.plotter.show(auto_close=False, interactive_update=True)
            self._opened = True
            iren = self.plotter.iren
            if iren is not None and not self.off_screen:
                self._install_input(iren)
            self._check_resize()
            self.reset_camera()  # pyvista's first show() put its own default camera in
            self.preview_panel.fit()
            self.thumb_panel.fit()
        self._render_now()

    def _install_input(self, iren: Any) -> None:
        """Our keys only; mouse to the 3D scene only; renders coalesced by the loop."""
        iren.clear_key_event_callbacks()  # pyvista's q/b/v/C/Up/Down/plus/minus
        inter = iren.interactor
        style = _scene_only_style(inter, self.scene_renderer)
        iren.style = style
        self._style = style
        self._observers = [(inter, inter.AddObserver("KeyPressEvent", self._on_key)),
                           (inter, inter.AddObserver("ExitEvent", lambda *_: self.quit())),
                           (inter, inter.AddObserver("RenderEvent", self._on_render_request))]
        axes = getattr(self.scene_renderer, "axes_widget", None)
        if axes is not None:
            axes.KeyPressActivationOff()
            axes.InteractiveOff()

    def _on_render_request(self, *_: Any) -> None:
        self._dirty = True

    def step(self) -> bool:
        """One turn of the event loop: X events, live sliders, background results, one frame if needed.

        Returns False once the window should close (``q``, the window's close button)."""
        if self._thumb_wanted:
            self._thumb_wanted = False
            self._guarded(self._update_thumbnail)
        iren = self.plotter.iren
        if iren is not None and not self.off_screen:
            inter = iren.interactor
            inter.EnableRenderOff()  # widget / camera renders are coalesced into one per turn
            self._in_events = True
            try:
                iren.process_events()
            finally:
                self._in_events = False
                inter.EnableRenderOn()
            if inter.GetDone():
                self._quit = True
        self._apply_live()
        released, self._released = self._released, []
        for spec in released:
            self._apply_release(spec)
        try:
            self.poll_thumbnail()
        except Exception as exc:  # noqa: BLE001 - a worker failure must not kill the event loop
            self._show_error(f"thumbnail failed: {exc}")
            self._thumb_pending_key = None
        self._collect_jobs()
        self._check_resize()
        if self._dirty:
            self._render_now()
        return not self._quit

    def run(self, until: Callable[[], bool] | None = None, timeout: float | None = None,
            idle_sleep: float = 0.004) -> bool:
        """Run the event loop until the window is closed, ``until()`` is true or ``timeout`` seconds pass.

        Returns True when it stopped because ``until()`` became true."""
        self.open()
        self._looping = True
        end = None if timeout is None else time.perf_counter() + timeout
        try:
            while self.step():
                if until is not None and until():
                    return True
                if end is not None and time.perf_counter() > end:
                    return False
                time.sleep(idle_sleep)
        finally:
            self._looping = False
        return False

    def show(self) -> None:
        """Open the window and run the event loop until it is closed (``q`` or the close button)."""
        self.open()
        self.run()
        if self._jobs.pending:  # quit asked while exporting: finish them with the window still drawn
            n = len(self._jobs.pending)
            print(f"holo-viewer: finishing {n} export(s) before quitting...")
            self._quit = False
            self._set_status(f"finishing {n} export(s), then quitting")
            self.run(until=lambda: not self._jobs.pending)
        self.close()

    def close(self) -> None:
        self._jobs.close()
        self._collect_jobs()
        if self._worker is not None:
            self._worker.close()
            self._worker = None
        # observers hold Python callables that hold this viewer: remove them, or the cycle keeps the
        # interactor (and its X display connection) alive after the window is gone
        for obj, tag in getattr(self, "_observers", []):
            obj.RemoveObserver(tag)
        self._observers = []
        style = getattr(self, "_style", None)
        if style is not None:
            style.RemoveAllObservers()
            self._style = None
        for w in self.sliders.values():
            w.EnabledOff()
            w.RemoveAllObservers()
            w.SetInteractor(None)
        self.plotter.close()

    # ================================================================== helpers for scripted input
    def window_id(self) -> int:
        """The X window id (for xdotool)."""
        s = str(self.plotter.ren_win.GetGenericWindowId())  # '_0000000000400002_p_void'
        return int(s.split("_")[1], 16)

    def slider_point(self, key: str, value: float | None = None) -> tuple[int, int]:
        """Window pixel (x, y from the top left) of slider ``key``'s track at ``value`` (default: the knob)."""
        spec = self._specs[key]
        rep = spec.widget.GetRepresentation()
        v = spec.value if value is None else float(value)
        lo, hi = spec.rng
        L = rep.GetSliderLength()  # the knob travels between L/2 and 1 - L/2 of the track
        t = L / 2 + (v - lo) / (hi - lo) * (1.0 - L)
        x0, y0, x1, y1 = self.slider_renderer.GetViewport()
        W, H = self.plotter.ren_win.GetSize()
        p1 = rep.GetPoint1Coordinate().GetValue()
        p2 = rep.GetPoint2Coordinate().GetValue()
        nx = p1[0] + t * (p2[0] - p1[0])
        ny = p1[1] + t * (p2[1] - p1[1])
        px = (x0 + nx * (x1 - x0)) * W
        py = (y0 + ny * (y1 - y0)) * H
        return int(round(px)), int(round(H - 1 - py))

    def panel_box(self, which: str) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) display pixels (VTK: y from the bottom) of ``"scene"``, ``"preview"``,
        ``"quilt"`` or ``"sliders"``."""
        ren = {"scene": self.scene_renderer, "preview": self.preview_panel.renderer,
               "quilt": self.thumb_panel.renderer, "sliders": self.slider_renderer}[which]
        x0, y0, x1, y1 = ren.GetViewport()
        W, H = self.plotter.ren_win.GetSize()
        return int(x0 * W), int(y0 * H), int(x1 * W) - 1, int(y1 * H) - 1

    def read_pixels(self, which: str, front: bool = True) -> np.ndarray:
        """(h, w, 3) uint8 pixels of a panel as currently drawn (no re-render)."""
        import vtk
        from vtk.util.numpy_support import vtk_to_numpy

        x0, y0, x1, y1 = self.panel_box(which)
        arr = vtk.vtkUnsignedCharArray()
        self.plotter.ren_win.GetPixelData(x0, y0, x1, y1, 1 if front else 0, arr, 0)
        return vtk_to_numpy(arr).reshape(y1 - y0 + 1, x1 - x0 + 1, 3)


def _export_image(pipe: Pipeline, job: Job, native: bool, chunk: int = 8) -> np.ndarray:
    """The full quilt (``native``: the native image) of ``pipe``: the views rendered ``chunk`` at a time,
    then :func:`~holo_viewer.display.native.views_to_native`, reporting progress to ``job``."""
    from ..display.native import views_to_native
    from ..display.lenticular import Interleaver
    from ..pipeline import quilt_layout, render_images

    g = pipe.gaussians()
    cams = pipe.cameras()
    V = len(cams)
    parts = []
    job.progress(0, V, "views")
    for s in range(0, V, chunk):
        idx = list(range(s, min(s + chunk, V)))
        parts.append(render_images(g, cams[idx], backend=pipe.backend, config=pipe.render_config))
        job.progress(idx[-1] + 1, V, "views")
    cols, rows = quilt_layout(pipe.calibration)
    target: Any = (cols, rows)
    if native:
        target = Interleaver(pipe.calibration, (rows * cams.height, cols * cams.width, 3), cols=cols, rows=rows,
                             mode="blend" if pipe.view.blend else "nearest")
    done = views_to_native(np.concatenate(parts, axis=0), target, progress=job.progress)
    return done.native if native else done.quilt


def _scene_only_style(interactor: Any, scene_renderer: Any) -> Any:
    """Trackball camera style that moves the 3D scene only and ignores VTK's built-in keys.

    Button presses and wheel turns outside the scene renderer are dropped (the image panels
    cannot be tilted or zoomed); releases always end the current interaction; ``CharEvent``
    (VTK's w/s/3/e/q/f/p/r/j/t/u/c/a keys) does nothing.
    """
    import vtk

    style = vtk.vtkInteractorStyleTrackballCamera()

    def in_scene() -> bool:
        x, y = interactor.GetEventPosition()
        return bool(scene_renderer.IsInViewport(x, y))

    def forward(method: str, only_in_scene: bool) -> Callable:
        def cb(obj: Any, _event: str) -> None:
            if only_in_scene and not in_scene():
                return
            if only_in_scene:
                obj.SetCurrentRenderer(scene_renderer)
            getattr(obj, method)()
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
