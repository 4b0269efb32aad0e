"""Live native frame rate by mode, against full quality (issue 16).

Default avatar (Pipeline defaults, 100k Gaussians), Portrait calibration, 48 views 420x560. A
short animation (smile and jaw changing every frame) is deformed first; the timed part of every
frame is **deformed Gaussians -> native image** (``NativeFrameRenderer.frame``). All from one run:

* ``full_quilt``: every view in full, uint8 quilt, interleave (the quality reference). Its views
  are also compared with the float64 reference renderer on ``--ref-views`` views (PSNR).
* ``all_views``: untracked, every view; one record per level of detail (``lod_fraction``), one
  with the renderer's error-for-blends knobs (``render_knobs``: ``t_min`` 0.01,
  ``alpha_threshold`` 2/255, every Gaussian kept), and one per ``view_step`` (every step-th view
  rendered, the others synthesized by a depth-compensated warp; 5 is the live default).
  ``psnr_db``: native image against full_quilt's, over the head region; the ``view_step``
  records add ``worst_sweep_psnr_db``, the worse eye over viewers at -12..12 degrees and
  0.45-0.9 m (last frame).
* ``tracked``: a viewer at 0.6 m moving sideways across the cone; one record per method
  (``slices``: one crossed-slit image per eye warped into the received subpixels, the default;
  ``bands``: the exact view bands) and head motion margin (``defaults``: the method's own,
  ``pipeline.live.TRACKED_DEFAULTS``). ``psnr_db``: the worse eye's perceived image (VirtualDisplay) against full_quilt's
  at the tracked position, head region, over the frames; ``worst_sweep_psnr_db``: the worst over
  a sweep of eye positions (last frame): sideways +-1 and +-2 cm (+-1 cm with --quick) and +-5 cm
  in depth, whatever the margin, so the records show what the margin buys (``sweep_psnr_db``:
  each offset's). The first tracked frame
  (everything) and the slices' one-off tables are not timed.
* ``tracked`` with ``cone_edge``: the default method and margins for a viewer standing at 15 and
  19 degrees (17 with --quick), 0.6 m, where an eye receives the next lobe's views through part of
  the panel; ``psnr_db`` of the last frame.
* ``eye_centred``: the same viewer path; one perspective image per eye (camera interpolated between
  the quilt cameras) written into the subpixels that eye receives. ``psnr_db`` as ``tracked``.
* ``vtk``: the VTK point-Gaussian pass after a warm-up. Default: the whole pass (every view in one
  ``render_views`` call, as an export renders a quilt), twice (once with ``--quick``), each
  between two full quilts (``paired_ratios``: its time / their mean, which a change of the
  machine's load between the full_quilt record and this one does not move). With
  ``--vtk-views N`` (N < 48): N views
  spread over the cone, one call each, extrapolated to 48 (``extrapolated``: true; a call per view
  costs ~20 % more than the whole pass, measured), each paired with the full quilt timed right
  after it. ``psnr_db``: the worst of views 8, 24, 40 (or the timed ones) against full_quilt's
  views; ``ratio_to_views_only``: against the full quilt's 48 float views alone (``full_quilt``'s
  ``views_seconds_per_frame``: VTK's time too is views only, no uint8 quilt and no interleave).
* ``--device cuda``: ``all_views`` with gsplat (one batched call, ``viewmats`` [48, 4, 4]) and
  the quilt + interleave as one torch gather on the GPU (``backend``: gsplat), and the same with
  view synthesis on the device (``view_step`` 3 and 5), each also with the Gaussians already on the
  GPU, and ``gpu_stages``: each stage of a GPU frame timed alone (validate, upload, gsplat for 48
  views and for the 11 sources, the synthesis of the other 37, the interleave
  gather, the download into pageable and page-locked memory); skipped, and said so, without CUDA.
  ``--gpu-only`` runs only the full-quality reference on the CPU before them (a lent GPU's time
  is short).

``--kernels-ab`` (alone): live-sized group frames (``holo-viewer live``'s renderer: tile scale 0.5, the per-view
visible mask, no face, a changing expression) with the float32 warp and the interleave's row gather in numba
against the C++ kernels (since 2026-11-29 06:00 the default's C++ warp straight into the native image; the same
bytes: asserted), rounds alternating in one process; CPU ms per frame
(``bench/results/live_frame_kernels_ab.json``).

``--live-scales [S,...]`` (alone): the default group frame at each tile scale as ``holo-viewer live --tile-scale S``
renders it (its per-view visible mask; ``SXxSY``: width and height scaled apart, not a live option), CPU a frame and
the cone / eye PSNR against the present full-quality frame (and a tile-scale-2.0 full quilt, ``--live-fine``);
``--live-pair PNG``: a bystander's eye image at tile scale 1.0 and 0.5 (``bench/results/live_frame_scales.json``).

Wall clock on a shared machine: the load average (1 min) before and after is recorded with the
CPU seconds of every mode; compare ratios from one run.

Usage::

    python bench/live_frame.py [--quick] [--device cpu|cuda [--gpu-only]] [--json bench/results/live_frame.json]
    python bench/live_frame.py --group-only [--quick]     python bench/live_frame.py --kernels-ab
    python bench/live_frame.py --live-scales 0.5,0.75,1.0,0.75x1.0 [--live-pair docs/images/live_tile_scale_pair.png]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from holo_viewer.display import eyes  # noqa: E402
from holo_viewer.display.calibration import DisplayCalibration  # noqa: E402
from holo_viewer.display.simulate import VirtualDisplay  # noqa: E402
from holo_viewer.errors import HoloViewerError  # noqa: E402
from holo_viewer.fileio import atomic_write  # noqa: E402
from holo_viewer.pipeline.live import NativeFrameConfig, NativeFrameRenderer  # noqa: E402
from holo_viewer.pipeline import Pipeline  # noqa: E402
from holo_viewer.pipeline import FaceControls  # noqa: E402
from holo_viewer.render import RenderConfig, render_views  # noqa: E402
from holo_viewer.render import view_synthesis  # noqa: E402
from holo_viewer.render.api import validate_inputs  # noqa: E402
from scenes import cpu_model  # noqa: E402  (bench/ is the script's own folder)


def frames_of_animation(pipe: Pipeline, n: int, params: list | None = None) -> list:
    """n deformed Gaussians of a smile + jaw animation (deformation not timed); their FLAME
    parameters are appended to ``params`` when given."""
    out = []
    for k in range(n):
        s = 0.5 + 0.5 * math.sin(2 * math.pi * k / max(n, 2))
        pipe.set_face(FaceControls(named=(("smile", s),), jaw_pose=np.array([0.15 * (1 - s), 0.0, 0.0])))
        out.append(pipe.gaussians())
        if params is not None:
            params.append(pipe.flame_params())
    return out


def deformer_on(device: str):
    """FLAME parameters -> the default avatar's Gaussians, with LBS and the triangle binding run on
    ``device`` (the Gaussians stay there): what a live frame costs when nothing crosses to the host."""
    import torch

    from holo_viewer.avatar.default_gaussians import default_avatar
    from holo_viewer.avatar.rigged import RiggedAvatar
    from holo_viewer.flame.default_head import load_default_model

    host = default_avatar()
    model = load_default_model(add_teeth=True, device=device)
    avatar = RiggedAvatar(model, host.local, binding=host.binding)

    def deform(params: dict):
        kw = {k: torch.as_tensor(np.asarray(v)[None], dtype=model.dtype, device=device) for k, v in params.items()}
        with torch.no_grad():
            return avatar.deform(model(**kw).vertices[0])

    return deform


def gpu_stages(live: NativeFrameRenderer, synth: NativeFrameRenderer, frames: list, reps: int = 20, device: str = "cuda") -> dict:
    """Where a GPU frame's time goes: each stage alone, synchronised before and after, median of
    ``reps`` (ms). The stages overlap nothing here, so their sum is above a frame's own time."""
    import torch

    from holo_viewer.render import gsplat_backend, view_synthesis

    cfg = live.config.render

    def sync() -> None:
        if device == "cuda":
            torch.cuda.synchronize()

    def ms(fn) -> float | str:
        try:
            fn(0)  # warm (and a stage the device refuses is recorded as such)
        except Exception as exc:  # noqa: BLE001 - a profile only
            return f"{type(exc).__name__}: {exc}"
        out = []
        for k in range(reps):
            sync()
            t0 = time.perf_counter()
            fn(k)
            sync()
            out.append((time.perf_counter() - t0) * 1000.0)
        return float(np.median(out))

    host = [frames[1 + k % (len(frames) - 1)] for k in range(reps)]
    dev = [g.torch(device=device, dtype=torch.float32) for g in host[:2]]
    views = gsplat_backend.render_device(dev[0], live.cameras, cfg)
    src_imgs = gsplat_backend.render_device(dev[0], synth._source_cams, cfg)
    res = live._device(views, to_host=False)
    pageable = np.empty(res.shape, dtype=np.uint8)
    st: dict[str, float | str] = {}  # ms, or why the stage failed
    st["validate"] = ms(lambda k: validate_inputs(host[k], live.cameras))
    st["upload"] = ms(lambda k: host[k].torch(device=device, dtype=torch.float32))
    st["rasterize_48"] = ms(lambda k: gsplat_backend.render_device(dev[k % 2], live.cameras, cfg))
    st["rasterize_11"] = ms(lambda k: gsplat_backend.render_device(dev[k % 2], synth._source_cams, cfg))

    def synthesize(k: int) -> None:
        g = dev[k % 2]
        w = view_synthesis.inverse_depth_torch(g.means, torch.sigmoid(g.opacity_logits), synth.cameras,
                                               synth._sources, rig=synth._rig)
        view_synthesis.warp_views_torch(src_imgs, w, synth._sources, synth._rig)
    st["synthesize_37"] = ms(synthesize)
    st["interleave_gather"] = ms(lambda k: live._device(views, to_host=False))
    st["download_pageable"] = ms(lambda k: torch.from_numpy(pageable).copy_(res))
    st["download_pinned"] = ms(lambda k: torch.from_numpy(live.native).copy_(res))
    return {"mode": "gpu_stages", "device": torch.cuda.get_device_name(0) if device == "cuda" else device,
            "ms": st, "reps": reps, "native_pinned": live._native_owner is not None,
            "note": "each stage alone between synchronisations, median ms"}


