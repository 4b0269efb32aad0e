"""Interactive inspection viewer (PyVista, no Qt): mesh, Gaussians, frusta, sliders, preview.

Layout of the window (``pyvista.Plotter`` with three renderers)::

    +-----------+--------------------------+-----------------+
    | sliders   | 3D scene: FLAME mesh,    | selected view   |
    | (expr,    | Gaussian ellipsoids,     | (fast renderer) |
    |  jaw,     | 48 frusta coloured by    +-----------------+
    |  pain...) | view, focal plane        | quilt thumbnail |
    +-----------+--------------------------+-----------------+

Sliders fire on ``EndInteractionEvent`` (``interaction_event="end"``): a release
updates the pipeline, then the mesh (rendered at once), the Gaussian glyphs and the
preview view, then the quilt thumbnail. Keys (``h`` shows them in the window):

====  ======================================================================
m     toggle the FLAME mesh          l   toggle mesh wireframe
g     toggle Gaussian ellipsoids     o   toggle frusta and focal plane
k     export the quilt PNG           n   export the native PNG
x     export an expression-sweep mp4 i   save a screenshot PNG
h     toggle the help overlay        q   quit
====  ======================================================================

Exports go to :attr:`ViewerConfig.out_dir`, written atomically.
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
from .scene import (focal_plane_polydata, vertex_normals, frusta_polydata, glyph_polydata, image_plane, mesh_polydata,
                    subsample_indices, view_colors)

__all__ = ["ViewerConfig", "HoloViewer", "HELP_TEXT", "scale_cameras"]

HELP_TEXT = """keys
 m  mesh on/off        l  wireframe
 g  Gaussians on/off   o  frusta on/off
 k  export quilt       n  export native
 x  sweep video        i  screenshot
 h  this help          q  quit
