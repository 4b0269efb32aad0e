"""The viewer's sliders: their specs and layout, live (while dragging) and release updates of the
face, the view settings and the selected view."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..errors import HoloViewerError, InputError
from ..pipeline import FaceControls, Pipeline, apply_frame
from .scene import au_label
from .widgets import _Slider, _text_actor


#: the most off-axis camera the shipped avatar was fitted through (orbit yaw; the quilt views span +-20 deg;
#: docs/avatar_fit.md). Views beyond it show unfitted Gaussians (pale mottled patches on cheek and jaw).
FITTED_YAW_DEG = 30.0
#: the viewer-angle slider's range for other avatars (Algorithm 1's cone centre)
VIEWER_ANGLE_MAX = 30.0


def viewer_angle_range(pipe: Pipeline) -> tuple[float, float]:
    """The viewer-angle slider's range (degrees): +-30, or for the default head's fitted avatar the angles
    at which every quilt view stays within the fitted cameras, +-(``FITTED_YAW_DEG`` - cone / 2) (at least
    +-1: the slider needs a range)."""
    if pipe.avatar is None or not getattr(pipe.model, "is_default_head", False):
        return -VIEWER_ANGLE_MAX, VIEWER_ANGLE_MAX
    cone = float(pipe.view.view_cone or pipe.calibration.view_cone)
    lim = float(np.clip(FITTED_YAW_DEG - cone / 2, 1.0, VIEWER_ANGLE_MAX))
    return -lim, lim


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
        specs += [
            _Slider("angle", "viewer angle (deg)", viewer_angle_range(pipe), "%+.1f", self._live_view, self._view_release,
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
        self.mesh_actor.SetVisibility(True)  # stands in for the splats / ellipsoids until release
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

    def set_face(self, face: FaceControls) -> None:
        """Apply new face controls: mesh now, then Gaussians and preview, then thumbnail."""
        t0 = time.perf_counter()
        self._set_mesh_points(self._mesh_for(face))
        self.mesh_actor.SetVisibility(self.show_mesh)
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

