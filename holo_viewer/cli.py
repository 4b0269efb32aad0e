"""``holo-viewer`` command line: a thin dispatcher.

Each subcommand lives in ``holo_viewer/commands/<module>.py`` and exposes

* ``add_arguments(parser: argparse.ArgumentParser) -> None``
* ``run(args: argparse.Namespace) -> int`` (the exit code)

Only the chosen subcommand's module is imported, so ``holo-viewer --help`` is fast
and never loads vtk, torch or usb. Exit codes: 0 success, 1 a
:class:`~holo_viewer.errors.HoloViewerError` (message on stderr), 2 usage error,
130 interrupted (Ctrl-C), 143 terminated (SIGTERM; temporary files are removed as on Ctrl-C).
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading
from typing import Sequence

from . import __version__
from .errors import HoloViewerError

__all__ = ["main", "SUBCOMMANDS"]

#: name -> (module under holo_viewer.commands, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("demo", "run the main job on the default avatar: quilt, native image, reaction video"),
    "export-mesh": ("export_mesh", "write the posed FLAME head (default or loaded) as OBJ/PLY/GLB"),
    "render-ply": ("render_ply", "render a 3DGS PLY for the cameras in a JSON file"),
    "quilt-to-native": ("quilt_to_native", "interleave a quilt PNG into the panel's native lenticular image"),
    "devices": ("devices", "list connected Looking Glass devices and their calibration"),
    "show": ("show", "show a native image, quilt or video fullscreen on the Looking Glass"),
    "view": ("view", "interactive PyVista viewer: mesh, Gaussians, camera frusta, sliders"),
    "snapshot": ("snapshot", "render the viewer scene offscreen to a PNG"),
    "train-reaction": ("train_reaction", "train the listener-reaction model"),
    "evaluate-reactions": ("evaluate_reactions", "REACT metrics of the model and baselines on the test split"),
    "react": ("react", "generate listener FLAME parameters from speaker audio and features"),
    "render-batch": ("render_batch", "render many clips from a manifest to quilt/native videos (Ray or in-process)"),
    "track": ("track", "track a speaker's face in a video: speaker.npz (25 fps FLAME parameters) for react"),
    "live": ("live", "live session: microphone + webcam (or replayed files) -> reacting, viewer-tracked hologram"),
    "replay": ("replay", "re-render a recorded live session to a native-image video, deterministically"),
    "report": ("report", "debrief a recorded live session: report.png, a text summary, a review video with audio"),
    "compact": ("compact", "re-encode finished sessions' FFVHuff native.mkv to x264 (lossless), verified bit-exact"),
    "patients": ("patients", "list the shipped patients, one a line, name first (--sheet F.png: thumbnails)"),
}


def _build_parser(selected: str | None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="holo-viewer",
        description="Talking-face Gaussian avatars as holograms on Looking Glass displays.",
    )
    parser.add_argument("--version", action="version", version=f"holo-viewer {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == selected:
            mod = importlib.import_module(f"holo_viewer.commands.{module}")
            mod.add_arguments(p)
            p.set_defaults(_run=mod.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``holo-viewer`` console script; returns the exit code."""
    console = argv is None  # the console script / python -m: the process ends with the command
    argv = list(sys.argv[1:] if argv is None else argv)
    selected = next((a for a in argv if not a.startswith("-")), None)
    if selected not in SUBCOMMANDS:
        selected = None
    parser = _build_parser(selected)
    args = parser.parse_args(argv)
    if getattr(args, "_run", None) is None:
        parser.print_help()
        return 0 if not argv else 2
    previous = _install_sigterm()
    try:
        code = int(args._run(args) or 0)
        if console and args.command in QUICK_EXIT:
            _quick_exit(code)
        return code
    except HoloViewerError as exc:
        print(f"holo-viewer {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


#: commands whose process ends at once when they return (console only): live's quit <= 2 s (issue 33)
QUICK_EXIT = ("live", "replay")


def _quick_exit(code: int) -> None:
    """End the process now: run the atexit handlers, flush stdio, skip the interpreter's teardown
    (2 s of CPU freeing torch, numba and the renderer's tables after a live session: 6 s at load 12).
    Every file the command writes is closed and renamed into place before it returns."""
    import atexit
    import os

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


class Terminated(BaseException):
    """Raised in the main thread on SIGTERM so that ``finally`` blocks (temp-file cleanup) run.

    A BaseException like KeyboardInterrupt: ``except Exception`` handlers do not swallow it.
    """


def _on_sigterm(signum: int, frame: object) -> None:
    raise Terminated()


def _install_sigterm():  # noqa: ANN202 - the previous handler, or None when not installed
    """SIGTERM -> :class:`Terminated` while a subcommand runs (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    try:
        return signal.signal(signal.SIGTERM, _on_sigterm)
    except (ValueError, OSError):  # pragma: no cover - no signals here
        return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