sliders act on release"""


@dataclass(frozen=True)
class ViewerConfig:
    """Viewer settings.

    Attributes
    ----------
    window_size : (int, int)
        Window width, height in pixels.
    n_expr_sliders : int
        Number of expression-component sliders: the components named ``expr_names`` when the model
        names its components (the default head: action units, range 0..1.5), else the first ones
        (range +-``expr_range`` standard deviations).
    max_glyphs : int
        Gaussians drawn as ellipsoids (a deterministic random subset keeps it interactive).
    glyph_sigmas : float
        Ellipsoid radius in standard deviations.
    glyph_subdivisions : int
        Icosphere subdivisions of each ellipsoid (0: 20 triangles; software OpenGL pays per triangle).
    preview_scale, thumbnail_scale : float
        Size of the preview view and of the thumbnail quilt's tiles relative to the quilt tile.
    auto_thumbnail : bool
        Re-render the thumbnail quilt after every slider release (else on the ``k`` export only).
    sweep_frames, sweep_scale : int, float
        Frames and tile scale of the expression-sweep video.
    out_dir : str
        Folder of exports.
    show_status : bool
        Show the status line (timings, last export) in the lower right corner.
    multi_samples : int
        MSAA samples (pyvista's default 8 costs ~3x per frame with software OpenGL; 0 = off).
    """

    window_size: tuple[int, int] = (1400, 800)
    n_expr_sliders: int = 4
    expr_names: tuple[str, ...] = ("AU2_L", "AU4", "AU9", "AU20")
    expr_range: float = 2.0
    max_glyphs: int = 1500
    glyph_sigmas: float = 1.5
    glyph_subdivisions: int = 0
    preview_scale: float = 0.4
    thumbnail_scale: float = 0.125
    auto_thumbnail: bool = True
    sweep_frames: int = 16
    sweep_scale: float = 0.5
    sweep_fps: float = 8.0
    out_dir: str = "holo_viewer_out"
    title: str = "holo-viewer"
    show_status: bool = True
    multi_samples: int = 0


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


class _ImagePanel:
    """An image shown on a textured quad in its own renderer (parallel projection)."""

    def __init__(self, plotter: Any, subplot: tuple[int, int], title: str) -> None:
        self.plotter = plotter
        self.subplot = subplot
        self.actor: Any = None
        self.shape: tuple[int, int] | None = None
        self.image: np.ndarray | None = None
        plotter.subplot(*subplot)
        plotter.add_text(title, position="upper_left", font_size=9, color="white")
        plotter.set_background("black", all_renderers=False)

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
            plane = image_plane(w / h, 1.0)
            self.actor = self.plotter.add_mesh(plane, texture=tex, lighting=False, reset_camera=False,
                                               name=f"panel{self.subplot}")
            self.shape = (h, w)
            self.plotter.enable_parallel_projection()
            cam = self.plotter.renderer.camera
            cam.position = (0.0, 0.0, 5.0)
            cam.focal_point = (0.0, 0.0, 0.0)
            cam.up = (0.0, 1.0, 0.0)
            self._fit(w / h)
        else:
            self.actor.texture = tex

    def _fit(self, image_aspect: float) -> None:
        """Parallel scale so the whole image (height 1, width ``image_aspect``) fits the viewport."""
        ren = self.plotter.renderer
        x0, y0, x1, y1 = ren.GetViewport()
        W, H = self.plotter.window_size
        vp_aspect = max((x1 - x0) * W, 1.0) / max((y1 - y0) * H, 1.0)
        ren.camera.parallel_scale = 0.52 * max(1.0, image_aspect / vp_aspect)


@dataclass
class UpdateTimings:
    """Milliseconds from a slider release to each part of the scene being on screen."""

    mesh_ms: float = float("nan")
    preview_ms: float = float("nan")
    thumbnail_ms: float = float("nan")
    stages: dict[str, float | None] = field(default_factory=dict)


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
        self.timings = UpdateTimings()
        self.exports: list[Path] = []
        self.sliders: dict[str, Any] = {}
        self._glyph_index: np.ndarray | None = None
        self._thumb_key: tuple | None = None
        self._building = True
        self._opened = False
        self._worker: Any = None
        self._thumb_pending_key: tuple | None = None
        self._thumb_started = 0.0

        self.plotter = pv.Plotter(shape=(2, 3), groups=[(np.s_[:], 0), (np.s_[:], 1)],
                                  col_weights=[0.9, 2.4, 1.2], window_size=list(self.config.window_size),
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
        # ---- 3D scene
        p.subplot(0, 1)
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
        self._add_frusta()
        self.status = p.add_text("", position="lower_right", font_size=8, color="white", name="status")
        self.help_actor = p.add_text(HELP_TEXT, position="upper_left", font_size=9, color="#ffe680",
                                     name="help")
        self.help_actor.SetVisibility(self.show_help)
        self._set_scene_camera()
        # ---- image panels
        self.preview_panel = _ImagePanel(p, (0, 2), "selected view")
        self.thumb_panel = _ImagePanel(p, (1, 2), "quilt")
        # ---- sliders
        p.subplot(0, 0)
        p.set_background("#15171b", all_renderers=False)
        self._add_sliders()
        # ---- keys
        for key, fn in {"m": self.toggle_mesh, "l": self.toggle_wireframe, "g": self.toggle_gaussians,
                        "o": self.toggle_frusta, "h": self.toggle_help, "k": self.export_quilt,
                        "n": self.export_native, "x": self.export_sweep_video,
                        "i": self.save_screenshot}.items():
            p.add_key_event(key, self._guard(fn))
        p.subplot(0, 1)
        self._update_preview()
        if self.config.auto_thumbnail:
            self._update_thumbnail(wait=True)
        self._update_status()

    def _set_scene_camera(self) -> None:
        cams = self.pipeline.cameras()
        centre, half = self.pipeline.get("framing")
        mid = cams.positions[len(cams) // 2]
        p = self.plotter
        p.subplot(0, 1)
        # look at the head and the camera rail from the front-right, above
        d = float(np.linalg.norm(mid - centre))
        focal = centre + np.array([0.0, 0.0, 0.2 * d])
        direction = np.array([1.0, 0.4, 1.1]) / np.linalg.norm([1.0, 0.4, 1.1])
        eye = focal + 1.05 * d * direction
        p.renderer.camera_position = [tuple(eye), tuple(focal), (0.0, 1.0, 0.0)]
        p.renderer.camera.view_angle = 30.0
        p.renderer.reset_camera_clipping_range()

    def _add_frusta(self) -> None:
        p = self.plotter
        p.subplot(0, 1)
        cams = self.pipeline.cameras()
        centre, _ = self.pipeline.get("framing")
        self.frusta = frusta_polydata(cams, centre)
        cols = view_colors(len(cams))
        rgb = (cols[self.frusta.cell_data["view"]] * 255).astype(np.uint8)
        self.frusta.cell_data["rgb"] = rgb
        self.frusta_actor = p.add_mesh(self.frusta, scalars="rgb", rgb=True, line_width=1.0,
                                       name="frusta", reset_camera=False, lighting=False)
        sel = frusta_polydata(cams[self.selected_view], centre)
        self.selected_actor = p.add_mesh(sel, color="white", line_width=3.0, name="selected",
                                         reset_camera=False, lighting=False)
        self.focal_actor = p.add_mesh(focal_plane_polydata(cams, centre), color="#5fa8ff", style="wireframe",
                                      line_width=2.0, name="focal", reset_camera=False, lighting=False)
        for a in (self.frusta_actor, self.selected_actor, self.focal_actor):
            a.SetVisibility(self.show_frusta)

    def _add_sliders(self) -> None:
        pipe, cfg, p = self.pipeline, self.config, self.plotter
        names = list(pipe.model.expression_names or [])
        specs: list[tuple[str, str, tuple[float, float], float, Callable[[float], None]]] = []
        chosen = [names.index(n) for n in cfg.expr_names if n in names] if names else []
        if not chosen:
            chosen = list(range(min(cfg.n_expr_sliders, int(pipe.model.n_expr))))
        rng = (0.0, 1.5) if getattr(pipe.model, "is_default_head", False) else (-cfg.expr_range, cfg.expr_range)
        for i in chosen[: cfg.n_expr_sliders]:
            label = f"expr {i}" + (f" ({names[i]})" if i < len(names) else "")
            value = float(pipe.face.expr[i]) if i < pipe.face.expr.shape[0] else 0.0
            specs.append((f"expr{i}", label, rng, value,
                          lambda v, i=i: self.set_face(self.pipeline.face.with_expr_component(i, v))))
        specs += [
            ("smile", "smile", (0.0, 1.0), dict(pipe.face.named).get("smile", 0.0), lambda v: self.set_face(self.pipeline.face.with_named("smile", v))),
            ("jaw", "jaw open (rad)", (0.0, 0.5), float(pipe.face.jaw_pose[0]),
             lambda v: self.set_face(self.pipeline.face.replace(
                 jaw_pose=np.array([v, *self.pipeline.face.jaw_pose[1:]])))),
            ("pain", "pain", (0.0, 1.0), float(pipe.face.pain), lambda v: self.set_face(self.pipeline.face.replace(pain=v))),
            ("distance", "viewer distance (m)", (0.3, 1.5), float(pipe.view.viewer_distance or 0.65),
             lambda v: self.set_view(viewer_distance=v)),
            ("cone", "view cone (deg)", (10.0, 60.0), float(pipe.view.view_cone or pipe.calibration.view_cone),
             lambda v: self.set_view(view_cone=v)),
            ("view", "selected view", (0, len(pipe.cameras()) - 1), float(self.selected_view),
             lambda v: self.select_view(int(round(v)))),
        ]
        if self.frames is not None and len(self.frames) > 1:
            specs.insert(0, ("frame", "sequence frame", (0, len(self.frames) - 1), 0.0,
                             lambda v: self.set_face(apply_frame(self._frame_base, self.frames[int(round(v))]))))
        k = len(specs)
        top, bottom = 0.96, 0.04
        step = (top - bottom) / k
        for j, (key, title, rng, value, fn) in enumerate(specs):
            y = top - (j + 0.55) * step
            w = p.add_slider_widget(self._guard(fn), rng, value=value, title=title, pointa=(0.08, y),
                                    pointb=(0.92, y), interaction_event="end", style="modern",
                                    title_height=0.018, fmt="%.0f" if key in ("view", "frame") else "%.2f",
                                    slider_width=0.02, tube_width=0.006, title_opacity=0.9)
            self.sliders[key] = w

    def _guard(self, fn: Callable) -> Callable:
        """Wrap a callback: show our errors in the status line instead of killing the event loop."""
        from ..errors import HoloViewerError

        def wrapped(value: Any = None) -> None:
            if self._building:  # pyvista fires every slider callback once on creation
                return
            try:
                fn() if value is None else fn(value)
            except HoloViewerError as exc:
                self._set_status(f"error: {exc}")
                self.plotter.render()
        return wrapped

    # ================================================================== updates
    def set_face(self, face: FaceControls) -> None:
        """Apply new face controls: mesh now, then Gaussians and preview, then thumbnail."""
        t0 = time.perf_counter()
        self.pipeline.set_face(face)
        (verts,), tim = self.pipeline.compute("mesh")
        self._set_mesh_points(verts)
        # the glyphs are stale until the Gaussians are recomputed: leave them out of this frame,
        # which halves its cost with software OpenGL
        if self.glyph_actor is not None and self.show_gaussians:
            self.glyph_actor.SetVisibility(False)
        self.plotter.render()
        self.timings = UpdateTimings(mesh_ms=(time.perf_counter() - t0) * 1e3)
        self._after_change(t0)

    def _set_mesh_points(self, verts: np.ndarray) -> None:
        self.mesh.points[:] = verts
        if "Normals" in self.mesh.point_data:
            self.mesh.point_data["Normals"][:] = vertex_normals(verts, self.faces)
        self.mesh.Modified()

    def set_view(self, **changes: Any) -> None:
        """Apply new view settings (viewer distance, view cone): frusta, preview, thumbnail."""
        t0 = time.perf_counter()
        self.pipeline.set_view(**changes)
        self.pipeline.cameras()
        self._refresh_frusta()
        self.plotter.render()
        self.timings = UpdateTimings(mesh_ms=(time.perf_counter() - t0) * 1e3)
        self._after_change(t0)

    def select_view(self, index: int) -> None:
        t0 = time.perf_counter()
        n = len(self.pipeline.cameras())
        if not 0 <= index < n:
            raise InputError(f"selected view: expected 0..{n - 1}, found {index}")
        self.selected_view = index
        self._refresh_frusta()
        self.plotter.render()
        self.timings = UpdateTimings(mesh_ms=(time.perf_counter() - t0) * 1e3)
        self._update_preview()
        self.timings.preview_ms = (time.perf_counter() - t0) * 1e3
        self._update_status()
        self.plotter.render()

    def _after_change(self, t0: float) -> None:
        if self.pipeline.avatar is not None:
            self._update_glyphs()
            self.glyph_actor.SetVisibility(self.show_gaussians)
            self._update_preview()
            self.timings.stages = self.pipeline.last_timings.as_dict()
            self._update_status()
            self.plotter.render()
            self.timings.preview_ms = (time.perf_counter() - t0) * 1e3
            self._update_status()
            if self.config.auto_thumbnail:
                self._update_thumbnail()
        else:
            self._update_status()
            self.plotter.render()

    def _refresh_frusta(self) -> None:
        vis = self.show_frusta
        self._add_frusta()  # named actors are replaced in place
        for a in (self.frusta_actor, self.selected_actor, self.focal_actor):
            a.SetVisibility(vis)

    def _update_glyphs(self) -> None:
        g = self.pipeline.gaussians()
        if self._glyph_index is None or self._glyph_index.max(initial=-1) >= len(g):
            self._glyph_index = subsample_indices(len(g), self.config.max_glyphs)
        poly = glyph_polydata(g, self._glyph_index, sigmas=self.config.glyph_sigmas,
                              subdivisions=self.config.glyph_subdivisions)
        if self.glyphs is None:
            self.plotter.subplot(0, 1)
            self.glyphs = poly
            self.glyph_actor = self.plotter.add_mesh(self.glyphs, scalars="rgb", rgb=True, name="glyphs",
                                                     reset_camera=False, smooth_shading=False)
            self.glyph_actor.SetVisibility(self.show_gaussians)
        else:
            self.glyphs.points[:] = poly.points
            self.glyphs.point_data["rgb"][:] = poly.point_data["rgb"]
            self.glyphs.Modified()

    def _preview_cameras(self) -> Any:
        return scale_cameras(self.pipeline.cameras(), self.config.preview_scale)

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
        if key == self._thumb_pending_key:
            self._thumb_pending_key = None
            self.timings.thumbnail_ms = (time.perf_counter() - self._thumb_started) * 1e3
        self.thumb_panel.update(img)
        self._thumb_key = key
        self._update_status()
        self.plotter.render()
        return True

    def _on_timer(self, *_: Any) -> None:
        try:
            self.poll_thumbnail()
        except Exception as exc:  # noqa: BLE001 - a worker failure must not kill the event loop
            self._set_status(f"thumbnail failed: {exc}")

    def _set_status(self, text: str) -> None:
        self.status.SetText(1, text if self.config.show_status else "")  # lower right corner

    def _update_status(self) -> None:
        t = self.timings
        f = self.pipeline.face
        self._set_status(f"view {self.selected_view}  pain {f.pain:.2f}\n"
                         f"mesh {t.mesh_ms:.0f} ms  preview {t.preview_ms:.0f} ms  "
                         f"quilt thumb {t.thumbnail_ms:.0f} ms")

    # ================================================================== toggles
    def toggle_mesh(self) -> None:
        self.show_mesh = not self.show_mesh
        self.mesh_actor.SetVisibility(self.show_mesh)
        self.plotter.render()

    def toggle_wireframe(self) -> None:
        self.wireframe = not self.wireframe
        prop = self.mesh_actor.GetProperty()
        prop.SetRepresentationToWireframe() if self.wireframe else prop.SetRepresentationToSurface()
        self.plotter.render()

    def toggle_gaussians(self) -> None:
        if self.glyph_actor is None:
            return
        self.show_gaussians = not self.show_gaussians
        self.glyph_actor.SetVisibility(self.show_gaussians)
        self.plotter.render()

    def toggle_frusta(self) -> None:
        self.show_frusta = not self.show_frusta
        for a in (self.frusta_actor, self.selected_actor, self.focal_actor):
            a.SetVisibility(self.show_frusta)
        self.plotter.render()

    def toggle_help(self) -> None:
        self.show_help = not self.show_help
        self.help_actor.SetVisibility(self.show_help)
        self.plotter.render()

    # ================================================================== exports
    def _out(self, name: str) -> Path:
        out = Path(self.config.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        return out / name

    def _stamp(self) -> str:
        return time.strftime("%Y%m%d-%H%M%S") + f"-{len(self.exports):03d}"

    def _record(self, path: Path) -> Path:
        self.exports.append(path)
        self._set_status(f"wrote {path}")
        self.plotter.render()
        return path

    def export_quilt(self) -> Path:
        """Write the full-resolution quilt PNG (``*_qs8x6a0.75.png``)."""
        from ..display.quilt import quilt_filename
        from ..fileio import save_image

        cal = self.pipeline.calibration
        path = self._out(quilt_filename(f"view-{self._stamp()}", cal.cols, cal.rows, cal.aspect))
        save_image(path, self.pipeline.quilt())
        return self._record(path)

    def export_native(self) -> Path:
        """Write the native (lenticular) PNG for the pipeline's calibration."""
        from ..fileio import save_image

        path = self._out(f"view-{self._stamp()}_native.png")
        save_image(path, self.pipeline.native())
        return self._record(path)

    def export_sweep_video(self) -> Path:
        """Write an mp4 of quilts sweeping smile 0 -> 1 -> 0 at the current pain (tiles at ``sweep_scale``).

        Models without an action-unit map sweep their first expression component instead."""
        from ..display.export import write_quilt_video
        from ..display.quilt import quilt_filename
        from .thumbnail_worker import render_thumbnail

        cfg, pipe = self.config, self.pipeline
        cal = pipe.calibration
        path = self._out(quilt_filename(f"sweep-{self._stamp()}", cal.cols, cal.rows, cal.aspect, suffix=".mp4"))
        base = pipe.face
        cams = scale_cameras(pipe.cameras(), cfg.sweep_scale)
        weights = np.sin(np.linspace(0.0, np.pi, max(2, cfg.sweep_frames)))
        self._set_status(f"rendering a {len(weights)}-quilt sweep video (progress in the terminal)...")
        self.plotter.render()

        try:
            pipe.au_map  # noqa: B018 - named expressions need the model's action-unit map
            def sweep(w: float) -> FaceControls:
                return base.with_named("smile", w)
        except HoloViewerError:  # a FLAME model without an AU map: sweep its first component
            def sweep(w: float) -> FaceControls:
                return base.with_expr_component(0, cfg.expr_range * w)

        def frames() -> Any:
            for w in weights:
                pipe.set_face(sweep(float(w)))
                yield render_thumbnail(pipe.gaussians(), cams, pipe.backend, pipe.render_config, cal.cols, cal.rows)

        try:
            write_quilt_video(path, frames(), fps=cfg.sweep_fps, total=len(weights), preset="veryfast")
        finally:
            pipe.set_face(base)
            pipe.get("gaussians")
        return self._record(path)

    def screenshot(self) -> np.ndarray:
        """(H, W, 3) uint8 image of the whole window."""
        img = self.plotter.screenshot(None, return_img=True)
        return np.asarray(img)[..., :3]

    def save_screenshot(self, path: str | Path | None = None) -> Path:
        from ..fileio import save_image

        target = Path(path) if path is not None else self._out(f"screenshot-{self._stamp()}.png")
        save_image(target, self.screenshot())
        return self._record(target)

    # ================================================================== run
    def open(self) -> None:
        """Map the window and draw it without entering the event loop (tests, scripted use)."""
        if not self._opened:
            self.plotter.show(auto_close=False, interactive_update=True)
            self._opened = True
        self.plotter.render()

    def show(self) -> None:
        """Open the window and run the event loop until it is closed."""
        iren = self.plotter.iren
        self.open()
        if iren is not None and not self.off_screen:
            iren.add_observer("TimerEvent", self._on_timer)
            iren.create_timer(200, repeating=True)
            iren.start()
        self.close()

    def close(self) -> None:
        if self._worker is not None:
            self._worker.close()
            self._worker = None
        self.plotter.close()


def _theme(config: ViewerConfig) -> Any:
    """A copy of pyvista's global theme with our anti-aliasing settings (the global one is left alone)."""
    import copy

    import pyvista as pv

    theme = copy.deepcopy(pv.global_theme)
    theme.multi_samples = int(config.multi_samples)
    theme.anti_aliasing = None
    theme.depth_peeling.enabled = False
    return theme
