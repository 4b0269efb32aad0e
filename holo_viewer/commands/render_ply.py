"""``holo-viewer render-ply SCENE.ply --cameras CAMS.json --out DIR``: render any 3DGS PLY.

The cameras file is a JSON list of objects, one per view, in OpenCV conventions
(:meth:`holo_viewer.camera.Cameras.from_dicts`)::

    [{"width": 420, "height": 560, "fx": 2277.5, "fy": 2277.5, "cx": 210.0, "cy": 280.0,
      "world_to_cam": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0.98], [0, 0, 0, 1]]}, ...]

(optional "near"/"far" in metres, equal for all views). Views are written as
``DIR/view_000.png, view_001.png, ...`` (each file atomically), rendered in batches of
views so the progress bar moves; one batch shares the backend's per-quilt work. A batch
holds at most ``BATCH_PIXELS`` pixels (views larger than a tile are rendered fewer at a time);
a camera larger than :data:`~holo_viewer.camera.MAX_IMAGE_SIDE` / ``MAX_IMAGE_PIXELS`` is refused.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from ..errors import InputError
from ..fileio import check_json_depth

__all__ = ["add_arguments", "run", "parse_background", "load_cameras"]

#: pixels rendered per backend call at most (a batch of big views is split; 16 LGP tiles are 3.8 Mpx)
BATCH_PIXELS = 32 * 1024 * 1024


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE.ply", help="3DGS PLY file (Inria layout)")
    parser.add_argument("--cameras", required=True, metavar="CAMS.json",
                        help='JSON list of {"width","height","fx","fy","cx","cy","world_to_cam"(4x4 row-major, '
                             'OpenCV)}')
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory for view_000.png, ...")
    from .renderer_args import add_renderer_argument

    add_renderer_argument(parser, help="renderer (auto = gsplat on CUDA when it runs, else fast)",
                          old_spelling="--backend")
    parser.add_argument("--background", default="0,0,0", metavar="R,G,B",
                        help="background colour, three numbers in [0, 1] (default 0,0,0)")
    parser.add_argument("--sh-degree", type=int, default=None, choices=(0, 1, 2, 3),
                        help="highest SH degree used (default: all the PLY holds)")
    parser.add_argument("--batch", type=int, default=16, metavar="V",
                        help="views rendered per backend call (default 16)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def parse_background(text: str) -> tuple[float, float, float]:
    """``"R,G,B"`` -> three floats in [0, 1]; InputError naming ``--background`` otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in vals):
        raise InputError(f"--background: expected R,G,B with three numbers in [0, 1] (e.g. 0,0,0 or 1,1,1), "
                         f"found {text!r}")
    return vals  # type: ignore[return-value]


def load_cameras(path: str | Path):  # noqa: ANN201 - Cameras, imported lazily
    """Read a cameras JSON file (see module docstring) into :class:`~holo_viewer.camera.Cameras`.

    Raises
    ------
    InputError
        Missing/unreadable file, invalid JSON (with line and column), or a malformed camera
        (the message names the file, the camera index and the field).
    """
    from ..camera import Cameras

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"--cameras {path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"--cameras {path}: cannot read ({exc})") from None
    check_json_depth(text, InputError, f"--cameras {path}", "the camera JSON")
    try:
        items = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"--cameras {path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    return Cameras.from_dicts(items, source=str(path))


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..avatar.ply import load_ply
    from ..fileio import ensure_dir, save_image
    from ..render.api import render_views
    from ..render.config import RenderConfig

    background = parse_background(args.background)
    if args.batch < 1:
        raise InputError(f"--batch: expected a positive number of views, found {args.batch}")
    scene = Path(args.scene)
    if not scene.is_file():
        raise InputError(f"SCENE.ply {scene}: file not found")
    cameras = load_cameras(args.cameras)
    gaussians = load_ply(scene)
    config = RenderConfig(background=background, sh_degree=args.sh_degree)
    out = ensure_dir(args.out, "output directory (--out)")
    n = len(cameras)
    batch = max(1, min(args.batch, BATCH_PIXELS // (cameras.width * cameras.height)))
    t0 = time.perf_counter()
    used = args.renderer
    with tqdm(total=n, desc=f"render-ply ({args.renderer})", unit="view", disable=args.quiet,
              file=sys.stderr) as bar:
        for v0 in range(0, n, batch):
            idx = list(range(v0, min(v0 + batch, n)))
            result = render_views(gaussians, cameras[idx], backend=args.renderer, config=config)
            used = result.backend
            for k, i in enumerate(idx):
                save_image(out / f"view_{i:03d}.png", result.images[k])
                bar.update(1)
    print(f"wrote {n} views ({cameras.width}x{cameras.height}) to {out} with {used} "
          f"in {time.perf_counter() - t0:.2f} s")
    return 0