class _GroupOnly(Exception):
    """--group-only: the group sweep's records, past the other modes."""

    def __init__(self, records: list) -> None:
        super().__init__("group only")
        self.records = records


def load() -> float:
    return os.getloadavg()[0]


#: the group sweep's face: a pain flare (fast onset, hold, easing) with a nod, one level per frame
FLARE_PAIN = (0.0, 0.9, 0.9, 0.6, 0.3, 0.0)
FLARE_NOD = (0.0, 0.12, 0.05, -0.08, 0.0, 0.0)
#: the tracked viewers of the group sweep (angle deg, distance m): 1 = the first, 4 = all
GROUP_VIEWERS = ((6.0, 0.6), (-15.0, 0.5), (-4.0, 0.75), (16.0, 0.9))
#: the group sweep's runs: (mode, tracked viewers, NativeFrameConfig knobs); the defaults first, then
#: the time-error trade-off of the group frames' cone fill (group_view_step; the default is 6), of the
#: viewers served with eye slices (group_slices; the default is 0: every viewer sees the fill), and the
#: eye slices replacing the fill instead of feathered into it (group_feather None: comfort); group and
#: all_views rows skip the Gaussians nobody sees (live_support.visible_mask), each rendered source view only those
#: seen in that view (per_view=True, since 2026-11-28 19:00), except "union_keep" (every source view draws the
#: union over the views, as `holo-viewer live` did until then), "all_gaussians" (every Gaussian drawn, as before
#: 2026-11-28 16:00), "quilt_warp" (the warp into the quilt, then the interleave, as before 2026-11-29 06:00; the
#: default's warp straight into the native image writes the same bytes) and the last ("numba_kernels": the float32
#: warp and the interleave's row gather in numba, as before 2026-11-28 21:50; the C++ kernels write the same bytes)
GROUP_RUNS = (("group", 0, {}), ("group", 1, {}), ("group", 4, {}), ("tracked", 1, {}), ("tracked", 4, {}),
              ("all_views", 0, {}), ("group", 0, {"group_view_step": 5}), ("group", 0, {"group_view_step": 8}),
              ("group", 1, {"group_view_step": 5}), ("group", 1, {"group_view_step": 8}),
              ("group", 1, {"group_view_step": 12}), ("group", 1, {"group_slices": 1}),
              ("group", 4, {"group_slices": 1}), ("group", 4, {"group_slices": 4}),
              ("group", 1, {"group_slices": 1, "group_feather": None}), ("group", 0, {"union_keep": True}),
              ("group", 0, {"all_gaussians": True}), ("group", 0, {"quilt_warp": True}),
              ("group", 0, {"numba_kernels": True}))
#: passes over the flare of each default group row, the rows taking turns (2 with --quick)
GROUP_ROUNDS = 4
#: comfort: a tracked viewer walks past fixed single-eye positions (deg, m), 1.5 deg a frame, face still
COMFORT_POSITIONS = ((0.0, 0.6), (-3.0, 0.6))
COMFORT_WALK_DEG = tuple(float(a) for a in np.arange(-6.0, 4.6, 1.5))


def comfort(live: NativeFrameRenderer, still, cone) -> dict:
    """Issue 37's visual comfort, with the face still (``still``: one frame's Gaussians): the worst
    PSNR between consecutive group frames seen at the fixed positions of ``cone``, with no viewer
    (``comfort_still_db``, None when the frames are identical) and while a tracked viewer walks past
    (``comfort_walk_db``)."""
    from holo_viewer.display.eyes import TrackedViewer

    def worst(natives: list) -> float | None:
        dbs = [float(cone.psnr(a, b).min()) for a, b in zip(natives, natives[1:]) if not np.array_equal(a, b)]
        return min(dbs) if dbs else None

    still_frames = [live.frame(still, None, "group").native.copy() for _ in range(2)]
    walk = [live.frame(still, TrackedViewer(a, 0.6), "group").native.copy() for a in COMFORT_WALK_DEG]
    return {"comfort_still_db": worst(still_frames), "comfort_walk_db": worst(walk),
            "comfort_positions": [list(p) for p in COMFORT_POSITIONS], "comfort_walk_deg": list(COMFORT_WALK_DEG)}


def flare_frames(pipe: Pipeline, pain=FLARE_PAIN, nod=FLARE_NOD) -> list:
    """Deformed Gaussians of a neutral face (primes the kept state), then one per ``pain`` / ``nod``
    (head pitch, radians) level: the face changes between every two frames."""
    out = []
    for p, n in zip((0.0,) + tuple(pain), (0.0,) + tuple(nod)):
        pipe.set_face(FaceControls(pain=float(p), rotation=np.array([float(n), 0.0, 0.0])))
        out.append(pipe.gaussians())
    return out


