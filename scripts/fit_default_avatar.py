"""Fit the default Gaussian avatar to renders of its own textured mesh and write assets/default_avatar.npz.

Usage::

    python scripts/fit_default_avatar.py [--out assets/default_avatar.npz] [--iterations N]
        [--random-poses K] [--images DIR] [--no-eval] [--json FILE]

Method and numbers: docs/avatar_fit.md. The fit is seeded (numpy and torch); bytes may still differ
between machines (float32 summation order in the threaded kernels).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from holo_viewer.avatar.default_gaussians import (  # noqa: E402
    DEFAULT_N_GAUSSIANS, fitted_asset_path, generate_default_gaussians, load_fitted_avatar, save_fitted_avatar)
from holo_viewer.flame.default_head import load_default_model  # noqa: E402
from holo_viewer.images import psnr  # noqa: E402
from holo_viewer.pipeline import FaceControls, Pipeline  # noqa: E402
from holo_viewer.assets_build import fit_avatar as fa  # noqa: E402

EVAL_VIEWS = (0, 24, 47)
#: poses and views the fit never saw (held out): pain 0.6, a smile + surprise mix; quilt views 12 and 36
HELDOUT_VIEWS = (12, 36)
HELDOUT_FACES = {"pain_06": FaceControls(pain=0.6),
                 "smile_surprise": FaceControls(named=(("smile", 0.5), ("surprise", 0.5)))}
EVAL_FACES = {"neutral": FaceControls(), "smile": FaceControls(named=(("smile", 1.0),)),
              "pain_1": FaceControls(pain=1.0), "mouth_open": FaceControls(named=(("mouth_open", 1.0),))}


def evaluate_only(asset: Path, images: Path | None, json_path: Path | None) -> int:
    """Fidelity of a fitted asset on the current head: the issue's 4 expressions x views 0/24/47, and
    the held-out poses and views."""
    from holo_viewer.avatar import RiggedAvatar
    from holo_viewer.fileio import atomic_write, save_image

    model = load_default_model(add_teeth=True)
    source = fa.TargetSource.for_model(model)
    local, binding, keys = load_fitted_avatar(asset)
    if keys["colour_source"] != source.name:
        print(f"note: {asset} was fitted to {keys['colour_source']}, the head's colouring is {source.name}")
    av = RiggedAvatar(model, local.replace(extra={}), binding=binding)
    pairs: dict[str, np.ndarray] = {}
    table = {"fitted": fa.fidelity(av, EVAL_FACES, EVAL_VIEWS, source.render, pairs),
             "fitted_heldout": fa.fidelity(av, HELDOUT_FACES, HELDOUT_VIEWS + EVAL_VIEWS, source.render)}
    for label, rows in table.items():
        for name, row in rows.items():
            print(f"  {label:<15} {name:<14} " + "  ".join(f"v{i} {p:5.2f} dB" for i, p in row.items()), flush=True)
    if images is not None:
        images.mkdir(parents=True, exist_ok=True)
        for name, stack in pairs.items():
            for k, i in enumerate(EVAL_VIEWS):
                save_image(images / f"fitted_{name}_view{i:02d}.png", stack[k])
    if json_path is not None:
        with atomic_write(json_path, "w") as fh:
            json.dump({"asset": str(asset), "keys": keys, "psnr_db": table}, fh, indent=1)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=fitted_asset_path())
    ap.add_argument("--iterations", type=int, default=fa.AvatarFitConfig.iterations)
    ap.add_argument("--random-poses", type=int, default=fa.AvatarFitConfig.n_random_poses)
    ap.add_argument("--images", type=Path, default=None, help="write Gaussians | mesh pairs here")
    ap.add_argument("--no-eval", action="store_true", help="skip the before/after fidelity measurement")
    ap.add_argument("--json", type=Path, default=None, help="write the run's numbers here")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch and numba threads (default 1: on a shared 2-core machine one thread is faster)")
    ap.add_argument("--eval-only", type=Path, default=None, metavar="ASSET",
                    help="no fit: measure this fitted asset (fidelity, both views' pictures with --images)")
    args = ap.parse_args(argv)
    if args.eval_only is not None:
        return evaluate_only(args.eval_only, args.images, args.json)

    import torch

    import numba

    torch.set_num_threads(args.threads)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    torch.manual_seed(0)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    model = load_default_model(add_teeth=True)
    source = fa.TargetSource.for_model(model)
    cfg = fa.AvatarFitConfig(iterations=args.iterations, n_random_poses=args.random_poses)
    local, binding = generate_default_gaussians(model, DEFAULT_N_GAUSSIANS, sh_degree=1, seed=0)
    init = fa.initial_with_surface_colors(local, binding, model, source.albedo_at)
    pipe = Pipeline(model=model, avatar=False)
    poses = fa.training_poses(pipe.au_map, n_random=cfg.n_random_poses, seed=cfg.seed)
    t1 = time.perf_counter()
    data = fa.build_dataset(pipe, poses, source.render, cfg)
    t2 = time.perf_counter()
    print(f"dataset: {len(data.names)} poses (skipped {data.skipped}) x {data.images.shape[1]} cameras at {data.cameras.width}x"
          f"{data.cameras.height}, {t2 - t1:.0f} s", flush=True)
    res = fa.fit_gaussians(init, binding, data, cfg)
    t3 = time.perf_counter()
    path = save_fitted_avatar(args.out, res.local, binding, model, colour_source=source.name,
                              info={"iterations": cfg.iterations, "poses": len(poses), "seconds": t3 - t0})
    t4 = time.perf_counter()
    total = t4 - t0
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB); total {total:.0f} s (setup {t1 - t0:.0f}, "
          f"dataset {t2 - t1:.0f}, fit {t3 - t2:.0f}, write {t4 - t3:.0f}); load {load0:.1f} -> "
          f"{os.getloadavg()[0]:.1f}; final loss {np.mean(res.losses[-100:]):.4f}", flush=True)
    record = {"seconds": {"total": total, "setup": t1 - t0, "dataset": t2 - t1, "fit": t3 - t2, "write": t4 - t3},
              "load_1min": [load0, os.getloadavg()[0]], "iterations": cfg.iterations, "poses": len(poses),
              "images": res.n_images, "skipped_poses": data.skipped, "loss_first_100": float(np.mean(res.losses[:100])),
              "loss_last_100": float(np.mean(res.losses[-100:]))}
    if not args.no_eval:
        from holo_viewer.avatar import RiggedAvatar
        from holo_viewer.fileio import save_image

        table = {}
        shipped, _, _ = load_fitted_avatar(path)  # evaluate what ships (float16)
        for label, loc in (("generator", local), ("fitted", shipped)):
            av = RiggedAvatar(model, loc.replace(extra={}), binding=binding)
            pairs: dict[str, np.ndarray] = {}
            table[label] = fa.fidelity(av, EVAL_FACES, EVAL_VIEWS, source.render, pairs)
            for name, row in table[label].items():
                print(f"  {label:<9} {name:<10} " + "  ".join(f"v{i} {p:5.2f} dB" for i, p in row.items()), flush=True)
            if args.images is not None:
                args.images.mkdir(parents=True, exist_ok=True)
                for name, stack in pairs.items():
                    for k, i in enumerate(EVAL_VIEWS):
                        save_image(args.images / f"{label}_{name}_view{i:02d}.png", stack[k])
        av = RiggedAvatar(model, shipped.replace(extra={}), binding=binding)
        table["fitted_heldout"] = fa.fidelity(av, {**HELDOUT_FACES, "neutral": FaceControls()}, HELDOUT_VIEWS + EVAL_VIEWS,
                                              source.render)
        for name, row in table["fitted_heldout"].items():
            print(f"  held-out  {name:<14} " + "  ".join(f"v{i} {p:5.2f} dB" for i, p in row.items()), flush=True)
        # float16 storage against the float32 fit: the same renderer, neutral, every fidelity view

        p32 = Pipeline(avatar=RiggedAvatar(model, res.local.replace(extra={}), binding=binding))
        p16 = Pipeline(avatar=av)
        v32, v16 = p32.views(), p16.views()
        full = np.ones(v32.shape[1:3], bool)
        table["float16_vs_float32"] = {int(i): psnr(v16[i], v32[i], mask=full) for i in EVAL_VIEWS}
        print("  float16 vs float32 renders: " + "  ".join(f"v{i} {p:5.1f} dB"
                                                           for i, p in table["float16_vs_float32"].items()))
        record["psnr_db"] = table
    if args.json is not None:
        from holo_viewer.fileio import atomic_write

        with atomic_write(args.json, "w") as fh:
            json.dump(record, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
