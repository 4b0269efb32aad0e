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

Where things are. :class:`HoloViewer` (this module: building the window, the status line, the event
loop, pixel readback for tests) is put together from parts, one module each:

* :mod:`.viewer_config` -- :class:`ViewerConfig`, the key table :data:`KEYS` and the help text;
* :mod:`.scene_view` -- the 3D scene: framing, frusta and camera labels, ellipsoids, overlay toggles;
* :mod:`.sliders` -- the sliders: specs, layout, live and release updates of face, view and selection;
* :mod:`.keys` -- key dispatch and the typed value entry;
* :mod:`.previews` -- the selected-view preview and the quilt thumbnail (worker process);
* :mod:`.exports` -- quilt / native / sweep / screenshot exports (worker thread);
* :mod:`.widgets` -- VTK building blocks (text actors, image panels, the scene-only mouse style);
* :mod:`.scene` -- pure polydata builders (mesh, ellipsoids, frusta), no window.

Event loop. :meth:`HoloViewer.run` drives VTK from Python: process the pending X events,
apply the newest live slider value, collect background results (thumbnail quilt from a worker
process, exports from a worker thread), render once if anything changed (only the panels that did),
then wait for X input or a splat image (at most a few ms: the period of the background results). So
the window never waits for an export, and renders requested by several events are coalesced.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import DisplayError, HoloViewerError
from ..pipeline import Pipeline
from .background import BackgroundJobs
from .exports import ExportsMixin, _export_image  # noqa: F401 - re-exported (tests, callers)
from .keys import KeysMixin
from .previews import PreviewsMixin
from .scene import mesh_polydata
from .scene_view import SceneMixin
from .screen import (DEFAULT_WINDOW, open_window, require_x_window, window_size_for_screen, x_input_wait,
                     x_screen_size)
from .sliders import STANDIN_MIN_TRIANGLES, SlidersMixin, viewer_angle_limits
from .splat_view import SplatViewMixin
from .viewer_config import HELP_TEXT, KEYS, ViewerConfig
from .widgets import (UpdateTimings, _font_px, _ImagePanel, _ms, _scene_only_style, _Slider, _text_actor, _theme,
                      scale_cameras)

__all__ = ["ViewerConfig", "HoloViewer", "HELP_TEXT", "KEYS", "scale_cameras", "UpdateTimings", "PARTS"]

#: the window's panels, each drawn by its own renderer; a frame draws only those that changed
PARTS = ("scene", "sliders", "preview", "quilt")
#: the image column's width (fraction of the window): the step of ``}`` / ``{`` and its limits
PANEL_STEP = 0.05
PANEL_WIDTHS = (0.15, 0.55)


def _renderers(ren_win: Any) -> list[Any]:
    rens = ren_win.GetRenderers()
    rens.InitTraversal()
    return [rens.GetNextItem() for _ in range(rens.GetNumberOfItems())]


