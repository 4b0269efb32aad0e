"""The 3D scene of the viewer: framing the camera, the quilt cameras' frusta and labels, the
Gaussian ellipsoids, and the overlay toggles (``m``, ``l``, ``g``, ``c``, ``o``, ``h``)."""

from __future__ import annotations


import numpy as np

from ..errors import InputError
from .scene import GLYPH_COLOR_MODES, focal_plane_polydata, frusta_arrays, glyph_polydata, glyph_selection, scene_bounds, view_colors
from .widgets import _text_actor


class SceneMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer` (uses its attributes; not used alone)."""

    def _default_camera_bounds(self) -> tuple[float, ...]:
        cams = self.pipeline.cameras()
        centre, _ = self.pipeline.get("framing")
        corners = frusta_arrays(cams[[0, len(cams) - 1]], centre)[0]
        return scene_bounds(self.pipeline.mesh(), cams.positions, corners, pad=0.02)

    def reset_camera(self) -> None:
        """Frame the head and all the quilt cameras, seen from the right and above (key ``r``)."""
        self._frame(self._default_camera_bounds(), (1.0, 0.7, 0.45), 1.05)

    def home_camera(self) -> None:
        """The opening view: the face filling the scene (``z``) when the splats are drawn, else the head
        and every quilt camera (``r``)."""
        if getattr(self, "show_splats", False):
            self.head_closeup()
        else:
            self.reset_camera()

    def head_closeup(self) -> None:
        """Frame the whole head, filling the scene, seen from the front and a little right and above (key ``z``)."""
        self._frame(scene_bounds(self.pipeline.mesh(), pad=0.0), (0.3, 0.12, 1.0), 1.2)

    def _frame(self, b: tuple[float, ...], direction: tuple[float, float, float], zoom: float) -> None:
        self.look_through = None
        ren = self.scene_renderer
        focal = np.array([(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2])
        cam = ren.GetActiveCamera()
        direction = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
        cam.SetFocalPoint(*focal)
        cam.SetPosition(*(focal + direction))
        cam.SetViewUp(0.0, 1.0, 0.0)
        cam.SetViewAngle(30.0)
        cam.SetWindowCenter(0.0, 0.0)  # a look-through camera's off-axis shift ends here
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
        if self.pipeline.avatar is None:
            self._set_status("no Gaussian avatar to draw (--avatar none): no ellipsoids to colour")
            self._render()
            return
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

    def camera_at(self, x: int, y: int, radius: float = 10.0) -> int | None:
        """The quilt camera whose centre is drawn within ``radius`` pixels of display pixel (x, y) (y from
        the bottom), the nearest; None when the cameras are hidden or none is that close."""
        if not self.show_frusta:
            return None
        ren = self.scene_renderer
        best, best_d = None, radius
        for i, p in enumerate(self.pipeline.cameras().positions):
            ren.SetWorldPoint(*p, 1.0)
            ren.WorldToDisplay()
            px, py, pz = ren.GetDisplayPoint()
            d = float(np.hypot(px - x, py - y))
            if 0.0 <= pz <= 1.0 and d <= best_d:
                best, best_d = i, d
        return best

    def _guarded_click(self, x: int, y: int) -> None:
        """A click in the scene selects the quilt camera under it."""
        index = self.camera_at(x, y)
        if index is not None:
            self._guarded(self.select_view, index)

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

