"""Across machines (issue 33: replayed frames agree to >= 60 dB on another machine), emulated on this one.

No second physical machine is available to this project. What differs between x86-64 machines for
``replay --quality live`` is emulated here, each in its own child process:

* ``numba haswell + cpp avx2``: a CPU without AVX-512: numba generates code for Haswell
  (``NUMBA_CPU_NAME=haswell``, an empty kernel cache of its own, so every kernel is compiled again for
  that target: vector widths and the order of vectorised reductions change), the C++ splat
  compositor's AVX2 path (``fast._CPP_MODE = 2``) and the eye-slice scatter without AVX-512
  (``kernel="cpp-scalar"``);
* ``numba generic + cpp scalar``: a baseline x86-64 CPU (SSE2 only: ``NUMBA_CPU_NAME=generic``), the
  portable scalar compositor (``_CPP_MODE = 1``) and scatter;
* ``numba kernels, 1 thread``: the numba compositor instead of the C++ extension (a build without a
  C++ compiler) and one render thread instead of all cores;
* ``same build`` (the reference: must be bit-exact).

The session is recorded by ``holo-viewer live --audio --video --headless`` on the bench's clip (a
tracked face: group frames with eye slices, so the scatter runs too). Per variant: displayed
frames, how many are identical to ``native.mkv``, the worst frame's PSNR (dB) and largest
difference (levels). Not emulated: another compiler or C++ standard library, other numpy / numba /
LLVM versions, another operating system, or a session recorded with gsplat on a GPU.

    python bench/replay_across_cpus.py [--frames 6] [--tile-scale 0.5] [--json bench/results/replay_across_cpus.json]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: name -> (environment, child set-up code run before the replay)
VARIANTS = {
    "same build": ({}, ""),
    "numba haswell + cpp avx2": ({"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": ""},
                                 "fast._CPP_MODE = 2; slices_kernel = 'cpp-scalar'"),
    "numba generic + cpp scalar": ({"NUMBA_CPU_NAME": "generic", "NUMBA_CPU_FEATURES": ""},
                                   "fast._CPP_MODE = 1; slices_kernel = 'cpp-scalar'"),
    "numba kernels, 1 thread": ({}, "fast._cpp = lambda: None; threads = 1; slices_kernel = 'numba'"),
}

CHILD = r"""
import functools, sys, numpy as np
from holo_viewer.render import fast
from holo_viewer.display import slices
threads, slices_kernel = None, 'auto'
{setup}
slices.scatter_slices = functools.partial(slices.scatter_slices, kernel=slices_kernel)
from holo_viewer.live.replay import replay_timed_frames
frames = [img for _, img in replay_timed_frames(sys.argv[1], render_threads=threads)]
np.save(sys.argv[2], np.stack(frames))
"""


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6, help="displayed frames of the recorded session")
    ap.add_argument("--tile-scale", type=float, default=0.5)
    ap.add_argument("--session", default=None, help="a recorded session folder instead of recording one")
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "holo_viewer_live_bench"))
    ap.add_argument("--json", default="bench/results/replay_across_cpus.json")
    args = ap.parse_args()
    from holo_viewer.media import read_frames
    from holo_viewer.pipeline.live_support import write_talking_head_clip

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(args.session) if args.session else Path(tmp) / "session"
        if not args.session:
            clip = Path(args.cache) / "clip_8s"
            if not (clip / "speaker.wav").exists():
                write_talking_head_clip(clip, seconds=8.0, n_gaussians=30_000)
            subprocess.run([sys.executable, "-m", "holo_viewer", "live", "--audio", str(clip / "speaker.wav"),
                            "--video", str(clip / "speaker.mp4"), "--headless", "--frames", str(args.frames),
                            "--tile-scale", f"{args.tile_scale:g}", "--out", str(session)], check=True,
                           capture_output=True)
        live = np.stack(list(read_frames(session / "native.mkv")))
        with np.load(session / "tracks.npz") as z:
            tracked = int(np.sum(z["render_tracked"]))
        for name, (env_extra, setup) in VARIANTS.items():
            env = dict(os.environ, **env_extra)
            if env_extra:  # numba compiles for another CPU: a kernel cache of its own
                env["NUMBA_CACHE_DIR"] = str(Path(tmp) / f"numba_{len(rows)}")
            out = Path(tmp) / f"v{len(rows)}.npy"
            t = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", CHILD.format(setup=setup), str(session), str(out)], env=env,
                                  capture_output=True, text=True)
            if proc.returncode != 0:
                raise SystemExit(f"{name}: replay failed: {proc.stderr[-2000:]}")
            again = np.load(out)
            ps = [psnr(a, b) for a, b in zip(live, again)]
            rows.append({"variant": name, "env": env_extra, "setup": setup, "frames": int(len(again)),
                         "identical": int(sum(np.array_equal(a, b) for a, b in zip(live, again))),
                         "worst_psnr_db": None if np.isinf(min(ps)) else round(min(ps), 1),
                         "max_diff": int(max(np.abs(a.astype(np.int16) - b).max() for a, b in zip(live, again))),
                         "seconds": round(time.perf_counter() - t, 1)})
            r = rows[-1]
            print(f"{name:28s} frames {r['frames']:3d} identical {r['identical']:3d} worst "
                  f"{'inf' if r['worst_psnr_db'] is None else r['worst_psnr_db']} dB max diff {r['max_diff']} "
                  f"({r['seconds']} s)", flush=True)
    result = {"config": vars(args), "displayed_frames": int(len(live)), "tracked_frames": tracked,
              "load_1min": round(os.getloadavg()[0], 2), "variants": rows, "target_db": 60.0}
    from holo_viewer.fileio import write_json

    write_json(args.json, result)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
