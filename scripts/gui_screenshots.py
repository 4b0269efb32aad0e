"""Screenshots of the viewer for docs/gui.md: the default window, the help overlay, a scrub in progress,
the native-image and eye panels; ``--screen-fit``: the window as sized for this X screen.

Run under an X server with xdotool (``xvfb-run -a -s "-screen 0 1920x1080x24" python
scripts/gui_screenshots.py``). The scrub is a real mouse drag on the pain slider, captured while the
button is still down (the mesh has followed the knob; the preview waits for the release). The
PNGs are reduced to a 256-colour palette when larger than ``--max-kb``.
"""

from __future__ import annotations

import argparse
import io
import subprocess
import sys
from pathlib import Path


def save_small(path: Path, img, max_kb: int) -> int:
    from PIL import Image

    im = Image.fromarray(img)
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=True)
    if buf.tell() > max_kb * 1024:
        buf = io.BytesIO()
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
            buf, format="PNG", optimize=True)
    path.write_bytes(buf.getvalue())
    return buf.tell() // 1024


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out-dir", default="docs/images")
    ap.add_argument("--window-size", type=int, nargs=2, default=(1200, 680))
    ap.add_argument("--max-kb", type=int, default=280)
    ap.add_argument("--screen-fit", action="store_true",
                    help="only viewer_screen_WxH.png: the default window for this X screen (no --window-size)")
    args = ap.parse_args(argv)
    if args.screen_fit:
        return screen_fit(Path(args.out_dir), args.max_kb)

    from holo_viewer.pipeline.scene import load_scene
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = load_scene("default")
    viewer = HoloViewer(scene.pipeline, ViewerConfig(window_size=tuple(args.window_size), out_dir="/tmp"))
    viewer.open()
    wid = str(viewer.window_id())

    def xdo(*a: object) -> None:
        subprocess.run(["xdotool", *map(str, a)], check=True)

    viewer.run(timeout=1.0)
    viewer.wait_for_thumbnail()
    viewer.run(timeout=0.3)
    print("viewer_default.png", save_small(out / "viewer_default.png", viewer.screenshot(), args.max_kb), "KB")
    xdo("mousemove", "--window", wid, *viewer.slider_point("expr2"))  # a real key press needs the pointer in
    xdo("key", "h")
    viewer.run(until=lambda: viewer.show_help, timeout=3)
    viewer.run(timeout=0.3)
    print("viewer_help.png", save_small(out / "viewer_help.png", viewer.screenshot(), args.max_kb), "KB")
    xdo("key", "h", "z")  # help off, close-up of the head
    viewer.run(timeout=0.5)
    start, end = viewer.slider_point("pain", 0.0), viewer.slider_point("pain", 0.9)
    xdo("mousemove", "--window", wid, *start)
    xdo("mousedown", 1)
    viewer.run(timeout=0.2)
    for k in range(1, 7):
        xdo("mousemove", "--window", wid, start[0] + (end[0] - start[0]) * k // 6, start[1])
        viewer.run(timeout=0.25)
    print("viewer_scrub.png", save_small(out / "viewer_scrub.png", viewer.screenshot(), args.max_kb), "KB")
    xdo("mouseup", 1)
    viewer.run(timeout=0.5)
    viewer.wait_for_thumbnail()
    xdo("key", "p")  # the native image, zoomed 4x (the lenticular stripes)
    viewer.run(until=lambda: viewer.panel_mode == "native", timeout=5)
    viewer.wait_for_native()  # the full-resolution one
    viewer.run(until=lambda: viewer.native_source == "full", timeout=5)
    xdo("key", "bracketright", "bracketright")
    viewer.run(until=lambda: viewer.native_zoom == 4, timeout=5)
    viewer.run(timeout=0.3)
    print("viewer_native.png", save_small(out / "viewer_native.png", viewer.screenshot(), args.max_kb), "KB")
    xdo("key", "p")  # what an eye 10 deg right of the panel, 0.5 m away, sees
    viewer.run(until=lambda: viewer.panel_mode == "eye", timeout=5)
    viewer.set_eye(angle=10.0, distance=0.5)
    viewer.run(timeout=0.3)
    print("viewer_eye.png", save_small(out / "viewer_eye.png", viewer.screenshot(), args.max_kb), "KB")
    viewer.close()
    return 0


def screen_fit(out: Path, max_kb: int) -> int:
    """The window as ``holo-viewer view`` opens it on this X screen (size from the screen), the thumbnail
    in, saved as ``viewer_screen_WxH.png`` (W x H: the screen)."""
    from holo_viewer.gui.screen import x_screen_size
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig
    from holo_viewer.pipeline.scene import load_scene

    out.mkdir(parents=True, exist_ok=True)
    sw, sh = x_screen_size()
    viewer = HoloViewer(load_scene("default").pipeline, ViewerConfig(out_dir="/tmp"))
    viewer.open()
    viewer.run(timeout=1.0)
    viewer.wait_for_thumbnail()
    viewer.run(timeout=0.3)
    name = f"viewer_screen_{sw}x{sh}.png"
    w, h = viewer.plotter.ren_win.GetSize()
    print(name, f"window {w}x{h}", save_small(out / name, viewer.screenshot(), max_kb), "KB")
    viewer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