class HoloViewer(SceneMixin, SplatViewMixin, SlidersMixin, KeysMixin, PreviewsMixin, ExportsMixin):
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
        self._dirty_parts: set[str] = set()  # panels to draw at the end of this loop turn (PARTS)
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
        self._size: tuple[int, int] = _window_size(self.config.window_size, off_screen)
        self.frames_drawn = 0
        self.last_frame_parts: tuple[str, ...] = ()
        self._splat_drawn_key: tuple | None = None
        self._presenter: Any = None  # copies only the panels drawn to the X window (gui/present.py)
        self._input_wait: Any = None  # the loop's idle wait: X input, a splat image or the poll period
        self._camera_released = False  # the scene camera's interaction just ended (its render: the scene)
        self._standin_job: Any = None  # the decimated face-drag stand-in being computed (gui/sliders.py)
        self._standin_cells: Any = None
        self.standin_min_triangles = STANDIN_MIN_TRIANGLES
        self._init_splats()
        self.panel_mode = "view"  # the upper image panel: view / native / eye (key p)
        self.native_zoom = 1
        self.eye_angle = float(pipeline.view.viewer_angle)
        self.eye_distance = float(pipeline.view.viewer_distance or 0.65)
        if self.show_splats:  # the splats are the picture; mesh and ellipsoids on request (m, g)
            self.show_mesh = False
            self.show_gaussians = False
        self._font = _font_px(self._size[1])

        def make_plotter() -> Any:
            plotter = pv.Plotter(shape=(2, 3), groups=[(np.s_[:], 0), (np.s_[:], 1)],
                                 col_weights=[1.15, 2.4, 1.2], window_size=list(self._size), off_screen=off_screen,
                                 title=self.config.title, border=False, theme=_theme(self.config))
            if not off_screen:
                try:
                    require_x_window(plotter.ren_win)
                except DisplayError:
                    plotter.close()
                    raise
            return plotter

        self.plotter = open_window(make_plotter)  # a refused X window: tried again, then one clear line
        self._build()
        self.panel_width = 1.0 - self.preview_panel.renderer.GetViewport()[0]  # the image column (keys } {)
        self._building = False

    @property
    def _dirty(self) -> bool:
        """Whether a frame is wanted; setting True asks for every panel (see :meth:`_render`)."""
        return bool(self._dirty_parts)

    @_dirty.setter
    def _dirty(self, value: bool) -> None:
        self._dirty_parts = set(PARTS) if value else set()

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
        self.mesh = mesh_polydata(pipe.mesh(), self.faces, normals=True)
        # smooth shading from our own vertex normals (the mesh's active normals, updated with the points):
        # pyvista's smooth_shading=True puts a Python algorithm between the mesh and the mapper that
        # recomputed the normals (vtkPolyDataNormals) at every live slider step (~40 ms CPU of ~95)
        self.mesh_actor = p.add_mesh(self.mesh, color="#e8c4a8", smooth_shading=False, specular=0.2,
                                     name="mesh", reset_camera=False)
        self.mesh_actor.GetProperty().SetInterpolationToPhong()
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
        self.mesh_actor.SetVisibility(self.show_mesh)
        self.home_camera()
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
        if "assumed" in self.angle_range_note:  # the avatar file does not say where it was fitted
            self._message = self._angle_note()
        p.subplot(0, 1)
        self._update_preview()
        if self.config.auto_thumbnail:
            # the first frame does not need the quilt thumbnail: the loop starts it after the first pixels
            # (offscreen, a snapshot draws it, so it waits)
            if self.off_screen:
                self._update_thumbnail(wait=True)
            else:
                self._thumb_wanted = True
        self._update_status()

    def set_avatar(self, avatar: Any, model: Any = None) -> None:
        """Show another avatar: the hook for an avatar chooser (call it from the chooser's callback).

        ``avatar`` is what a :class:`~holo_viewer.pipeline.Pipeline` takes (a ``RiggedAvatar``, or None for
        the mesh only), on ``model`` (default: the pipeline's FLAME model). An ``avatar.fit_file`` (the
        .npz it was fitted in) or ``avatar.fit_angle_range_deg`` sets the viewer-angle range. The mesh,
        the ellipsoids, the splats, the cameras and frusta, the viewer-angle slider, the preview, the
        native and eye panels and the quilt thumbnail all follow; the face sliders keep their values."""

        old = self.pipeline
        try:
            au_map = old.au_map if model is None or model is old.model else None
        except HoloViewerError:
            au_map = None
        if model is None and avatar is None:
            model = old.model
        pipe = Pipeline(model=model, avatar=avatar if avatar is not None else False, calibration=old.calibration,
                        face=old.face, view=old.view, backend=old.backend, render_config=old.render_config,
                        au_map=au_map)
        self.pipeline = pipe
        self._splat_key = self._thumb_key = self._thumb_pending_key = None
        self._native_key = self._native_full = self._native_pending = None
        self._avatar_epoch = getattr(self, "_avatar_epoch", 0) + 1  # stage versions restart with a new pipeline
        verts = pipe.mesh()
        if verts.shape[0] != self.mesh.n_points or self.mesh.n_cells != self.faces.shape[0]:
            self.mesh.copy_from(mesh_polydata(verts, self.faces, normals=True))
        self._set_mesh_points(verts)
        if self._opened and not self.off_screen and self.config.live_sliders:
            self._start_standin()  # the new model's stand-in
        self._glyph_index = None
        for panel in (self.preview_panel, self.thumb_panel):
            if panel.actor is not None:
                panel.actor.SetVisibility(avatar is not None)
        if avatar is None:
            for panel in (self.preview_panel, self.thumb_panel):
                panel.set_message("no Gaussian avatar\n(--avatar none: mesh only)\nnothing to render here")
            if self.glyph_actor is not None:
                self.glyph_actor.SetVisibility(False)
            if self.show_splats:
                self.show_splats = False
                self._hide_splats()
                self._show_camera_actors()
            self.show_mesh = True
            self.mesh_actor.SetVisibility(True)
        else:
            for panel in (self.preview_panel, self.thumb_panel):
                panel.set_message("")
            self._update_glyphs()
        self._refresh_cameras()
        spec = self._specs.get("angle")
        if spec is not None:
            lo, hi, self.angle_range_note = viewer_angle_limits(pipe)
            spec.rng = (lo, hi)
            rep = spec.widget.GetRepresentation()
            rep.SetMinimumValue(lo)
            rep.SetMaximumValue(hi)
            angle = float(np.clip(pipe.view.viewer_angle, lo, hi))
            spec.set_value(angle)
            if angle != pipe.view.viewer_angle:
                pipe.set_view(viewer_angle=angle)
                self._refresh_cameras()
            self._set_status(self._angle_note() if "assumed" in self.angle_range_note else "")
        self._update_preview()
        if avatar is not None and self.config.auto_thumbnail:
            self._update_thumbnail(wait=self.off_screen)
        self._render()

    def _guarded(self, fn: Callable, *args: Any) -> Any:
        """Run a callback; our errors go to the status line instead of killing the event loop.
        A success (no new error) clears an earlier error from the status line."""
        n_errors = len(self.errors)
        try:
            result = fn(*args)
        except HoloViewerError as exc:
            self._show_error(str(exc))
            return None
        if len(self.errors) == n_errors and self._message.startswith(("error: ", "note: ")):
            self._set_status("")
            self._render()
        return result

    def _angle_note(self) -> str:
        """The status line's note when the avatar file does not say where it was fitted (cleared by the
        next action, as errors are; the whole note: ``angle_range_note``)."""
        lo, hi = self._specs["angle"].rng
        return f"note: viewer angle {lo:+.0f}..{hi:+.0f} deg: the avatar file stores no fit_angle_range_deg"

    def _unprompted(self, fn: Callable, *args: Any) -> Any:
        """Run work the loop does by itself (no user action): errors go to the status line, but a success
        does not clear an earlier error (unlike :meth:`_guarded`)."""
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

    def _update_status(self) -> None:
        if not self.config.show_status:
            self.status.SetInput("")
            return
        t = self.timings
        f = self.pipeline.face
        fps = "" if not t.frame_ms else f" ({1000.0 / t.frame_ms:.0f} fps)"
        lines = [f"view {self.selected_view}   pain {f.pain:.2f}   frame {_ms(t.frame_ms)}{fps}",
                 f"drag {_ms(t.live_ms)}   release: mesh {_ms(t.mesh_ms)}, preview {_ms(t.preview_ms)}, "
                 f"quilt {_ms(t.thumbnail_ms)}   splats {_ms(t.splat_ms)} (drag {_ms(t.splat_drag_ms)})"]
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

    def _render(self, parts: tuple[str, ...] | None = None) -> None:
        """Ask for a frame of ``parts`` (of :data:`PARTS`; None: all): drawn at the end of this loop turn
        (at once outside the loop)."""
        if self._looping:
            self._dirty_parts.update(PARTS if parts is None else parts)
        elif self._opened or self.off_screen:
            self._render_now(parts)

    def _part_renderers(self) -> dict[str, Any]:
        return {"scene": self.scene_renderer, "sliders": self.slider_renderer,
                "preview": self.preview_panel.renderer, "quilt": self.thumb_panel.renderer}

    def _render_now(self, parts: tuple[str, ...] | None = None) -> None:
        """Draw a frame now. Only the panels in ``parts`` (None: all) and those asked for earlier in this
        turn are drawn again; the others keep their pixels (VTK renders into its own framebuffer and copies
        it to the window, so a renderer that does not draw keeps what it drew last)."""
        if self._building and not self._opened:
            return
        draw = self._dirty_parts | set(PARTS if parts is None else parts)
        if self.show_splats and not self._in_events and "scene" in draw:
            self._unprompted(self.update_splats)
            draw |= self._dirty_parts  # a new splat image asks for the scene
        self._update_status()  # shows the previous frame's time
        rw = self.plotter.ren_win
        skipped = []
        if not draw >= set(PARTS):
            named = self._part_renderers()
            scene_drawn = "scene" in draw
            for ren in _renderers(rw):
                if not ren.GetDraw():
                    continue
                part = next((k for k, r in named.items() if r is ren), None)
                # unnamed renderers (the orientation axes' layer) are drawn with the scene they sit on
                if not (part in draw if part is not None else scene_drawn):
                    ren.DrawOff()
                    skipped.append(ren)
        t0 = time.perf_counter()
        try:
            rw.Render()
            if self._presenter is not None:  # only the panels drawn go to the X window
                self._presenter.present(None if not skipped else self._drawn_box(draw))
        finally:
            for ren in skipped:
                ren.DrawOn()
        self.timings.frame_ms = (time.perf_counter() - t0) * 1e3
        self.frames_drawn += 1
        self.last_frame_parts = tuple(sorted(draw))
        if "scene" in draw:
            self._splat_drawn_key = self._splat_key
            self._splat_fresh = False
        self._dirty_parts = set()

    def _drawn_box(self, parts: set[str]) -> tuple[int, int, int, int]:
        """The display-pixel rectangle (x0, y0, x1, y1) around the panels ``parts`` (the orientation axes
        sit inside the scene)."""
        boxes = [self.panel_box(p) for p in parts if p in PARTS]
        return (min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes),
                max(b[3] for b in boxes))

    def resize_panels(self, step: int) -> None:
        """Make the image column (preview above, quilt below) wider (``step`` > 0, key ``}``) or narrower
        (``{``) by ``PANEL_STEP`` of the window, within ``PANEL_WIDTHS``; the 3D scene takes the rest."""
        x0 = self.scene_renderer.GetViewport()[0]  # the slider column keeps its width
        width = float(np.clip(round(self.panel_width / PANEL_STEP + step) * PANEL_STEP, *PANEL_WIDTHS))
        if abs(width - self.panel_width) < 1e-9:
            self._set_status(f"image panels: {width:.0%} of the window is the "
                             f"{'widest' if step > 0 else 'narrowest'} they go")
            self._render()
            return
        self.panel_width = width
        split = 1.0 - width
        sx0, sy0, _, sy1 = self.scene_renderer.GetViewport()
        self.scene_renderer.SetViewport(x0, sy0, split, sy1)
        for panel in (self.preview_panel, self.thumb_panel):
            _, y0, _, y1 = panel.renderer.GetViewport()
            panel.renderer.SetViewport(split, y0, 1.0, y1)
            panel.fit()
        if self.look_through is not None:  # keep the quilt camera's pixels under its own projection
            self._place_scene_camera_at_view(self.look_through)
        self._set_status(f"image panels: {width:.0%} of the window")
        self._render()

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
                if self.config.partial_present:
                    from .present import region_presenter

                    self._presenter = region_presenter(self.plotter.ren_win)
                self._input_wait = x_input_wait(self.plotter.ren_win)
            self._check_resize()
            self.home_camera()  # pyvista's first show() put its own default camera in
            self.preview_panel.fit()
            self.thumb_panel.fit()
            self._render_now()
            if not self.off_screen and self.config.live_sliders:
                self._start_standin()  # after the first frame: a face drag's decimated mesh
            return
        self._render_now()

    def _install_input(self, iren: Any) -> None:
        """Our keys only; mouse to the 3D scene only; renders coalesced by the loop."""
        iren.clear_key_event_callbacks()  # pyvista's q/b/v/C/Up/Down/plus/minus
        inter = iren.interactor
        style = _scene_only_style(inter, self.scene_renderer, on_click=self._guarded_click)
        iren.style = style
        self._style = style
        # a camera drag or wheel turn ends with EndInteractionEvent and then a render request: the scene only
        style.AddObserver("EndInteractionEvent", lambda *_: setattr(self, "_camera_released", True))
        self._observers = [(inter, inter.AddObserver("KeyPressEvent", self._on_key)),
                           (inter, inter.AddObserver("ExitEvent", lambda *_: self.quit())),
                           (inter, inter.AddObserver("RenderEvent", self._on_render_request))]
        axes = getattr(self.scene_renderer, "axes_widget", None)
        if axes is not None:
            axes.KeyPressActivationOff()
            axes.InteractiveOff()

    def _on_render_request(self, *_: Any) -> None:
        # VTK asks for a frame: a camera drag (and its release) moves the scene only; widgets, expose events:
        # everything
        if self._camera_moving() or self._camera_released:
            self._camera_released = False
            self._dirty_parts.add("scene")
        elif self._live:  # a slider being dragged: its panel and the scene (the mesh follows)
            self._dirty_parts.update(("sliders", "scene"))
        else:
            self._dirty_parts.update(PARTS)

    def step(self) -> bool:
        """One turn of the event loop: X events, live sliders, background results, one frame if needed.

        Returns False once the window should close (``q``, the window's close button)."""
        if self._thumb_wanted:
            self._thumb_wanted = False
            self._unprompted(self._update_thumbnail)
        iren = self.plotter.iren
        if iren is not None and not self.off_screen:
            inter = iren.interactor
            inter.EnableRenderOff()  # widget / camera renders are coalesced into one per turn
            self._in_events = True
            try:
                iren.process_events()
            finally:
                self._in_events = False
                self._camera_released = False  # its render request came with it, in these events
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
        try:
            self.poll_native()
        except Exception as exc:  # noqa: BLE001 - a worker failure must not kill the event loop
            self._show_error(f"native image failed: {exc}")
            self._native_pending = None
        self._collect_jobs()
        self._unprompted(self.poll_splats)
        self._check_resize()
        if self._dirty:
            if self.show_splats and "scene" in self._dirty_parts:
                self._unprompted(self.update_splats)  # a camera drag: the worker starts on the new pose
            if not self._holding_for_splat():
                self._render_now(())  # the panels asked for this turn only (a camera drag: the scene)
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
                self.wait_for_input(idle_sleep)
        finally:
            self._looping = False
        return False

    def wait_for_input(self, timeout: float) -> None:
        """The loop's idle wait: until X input arrives or the splat worker has an image (at once, no poll
        period on the input path), at most ``timeout`` seconds (the period at which background results,
        thumbnails, native images and exports, are collected). Without an X connection: a plain sleep."""
        if self._input_wait is None:
            time.sleep(timeout)
            return
        self._input_wait.wait(timeout, (self._splat_worker.wake_fd,) if self._splat_worker.wake_fd >= 0 else ())

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
        self._close_splats()
        self._close_standin()
        self._jobs.close()
        self._collect_jobs()
        for name in ("_worker", "_native_worker"):
            worker = getattr(self, name, None)
            if worker is not None:
                worker.release()  # an idle worker serves the next viewer of this process
                setattr(self, name, None)
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
        if self._presenter is not None:
            self._presenter.close()
            self._presenter = None
        self._input_wait = None
        self.plotter.close()

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
        x0, y0 = ren.GetOrigin()  # the pixels VTK gives the viewport (it rounds the fractions itself)
        w, h = ren.GetSize()
        return x0, y0, x0 + w - 1, y0 + h - 1

    def read_pixels(self, which: str, front: bool = True) -> np.ndarray:
        """(h, w, 3) uint8 pixels of a panel as currently drawn (no re-render)."""
        import vtk
        from vtk.util.numpy_support import vtk_to_numpy

        x0, y0, x1, y1 = self.panel_box(which)
        arr = vtk.vtkUnsignedCharArray()
        self.plotter.ren_win.GetPixelData(x0, y0, x1, y1, 1 if front else 0, arr, 0)
        return vtk_to_numpy(arr).reshape(y1 - y0 + 1, x1 - x0 + 1, 3)


def _window_size(size: tuple[int, int] | None, off_screen: bool) -> tuple[int, int]:
    """``size``, or (None) the default window for the X screen (:data:`~.screen.DEFAULT_WINDOW` offscreen)."""
    if size is not None:
        return int(size[0]), int(size[1])
    if off_screen:
        return DEFAULT_WINDOW
    try:
        return window_size_for_screen(x_screen_size())
    except OSError:  # no screen to measure: VTK reports the display problem itself
        return DEFAULT_WINDOW