def group_sweep(cal: DisplayCalibration, pipe: Pipeline, quick: bool = False, sheet: str | None = None) -> list[dict]:
    """Issue 37: every live mode judged where a group stands. A pain flare with a nod
    (:func:`flare_frames`) is played through each mode with 0, 1 and 4 tracked viewers; each frame
    is compared with the *present* frame's full quilt, at every position of
    :class:`~holo_viewer.display.eyes.ConeSweep` (single eyes at -20..20 deg x 0.4, 1.0 m) and at the
    tracked viewers' eyes. Records: ``mode``, ``viewers``, ``seconds_per_frame`` (median),
    ``tracked_eye_db`` (worst tracked eye, frames evaluated), ``cone_worst_db``, ``cone_median_db``.
    ``tracked`` serves the first viewer only (the old default collapsed the faces to the nearest).
    ``sheet``: a picture (PNG, or JPEG by its suffix) of what the tracked viewer's left eye and bystanders at 0, -15, +15 deg (0.6 m)
    see at three moments of the flare, for ``tracked`` (rows 1-3) and ``group`` (rows 4-6).
    :data:`GROUP_RUNS` also holds the time-error trade-off of the cone fill (``group_view_step``;
    records with ``default`` false, ``knobs`` naming the change), every record
    has ``cpu_seconds_per_frame`` (process CPU, both cores) beside the wall time, and the ``group``
    records with 0 or 1 viewer add :func:`comfort`'s ``comfort_still_db`` / ``comfort_walk_db``.
    Timing: every renderer is primed (frame 0, ``prime_seconds``: the first frame and the one-off tables) and,
    unless its frames update the last one (``tracked``), warmed by one untimed pass over the flare
    (``warmup_seconds`` / ``warmup_cpu_seconds``, each frame's), so every row is timed in the same steady state;
    the default ``group`` rows (0, 1, 4 viewers: the targets) are timed interleaved, :data:`GROUP_ROUNDS` passes
    each in turn (``timing``, ``round_seconds``: each pass's median; ``frames_timed``), so that none is measured
    first; the others one pass each."""
    from holo_viewer.display.eyes import ConeSweep, TrackedViewer

    from holo_viewer.pipeline.live_support import visible_mask

    cams = pipe.cameras()
    t0, c0 = time.perf_counter(), time.process_time()
    keep_views = visible_mask(pipe, per_view=True)  # what live frames skip (cached on disk after the first run)
    keep = keep_views.any(axis=0)
    per_view = keep_views.sum(axis=1)
    print(f"visible Gaussians: {int(keep.sum())} of {keep.size}, per view {int(per_view.min())}-{int(per_view.max())} "
          f"({time.perf_counter() - t0:.1f} s, CPU {time.process_time() - c0:.1f} s)", flush=True)
    frames = flare_frames(pipe)
    display = VirtualDisplay(cal)
    full = NativeFrameRenderer(cal, cams)
    refs = [full.frame(g, mode="full_quilt").native.copy() for g in frames]
    evaluated = [2, 4] if quick else [2, 3, 4, 6]  # onset, hold, easing, end (frame 0 primes, 1 is still neutral)
    t0 = time.perf_counter()
    cone = ConeSweep(display)
    print(f"group sweep: {len(cone.positions)} cone positions ({time.perf_counter() - t0:.1f} s to build), "
          f"frames {evaluated} of {len(frames) - 1}, load {load():.2f}", flush=True)
    ref_seen = {k: [cone.see(refs[k], i) for i in range(len(cone.positions))] for k in evaluated}
    all_viewers = [TrackedViewer(a, d) for a, d in GROUP_VIEWERS]
    fixed = ConeSweep(display, COMFORT_POSITIONS)
    records, shown = [], {}
    moments = (1, 2, 4)  # before, onset, easing
    # warm-up, untimed: numba dispatch, the C++ kernels' first calls, the allocator's first large blocks
    warm = NativeFrameRenderer(cal, cams, keep=keep_views)
    for k in range(len(frames)):
        warm.frame(frames[k], all_viewers[:1] or None, "group")
    del warm

    def build(mode: str, n: int, knobs: dict) -> tuple:
        """The run's renderer, primed (frame 0: everything, timed as ``prime_seconds``) and, for frames that
        redraw everything, warmed by one untimed pass over the flare (each frame's wall and CPU kept): every
        row is then timed in the same steady state, after the same warm-up."""
        viewers = all_viewers[:n]
        config = {k: v for k, v in knobs.items()
                  if k not in ("all_gaussians", "union_keep", "numba_kernels", "quilt_warp")}
        live = NativeFrameRenderer(cal, cams, NativeFrameConfig(**config),  # all_gaussians: every one, as before
                                   keep=None if knobs.get("all_gaussians") else keep if knobs.get("union_keep")
                                   else keep_views)
        arg = (viewers[0] if viewers else None) if mode == "tracked" else (viewers or None)
        kernels(knobs, live)
        t0 = time.perf_counter()
        live.frame(frames[0], arg, mode)  # everything once (the kept state of incremental modes)
        live.prepare_tracked()
        live.prepare_all_views()
        warmup = {"prime_seconds": time.perf_counter() - t0, "warmup_seconds": [], "warmup_cpu_seconds": []}
        if mode != "tracked":  # tracked frames update the last one: their kept state stays frame 0's
            for k in range(1, len(frames)):
                c0 = time.process_time()
                f = live.frame(frames[k], arg, mode)
                warmup["warmup_cpu_seconds"].append(time.process_time() - c0)
                warmup["warmup_seconds"].append(f.seconds)
        return live, arg, viewers, warmup

    def kernels(knobs: dict, live: NativeFrameRenderer) -> None:
        numba_kernels = bool(knobs.get("numba_kernels"))  # the A/B of the compiled warp and row gather
        view_synthesis.WARP_KERNEL = "numba" if numba_kernels else "auto"
        live.interleaver.row_kernel = "numba" if numba_kernels else "auto"
        # quilt_warp (and the numba pair): the warp into the quilt, then the interleave (the same bytes as the
        # default's warp straight into the native image)
        live.warp_native = not (numba_kernels or knobs.get("quilt_warp"))

    def timed_pass(live: NativeFrameRenderer, arg, mode: str, acc: dict) -> None:
        """One timed pass over the flare (frames 1..): wall, CPU, load, and the frames evaluated or shown."""
        for k in range(1, len(frames)):
            c0 = time.process_time()
            f = live.frame(frames[k], arg, mode)
            acc["cpus"].append(time.process_time() - c0)
            acc["secs"].append(f.seconds)
            acc["loads"].append(load())
            if k in evaluated or k in moments:
                acc["natives"][k] = f.native.copy()

    # the default group rows (0, 1, 4 viewers: the targets) are timed interleaved, GROUP_ROUNDS passes each in
    # turn, so no row is measured first: in the 2026-11-29 runs the first row (0 faces) cost ~0.03 s more CPU a
    # frame than the second, the same work; the other runs once each, after the same warm-up
    rounds = 2 if quick else GROUP_ROUNDS
    together = [r for r in GROUP_RUNS if r[0] == "group" and not r[2]]
    built = {id(r): build(*r) for r in together}
    timed = {id(r): {"secs": [], "cpus": [], "loads": [], "natives": {}, "round_seconds": []} for r in together}
    for _ in range(rounds):
        for r in together:
            live, arg, _, _ = built[id(r)]
            kernels(r[2], live)
            acc = timed[id(r)]
            n0 = len(acc["secs"])
            timed_pass(live, arg, r[0], acc)
            acc["round_seconds"].append(float(np.median(acc["secs"][n0:])))
    for run in GROUP_RUNS:
        mode, n, knobs = run
        key = next((id(r) for r in together if r is run), None)
        if key is not None:
            live, arg, viewers, warmup = built.pop(key)
            acc = timed.pop(key)
            kernels(knobs, live)
        else:
            live, arg, viewers, warmup = build(mode, n, knobs)
            acc = {"secs": [], "cpus": [], "loads": [], "natives": {}, "round_seconds": []}
            timed_pass(live, arg, mode, acc)
        secs, cpus, natives, loads = acc["secs"], acc["cpus"], acc["natives"], acc["loads"]
        cone_db = np.array([[eyes.head_psnr(ref_seen[k][i], cone.see(natives[k], i)) for i in range(len(cone.positions))]
                            for k in evaluated])
        eye_db = min((eyes.eye_psnr(display, refs[k], natives[k], v) for k in evaluated for v in viewers),
                     default=None)
        worst = cone_db.min(axis=0)
        s = float(np.median(secs))
        served = 1 if mode == "tracked" else min(n, live.config.group_slices) if mode == "group" else 0
        rec = {"mode": mode, "viewers": n, "served": served,
               "view_step": live.view_step, "group_view_step": live.group_view_step,
               "default": not knobs, "knobs": knobs,
               "gaussians_drawn": int(keep.sum()) if mode != "tracked" and not knobs.get("all_gaussians")
               else len(frames[0]),
               "per_view_keep": mode != "tracked" and not knobs.get("all_gaussians") and not knobs.get("union_keep"),
               "seconds_per_frame": s, "best_seconds": float(min(secs)),
               "cpu_seconds_per_frame": float(np.median(cpus)),
               "timing": (f"interleaved with the other default group rows, {rounds} rounds" if key is not None
                          else "one pass"), "frames_timed": len(secs),
               "round_seconds": acc["round_seconds"] or None, **warmup,
               "tracked_eye_db": eye_db, "cone_worst_db": float(worst.min()),
               "cone_median_db": float(np.median(cone_db)),
               "cone_worst_position": cone.positions[int(np.argmin(worst))],
               "cone_worst_by_position_db": {f"{a:+.0f} deg {d:.1f} m": float(w)
                                             for (a, d), w in zip(cone.positions, worst)},
               "load_1min": float(np.mean(loads)), "frames_evaluated": evaluated,
               "face": "pain flare " + "/".join(f"{p:g}" for p in FLARE_PAIN) + " with a nod",
               "viewer_positions": [list(v) for v in GROUP_VIEWERS[:n]]}
        if mode == "group" and n <= 1:
            rec.update(comfort(live, frames[0], fixed))
        view_synthesis.WARP_KERNEL = "auto"
        records.append(rec)
        step = live.group_view_step if mode == "group" else live.view_step
        print(f"{mode:9s} viewers {n} step {step:2d}{f' {knobs}' if knobs else ' (default)'}  {s:.3f} s/frame "
              f"(best {min(secs):.3f}, CPU {np.median(cpus):.3f} s)  tracked eyes "
              f"{'-' if eye_db is None else f'{eye_db:.1f}'} dB  cone worst {worst.min():.1f} dB "
              f"(at {cone.positions[int(np.argmin(worst))]}), median {np.median(cone_db):.1f} dB, "
              f"load {np.mean(loads):.2f}", flush=True)
        print(f"          warm-up: prime {warmup['prime_seconds']:.3f} s, then "
              + (", ".join(f"{x:.3f}" for x in warmup["warmup_seconds"]) or "none")
              + (f"; rounds {', '.join(f'{x:.3f}' for x in acc['round_seconds'])}" if acc["round_seconds"] else ""),
              flush=True)
        if "comfort_walk_db" in rec:
            walk = rec.get("comfort_walk_db")
            print(f"          comfort (face still): no viewer {rec['comfort_still_db']} dB, a viewer walking past "
                  f"{'-' if walk is None else f'{walk:.1f}'} dB", flush=True)
        if n == 1 and mode in ("tracked", "group") and not knobs:
            shown[mode] = {k: natives[k] for k in moments}
    if sheet and len(shown) == 2:
        write_sheet(sheet, display, shown, all_viewers[0], moments, refs)
        print(f"wrote {sheet}", flush=True)
    return records


