"""The 3D scene of the viewer: framing the camera, the quilt cameras' frusta and labels, the
Gaussian ellipsoids, and the overlay toggles (``m``, ``l``, ``g``, ``c``, ``o``, ``h``)."""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from .scene import GLYPH_COLOR_MODES, cut_segments_at_box, focal_plane_polydata, frusta_arrays, glyph_polydata, glyph_selection, scene_bounds, view_colors
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
        self._add_cut_overlays()
        self._show_camera_actors()

    # the overlay lines over the splats: cut where they would cross the head
    _CUT_LINES = (("frusta", 1.0), ("selected", 4.0), ("focal", 2.0))
    _FOCAL_RGB = (95, 168, 255)  # #5fa8ff

    def _add_cut_overlays(self) -> None:
        """With the splats drawn, the frusta, the selected frustum and the focal-plane outline are drawn by
        actors of their own holding only the parts outside the head's box on screen (recomputed before each
        frame of the scene, ``_cut_overlays``), so no overlay line crosses the face; without the splats the
        whole lines are drawn (the rig framing of ``r``)."""
        import vtk

        self._cut_actors = {}
        for name, width in self._CUT_LINES:
            mapper = vtk.vtkPolyDataMapper()
            mapper.SetInputData(vtk.vtkPolyData())
            mapper.SetScalarModeToUseCellData()
            mapper.SetColorModeToDirectScalars()  # the uint8 rgb of each line, as the whole lines
            actor = vtk.vtkActor()
            actor.SetMapper(mapper)
            actor.GetProperty().SetLineWidth(width)
            actor.GetProperty().LightingOff()
            actor.SetVisibility(False)
            self.scene_renderer.AddActor(actor)
            self._cut_actors[name] = actor
        self._cut_key = None
        self.head_screen_box: tuple[float, float, float, float] | None = None  # NDC, the last cut's
        self.scene_renderer.AddObserver("StartEvent", lambda *_: self._unprompted(self._cut_overlays))

    def _cut_sources(self) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """{name: (points, (n, 2) segment point ids, (n, 3) uint8 colours)} of the whole overlay lines."""
        fr, sel = self.frusta, self.selected
        focal = np.asarray(self.focal_actor.mapper.dataset.points)
        return {"frusta": (np.asarray(fr.points), fr.lines.reshape(-1, 3)[:, 1:],
                           np.asarray(fr.cell_data["rgb"])),
                "selected": (np.asarray(sel.points), sel.lines.reshape(-1, 3)[:, 1:],
                             np.full((sel.n_lines, 3), 255, np.uint8)),
                "focal": (focal[:4], np.array([[0, 1], [1, 2], [2, 3], [3, 0]]),
                          np.tile(np.array(self._FOCAL_RGB, np.uint8), (4, 1)))}

    def _cut_overlays(self) -> None:
        """Before a frame of the scene: the overlay lines with the splats (see :meth:`_add_cut_overlays`)."""
        import vtk
        from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

        on = bool(getattr(self, "show_splats", False) and self.show_frusta)
        for actor in self._cut_actors.values():
            actor.SetVisibility(on)
        if not on:
            self._cut_key = None
            return
        ren = self.scene_renderer
        m = ren.GetActiveCamera().GetCompositeProjectionTransformMatrix(ren.GetTiledAspectRatio(), -1.0, 1.0)
        M = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
        head = np.asarray(self.mesh.points)[::8].astype(np.float64)  # (every 8th vertex: the box within a pixel)
        h = head @ M[:, :3].T + M[:, 3]
        h = h[h[:, 3] > 1e-6]
        box = (2.0, 2.0, 2.0, 2.0)  # off the screen: nothing cut
        if len(h):
            q = h[:, :2] / h[:, 3:4]
            (x0, y0), (x1, y1) = q.min(axis=0), q.max(axis=0)
            pad = 0.03 * max(x1 - x0, y1 - y0)
            # grown to whole pixels of the scene: a face-slider drag step that leaves the head's pixel box
            # as it was (most of them) keeps the cut lines (~2 ms a step) instead of cutting them again
            w, hh = (max(1, n) / 2.0 for n in ren.GetSize())
            box = (math.floor((x0 - pad) * w) / w, math.floor((y0 - pad) * hh) / hh,
                   math.ceil((x1 + pad) * w) / w, math.ceil((y1 + pad) * hh) / hh)
        mtimes = (self.frusta.GetMTime(), self.selected.GetMTime(), self.focal_actor.mapper.dataset.GetMTime())
        key = (M.tobytes(), box, mtimes)  # the mesh enters through its box only
        if key == self._cut_key:
            return
        self._cut_key, self.head_screen_box = key, box
        if getattr(self, "_cut_src_key", None) != mtimes:  # the whole lines' segments, once per change
            srcs = self._cut_sources()
            self._cut_src = (np.concatenate([p[g[:, 0]] for p, g, _ in srcs.values()]),
                             np.concatenate([p[g[:, 1]] for p, g, _ in srcs.values()]),
                             np.concatenate([c for _, _, c in srcs.values()]),
                             np.repeat(np.arange(len(srcs)), [len(g) for _, g, _ in srcs.values()]))
            self._cut_src_key = mtimes
        a_all, b_all, cols, owner = self._cut_src
        a, b, src = cut_segments_at_box(a_all, b_all, M, box)  # every overlay line at once
        for k, (name, _) in enumerate(self._CUT_LINES):
            mine = owner[src] == k
            n = int(mine.sum())
            actor = self._cut_actors[name]
            if not n:
                actor.SetVisibility(False)
                continue
            poly = actor.GetMapper().GetInput()
            points = vtk.vtkPoints()
            points.SetData(numpy_to_vtk(np.stack([a[mine], b[mine]], axis=1).reshape(-1, 3), deep=True))
            lines = vtk.vtkCellArray()
            lines.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 2 * n + 1, 2), deep=True),
                          numpy_to_vtkIdTypeArray(np.arange(2 * n), deep=True))
            rgb = numpy_to_vtk(np.ascontiguousarray(cols[src[mine]]), deep=True)
            rgb.SetName("rgb")
            poly.SetPoints(points)
            poly.SetLines(lines)
            poly.GetCellData().SetScalars(rgb)
            poly.Modified()

    def _show_camera_actors(self) -> None:
        """The rig's overlays follow ``o``; with the splats, the cut lines stand in for the whole ones."""
        splats = bool(getattr(self, "show_splats", False))
        for a in self._camera_actors:
            a.SetVisibility(self.show_frusta)
        for a in (self.frusta_actor, self.selected_actor, self.focal_actor):
            a.SetVisibility(self.show_frusta and not splats)
        self._cut_key = None

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
        self._show_camera_actors()
        self._place_camera_labels()
        self._render()

    def toggle_help(self) -> None:
        self.show_help = not self.show_help
        self.help_actor.SetVisibility(self.show_help)
        self.hint.SetVisibility(not self.show_help)
        self._render()

