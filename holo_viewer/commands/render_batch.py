"""``holo-viewer render-batch``: render every job of a manifest (see docs/batch.md)."""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``render-batch``."""
    parser.add_argument("manifest", metavar="MANIFEST", help="jobs, one per row: .jsonl or .csv (docs/batch.md)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output folder; a re-run into the same folder skips finished jobs")
    parser.add_argument("--address", default=None, metavar="ADDR",
                        help="Ray cluster to join: 'auto' (this node's cluster) or ray://HOST:10001; "
                             "default: start a local Ray")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="chunks rendered at once (default: CPUs // --threads-per-worker)")
    parser.add_argument("--threads-per-worker", type=int, default=1, metavar="T",
                        help="renderer threads per worker (default 1)")
    parser.add_argument("--chunk-frames", type=int, default=None, metavar="F",
                        help="frames per chunk; longer clips are split across workers (default 25)")
    parser.add_argument("--in-process", action="store_true",
                        help="render here, one chunk after another, even when Ray is installed")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    from .behaviour_args import add_behaviour_arguments

    add_behaviour_arguments(parser, pain_timeline=False)  # a row's own pain_timeline / behaviour field


def run(args: argparse.Namespace) -> int:
    """Run the batch; 0 when every job is done or skipped, 1 when a job failed."""
    from tqdm import tqdm

    from ..batch import make_executor, run_batch
    from ..batch.runner import DEFAULT_CHUNK_FRAMES
    from ..errors import InputError

    for name in ("workers", "threads_per_worker", "chunk_frames"):
        v = getattr(args, name)
        if v is not None and v < 1:
            raise InputError(f"--{name.replace('_', '-')}: expected a positive integer, found {v}")

    def log(msg: str) -> None:
        tqdm.write(msg, file=sys.stderr)

    from ..behaviour import LAYERS

    off = ("behaviour",) if args.no_behaviour else tuple(n for n in LAYERS if getattr(args, f"no_{n}"))
    executor = make_executor(args.address, args.workers, args.threads_per_worker, in_process=args.in_process,
                             log=log)
    try:
        summary = run_batch(args.manifest, args.out, executor, chunk_frames=args.chunk_frames or DEFAULT_CHUNK_FRAMES,
                            progress=not args.no_progress, log=log, behaviour_off=off)
    finally:
        executor.close()
    counts = ", ".join(f"{n} {k}" for k, n in sorted(summary.counts().items()))
    print(f"render-batch: {len(summary.jobs)} jobs ({counts}) in {summary.seconds:.1f} s, "
          f"{summary.frames_rendered} frames rendered; summary: {args.out}/summary.json")
    for job in summary.failed:
        print(f"render-batch: failed: {job.error}", file=sys.stderr)
    return 1 if summary.failed else 0