def kernels_ab(rounds: int = 5, n_frames: int = 6) -> list[dict]:
    """``--kernels-ab``: CPU per live-sized group frame with the numba warp and row gather, then the C++ ones,
    ``rounds`` times alternating over the same ``n_frames`` deformed faces; every native image compared."""
    from holo_viewer.live.render import LiveAvatarRenderer

    r = LiveAvatarRenderer(tile_scale=0.5, visible_only=True, mode="auto")
    live = r._live
    n_expr = int(r.pipeline.model.n_expr)
    faces = [r.deform({"expr": 0.3 * np.sin(0.3 * i + np.arange(n_expr)),
                       "jaw_pose": np.array([0.1 * np.sin(0.2 * i), 0.0, 0.0])}, 0.2, ()) for i in range(n_frames)]
    for g in faces:  # warm-up, untimed
        live.frame(g, None, "auto")
    cpu: dict[str, list[float]] = {"numba": [], "cpp": []}
    first: dict[tuple[str, int], np.ndarray] = {}
    load0 = load()
    for rnd in range(rounds):
        for k in ("numba", "cpp"):
            view_synthesis.WARP_KERNEL = "numba" if k == "numba" else "auto"
            live.interleaver.row_kernel = "numba" if k == "numba" else "auto"
            live.warp_native = k == "cpp"  # the C++ side: the default, the warp straight into the native image
            for i, g in enumerate(faces):
                c0 = time.process_time()
                f = live.frame(g, None, "auto")
                cpu[k].append(time.process_time() - c0)
                if rnd == 0:
                    first[(k, i)] = f.native.copy()
    view_synthesis.WARP_KERNEL = "auto"
    same = all(np.array_equal(first[("numba", i)], first[("cpp", i)]) for i in range(n_frames))
    rec = {"mode": "group", "viewers": 0, "tile_scale": 0.5, "rounds": rounds, "frames": n_frames,
           "cpu_ms_per_frame_numba": 1e3 * float(np.median(cpu["numba"])),
           "cpu_ms_per_frame_cpp": 1e3 * float(np.median(cpu["cpp"])),
           "native_identical": same, "load_1min": [load0, load()]}
    print(f"live-size group frames, CPU ms a frame (median of {rounds} x {n_frames}): numba warp + row gather "
          f"{rec['cpu_ms_per_frame_numba']:.1f}, C++ {rec['cpu_ms_per_frame_cpp']:.1f}; native images identical: "
          f"{same}; load {load0:.2f} -> {load():.2f}", flush=True)
    if not same:
        raise HoloViewerError("kernels A/B: the C++ kernels' native images differ from the numba ones")
    return [rec]


#: ``--live-scales``' default: the tile scales ``holo-viewer live`` can be given (1.0 is its default, 0.5 the latency bench's)
LIVE_SCALES = "0.5,0.75,1.0"
#: the bystander of ``--live-pair``'s picture (deg, m)
PAIR_POSITION = (-15.0, 0.6)


class _WithCameras:
    """A pipeline seen through other quilt cameras (the tile shapes the live command cannot ask for), enough for
    :func:`~holo_viewer.pipeline.live_support.visible_mask`: its face, Gaussians and these cameras."""

    def __init__(self, pipe: Pipeline, cameras) -> None:
        self._pipe, self._cameras = pipe, cameras

    @property
    def face(self):
        return self._pipe.face

    def set_face(self, face) -> None:
        self._pipe.set_face(face)

    def gaussians(self):
        return self._pipe.gaussians()

    def cameras(self):
        return self._cameras


def scaled_cameras(cams, sx: float, sy: float):
    """The quilt cameras with tiles ``sx`` x ``sy`` of the full size (each axis as ``ViewSettings.tile_scale``
    rounds it): the same rig and field of view, pixels ``1/sx`` wide and ``1/sy`` tall (fx, cx scaled by the
    width's ratio, fy, cy by the height's); ``sx == sy`` gives the pipeline's own cameras at that tile scale."""
    from holo_viewer.camera import Cameras

    w, h = max(8, round(cams.width * sx)), max(8, round(cams.height * sy))
    K = np.array(cams.K, dtype=np.float64, copy=True)
    K[:, 0, :] *= w / cams.width
    K[:, 1, :] *= h / cams.height
    return Cameras(np.array(cams.world_to_cam, dtype=np.float64), K, w, h, cams.near, cams.far)


