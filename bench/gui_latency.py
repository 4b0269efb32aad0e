"""Viewer responsiveness on the default avatar: slider release -> mesh on screen, -> preview on screen.

Run under an X server (a real display, or ``xvfb-run -s "-screen 0 1920x1080x24" python bench/gui_latency.py``);
``--offscreen`` uses OSMesa instead. Fires slider releases from code (set value + EndInteractionEvent,
exactly what a mouse release does), records the viewer's own timings, and prints a table:
median and max milliseconds for "mesh" (pipeline params+mesh and one window render) and "preview"
(Gaussians, glyphs, the selected view rendered by the fast renderer, second window render), plus the
thumbnail quilt (rendered in a worker process). ``--json FILE`` writes the records; ``--screenshot PNG``
saves the window after the last release.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=4, help="releases per slider")
    ap.add_argument("--offscreen", action="store_true", help="OSMesa instead of the X display")
    ap.add_argument("--window-size", type=int, nargs=2, default=(1400, 800))
    ap.add_argument("--json", default=None)
    ap.add_argument("--screenshot", default=None)
    args = ap.parse_args(argv)

    from holo_viewer.gui.loading import load_scene
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    if not args.offscreen and not os.environ.get("DISPLAY"):
        print("no DISPLAY: run under xvfb-run or pass --offscreen", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    scene = load_scene("default")
    load_s = time.perf_counter() - t0
    cfg = ViewerConfig(window_size=tuple(args.window_size))
    t0 = time.perf_counter()
    if args.offscreen:
        from holo_viewer.gui.offscreen import osmesa_window

        with osmesa_window():
            viewer = HoloViewer(scene.pipeline, cfg, off_screen=True)
    else:
        viewer = HoloViewer(scene.pipeline, cfg)
    viewer.open()
    build_s = time.perf_counter() - t0
    sliders = {"pain": (0.2, 0.9), "smile": (0.3, 1.0), "jaw": (0.05, 0.3), "expr4": (0.2, 1.0)}
    records = []
    for rep in range(args.repeats):
        for key, (lo, hi) in sliders.items():
            w = viewer.sliders[key]
            w.GetRepresentation().SetValue(lo if rep % 2 == 0 else hi)
            w.InvokeEvent("EndInteractionEvent")
            tm = viewer.timings
            viewer.poll_thumbnail(wait=True)  # let the worker finish so it does not skew the next release
            records.append({"slider": key, "mesh_ms": tm.mesh_ms, "preview_ms": tm.preview_ms,
                            "thumbnail_ms": viewer.timings.thumbnail_ms})
    if args.screenshot:
        viewer.save_screenshot(args.screenshot)
    viewer.close()

    def col(name: str) -> list[float]:
        return [r[name] for r in records if r[name] == r[name]]

    print(f"default avatar: {len(scene.pipeline.avatar)} Gaussians; load {load_s:.1f} s, window {build_s:.1f} s; "
          f"{'OSMesa' if args.offscreen else 'X display ' + os.environ.get('DISPLAY', '')}, "
          f"{args.window_size[0]}x{args.window_size[1]}, cpu count {os.cpu_count()}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{'slider release ->':<22} {'median ms':>10} {'max ms':>8}  n")
    for name, label in (("mesh_ms", "mesh on screen"), ("preview_ms", "preview on screen"),
                        ("thumbnail_ms", "thumbnail quilt")):
        v = col(name)
        print(f"{label:<22} {statistics.median(v):>10.0f} {max(v):>8.0f}  {len(v)}")
    if args.json:
        from holo_viewer.fileio import atomic_write

        with atomic_write(args.json, "w") as fh:
            json.dump({"config": {"window_size": list(args.window_size), "offscreen": args.offscreen,
                                  "n_gaussians": len(scene.pipeline.avatar), "preview_scale": cfg.preview_scale,
                                  "thumbnail_scale": cfg.thumbnail_scale, "max_glyphs": cfg.max_glyphs},
                       "load_average": os.getloadavg()[0], "records": records}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
