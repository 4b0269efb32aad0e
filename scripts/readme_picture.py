"""Regenerate docs/images/avatar_views.png, the README's picture.

The default avatar smiling with pain (the demo's quilt settings), seen by the leftmost, centre and
rightmost of the Portrait's 48 quilt cameras, beside the centre of the lenticular native image (magnified 2x).
Usage: python scripts/readme_picture.py [--out docs/images/avatar_views.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from holo_viewer.fileio import save_image
from holo_viewer.images import to_uint8
from holo_viewer.pipeline import FaceControls, Pipeline, ViewSettings


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs/images/avatar_views.png")
    args = ap.parse_args()
    pipe = Pipeline(face=FaceControls(named=(("smile", 0.8),), pain=0.6), view=ViewSettings(tile_scale=0.5))
    views = pipe.views()  # (48, 280, 210, 3)
    picked = [views[0], views[len(views) // 2], views[-1]]
    native = pipe.native()  # (2048, 1536, 3) uint8: its centre, magnified 2x to show the interleave
    h, w = views.shape[1], views.shape[2]
    cy, cx = native.shape[0] // 2, native.shape[1] // 2
    crop = native[cy - h // 4: cy + h // 4, cx - w // 4: cx + w // 4].repeat(2, axis=0).repeat(2, axis=1)
    gap = np.full((h, 6, 3), 255, np.uint8)
    row = [to_uint8(v) for v in picked] + [crop]
    sheet = np.concatenate([x for v in row for x in (v, gap)][:-1], axis=1)
    print(save_image(args.out, sheet), sheet.shape)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
