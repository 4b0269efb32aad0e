"""Splats in the 3D scene: the Gaussians rendered by the pipeline's splat renderer from the interactive
camera, drawn as the scene's background under the overlays (mesh, ellipsoids, frusta, labels).

While the camera is being dragged the image is rendered at ``splat_drag_scale`` of the scene's pixels
(and stretched); when the camera stands still, at full resolution, pixel for pixel. ``v`` looks through
the selected quilt camera: the splat image is then that camera's own view (its sheared projection, its
pixels), centred in the scene, so the scene shows exactly the quilt's tile.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..camera import Cameras, intrinsics, look_at

__all__ = ["scene_camera", "look_through_camera", "SplatViewMixin"]


def scene_camera(position: Any, focal_point: Any, view_up: Any, view_angle: float, width: int, height: int,
                 near: float = 0.01, far: float = 100.0) -> Cameras:
    """The :class:`~holo_viewer.camera.Cameras` (one camera, ``width`` x ``height`` pixels) that sees what
    a VTK perspective camera sees: eye ``position`` looking at ``focal_point``, ``view_up`` up, vertical
    field of view ``view_angle`` degrees, principal point at the image centre."""
    fy = (height / 2.0) / math.tan(math.radians(view_angle) / 2.0)
    w2c = look_at(position, focal_point, view_up)
    return Cameras(w2c[None], intrinsics(fy, fy, width / 2.0, height / 2.0)[None], int(width), int(height),
                   near=near, far=far)


def look_through_camera(cameras: Cameras, index: int, width: int, height: int) -> Cameras:
    """Quilt camera ``index`` with its image grown to ``width`` x ``height`` around the same pixels: its
    tile sits centred (offset ((width - w) // 2, (height - h) // 2)); same pose, focal lengths and shear."""
    K = cameras.K[index].copy()
    K[0, 2] += (width - cameras.width) // 2
    K[1, 2] += (height - cameras.height) // 2
    return Cameras(cameras.world_to_cam[index][None], K[None], int(width), int(height), near=cameras.near,
                   far=cameras.far)


def _upscale(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Nearest-neighbour resize of an (h, w, 3) image to (height, width, 3)."""
    h, w = img.shape[:2]
    rows = np.minimum((np.arange(height) * h) // height, h - 1)
    cols = np.minimum((np.arange(width) * w) // width, w - 1)
    return img[rows][:, cols]


class SplatViewMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer`: the splat image behind the 3D scene."""

    def _init_splats(self) -> None:
        import vtk

        self.show_splats = bool(self.config.splat_view) and self.pipeline.avatar is not None
        self.look_through: int | None = None
        self._splat_key: tuple | None = None  # what the shown image was rendered for
        self._splat_full = False  # the shown image is at full resolution
        self.splat_image: np.ndarray | None = None  # (H, W, 3) uint8 as drawn in the scene
        self._splat_texture = vtk.vtkTexture()
        self._splat_texture.InterpolateOff()

    def _scene_pixels(self) -> tuple[int, int]:
        w, h = self.scene_renderer.GetSize()  # the viewport's pixels as VTK rounds them
        return max(1, int(w)), max(1, int(h))

    def splat_cameras(self, scale: float = 1.0) -> Cameras:
        """The camera the splat image is rendered from: the scene's camera (or, looking through a quilt
        camera, that camera), at ``scale`` x the scene's pixels."""
        W, H = self._scene_pixels()
        if self.look_through is not None:
            return look_through_camera(self.pipeline.cameras(), self.look_through, W, H)
        cam = self.scene_renderer.GetActiveCamera()  # clip range: the quilt cameras' (VTK's moves per frame)
        quilt = self.pipeline.cameras()
        return scene_camera(cam.GetPosition(), cam.GetFocalPoint(), cam.GetViewUp(), cam.GetViewAngle(),
                            max(4, int(round(W * scale))), max(4, int(round(H * scale))), near=quilt.near,
                            far=quilt.far)

    def _splat_state(self) -> tuple:
        cam = self.scene_renderer.GetActiveCamera()
        return (self._scene_pixels(), cam.GetPosition(), cam.GetFocalPoint(), cam.GetViewUp(), cam.GetViewAngle(),
                self.look_through, self.pipeline.stage_version("gaussians"), self.pipeline.stage_version("cameras"))

    def _camera_moving(self) -> bool:
        style = getattr(self, "_style", None)
        return style is not None and style.GetState() != 0  # VTKIS_NONE: no button held

    def update_splats(self, force_full: bool = False) -> bool:
        """Render the splat image if the camera or the Gaussians changed (reduced while the camera is dragged,
        full resolution once it stands still). True if a new image was drawn."""
        if not self.show_splats:
            return False
        key = self._splat_state()
        moving = self._camera_moving() and not force_full and self.look_through is None
        if key == self._splat_key and (self._splat_full or moving):
            return False
        import time

        t0 = time.perf_counter()
        scale = float(self.config.splat_drag_scale) if moving else 1.0
        cams = self.splat_cameras(scale)
        g = self.pipeline.gaussians()
        from ..pipeline import render_images

        img = render_images(g, cams, backend=self.pipeline.backend, config=self.pipeline.render_config)[0]
        W, H = self._scene_pixels()
        from ..display.quilt import to_uint8

        img = to_uint8(img)
        if img.shape[:2] != (H, W):
            img = _upscale(img, W, H)
        self._show_splat_image(img)
        self._splat_key, self._splat_full = key, not moving
        ms = (time.perf_counter() - t0) * 1e3
        if moving:
            self.timings.splat_drag_ms = ms
        else:
            self.timings.splat_ms = ms
        self._dirty = True
        return True

    def _show_splat_image(self, img: np.ndarray) -> None:
        from vtk.util.numpy_support import numpy_to_vtk
        import vtk

        self.splat_image = img
        H, W = img.shape[:2]
        data = vtk.vtkImageData()
        data.SetDimensions(W, H, 1)
        arr = numpy_to_vtk(np.ascontiguousarray(img[::-1]).reshape(-1, 3), deep=True)  # VTK rows: bottom up
        arr.SetName("rgb")
        data.GetPointData().SetScalars(arr)
        self._splat_texture.SetInputData(data)
        self._splat_texture.Modified()
        ren = self.scene_renderer
        ren.SetBackgroundTexture(self._splat_texture)
        ren.TexturedBackgroundOn()

    def _hide_splats(self) -> None:
        self.scene_renderer.TexturedBackgroundOff()
        self._splat_key = None

    def toggle_splats(self) -> None:
        """Splat image behind the scene on / off (key ``s``); with it on, the mesh is drawn on request only."""
        if self.pipeline.avatar is None:
            self._set_status("no Gaussian avatar to render (--avatar none)")
            self._render()
            return
        self.show_splats = not self.show_splats
        if self.show_splats:
            self.update_splats(force_full=True)
        else:
            self._hide_splats()
        self._render()

    def toggle_look_through(self) -> None:
        """Look through the selected quilt camera (key ``v``): the scene shows that view's own image, the
        scene camera moves to its pose; again: back to the free camera."""
        if self.look_through is None:
            self.look_through = int(self.selected_view)
            self._place_scene_camera_at_view(self.look_through)
            if not self.show_splats and self.pipeline.avatar is not None:
                self.show_splats = True
        else:
            self.look_through = None
        self.update_splats(force_full=True)
        self._render()

    def _place_scene_camera_at_view(self, index: int) -> None:
        cams = self.pipeline.cameras()
        w2c = cams.world_to_cam[index]
        R, t = w2c[:3, :3], w2c[:3, 3]
        eye = -R.T @ t
        forward, down = R[2], R[1]
        centre, _ = self.pipeline.get("framing")
        dist = float(np.dot(np.asarray(centre) - eye, forward))
        cam = self.scene_renderer.GetActiveCamera()
        cam.SetPosition(*eye)
        cam.SetFocalPoint(*(eye + forward * max(dist, 1e-3)))
        cam.SetViewUp(*(-down))
        fy = cams.K[index][1, 1]
        H = self._scene_pixels()[1]
        cam.SetViewAngle(math.degrees(2.0 * math.atan((H / 2.0) / fy)))
        self.scene_renderer.ResetCameraClippingRange()
