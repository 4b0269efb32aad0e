"""Render a named-expression sweep of the default avatar as quilt PNGs and a contact sheet of centre views.

Example::

    python apps/render_expression_sweep.py --expression smile --steps 5 --pain 0.3 --out out/sweep

Writes ``OUT/smile_00_qs8x6a0.75.png`` ... (one quilt per step) and ``OUT/smile_centre_views.png``
(the middle view of every step side by side), atomically, and prints the stage timings per step.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--expression", default="smile",
                    choices=("smile", "pain", "surprise", "frown", "mouth_open"))
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--pain", type=float, default=0.0)
    ap.add_argument("--tile-scale", type=float, default=0.5)
    ap.add_argument("--out", default="out/sweep")
    args = ap.parse_args(argv)

    import numpy as np

    from holo_viewer.display.quilt import quilt_filename
    from holo_viewer.errors import HoloViewerError
    from holo_viewer.fileio import save_image
    from holo_viewer.pipeline import FaceControls, Pipeline, ViewSettings

    try:
        pipe = Pipeline(view=ViewSettings(tile_scale=args.tile_scale), face=FaceControls(pain=args.pain))
        cal, out = pipe.calibration, Path(args.out)
        centres = []
        for k, w in enumerate(np.linspace(0.0, 1.0, max(2, args.steps))):
            pipe.set_face(pipe.face.with_named(args.expression, float(w)))
            (views, quilt), t = pipe.compute("views", "quilt")
            path = save_image(out / quilt_filename(f"{args.expression}_{k:02d}", cal.cols, cal.rows, cal.aspect), quilt)
            centres.append(views[len(views) // 2])
            print(f"{path}  intensity {w:.2f}  " + "  ".join(f"{s} {v * 1e3:.0f} ms" for s, v in t.as_dict().items()
                                                              if v is not None))
        sheet = save_image(out / f"{args.expression}_centre_views.png", np.concatenate(centres, axis=1))
        print(sheet)
    except HoloViewerError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
