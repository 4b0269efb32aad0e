"""The one place the live loop touches the render pipeline (an adapter, so a new pipeline API is a
one-function change): face + viewer pose in, native image (and a preview view) out.

Modes (the rows of :data:`holo_viewer.pipeline.live_modes.SESSION_MODES`):

``cone``
    Algorithm 1's cameras follow the tracked viewer (``ViewSettings.viewer_angle/viewer_distance``):
    the whole 48-view quilt is re-rendered for the viewer's cone (``Pipeline.native``).
``tracked``
    The cone stays at the panel's default; only the native subpixels whose light reaches the
    tracked eyes are redrawn, from one crossed-slit image per eye (:mod:`holo_viewer.pipeline.live`,
    the "live frame rate" work; ~50 dB per eye against the full quilt).
``all_views``
    Every view of the default cone each frame (untracked): every 5th rendered, the others
    synthesized by a depth-compensated warp (``view_step``; 43 dB on the native image, 2.6x
    faster than rendering all 48).
``auto`` (the live command's default)
    ``group`` frames: every view each frame (every 6th rendered, ``NativeFrameConfig.group_view_step``,
    the others synthesized as in ``all_views``) and, over them, exact eye images (slices) for every
    tracked face, so no position of the cone sees an old face (issue 37).

Backends: ``fast`` (the CPU paths above) or ``gsplat`` (CUDA): all 48 views in one batched gsplat
call, tiled and interleaved on the GPU, 12-16 ms a frame on an H100/H200 (docs/live_frame.md), so
every mode but ``cone`` renders every view there, tracked or not (the whole room sees the hologram,
in less time than the CPU takes for two eyes). ``auto`` (the default) is ``gsplat`` where it runs
(a CUDA GPU and the gsplat package), else ``fast``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

__all__ = ["LiveAvatarRenderer", "RenderedFrame", "resolve_backend", "visible_record"]

BACKENDS = ("auto", "fast", "gsplat")


def resolve_backend(backend: str) -> str:
    """``auto`` -> ``gsplat`` where gsplat and CUDA work, else ``fast``; ``fast`` and ``gsplat`` as
    given (``gsplat`` without CUDA or gsplat: RenderError saying which is missing)."""
    from ..errors import InputError

    if backend not in BACKENDS:
        raise InputError(f"backend: expected one of {', '.join(BACKENDS)}, found {backend!r}")
    from ..render import gsplat_backend

    if backend == "gsplat":
        gsplat_backend._import()  # RenderError naming what is missing
        return backend
    if backend == "auto":
        return "gsplat" if gsplat_backend.is_available() else "fast"
    return backend


def visible_record(keep: np.ndarray | None, gaussians: int) -> dict:
    """``{"used", "gaussians", "kept", "digest"}`` of a visible-Gaussian mask (None: every Gaussian drawn,
    ``kept`` = ``gaussians``, digest None).

    An (N,) mask (sessions before 2026-11-28 19:30 drew one): ``kept`` its count, the digest the first 32
    hex digits of the sha256 of ``"N:"`` and its packed bits (as recorded then), and ``"per_view": False``.
    A (V, N) per-view mask (each source view draws its own row): ``kept`` the union's count,
    ``"per_view": True``, ``"shape": [V, N]``, ``"kept_per_view": [min, max]`` over the rows, and the digest
    of ``"VxN:"`` and the whole mask's packed bits (row-major), so that another per-view mask with the same
    union is told apart."""
    import hashlib

    if keep is None:
        return {"used": False, "gaussians": int(gaussians), "kept": int(gaussians), "digest": None}
    k = np.asarray(keep, dtype=bool)
    if k.ndim == 2:
        h = hashlib.sha256(f"{k.shape[0]}x{k.shape[1]}:".encode())
        h.update(np.packbits(np.ascontiguousarray(k)).tobytes())
        rows = k.sum(axis=1)
        return {"used": True, "gaussians": int(k.shape[1]), "kept": int(k.any(axis=0).sum()),
                "digest": h.hexdigest()[:32], "per_view": True, "shape": [int(k.shape[0]), int(k.shape[1])],
                "kept_per_view": [int(rows.min(initial=0)), int(rows.max(initial=0))]}
    h = hashlib.sha256(f"{k.size}:".encode())
    h.update(np.packbits(k).tobytes())
    return {"used": True, "gaussians": int(k.size), "kept": int(k.sum()), "digest": h.hexdigest()[:32],
            "per_view": False}


@dataclass
class RenderedFrame:
    """``native`` (H, W, 3) uint8 or None (the frame's own array while anything holds it: the loop hands it
    to the video writer's thread; once nobody does, a later frame may be rendered into it), ``preview``
    (h, w, 3) float32 or None, ``seconds``."""

    native: np.ndarray | None
    preview: np.ndarray | None
    seconds: float


class LiveAvatarRenderer:
    """Render the default avatar for the live loop through :class:`holo_viewer.pipeline.Pipeline`.

    Parameters
    ----------
    tile_scale : float
        Quilt tile size relative to the calibration's (1 = full 420x560 tiles; smaller is faster).
    native : bool
        Compute the native (lenticular) image (the panel and the recorded video need it).
    preview : bool
        Render the one view that faces the tracked viewer (the desktop preview).
    backend : {"auto", "fast", "gsplat"}
        The live frames' renderer (module docstring); ``auto``: gsplat where it runs, else fast,
        and fast with a RuntimeWarning when gsplat's first frame fails (its CUDA kernels are built
        on first use); an explicit ``gsplat`` raises RenderError then. The resolved name is
        ``self.backend``.
    mode : {"cone", "auto", "tracked", "all_views"}
        See the module docstring.
    calibration : DisplayCalibration, optional
    render_threads : int, optional
        Renderer threads (default: all cores). The tracker and reaction threads need a fifth of a
        core and sleep between frames; the scheduler runs them as soon as they wake, so they are
        not starved (no late reaction window in ``bench/live_latency.py``). Reserving them a core
        left it mostly idle: on 2 cores the render took 84 ms a frame instead of 55.
    view_step : int or None
        ``all_views``: render every view_step-th view and synthesize the others by depth
        (:class:`holo_viewer.pipeline.live.NativeFrameConfig`; None: the live default, 5; 1: every view).
    visible_only : bool
        CPU frames that redraw every view (``auto``/``group``, ``all_views``) skip the Gaussians nobody
        sees, each rendered source view those nobody sees in that view (``visible_per_view``)
        (:func:`holo_viewer.pipeline.live_support.visible_mask`: largest blending weight over the
        quilt views at a set of poses <= 1/255; the default avatar keeps ~65 % at full size, the cone
        error unchanged, docs/live_frame.md). Loaded from the cache; where it is not there yet this session
        draws every Gaussian and a process at nice 19 builds it for the next ones (~30 s of CPU at tile
        scale 0.5, :func:`~holo_viewer.pipeline.live_support.build_visible_mask_later`; default
        calibration only). ``holo-viewer live`` turns it on. ``"build"``: loaded, or built now in this
        process (replay --quality live of a session that used it). The mask used is
        :attr:`visible_keep`, recorded by :meth:`visible_record` (session.json ``render.visible``).
    visible_per_view : bool
        With ``visible_only``: the (V, N) per-view mask (``visible_mask(per_view=True)``: each source view
        draws only the Gaussians seen in it, the eye slices the union; the same cache entry as the (N,) mask,
        which a background build writes both of), as ``bench/live_frame.py``'s default rows; False: the (N,)
        union for every view (sessions recorded before 2026-11-28 19:30; replay --quality live of those).
    visible_keep : numpy.ndarray, optional
        The (N,) or (V, N) bool mask itself, instead of looking it up (:meth:`twin` passes its renderer's,
        so frames in flight draw the same Gaussians even when a background build lands in between). A mask
        of another shape (another avatar, other cameras) is ignored: every Gaussian drawn, as uncached.
    """

    def __init__(self, tile_scale: float = 1.0, native: bool = True, preview: bool = False, backend: str = "auto",
                 calibration: Any = None, render_threads: int | None = None, mode: str = "auto",
                 view_step: int | None = None, avatar: str = "default", visible_only: bool | str = False,
                 visible_keep: np.ndarray | None = None, visible_per_view: bool = True) -> None:
        import os

        from ..pipeline.live_modes import SESSION_MODE

        if visible_only not in (False, True, "build"):
            from ..errors import InputError

            raise InputError(f"visible_only: expected False, True or 'build', found {visible_only!r}")
        #: the arguments, for :meth:`twin`
        self._args = {"tile_scale": tile_scale, "native": native, "preview": preview, "backend": backend,
                      "calibration": calibration, "render_threads": render_threads, "mode": mode,
                      "view_step": view_step, "avatar": avatar, "visible_only": visible_only,
                      "visible_per_view": bool(visible_per_view)}
        self.visible_only = visible_only
        self.visible_per_view = bool(visible_per_view)
        self._visible_given = None if visible_keep is None else np.asarray(visible_keep, dtype=bool)
        #: the visible-Gaussian mask the frames draw (None: every Gaussian)
        self.visible_keep: np.ndarray | None = None
        threads = max(1, os.cpu_count() or 1) if render_threads is None else int(render_threads)
        if mode not in SESSION_MODE:
            from ..errors import InputError

            raise InputError(f"mode: expected one of {', '.join(SESSION_MODE)}, found {mode!r}")
        self.mode = mode
        self.session_mode = SESSION_MODE[mode]
        self._threads = threads
        #: ``default``, a patient's name or a fitted .npz (docs/patients.md); session.json records it
        self.avatar_name = str(avatar)
        self.native_enabled = bool(native)
        self.preview_enabled = bool(preview)
        self.backend = resolve_backend(backend)
        try:
            self._build(tile_scale, calibration, threads, view_step)
        except Exception as exc:  # noqa: BLE001 - gsplat's first use builds CUDA kernels, which can fail
            from ..errors import HoloViewerError, RenderError

            if self.backend != "gsplat" or (backend != "auto" and isinstance(exc, HoloViewerError)):
                raise
            if backend != "auto":
                raise RenderError(f"gsplat backend: the first frame failed ({type(exc).__name__}: {exc}); "
                                  "use --renderer fast to render on the CPU") from exc
            import warnings

            warnings.warn(f"gsplat failed on the first frame ({type(exc).__name__}: {exc}); the live frames "
                          "render on the CPU (backend 'fast')", RuntimeWarning, stacklevel=2)
            self.backend = "fast"
            self._build(tile_scale, calibration, threads, view_step)

    def _build(self, tile_scale: float, calibration: Any, threads: int, view_step: int | None) -> None:
        """The pipeline and the frame renderer for ``self.backend``, warmed up: the one-off tables and
        kernel loads now, not at the first tracked face or the first frame without one (that froze
        the display for 1.5 s); with gsplat one frame (its kernels, built once per machine)."""
        from ..pipeline import Pipeline, ViewSettings
        from ..render.config import RenderConfig

        who = {}
        if self.avatar_name != "default":  # a patient (fitted: live renders Gaussians) or a fitted .npz
            from ..pipeline.scene import load_avatar

            model, avatar, _, self.avatar_name = load_avatar(self.avatar_name, need_gaussians=True)
            who = {"model": model, "avatar": avatar}
        self.pipeline = Pipeline(calibration=calibration, view=ViewSettings(tile_scale=tile_scale),
                                 backend=self.backend, render_config=RenderConfig(num_threads=threads), **who)
        self._live = None
        self._drawn = None  # _drawn_setup's tables
        self._native_own = None  # _frame_native's: this frame renderer's own native buffer
        if self.session_mode.tracked is None:  # cone: the pipeline renders the viewer's whole quilt
            if self.backend == "gsplat":
                self.pipeline.render_view(0)
            return
        from ..pipeline.live import NativeFrameConfig, NativeFrameRenderer

        config = NativeFrameConfig(render=RenderConfig(num_threads=threads), view_step=view_step, backend=self.backend)
        keep = None
        if self._visible_given is not None and self.backend == "fast":
            keep = self._visible_given
        elif self.visible_only and self.backend == "fast":
            from ..pipeline.live_support import build_visible_mask_later, visible_mask

            # (V, N) and (N,) are one cache entry, which the background build writes whole
            keep = visible_mask(self.pipeline, cached_only=self.visible_only != "build",
                                per_view=self.visible_per_view)
            if keep is None and calibration is None:  # not cached yet: built beside this session, used next time
                build_visible_mask_later(self.avatar_name, tile_scale)
        cams, n = self.pipeline.cameras(), len(self.pipeline.gaussians())
        if keep is not None and keep.shape not in ((n,), (len(cams), n)):
            keep = None  # another avatar's or other cameras' mask: every Gaussian drawn, as uncached
        self._live = NativeFrameRenderer(self.pipeline.calibration, cams, config, keep=keep)
        # what the frames draw: the per-view rows (each source view its own), else the (N,) mask
        self.visible_keep = keep
        self._drawn = self._drawn_setup(keep)
        if self.backend == "gsplat":
            self._live.frame(self.pipeline.gaussians(), None, "all_views")
        else:
            for prepare in self.session_mode.prepare:
                getattr(self._live, prepare)()

    def _drawn_setup(self, keep: np.ndarray | None) -> dict | None:
        """The state of :meth:`_deform_drawn` (None: every frame deforms the whole avatar): a CPU renderer
        with a visible mask, a rigged avatar on the numba path (``RiggedStage.drawn_deform``), frame modes
        that draw the mask's Gaussians alone (``group``, ``all_views``) and no preview (it renders every
        Gaussian)."""
        from ..pipeline.avatars import RiggedStage

        stage = getattr(self.pipeline, "_avatar", None)
        s = self.session_mode
        if (keep is None or self.backend != "fast" or self.preview_enabled or not isinstance(stage, RiggedStage)
                or any(m not in ("group", "all_views") for m in (s.tracked, s.untracked))):
            return None
        deform = stage.drawn_deform(np.flatnonzero(keep.any(axis=0) if keep.ndim == 2 else keep))
        if deform is None:
            return None
        return {"deform": deform, "index": deform.index, "face_mask": deform.face_mask, "gaussians": None}

    def _deform_drawn(self) -> Any:
        """The pipeline's posed mesh bound to the Gaussians the frames draw, written in place into this
        renderer's own (N,) Gaussians (the first frame deforms all of them, through the pipeline): those rows
        are the full deform's bit for bit (tested); the others keep an earlier frame's values, which no group /
        all_views frame reads."""
        d = self._drawn
        p = self.pipeline
        if d["gaussians"] is None:  # the first frame: all of them, copied into buffers of our own
            g = p.gaussians()
            d["gaussians"] = g.replace(means=g.means.clone(), quats=g.quats.clone(), log_scales=g.log_scales.clone())
            return d["gaussians"]
        return d["deform"](p.mesh(), d["gaussians"])

    #: native images the frames hand out before one is copied instead (each 9.4 MB at the panel's size)
    NATIVE_BUFFERS = 4

    def _frame_native(self, deformed: Any, viewer: Any, mode: str) -> np.ndarray:
        """The frame's native image as an array of its own. Frames that rewrite every subpixel
        (:attr:`frames_independent`) are rendered straight into a buffer nobody else holds any more (CPython's
        reference count: the video writer's queue, the panel or a caller still holding an earlier frame keep
        theirs), so no 9.4 MB copy; with all :data:`NATIVE_BUFFERS` held, or for frames that update the last one,
        into the renderer's own buffer and copied, as before. The same bytes either way (tested)."""
        import sys

        live = self._live
        if getattr(self, "_native_own", None) is None:
            self._native_own, self._natives = live.native, []  # the renderer's buffer: never handed out
        buf = None
        if self.frames_independent:
            for b in self._natives:  # held by the list, b, getrefcount's argument (and live.native)
                if sys.getrefcount(b) - (b is live.native) <= 3:
                    buf = b
                    break
            if buf is None and len(self._natives) < self.NATIVE_BUFFERS:
                buf = np.empty_like(self._native_own)
                self._natives.append(buf)
        live.native = self._native_own if buf is None else buf
        out = live.frame(deformed, viewer, mode).native
        return out.copy() if buf is None else out

    @property
    def frames_independent(self) -> bool:
        """Each frame is a function of its own render call alone, not of earlier frames: the CPU backend's
        frame modes that redraw everything (``group``, ``all_views``: rows of
        :data:`~holo_viewer.pipeline.live_modes.FRAME_MODES` that are not ``incremental``), so renderers
        with the same settings give the same frame for the same call, whatever each rendered before
        (tested), and the live loop may render frames on several of them at once
        (:mod:`holo_viewer.live.inflight`). False for ``tracked`` (it updates the previous frame),
        ``cone`` (not checked) and gsplat (one device)."""
        from ..pipeline.live_modes import FRAME_MODE

        if self._live is None or self.backend != "fast":
            return False
        s = self.session_mode
        return all(m is not None and not FRAME_MODE[m].incremental for m in (s.tracked, s.untracked))

    def twin(self, render_threads: int | None = None) -> "LiveAvatarRenderer":
        """A new renderer with this one's settings (its own pipeline and frame buffers: safe to run in
        another thread beside this one); ``render_threads`` replaces the thread count (the frames are the
        same for any count: tested). The backend is the one this renderer resolved to."""
        # the same mask object (read only; NativeFrameRenderer keeps its own copy): the same Gaussians drawn
        args = {**self._args, "backend": self.backend, "visible_only": False, "visible_keep": self.visible_keep}
        if render_threads is not None:
            args["render_threads"] = int(render_threads)
        return LiveAvatarRenderer(**args)

    def visible_record(self) -> dict:
        """session.json ``render.visible`` (:func:`visible_record`): whether the frames skip the Gaussians
        nobody sees, how many they draw of how many, per view or the union, and a digest of the mask drawn
        (32 hex digits), so that replay --quality live draws the same ones (:mod:`holo_viewer.live.replay`)."""
        return visible_record(self.visible_keep, len(self.pipeline.gaussians()))

    @property
    def render_threads(self) -> int:
        """The render's threads (its kernels' numba / OpenMP threads)."""
        return self._threads

    def set_render_threads(self, n: int) -> None:
        """Render the next frames on ``n`` threads (the frames are the same for any count: tested); the
        live loop gives each of two renderers in flight one thread of the 2 cores (holo_viewer.live.inflight)."""
        import dataclasses

        from ..render.config import RenderConfig

        n = max(1, int(n))
        self._threads = n
        p = self.pipeline
        p.set_render(config=dataclasses.replace(p.render_config or RenderConfig(), num_threads=n))
        if self._live is not None:
            c = self._live.config
            self._live.config = dataclasses.replace(c, render=dataclasses.replace(c.render, num_threads=n))

    def deform(self, listener: Mapping[str, np.ndarray], pain: float, named: tuple[tuple[str, float], ...]) -> Any:
        """The deformed Gaussians of one listener frame (the first step of :meth:`render`; its own stage in
        ``bench/live_stages.py``). Not at the same time as :meth:`render` (one pipeline). With a visible mask
        on the CPU (``group`` / ``all_views`` sessions, no preview) only the Gaussians the frames draw are
        deformed (:meth:`_deform_drawn`; the others hold an earlier frame's values) in a buffer this
        renderer overwrites each frame."""
        from ..pipeline import FaceControls

        p = self.pipeline
        n_expr = int(p.model.n_expr)
        expr = np.asarray(listener["expr"], dtype=np.float64)[:n_expr]
        p.set_face(FaceControls(expr=expr, jaw_pose=listener.get("jaw_pose"), rotation=listener.get("rotation"),
                                neck_pose=listener.get("neck_pose"), eyes_pose=listener.get("eyes_pose"),
                                translation=listener.get("translation"), named=named, pain=float(pain)))
        return p.gaussians() if self._drawn is None else self._deform_drawn()

    def render(self, listener: Mapping[str, np.ndarray], pain: float, named: tuple[tuple[str, float], ...],
               viewer_angle_deg: float, viewer_distance_m: float, viewer_tracked: bool = True,
               others: tuple[tuple[float, float], ...] = ()) -> RenderedFrame:
        """One frame: FLAME arrays of one listener frame (``expr``, ``jaw_pose``, ``rotation``, ...).
        ``viewer_tracked``: a face is tracked (mode ``auto`` adds exact images for its eyes to every
        view); ``others``: the (angle, distance) of the other faces seen
        (:attr:`holo_viewer.tracking.viewer.ViewerPose.others`), served too by group frames (up to 6 in all)."""
        import time

        t0 = time.perf_counter()
        p = self.pipeline
        deformed = self.deform(listener, pain, named)
        angle = float(np.clip(viewer_angle_deg, -60, 60))
        distance = float(np.clip(viewer_distance_m, 0.05, 20.0))
        native = None
        if self._live is not None:  # fixed default cone: render what the viewer's eyes see
            from ..display.eyes import TrackedViewer

            if self.native_enabled:
                s = self.session_mode
                mode = "all_views" if self.backend == "gsplat" else s.tracked if viewer_tracked else s.untracked
                viewer = (TrackedViewer(angle_deg=angle, distance_m=distance)
                          if mode != "all_views" and (viewer_tracked or mode != "group") else None)
                if mode == "group" and viewer is not None and others:
                    viewer = [viewer] + [TrackedViewer(angle_deg=float(np.clip(a, -60, 60)),
                                                       distance_m=float(np.clip(d, 0.05, 20.0))) for a, d in others]
                native = self._frame_native(deformed, viewer, mode)
        else:
            p.set_view(viewer_angle=angle, viewer_distance=distance)
            native = p.native().copy() if self.native_enabled else None
        preview = None
        if self.preview_enabled:
            # a view from the viewer's angle: the centre view of a cone centred on the viewer
            if self._live is not None:
                p.set_view(viewer_angle=angle, viewer_distance=distance)
            n = len(p.cameras())
            preview = p.get("views")[n // 2] if self.native_enabled and self._live is None else p.render_view(n // 2)
        return RenderedFrame(native=native, preview=preview, seconds=time.perf_counter() - t0)
