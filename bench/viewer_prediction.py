"""Viewer prediction: where the tracked eyes are when a frame is shown, and what they then see.

The live loop renders each frame for the newest viewer pose, which comes from a webcam frame that
is already some milliseconds old and is smoothed by a One-Euro filter (which trails a moving
viewer); the frame is shown a render later. ``LiveSessionConfig.predict_viewer`` (default on) renders for
the pose extrapolated over the filter's lag plus that lead (``ViewerPose.predicted``).

A viewer at 0.6 m moves along one of three paths, measured by the webcam at 25 fps with
``--noise`` degrees of tracking noise; ``--lead`` seconds pass between a webcam frame and the
display of the frame rendered for it (default 0.07: ~15 ms webcam age + the 54 ms render
measured by ``bench/live_latency.py``). Per path and variant (``filtered``: the smoothed pose as
tracked, the baseline; ``predicted``):

* ``angle_error_deg``: |rendered-for angle - true angle at display|, RMS, p95 and max over the
  frames after the first second (``error_cm_at_0.6m``: the RMS sideways);
* ``eye_psnr_db``: the per-eye PSNR (the worse eye, head region; ``display.eyes.eye_psnr``) of the
  tracked frame (default eye slices) seen from the true eye position at display, against the
  full quilt's native image of the same frame, median and worst over the evaluated frames (the
  avatar talks: smile and jaw with a 2 s period, so subpixels left from earlier frames show an
  earlier face);
* ``predict_us``: time per ``ViewerPose.predicted`` call.

Usage::

    python bench/viewer_prediction.py [--quick] [--json bench/results/viewer_prediction.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from holo_viewer.display import eyes  # noqa: E402
from holo_viewer.display.calibration import DisplayCalibration  # noqa: E402
from holo_viewer.display.simulate import VirtualDisplay  # noqa: E402
from holo_viewer.fileio import atomic_write  # noqa: E402
from holo_viewer.pipeline import FaceControls, Pipeline  # noqa: E402
from holo_viewer.pipeline.live import NativeFrameRenderer  # noqa: E402
from holo_viewer.tracking.viewer import ViewerTracker, WebcamMount  # noqa: E402

FPS = 25.0
DISTANCE_M = 0.6


def paths(seconds: float) -> dict[str, np.ndarray]:
    """Viewer angle (degrees) per webcam frame for each path."""
    t = np.arange(int(round(seconds * FPS))) / FPS
    phase = t % 4.0
    return {
        "slow sway (15 deg, 0.3 Hz)": 15.0 * np.sin(2.0 * math.pi * 0.3 * t),
        "walk and stop (15 deg/s, 1 s)": np.where(phase < 2.0, 15.0 * np.minimum(phase, 1.0),
                                                  15.0 * np.maximum(0.0, 3.0 - phase)) - 7.5,
        "standing still": np.zeros_like(t),
    }


def frame_at(pipe: Pipeline, t: float):
    """The default avatar's Gaussians at time t of a talking animation (smile and jaw, 2 s period)."""
    s = 0.5 + 0.5 * math.sin(math.pi * t)
    pipe.set_face(FaceControls(named=(("smile", s),), jaw_pose=np.array([0.15 * (1.0 - s), 0.0, 0.0])))
    return pipe.gaussians()


