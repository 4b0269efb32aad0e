"""Live native frames: render only what the viewers can see (``holo_viewer.pipeline.live``).

Modes (``NativeFrameRenderer.frame`` / :func:`render_native`), all producing the panel's native image;
each is a row of the mode table :data:`holo_viewer.pipeline.live_modes.FRAME_MODES` (its method, what it
needs, where its work is done), and every quilt goes through
:func:`holo_viewer.display.native.views_to_native`:

``full_quilt``
    Every view in full (the quality reference): render -> uint8 quilt -> interleave.
``all_views``
    Untracked: every view, optionally with a level of detail (``NativeFrameConfig.lod_fraction``, the
    Gaussians that contribute most over the cone, chosen once per avatar), and by default with
    only every ``NativeFrameConfig.view_step``-th view rendered and the others synthesized by a
    depth-compensated warp of their rendered neighbours (:mod:`holo_viewer.render.view_synthesis`;
    ``view_step=1`` renders every view). The interleave samples 59 % of the quilt's pixels but
    some pixel of every 16x16 tile of every view (measured on the Portrait), so a per-calibration
    tile mask saves nothing with row-vector compositing; see docs/live_frame.md.
``tracked``
    A tracked viewer (:class:`~holo_viewer.display.eyes.TrackedViewer`); two methods
    (``NativeFrameConfig.tracked``), both writing only the native subpixels whose light can reach the
    two eyes (beam weight > ``threshold``, over the head motion margin) plus ``refresh_columns``
    tile columns of the other views in round-robin order (rendered exactly, so other people in
    the room still see a hologram); the other subpixels hold older frames.

    ``slices`` (default on quilt cameras): one crossed-slit image per eye, each column seen from
    the quilt camera the eye looks through there (:mod:`holo_viewer.render.crossed_slit`, drawn
    from the same depth sort as the refresh), and every received subpixel's view texel warped
    out of it by depth straight into the native image (:mod:`holo_viewer.display.slices`): two
    images instead of ~25 view bands, approximate (measured per eye against ``full_quilt``).

    ``bands``: the tile columns of the views those subpixels read are rendered into the kept
    views of the previous frames (``fast.render(tile_mask=..., out=...)``); the quilt and the
    native image are updated only where they read those columns (:meth:`Interleaver.update`).
    The received subpixels are exactly those of ``full_quilt`` (tested).
``eye_centred``
    A tracked viewer, the alternative of the tracked light-field displays in the literature: one
    perspective image per eye from the eye's own position (a camera interpolated between the
    quilt cameras, :func:`~holo_viewer.display.eyes.eye_cameras`), written into the subpixels
    whose light reaches that eye (weight > ``threshold``, the nearer eye wins;
    :func:`~holo_viewer.display.eyes.scatter_eye_images`). Two views instead of dozens of bands,
    but a different picture from the 48-view light field: its error against full quality is
    the perspective difference (bench/live_frame.py measures it).
``group``
    Every position of the cone sees the present frame (issue 37): ``all_views`` (the cone fill), then
    the eye slices of the first ``NativeFrameConfig.group_slices`` tracked viewers given (0 by default:
    every viewer sees the fill, >= 40.8 dB at any eye over the default avatar's flare; a TrackedViewer
    or a sequence of up to 6) warped into the subpixels their eyes receive, over that fill; the fill
    renders every ``NativeFrameConfig.group_view_step``-th view (6; ``all_views`` keeps ``view_step``).
    Nothing is kept from earlier frames.
``auto``
    ``group``.

The first frame of a :class:`NativeFrameRenderer` (or after a change of avatar size) renders everything.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from ..camera import Cameras
from ..errors import InputError
from ..render.config import RenderConfig
from .live_modes import FRAME_MODE, TRACKED_METHODS, frame_mode

__all__ = ["NativeFrameConfig", "LiveFrame", "NativeFrameRenderer", "render_native", "MODES", "TRACKED_DEFAULTS",
           "LIVE_T_MIN", "MAX_VIEWERS", "group_viewers", "GROUP_FEATHER", "GROUP_SLICES"]

AUTO_VIEW_STEP = 5  # NativeFrameConfig.view_step=None on a horizontal rig
#: NativeFrameConfig.group_view_step=None: the cone fill's step of group frames, with tracked faces or
#: without (one step: a fill that changed with them made every bystander see a face found or lost,
#: 41-46 dB between consecutive frames). 6 against 5: 0.72x / 0.88x the CPU without / with a face, cone
#: worst 41.6 / 38.9 dB (targets 38 / 35); measured in docs/live_frame.md
AUTO_GROUP_VIEW_STEP = 6
#: NativeFrameConfig.group_feather default: group frames feather the eye slices into the cone fill, a
#: subpixel's slice weight falling linearly from 1 at this many views *inside* its eye's range
#: (negative) to 0 at the reach (D0, 1.52 views), both eyes' slices blended where their reaches meet.
#: Issue 37's comfort (a tracked viewer walking past fixed positions, face still, tests' 0.25-scale
#: views): slices replacing 41.5 dB between consecutive frames; a prototype ramp from -1.5 / -2.5 views to
#: 1 view past the reach 45.2 / 47.1 dB; to the reach from -3 50.0, -3.5 50.8 dB; the tracked eyes 47.0
#: -> 46.0 / 44.8 / 43.3 / 42.9 dB (the eye takes part of the fill): -3 (docs/live_frame.md "Comfort")
GROUP_FEATHER = -3.0
#: group frames serve at most this many tracked viewers (the faces a webcam finds around a Portrait)
MAX_VIEWERS = 6
#: NativeFrameConfig.group_slices default: group frames draw no eye slices; every viewer sees the cone
#: fill, which meets the tracked eyes' target by itself: over the default avatar's whole flare and a walk
#: of eyes over -20..20 deg x 0.45-0.9 m the worst eye sees 40.8 dB (median 45.7; target 40). One
#: viewer's slices raise its eyes to 46-51 dB for ~60-90 ms of CPU a frame (2 slices' render and a
#: scatter: 0.30 against 0.25 s), which the frame-time targets cannot pay (docs/live_frame.md "Group frames")
GROUP_SLICES = 0
#: fixed-point steps of the slices' warp after the first guess: 0 (the default avatar at 0.6 m: per
#: eye 52.1 dB against 52.2 with one step, the worst eye 1 cm off 43.4 against 43.9 dB; -20 % scatter)
SLICE_WARP_ITERS = 0
#: the approximate modes' early-termination threshold (tracked slices, synthesized all views; at
#: least the render config's): a pixel stops after the splat that takes its transmittance below
#: it, so it is off by less than that. 3e-3 against the render default 1e-4, measured: slices per
#: eye 50.2 dB against 50.7 dB, their render -5 ms (1e-2: 47.6 dB, no faster); all views (step 5)
#: 44.3 dB against 44.5 dB, -6 %. Exports (full_quilt), the exact all views and bands keep the config's,
#: and so does gsplat (its T < 1e-4 is compiled in).
LIVE_T_MIN = 3e-3
#: NativeFrameConfig's None for (motion_m, motion_distance_m, refresh_columns), per tracked method
TRACKED_DEFAULTS = {"bands": (0.01, 0.05, 8), "slices": (0.005, 0.02, 2)}


def reach_limit(config: "NativeFrameConfig") -> float:
    """The reach (views) of ``config``'s optics (:func:`~holo_viewer.display.eyes.reach_views`; inf
    where its threshold or beam width is not valid: checked where it is used)."""
    t, sig = float(config.threshold), float(config.sigma_views)
    return sig * math.sqrt(2.0 * math.log(1.0 / t)) if 0.0 < t < 1.0 and sig > 0 else math.inf


Mode = Literal["auto", "group", "tracked", "all_views", "full_quilt", "eye_centred"]
#: the modes of NativeFrameRenderer.frame: "auto" and the rows of pipeline/live_modes.py's FRAME_MODES
MODES = ("auto",) + tuple(FRAME_MODE)


@dataclass(frozen=True)
class NativeFrameConfig:
    """Knobs of :class:`NativeFrameRenderer`.

    Parameters
    ----------
    render : RenderConfig
        Renderer knobs (tile_size is the unit of the tracked restriction).
    blend : bool
        Interleave mode: blend of the two nearest views (True) or nearest (False).
    threshold : float
        Tracked: light weight above which a subpixel counts as seen by an eye.
    sigma_views : float
        Beam width of the optics model (VirtualDisplay), view spacings.
    motion_m, motion_distance_m : float or None
        Tracked: head motion margin during one frame, sideways and in depth (metres). None: the
        method's default (:data:`TRACKED_DEFAULTS`: bands 1 cm / 5 cm, where an eye leaving the
        margin sees stale subpixels; slices 0.5 cm / 2 cm, where the warp's own error beyond it
        is larger than the staleness: the same worst eye at +-1 cm as with 1 cm, measured).
    refresh_columns : int or None
        Tracked: tile columns of the other views re-rendered per frame, round-robin (0 = none).
        None: the method's default (bands 8, slices 2: 8 columns cost a slices frame ~5 ms on 2
        cores, measured).
    lod_fraction : float
        all_views: fraction of the Gaussians kept (1 = all).
    view_step : int or None
        all_views: render views 0, view_step, 2 view_step, ... and the last; synthesize the others
        from their nearest rendered views by a depth-compensated warp (1 = render every view).
        An explicit step > 1 needs a horizontal camera rig (the quilt cameras are one). None
        (default): 5 when the cameras are such a rig (43 dB on the native image of the default
        avatar, 0.18 s against 0.46 s; docs/live_frame.md), else 1; with the gsplat backend None
        renders every view: its synthesis on the device (``view_step > 1``, tested on CPU torch
        and CUDA) costs about what gsplat takes to render those views (H100: 20.3 ms per frame
        at step 5 against 15.8 ms for every view).
    backend : str
        all_views / full_quilt renderer: "fast" (CPU), or "gsplat" (CUDA: the views stay on the
        GPU and are tiled and interleaved there, :class:`~holo_viewer.display.device.DeviceInterleaver`).
    tracked : {"slices", "bands"} or None
        Method of tracked frames (see the module docstring): per-eye slices warped into the
        received subpixels (approximate, fast), or the exact bands of the views. None (default):
        slices on the calibration's quilt cameras, else bands.
    group_view_step : int or None
        ``group`` frames: the ``view_step`` of their cone fill, with tracked faces or without (one
        step, so that a face found or lost changes nothing away from it); at least 2. None
        (default): :data:`AUTO_GROUP_VIEW_STEP` where ``view_step`` is synthesized on the CPU (else
        ``view_step`` is used).
    group_feather : float or None
        ``group`` frames: where the eye slices' weight over the cone fill starts to fall, in views
        of lens coordinate from the eye's range (negative: inside it; 0 at the reach; see
        :func:`~holo_viewer.display.slices.scatter_slices`'s ``inner``), so that moving eyes change
        what fixed positions see smoothly. Default :data:`GROUP_FEATHER`; None: the slices replace
        the fill (sharper tracked eyes, popping where a walker's reach arrives).
    group_slices : int
        ``group`` frames: how many of the tracked viewers given (the first ones: the followed face,
        then the nearest) get exact eye slices over the cone fill, 0..:data:`MAX_VIEWERS`; the others
        see the fill. Default :data:`GROUP_SLICES` (0: every viewer sees the fill).
    """

    render: RenderConfig = field(default_factory=RenderConfig)
    blend: bool = False
    threshold: float = 0.01
    sigma_views: float = 0.5
    motion_m: float | None = None
    motion_distance_m: float | None = None
    refresh_columns: int | None = None
    lod_fraction: float = 1.0
    view_step: int | None = None
    backend: str = "fast"
    tracked: str | None = None
    group_view_step: int | None = None
    group_feather: float | None = GROUP_FEATHER
    group_slices: int = GROUP_SLICES

    def __post_init__(self) -> None:
        if not isinstance(self.render, RenderConfig):
            raise InputError(f"render: expected RenderConfig, found {type(self.render).__name__}")
        if self.refresh_columns is not None and (int(self.refresh_columns) != self.refresh_columns
                                                 or self.refresh_columns < 0):
            raise InputError(f"refresh_columns: expected an integer >= 0 or None, found {self.refresh_columns!r}")
        for name in ("motion_m", "motion_distance_m"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{name}: expected metres >= 0 or None, found {v!r}")
        if not 0.0 < float(self.lod_fraction) <= 1.0:
            raise InputError(f"lod_fraction: expected in (0, 1], found {self.lod_fraction}")
        for name, least in (("view_step", 1), ("group_view_step", 2)):
            v = getattr(self, name)
            if v is not None and (int(v) != v or v < least):
                raise InputError(f"{name}: expected an integer >= {least}, found {v!r}")
        n = self.group_slices
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 0 <= n <= MAX_VIEWERS:
            raise InputError(f"group_slices: expected an integer in 0..{MAX_VIEWERS}, found {n!r}")
        f = self.group_feather
        if f is not None and not (isinstance(f, (int, float)) and math.isfinite(f) and f < reach_limit(self)):
            raise InputError(f"group_feather: expected views < the reach {reach_limit(self):.4g} or None, found {f!r}")
        if self.backend not in ("fast", "gsplat"):
            raise InputError(f"backend: expected 'fast' or 'gsplat', found {self.backend!r}")
        if self.tracked not in (None, "slices", "bands"):
            raise InputError(f"tracked: expected 'slices', 'bands' or None, found {self.tracked!r}")


@dataclass
class LiveFrame:
    """One native frame: ``native`` (screen_h, screen_w, 3) uint8, the mode that ran, wall seconds
    from Gaussians to native, per-step timings and the fraction of the quilt's tiles rendered."""

    native: np.ndarray
    mode: str
    seconds: float
    timings: dict[str, float]
    rendered_fraction: float


class NativeFrameRenderer:
    """Renders native frames for one calibration and one set of quilt cameras, keeping the last
    views, quilt and native image between frames (see the module docstring).

    Parameters
    ----------
    calibration : DisplayCalibration
    cameras : Cameras
        The quilt cameras (V <= cols x rows views, each the size of a quilt tile).
    config : NativeFrameConfig, optional
    rest : Gaussians, optional
        The avatar at rest, for the level of detail (default: the first frame's Gaussians).
    keep : numpy.ndarray, optional
        (N,) bool: the Gaussians the approximate live frames (``group``, ``all_views``) draw, the others
        never being seen (:func:`holo_viewer.pipeline.live_support.visible_mask`: largest blending weight
        over the 48 views at a set of poses <= 1/255); ``full_quilt`` (exports) and the tracked modes
        draw all. A mask of another length than the frame's Gaussians (another avatar) is ignored.
        Or (V, N) bool, one row per camera (``visible_mask(per_view=True)``): the frames draw the union
        of the rows, and each view rendered on the CPU path draws only its own row
        (``fast.render(view_keep=)``; the eye slices draw the union).

    Notes
    -----
    Holds ~250 MB (float views, quilt, native, the interleaver's tables; ~80 MB more with view
    synthesis: source renders, depth maps, the sampled-pixel lists); not thread-safe (one
    renderer per render thread). With ``backend="gsplat"`` the views stay on the GPU, so every
    frame renders all views (a tracked frame on the CPU path needs the kept host views).
    """

    def __init__(self, calibration: Any, cameras: Cameras, config: NativeFrameConfig | None = None,
                 rest: Any = None, keep: np.ndarray | None = None) -> None:
        from ..display.calibration import DisplayCalibration
        from ..display.lenticular import Interleaver

        if not isinstance(calibration, DisplayCalibration):
            raise InputError(f"calibration: expected a DisplayCalibration, found {type(calibration).__name__}")
        if not isinstance(cameras, Cameras):
            raise InputError(f"cameras: expected holo_viewer.camera.Cameras, found {type(cameras).__name__}")
        self.config = config or NativeFrameConfig()
        self.calibration = calibration
        self.cameras = cameras
        V, H, W = len(cameras), cameras.height, cameras.width
        cols, rows = calibration.cols, calibration.rows
        if V > cols * rows:
            raise InputError(f"cameras: {V} views do not fit the calibration's {cols}x{rows} quilt")
        self.quilt_shape = (rows * H, cols * W, 3)
        self.interleaver = Interleaver(calibration, self.quilt_shape, cols=cols, rows=rows, n_views=V,
                                       mode="blend" if self.config.blend else "nearest")
        self.views = np.zeros((V, H, W, 3), dtype=np.float32)
        self.quilt = np.zeros(self.quilt_shape, dtype=np.uint8)
        self._native_owner = None
        if self.config.backend == "gsplat":  # the GPU's native image lands here in one DMA
            from ..display.device import pinned_native

            self.native, self._native_owner = pinned_native(self.interleaver.shape)
        else:
            self.native = np.zeros(self.interleaver.shape, dtype=np.uint8)
        tile = int(self.config.render.tile_size)
        self.tile = tile
        self.tiles_y, self.tiles_x = -(-H // tile), -(-W // tile)
        self._n_gaussians: int | None = None
        self._rr = 0
        self._lod = None
        self._rest = rest
        self._keep: np.ndarray | None = None  # the visible Gaussians (bool mask), see keep
        self._depth_cell: int | None = None  # the z-buffer's cell of the whole avatar, when keep drops some
        self._view_keep: np.ndarray | None = None  # (V, N) bool: per camera, the Gaussians it draws
        self._view_keep_lod: dict[int, np.ndarray] = {}  # per view step: the sources' rows over the drawn ones
        self._lod_visible = False
        if keep is not None:
            k = np.asarray(keep)
            if k.dtype != np.bool_ or k.ndim not in (1, 2) or (k.ndim == 2 and k.shape[0] != len(cameras)):
                raise InputError(f"keep: expected an (N,) or ({len(cameras)}, N) bool mask of the Gaussians drawn, "
                                 f"found {k.dtype} {k.shape}")
            if k.ndim == 2:
                self._view_keep = k.copy()
                k = k.any(axis=0)
            self._keep = k.copy()
        self._device = None
        self._zeta: np.ndarray | None = None
        self._texel: np.ndarray | None = None
        self._rig = None
        step = self.config.view_step
        if step is None and self.config.backend != "fast":
            step = 1  # the GPU path renders every view unless asked: its synthesis is not timed yet
        if step is None or step > 1:
            from ..render import view_synthesis

            try:
                self._rig = view_synthesis.rig_of(cameras)
            except InputError:
                if step is not None:
                    raise
            step = AUTO_VIEW_STEP if step is None else int(step)
        self.view_step = step if self._rig is not None and V > 2 else 1
        self._slice_rig = None
        self._buckets = None
        self._tracked_ready = False  # prepare_tracked has run
        if self.config.tracked != "bands" and self.config.backend == "fast":
            from ..render import crossed_slit

            try:
                self._slice_rig = crossed_slit.slice_rig(cameras, calibration)
            except InputError:
                if self.config.tracked == "slices":
                    raise
        self.tracked_method = "slices" if self._slice_rig is not None else "bands"
        c, d = self.config, TRACKED_DEFAULTS[self.tracked_method]
        #: the effective margins and refresh of tracked frames (NativeFrameConfig's, or the method's defaults)
        self.motion_m = d[0] if c.motion_m is None else float(c.motion_m)
        self.motion_distance_m = d[1] if c.motion_distance_m is None else float(c.motion_distance_m)
        self.refresh_columns = d[2] if c.refresh_columns is None else int(c.refresh_columns)
        if self.view_step > 1:
            from ..display.quilt import tile_slices

            self._sources = view_synthesis.source_views(V, self.view_step)
            self._source_cams = cameras[self._sources.tolist()]
        if self.view_step > 1 and self.config.backend == "fast":
            self._wmaps = np.empty((self._sources.size, H, W), dtype=np.float32)
            self._source_images = np.zeros((self._sources.size, H, W, 3), dtype=np.float32)
            Hq, Wq, _ = self.quilt_shape
            self._tiles = np.array([[tile_slices(Hq, Wq, cols, rows, k)[i].start for i in (0, 1)] for k in range(V)],
                                   dtype=np.int64)
            self._sampled: tuple[np.ndarray, np.ndarray] | None = None  # the pixels the interleave reads
        #: view synthesis on the CPU writes the native image straight from the warp (``warp_views(native=)``:
        #: the bytes of warping into the quilt and interleaving it, tested) where the layout fits and the
        #: extension is built; False: into the quilt, then the interleave (the reference). The synthesized
        #: views' quilt tiles are then not written (the quilt is no output of these frames).
        self.warp_native = True
        self._targets: Any = None  # view_synthesis.NativeTargets of the interleave, or False where none fits
        gs = self.config.group_view_step
        #: the cone fill's view step of group frames with tracked faces (= view_step without synthesis)
        self.group_view_step = self.view_step if self.view_step <= 1 or self.config.backend != "fast" else (
            AUTO_GROUP_VIEW_STEP if gs is None else int(gs))
        self._synth: dict[int, tuple] = {}  # other steps' (sources, cameras, images, depth maps)

    # ------------------------------------------------------------------ public
    def frame(self, gaussians: Any, viewer: Any = None, mode: Mode = "auto") -> LiveFrame:
        """Render one native frame.

        Parameters
        ----------
        gaussians : Gaussians
            The deformed avatar (N Gaussians; N fixed while the renderer keeps state).
        viewer : TrackedViewer, sequence of TrackedViewer, or None
            The tracked viewer; needed by ``tracked``; ``group`` (and ``auto``) serves every viewer of
            a sequence (the first :data:`MAX_VIEWERS`).
        mode : {"auto", "group", "tracked", "all_views", "full_quilt", "eye_centred"}

        Returns
        -------
        LiveFrame
            ``native`` is the renderer's own buffer, overwritten by the next frame (copy to keep).
        """
        from ..render.api import validate_inputs

        t0 = time.perf_counter()
        row = frame_mode(mode, viewer)  # the mode table: pipeline/live_modes.py
        validate_inputs(gaussians, self.cameras)
        if self._n_gaussians != len(gaussians):  # a new avatar: no valid previous frame
            self._n_gaussians = None
            self._lod = None
            self._depth_cell = None
            self._view_keep_lod = {}
        timings: dict[str, float] = {"validate": time.perf_counter() - t0}
        if row.incremental and self._n_gaussians is None:
            row = FRAME_MODE["full_quilt"]  # nothing to update yet: everything
        fraction = getattr(self, row.method)(gaussians, viewer, timings)
        if not row.incremental:  # the kept host views are this frame's (the GPU path keeps its views there)
            self._n_gaussians = len(gaussians) if self.config.backend == "fast" else None
        return LiveFrame(native=self.native, mode=row.name, seconds=time.perf_counter() - t0, timings=timings,
                         rendered_fraction=fraction)

    # ------------------------------------------------------------------ modes (FRAME_MODES' methods)
    def _full_quilt(self, gaussians: Any, viewer: Any, timings: dict[str, float]) -> float:
        return self._everything(gaussians, lod=False, timings=timings)

    def _all_views(self, gaussians: Any, viewer: Any, timings: dict[str, float]) -> float:
        return self._everything(gaussians, lod=True, timings=timings)

    def _tracked(self, gaussians: Any, viewer: Any, timings: dict[str, float]) -> float:
        return getattr(self, TRACKED_METHODS[self.tracked_method])(gaussians, viewer, timings)

    def _everything(self, gaussians: Any, lod: bool, timings: dict[str, float]) -> float:
        from ..display.native import views_to_native
        from ..render import fast

        if lod and self.view_step > 1 and self.config.backend != "gsplat":
            return self._synthesized(gaussians, timings, index=self._lod_index(gaussians))
        g = self._lod_subset(gaussians) if lod else gaussians
        t = time.perf_counter()
        if self.config.backend == "gsplat":
            return self._everything_device(g, timings)
        fast.render(g, self.cameras, self.config.render, out=self.views)
        t1 = time.perf_counter()
        done = views_to_native(self.views, self.interleaver, quilt=self.quilt, native=self.native)
        timings.update(render=t1 - t, **done.seconds)
        return 1.0

    def _lod_subset(self, gaussians: Any) -> Any:
        """The Gaussians the approximate frames draw: those of ``keep`` (the visible ones) and of
        ``lod_fraction`` (chosen once per avatar, from the rest pose), or all."""
        idx = self._lod_index(gaussians)
        return gaussians if idx is None else gaussians.subset(idx)

    def _lod_index(self, gaussians: Any) -> np.ndarray | None:
        """:meth:`_lod_subset` as indices of ``gaussians`` (None: all), for ``fast.render(index=)``."""
        visible = self._keep is not None and self._keep.size == len(gaussians)
        if self.config.lod_fraction >= 1.0 and not visible:
            return None
        if self._lod is None:
            from ..render.lod import lod_keep
            from ..render.view_synthesis import auto_cell

            n = len(gaussians)
            idx = np.arange(n, dtype=np.int64)
            if self.config.lod_fraction < 1.0:
                rest = self._rest if self._rest is not None and len(self._rest) == n else gaussians
                idx = lod_keep(rest, self.config.lod_fraction)
            if visible:
                idx = idx[self._keep[idx]]
                # the depth maps' cell from the whole avatar's centres (auto_cell counts them: the
                # dropped ones are unseen, not a sparser surface)
                op = np.asarray(gaussians.numpy().opacity_logits, dtype=np.float64).reshape(-1)
                self._depth_cell = auto_cell(int((op >= 0.0).sum()), self.cameras.height, self.cameras.width)
            self._lod = idx
            self._lod_visible = visible  # keep applied (per-view rows too: _source_keep)
        return self._lod

    def _source_keep(self, step: int, src: np.ndarray, n: int) -> np.ndarray | None:
        """(sources, n) bool: per source view of ``step``, which of the drawn Gaussians (``_lod``) it
        draws (``keep``'s per-view rows), or None (every view draws every drawn Gaussian)."""
        vk = self._view_keep
        if vk is None or self._lod is None or not self._lod_visible:
            return None
        rows = self._view_keep_lod.get(step)
        if rows is None or rows.shape != (src.size, n):
            rows = self._view_keep_lod[step] = np.ascontiguousarray(vk[src][:, self._lod])
        return rows

    def _synth_buffers(self, step: int) -> tuple:
        """(sources, their cameras, their images, their depth maps) of view step ``step``."""
        if step == self.view_step:
            return self._sources, self._source_cams, self._source_images, self._wmaps
        if step not in self._synth:
            from ..render import view_synthesis

            V, H, W = len(self.cameras), self.cameras.height, self.cameras.width
            src = view_synthesis.source_views(V, step)
            self._synth[step] = (src, self.cameras[src.tolist()], np.zeros((src.size, H, W, 3), dtype=np.float32),
                                 np.empty((src.size, H, W), dtype=np.float32))
        return self._synth[step]

    def _synthesized(self, g: Any, timings: dict[str, float], slits: Any = None, step: int | None = None,
                     index: np.ndarray | None = None) -> float:
        """all_views with view synthesis: the source views rendered, the others warped from them
        straight into the quilt (their float views are not kept). ``slits``: eye slices drawn in the
        same depth sort and projection pass (``group`` frames); ``step``: the view step (default
        ``view_step``); ``index``: draw ``g.subset(index)`` (:meth:`_lod_index`) without copying it
        (``fast.render(index=)``: the same frame bit for bit, ~2-3 ms of CPU less)."""
        from ..display.native import views_to_native
        from ..render import fast, view_synthesis

        t = time.perf_counter()
        step = self.view_step if step is None else int(step)
        src, src_cams, images, wmaps = self._synth_buffers(step)
        cfg = self.config.render
        n = len(g) if index is None else index.size
        fast.render(g, src_cams, dataclasses.replace(cfg, t_min=max(cfg.t_min, LIVE_T_MIN)), out=images, slits=slits,
                    view_keep=self._source_keep(step, src, n), index=index)
        t1 = time.perf_counter()
        # the two fields' numpy arrays (Gaussians.numpy() builds and checks a whole new Gaussians: ~0.25 ms)
        means, logits = _field_np(g.means), np.asarray(_field_np(g.opacity_logits), dtype=np.float64)
        if index is not None:
            means, logits = np.take(means, index, axis=0), logits[index]  # take: means[index]'s rows, ~4x faster
        opacity = fast.sigmoid_cached(logits)  # the same values; cached while the logits stay
        view_synthesis.inverse_depth(means, opacity, self.cameras, src, rig=self._rig, out=wmaps,
                                     cell=self._depth_cell)
        t2 = time.perf_counter()
        if self._sampled is None:  # once: only the quilt pixels the interleave reads are synthesized
            self.prepare_all_views()
        background = self.config.render.background
        if self.warp_native and self._targets:  # every native subpixel from the sources and the warp
            t3 = time.perf_counter()
            view_synthesis.warp_views(images, wmaps, src, self._rig, pixels=self._sampled, background=background,
                                      native=self.native, targets=self._targets)
            t4 = t5 = time.perf_counter()
        else:
            layout = (self.calibration.cols, self.calibration.rows)
            views_to_native(images, layout, quilt=self.quilt, tiles=src)  # the rendered views' tiles
            t3 = time.perf_counter()
            view_synthesis.warp_views(images, wmaps, src, self._rig, quilt=self.quilt, tiles=self._tiles,
                                      pixels=self._sampled, background=background)
            t4 = time.perf_counter()
            views_to_native(None, self.interleaver, quilt=self.quilt, native=self.native)
            t5 = time.perf_counter()
        timings.update(render=t1 - t, depth=t2 - t1, quilt=t3 - t2, warp=t4 - t3, interleave=t5 - t4)
        return src.size / len(self.cameras)

    def _group(self, gaussians: Any, viewers: Any, timings: dict[str, float]) -> float:
        """Every position of the cone sees this frame: all views (every ``group_view_step``-th rendered,
        the others synthesized by depth, as ``all_views``), and the exact eye slices of the first
        ``config.group_slices`` tracked viewers (drawn in the same depth sort and projection pass as the
        rendered views) warped into the native subpixels those eyes receive, over the cone fill.
        Nothing is kept from earlier frames. Without viewers it is that fill alone; without view
        synthesis on the CPU (``view_step`` 1, the gsplat backend) it is ``all_views``."""
        from ..display.eyes import eye_positions, eye_view_bounds, reach_views
        from ..display.slices import scatter_slices
        from ..render import crossed_slit

        viewers = group_viewers(viewers)[:self.config.group_slices]  # the others see the fill
        if self.view_step <= 1 or self.config.backend != "fast":
            return self._all_views(gaussians, None, timings)
        if not viewers or self._slice_rig is None:  # the same fill as with faces
            return self._synthesized(gaussians, timings, step=self.group_view_step, index=self._lod_index(gaussians))
        t = time.perf_counter()
        self.prepare_tracked()
        if self._sampled is None:
            self.prepare_all_views()
        rig, c = self._slice_rig, self.config
        eyes_ = [e for v in viewers for e in crossed_slit.eye_slices(rig, eye_positions(v))]
        E = len(eyes_)
        if self._slices.shape[0] < E:
            H, W = self.cameras.height, self.cameras.width
            self._slices = np.zeros((E, H, W, 3), dtype=np.float32)
            self._slice_w = np.zeros((E, H, W), dtype=np.float32)
        slits = crossed_slit.slit_views(rig, eyes_, self._slices[:E], t_min=max(c.render.t_min, LIVE_T_MIN))
        idx = self._lod_index(gaussians)  # the level of detail of all_views, slices included
        fraction = self._synthesized(gaussians, timings, slits=slits, step=self.group_view_step, index=idx)
        t1 = time.perf_counter()
        means, logits = _field_np(gaussians.means), np.asarray(_field_np(gaussians.opacity_logits), dtype=np.float64)
        if idx is not None:
            means, logits = np.take(means, idx, axis=0), logits[idx]  # take: means[idx]'s rows, ~4x faster
        opacity = 1.0 / (1.0 + np.exp(-logits))
        crossed_slit.slice_depth(means, opacity, rig, eyes_, out=self._slice_w[:E],
                                 cell=self._depth_cell)  # the whole avatar's cell, as the views' depth
        t2 = time.perf_counter()
        reach = reach_views(c.sigma_views, c.threshold)
        e = 0
        # each viewer's eyes over the cone fill (across the lobe boundary the fill stays); one scatter per
        # viewer: one call for all (each subpixel to the nearest of every eye) took 2x as long with 4
        for v in viewers:
            n = 2 if v.ipd_m else 1
            bounds = eye_view_bounds(self.calibration, v, n_views=len(self.cameras), motion_m=self.motion_m,
                                     motion_distance_m=self.motion_distance_m)
            segments, lobe = self.tracked_segments(v, bounds, lobes=True)
            kv, gh = crossed_slit.warp_coefficients(rig, eyes_[e:e + n])
            scatter_slices(self.native, self._buckets, segments[lobe == 0], bounds, reach, self._slices[e:e + n],
                           self._slice_w[e:e + n], kv, gh, iters=SLICE_WARP_ITERS, inner=c.group_feather)
            e += n
        t3 = time.perf_counter()
        timings.update(slice_depth=t2 - t1, scatter=t3 - t2, prepare=t1 - t - sum(
            timings.get(k, 0.0) for k in ("render", "depth", "quilt", "warp", "interleave")))
        return fraction + E / len(self.cameras)

    def _everything_device(self, g: Any, timings: dict[str, float]) -> float:
        """All views with gsplat on CUDA, tiled and interleaved on the GPU (views stay there)."""
        from ..display.native import views_to_native
        from ..display.device import DeviceInterleaver
        from ..render import gsplat_backend

        t = time.perf_counter()
        if self.view_step > 1:  # the source views rendered, the others warped on the device
            import torch

            from ..render import view_synthesis

            src = self._sources
            images = gsplat_backend.render_device(g, self._source_cams, self.config.render)
            t1 = time.perf_counter()
            gt = g.torch(device=images.device, dtype=torch.float32)
            wmaps = view_synthesis.inverse_depth_torch(gt.means, torch.sigmoid(gt.opacity_logits), self.cameras, src,
                                                       rig=self._rig)
            views = view_synthesis.warp_views_torch(images, wmaps, src, self._rig)
            fraction = src.size / len(self.cameras)
        else:
            views = gsplat_backend.render_device(g, self.cameras, self.config.render)
            t1 = time.perf_counter()
            fraction = 1.0
        t2 = time.perf_counter()
        if self._device is None:
            V, H, W = len(self.cameras), self.cameras.height, self.cameras.width
            self._device = DeviceInterleaver(self.interleaver, V, H, W, device=views.device)
        views_to_native(views, self._device, native=self.native)  # the frame's one synchronisation
        t3 = time.perf_counter()
        # (device work is asynchronous: only the sum, ending with the copy to the host, is a GPU time)
        timings.update(render=t1 - t, synthesis=t2 - t1, interleave=t3 - t2)
        return fraction

    def tracked_columns(self, viewer: Any) -> np.ndarray:
        """(V, tiles_x) bool: the tile columns of each view a tracked frame renders for ``viewer``
        (before the round-robin refresh)."""
        from ..display.eyes import view_columns

        c = self.config
        cols = view_columns(self.calibration, viewer, self.cameras.width, n_views=len(self.cameras),
                            mode="blend" if c.blend else "nearest", sigma_views=c.sigma_views,
                            threshold=c.threshold, motion_m=self.motion_m, motion_distance_m=self.motion_distance_m)
        pad = np.zeros((cols.shape[0], self.tiles_x * self.tile), dtype=bool)
        pad[:, :cols.shape[1]] = cols
        return pad.reshape(cols.shape[0], self.tiles_x, self.tile).any(axis=2)

    def _refresh(self, colmask: np.ndarray) -> None:
        """Add the next ``refresh_columns`` tile columns (round-robin over every view) to ``colmask``."""
        n_cols = colmask.size
        r = self.refresh_columns
        if r:  # round-robin refresh of everything else
            nxt = (self._rr + np.arange(min(r, n_cols))) % n_cols
            colmask.reshape(-1)[nxt] = True
            self._rr = int((self._rr + r) % n_cols)

    def _columns_to_native(self, colmask: np.ndarray, sparse: bool = False) -> dict[str, float]:
        """The kept float views' tile columns ``colmask`` (V, tiles_x) -> the uint8 quilt -> the native
        subpixels that read them (``sparse``: through the reader lists, for a few columns); seconds."""
        from ..display.native import ColumnUpdate, views_to_native

        return views_to_native(self.views, self.interleaver, quilt=self.quilt, native=self.native,
                               columns=ColumnUpdate(colmask, self.tile, sparse)).seconds

    def _tracked_bands(self, gaussians: Any, viewer: Any, timings: dict[str, float]) -> float:
        from ..render import fast

        t = time.perf_counter()
        colmask = self.tracked_columns(viewer)
        self._refresh(colmask)
        tile_mask = np.repeat(colmask[:, None, :], self.tiles_y, axis=1)
        t1 = time.perf_counter()
        fast.render(gaussians, self.cameras, self.config.render, tile_mask=tile_mask, out=self.views)
        t2 = time.perf_counter()
        timings.update(select=t1 - t, render=t2 - t1, **self._columns_to_native(colmask))
        return float(colmask.mean())

    def tracked_segments(self, viewer: Any, bounds: np.ndarray | None = None,
                         lobes: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """(S, 4) (eye, view, x0, x1) native-column segments of ``viewer``'s eyes
        (:func:`~holo_viewer.display.eyes.view_segments` with this renderer's knobs; ``bounds``
        its eyes' view-coordinate ranges when already computed; ``lobes``: also each row's lobe)."""
        from ..display.eyes import view_segments

        c = self.config
        return view_segments(self.calibration, viewer, n_views=len(self.cameras),
                             mode="blend" if c.blend else "nearest", sigma_views=c.sigma_views,
                             threshold=c.threshold, motion_m=self.motion_m, motion_distance_m=self.motion_distance_m,
                             bounds=bounds, lobes=lobes)

    def _exact_wrapped(self, segments: np.ndarray, lobe: np.ndarray, colmask: np.ndarray) -> np.ndarray:
        """Split off the segments an eye receives across the lobe boundary (``lobe`` != 0: near
        the cone's edge it looks past the last view through part of the panel and gets the first
        views of the next lobe, or the reverse): their subpixels show a view ~n views from the
        eye's slice, which cannot stand in for it. Their views' tile columns (one texel to spare
        each side) are added to ``colmask``, so they are rendered exactly through the quilt;
        returns the others."""
        wrapped = lobe != 0
        if not wrapped.any():
            return segments
        tw, W = self.cameras.width, self.calibration.screen_w
        _, k, x0, x1 = segments.T
        for kk, a, b in zip(k[wrapped], x0[wrapped], x1[wrapped]):
            # the texel columns native columns a..b-1 read (view_columns' rule), one to spare
            c0 = max(int(np.floor((a + 0.5) / W * tw)) - 1, 0) // self.tile
            c1 = min(int(np.floor((b - 0.5) / W * tw)) + 1, tw - 1) // self.tile
            colmask[kk, c0:c1 + 1] = True
        return segments[~wrapped]

    def prepare_tracked(self) -> None:
        """Build the one-off tables of tracked frames now (otherwise the first tracked frame does,
        and takes ~0.5 s longer for the Portrait): the interleaver's per-subpixel tile-column keys
        (``bands``; ``slices``: the lists of the subpixels reading each tile column, for the
        refresh) and, for ``slices``, the subpixels sorted by view (~2 s, ~60 MB), and load the
        compiled kernels a slices frame calls (numba caches: the first call took ~20 ms more). A
        live session calls it while it warms up, a benchmark before it times."""
        if self._tracked_ready:
            return
        self._tracked_ready = True
        none = np.zeros((len(self.cameras), self.tiles_x), dtype=bool)
        if self.tracked_method == "bands":
            self.interleaver.update_columns(self.quilt, self.native, none, block=self.tile)
            return
        from ..display.native import ColumnUpdate, views_to_native
        from ..display.eyes import TrackedViewer, eye_positions
        from ..display.slices import subpixel_buckets
        from ..render import crossed_slit

        if self.refresh_columns > 0:  # slices
            self.interleaver.readers(none, block=self.tile)
            # the refresh's kernels, on no subpixel and on one tile column that already holds its
            # views' values (the quilt is always the uint8 of the kept views)
            one = none.copy()
            one[0, 0] = True
            views_to_native(self.views, (self.calibration.cols, self.calibration.rows), quilt=self.quilt,
                            columns=ColumnUpdate(one, self.tile))
            self.interleaver.update(self.quilt, self.native, np.zeros(0, dtype=np.int32))
        V, H, W = len(self.cameras), self.cameras.height, self.cameras.width
        self._buckets = subpixel_buckets(self.interleaver, V, H, W)  # shared by the renderers of this panel
        self._slices = np.zeros((2, H, W, 3), dtype=np.float32)
        self._slice_w = np.zeros((2, H, W), dtype=np.float32)
        eyes_ = crossed_slit.eye_slices(self._slice_rig, eye_positions(TrackedViewer(0.0, 0.6)))
        crossed_slit.slice_depth(np.zeros((1, 3)), np.zeros(1), self._slice_rig, eyes_,  # the z-buffer, no centre
                                 out=self._slice_w[:len(eyes_)])

    def prepare_all_views(self) -> None:
        """Build the one-off tables of untracked (``all_views``) frames now and load their compiled
        kernels: with view synthesis, the quilt pixels the interleave reads (otherwise the first
        such frame of a session builds them and took 1.5 s instead of 0.14 s for the Portrait).
        Changes no image. A live session calls it while it warms up."""
        if self.view_step <= 1 or self.config.backend != "fast" or self._sampled is not None:
            return
        from ..render import view_synthesis

        self._sampled = view_synthesis.sampled_columns(read_pixels(self.interleaver, self.calibration,
                                                                   len(self.cameras)))
        # where each read texel lands in the native image (~0.3 s of CPU for the Portrait), for the direct warp
        self._targets = self.interleaver.mode == "nearest" and view_synthesis.native_warp_available() and \
            view_synthesis.native_targets(self.interleaver.gather_indices()[0], self._tiles, self._sampled,
                                          self.interleaver.quilt_shape, self.interleaver.shape)
        # the z-buffer and the warp, on no centre and no pixel, into scratch depth maps (this may
        # run in the middle of a frame, whose depth maps are already in self._wmaps)
        src, H = self._sources, self.cameras.height
        wmaps = view_synthesis.inverse_depth(np.zeros((1, 3)), np.zeros(1), self.cameras, src, rig=self._rig,
                                             out=np.empty_like(self._wmaps))
        none = (np.zeros(len(self.cameras) * H + 1, dtype=np.int64), np.zeros(0, dtype=np.int32))
        view_synthesis.warp_views(self._source_images, wmaps, src, self._rig, quilt=self.quilt, tiles=self._tiles,
                                  pixels=none, background=self.config.render.background)

    def _tracked_slices(self, gaussians: Any, viewer: Any, timings: dict[str, float]) -> float:
        """A tracked frame from one crossed-slit image per eye (see the module docstring)."""
        from ..display.eyes import eye_positions, eye_view_bounds, reach_views
        from ..display.slices import scatter_slices
        from ..render import crossed_slit, fast

        t = time.perf_counter()
        rig = self._slice_rig
        self.prepare_tracked()
        eyes_ = crossed_slit.eye_slices(rig, eye_positions(viewer))
        E = len(eyes_)
        c = self.config
        bounds = eye_view_bounds(self.calibration, viewer, n_views=len(self.cameras), motion_m=self.motion_m,
                                 motion_distance_m=self.motion_distance_m)
        segments, lobe = self.tracked_segments(viewer, bounds, lobes=True)
        colmask = np.zeros((len(self.cameras), self.tiles_x), dtype=bool)
        segments = self._exact_wrapped(segments, lobe, colmask)
        self._refresh(colmask)
        tile_mask = np.repeat(colmask[:, None, :], self.tiles_y, axis=1)
        t1 = time.perf_counter()
        fast.render(gaussians, self.cameras, self.config.render, tile_mask=tile_mask, out=self.views,
                    slits=crossed_slit.slit_views(rig, eyes_, self._slices[:E],
                                                  t_min=max(self.config.render.t_min, LIVE_T_MIN)))
        t2 = time.perf_counter()
        gn = gaussians.numpy()
        opacity = 1.0 / (1.0 + np.exp(-np.asarray(gn.opacity_logits, dtype=np.float64)))
        crossed_slit.slice_depth(gn.means, opacity, rig, eyes_, out=self._slice_w[:E])
        t3 = time.perf_counter()
        if colmask.any():  # the refreshed columns: exact, through the quilt
            self._columns_to_native(colmask, sparse=True)
        t4 = time.perf_counter()
        kv, gh = crossed_slit.warp_coefficients(rig, eyes_)
        scatter_slices(self.native, self._buckets, segments, bounds, reach_views(c.sigma_views, c.threshold),
                       self._slices[:E], self._slice_w[:E], kv, gh, iters=SLICE_WARP_ITERS)
        t5 = time.perf_counter()
        timings.update(select=t1 - t, render=t2 - t1, depth=t3 - t2, interleave=t4 - t3, scatter=t5 - t4)
        return float((E * self.tiles_x + colmask.sum()) / colmask.size)


    def _eye_centred(self, gaussians: Any, viewer: Any, timings: dict[str, float]) -> float:
        from ..display import eyes
        from ..display.quilt import to_uint8
        from ..render import fast

        t = time.perf_counter()
        if self._zeta is None:
            from ..display.device import view_gather_indices
            from ..display.simulate import VirtualDisplay

            V, H, W = len(self.cameras), self.cameras.height, self.cameras.width
            vd = VirtualDisplay(self.calibration, n_views=V, sigma_views=self.config.sigma_views)
            self._zeta = vd.zeta.astype(np.float32)
            idx0 = view_gather_indices(self.interleaver, V, H, W)[0]
            self._texel = (idx0 % (H * W * 3)).astype(np.int32)
        cams = eyes.eye_cameras(self.cameras, self.calibration, viewer)
        t1 = time.perf_counter()
        imgs = fast.render(gaussians, cams, self.config.render).images
        t2 = time.perf_counter()
        c = self.config
        reach = c.sigma_views * math.sqrt(2.0 * math.log(1.0 / c.threshold))
        t_eyes = eyes.eye_view_coordinates(self.calibration, viewer, len(self.cameras))
        eyes.scatter_eye_images(self.native, self._zeta, t_eyes, self._texel, to_uint8(imgs), len(self.cameras), reach)
        t3 = time.perf_counter()
        timings.update(select=t1 - t, render=t2 - t1, interleave=t3 - t2)
        return len(cams) / len(self.cameras)


def _field_np(x: Any) -> np.ndarray:
    """A Gaussians field as numpy (a CPU tensor's own memory, as ``Gaussians.numpy()`` gives it)."""
    from ..avatar.gaussians import Gaussians

    return Gaussians._np(x)


def group_viewers(viewers: Any) -> list:
    """None, one :class:`~holo_viewer.display.eyes.TrackedViewer` or a sequence of them -> a list of at
    most :data:`MAX_VIEWERS` (the first ones: the tracker lists the nearest faces first).

    Raises
    ------
    InputError
        An entry that is not a TrackedViewer (naming its index).
    """
    from ..display.eyes import TrackedViewer

    if viewers is None:
        return []
    if isinstance(viewers, TrackedViewer):
        return [viewers]
    out = list(viewers)
    for i, v in enumerate(out):
        if not isinstance(v, TrackedViewer):
            raise InputError(f"viewers[{i}]: expected a holo_viewer.display.eyes.TrackedViewer, "
                             f"found {type(v).__name__}")
    return out[:MAX_VIEWERS]


def read_pixels(interleaver: Any, calibration: Any, n_views: int) -> np.ndarray:
    """(n_views, H, W) bool: the views' pixels whose quilt texels the interleave reads (either
    texel of a blend), through the quilt's tile layout (:func:`holo_viewer.display.quilt.tile_slices`)."""
    from ..display.quilt import tile_slices

    Hq, Wq, _ = interleaver.quilt_shape
    read = np.zeros(Hq * Wq, dtype=bool)
    for idx in interleaver.gather_indices()[:2]:
        if idx is not None:
            read[idx // 3] = True
    read = read.reshape(Hq, Wq)
    tiles = [tile_slices(Hq, Wq, calibration.cols, calibration.rows, k) for k in range(n_views)]
    return np.stack([read[rs, cs] for rs, cs in tiles])


_CACHE: dict[Any, NativeFrameRenderer] = {}


def render_native(gaussians: Any, cameras: Cameras, calibration: Any, viewer: Any = None, mode: Mode = "auto",
                  config: NativeFrameConfig | None = None) -> LiveFrame:
    """One native frame; the mode chooser for the pipeline and the live loop.

    ``mode="auto"``: ``group``, every view and the exact eye images of the viewers given, if any.
    Keeps one :class:`NativeFrameRenderer` per (calibration, cameras, config) between calls, so a tracked
    frame reuses the previous frames' views; hold your own ``NativeFrameRenderer`` to control that state.

    Parameters
    ----------
    gaussians : Gaussians
    cameras : Cameras
        Quilt cameras.
    calibration : DisplayCalibration
    viewer : TrackedViewer or None
    mode : {"auto", "group", "tracked", "all_views", "full_quilt", "eye_centred"}
    config : NativeFrameConfig, optional

    Returns
    -------
    LiveFrame
    """
    config = config or NativeFrameConfig()
    key = (id(calibration), cameras.width, cameras.height, np.asarray(cameras.world_to_cam).tobytes(),
           np.asarray(cameras.K).tobytes(), config)
    renderer = _CACHE.get(key)
    if renderer is None or renderer.calibration is not calibration:
        _CACHE.clear()  # one live state at a time (each holds ~200 MB of views and quilt)
        renderer = _CACHE[key] = NativeFrameRenderer(calibration, cameras, config)
    return renderer.frame(gaussians, viewer, mode)
