"""``holo-viewer view``: the interactive inspection window (PyVista, no Qt; or Open3D)."""

from __future__ import annotations

import argparse

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--avatar", default="default",
                        help="'default' (embedded head + avatar), 'none' (mesh only), or a 3DGS / GaussianAvatars PLY")
    parser.add_argument("--flame-model", default=None, metavar="PKL",
                        help="FLAME model .pkl/.npz (default: the embedded default head)")
    parser.add_argument("--flame-params", default=None, metavar="NPZ",
                        help="flame_param.npz sequence; frame 0 is shown and a slider scrubs the frames")
    parser.add_argument("--calibration", default=None, metavar="JSON",
                        help="Looking Glass visual.json or preset name (default: the shipped Portrait calibration)")
    parser.add_argument("--backend", choices=("pyvista", "open3d"), default="pyvista",
                        help="window toolkit (open3d needs the optional extra: pip install 'holo_viewer[open3d]')")
    parser.add_argument("--renderer", default="fast", help="splat renderer backend for the preview (default fast)")
    parser.add_argument("--out-dir", default="holo_viewer_out", help="folder for exports (keys k, n, x, i)")
    parser.add_argument("--max-glyphs", type=int, default=2500, help="Gaussians drawn as ellipsoids")
    parser.add_argument("--pain", type=float, default=0.0, help="initial pain intensity in [0, 1]")
    parser.add_argument("--window-size", type=int, nargs=2, default=(1400, 800), metavar=("W", "H"))


def run(args: argparse.Namespace) -> int:
    from ..gui.loading import load_scene
    from ..pipeline import FaceControls

    if args.backend == "open3d":
        from ..gui.open3d_viewer import require_open3d

        require_open3d()  # fail before loading anything
    scene = load_scene(args.avatar, args.flame_model, args.flame_params, args.calibration, backend=args.renderer,
                       face=FaceControls(pain=args.pain))
    print(f"holo-viewer view: {scene.description}")
    if args.backend == "open3d":
        from ..gui.open3d_viewer import run_open3d_viewer

        run_open3d_viewer(scene.pipeline, max_glyphs=args.max_glyphs)
        return 0
    from ..gui.viewer import HoloViewer, ViewerConfig

    cfg = ViewerConfig(window_size=tuple(args.window_size), max_glyphs=args.max_glyphs, out_dir=args.out_dir)
    viewer = HoloViewer(scene.pipeline, cfg, frames=scene.frames)
    print("keys: h help, m mesh, l wireframe, g Gaussians, o frusta, k quilt, n native, x sweep video, "
          "i screenshot, q quit")
    viewer.show()
    for path in viewer.exports:
        print(f"wrote {path}")
    return 0
