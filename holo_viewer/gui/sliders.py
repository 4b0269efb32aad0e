"""The viewer's sliders: their specs and layout, live (while dragging) and release updates of the
face, the view settings and the selected view."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HoloViewerError, InputError
from ..pipeline import FaceControls, Pipeline, apply_frame
from .scene import au_label, decimated_faces, live_vertex_normals
from .widgets import _Slider, _text_actor


#: the fit's camera range assumed for the default head's avatar when its file does not say
#: (``fit_angle_range_deg`` absent: avatars fitted before it was stored, through orbit cameras at +-30 deg)
FITTED_YAW_DEG = 30.0
#: what a live slider step redraws: the slider's panel and the 3D scene (the image panels follow on release)
LIVE_PARTS = ("scene", "sliders")
#: the viewer-angle slider's range for other avatars (Algorithm 1's cone centre)
VIEWER_ANGLE_MAX = 30.0
#: meshes with fewer triangles are their own stand-in during a face drag (decimating gains nothing there)
STANDIN_MIN_TRIANGLES = 20000


def fit_angle_range(path: str | Path) -> tuple[float, float] | None:
    """``fit_angle_range_deg`` = [min, max] horizontal angle (degrees) of the cameras an avatar file was
    fitted through, or None when the file does not store it. Only that field is read."""
    from ..errors import AvatarError

    with np.load(path, allow_pickle=False) as z:
        if "fit_angle_range_deg" not in z.files:
            return None
        rng = np.asarray(z["fit_angle_range_deg"], dtype=np.float64)
    if rng.shape != (2,) or not np.all(np.isfinite(rng)) or rng[0] > rng[1]:
        raise AvatarError(f"{path}: field 'fit_angle_range_deg': expected [min, max] finite degrees, "
                          f"found {rng.tolist()}")
    return float(rng[0]), float(rng[1])


def _avatar_fit_file(pipe: Pipeline) -> Path | None:
    """The file the pipeline's avatar was fitted in: ``avatar.fit_file`` when set (an avatar loaded by a
    chooser), else the shipped fitted avatar for the default head."""
    path = getattr(pipe.avatar, "fit_file", None)
    if path is not None:
        return Path(path)
    if getattr(pipe.model, "is_default_head", False):
        from ..avatar.default_gaussians import fitted_asset_path

        return fitted_asset_path()
    return None


def viewer_angle_limits(pipe: Pipeline) -> tuple[float, float, str]:
    """(lo, hi, note): the viewer-angle slider's range in degrees and how it was found.

    Every quilt view (viewer angle +- cone / 2) stays within the cameras the avatar was fitted through:
    [min + cone / 2, max - cone / 2] of the avatar file's ``fit_angle_range_deg`` (an avatar's own
    ``fit_angle_range_deg`` attribute first). A default-head avatar whose file does not store it: +-
    ``FITTED_YAW_DEG`` is assumed (+-10 deg at the Portrait's 40 deg cone) and the note says so. No
    avatar, or an avatar not fitted here: +-30. The range is at least 2 degrees wide (about its centre)."""
    if pipe.avatar is None:
        return -VIEWER_ANGLE_MAX, VIEWER_ANGLE_MAX, "no avatar: the full +-30 deg"
    fit = getattr(pipe.avatar, "fit_angle_range_deg", None)
    where = "the avatar"
    if fit is None:
        path = _avatar_fit_file(pipe)
        if path is None:
            return -VIEWER_ANGLE_MAX, VIEWER_ANGLE_MAX, "avatar not fitted here: the full +-30 deg"
        fit = fit_angle_range(path) if path.exists() else None
        where = path.name
        if fit is None:
            fit = (-FITTED_YAW_DEG, FITTED_YAW_DEG)
            where = f"{path.name} (no fit_angle_range_deg stored: +-{FITTED_YAW_DEG:g} deg assumed)"
    cone = float(pipe.view.view_cone or pipe.calibration.view_cone)
    lo, hi = float(fit[0]) + cone / 2, float(fit[1]) - cone / 2
    lo, hi = max(lo, -VIEWER_ANGLE_MAX), min(hi, VIEWER_ANGLE_MAX)
    if hi - lo < 2.0:
        mid = float(np.clip((lo + hi) / 2, -VIEWER_ANGLE_MAX + 1, VIEWER_ANGLE_MAX - 1))
        lo, hi = mid - 1.0, mid + 1.0
    note = (f"viewer angle {lo:+.1f}..{hi:+.1f} deg: the views stay within the avatar's fit cameras "
            f"{float(fit[0]):+.0f}..{float(fit[1]):+.0f} deg ({where})")
    return lo, hi, note


def viewer_angle_range(pipe: Pipeline) -> tuple[float, float]:
    """The viewer-angle slider's range in degrees (:func:`viewer_angle_limits` without the note)."""
    return viewer_angle_limits(pipe)[:2]


class SlidersMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer` (uses its attributes; not used alone)."""

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
        lo, hi, self.angle_range_note = viewer_angle_limits(pipe)
        specs += [
            _Slider("angle", "viewer angle (deg)", (lo, hi), "%+.1f", self._live_view, self._view_release,
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
                _Slider("eye_angle", "eye angle (deg)", (-30.0, 30.0), "%+.1f", None,
                        lambda v: self.set_eye(angle=v), "simulated eye", aliases=("eye",)),
                _Slider("eye_distance", "eye distance (m)", (0.2, 2.0), "%.2f", None,
                        lambda v: self.set_eye(distance=v), "simulated eye"),
            ]
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
            "min_opacity": self.glyph_min_opacity, "eye_angle": self.eye_angle, "eye_distance": self.eye_distance,
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
        self._dirty_parts.update(("sliders", "scene"))

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
        c0 = time.process_time()
        self._set_mesh_points(self._mesh_for(self._face_from_sliders(key, value)))
        if not self.show_mesh:  # a stand-in: one headlight instead of pyvista's five (~13 ms a frame)
            self._stand_in_lights(True)
        self.mesh_actor.SetVisibility(True)  # stands in for the splats / ellipsoids until release
        if self.glyph_actor is not None:
            self.glyph_actor.SetVisibility(False)  # stale until release
        self._render_now(LIVE_PARTS)
        self.timings.live_ms = (time.perf_counter() - t0) * 1e3
        self.timings.live_cpu_ms = (time.process_time() - c0) * 1e3

    def _face_release(self, value: float, key: str | None = None) -> None:
        key = key or self._releasing
        self.set_face(self._face_from_sliders(key, value))

    def _view_changes(self, key: str, value: float) -> dict[str, float]:
        return {"angle": {"viewer_angle": value}, "distance": {"viewer_distance": value},
                "cone": {"view_cone": value}}[key]

    def _live_view(self, key: str, value: float, t0: float) -> None:
        self.pipeline.set_view(**self._view_changes(key, value))
        self._refresh_cameras()
        self._render_now(LIVE_PARTS + ("preview",))  # its title names the selected view's angle
        self.timings.live_ms = (time.perf_counter() - t0) * 1e3

    def _view_release(self, value: float, key: str | None = None) -> None:
        key = key or self._releasing
        self.set_view(**self._view_changes(key, value))

    def _live_select(self, key: str, value: float, t0: float) -> None:
        self._move_selection(int(round(value)))
        self._render_now(LIVE_PARTS + ("preview",))
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

    def set_face(self, face: FaceControls) -> None:
        """Apply new face controls: mesh now, then Gaussians and preview, then thumbnail."""
        t0 = time.perf_counter()
        self._set_mesh_points(self._mesh_for(face))
        self._stand_in_lights(False)
        self.mesh_actor.SetVisibility(self.show_mesh)
        # the glyphs are stale until the Gaussians are recomputed: leave them out of this frame,
        # which halves its cost with software OpenGL
        if self.glyph_actor is not None:
            self.glyph_actor.SetVisibility(False)
        if not self.show_splats:  # with the splats the new face's picture is their frame, drawn next:
            self._render_now()  # a frame now would only bring the old splats back for ~100 ms
        self.timings.mesh_ms = (time.perf_counter() - t0) * 1e3
        self._after_change(t0)

    def _start_standin(self, wait: bool = False) -> None:
        """Decimate the mesh for the face-drag stand-in (``ViewerConfig.standin_reduction`` of its triangles
        removed, :func:`~.scene.decimated_faces`) in a background thread: started after the first frame, so
        neither the launch nor a drag waits for it (until it is done a drag shows the whole mesh).
        Meshes under ``standin_min_triangles`` triangles are their own stand-in."""
        self._standin_cells = None
        faces = self.faces
        red = float(self.config.standin_reduction)
        if red <= 0.0 or len(faces) < int(self.standin_min_triangles):
            self._standin_job = None
            return
        verts, faces = np.asarray(self.mesh.points, dtype=np.float64).copy(), np.array(faces, dtype=np.int64)
        box: dict[str, Any] = {}

        def work() -> None:
            try:
                box["faces"] = decimated_faces(verts, faces, red)
            except Exception as exc:  # noqa: BLE001 - no stand-in then: the whole mesh is drawn
                box["error"] = exc

        thread = threading.Thread(target=work, name="standin-decimate", daemon=True)
        self._standin_job = ((len(verts), len(faces)), thread, box)
        thread.start()
        if wait:
            thread.join()

    def _standin_polys(self) -> Any:
        """The decimated stand-in's triangles as a ``vtkCellArray`` over the mesh's own points, or None
        (not computed yet, failed, or the mesh is its own stand-in)."""
        job = getattr(self, "_standin_job", None)
        if job is None or job[1].is_alive():
            return None
        key, _, box = job
        if key != (self.mesh.n_points, len(self.faces)) or "faces" not in box:
            return None
        if self._standin_cells is None:
            import vtk
            from vtk.util.numpy_support import numpy_to_vtkIdTypeArray

            tri = box["faces"]
            cells = vtk.vtkCellArray()
            cells.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(tri) + 1, 3, dtype=np.int64), deep=True),
                          numpy_to_vtkIdTypeArray(np.ascontiguousarray(tri, dtype=np.int64).ravel(), deep=True))
            self._standin_cells = cells
        return self._standin_cells

    def _close_standin(self) -> None:
        job = getattr(self, "_standin_job", None)
        if job is not None:
            job[1].join(timeout=10)

    def _stand_in_lights(self, on: bool) -> None:
        """Light the scene with one headlight while the mesh stands in for the splats during a face-slider
        drag (per-pixel lighting of the face-filling mesh is most of that frame with software OpenGL:
        pyvista's light kit has five lights); back to the light kit on release. The stand-in also skips
        the mesh's back faces (the insides of the mouth, eyelids and hair shell: ~8 ms CPU of a ~57 ms
        step on the default head, 0.1 % of the scene's pixels differ); culling is off again on release.
        And it draws the decimated triangles (:meth:`_start_standin`; the same points, normals and LBS,
        half the triangles on the default head), the whole mesh's triangles back on release."""
        import vtk

        ren = self.scene_renderer
        self.mesh_actor.GetProperty().SetBackfaceCulling(bool(on))
        full = getattr(self, "_full_polys", None)
        if on and full is None:
            cells = self._standin_polys()
            if cells is not None:
                self._full_polys = self.mesh.GetPolys()
                self.mesh.SetPolys(cells)
        elif not on and full is not None:
            self.mesh.SetPolys(full)
            self._full_polys = None
        saved = getattr(self, "_saved_lights", None)
        if on and saved is None:
            lights = ren.GetLights()
            lights.InitTraversal()
            self._saved_lights = [lights.GetNextItem() for _ in range(lights.GetNumberOfItems())]
            ren.RemoveAllLights()
            head = vtk.vtkLight()
            head.SetLightTypeToHeadlight()
            ren.AddLight(head)
        elif not on and saved is not None:
            ren.RemoveAllLights()
            for light in saved:
                ren.AddLight(light)
            self._saved_lights = None

    def _set_mesh_points(self, verts: np.ndarray) -> None:
        self.mesh.points[:] = verts
        if "Normals" in self.mesh.point_data:  # the mesh's own smooth-shading normals (mesh_polydata)
            normals = np.asarray(self.mesh.point_data["Normals"])
            if normals.dtype == np.float64 and normals.flags.c_contiguous:
                live_vertex_normals(verts, self.faces, out=normals)
            else:
                normals[:] = live_vertex_normals(verts, self.faces)
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
        if getattr(self, "look_through", None) is not None:
            self.look_through = self.selected_view
            self._place_scene_camera_at_view(self.selected_view)
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

