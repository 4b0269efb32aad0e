"""``holo-viewer replay``: re-render a recorded live session to a native-image video, deterministically."""

from __future__ import annotations

import argparse

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``replay``."""
    parser.add_argument("session", metavar="SESSION", help="a session folder written by `holo-viewer live`")
    parser.add_argument("--out", required=True, metavar="VIDEO.mkv", help="native-image video, lossless RGB "
                        "(.mkv or .mp4; written atomically)")
    parser.add_argument("--quality", choices=("full", "live"), default="full",
                        help="full (default): every 25 fps frame with every view rendered (the exact quilt); live: "
                             "the displayed frames as the live renderer drew them (native.mkv again, bit-exact), at "
                             "the times they were shown")
    parser.add_argument("--tile-scale", type=float, default=None,
                        help="quilt tile scale (default: the session's)")
    parser.add_argument("--every", type=int, default=1, metavar="N",
                        help="render every N-th 25 fps frame (the video plays at 25 / N fps; default 1)")


def run(args: argparse.Namespace) -> int:
    """Render every recorded frame (listener FLAME arrays, pain, viewer pose); returns 0."""
    from ..errors import InputError
    from ..live.replay import replay_session

    if args.every < 1:
        raise InputError(f"--every: expected >= 1, found {args.every}")
    if args.quality == "live" and (args.every != 1 or args.tile_scale is not None):
        raise InputError("--quality live: replays the displayed frames at the session's tile scale; "
                         "--every and --tile-scale are for --quality full")
    n = replay_session(args.session, args.out, tile_scale=args.tile_scale, every=args.every, quality=args.quality)
    print(f"wrote {args.out}: {n} frames")
    return 0
