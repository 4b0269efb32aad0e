"""The viewer's exports (``k``, ``n``, ``x``, ``i``), run in a worker thread on a pipeline of their own."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import HoloViewerError, InputError
from ..pipeline import FaceControls, Pipeline
from .background import Job
from .widgets import scale_cameras


class ExportsMixin:
    """Part of :class:`~holo_viewer.gui.viewer.HoloViewer` (uses its attributes; not used alone)."""

    def _out(self, name: str) -> Path:
        out = Path(self.config.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        return out / name

    def _stamp(self) -> str:
        return time.strftime("%Y%m%d-%H%M%S") + f"-{len(self.exports) + len(self._jobs.pending):03d}"

    def _record(self, path: Path) -> Path:
        self.exports.append(path)
        self._set_status(f"wrote {path}")
        self._render()
        return path

    def _export_pipeline(self) -> Pipeline:
        """A pipeline of its own for a worker thread (same model, avatar and settings; own caches)."""
        pipe = self.pipeline
        if pipe.avatar is None:
            raise InputError("export: no Gaussian avatar (--avatar none shows the mesh only); nothing to render")
        try:
            au_map = pipe.au_map
        except HoloViewerError:
            au_map = None
        return Pipeline(model=pipe.model, avatar=pipe.avatar, calibration=pipe.calibration, face=pipe.face,
                        view=pipe.view, backend=pipe.backend, render_config=pipe.render_config, au_map=au_map)

    def _submit(self, label: str, fn: Callable[[Job], Path]) -> Job:
        job = self._jobs.submit(label, fn)
        self._update_status()
        self._render()
        return job

    def export_quilt(self) -> Job:
        """Write the full-resolution quilt PNG (``*_qs8x6a0.75.png``) in the background."""
        from ..display.quilt import quilt_filename
        from ..fileio import save_image

        pipe = self._export_pipeline()
        cal = pipe.calibration
        path = self._out(quilt_filename(f"view-{self._stamp()}", cal.cols, cal.rows, cal.aspect))

        def work(job: Job) -> Path:
            save_image(path, _export_image(pipe, job, native=False))
            return path
        return self._submit("exporting quilt", work)

    def export_native(self) -> Job:
        """Write the native (lenticular) PNG for the pipeline's calibration in the background."""
        from ..fileio import save_image

        pipe = self._export_pipeline()
        path = self._out(f"view-{self._stamp()}_native.png")

        def work(job: Job) -> Path:
            save_image(path, _export_image(pipe, job, native=True))
            return path
        return self._submit("exporting native image", work)

    def export_sweep_video(self, what: str = "expression") -> Job:
        """Write two mp4s in the background, the quilt video (tiles at ``sweep_scale``) and the panel's
        native video (the same quilts interleaved for the calibration), of a sweep 0 -> 1 -> 0: of smile
        (``what="expression"``, key ``x``; a model without an action-unit map sweeps its first expression
        component) or of pain (``what="pain"``, key ``X``), the rest of the face as it is."""
        from ..display.export import write_quilt_video
        from ..display.lenticular import Interleaver
        from ..display.quilt import quilt_filename
        from .thumbnail_worker import render_thumbnail

        cfg = self.config
        pipe = self._export_pipeline()
        cal = pipe.calibration
        stem = f"sweep-{what}-{self._stamp()}"
        path = self._out(quilt_filename(stem, cal.cols, cal.rows, cal.aspect, suffix=".mp4"))
        native_path = self._out(f"{stem}_native.mp4")
        base = pipe.face
        weights = np.sin(np.linspace(0.0, np.pi, max(2, cfg.sweep_frames)))
        try:
            pipe.au_map  # noqa: B018 - named expressions and pain need the model's action-unit map
            has_aus = True
        except HoloViewerError:
            has_aus = False
        if what == "pain":
            if not has_aus:
                raise InputError("pain sweep: this FLAME model has no action-unit map (pain is made of AUs)")

            def sweep(w: float) -> FaceControls:
                return base.replace(pain=w)
        elif what == "expression":
            def sweep(w: float) -> FaceControls:
                return base.with_named("smile", w) if has_aus else base.with_expr_component(0, cfg.expr_range * w)
        else:
            raise InputError(f"sweep: expected 'expression' or 'pain', found {what!r}")

        def work(job: Job) -> list[Path]:
            cams = scale_cameras(pipe.cameras(), cfg.sweep_scale)
            quilts = []
            job.progress(0, len(weights), "frames")
            for k, w in enumerate(weights):
                pipe.set_face(sweep(float(w)))
                quilts.append(render_thumbnail(pipe.gaussians(), cams, pipe.backend, pipe.render_config, cal.cols,
                                               cal.rows))
                job.progress(k + 1, len(weights), "frames")
            write_quilt_video(path, quilts, fps=cfg.sweep_fps, total=len(quilts), preset="veryfast", progress=False)
            inter = Interleaver(cal, quilts[0].shape, cols=cal.cols, rows=cal.rows,
                                mode="blend" if pipe.view.blend else "nearest")
            write_quilt_video(native_path, (inter(q) for q in quilts), fps=cfg.sweep_fps, total=len(quilts),
                              preset="veryfast", progress=False)
            return [path, native_path]
        return self._submit(f"exporting {what} sweep video", work)

    def _collect_jobs(self) -> None:
        for job in self._jobs.finished():
            if job.error is not None:
                msg = str(job.error) if isinstance(job.error, HoloViewerError) else \
                    f"{type(job.error).__name__}: {job.error}"
                self._show_error(f"{job.label} failed: {msg}")
            else:
                for path in job.result if isinstance(job.result, list) else [job.result]:
                    self._record(path)
        if self._jobs.pending:
            line = self._jobs.status_line()
            if line != self._last_job_line:
                self._last_job_line = line
                self._update_status()
                self._dirty = True

    def wait_exports(self, timeout: float | None = None) -> list[Path]:
        """Block until the running and queued exports are written; returns every export so far."""
        self._jobs.wait(timeout)
        self._collect_jobs()
        return list(self.exports)

    def screenshot(self) -> np.ndarray:
        """(H, W, 3) uint8 image of the whole window."""
        img = self.plotter.screenshot(None, return_img=True)
        return np.asarray(img)[..., :3]

    def save_screenshot(self, path: str | Path | None = None) -> Path:
        from ..fileio import save_image

        target = Path(path) if path is not None else self._out(f"screenshot-{self._stamp()}.png")
        save_image(target, self.screenshot())
        return self._record(target)



def _export_image(pipe: Pipeline, job: Job, native: bool, chunk: int = 8) -> np.ndarray:
    """The full quilt (``native``: the native image) of ``pipe``: the views rendered ``chunk`` at a time,
    then :func:`~holo_viewer.display.native.views_to_native`, reporting progress to ``job``."""
    from ..display.native import views_to_native
    from ..display.lenticular import Interleaver
    from ..pipeline import quilt_layout, render_images

    g = pipe.gaussians()
    cams = pipe.cameras()
    V = len(cams)
    parts = []
    job.progress(0, V, "views")
    for s in range(0, V, chunk):
        idx = list(range(s, min(s + chunk, V)))
        parts.append(render_images(g, cams[idx], backend=pipe.backend, config=pipe.render_config))
        job.progress(idx[-1] + 1, V, "views")
    cols, rows = quilt_layout(pipe.calibration)
    target: Any = (cols, rows)
    if native:
        target = Interleaver(pipe.calibration, (rows * cams.height, cols * cams.width, 3), cols=cols, rows=rows,
                             mode="blend" if pipe.view.blend else "nearest")
    done = views_to_native(np.concatenate(parts, axis=0), target, progress=job.progress)
    return done.native if native else done.quilt

