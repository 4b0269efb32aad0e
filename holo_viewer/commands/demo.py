"""``holo-viewer demo``: the main job on the default avatar (what ``make demo`` runs).

Writes, atomically, into ``--out DIR``:

* ``head/``: the default head's renders (neutral, smile, pain, mouth open from three angles and a
  contact sheet; ``flame.preview.write_head_renders``),
* ``default_qs8x6a0.75.png``: the 48-view quilt of a smile with pain,
* ``default_native.png``: its lenticular native image for the shipped Portrait calibration
  (``assets/lkg_portrait_visual.json``),
* ``default_reaction_qs8x6a0.75.mp4``: a quilt video of the avatar reacting, through the shipped
  listener-reaction model, to a synthesized speaker clip,
* ``timings.json``: the per-stage timings printed at the end.

``--avatar NAME`` (a fitted patient, docs/patients.md) or a fitted ``.npz`` runs the same job on that
avatar; its files are named after it (``NAME_qs8x6a0.75.png``, ``NAME_native.png``, ...).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from ..validation import fps_arg, seed_arg

__all__ = ["add_arguments", "run", "format_timing_table"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument("--smile", type=float, default=0.8, help="smile intensity of the quilt, 0..1 (default 0.8)")
    parser.add_argument("--pain", type=float, default=0.6, help="pain intensity of the quilt and the reaction, 0..1")
    parser.add_argument("--seconds", type=float, default=2.0, help="length of the reaction video (default 2 s)")
    parser.add_argument("--fps", type=fps_arg, default=25.0,
                        help="frame rate of the reaction video (default 25; lowered when --time-budget needs it)")
    parser.add_argument("--time-budget", type=float, default=270.0,
                        help="seconds the whole demo may take (default 270): when the quilt time measured on "
                             "the video's first frame cannot fill the video at --fps in time, the video uses a "
                             "lower frame rate (same length) and says so; 0 = no limit")
    parser.add_argument("--video-scale", type=float, default=1.0,
                        help="tile size of the video relative to the 420x560 quilt tile (default 1)")
    from .renderer_args import add_renderer_argument

    add_renderer_argument(parser, help="splat renderer")
    parser.add_argument("--seed", type=seed_arg, default=0, help="seed of the synthesized speaker clip")
    parser.add_argument("--skip-head-renders", action="store_true", help="do not write head/ (faster)")
    from .avatar_args import add_avatar_argument

    add_avatar_argument(parser, kinds=("default", "patient", "npz"), fitted=True,
                        help="whose quilt and video; files are named after it (default_*.png for the default)")
    from .behaviour_args import add_behaviour_arguments

    add_behaviour_arguments(parser, pain_timeline=False)


def format_timing_table(rows: list[tuple[str, float, str]]) -> str:
    """A fixed-width table of (step, seconds, note) rows."""
    w = max(len(r[0]) for r in rows) if rows else 10
    lines = [f"{'step':<{w}}  {'seconds':>9}  note", f"{'-' * w}  {'-' * 9}  {'-' * 30}"]
    for name, sec, note in rows:
        lines.append(f"{name:<{w}}  {sec:>9.3f}  {note}")
    return "\n".join(lines)


def _reaction_frames(seconds: float, pain: float, seed: int, behaviour: object = "default",
                     au_map: object = None) -> tuple[list[dict], float]:
    """Listener FLAME frames (and their rate) from the reaction model for a synthesized speaker clip,
    with the behaviour layers (``behaviour``: a BehaviourConfig, "default", or None for the model alone;
    ``au_map``: the avatar's map, whose pain gains shape their pain face)."""
    from ..errors import ReactionError
    from ..pipeline import reaction_frames

    try:
        return reaction_frames(seconds=seconds, pain=pain, seed=seed, behaviour=behaviour, au_map=au_map)
    except ImportError as exc:
        raise ReactionError("demo: the reaction video needs the listener-reaction model "
                            f"(holo_viewer.reaction), which cannot be imported ({exc})") from exc


def _resample(frames: list[dict], src_fps: float, fps: float) -> list[dict]:
    """Nearest-frame resampling of a sequence from ``src_fps`` to ``fps`` (same duration)."""
    import numpy as np

    if abs(src_fps - fps) < 1e-9:
        return list(frames)
    n = max(1, int(round(len(frames) * fps / src_fps)))
    idx = np.minimum(np.round(np.arange(n) * src_fps / fps).astype(int), len(frames) - 1)
    return [frames[i] for i in idx]


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from ..display.export import write_quilt_video
    from ..display.quilt import quilt_filename
    from ..errors import InputError
    from ..fileio import atomic_write, ensure_dir, save_image
    from ..pipeline import STAGES, FaceControls, Pipeline, StageTimings, apply_frame, render_images

    from ..flame.expressions import PAIN_RANGE

    lo, hi = PAIN_RANGE  # named-expression intensities share pain's range
    for name in ("smile", "pain"):
        v = getattr(args, name)
        if not lo <= v <= hi:
            raise InputError(f"--{name}: expected a value in [{lo:g}, {hi:g}], found {v}")
    if not (0 < args.seconds <= 60 and 0 < args.fps <= 120 and 0.05 <= args.video_scale <= 1.0):
        raise InputError(f"--seconds/--fps/--video-scale: expected (0, 60], (0, 120], [0.05, 1], found "
                         f"{args.seconds}, {args.fps}, {args.video_scale}")
    out = ensure_dir(args.out, "output directory (--out)")
    rows: list[tuple[str, float, str]] = []
    t_all = time.perf_counter()
    steps = tqdm(total=6, desc="demo", unit="step")

    def step(name: str, t0: float, note: str = "") -> None:
        rows.append((name, time.perf_counter() - t0, note))
        steps.set_postfix_str(name)
        steps.update(1)

    # 1. the avatar (default, or --avatar's patient / fitted file)
    t0 = time.perf_counter()
    face = FaceControls(named=(("smile", args.smile),), pain=args.pain)
    stem = "default"
    if getattr(args, "avatar", "default") == "default":
        pipe = Pipeline(backend=args.renderer, face=face)
    else:
        from ..avatar.patients import load_choice

        model, avatar, _, name = load_choice(args.avatar, need_gaussians=True)
        pipe = Pipeline(model=model, avatar=avatar, backend=args.renderer, face=face)
        stem = Path(name).stem
    step(f"load {stem} avatar", t0, f"{len(pipe.avatar)} Gaussians, {pipe.model.n_vertices} vertices")

    # 2. head renders (issue 2)
    t0 = time.perf_counter()
    if args.skip_head_renders:
        step("head renders", t0, "skipped")
    else:
        from ..flame.preview import write_head_renders

        files = write_head_renders(out / "head", pipe.model, verbose=False)
        step("head renders", t0, f"{len(files)} PNGs in {out / 'head'}")

    # 3. quilt of a smile with pain, 4. native image
    cal = pipe.calibration
    t0 = time.perf_counter()
    (quilt,), quilt_t = pipe.compute("quilt")
    qpath = save_image(out / quilt_filename(stem, cal.cols, cal.rows, cal.aspect), quilt)
    step("quilt (smile + pain)", t0, f"{qpath.name} {quilt.shape[1]}x{quilt.shape[0]}")
    t0 = time.perf_counter()
    (native,), native_t = pipe.compute("native")
    npath = save_image(out / f"{stem}_native.png", native)
    step("native image", t0, f"{npath.name} {native.shape[1]}x{native.shape[0]} ({cal.source or 'calibration'})")
    first = StageTimings()
    first.add(quilt_t)
    first.add(native_t)

    # 5. reaction to a synthesized speaker clip
    t0 = time.perf_counter()
    from .behaviour_args import behaviour_from_args

    behaviour = behaviour_from_args(args, seed=args.seed)
    src_frames, src_fps = _reaction_frames(args.seconds, args.pain, args.seed, behaviour, pipe.au_map)
    step("reaction model", t0, f"{len(src_frames)} frames at {src_fps:g} fps for a synthesized speaker clip")

    # the frame rate the time budget allows, from the (warm) time of the video's first quilt
    base = FaceControls()  # the frames' expressions already carry the requested pain (behaviour layer or model)
    if args.video_scale != 1.0:
        pipe.set_view(tile_scale=args.video_scale)
    fps = float(args.fps)
    t_video = t0 = time.perf_counter()
    pipe.set_face(apply_frame(base, src_frames[0]))
    pipe.compute("quilt")  # frame 0 of every rate; the stream below finds it cached
    probe = time.perf_counter() - t0
    if probe > 1.0:  # may still include one-time compilation (fresh numba cache): time a second, warm render
        t0 = time.perf_counter()
        render_images(pipe.gaussians(), pipe.cameras(), backend=pipe.backend, config=pipe.render_config)
        probe = min(probe, time.perf_counter() - t0)
    per_frame = 1.2 * probe + 0.3  # + H.264 encoding of one 3360x3360 frame
    if args.time_budget > 0:
        left = args.time_budget - (time.perf_counter() - t_all) - 5.0
        affordable = left / max(per_frame, 1e-3) / args.seconds
        if affordable < fps:
            new_fps = max(2.0, float(np.floor(affordable)))
            print(f"demo: one quilt takes {per_frame:.1f} s here; to finish within --time-budget "
                  f"{args.time_budget:g} s the {args.seconds:g}-second video uses {new_fps:g} fps instead of "
                  f"{fps:g} (raise --time-budget or lower --fps to choose)")
            fps = new_fps
    frames = _resample(src_frames, src_fps, fps)

    # 6. quilt video, streamed through the pipeline (its time includes the probe above)
    from ..pipeline import StreamReport

    report = StreamReport(n_frames=0, budget=0.0, policy="all")
    quilts = (r.quilt for r in pipe.iter_stream(frames, fps=fps, output="quilt", policy="all", base=base,
                                                 report=report))
    vpath = write_quilt_video(out / quilt_filename(f"{stem}_reaction", cal.cols, cal.rows, cal.aspect,
                                                   suffix=".mp4"), quilts, fps=fps, total=len(frames),
                              preset="veryfast")
    step("reaction quilt video", t_video, f"{vpath.name}: {report.summary()}")
    steps.close()
    total = time.perf_counter() - t_all

    # timing tables
    print()
    print(format_timing_table(rows + [("total", total, "")]))
    print()
    per = report.stage_seconds
    n = max(1, len(report.rendered))
    stage_rows = []
    for s in STAGES:
        a, b = getattr(first, s), getattr(per, s)
        stage_rows.append((s, a or 0.0, "" if b is None else f"video: {b / n * 1e3:.1f} ms/frame"))
    print("pipeline stages (first full quilt + native; video mean per frame):")
    print(format_timing_table(stage_rows))
    record = {"steps": {r[0]: {"seconds": r[1], "note": r[2]} for r in rows}, "total_seconds": total,
              "first_quilt_stage_seconds": first.as_dict(),
              "video": {"frames": len(report.rendered), "fps": fps, "requested_fps": args.fps,
                        "tile_scale": args.video_scale,
                        "stage_seconds_per_frame": {k: (v / n if v is not None else None)
                                                    for k, v in per.as_dict().items()},
                        "late_frames": len(report.late), "achieved_fps": report.achieved_fps},
              "config": {"smile": args.smile, "pain": args.pain, "seconds": args.seconds,
                         "behaviour": None if behaviour is None else behaviour.to_dict(),
                         "renderer": args.renderer, "n_gaussians": len(pipe.avatar)}}
    with atomic_write(out / "timings.json", "w") as fh:
        json.dump(record, fh, indent=2, default=lambda o: float(o) if isinstance(o, np.floating) else str(o))
    print(f"\nwrote {qpath}\nwrote {npath}\nwrote {vpath}\nwrote {out / 'timings.json'}")
    return 0
