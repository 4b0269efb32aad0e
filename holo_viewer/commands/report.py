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


def run(args: argparse.Namespace) -> int:
    """Write the report (and the review video); returns 0."""
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
    return 0