def positions(angle_deg: np.ndarray) -> np.ndarray:
    """Webcam-frame eye midpoints of a viewer at these angles (webcam at the panel centre)."""
    a = np.radians(angle_deg)
    return np.stack([-DISTANCE_M * np.sin(a), np.zeros_like(a), DISTANCE_M * np.cos(a)], axis=-1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 s paths, 3 frames per path through the virtual display "
                    "(~1.5 min)")
    ap.add_argument("--lead", type=float, default=0.07, help="seconds from webcam frame to display (default 0.07)")
    ap.add_argument("--noise", type=float, default=0.2, help="tracking noise, degrees (default 0.2)")
    ap.add_argument("--json", default="bench/results/viewer_prediction.json", help="output JSON file")
    args = ap.parse_args(argv)
    seconds = 4.0 if args.quick else 12.0
    every = 25 if args.quick else 15  # frames between evaluations through the virtual display (~3 s each)
    t_run = time.perf_counter()
    rng = np.random.default_rng(0)

    pipe = Pipeline(calibration=DisplayCalibration.load(None))
    cal, cams = pipe.calibration, pipe.cameras()
    n = int(round(seconds * FPS))
    # the avatar talks (smile and jaw, 2 s period), so a subpixel left from an earlier frame shows
    # an earlier face; the full quilt of the evaluated frames is the reference
    frames = [frame_at(pipe, i / FPS) for i in range(n)]
    evaluated = list(range(int(FPS), n, every))
    full = NativeFrameRenderer(cal, cams)
    refs = {i: full.frame(frames[i], mode="full_quilt").native.copy() for i in evaluated}
    display = VirtualDisplay(cal)

    records = []
    for name, angle in paths(seconds).items():
        t = np.arange(n) / FPS
        shown = np.interp(t + args.lead, t, angle, right=angle[-1])  # the eyes at display
        measured = positions(angle + rng.normal(0.0, args.noise, n))
        tracker = ViewerTracker(WebcamMount(position_m=(0.0, 0.0, 0.0)))
        poses = [tracker.update(measured[i:i + 1], float(t[i])) for i in range(n)]
        t0 = time.perf_counter()
        ahead = [p.predicted(args.lead) for p in poses]
        predict_us = (time.perf_counter() - t0) / n * 1e6
        for variant, used in (("filtered", poses), ("predicted", ahead)):
            live = NativeFrameRenderer(cal, cams)
            live.prepare_tracked()
            live.frame(frames[0], eyes.TrackedViewer(float(used[0].angle_deg), DISTANCE_M), mode="tracked")
            err = np.array([u.angle_deg for u in used]) - shown
            psnr = []
            for i in range(1, n):
                f = live.frame(frames[i], eyes.TrackedViewer(float(used[i].angle_deg), float(used[i].distance_m)),
                               mode="tracked")
                if i in refs:
                    psnr.append(eyes.eye_psnr(display, refs[i], f.native,
                                              eyes.TrackedViewer(float(shown[i]), DISTANCE_M)))
            e = np.abs(err[int(FPS):])
            rms = float(np.sqrt(np.mean(e ** 2)))
            records.append({"path": name, "variant": variant, "lead_s": args.lead, "noise_deg": args.noise,
                            "angle_error_deg": {"rms": rms, "p95": float(np.percentile(e, 95)), "max": float(e.max())},
                            "error_cm_at_0.6m": 100 * DISTANCE_M * math.tan(math.radians(rms)),
                            "eye_psnr_db": {"median": float(np.median(psnr)), "worst": float(np.min(psnr)),
                                            "frames": len(psnr)},
                            "predict_us": predict_us if variant == "predicted" else 0.0})
            r = records[-1]
            print(f"{name:32s} {variant:9s} angle error rms {rms:5.2f} p95 {r['angle_error_deg']['p95']:5.2f} "
                  f"max {r['angle_error_deg']['max']:5.2f} deg ({r['error_cm_at_0.6m']:.1f} cm)  "
                  f"per eye {r['eye_psnr_db']['median']:5.1f} dB median, {r['eye_psnr_db']['worst']:5.1f} worst",
                  flush=True)
        base, pred = records[-2], records[-1]
        pred["error_ratio_to_filtered"] = pred["angle_error_deg"]["rms"] / max(base["angle_error_deg"]["rms"], 1e-12)
    result = {"config": {**vars(args), "seconds": seconds, "fps": FPS, "distance_m": DISTANCE_M,
                         "evaluated_every": every},
              "records": records, "seconds": time.perf_counter() - t_run, "load_average": os.getloadavg(),
              "cores": os.cpu_count()}
    with atomic_write(args.json, "w") as fh:
        json.dump(result, fh, indent=2)
    print(f"wrote {args.json} ({result['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
