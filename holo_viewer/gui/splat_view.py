"""Splats in the 3D scene: the Gaussians rendered by the pipeline's splat renderer from the interactive
camera, drawn as the scene's background under the overlays (mesh, ellipsoids, frusta, labels).

While the camera is being dragged the image is rendered at ``splat_drag_scale`` of the scene's pixels, in
a worker thread (the compiled renderer releases the GIL, so the window keeps drawing the overlays), the
newest camera replacing a request not yet started (stale poses are never rendered); the reduced image is
stretched over the scene by the texture (nearest), not resized on the CPU. When the camera stands still
the image is rendered at full resolution, pixel for pixel, on the UI thread. ``v`` looks through
the selected quilt camera: the splat image is then that camera's own view (its sheared projection, its
pixels), centred in the scene, so the scene shows exactly the quilt's tile.
"""

from __future__ import annotations

import math
import os
import threading
import time
from typing import Any, Callable

import numpy as np

from ..camera import Cameras, intrinsics, look_at

__all__ = ["scene_camera", "look_through_camera", "window_centre", "SplatViewMixin", "SplatWorker"]

#: the longest a camera-drag frame waits for the splat image being rendered (seconds), unless the last drag
#: render took longer: then up to 1.5 x that, at most ``SPLAT_HOLD_MAX_S`` (a frame drawn while the render
#: runs shows the old image under moved overlays and, on 2 cores, delays the new image by its own cost)
SPLAT_HOLD_S = 0.15
SPLAT_HOLD_MAX_S = 0.5


def scene_camera(position: Any, focal_point: Any, view_up: Any, view_angle: float, width: int, height: int,
                 near: float = 0.01, far: float = 100.0) -> Cameras:
    """The :class:`~holo_viewer.camera.Cameras` (one camera, ``width`` x ``height`` pixels) that sees what
    a VTK perspective camera sees: eye ``position`` looking at ``focal_point``, ``view_up`` up, vertical
    field of view ``view_angle`` degrees, principal point at the image centre."""
    fy = (height / 2.0) / math.tan(math.radians(view_angle) / 2.0)
    w2c = look_at(position, focal_point, view_up)
    return Cameras(w2c[None], intrinsics(fy, fy, width / 2.0, height / 2.0)[None], int(width), int(height),
                   near=near, far=far)


def window_centre(K: np.ndarray, width: int, height: int) -> tuple[float, float]:
    """VTK's ``vtkCamera.SetWindowCenter`` arguments that put the optical axis at principal point
    (``K[0, 2]``, ``K[1, 2]``) (pixels, x right, y down, edges at 0) of a ``width`` x ``height`` viewport:
    VTK's frustum spans ((wc - 1), (wc + 1)) x the half-size, so the axis sits at NDC -wc."""
    return 1.0 - 2.0 * float(K[0, 2]) / width, 2.0 * float(K[1, 2]) / height - 1.0


def look_through_camera(cameras: Cameras, index: int, width: int, height: int) -> Cameras:
    """Quilt camera ``index`` with its image grown to ``width`` x ``height`` around the same pixels: its
    tile sits centred (offset ((width - w) // 2, (height - h) // 2)); same pose, focal lengths and shear."""
    K = cameras.K[index].copy()
    K[0, 2] += (width - cameras.width) // 2
    K[1, 2] += (height - cameras.height) // 2
    return Cameras(cameras.world_to_cam[index][None], K[None], int(width), int(height), near=cameras.near,
                   far=cameras.far)


