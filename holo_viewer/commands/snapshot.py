"""``holo-viewer snapshot``: the viewer's window rendered offscreen (OSMesa) to a PNG.

It draws what ``holo-viewer view`` draws, with the same ellipsoid options and defaults."""

from __future__ import annotations

import argparse
from typing import Any

from .view import add_glyph_arguments, glyph_config

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="holo_viewer_snapshot.png", help="PNG file to write (atomic)")
    from .avatar_args import add_avatar_argument

    add_avatar_argument(parser, help="what the image shows (as for view)")
    parser.add_argument("--flame-model", default=None, metavar="PKL")
    parser.add_argument("--flame-params", default=None, metavar="NPZ")
    parser.add_argument("--calibration", default=None, metavar="JSON")
    from .renderer_args import add_renderer_argument

    add_renderer_argument(parser, help="splat renderer")
    parser.add_argument("--pain", type=float, default=0.0)
    parser.add_argument("--smile", type=float, default=0.0)
    parser.add_argument("--window-size", type=int, nargs=2, default=(1400, 800), metavar=("W", "H"))
    parser.add_argument("--help-overlay", action="store_true", help="draw the key help in the image")
    parser.add_argument("--expr", action="append", default=[], metavar="NAME=VALUE",
                        help="set a face slider as in the viewer's value entry (an AU code such as au9, or smile, "
                             "jaw, pain); repeatable")
    parser.add_argument("--view", type=int, default=None, metavar="K", help="selected view (preview panel)")
    parser.add_argument("--angle", type=float, default=None, metavar="DEG",
                        help="viewer angle in degrees (the viewer's slider range)")
    parser.add_argument("--close-up", action="store_true", help="frame the head only (the viewer's key z)")
    add_glyph_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..pipeline.scene import load_scene
    from ..gui.offscreen_viewer import offscreen_viewer
    from ..pipeline import FaceControls

    face = FaceControls(pain=args.pain, named=(("smile", args.smile),) if args.smile > 0 else ())
    scene = load_scene(args.avatar, args.flame_model, args.flame_params, args.calibration, backend=args.renderer,
                       face=face)
    with offscreen_viewer(scene, window_size=tuple(args.window_size), **glyph_config(args)) as viewer:
        apply_settings(viewer, args)
        if args.help_overlay:
            viewer.toggle_help()
        path = viewer.save_screenshot(args.out)
    print(f"wrote {path}")
    return 0


def apply_settings(viewer: Any, args: argparse.Namespace) -> None:
    """Set ``--expr``, ``--angle`` and ``--view`` through the viewer's value entry (same names, ranges and
    errors as typing them in the window), then ``--close-up``; waits for the thumbnail."""
    from ..errors import InputError

    entries = []
    for item in args.expr:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise InputError(f"--expr: expected NAME=VALUE (e.g. au9=1 or pain=0.6), found {item!r}")
        entries.append(f"{name.strip()} {value.strip()}")
    if args.angle is not None:
        entries.append(f"angle {args.angle}")
    if args.view is not None:
        entries.append(f"view {args.view}")
    for text in entries:
        n_errors = len(viewer.errors)
        viewer.apply_entry(text)
        if len(viewer.errors) > n_errors:  # the release handler put it on the status line
            raise InputError(viewer.errors[-1])
    if args.close_up:
        viewer.head_closeup()
    if entries:
        viewer._update_thumbnail(wait=True)
