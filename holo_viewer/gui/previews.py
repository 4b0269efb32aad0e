"""The viewer's image panels: the selected view (fast renderer) and the quilt thumbnail (worker process)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from .widgets import scale_cameras


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