class SplatWorker:
    """One thread rendering splat images; at most one job queued, a newer one replaces it (stale poses
    are dropped before they start). :meth:`take` returns the newest finished (key, image, ms)."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        # written when a result is ready: the event loop's idle wait selects on it (wake_fd)
        self.wake_fd, self._wake_w = os.pipe()
        os.set_blocking(self.wake_fd, False)
        os.set_blocking(self._wake_w, False)
        self._job: tuple[Any, Callable[[], np.ndarray]] | None = None
        self._result: tuple[Any, Any, float] | None = None
        self._busy = False
        self._closed = False
        self._thread: threading.Thread | None = None
        self.dropped = 0  # queued jobs replaced before they started

    def submit(self, key: Any, fn: Callable[[], np.ndarray]) -> None:
        with self._cv:
            if self._job is not None:
                self.dropped += 1
            self._job = (key, fn)
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="splat-render", daemon=True)
                self._thread.start()
            self._cv.notify_all()

    def _loop(self) -> None:
        while True:
            with self._cv:
                while self._job is None and not self._closed:
                    self._cv.wait()
                if self._closed:
                    return
                (key, fn), self._job = self._job, None
                self._busy = True
            t0 = time.perf_counter()
            try:
                out: Any = fn()
            except Exception as exc:  # noqa: BLE001 - handed to the UI thread, which shows it
                out = exc
            with self._cv:
                self._result = (key, out, (time.perf_counter() - t0) * 1e3)
                self._busy = False
                self._cv.notify_all()
            try:
                os.write(self._wake_w, b"1")
            except (BlockingIOError, OSError):  # the pipe is full (nobody waits) or closed
                pass

    def take(self) -> tuple[Any, Any, float] | None:
        with self._cv:
            r, self._result = self._result, None
            return r

    @property
    def idle(self) -> bool:
        with self._cv:
            return self._job is None and not self._busy

    def cancel(self, wait: bool = True) -> None:
        """Drop the queued job and (``wait``) wait for a running one; its result is discarded."""
        with self._cv:
            self._job = None
            while wait and self._busy:
                self._cv.wait()
            self._result = None

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._job = None
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        for fd in (self.wake_fd, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self.wake_fd = self._wake_w = -1


class SplatViewMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer`: the splat image behind the 3D scene."""

    def _init_splats(self) -> None:
        import vtk

        self.show_splats = bool(self.config.splat_view) and self.pipeline.avatar is not None
        self.look_through: int | None = None
        self._splat_key: tuple | None = None  # what the shown image was rendered for
        self._splat_full = False  # the shown image is at full resolution
        self.splat_image: np.ndarray | None = None  # (h, w, 3) uint8 stretched over the scene (full: pixel for pixel)
        self._splat_worker = SplatWorker()
        self._splat_requested: tuple | None = None  # the pose of the drag render in flight
        self._splat_requested_at = 0.0
        self._splat_fresh = False  # a drag image arrived that no frame has drawn yet
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

    def _splat_render_fn(self, scale: float) -> Callable[[], np.ndarray]:
        """A function rendering the splat image of the current camera at ``scale`` (uint8), safe to run in
        the worker thread (it holds the cameras and the Gaussians of now)."""
        from ..display.quilt import to_uint8
        from ..pipeline import render_images

        cams = self.splat_cameras(scale)
        g = self.pipeline.gaussians()
        backend, config = self.pipeline.backend, self.pipeline.render_config
        return lambda: to_uint8(render_images(g, cams, backend=backend, config=config)[0])

    def update_splats(self, force_full: bool = False) -> bool:
        """Bring the splat image up to date with the camera and the Gaussians: while the camera is dragged,
        ask the worker thread for a reduced image (shown by :meth:`poll_splats`); when it stands still,
        render the full-resolution image now. True if a new image was put in the scene."""
        if not self.show_splats:
            return False
        key = self._splat_state()
        moving = self._camera_moving() and not force_full and self.look_through is None
        if moving:
            if key != self._splat_key and key != self._splat_requested:
                self._splat_worker.submit(key, self._splat_render_fn(float(self.config.splat_drag_scale)))
                self._splat_requested = key
                self._splat_requested_at = time.perf_counter()
            return False
        if key == self._splat_key and self._splat_full:
            return False
        self._splat_worker.cancel()  # a drag image would now be stale
        self._splat_requested = None
        t0 = time.perf_counter()
        img = self._splat_render_fn(1.0)()
        self._show_splat_image(img)
        self._splat_key, self._splat_full = key, True
        self.timings.splat_ms = (time.perf_counter() - t0) * 1e3
        self._dirty_parts.add("scene")
        return True

    def poll_splats(self) -> bool:
        """Show the worker's newest reduced image if the camera is still being dragged (a finished drag
        gets its full-resolution image instead). True if one was put in the scene."""
        done = self._splat_worker.take()
        if done is None:
            return False
        key, img, ms = done
        if key == self._splat_requested:
            self._splat_requested = None
        if isinstance(img, Exception):
            raise img
        if not (self.show_splats and self._camera_moving() and self.look_through is None):
            return False
        self._show_splat_image(img)
        self._splat_key, self._splat_full = key, False
        self.timings.splat_drag_ms = ms
        self._dirty_parts.add("scene")
        self._splat_fresh = True  # drawn by the next frame even while the next pose renders
        return True

    def _holding_for_splat(self) -> bool:
        """During a camera drag, a scene-only frame waits for the splat image being rendered (``SPLAT_HOLD_S``,
        up to 1.5 x the last drag render when that was slower, at most ``SPLAT_HOLD_MAX_S``): drawn now it
        would show the old image under moved overlays, and on 2 cores it would delay the render by its cost."""
        last = self.timings.splat_drag_ms
        hold = SPLAT_HOLD_S if last is None else min(max(SPLAT_HOLD_S, 1.5e-3 * last), SPLAT_HOLD_MAX_S)
        return (self._dirty_parts == {"scene"} and not self._splat_fresh and self._splat_requested is not None
                and self._camera_moving() and time.perf_counter() - self._splat_requested_at < hold)

    def splat_on_screen(self) -> bool:
        """Whether the last frame drawn shows the splat image of the scene camera as it is now (benchmarks)."""
        return self._splat_key is not None and self._splat_drawn_key == self._splat_key == self._splat_state()

    def _close_splats(self) -> None:
        self._splat_worker.close()

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
        self._splat_worker.cancel()
        self._splat_requested = None
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
            if getattr(self, "_geometry_for_no_splats", False):  # hidden again, as before s
                self._geometry_for_no_splats = False
                self._set_geometry_visible(False)
            self.update_splats(force_full=True)
        else:
            self._hide_splats()
            if not self.show_mesh and not self.show_gaussians:  # the scene of before: mesh and ellipsoids
                self._geometry_for_no_splats = True
                self._set_geometry_visible(True)
        self._show_camera_actors()  # whole overlay lines without the splats, cut at the head with them
        self._render()

    def _set_geometry_visible(self, on: bool) -> None:
        """The mesh and (with an avatar) the ellipsoids on or off, as ``m`` and ``g`` set them."""
        self.show_mesh = on
        self.mesh_actor.SetVisibility(on)
        if self.glyph_actor is not None:
            self.show_gaussians = on
            self.glyph_actor.SetVisibility(on)

    def toggle_look_through(self) -> None:
        """Look through the selected quilt camera (key ``v``): the scene shows that view's own image, the
        scene camera moves to its pose; again: back to the free camera."""
        if self.look_through is None:
            self.look_through = int(self.selected_view)
            self._place_scene_camera_at_view(self.look_through)
            if not self.show_splats and self.pipeline.avatar is not None:
                self.show_splats = True
                self._show_camera_actors()
        else:
            self.look_through = None
            self.scene_renderer.GetActiveCamera().SetWindowCenter(0.0, 0.0)
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
        W, H = self._scene_pixels()
        K = look_through_camera(cams, index, W, H).K[0]
        cam.SetViewAngle(math.degrees(2.0 * math.atan((H / 2.0) / K[1, 1])))
        # the quilt camera is sheared (off-axis): its principal point is not the image centre. VTK's
        # window centre shifts the frustum so that the optical axis lands at pixel (cx, cy) too, and the
        # overlays (frusta, labels, mesh) fall on the splat image's pixels
        cam.SetWindowCenter(*window_centre(K, W, H))
        self.scene_renderer.ResetCameraClippingRange()
