"""Stream a FLAME sequence (or a fresh listener reaction) through the pipeline with a frame budget.

Examples
--------
Live-display policy (drop frames when behind) on the reaction model's output::

    python apps/stream_sequence.py --reaction --seconds 2 --fps 25 --output quilt

Every frame of a GaussianAvatars sequence, written as a quilt video::

    python apps/stream_sequence.py --flame-params flame_param.npz --avatar point_cloud.ply \\
        --flame-model generic_model.pkl --policy all --video out/seq_qs8x6a0.75.mp4

Prints the stream report (rendered, dropped, held, late frames) and the mean stage timings.
"""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    from holo_viewer.pipeline.stages import STREAM_OUTPUTS
    from holo_viewer.validation import fps_arg

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--flame-params", metavar="NPZ", help="flame_param.npz sequence")
    src.add_argument("--reaction", action="store_true", help="generate a listener reaction to a synthetic speaker")
    ap.add_argument("--avatar", default="default", help="'default', 'none' or a PLY")
    ap.add_argument("--flame-model", default=None)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--pain", type=float, default=0.5)
    ap.add_argument("--fps", type=fps_arg, default=25.0)
    ap.add_argument("--output", default="quilt", choices=STREAM_OUTPUTS)
    ap.add_argument("--policy", default="drop", choices=("drop", "all"))
    ap.add_argument("--tile-scale", type=float, default=1.0)
    ap.add_argument("--video", default=None, help="write the computed quilts as mp4 (needs --output quilt)")
    args = ap.parse_args(argv)

    from holo_viewer.errors import HoloViewerError
    from holo_viewer.pipeline import STAGES, StreamReport, load_scene, reaction_frames

    try:
        scene = load_scene(args.avatar, args.flame_model, args.flame_params)
        pipe = scene.pipeline
        pipe.set_view(tile_scale=args.tile_scale)
        if args.reaction:
            frames, _ = reaction_frames(seconds=args.seconds, pain=args.pain, au_map=pipe.au_map)
        else:
            frames = scene.frames or []
        report = StreamReport(n_frames=0, budget=0.0, policy=args.policy)
        results = pipe.iter_stream(frames, fps=args.fps, output=args.output, policy=args.policy, report=report,
                                   progress=args.video is None)
        if args.video:
            if args.output != "quilt":
                raise SystemExit("--video needs --output quilt")
            from holo_viewer.display.export import write_quilt_video

            write_quilt_video(args.video, (r.quilt for r in results), fps=args.fps, total=len(frames))
        else:
            for _ in results:
                pass
    except HoloViewerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(report.summary())
    n = max(1, len(report.rendered))
    for s in STAGES:
        v = getattr(report.stage_seconds, s)
        if v is not None:
            print(f"  {s:<10} {v / n * 1e3:9.1f} ms/frame")
    return 0


if __name__ == "__main__":
    sys.exit(main())
