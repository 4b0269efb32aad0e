"""``holo-viewer report``: the debrief of a recorded live session (a PNG, a text summary, a review video)."""

from __future__ import annotations

import argparse

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``report``."""
    parser.add_argument("session", metavar="SESSION", help="a session folder written by `holo-viewer live`")
    parser.add_argument("--out", required=True, metavar="REPORT.png", help="the report picture (the text summary "
                        "is printed and written next to it as REPORT.txt)")
    parser.add_argument("--ratings", metavar="RATINGS.csv", help="first add trainees' ratings to the session from a "
                        "CSV with columns t (session seconds), trainee, rating (0-10)")
    parser.add_argument("--video", metavar="REVIEW.mp4", help="also write the review video: the native video at "
                        "25 fps with the session's audio")
    parser.add_argument("--compact", action="store_true", help="then compact the session's video as `holo-viewer "
                        "compact` does (an FFVHuff native.mkv to x264rgb crf 0, verified bit-exact)")


def run(args: argparse.Namespace) -> int:
    """Write the report (and the review video; then compact the session with ``--compact``); returns 0, or 1 if
    the compaction failed (the original video stays)."""
    from pathlib import Path

    from ..fileio import atomic_write
    from ..live.report import plot_report, review_video, session_report
    from ..live.session import add_ratings_csv

    if args.ratings:
        n = add_ratings_csv(args.session, args.ratings)
        print(f"added {n} ratings from {args.ratings} to {args.session}/session.json")
    report = session_report(args.session)
    out = plot_report(report, args.out)
    text = report.text()
    with atomic_write(Path(out).with_suffix(".txt"), "w") as fh:
        fh.write(text + "\n")
    print(text)
    print(f"wrote {out} and {Path(out).with_suffix('.txt')}")
    if args.video:
        print(f"wrote {review_video(args.session, args.video)}")
    if args.compact:
        from types import SimpleNamespace

        from .compact import run as compact

        return compact(SimpleNamespace(sessions=[args.session], threads=0, no_progress=False))
    return 0
