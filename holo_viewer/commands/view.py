"""``holo-viewer view``: the interactive inspection window (PyVista/VTK, no Qt; or Open3D)."""

from __future__ import annotations

import argparse
import os
import sys

__all__ = ["add_arguments", "add_glyph_arguments", "glyph_config", "require_display", "run"]


def add_glyph_arguments(parser: argparse.ArgumentParser) -> None:
    """Ellipsoid options shared by ``view`` and ``snapshot`` (defaults from ``ViewerConfig``)."""
    from ..gui.scene import GLYPH_COLOR_MODES

    # the numbers below are ViewerConfig's defaults, repeated so that --help needs no VTK import;
    # tests/test_gui.py checks that they agree
    parser.add_argument("--max-glyphs", type=int, default=2500, metavar="N",
                        help="Gaussians drawn as ellipsoids (default 2500; slider 'ellipsoids drawn')")
    parser.add_argument("--glyph-sigmas", type=float, default=1.5, metavar="S",
                        help="ellipsoid radius in standard deviations (default 1.5)")
    parser.add_argument("--glyph-min-opacity", type=float, default=0.5, metavar="O",
                        help="draw only Gaussians at least this opaque (default 0.5)")
    parser.add_argument("--glyph-color", choices=GLYPH_COLOR_MODES, default="colour",
                        help="colour ellipsoids by their own colour, their opacity or their size (default colour)")


def glyph_config(args: argparse.Namespace) -> dict:
    """The ``ViewerConfig`` fields set by :func:`add_glyph_arguments`."""
    return {"max_glyphs": args.max_glyphs, "glyph_sigmas": args.glyph_sigmas,
            "glyph_min_opacity": args.glyph_min_opacity, "glyph_color": args.glyph_color}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .avatar_args import add_avatar_argument

    add_avatar_argument(parser, help="what the window shows")
    parser.add_argument("--flame-model", default=None, metavar="PKL",
                        help="FLAME model .pkl/.npz (default: the embedded default head)")
    parser.add_argument("--flame-params", default=None, metavar="NPZ",
                        help="flame_param.npz sequence; frame 0 is shown and a slider scrubs the frames")
    parser.add_argument("--calibration", default=None, metavar="JSON",
                        help="Looking Glass visual.json or preset name (default: the shipped Portrait calibration)")
    parser.add_argument("--toolkit", choices=("pyvista", "open3d"), default=None,
                        help="window toolkit (default pyvista; open3d needs the optional extra, from a checkout: "
                             "pip install -e \".[open3d]\")")
    parser.add_argument("--backend", choices=("pyvista", "open3d"), default=None, dest="backend_deprecated",
                        help=argparse.SUPPRESS)  # the old name of --toolkit
    from .renderer_args import add_renderer_argument

    add_renderer_argument(parser, help="splat renderer of the preview")
    parser.add_argument("--out-dir", default="holo_viewer_out", help="folder for exports (keys k, n, x, i)")
    add_glyph_arguments(parser)
    parser.add_argument("--pain", type=float, default=0.0, help="initial pain intensity in [0, 1]")
    parser.add_argument("--window-size", type=int, nargs=2, default=None, metavar=("W", "H"),
                        help="window size in pixels (default: 94%% x 86%% of the screen, at most 1600 x 960)")


def require_display() -> None:
    """Raise DisplayError unless an X display can be opened (the window needs one)."""
    from ..errors import DisplayError

    hint = ("run it under a virtual X server: xvfb-run -a holo-viewer view ..., or render the same scene to a "
            "PNG without a display: holo-viewer snapshot --out viewer.png")
    if not sys.platform.startswith("linux"):
        return  # VTK opens native windows on macOS / Windows
    display = os.environ.get("DISPLAY", "")
    if not display:
        raise DisplayError(f"view: no X display (DISPLAY is not set); {hint}")
    from ..gui.screen import x_screen_size

    try:
        x_screen_size(display)
    except OSError:
        raise DisplayError(f"view: cannot open the X display DISPLAY={display}; {hint}") from None

def run(args: argparse.Namespace) -> int:
    from ..pipeline.scene import load_scene
    from ..pipeline import FaceControls

    toolkit = args.toolkit
    if args.backend_deprecated is not None:
        print("holo-viewer view: --backend is deprecated, use --toolkit", file=sys.stderr)
        toolkit = toolkit or args.backend_deprecated
    toolkit = toolkit or "pyvista"
    if toolkit == "open3d":
        from ..gui.open3d_viewer import require_open3d

        require_open3d()  # fail before loading anything
    require_display()
    scene = load_scene(args.avatar, args.flame_model, args.flame_params, args.calibration, backend=args.renderer,
                       face=FaceControls(pain=args.pain))
    print(f"holo-viewer view: {scene.description}")
    if toolkit == "open3d":
        from ..gui.open3d_viewer import run_open3d_viewer

        run_open3d_viewer(scene.pipeline, max_glyphs=args.max_glyphs)
        return 0
    from ..gui.viewer import HoloViewer, ViewerConfig

    size = None if args.window_size is None else tuple(args.window_size)
    cfg = ViewerConfig(window_size=size, out_dir=args.out_dir, **glyph_config(args))
    viewer = HoloViewer(scene.pipeline, cfg, frames=scene.frames)  # retries a refused X window itself
    if hasattr(viewer, "set_avatar"):  # the patient chooser: keys P / O step through default and the patients
        from ..gui.patient_chooser import bind_patient_keys

        viewer.patient_name = args.avatar
        bind_patient_keys(viewer)
    print("press h in the window for the keys (q quits)")
    viewer.show()
    for path in viewer.exports:
        print(f"wrote {path}")
    for err in viewer.errors:
        print(f"error shown in the window: {err}", file=sys.stderr)
    return 0
