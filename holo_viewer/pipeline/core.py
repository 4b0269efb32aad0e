"""The one place that chains the stages (docs/design.md section 2), with caching and timings.

::

    FaceControls ─► params ─► mesh ─► gaussians ─┐
                  shape ─► framing ─► cameras ───┴─► views ─► quilt ─► native

The stages, what each consumes and reads, and the module that does its work are listed once,
in :data:`~holo_viewer.pipeline.stages.STAGE_TABLE`. Each stage's result is cached with a *key*: a fingerprint of the settings the stage
reads plus the versions of the stages it consumes. Asking for a stage recomputes
only the stages whose key changed, so changing pain re-runs
``params -> mesh -> gaussians -> views -> quilt -> native`` but keeps the cameras,
and changing the viewer distance re-runs ``cameras -> views -> quilt -> native`` but
keeps the mesh and Gaussians. Every recomputation is appended to
:attr:`Pipeline.recompute_log` and timed (:class:`StageTimings`).

:meth:`Pipeline.stream` plays a FLAME sequence (or the reaction model's output) with a
frame budget and reports the frames it dropped and held when it cannot keep up.

The stage bodies call the stage modules (``flame``, ``avatar``, ``display``,
``render`` through :mod:`.rendering`); this module holds no math of its own beyond the framing
of the head. The avatar is anything :func:`~holo_viewer.pipeline.avatars.as_pipeline_avatar`
accepts: rigged (GaussianAvatars binding), blend-shape (seed paper) or a static 3DGS scene.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Literal, Mapping

import numpy as np

from ..errors import InputError
from ..validation import check_array, check_finite_scalar
from .avatars import AvatarLike, PipelineAvatar, as_pipeline_avatar
from .rendering import render_images, tile_views
from .settings import FaceControls, FlameFrame, FrameResult, StreamReport, ViewSettings, apply_frame
from .stages import STAGE_TABLE, STAGES, STREAM_OUTPUTS, Stage, StageTimings

if TYPE_CHECKING:  # pragma: no cover
    from ..avatar.gaussians import Gaussians
    from ..camera import Cameras
    from ..display.calibration import DisplayCalibration
    from ..flame.expressions import AUMap
    from ..flame.model import FlameModel
    from ..render.config import RenderConfig

__all__ = ["Pipeline", "frame_head", "default_calibration", "quilt_layout"]

_STAGE = {s.name: s for s in STAGE_TABLE}

# =============================================================================== framing


def frame_head(vertices: np.ndarray, margin: float = 1.08) -> tuple[np.ndarray, float]:
    """Focal-plane centre and half-height that frame a head like a portrait.

    The focal plane passes through the centre of the head's axis-aligned bounding box
    (FLAME frame: nose toward +z, so the plane is parallel to the face); its half-height
    is ``margin`` x half the box height, so the head fills the portrait tile.

    Parameters
    ----------
    vertices : numpy.ndarray
        (V, 3) neutral head vertices in metres.
    margin : float
        > 1 leaves a border above and below the head.

    Returns
    -------
    centre : numpy.ndarray
        (3,) focal-plane centre in metres.
    half_height : float
        Focal-plane half-height in metres.
    """
    v = check_array(np.asarray(vertices, dtype=np.float64), "vertices", ("V", 3))
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * float(hi[1] - lo[1]) * float(margin)
    if not half > 0:
        raise InputError("vertices: expected a head with non-zero height, found a flat bounding box")
    return centre, half


# =============================================================================== fingerprints


def _fingerprint(obj: Any) -> str:
    h = hashlib.blake2b(digest_size=16)

    def feed(o: Any) -> None:
        if o is None:
            h.update(b"N")
        elif isinstance(o, np.ndarray):
            a = np.ascontiguousarray(o)
            h.update(f"A{a.dtype}{a.shape}".encode())
            h.update(a.tobytes())
        elif dataclasses.is_dataclass(o) and not isinstance(o, type):
            h.update(type(o).__name__.encode())
            for f in dataclasses.fields(o):
                h.update(f.name.encode())
                feed(getattr(o, f.name))
        elif isinstance(o, (tuple, list)):
            h.update(b"(")
            for x in o:
                feed(x)
            h.update(b")")
        elif isinstance(o, Mapping):
            h.update(b"{")
            for k in sorted(o):
                feed(k)
                feed(o[k])
            h.update(b"}")
        elif isinstance(o, (bool, int, float, str, np.floating, np.integer)):
            h.update(repr(o).encode())
        else:
            h.update(f"id{id(o)}".encode())

    feed(obj)
    return h.hexdigest()


@dataclass
class _Entry:
    key: str
    value: Any
    version: int


# =============================================================================== pipeline


class Pipeline:
    """FLAME params -> mesh -> Gaussians -> cameras -> views -> quilt -> native, cached.

    Parameters
    ----------
    model : FlameModel or None
        The FLAME model; None = the avatar's ``flame_model`` (or the embedded default head).
    avatar : RiggedAvatar, BlendshapeAvatar, StaticAvatar, PipelineAvatar, None or False
        A rigged avatar bound to ``model``'s triangles, a blend-shape avatar built on ``model``
        (:class:`~holo_viewer.avatar.BlendshapeAvatar`), static world Gaussians, or any
        :class:`~holo_viewer.pipeline.avatars.PipelineAvatar`; None = the default avatar.
        ``False`` disables the Gaussian stages (mesh-only use, e.g. the GUI without splats).
    calibration : DisplayCalibration or None
        Looking Glass calibration; None = the Portrait calibration shipped in ``assets/``.
    face, view : FaceControls, ViewSettings
        Initial settings.
    backend : str
        Renderer backend name for :func:`holo_viewer.render.render_views`.
    render_config : RenderConfig or None
    au_map : AUMap or None
        Action-unit map for named expressions and pain; None = ``au_map_for(model)``.
    """

    def __init__(self, model: "FlameModel | None" = None, avatar: "AvatarLike | Literal[False] | None" = None,
                 calibration: "DisplayCalibration | None" = None, *, face: FaceControls | None = None,
                 view: ViewSettings | None = None, backend: str = "fast",
                 render_config: "RenderConfig | None" = None, au_map: "AUMap | None" = None) -> None:
        if avatar is None:
            from ..avatar.default_gaussians import default_avatar

            avatar = default_avatar()  # bound to the default head with teeth
            if model is not None and model is not avatar.flame_model:
                raise InputError("model: the default avatar is bound to the default head (with teeth); pass "
                                 "avatar=False for a mesh-only pipeline or an avatar bound to your model")
        stage_avatar = as_pipeline_avatar(avatar, model) if avatar is not False else None
        if model is None and stage_avatar is not None:
            model = stage_avatar.flame_model
        if model is None:
            from ..flame.default_head import load_default_model

            model = load_default_model()
        self.model = model
        #: the avatar as given (None for a mesh-only pipeline)
        self.avatar = avatar if avatar is not False else None
        self._avatar: PipelineAvatar | None = stage_avatar
        #: per-subject FLAME parameters of the avatar (``shape``, ``static_offset``)
        self.identity: dict[str, np.ndarray] = dict(stage_avatar.identity) if stage_avatar is not None else {}
        if calibration is None:
            calibration = default_calibration()
        self.calibration = calibration
        self._au_map = au_map
        self._au_map_version = 0
        self.face = face or FaceControls()
        self.view = view or ViewSettings()
        self.backend = backend
        self.render_config = render_config
        self._cache: dict[str, _Entry] = {}
        self._versions = 0
        self._timings = StageTimings()
        #: (request number, stage) for every stage computation, oldest first
        self.recompute_log: list[tuple[int, str]] = []
        self._request = 0
        self._interleaver: Any = None
        self._interleaver_key: str | None = None

    # ---------------------------------------------------------------- settings
    @property
    def au_map(self) -> "AUMap":
        """Action-unit map of the model (named expressions, pain)."""
        if self._au_map is None:
            from ..flame.expressions import au_map_for

            self._au_map = au_map_for(self.model)
        return self._au_map

    def set_au_map(self, au_map: "AUMap") -> None:
        """Use another action-unit map (``flame.expressions.AUMap``) for named expressions and pain."""
        self._au_map = au_map
        self._au_map_version += 1

    def set_face(self, face: FaceControls | None = None, **changes: object) -> None:
        """Replace the face controls (or some of their fields)."""
        self.face = (face or self.face).replace(**changes) if changes else (face or self.face)

    def set_view(self, view: ViewSettings | None = None, **changes: object) -> None:
        """Replace the view settings (or some of their fields)."""
        base = view or self.view
        self.view = dataclasses.replace(base, **changes) if changes else base

    def set_render(self, backend: str | None = None, config: "RenderConfig | None" = None) -> None:
        """Change the renderer backend and/or its configuration."""
        if backend is not None:
            self.backend = backend
        if config is not None:
            self.render_config = config

    def set_calibration(self, calibration: "DisplayCalibration") -> None:
        """Use another display calibration (cameras and native image follow)."""
        self.calibration = calibration

    # ---------------------------------------------------------------- cache core
    def _read(self, path: str) -> Any:
        """The value of one ``reads`` entry of the stage table, as fingerprinted."""
        if path in ("model", "avatar"):
            return id(getattr(self, path))
        if path == "au_map":
            return self._au_map_version
        if path == "calibration":
            return _calib_fingerprint(self.calibration)
        if path == "calibration.layout":
            return quilt_layout(self.calibration)
        if path == "face.shape":  # trailing zero coefficients do not change the head: (0, 0) frames like ()
            return np.trim_zeros(self.face.shape, "b")
        obj: Any = self
        for part in path.split("."):
            obj = getattr(obj, part)
        return obj

    def _stage(self, stage: str) -> Stage:
        try:
            return _STAGE[stage]
        except KeyError:
            raise InputError(f"stage: expected one of {STAGES}, found {stage!r}") from None

    def _get(self, stage: str, timings: StageTimings) -> _Entry:
        row = self._stage(stage)
        dep_entries = [self._get(d, timings) for d in row.deps]
        key = _fingerprint(([self._read(r) for r in row.reads], [e.version for e in dep_entries]))
        cached = self._cache.get(stage)
        if cached is not None and cached.key == key:
            return cached
        t0 = time.perf_counter()
        value = getattr(self, f"_compute_{stage}")(*[e.value for e in dep_entries])
        dt = time.perf_counter() - t0
        setattr(timings, stage, (getattr(timings, stage) or 0.0) + dt)
        self._versions += 1
        entry = _Entry(key, value, self._versions)
        self._cache[stage] = entry
        self.recompute_log.append((self._request, stage))
        return entry

    def compute(self, *stages: str) -> tuple[list[Any], StageTimings]:
        """Bring ``stages`` up to date; return their values and this request's timings."""
        self._request += 1
        timings = StageTimings()
        values = [self._get(s, timings).value for s in stages]
        self._timings = timings
        return values, timings

    def get(self, stage: str) -> Any:
        """The up-to-date value of one stage (see :data:`STAGES`)."""
        return self.compute(stage)[0][0]

    def stage_version(self, stage: str) -> int | None:
        """Version number of the cached value of ``stage`` (None = never computed)."""
        e = self._cache.get(stage)
        return None if e is None else e.version

    @property
    def last_timings(self) -> StageTimings:
        """Timings of the latest request."""
        return self._timings

    def recomputed_in_last_request(self) -> list[str]:
        """Stages computed by the latest request, in order."""
        return [s for r, s in self.recompute_log if r == self._request]

    def clear_cache(self) -> None:
        self._cache.clear()

    # ---------------------------------------------------------------- conveniences
    def flame_params(self) -> dict[str, np.ndarray]:
        """FLAME parameters of the current face (``shape``, ``expr``, ``jaw_pose``, ...)."""
        return self.get("params")

    def mesh(self) -> np.ndarray:
        """(V, 3) posed vertices (float64, metres)."""
        return self.get("mesh")

    def gaussians(self) -> "Gaussians":
        """World Gaussians of the current face."""
        return self.get("gaussians")

    def cameras(self) -> "Cameras":
        """The quilt's cameras, view 0 leftmost."""
        return self.get("cameras")

    def views(self) -> np.ndarray:
        """(n_views, H, W, 3) float32 views."""
        return self.get("views")

    def quilt(self) -> np.ndarray:
        """(rows*H, cols*W, 3) uint8 quilt."""
        return self.get("quilt")

    def native(self) -> np.ndarray:
        """(screenH, screenW, 3) uint8 native image."""
        return self.get("native")

    def render_view(self, index: int, cameras: "Cameras | None" = None) -> np.ndarray:
        """Render one view (H, W, 3) of the current Gaussians without touching the quilt cache.

        Used for the GUI preview: 1/48 of the quilt's work. ``cameras`` overrides the
        pipeline's cameras (e.g. a different tile size).
        """
        (g, cams), timings = self.compute("gaussians", "cameras") if cameras is None else \
            ((self.get("gaussians"), cameras), self._timings)
        if not 0 <= index < len(cams):
            raise InputError(f"view index: expected 0..{len(cams) - 1}, found {index}")
        t0 = time.perf_counter()
        img = render_images(g, cams[int(index)], backend=self.backend, config=self.render_config)[0]
        timings.views = (timings.views or 0.0) + time.perf_counter() - t0
        return img

    # ---------------------------------------------------------------- stage bodies
    def _compute_params(self) -> dict[str, np.ndarray]:
        f = self.face
        n_expr, n_shape = int(self.model.n_expr), int(self.model.n_shape)
        if f.expr.shape[0] > n_expr:
            raise InputError(f"expr: expected at most {n_expr} coefficients (the model's n_expr), "
                             f"found {f.expr.shape[0]}")
        if f.shape.shape[0] > n_shape:
            raise InputError(f"shape: expected at most {n_shape} coefficients (the model's n_shape), "
                             f"found {f.shape.shape[0]}")
        expr = np.zeros(n_expr)
        expr[: f.expr.shape[0]] = f.expr
        jaw = f.jaw_pose.copy()
        if f.named or f.pain > 0:
            from ..flame.expressions import jaw_for_expression, named_expression, pain_expression
        for name, w in f.named:
            if w > 0:
                expr += np.asarray(named_expression(name, w, self.au_map), dtype=np.float64)[:n_expr]
                jaw += np.asarray(jaw_for_expression(name, w), dtype=np.float64)
        if f.pain > 0:
            expr += np.asarray(pain_expression(f.pain, self.au_map), dtype=np.float64)[:n_expr]
        shape = np.zeros(n_shape)
        # an empty or all-zero shape means "the avatar's identity" (GaussianAvatars' flame_param shape)
        src = f.shape if np.any(f.shape) or "shape" not in self.identity else self.identity["shape"].reshape(-1)
        shape[: min(n_shape, src.shape[0])] = src[:n_shape]
        out = {"shape": shape, "expr": expr, "jaw_pose": jaw, "rotation": f.rotation.copy(),
                "neck_pose": f.neck_pose.copy(), "eyes_pose": f.eyes_pose.copy(),
                "translation": f.translation.copy()}
        offset = self.identity.get("static_offset")
        if f.dynamic_offset is not None:
            offset = f.dynamic_offset if offset is None else offset.reshape(f.dynamic_offset.shape) + f.dynamic_offset
        if offset is not None:
            out["static_offset"] = np.asarray(offset).reshape(-1, 3)
        return out

    def _flame_vertices(self, params: Mapping[str, np.ndarray]) -> np.ndarray:
        import torch

        dt = self.model.dtype
        kw = {k: torch.as_tensor(np.asarray(v)[None], dtype=dt) for k, v in params.items()}
        # one frame of LBS is ~1 ms single-threaded; torch's thread pool costs 50 ms on a busy CPU
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            with torch.no_grad():
                out = self.model(**kw)
        finally:
            torch.set_num_threads(threads)
        return out.vertices[0].detach().cpu().numpy().astype(np.float64)

    def _compute_mesh(self, params: Mapping[str, np.ndarray]) -> np.ndarray:
        return self._flame_vertices(params)

    def _compute_gaussians(self, vertices: np.ndarray, params: Mapping[str, np.ndarray]) -> "Gaussians":
        if self._avatar is None:
            raise InputError("gaussians: this pipeline has no avatar (avatar=False)")
        return self._avatar.gaussians(vertices, params)

    def _compute_framing(self) -> tuple[np.ndarray, float]:
        neutral = {"shape": self._compute_params()["shape"]}
        if "static_offset" in self.identity:
            neutral["static_offset"] = self.identity["static_offset"].reshape(-1, 3)
        return frame_head(self._flame_vertices(neutral), self.view.framing_margin)

    def _compute_cameras(self, framing: tuple[np.ndarray, float]) -> "Cameras":
        from ..display.cameras import make_quilt_cameras

        centre, half = framing
        v, cal = self.view, self.calibration
        tw, th = cal.tile_width, cal.tile_height
        if v.tile_scale != 1.0:
            tw, th = max(8, round(tw * v.tile_scale)), max(8, round(th * v.tile_scale))
        return make_quilt_cameras(cal, focal_center=centre, size=half, view_cone_deg=v.view_cone,
                                  viewer_angle_deg=v.viewer_angle, viewer_distance=v.viewer_distance,
                                  tile_width=tw, tile_height=th, near=0.01, far=10.0)

    def _compute_views(self, gaussians: "Gaussians", cameras: "Cameras") -> np.ndarray:
        return render_images(gaussians, cameras, backend=self.backend, config=self.render_config)

    def _compute_quilt(self, views: np.ndarray) -> np.ndarray:
        return tile_views(views, *quilt_layout(self.calibration))

    def _compute_native(self, quilt: np.ndarray) -> np.ndarray:
        from ..display.native import views_to_native
        from ..display.lenticular import Interleaver

        cols, rows = quilt_layout(self.calibration)
        key = _fingerprint((_calib_fingerprint(self.calibration), quilt.shape, cols, rows, self.view.blend))
        if self._interleaver is None or self._interleaver_key != key:
            self._interleaver = Interleaver(self.calibration, quilt.shape, cols=cols, rows=rows,
                                            mode="blend" if self.view.blend else "nearest")
            self._interleaver_key = key
        return views_to_native(None, self._interleaver, quilt=quilt).native

    # ---------------------------------------------------------------- streaming
    def stream(self, frames: Iterable[FlameFrame], *, fps: float = 25.0, output: str = "quilt",
               policy: Literal["drop", "all"] = "drop", sink: Callable[[FrameResult], None] | None = None,
               base: FaceControls | None = None, clock: Callable[[], float] = time.perf_counter,
               progress: bool = False) -> StreamReport:
        """Play a FLAME sequence through the pipeline with a frame budget of ``1/fps`` seconds.

        Parameters
        ----------
        frames : iterable of mapping
            Per-frame FLAME parameters with keys of :data:`FLAME_KEYS` (plus ``shape``, ``pain``;
            missing keys keep the ``base`` controls' values); see :func:`flame_sequence_frames`.
        fps : float
            Playback rate; frame ``k`` is due at ``start + (k + 1) / fps``.
        output : str
            The last stage computed per frame (``"mesh"``, ``"gaussians"``, ``"views"``,
            ``"quilt"`` or ``"native"``).
        policy : {"drop", "all"}
            ``"drop"`` (live display): after a late frame, skip the frames whose display slot
            has already passed; the last computed frame is held in their slots. ``"all"``
            (export): compute every frame; late frames are counted, and the slots they overran
            are counted as held.
        sink : callable or None
            Called with a :class:`FrameResult` for every computed frame (a display, a writer).
        base : FaceControls or None
            Controls that the frames override (default: the current ones; restored at the end).
        clock : callable
            Seconds; injectable for tests.

        Returns
        -------
        StreamReport
        """
        report = StreamReport(n_frames=0, budget=0.0, policy=policy)
        for res in self.iter_stream(frames, fps=fps, output=output, policy=policy, base=base, clock=clock,
                                    report=report, progress=progress):
            if sink is not None:
                sink(res)
        return report

    def iter_stream(self, frames: Iterable[FlameFrame], *, fps: float = 25.0, output: str = "quilt",
                    policy: Literal["drop", "all"] = "drop", base: FaceControls | None = None,
                    clock: Callable[[], float] = time.perf_counter, report: StreamReport | None = None,
                    progress: bool = False) -> Iterator[FrameResult]:
        """Generator form of :meth:`stream`: yields each computed :class:`FrameResult` and fills
        ``report`` (pass your own to read it afterwards). The time the consumer spends between
        frames counts against the budget, as a display or encoder would."""
        fps = check_finite_scalar(fps, "fps", low=0.0, low_open=True)
        if policy not in ("drop", "all"):
            raise InputError(f"policy: expected 'drop' or 'all', found {policy!r}")
        if output not in STREAM_OUTPUTS:
            raise InputError(f"output: expected one of {', '.join(STREAM_OUTPUTS)}, found {output!r}")
        frames = list(frames)
        budget = 1.0 / fps
        if report is None:
            report = StreamReport(n_frames=0, budget=budget, policy=policy)
        report.n_frames, report.budget, report.policy = len(frames), budget, policy
        base = base or self.face
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(frames), desc=f"stream {output}", unit="frame")
        start = clock()
        k = 0
        try:
            while k < len(frames):
                t0 = clock()
                self.face = apply_frame(base, frames[k], k)
                (value,), timings = self.compute(output)
                res = FrameResult(index=k, timings=timings)
                if output in ("quilt", "native", "views"):
                    setattr(res, output, value)
                yield res
                t1 = clock()
                report.rendered.append(k)
                report.frame_seconds.append(t1 - t0)
                report.stage_seconds.add(timings)
                deadline = start + (k + 1) * budget
                nxt = k + 1
                if t1 > deadline + 1e-12:
                    report.late.append(k)
                    slot = min(int(math.floor((t1 - start) / budget)), len(frames))  # slot showing now
                    if policy == "drop":
                        nxt = max(k + 1, slot)
                        report.dropped.extend(range(k + 1, nxt))
                    report.held += max(0, slot - (k + 1))
                if bar is not None:
                    bar.update(nxt - k)
                k = nxt
        finally:
            if bar is not None:
                bar.close()
            self.face = base


# =============================================================================== helpers


def default_calibration() -> "DisplayCalibration":
    """The fixture-style Looking Glass Portrait calibration shipped in ``assets/``."""
    from ..display.calibration import DisplayCalibration

    return DisplayCalibration.load(None)


def _calib_fingerprint(calib: Any) -> str:
    if dataclasses.is_dataclass(calib):
        return _fingerprint(calib)
    return f"id{id(calib)}"


def quilt_layout(calib: "DisplayCalibration") -> tuple[int, int]:
    """(cols, rows) of the calibration's quilt."""
    return int(calib.cols), int(calib.rows)
