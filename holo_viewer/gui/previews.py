"""The viewer's image panels: the upper one shows (key ``p``) the selected view (fast renderer), the native
(lenticular) image, or what an eye placed at the panel sees (``display/simulate.py``); the lower one the
quilt thumbnail (worker process).

The native image and the eye's picture are made from the full-resolution native image (the quilt at the
pipeline's tile size, interleaved), rendered in a second worker process when one of them is shown and the
sliders have settled (on release), and cached per Gaussians, cameras and blend mode. Until it arrives they
show the native image interleaved from the quilt thumbnail (the panel title says so)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .widgets import scale_cameras

#: what the upper image panel shows, in the order ``p`` cycles through
PANEL_MODES = ("view", "native", "eye")
#: native-image zoom steps (``]`` in, ``[`` out): the centre 1/z of the image
NATIVE_ZOOMS = (1, 2, 4, 8, 16)


class PreviewsMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer` (uses its attributes; not used alone)."""

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
        mode = getattr(self, "panel_mode", "view")
        soft = " (from the thumbnail)" if getattr(self, "native_source", "full") == "thumbnail" else ""
        if mode == "native":
            cal = self.pipeline.calibration
            self.preview_panel.set_title(f"native {cal.screen_w}x{cal.screen_h}, zoom {self.native_zoom}x{soft}")
        elif mode == "eye":
            self.preview_panel.set_title(f"eye at {self.eye_angle:+.1f} deg, {self.eye_distance:.2f} m{soft}")
        else:
            n = len(self.pipeline.cameras())
            self.preview_panel.set_title(f"view {self.selected_view}/{n - 1} "
                                         f"({self._view_angle(self.selected_view):+.1f} deg)")

    def _update_preview(self) -> None:
        if self.pipeline.avatar is None:
            return
        mode = getattr(self, "panel_mode", "view")
        if mode == "view":
            img = self.pipeline.render_view(self.selected_view, cameras=self._preview_cameras())
        else:
            native = self.native_preview()
            if native is None:
                return  # shown when the thumbnail quilt arrives
            img = self.eye_preview(native) if mode == "eye" else zoom_centre(native, self.native_zoom)
        self.preview_panel.update(img)
        self._update_preview_title()

    def _native_full_key(self) -> tuple:
        pipe = self.pipeline
        return (pipe.stage_version("gaussians"), pipe.stage_version("cameras"), bool(pipe.view.blend),
                getattr(self, "_avatar_epoch", 0))

    def native_preview(self) -> np.ndarray | None:
        """(screen_h, screen_w, 3) uint8 native image: the full-resolution one when it is up to date (see
        :meth:`_request_native`), else the one interleaved from the current quilt thumbnail (None until one
        is shown; cached per thumbnail)."""
        full = getattr(self, "_native_full", None)
        if full is not None and full[0] == self._native_full_key():
            self.native_source = "full"
            return full[1]
        self._request_native()
        self.native_source = "thumbnail"
        quilt = self.thumb_panel.image
        if quilt is None:
            return None
        key = (self._thumb_key, quilt.shape, bool(self.pipeline.view.blend))
        if getattr(self, "_native_key", None) != key:
            from ..display.lenticular import Interleaver

            cal = self.pipeline.calibration
            inter = Interleaver(cal, quilt.shape, cols=cal.cols, rows=cal.rows,
                                mode="blend" if self.pipeline.view.blend else "nearest")
            self._native, self._native_key = inter(quilt), key
        return self._native

    def _request_native(self) -> None:
        """Start the full-resolution native image in its worker process if it is not up to date (one job in
        flight; a newer request replaces a queued one). :meth:`poll_native` shows it."""
        if self.pipeline.avatar is None:
            return
        key = self._native_full_key()
        if key == getattr(self, "_native_pending", None):
            return
        pipe = self.pipeline
        if getattr(self, "_native_worker", None) is None:
            from .thumbnail_worker import ThumbnailWorker

            self._native_worker = ThumbnailWorker.acquire()
        self._native_worker.submit(key, ("native", pipe.gaussians().numpy(), pipe.cameras(), pipe.backend,
                                         pipe.render_config, pipe.calibration.cols, pipe.calibration.rows,
                                         pipe.calibration, bool(pipe.view.blend)))
        self._native_pending = key

    def poll_native(self, wait: bool = False) -> bool:
        """Take a finished full-resolution native image (``wait``: block for the running job) and show it
        if the panel shows the native image or the eye's view. True if one arrived."""
        worker = getattr(self, "_native_worker", None)
        if worker is None:
            return False
        done = worker.poll(wait=wait)
        if done is None:
            return False
        key, native = done
        if key == getattr(self, "_native_pending", None):
            self._native_pending = None
        self._native_full = (key, native)
        if getattr(self, "panel_mode", "view") != "view" and key == self._native_full_key():
            self._update_preview()
            self._render(("preview",))
        return True

    def wait_for_native(self) -> None:
        """Block until the full-resolution native image of the current state is shown (tests, scripts)."""
        self._request_native()
        while getattr(self, "_native_pending", None) is not None and self.poll_native(wait=True):
            pass

    def eye_preview(self, native: np.ndarray) -> np.ndarray:
        """What an eye at (``eye_angle``, ``eye_distance``) sees of ``native`` (simulated, 1/4 resolution)."""
        from ..display.simulate import VirtualDisplay

        cal = self.pipeline.calibration
        if getattr(self, "_eye_display", None) is None:
            self._eye_display = VirtualDisplay(cal, n_views=len(self.pipeline.cameras()), downsample=4)
        return self._eye_display.see(native, self.eye_angle, self.eye_distance)

    def cycle_panel(self) -> None:
        """The upper image panel shows the next of :data:`PANEL_MODES` (key ``p``)."""
        if self.pipeline.avatar is None:
            self._set_status("no Gaussian avatar to render (--avatar none)")
            self._render()
            return
        self.panel_mode = PANEL_MODES[(PANEL_MODES.index(self.panel_mode) + 1) % len(PANEL_MODES)]
        self._update_preview_title()
        self._update_preview()
        self._render()

    def zoom_native(self, step: int) -> None:
        """Zoom the native image in (``step`` > 0, key ``]``) or out (``[``) about its centre."""
        i = NATIVE_ZOOMS.index(self.native_zoom)
        self.native_zoom = NATIVE_ZOOMS[int(np.clip(i + step, 0, len(NATIVE_ZOOMS) - 1))]
        if self.panel_mode != "native":
            self.panel_mode = "native"
        self._update_preview()
        self._render()

    def set_eye(self, *, angle: float | None = None, distance: float | None = None) -> None:
        """Place the simulated eye: ``angle`` degrees from the panel normal, ``distance`` metres."""
        from ..errors import InputError

        if angle is not None:
            self.eye_angle = float(angle)
        if distance is not None:
            if not distance > 0:
                raise InputError(f"eye distance: expected > 0 m, found {distance}")
            self.eye_distance = float(distance)
        if self.panel_mode != "eye":
            self.panel_mode = "eye"
        self._update_preview()
        self._render()

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

                self._worker = ThumbnailWorker.acquire()
            self._worker.submit(key, args)
            self._thumb_pending_key = key
            self._thumb_started = time.perf_counter()
        if wait:
            while self.poll_thumbnail(wait=True) and self._worker is not None and self._worker.busy:
                pass

    def wait_for_thumbnail(self) -> None:
        """Block until the quilt thumbnail of the current Gaussians is shown (tests, scripts; the window
        itself never waits: the loop shows it when the worker is done)."""
        self._thumb_wanted = False
        self._update_thumbnail(wait=True)

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
        if getattr(self, "panel_mode", "view") != "view":
            self._update_preview()  # the native image and the eye's picture come from the thumbnail
        self._render_now()
        if key == self._thumb_pending_key:
            self._thumb_pending_key = None
            self.timings.thumbnail_ms = (time.perf_counter() - self._thumb_started) * 1e3
        self._update_status()
        self._render()
        return True


def zoom_centre(img: np.ndarray, zoom: int) -> np.ndarray:
    """The centre 1/``zoom`` of ``img`` (rows and columns), pixels unchanged."""
    if zoom <= 1:
        return img
    h, w = img.shape[:2]
    ch, cw = max(1, h // zoom), max(1, w // zoom)
    y0, x0 = (h - ch) // 2, (w - cw) // 2
    return img[y0:y0 + ch, x0:x0 + cw]
