"""Render frames of the listening patient for docs/behaviour.md: a blink, a gaze aversion, a pain flare,
and the eyes on a viewer at the side seen from that viewer's view and from the centre view; and the
pain face at levels 0, 0.2 ... 1.0 from the centre view.

Usage::

    python scripts/behaviour_frames.py [--out docs/images/behaviour_frames.jpg] [--levels-out docs/images/pain_levels.jpg]

The reaction is the shipped model's to a synthesized speaker (as the demo), 20 s at pain level 0.6,
with every behaviour layer on (the default); the frames are picked from it: the deepest blink, the
largest aversion, the flare's apex, a frame looking at the viewer. Prints the picked frames' numbers.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def gaze_error_deg(params: dict, target: np.ndarray) -> np.ndarray:
    """(T,) the larger of the two eyes' angles between gaze and the target, degrees."""
    from holo_viewer.behaviour import eye_directions

    c, d = eye_directions(params["rotation"], params["neck_pose"], params["eyes_pose"], params["translation"])
    v = target - c
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip((v * d).sum(-1), -1, 1))).max(axis=1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/images/behaviour_frames.jpg")
    ap.add_argument("--levels-out", default="docs/images/pain_levels.jpg")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args(argv)

    from holo_viewer.behaviour import default_target, viewer_target
    from holo_viewer.fileio import save_image
    from holo_viewer.pipeline import Pipeline, apply_frame, flame_sequence_frames
    from holo_viewer.pipeline.reactions import with_behaviour
    from holo_viewer.pipeline.settings import FaceControls
    from holo_viewer.reaction.api import generate_demo_reaction

    raw = generate_demo_reaction(seconds=20.0, pain=0.0, seed=args.seed)
    p = with_behaviour(dict(raw), pain=0.6, seed=args.seed)
    err = gaze_error_deg(p, default_target())
    lid = p["expr"][:, 22]
    shown = p["pain_shown"]
    looking = np.flatnonzero((err < 1.0) & (lid < 0.2))
    picks = {"listening": int(looking[np.argmin(np.abs(shown[looking] - np.median(shown)))]),
             "blink": int(np.argmax(lid)), "aversion": int(np.argmax(np.where(lid < 0.2, err, 0))),
             "pain flare": int(np.argmax(shown))}
    for name, t in picks.items():
        print(f"{name:<11} frame {t:4d} ({t / 25:5.2f} s): eyelid {lid[t]:.2f}, gaze off target {err[t]:5.1f} deg, "
              f"pain shown {shown[t]:.2f}")
    side = with_behaviour(dict(raw), pain=0.6, seed=args.seed, target=viewer_target(15.0, 0.6))
    side_err = gaze_error_deg(side, viewer_target(15.0, 0.6))
    t_side = int(np.flatnonzero((side_err < 1.0) & (side["expr"][:, 22] < 0.2))[0])

    pipe = Pipeline()
    cams = pipe.cameras()
    n = len(cams)
    from holo_viewer.display.cameras import view_angles

    angles = view_angles(n, pipe.calibration.view_cone)
    v_side = int(np.argmin(np.abs(angles - 15.0)))
    frames = flame_sequence_frames({k: v for k, v in p.items() if k != "pain_shown"})
    sframes = flame_sequence_frames({k: v for k, v in side.items() if k != "pain_shown"})
    tiles = []
    for name, t in picks.items():
        pipe.set_face(apply_frame(FaceControls(), frames[t]))
        tiles.append((f"{name} ({t / 25:.1f} s)", pipe.render_view(n // 2)))
    pipe.set_face(apply_frame(FaceControls(), sframes[t_side]))
    tiles.append((f"eyes on a viewer at +15 deg, seen from there (view {v_side})", pipe.render_view(v_side)))
    tiles.append(("the same frame from the centre view", pipe.render_view(n // 2)))

    print(f"wrote {save_image(args.out, _sheet(tiles, 3))}")
    levels = []
    for lv in (0.0, 0.2, 0.4, 0.6, 0.8, 1.0):
        pipe.set_face(FaceControls(pain=lv))
        levels.append((f"pain {lv:g}", pipe.render_view(n // 2)))
    print(f"wrote {save_image(args.levels_out, _sheet(levels, 6))}")
    return 0


def _sheet(tiles: list, cols: int) -> np.ndarray:
    """Labelled tiles cropped to the face, ``cols`` per row."""
    from PIL import Image, ImageDraw

    h, w = tiles[0][1].shape[:2]
    top, bottom = int(0.12 * h), int(0.62 * h)
    left, right = int(0.18 * w), int(0.82 * w)
    cw, ch = right - left, bottom - top
    rows = -(-len(tiles) // cols)
    sheet = Image.new("RGB", (cols * cw, rows * (ch + 18)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for k, (label, img) in enumerate(tiles):
        x, y = (k % cols) * cw, (k // cols) * (ch + 18)
        crop = (np.clip(img[top:bottom, left:right], 0, 1) * 255 + 0.5).astype(np.uint8)
        sheet.paste(Image.fromarray(crop), (x, y + 18))
        draw.text((x + 4, y + 3), label[:60], fill=(0, 0, 0))
    return np.asarray(sheet)


if __name__ == "__main__":
    sys.exit(main())