def live_scales(cal: DisplayCalibration, pipe: Pipeline, scales: list, quick: bool = False,
                pair: str | None = None, fine: float | None = 2.0) -> list[dict]:
    """``--live-scales``: the default group frame at each tile scale as ``holo-viewer live`` renders it
    (``LiveAvatarRenderer(tile_scale=S, native=True, mode="auto", visible_only=...)``: the per-view visible mask
    of that scale, built first and untimed; the renderer's own frame renderer, one tracked viewer at
    :data:`GROUP_VIEWERS`' first, the fill serving it), against the *present* full-quality frame (tile scale 1.0,
    every view: ``full_quilt``) over :class:`~holo_viewer.display.eyes.ConeSweep` and at the viewer's eyes. An
    entry ``SXxSY`` (e.g. ``0.5x1.0``) is a tile shape the command cannot ask for: the quilt cameras with
    the width and the height scaled apart (:func:`scaled_cameras`), with their own per-view mask. The flare of
    :func:`flare_frames`; one untimed pass, then ``2`` (quick) or :data:`GROUP_ROUNDS` passes, the scales taking
    turns. Records: ``tile_scale`` (the width's), ``tile_scale_y``, ``tile``, ``cpu_seconds_per_frame`` (process
    CPU, both cores), ``seconds_per_frame`` (wall), ``cone_worst_db``, ``cone_median_db``, ``tracked_eye_db``,
    ``gaussians_drawn_per_view``. ``fine``: also each record's ``cone_worst_db_fine`` / ``cone_median_db_fine`` /
    ``tracked_eye_db_fine`` against the full quilt at that finer tile scale (nearer the picture the panel could
    show), and a first record (``mode`` ``full_quilt``, tile scale 1.0) scored against it: what rendering the
    reference's own views on another pixel grid costs in this measure. ``pair``: a PNG of what the bystander at :data:`PAIR_POSITION` sees at
    tile scale 1.0 and 0.5 (flare frame 2), side by side."""
    from holo_viewer.display.eyes import ConeSweep, TrackedViewer
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.pipeline.live_support import visible_mask

    frames = flare_frames(pipe)
    display = VirtualDisplay(cal)
    full = NativeFrameRenderer(cal, pipe.cameras())
    refs = [full.frame(g, mode="full_quilt").native.copy() for g in frames]
    del full
    evaluated = [2, 4] if quick else [2, 3, 4, 6]
    cone = ConeSweep(display)
    ref_seen = {k: [cone.see(refs[k], i) for i in range(len(cone.positions))] for k in evaluated}
    viewer = TrackedViewer(*GROUP_VIEWERS[0])

    def scores(ref: dict, seen: dict, natives: dict) -> tuple[np.ndarray, float]:
        """(frames, positions) cone PSNR and the worst tracked eye of ``natives`` against ``ref``."""
        db = np.array([[eyes.head_psnr(seen[k][i], cone.see(natives[k], i)) for i in range(len(cone.positions))]
                       for k in evaluated])
        return db, min(eyes.eye_psnr(display, ref[k], natives[k], viewer) for k in evaluated)

    records = []
    if fine:
        t0 = time.process_time()
        fine_live = NativeFrameRenderer(cal, scaled_cameras(pipe.cameras(), fine, fine))
        fine_refs = {k: fine_live.frame(frames[k], mode="full_quilt").native.copy() for k in evaluated}
        del fine_live
        fine_seen = {k: [cone.see(fine_refs[k], i) for i in range(len(cone.positions))] for k in evaluated}
        db, eye_db = scores(fine_refs, fine_seen, {k: refs[k] for k in evaluated})
        records.append({"mode": "full_quilt", "tile_scale": 1.0, "tile_scale_y": 1.0, "reference": f"full_quilt at tile "
                        f"scale {fine:g}", "cone_worst_db_fine": float(db.min()), "cone_median_db_fine": float(np.median(db)),
                        "tracked_eye_db_fine": eye_db, "frames_evaluated": evaluated})
        print(f"full quilt at tile scale 1.0 against {fine:g}: cone worst {db.min():.1f} dB, median {np.median(db):.1f}, "
              f"eyes {eye_db:.1f} ({time.process_time() - t0:.0f} s of CPU)", flush=True)
    runs = []
    for spec in scales:
        t0, c0 = time.perf_counter(), time.process_time()
        if "x" in str(spec):
            sx, sy = (float(v) for v in str(spec).split("x"))
            cams = scaled_cameras(pipe.cameras(), sx, sy)
            keep = visible_mask(_WithCameras(pipe, cams), per_view=True)
            live = NativeFrameRenderer(cal, cams, NativeFrameConfig(render=RenderConfig(num_threads=os.cpu_count() or 1)),
                                       keep=keep)
            live.prepare_all_views()
            mode, how = "group", "quilt cameras scaled per axis (not a live option)"
        else:
            sx = sy = float(spec)
            r = LiveAvatarRenderer(tile_scale=sx, native=True, preview=False, mode="auto", visible_only="build")
            live, keep, mode, how = r._live, r.visible_keep, r.session_mode.tracked, "LiveAvatarRenderer"
        print(f"tile {live.cameras.width}x{live.cameras.height}: built in {time.perf_counter() - t0:.1f} s "
              f"(CPU {time.process_time() - c0:.1f} s, the visible mask included when not cached), load {load():.2f}",
              flush=True)
        for g in frames:  # warm-up, untimed
            live.frame(g, [viewer], mode)
        runs.append({"spec": str(spec), "sx": sx, "sy": sy, "live": live, "keep": keep, "mode": mode, "how": how,
                     "cpus": [], "secs": [], "loads": [], "natives": {}})
    rounds = 2 if quick else GROUP_ROUNDS
    for _ in range(rounds):
        for run in runs:
            for k in range(1, len(frames)):
                c0 = time.process_time()
                f = run["live"].frame(frames[k], [viewer], run["mode"])
                run["cpus"].append(time.process_time() - c0)
                run["secs"].append(f.seconds)
                run["loads"].append(load())
                if k in evaluated:
                    run["natives"][k] = f.native.copy()
    for run in runs:
        live, natives = run["live"], run["natives"]
        cone_db, eye_db = scores(refs, ref_seen, natives)
        worst = cone_db.min(axis=0)
        keep = run["keep"]
        cpu = float(np.median(run["cpus"]))
        rec = {"mode": run["mode"], "viewers": 1, "served": 0, "tile_scale": run["sx"], "tile_scale_y": run["sy"],
               "tile": f"{live.cameras.width}x{live.cameras.height}", "renderer": run["how"],
               "group_view_step": live.group_view_step,
               "gaussians_drawn_per_view": None if keep is None or keep.ndim != 2
               else [int(keep.sum(axis=1).min()), int(keep.sum(axis=1).max())],
               "cpu_seconds_per_frame": cpu, "seconds_per_frame": float(np.median(run["secs"])),
               "best_seconds": float(min(run["secs"])), "frames_timed": len(run["cpus"]),
               "timing": f"after one untimed pass, {rounds} rounds, the tile scales taking turns",
               "tracked_eye_db": eye_db, "cone_worst_db": float(worst.min()), "cone_median_db": float(np.median(cone_db)),
               "cone_worst_position": cone.positions[int(np.argmin(worst))],
               "reference": "full_quilt at tile scale 1.0 of the same face (the present frame)",
               "load_1min": float(np.mean(run["loads"])), "frames_evaluated": evaluated,
               "viewer_positions": [list(GROUP_VIEWERS[0])]}
        if fine:
            db, e = scores(fine_refs, fine_seen, natives)
            rec.update(cone_worst_db_fine=float(db.min()), cone_median_db_fine=float(np.median(db)), tracked_eye_db_fine=e)
        records.append(rec)
        print(f"live tile {rec['tile']:8s} ({run['spec']:>7s})  CPU {cpu:.3f} s/frame (wall {rec['seconds_per_frame']:.3f}, "
              f"best {rec['best_seconds']:.3f})  cone worst {rec['cone_worst_db']:.1f} dB (at {rec['cone_worst_position']}), "
              f"median {rec['cone_median_db']:.1f}, tracked eyes {eye_db:.1f} dB"
              + (f"; against {fine:g}: {rec['cone_worst_db_fine']:.1f} / {rec['cone_median_db_fine']:.1f} / "
                 f"{rec['tracked_eye_db_fine']:.1f} dB" if fine else "") + f", load {rec['load_1min']:.2f}", flush=True)
    if pair:
        by = {(r["sx"], r["sy"]): r for r in runs}
        if (1.0, 1.0) in by and (0.5, 0.5) in by:
            write_pair(pair, display, refs[2], [by[(1.0, 1.0)]["natives"][2], by[(0.5, 0.5)]["natives"][2]],
                       ["tile scale 1.0", "tile scale 0.5"])
            print(f"wrote {pair}", flush=True)
    return records


def write_pair(path: str, display: VirtualDisplay, ref: np.ndarray, natives: list, labels: list) -> None:
    """What an eye at :data:`PAIR_POSITION` sees of each native image, the head region side by side at twice
    the size (nearest), each labelled with its PSNR against ``ref`` seen from there."""
    from PIL import Image, ImageDraw

    a, d = PAIR_POSITION
    seen = display.see_many([ref] + list(natives), a, d)
    h, w = seen[0].shape[:2]
    tiles = []
    for img, label in zip(seen[1:], labels):
        crop = img[int(h * 0.12):int(h * 0.62), int(w * 0.2):int(w * 0.8)]
        im = Image.fromarray((np.clip(crop, 0, 1) * 255).astype(np.uint8))
        im = im.resize((im.width * 2, im.height * 2), Image.NEAREST)
        ImageDraw.Draw(im).text((4, 4), f"{label}, eye at {a:+.0f} deg {d:.1f} m: {eyes.head_psnr(seen[0], img):.1f} dB",
                                fill=(255, 255, 0))
        tiles.append(np.asarray(im))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as fh:
        Image.fromarray(np.concatenate(tiles, axis=1)).save(fh, format="PNG")


