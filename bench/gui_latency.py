"""Viewer responsiveness on the default avatar, measured on screen: input event -> pixels changed.

Run under an X server (a real display, or ``xvfb-run -a -s "-screen 0 1920x1080x24" python
bench/gui_latency.py``). The viewer runs its own event loop (``HoloViewer.step``); after every turn
the benchmark reads the window's front buffer (``vtkRenderWindow.GetPixelData``) in the 3D
scene, the preview and the quilt-thumbnail panels, and records when each first differs from
the frame before the input. Input is real X input by default: xdotool presses the mouse on a
slider's knob, drags it (live scrub) and releases it, so the times include X delivery and
xdotool's own start (``input overhead`` in the output); ``--input events`` fires the widget's
VTK events from code instead. Rows:

* drag step -> mesh on screen (the live scrub: one pointer motion, the mesh follows);
* release -> ellipsoids on screen (the Gaussians of the new face drawn in the 3D scene);
* release -> preview on screen (the selected view rendered by the fast renderer);
* release -> quilt thumbnail on screen (rendered in the worker process, shown by the loop);
* camera drag step -> the scene moved (first frame of the new pose), -> the splat image of that pose on
  screen (reduced resolution: ``viewer.splat_on_screen()`` after a drawn frame), release -> full-resolution
  splats on screen (a real left drag in the 3D scene, the splat view on: the ``view`` default);
* idle: frames the loop draws in 1 s with nothing changed (0: no redraw), and the cost of one frame of
  the whole window (every panel drawn: "idle redraw" fps) and of a scene-only frame (what a camera drag
  draws), wall and CPU;
* launch: ``--launch-runs`` fresh processes doing what ``holo-viewer view`` does up to its first frame
  (the last one warm: its files in the page cache), from before the process starts to first pixels.

One command writes everything (the quiet run): ``xvfb-run -a -s "-screen 0 1920x1080x24" python
bench/gui_latency.py --repeats 2 --json bench/results/gui_latency.json`` (about 2 minutes on a quiet
2-core machine). The baseline of each on-screen time is the viewer's own timer for the same update
measured in the same run (the ratio column).

Beside each on-screen time it prints the viewer's own timer for the same update (what the
status line shows, measured inside the callback) and the ratio on-screen / own timer. The
ellipsoid count is the ``view`` command's default (``ViewerConfig.max_glyphs``); the status
line is off so that its text does not count as a changed pixel. ``--json FILE`` writes the
config and every record; ``--screenshot PNG`` saves the window after the last release.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time

import numpy as np

PANELS = ("scene", "preview", "quilt")


def launch_child(t0: float) -> int:
    """``--launch-child T0``: what ``holo-viewer view`` does up to its first frame, then print the seconds
    since ``T0`` (the parent's clock before it started this process) and each step's, and exit."""
    marks = {"start": time.time() - t0}
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig
    from holo_viewer.pipeline.scene import load_scene

    marks["imports"] = time.time() - t0
    scene = load_scene("default")
    marks["avatar"] = time.time() - t0
    viewer = HoloViewer(scene.pipeline, ViewerConfig())
    viewer.open()  # the first frame is drawn (and copied to the X window) when this returns
    marks["first_pixels"] = time.time() - t0
    marks["cpu_s"] = time.process_time()
    viewer.close()
    print(json.dumps(marks))
    return 0


def measure_launch(runs: int) -> list[dict[str, float]]:
    """Start the viewer ``runs`` times in a fresh process (the first warms the file cache)."""
    out = []
    for _ in range(runs):
        t0 = time.time()
        res = subprocess.run([sys.executable, __file__, "--launch-child", repr(t0)], capture_output=True,
                             text=True, timeout=300)
        if res.returncode != 0:
            raise RuntimeError(f"launch child failed: {res.stderr[-2000:]}")
        out.append(json.loads(res.stdout.strip().splitlines()[-1]))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="drags per slider")
    ap.add_argument("--window-size", type=int, nargs=2, default=None, help="default: sized from the screen")
    ap.add_argument("--input", choices=("xdotool", "events"), default=None,
                    help="real X input (default when xdotool is installed) or VTK events fired from code")
    ap.add_argument("--timeout", type=float, default=15.0, help="seconds to wait for a panel to change")
    ap.add_argument("--json", default=None)
    ap.add_argument("--screenshot", default=None)
    ap.add_argument("--launch-runs", type=int, default=2, help="fresh-process launches timed (the last is warm)")
    ap.add_argument("--launch-child", type=float, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.launch_child is not None:
        return launch_child(args.launch_child)

    if not os.environ.get("DISPLAY"):
        print("no DISPLAY: run under xvfb-run (the benchmark measures pixels on an X window)", file=sys.stderr)
        return 2
    method = args.input or ("xdotool" if shutil.which("xdotool") else "events")
    if method == "xdotool" and not shutil.which("xdotool"):
        print("xdotool is not installed (apt-get install xdotool); pass --input events", file=sys.stderr)
        return 2

    load0 = os.getloadavg()[0]
    launches = measure_launch(args.launch_runs) if args.launch_runs > 0 else []
    from holo_viewer.pipeline.scene import load_scene
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    t0 = time.perf_counter()
    scene = load_scene("default")
    load_s = time.perf_counter() - t0
    cfg = ViewerConfig(window_size=None if args.window_size is None else tuple(args.window_size), show_status=False)
    t0 = time.perf_counter()
    viewer = HoloViewer(scene.pipeline, cfg)
    viewer.open()
    build_s = time.perf_counter() - t0
    viewer._looping = True  # renders requested by callbacks are drawn by step(), as in run()

    def xdo(*a: object) -> None:
        subprocess.run(["xdotool", *map(str, a)], check=True)

    wid = str(viewer.window_id())
    H = viewer.plotter.ren_win.GetSize()[1]

    def settle(seconds: float = 0.3) -> None:
        """Loop until the thumbnail worker is idle, then ``seconds`` more."""
        end = time.perf_counter() + args.timeout
        while (viewer._thumb_pending_key is not None) and time.perf_counter() < end:
            viewer.step()
            time.sleep(0.002)
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            viewer.step()
            time.sleep(0.002)

    def grab() -> dict[str, np.ndarray]:
        return {p: viewer.read_pixels(p).astype(np.int16) for p in PANELS}

    def wait_changes(before: dict[str, np.ndarray], t_input: float, panels: tuple[str, ...]) -> dict[str, float]:
        """Milliseconds from ``t_input`` until each panel's pixels differ (> 8 levels) from ``before``.

        The panels are read back after each loop turn that drew a frame (the framebuffer changes only
        then): reading them after every turn, ~2-10 ms of the UI thread each, competed with the splat
        render for the 2 cores while a camera-drag frame waited for it."""
        seen: dict[str, float] = {}
        end = time.perf_counter() + args.timeout
        frames = -1
        while len(seen) < len(panels) and time.perf_counter() < end:
            viewer.step()
            now = time.perf_counter()
            if viewer.frames_drawn != frames:
                frames = viewer.frames_drawn
                for p in panels:
                    if p not in seen and np.abs(viewer.read_pixels(p).astype(np.int16) - before[p]).max() > 8:
                        seen[p] = (now - t_input) * 1e3
            time.sleep(0.001)
        return {p: seen.get(p, float("nan")) for p in panels}

    overhead = []
    if method == "xdotool":
        for _ in range(5):
            t = time.perf_counter()
            xdo("mousemove", "--window", wid, 5, 5)
            overhead.append((time.perf_counter() - t) * 1e3)

    sliders = {"pain": (0.2, 0.9), "smile": (0.3, 0.95), "jaw": (0.05, 0.3), "expr4": (0.2, 1.0)}
    records = []
    settle(1.0)
    for rep in range(args.repeats):
        for key, (lo, hi) in sliders.items():
            spec = viewer._specs[key]
            start_v = spec.value
            target = lo if abs(start_v - lo) > abs(start_v - hi) else hi
            mid = 0.5 * (start_v + target)
            w = viewer.sliders[key]
            # press on the knob, move half way (a drag step), measure, then the rest, then release
            if method == "xdotool":
                xdo("mousemove", "--window", wid, *viewer.slider_point(key))
                xdo("mousedown", 1)
            else:
                w.InvokeEvent("StartInteractionEvent")
            settle(0.2)
            before = grab()
            t = time.perf_counter()
            if method == "xdotool":
                xdo("mousemove", "--window", wid, *viewer.slider_point(key, mid))
            else:
                w.GetRepresentation().SetValue(mid)
                w.InvokeEvent("InteractionEvent")
            drag = wait_changes(before, t, ("scene",))["scene"]
            own_live, own_live_cpu = viewer.timings.live_ms, viewer.timings.live_cpu_ms
            if method == "xdotool":
                xdo("mousemove", "--window", wid, *viewer.slider_point(key, target))
            else:
                w.GetRepresentation().SetValue(target)
                w.InvokeEvent("InteractionEvent")
            settle(0.2)
            before = grab()
            t = time.perf_counter()
            if method == "xdotool":
                xdo("mouseup", 1)
            else:
                w.InvokeEvent("EndInteractionEvent")
            rel = wait_changes(before, t, PANELS)
            tm = viewer.timings
            records.append({"slider": key, "value": spec.value, "drag_mesh_ms": drag,
                            "release_glyphs_ms": rel["scene"], "release_preview_ms": rel["preview"],
                            "release_thumbnail_ms": rel["quilt"], "own_live_ms": own_live, "own_live_cpu_ms": own_live_cpu,
                            "own_preview_ms": tm.preview_ms, "own_thumbnail_ms": tm.thumbnail_ms})
            settle(0.2)
    cam_records = []
    x0, y0, x1, y1 = viewer.panel_box("scene")
    cx, cy = (x0 + x1) // 2, H - (y0 + y1) // 2
    for rep in range(args.repeats * 2 if viewer.show_splats and method == "xdotool" else 0):
        xdo("mousemove", "--window", wid, cx, cy)
        xdo("mousedown", 1)
        settle(0.2)
        before = grab()
        t = time.perf_counter()
        xdo("mousemove", "--window", wid, cx + (30 if rep % 2 == 0 else -30), cy)
        mesh_drag = wait_changes(before, t, ("scene",))["scene"]  # the first frame of the moved camera
        end = time.perf_counter() + args.timeout  # then the splat image of that camera on screen
        while not viewer.splat_on_screen() and time.perf_counter() < end:
            viewer.step()
            time.sleep(0.001)
        drag = (time.perf_counter() - t) * 1e3 if viewer.splat_on_screen() else float("nan")
        own_drag = viewer.timings.splat_drag_ms
        settle(0.2)
        before = grab()
        t = time.perf_counter()
        xdo("mouseup", 1)
        end = time.perf_counter() + args.timeout
        while not viewer._splat_full and time.perf_counter() < end:
            viewer.step()
            time.sleep(0.001)
        full = (time.perf_counter() - t) * 1e3 if viewer._splat_full else float("nan")
        cam_records.append({"drag_splat_ms": drag, "drag_scene_ms": mesh_drag, "release_full_splat_ms": full,
                            "own_drag_ms": own_drag,
                            "own_full_ms": viewer.timings.splat_ms})
        settle(0.2)
    # idle: how many frames the loop draws with nothing changed; then the cost of one frame of the whole
    # window (every panel drawn again) and of a scene-only frame (what a camera drag draws), wall and CPU
    settle(0.5)
    n0 = viewer.frames_drawn
    idle_end = time.perf_counter() + 1.0
    while time.perf_counter() < idle_end:
        viewer.step()
        time.sleep(0.004)
    idle_frames = viewer.frames_drawn - n0

    def frame_cost(parts):
        wall, cpu = [], []
        for _ in range(20):
            t, c = time.perf_counter(), time.process_time()
            viewer._render_now(parts)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        return statistics.median(wall), statistics.median(cpu)

    full_wall, full_cpu = frame_cost(None)
    scene_wall, scene_cpu = frame_cost(("scene",))
    idle_fps = 1.0 / full_wall
    records += cam_records
    if args.screenshot:
        viewer.save_screenshot(args.screenshot)
    size = tuple(viewer.plotter.ren_win.GetSize())
    viewer._looping = False
    viewer.close()
    load1 = os.getloadavg()[0]

    def col(name: str) -> list[float]:
        return [r[name] for r in records if r.get(name) is not None and r[name] == r[name]]

    n_g = len(scene.pipeline.avatar)
    print(f"default avatar: {n_g} Gaussians, {cfg.max_glyphs} drawn as ellipsoids (the view command's default); "
          f"load {load_s:.1f} s, window {build_s:.1f} s (launch to first pixels {load_s + build_s:.1f} s); "
          f"splat view {'on' if viewer.show_splats else 'off'}")
    print(f"idle: {idle_frames} frames drawn in 1 s with nothing changed; a redraw of the whole window "
          f"{1e3 * full_wall:.1f} ms ({1.0 / full_wall:.1f} fps, CPU {1e3 * full_cpu:.1f} ms), of the scene only "
          f"(a camera-drag frame) {1e3 * scene_wall:.1f} ms ({1.0 / scene_wall:.1f} fps, CPU {1e3 * scene_cpu:.1f} ms)")
    for i, m in enumerate(launches):
        print(f"launch {i + 1} (fresh process{', warm' if i else ''}): first pixels {m['first_pixels']:.1f} s "
              f"(python start {m['start']:.1f}, imports {m['imports']:.1f}, avatar {m['avatar']:.1f} s; "
              f"CPU {m['cpu_s']:.1f} s)")
    print(f"X display {os.environ.get('DISPLAY')}, window {size[0]}x{size[1]}, input {method}"
          + (f" (input overhead: xdotool run {statistics.median(overhead):.0f} ms median, included)" if overhead
             else "") + f", cpu count {os.cpu_count()}, load average {load0:.1f} -> {load1:.1f}")
    print(f"{'event -> pixels changed':<36} {'median ms':>10} {'max ms':>8} {'own timer ms':>13} {'ratio':>6}  n")
    rows = (("drag_mesh_ms", "drag step -> mesh on screen", "own_live_ms"),
            ("release_glyphs_ms", "release -> 3D scene on screen", None),
            ("release_preview_ms", "release -> preview on screen", "own_preview_ms"),
            ("release_thumbnail_ms", "release -> quilt thumbnail on screen", "own_thumbnail_ms"),
            ("drag_scene_ms", "camera drag -> scene moved (overlays)", None),
            ("drag_splat_ms", "camera drag -> reduced splats", "own_drag_ms"),
            ("release_full_splat_ms", "camera release -> full splats", "own_full_ms"))
    summary = {}
    for name, label, own in rows:
        v = col(name)
        if not v:
            print(f"{label:<36} {'-':>10} {'-':>8}")
            continue
        med = statistics.median(v)
        own_med = statistics.median(col(own)) if own and col(own) else None
        ratio = med / own_med if own_med else None
        summary[name] = {"median_ms": med, "max_ms": max(v), "own_median_ms": own_med, "ratio": ratio,
                         "n": len(v), "missed": len(records) - len(v)}
        print(f"{label:<36} {med:>10.0f} {max(v):>8.0f} "
              f"{(f'{own_med:.0f}' if own_med else '-'):>13} {(f'{ratio:.2f}' if ratio else '-'):>6}  {len(v)}")
    live_cpu = col("own_live_cpu_ms")
    if live_cpu:  # what a live step costs whatever the load: CPU of the whole process (llvmpipe's threads too)
        summary["drag_mesh_cpu_ms"] = {"median_ms": statistics.median(live_cpu), "max_ms": max(live_cpu),
                                       "n": len(live_cpu)}
        print(f"drag step CPU (mesh update + frame, all threads): median {statistics.median(live_cpu):.0f} ms, "
              f"max {max(live_cpu):.0f} ms, n {len(live_cpu)}")
    if args.json:
        from holo_viewer.fileio import atomic_write

        with atomic_write(args.json, "w") as fh:
            json.dump({"config": {"window_size": list(size), "input": method, "n_gaussians": n_g,
                                  "max_glyphs": cfg.max_glyphs, "glyph_min_opacity": cfg.glyph_min_opacity,
                                  "preview_scale": cfg.preview_scale, "thumbnail_scale": cfg.thumbnail_scale,
                                  "repeats": args.repeats, "cpu_count": os.cpu_count()},
                       "load_average": [load0, load1], "idle_fps": idle_fps, "idle_frames_per_s": idle_frames,
                       "frame_ms": {"whole_window": 1e3 * full_wall, "whole_window_cpu": 1e3 * full_cpu,
                                    "scene_only": 1e3 * scene_wall, "scene_only_cpu": 1e3 * scene_cpu},
                       "launch_s": load_s + build_s, "launch_load_s": load_s, "launch_window_s": build_s,
                       "launches": launches,
                       "launch_warm_first_pixels_s": launches[-1]["first_pixels"] if launches else None, "input_overhead_ms": overhead, "summary": summary,
                       "records": records}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
