"""``holo-viewer snapshot``: the viewer's window rendered offscreen (OSMesa) to a PNG.

It draws what ``holo-viewer view`` draws, with the same ellipsoid options and defaults."""

from __future__ import annotations

import argparse

from .view import add_glyph_arguments, glyph_config

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="holo_viewer_snapshot.png", help="PNG file to write (atomic)")
    parser.add_argument("--avatar", default="default", help="'default', 'none' or a PLY (as for view)")
    parser.add_argument("--flame-model", default=None, metavar="PKL")
    parser.add_argument("--flame-params", default=None, metavar="NPZ")
    parser.add_argument("--calibration", default=None, metavar="JSON")
    from .renderer_args import add_renderer_argument

    add_renderer_argument(parser, help="splat renderer")
    parser.add_argument("--pain", type=float, default=0.0)
    parser.add_argument("--smile", type=float, default=0.0)
    parser.add_argument("--window-size", type=int, nargs=2, default=(1400, 800), metavar=("W", "H"))
    parser.add_argument("--help-overlay", action="store_true", help="draw the key help in the image")
    add_glyph_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ..pipeline.scene import load_scene
    from ..gui.offscreen_viewer import offscreen_viewer
    from ..pipeline import FaceControls

    face = FaceControls(pain=args.pain, named=(("smile", args.smile),) if args.smile > 0 else ())
    scene = load_scene(args.avatar, args.flame_model, args.flame_params, args.calibration, backend=args.renderer,
                       face=face)
    with offscreen_viewer(scene, window_size=tuple(args.window_size), **glyph_config(args)) as viewer:
        if args.help_overlay:
            viewer.toggle_help()
        path = viewer.save_screenshot(args.out)
    print(f"wrote {path}")
    return 0
