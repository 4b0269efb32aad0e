"""``holo-viewer track``: a video of a speaker -> speaker.npz (25 fps FLAME parameters) for ``react``."""

from __future__ import annotations

import argparse

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``track``."""
    parser.add_argument("video", metavar="VIDEO", help="video of one speaker's face (mp4, avi, ...; any frame rate)")
    parser.add_argument("--out", required=True, metavar="SPEAKER.npz",
                        help="output: expr, jaw_pose, rotation at 25 fps (what `react --speaker` reads) plus "
                             "state, found, head_position, landmarks, rms_px; written atomically")
    parser.add_argument("--hfov", type=float, default=60.0, metavar="DEG",
                        help="the camera's horizontal field of view in degrees (default 60)")
    parser.add_argument("--no-smoothing", action="store_true", help="write the raw per-frame fits (no One-Euro filter)")
    parser.add_argument("--redetect-every", type=int, default=10, metavar="N",
                        help="run the face detector every N frames, tracking the face in between (default 10)")


def run(args: argparse.Namespace) -> int:
    """Track the video and write SPEAKER.npz; returns 0."""
    from tqdm import tqdm

    from ..fileio import save_npz
    from ..tracking.tracker import TrackerConfig
    from ..tracking.video import track_video

    config = TrackerConfig(hfov_deg=args.hfov, redetect_every=args.redetect_every,
                           **({"smoothing": None} if args.no_smoothing else {}))
    with tqdm(desc="track", unit="frame") as bar:
        out = track_video(args.video, config, progress=lambda n: bar.update(1))
    save_npz(args.out, **out)
    found = out["found"]
    print(f"wrote {args.out}: {len(found)} frames at 25 fps, face found in {int(found.sum())} "
          f"({100 * found.mean():.0f} %)")
    return 0