def write_sheet(path: str, display: VirtualDisplay, shown: dict, viewer, moments: tuple, refs: list) -> None:
    """'tracked eye | bystander 0 | -15 | +15 deg' (0.6 m) per moment and mode, each labelled with its
    PSNR against the present frame seen from there; the head region of each perceived image."""
    from PIL import Image, ImageDraw

    from holo_viewer.display.eyes import eye_positions

    spots = [("tracked eye", *eye_positions(viewer)[0]), ("bystander 0", 0.0, 0.6),
             ("bystander -15", -15.0, 0.6), ("bystander +15", 15.0, 0.6)]
    rows = []
    for mode in ("tracked", "group"):
        for k in moments:
            row = []
            for name, a, d in spots:
                r, t = display.see_many([refs[k], shown[mode][k]], a, d)
                db = eyes.head_psnr(r, t)
                h, w = t.shape[:2]
                crop = t[int(h * 0.12):int(h * 0.62), int(w * 0.2):int(w * 0.8)]
                img = Image.fromarray((np.clip(crop, 0, 1) * 255).astype(np.uint8))
                ImageDraw.Draw(img).text((4, 4), f"{mode} frame {k} (pain {FLARE_PAIN[k - 1]:g})\n{name}: {db:.1f} dB",
                                         fill=(255, 255, 0))
                row.append(np.asarray(img))
            rows.append(np.concatenate(row, axis=1))
    sheet = np.concatenate(rows, axis=0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    jpeg = path.lower().endswith((".jpg", ".jpeg"))
    with atomic_write(path, "wb") as fh:
        Image.fromarray(sheet).save(fh, format="JPEG" if jpeg else "PNG", **({"quality": 88} if jpeg else {}))


def run_mode(live: NativeFrameRenderer, frames: list, mode: str, viewers: list | None = None,
             timings: list | None = None) -> tuple[list, float, float]:
    """Frame times (wall), natives (copies) and CPU seconds per frame; each frame's
    ``LiveFrame.timings`` appended to ``timings`` when given."""
    secs, natives = [], []
    c0 = time.process_time()
    for k, g in enumerate(frames):
        f = live.frame(g, viewers[k] if viewers else None, mode)
        secs.append(f.seconds)
        natives.append(f.native.copy())
        if timings is not None:
            timings.append(dict(f.timings))
    return secs, natives, (time.process_time() - c0) / len(frames)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer frames and knobs (< 3 min)")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="also time the GPU path (cuda)")
    ap.add_argument("--gpu-only", action="store_true",
                    help="with --device cuda: only the full-quality reference on the CPU, then the GPU records "
                         "(what a lent GPU machine runs first)")
    ap.add_argument("--json", default=None,
                    help="output JSON file (default bench/results/live_frame.json; --group-only: live_frame_group.json)")
    ap.add_argument("--group-only", action="store_true",
                    help="only the group sweep (issue 37): every mode judged at every position of the cone")
    ap.add_argument("--sheet", default="docs/images/live_group_sheet.jpg",
                    help="the group sweep's picture (tracked eye and bystanders at three moments of a flare)")
    ap.add_argument("--frames", type=int, default=None,
                    help="frames per mode (default 6 quick, 10 full; the median of 4 was carried by one cold frame)")
    ap.add_argument("--ref-views", type=int, default=None, help="views checked against float64 (1 quick, 2)")
    ap.add_argument("--kernels-ab", action="store_true",
                    help="only the live-size A/B of the numba warp + row gather against the C++ kernels")
    ap.add_argument("--live-scales", nargs="?", const=LIVE_SCALES, default=None,
                    help="only the default group frame at these tile scales as holo-viewer live renders it "
                         f"(default {LIVE_SCALES}; SXxSY: width and height scaled apart)")
    ap.add_argument("--live-fine", type=float, default=2.0,
                    help="with --live-scales: also score against the full quilt at this tile scale (0: not)")
    ap.add_argument("--live-pair", default=None,
                    help="with --live-scales (0.5 and 1.0 among them): a PNG of a bystander's eye image at both")
    ap.add_argument("--vtk-views", type=int, default=None,
                    help="VTK views timed one call each and extrapolated; default: the whole pass")
    args = ap.parse_args(argv)
    if args.json is None:
        args.json = ("bench/results/live_frame_kernels_ab.json" if args.kernels_ab else
                     "bench/results/live_frame_scales.json" if args.live_scales else
                     "bench/results/live_frame_group.json" if args.group_only else "bench/results/live_frame.json")
    n_frames = args.frames or (6 if args.quick else 10)
    ref_views = args.ref_views if args.ref_views is not None else (1 if args.quick else 2)
    vtk_views = args.vtk_views if args.vtk_views is not None else 10**6  # default: the whole pass
    t_run = time.perf_counter()
    load_before = load()
    try:
        cal = DisplayCalibration.load(None)
        pipe = Pipeline(calibration=cal)
        cams = pipe.cameras()
        if args.kernels_ab:
            raise _GroupOnly(kernels_ab())
        if args.live_scales:
            raise _GroupOnly(live_scales(cal, pipe, [v.strip() for v in args.live_scales.split(",") if v.strip()],
                                         args.quick, args.live_pair, args.live_fine or None))
        if args.group_only:
            raise _GroupOnly(group_sweep(cal, pipe, args.quick, args.sheet))
        params: list = []
        frames = frames_of_animation(pipe, n_frames + 1, params)  # frame 0 primes the kept state
        display = VirtualDisplay(cal)
        records: list[dict] = []
        print(f"avatar: {len(frames[0])} Gaussians, {len(cams)} views {cams.width}x{cams.height}, "
              f"{n_frames} frames per mode, load {load_before:.2f}", flush=True)

        # ---- full quality (reference of every other mode)
        full = NativeFrameRenderer(cal, cams)
        full.frame(frames[0], mode="full_quilt")  # warm-up (numba cache, buffers)
        full_timings: list = []
        secs, ref_natives, cpu = run_mode(full, frames[1:], "full_quilt", timings=full_timings)
        views_s = float(np.median([t["render"] for t in full_timings]))  # the 48 float views alone
        ref_views_img = full.views[:ref_views].copy()  # last frame's views
        f64 = render_views(frames[-1], cams[list(range(ref_views))], "reference", RenderConfig()).images
        p64 = min(eyes.psnr(f64[i], ref_views_img[i]) for i in range(ref_views))
        full_s = float(np.median(secs))
        records.append({"mode": "full_quilt", "seconds_per_frame": full_s, "best_seconds": float(min(secs)),
                        "cpu_seconds_per_frame": cpu, "views_seconds_per_frame": views_s,
                        "psnr_db": math.inf, "psnr_vs_float64_db": p64,
                        "float64_views": ref_views, "rendered_fraction": 1.0})
        print(f"full_quilt   {full_s:.3f} s/frame (best {min(secs):.3f}, cpu {cpu:.2f})  "
              f"views vs float64 {p64:.1f} dB", flush=True)

        sweep_viewers = [eyes.TrackedViewer(a, d) for a in (-12.0, -6.0, 0.0, 6.0, 12.0) for d in (0.45, 0.6, 0.9)]
        if not args.gpu_only:  # the CPU modes (--gpu-only: only the reference above, then the GPU)
            # ---- untracked, all views, by level of detail
            for frac in ((1.0, 0.5) if args.quick else (1.0, 0.7, 0.5, 0.3)):
                live = NativeFrameRenderer(cal, cams, NativeFrameConfig(lod_fraction=frac, view_step=1), rest=frames[0])
                live.frame(frames[0], mode="all_views")
                secs, natives, cpu = run_mode(live, frames[1:], "all_views")
                p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                s = float(np.median(secs))
                records.append({"mode": "all_views", "lod_fraction": frac, "seconds_per_frame": s,
                                "best_seconds": float(min(secs)), "cpu_seconds_per_frame": cpu, "psnr_db": p,
                                "rendered_fraction": 1.0, "ratio_to_full_quilt": full_s / s})
                print(f"all_views    lod {frac:.1f}  {s:.3f} s/frame (cpu {cpu:.2f})  native {p:.1f} dB", flush=True)
            # ---- untracked, all views, with the renderer's error-for-blends knobs (every Gaussian kept):
            # a pixel stops after T < t_min (error < t_min there), splats fainter than alpha_threshold skip
            for knobs in (dict(t_min=1e-2, alpha_threshold=2.0 / 255.0),):
                live = NativeFrameRenderer(cal, cams, NativeFrameConfig(render=RenderConfig(**knobs), view_step=1))
                live.frame(frames[0], mode="all_views")
                secs, natives, cpu = run_mode(live, frames[1:], "all_views")
                p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                s = float(np.median(secs))
                records.append({"mode": "all_views", "lod_fraction": 1.0, "render_knobs": knobs, "seconds_per_frame": s,
                                "best_seconds": float(min(secs)), "cpu_seconds_per_frame": cpu, "psnr_db": p,
                                "rendered_fraction": 1.0, "ratio_to_full_quilt": full_s / s})
                print(f"all_views    {knobs}  {s:.3f} s/frame (cpu {cpu:.2f})  native {p:.1f} dB", flush=True)

            # ---- untracked, all views, with view synthesis: every view_step-th view rendered, the others
            # warped from their rendered neighbours by depth; also the worst eye over a sweep of viewers
            # (what a person anywhere in front of the panel sees), last frame
            for step in ((5,) if args.quick else (2, 3, 4, 5, 6, 8)):
                live = NativeFrameRenderer(cal, cams, NativeFrameConfig(view_step=step))
                fraction = live.frame(frames[0], mode="all_views").rendered_fraction
                secs, natives, cpu = run_mode(live, frames[1:], "all_views")
                p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                worst = min(eyes.eye_psnr(display, ref_natives[-1], natives[-1], v)
                            for v in (sweep_viewers[::3] if args.quick else sweep_viewers))
                s = float(np.median(secs))
                records.append({"mode": "all_views", "lod_fraction": 1.0, "view_step": step,
                                "seconds_per_frame": s, "best_seconds": float(min(secs)), "cpu_seconds_per_frame": cpu,
                                "psnr_db": p, "worst_sweep_psnr_db": worst,
                                "rendered_fraction": fraction, "ratio_to_full_quilt": full_s / s,
                                "sweep": "eyes at -12..12 deg, 0.45-0.9 m"})
                print(f"all_views    view_step {step}  {s:.3f} s/frame (cpu {cpu:.2f})  native {p:.1f} dB, "
                      f"worst eye in sweep {worst:.1f} dB", flush=True)

            # ---- tracked viewer, by method and head motion margin
            angles = np.linspace(-8.0, 8.0, n_frames + 1)
            viewers = [eyes.TrackedViewer(float(a), 0.6) for a in angles]
            # (method, sideways margin, depth margin); None: the method's defaults (TRACKED_DEFAULTS)
            runs = ([("slices", None, None), ("bands", None, None)] if args.quick else
                    [("slices", 0.0, 0.0), ("slices", None, None), ("slices", 0.01, 0.05),
                     ("bands", 0.0, 0.0), ("bands", None, None), ("bands", 0.02, 0.05)])
            for method, motion, motion_d in runs:
                cfg = NativeFrameConfig(motion_m=motion, motion_distance_m=motion_d, tracked=method)
                live = NativeFrameRenderer(cal, cams, cfg)
                live.frame(frames[0], viewers[0], mode="tracked")  # everything, once
                live.prepare_tracked()  # the slices' one-off tables (a live session builds them while warming up)
                secs, fracs, worst = [], [], math.inf
                c0 = time.process_time()
                natives = []
                for k in range(1, n_frames + 1):
                    f = live.frame(frames[k], viewers[k], mode="tracked")
                    secs.append(f.seconds)
                    fracs.append(f.rendered_fraction)
                    natives.append(f.native.copy())
                cpu = (time.process_time() - c0) / n_frames
                eval_frames = [n_frames - 1] if args.quick else list(range(0, n_frames, max(1, n_frames // 3)))
                per_eye = min(eyes.eye_psnr(display, ref_natives[k], natives[k], viewers[k + 1]) for k in eval_frames)
                v = viewers[-1]
                # eyes displaced sideways (and in depth) from the tracked position: inside the margin
                # every received subpixel is exact; outside it, stale ones start to be seen
                sweep = [(dx, 0.0) for dx in ((-0.01, 0.01) if args.quick else (-0.02, -0.01, 0.01, 0.02))]
                if not args.quick:
                    sweep += [(0.0, -0.05), (0.0, 0.05)]
                by_offset = {}
                for dx, dd in sweep:
                    x = v.centre_x_m + dx
                    moved = eyes.TrackedViewer(math.degrees(math.atan2(x, v.distance_m + dd)), v.distance_m + dd)
                    by_offset[f"{dx * 100:+.0f} cm, {dd * 100:+.0f} cm"] = p_moved = eyes.eye_psnr(
                        display, ref_natives[-1], natives[-1], moved)
                    worst = min(worst, p_moved)
                s = float(np.median(secs))
                records.append({"mode": "tracked", "method": method, "motion_m": live.motion_m,
                                "motion_distance_m": live.motion_distance_m, "refresh_columns": live.refresh_columns,
                                "defaults": motion is None,
                                "seconds_per_frame": s, "best_seconds": float(min(secs)), "cpu_seconds_per_frame": cpu,
                                "psnr_db": per_eye, "worst_sweep_psnr_db": worst, "sweep_psnr_db": by_offset,
                                "rendered_fraction": float(np.mean(fracs)), "ratio_to_full_quilt": full_s / s,
                                "viewer": "0.6 m, angle -8..8 deg"})
                print(f"tracked      {method:6s} margin {live.motion_m * 100:.1f}/{live.motion_distance_m * 100:.0f} cm, "
                      f"refresh {live.refresh_columns}  {s:.3f} s/frame (cpu {cpu:.2f}, "
                      f"{np.mean(fracs) * 100:.0f} % of tiles)  per-eye {per_eye:.1f} dB, worst in sweep {worst:.1f} dB",
                      flush=True)

            # ---- tracked slices near the cone's edge: an eye looks past the last view through part of the
            # panel and receives the next lobe's first views there (rendered exactly through the quilt)
            live = NativeFrameRenderer(cal, cams)
            live.frame(frames[0], viewers[0], mode="tracked")
            live.prepare_tracked()
            for angle in ((17.0,) if args.quick else (15.0, 19.0)):
                v = eyes.TrackedViewer(angle, 0.6)
                secs, fracs = [], []
                for k in range(1, n_frames + 1):
                    f = live.frame(frames[k], v, mode="tracked")
                    secs.append(f.seconds)
                    fracs.append(f.rendered_fraction)
                per_eye = eyes.eye_psnr(display, ref_natives[n_frames - 1], f.native, v)
                s = float(np.median(secs))
                records.append({"mode": "tracked", "method": live.tracked_method, "cone_edge": True, "defaults": True,
                                "motion_m": live.motion_m, "motion_distance_m": live.motion_distance_m,
                                "refresh_columns": live.refresh_columns, "seconds_per_frame": s,
                                "best_seconds": float(min(secs)), "psnr_db": per_eye,
                                "rendered_fraction": float(np.mean(fracs)), "ratio_to_full_quilt": full_s / s,
                                "viewer": f"0.6 m, angle {angle:g} deg (eyes "
                                          + ", ".join(f"{a:.1f}" for a, _ in eyes.eye_positions(v)) + " deg)"})
                print(f"tracked      {live.tracked_method} at {angle:g} deg (cone edge)  {s:.3f} s/frame "
                      f"({np.mean(fracs) * 100:.0f} % of tiles)  per-eye {per_eye:.1f} dB (last frame)", flush=True)

            # ---- eye-centred: one perspective image per eye, scattered into the subpixels it receives
            live = NativeFrameRenderer(cal, cams)
            live.frame(frames[0], mode="full_quilt")
            secs, natives = [], []
            c0 = time.process_time()
            for k in range(1, n_frames + 1):
                f = live.frame(frames[k], viewers[k], mode="eye_centred")
                secs.append(f.seconds)
                natives.append(f.native.copy())
            cpu = (time.process_time() - c0) / n_frames
            k = n_frames - 1
            per_eye = eyes.eye_psnr(display, ref_natives[k], natives[k], viewers[k + 1])
            s = float(np.median(secs))
            records.append({"mode": "eye_centred", "seconds_per_frame": s, "best_seconds": float(min(secs)),
                            "cpu_seconds_per_frame": cpu, "psnr_db": per_eye, "rendered_fraction": 2 / len(cams),
                            "ratio_to_full_quilt": full_s / s, "viewer": "0.6 m, angle -8..8 deg"})
            print(f"eye_centred  {s:.3f} s/frame (cpu {cpu:.2f})  per-eye {per_eye:.1f} dB", flush=True)

            # ---- VTK: the whole pass (every view in one call, as an export renders a quilt) between two
            # full quilts, twice (once with --quick); or --vtk-views N < 48 views spread over the cone, extrapolated
            try:
                V = len(cams)
                check = [int(x) for x in (np.arange(3) + 0.5) / 3 * V]  # views whose PSNR is taken
                render_views(frames[-1], cams[[0]], "vtk")  # warm-up: OSMesa context, shaders
                vtk_s, vtk_cpu, pair_full, imgs = [], 0.0, [], {}
                whole = vtk_views >= V
                if whole:
                    for _ in range(1 if args.quick else 2):
                        before = full.frame(frames[-1], mode="full_quilt").seconds  # same views as before
                        t0, c0 = time.perf_counter(), time.process_time()
                        res = render_views(frames[-1], cams, "vtk")
                        vtk_s.append(time.perf_counter() - t0)
                        vtk_cpu += time.process_time() - c0
                        pair_full.append(0.5 * (before + full.frame(frames[-1], mode="full_quilt").seconds))
                    imgs = {j: res.images[j] for j in check}
                    s = float(np.median(vtk_s))
                    cpu = vtk_cpu / len(vtk_s)
                    paired = [t / f for t, f in zip(vtk_s, pair_full)]
                else:
                    timed = [int(x) for x in (np.arange(vtk_views) + 0.5) / vtk_views * V]
                    for j in timed:
                        t0, c0 = time.perf_counter(), time.process_time()
                        imgs[j] = render_views(frames[-1], cams[[j]], "vtk").images[0]
                        vtk_s.append(time.perf_counter() - t0)
                        vtk_cpu += time.process_time() - c0
                        pair_full.append(full.frame(frames[-1], mode="full_quilt").seconds)
                    s = float(np.mean(vtk_s)) * V
                    cpu = vtk_cpu / len(timed) * V
                    paired = [t * V / f for t, f in zip(vtk_s, pair_full)]
                p = min(eyes.psnr(full.views[j], img) for j, img in imgs.items())
                records.append({"mode": "vtk", "seconds_per_frame": s, "cpu_seconds_per_frame": cpu, "psnr_db": p,
                                "extrapolated": not whole, "views_timed": "all, one call" if whole else timed,
                                "pass_seconds": vtk_s if whole else None,
                                "psnr_views": sorted(imgs), "ratio_to_full_quilt": full_s / s,
                                "paired_ratios": paired, "paired_ratio_median": float(np.median(paired)),
                                "ratio_to_views_only": s / views_s,
                                "paired_full_quilt_seconds": pair_full,
                                "note": (f"the whole VTK pass (48 views, one call), {len(vtk_s)} time(s), each between two "
                                         "full quilts (paired_ratios: its time / their mean)" if whole else
                                         "views timed one call each, extrapolated to 48 (a call per view costs "
                                         "~20 % more than the whole pass); each paired with the full quilt "
                                         "timed right after it") + "; views only (no quilt or interleave)"})
                what = "the whole pass, one call" if whole else f"extrapolated from views {timed}"
                print(f"vtk          {s:.2f} s/frame ({what})  views {p:.1f} dB; "
                      f"x{s / full_s:.1f} the full quilt, paired x{np.median(paired):.1f} "
                      f"({', '.join(f'{x:.1f}' for x in paired)}), x{s / views_s:.1f} its views alone", flush=True)
            except HoloViewerError as exc:
                records.append({"mode": "vtk", "skipped": str(exc)})
                print(f"vtk skipped: {exc}", flush=True)

        # ---- GPU
        if args.device == "cuda":
            try:
                import torch

                if not torch.cuda.is_available():
                    raise HoloViewerError("no CUDA device")
                live = NativeFrameRenderer(cal, cams, NativeFrameConfig(backend="gsplat"))
                live.frame(frames[0], mode="all_views")
                secs, natives, cpu = run_mode(live, frames[1:], "all_views")
                p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                s = float(np.median(secs))
                records.append({"mode": "all_views", "backend": "gsplat", "device": torch.cuda.get_device_name(0),
                                "seconds_per_frame": s, "best_seconds": float(min(secs)), "psnr_db": p,
                                "frames_per_second": 1.0 / s})
                print(f"all_views GPU  {s * 1000:.1f} ms/frame ({1 / s:.0f} fps)  native {p:.1f} dB", flush=True)
                # view synthesis on the device: every step-th view rendered by gsplat, the others warped there
                synths = {}
                for step in (3, 5):
                    synth = synths[step] = NativeFrameRenderer(cal, cams, NativeFrameConfig(backend="gsplat", view_step=step))
                    synth.frame(frames[0], mode="all_views")
                    secs_v, natives_v, _ = run_mode(synth, frames[1:], "all_views")
                    p_v = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives_v))
                    worst_v = min(eyes.eye_psnr(display, ref_natives[-1], natives_v[-1], v)
                                  for v in sweep_viewers[::3])
                    s_v = float(np.median(secs_v))
                    records.append({"mode": "all_views", "backend": "gsplat", "view_step": step,
                                    "device": torch.cuda.get_device_name(0), "seconds_per_frame": s_v,
                                    "best_seconds": float(min(secs_v)), "psnr_db": p_v,
                                    "frames_per_second": 1.0 / s_v, "worst_sweep_psnr_db": worst_v,
                                    "sweep": "eyes at -12..12 deg, 0.45 m"})
                    print(f"all_views GPU, view_step {step}  {s_v * 1000:.1f} ms/frame ({1 / s_v:.0f} fps)  "
                          f"native {p_v:.1f} dB, worst eye in sweep {worst_v:.1f} dB", flush=True)
                try:
                    st = gpu_stages(live, synths[5], frames)
                    records.append(st)
                    print("GPU stages (ms, each alone): " + ", ".join(f"{k} {v}" for k, v in st["ms"].items()),
                          flush=True)
                except Exception as exc:  # a profile only: say why, keep the frame records
                    records.append({"mode": "gpu_stages", "skipped": f"{type(exc).__name__}: {exc}"})
                    print(f"GPU stage profile skipped: {exc}", flush=True)
                try:
                    # the same frames with the Gaussians already on the GPU (what a frame costs when the
                    # deformation runs there too: the host -> device upload of ~24 MB of Gaussians is gone;
                    # the deformation itself is not in this number)
                    resident = [g.torch(device="cuda") for g in frames]
                    torch.cuda.synchronize()
                    t_up = time.perf_counter()
                    frames[1].torch(device="cuda")
                    torch.cuda.synchronize()
                    upload_s = time.perf_counter() - t_up
                    live.frame(resident[0], mode="all_views")
                    secs, natives, cpu = run_mode(live, resident[1:], "all_views")
                    p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                    s = float(np.median(secs))
                    records.append({"mode": "all_views", "backend": "gsplat", "gaussians_on_device": True,
                                    "device": torch.cuda.get_device_name(0), "seconds_per_frame": s,
                                    "best_seconds": float(min(secs)), "psnr_db": p, "frames_per_second": 1.0 / s,
                                    "upload_seconds": upload_s})
                    print(f"all_views GPU, Gaussians on the GPU  {s * 1000:.1f} ms/frame ({1 / s:.0f} fps)  "
                          f"native {p:.1f} dB  (their upload: {upload_s * 1000:.1f} ms)", flush=True)
                    synth = synths[5]
                    synth.frame(resident[0], mode="all_views")
                    secs, natives, _ = run_mode(synth, resident[1:], "all_views")
                    p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                    s = float(np.median(secs))
                    records.append({"mode": "all_views", "backend": "gsplat", "gaussians_on_device": True,
                                    "view_step": 5, "device": torch.cuda.get_device_name(0), "seconds_per_frame": s,
                                    "best_seconds": float(min(secs)), "psnr_db": p, "frames_per_second": 1.0 / s})
                    print(f"all_views GPU, Gaussians on the GPU, view_step 5  {s * 1000:.1f} ms/frame "
                          f"({1 / s:.0f} fps)  native {p:.1f} dB", flush=True)
                    # the whole frame on the GPU: FLAME LBS + binding there, then the same render
                    deform = deformer_on("cuda")
                    live.frame(deform(params[0]), mode="all_views")
                    secs, natives = [], []
                    for k in range(1, n_frames + 1):
                        t0 = time.perf_counter()
                        f = live.frame(deform(params[k]), mode="all_views")  # native on the host: synchronised
                        secs.append(time.perf_counter() - t0)
                        natives.append(f.native.copy())
                    p = min(eyes.head_psnr(r / 255.0, n / 255.0) for r, n in zip(ref_natives, natives))
                    s = float(np.median(secs))
                    records.append({"mode": "all_views", "backend": "gsplat", "deformed_on_device": True,
                                    "device": torch.cuda.get_device_name(0), "seconds_per_frame": s,
                                    "best_seconds": float(min(secs)), "psnr_db": p, "frames_per_second": 1.0 / s,
                                    "note": "FLAME parameters -> LBS -> binding -> 48 views -> native, all on the GPU"})
                    print(f"all_views GPU, deformed on the GPU  {s * 1000:.1f} ms/frame ({1 / s:.0f} fps)  "
                          f"native {p:.1f} dB", flush=True)
                except (HoloViewerError, RuntimeError, TypeError) as exc:  # a GPU-only path: say why, keep the rest
                    records.append({"mode": "all_views", "backend": "gsplat", "gaussians_on_device": True,
                                    "skipped": f"{type(exc).__name__}: {exc}"})
                    print(f"GPU-resident run skipped: {exc}", flush=True)
            except Exception as exc:  # no CUDA, no gsplat, or a failure there: say why, keep the CPU records
                records.append({"mode": "all_views", "backend": "gsplat", "skipped": f"{type(exc).__name__}: {exc}"})
                print(f"GPU skipped: {exc}", flush=True)
        if not args.gpu_only:
            records += group_sweep(cal, Pipeline(calibration=cal), args.quick, args.sheet)
    except _GroupOnly as only:
        records = only.records
    except HoloViewerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    result = {"benchmark": "live_frame", "quick": args.quick, "frames_per_mode": n_frames,
              "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "cpu_model": cpu_model(),
                          "load_1min_before": load_before, "load_1min_after": load()},
              "seconds_total": time.perf_counter() - t_run, "records": records}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(args.json, "w") as fh:
        json.dump(result, fh, indent=1, default=float)
    print(f"wrote {args.json} ({result['seconds_total']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
