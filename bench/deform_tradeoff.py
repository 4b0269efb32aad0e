"""Deformation speed vs error: rigged, rigged with caching, blend-shape; back-face culling.

For the default avatar (100k Gaussians, float32, batch 1) this measures

* time per frame (best-of-N and median wall time, best process time) of
  ``RiggedAvatar.pose`` (FLAME + binding), the cached variant on a sequence that moves one
  expression component at a time, and ``BlendshapeAvatar.pose``;
* the blend-shape centre error against the rigged avatar (mean / max in mm) over sweeps of
  each expression component to +-0.25 .. 3 standard deviations (default head: 1 std = 1.0) and
  over random combinations with every |psi_k| <= s;
* the caching error for positive tolerances;
* rendered-image PSNR (fast renderer) of blend-shape vs rigged and of back-face culling vs no
  culling on views of the 48-view quilt cone, with the render time saved; also for a
  semi-transparent copy of the avatar, where culling is not safe.

Prints tables and writes JSON (``--json FILE``). Timings depend on the load of this shared
CPU: best-of-N and process times are the robust numbers.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch


def _timeit(fn: Callable[[], Any], repeat: int) -> dict[str, float]:
    fn()  # warm-up (numba compile, caches)
    walls, procs = [], []
    for _ in range(repeat):
        t0, p0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - t0)
        procs.append(time.process_time() - p0)
    return {"best_ms": 1e3 * min(walls), "median_ms": 1e3 * statistics.median(walls),
            "best_process_ms": 1e3 * min(procs)}


def _timeit_interleaved(fns: dict[str, Callable[[], Any]], repeat: int) -> dict[str, dict[str, float]]:
    """Like :func:`_timeit` for several functions, run round-robin so that load from other jobs on
    this shared CPU hits all of them alike (the ratios are then meaningful)."""
    for fn in fns.values():
        fn()
    walls: dict[str, list[float]] = {k: [] for k in fns}
    procs: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0, p0 = time.perf_counter(), time.process_time()
            fn()
            walls[name].append(time.perf_counter() - t0)
            procs[name].append(time.process_time() - p0)
    return {k: {"best_ms": 1e3 * min(walls[k]), "median_ms": 1e3 * statistics.median(walls[k]),
                "best_process_ms": 1e3 * min(procs[k])} for k in fns}


def _per_gaussian_layout(blend: Any) -> Any:
    """The same blend shapes in the v1 layout (per-Gaussian sparse B_0 + B rows), for comparison."""
    from holo_viewer.avatar.blendshape import BlendshapeAvatar, _Sparse

    b0, bk = blend.blend_shapes()
    mask = (np.abs(bk[..., :3]).max(-1) >= 1e-7) | (np.abs(bk[..., 3:]).max(-1) >= 1e-4)
    g = blend.pose(np.zeros(blend.n_expr))
    return BlendshapeAvatar(_Sparse.from_dense(b0, bk, mask), blend.n_expr, blend.has_jaw,
                            g.opacity_logits.numpy(), g.sh.numpy(), blend.root)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def _with_opacity(g: Any, opacity: float) -> Any:
    return g.replace(opacity_logits=torch.full_like(g.opacity_logits, float(np.log(opacity / (1 - opacity)))))


def _render_all(render_views: Any, frames: list[Any], cams: Any, repeat: int) -> tuple[dict[str, float], np.ndarray]:
    """Render every frame into ``cams``; best-of-``repeat`` total time and the stacked images."""
    def run() -> np.ndarray:
        return np.stack([render_views(g, cams, backend="fast").images for g in frames])
    return _timeit(run, repeat), run()


def _sweep_errors(rig: Any, blend: Any, levels: list[float], n_random: int, seed: int) -> list[dict[str, Any]]:
    k = blend.n_expr
    rng = np.random.default_rng(seed)
    rows = []
    for s in levels:
        single_mean, single_max = [], []
        for comp in range(k):
            for sign in (1.0, -1.0):
                e = np.zeros(k, np.float32)
                e[comp] = sign * s
                err = (rig.pose(expr=e).means - blend.pose(e).means).norm(dim=-1) * 1e3
                single_mean.append(float(err.mean()))
                single_max.append(float(err.max()))
        comb_mean, comb_max = [], []
        for _ in range(n_random):
            e = rng.uniform(-s, s, k).astype(np.float32)
            err = (rig.pose(expr=e).means - blend.pose(e).means).norm(dim=-1) * 1e3
            comb_mean.append(float(err.mean()))
            comb_max.append(float(err.max()))
        rows.append({"level_std": s, "single_mean_mm": float(np.mean(single_mean)),
                     "single_worst_mean_mm": float(np.max(single_mean)), "single_max_mm": float(np.max(single_max)),
                     "random_mean_mm": float(np.mean(comb_mean)), "random_max_mm": float(np.max(comb_max))})
    return rows


def _sequence(k: int, frames_per_comp: int, level: float) -> np.ndarray:
    """Ramp one component at a time 0 -> level -> 0 (a talking-head-like local motion)."""
    seq = []
    ramp = level * np.sin(np.linspace(0, np.pi, frames_per_comp))
    for comp in range(k):
        for a in ramp:
            e = np.zeros(k, np.float32)
            e[comp] = a
            seq.append(e)
    return np.stack(seq)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-gaussians", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=30, help="timing repetitions (best-of)")
    ap.add_argument("--threads", type=int, default=1, help="torch and numba threads")
    ap.add_argument("--levels", type=str, default="0.25,0.5,1,2,3", help="sweep levels in standard deviations")
    ap.add_argument("--n-random", type=int, default=8, help="random combinations per level")
    ap.add_argument("--render-views", type=int, default=6, help="views of the 48-view cone rendered for PSNR (0: skip)")
    ap.add_argument("--margin-deg", type=float, default=10.0, help="back-face culling margin (also 0, 20, 30)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    import numba

    from holo_viewer.avatar import BlendshapeAvatar, cull_backfacing, default_avatar

    torch.set_num_threads(args.threads)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    levels = [float(x) for x in args.levels.split(",")]
    t0 = time.perf_counter()
    rig = default_avatar(n_gaussians=args.n_gaussians)
    t_gen = time.perf_counter() - t0
    t0 = time.perf_counter()
    blend = BlendshapeAvatar.from_rigged(rig)
    t_lin = time.perf_counter() - t0
    k = blend.n_expr
    n_faces = int(rig.faces.shape[0])
    print(f"default avatar: {rig.n_gaussians} Gaussians, {k} expression components, "
          f"load/generate {t_gen:.1f} s, linearise {t_lin:.1f} s, blend ({blend.representation}) nnz {blend.nnz} "
          f"({blend.nnz / n_faces:.2f} per face of {n_faces}); threads {args.threads}")
    legacy = _per_gaussian_layout(blend)

    # ---------------------------------------------------------------- timing
    rng = np.random.default_rng(0)
    e_rand = rng.normal(size=k).astype(np.float32)
    seq = _sequence(k, 6, 1.0)
    e_one = np.zeros(k, np.float32)
    e_one[int(np.argmax(np.abs(e_rand)))] = 1.0
    verts = rig.flame_model(expr=e_rand).vertices
    # rigged and blend-shape interleaved (same load); dense psi (all k components non-zero) is the headline
    timings: dict[str, dict[str, float]] = _timeit_interleaved({
        "rigged": lambda: rig.pose(expr=e_rand),
        "rigged_flame_only": lambda: rig.flame_model(expr=e_rand),
        "rigged_binding_only": lambda: rig.deform(verts),
        "blendshape": lambda: blend.pose(e_rand),
        "blendshape_one_component": lambda: blend.pose(e_one),
        "blendshape_v1_per_gaussian_layout": lambda: legacy.pose(e_rand),
    }, args.repeat)
    rig.backend = "torch"  # the pure-torch binding (GaussianAvatars-style), for reference
    timings["rigged_torch_path"] = _timeit(lambda: rig.pose(expr=e_rand), max(5, args.repeat // 3))
    rig.backend = "auto"

    def run_seq(cache: bool, tol: float) -> Callable[[], None]:
        state = {"i": 0}

        def step() -> None:
            rig.pose(expr=seq[state["i"] % len(seq)], cache=cache, cache_tol=tol)
            state["i"] += 1
        return step

    cache_rows = []
    for tol in (0.0, 1e-6, 1e-5, 1e-4):
        rig.reset_cache()
        tm = _timeit(run_seq(True, tol), max(args.repeat, len(seq)))
        # error of the cached sequence against the uncached rigged avatar, and moved fraction
        rig.reset_cache()
        errs, fracs = [], []
        for e in seq:
            c = rig.pose(expr=e, cache=True, cache_tol=tol)
            fracs.append(rig.last_cache_fraction)
            errs.append(float((c.means - rig.pose(expr=e).means).norm(dim=-1).max()) * 1e3)
        cache_rows.append({"tol_m": tol, **tm, "max_err_mm": max(errs), "mean_moved_face_fraction": float(np.mean(fracs))})
    rig.reset_cache()
    timings["rigged_sequence_nocache"] = _timeit(run_seq(False, 0.0), max(args.repeat, len(seq)))
    bstate = {"i": 0}

    def blend_step() -> None:
        blend.pose(seq[bstate["i"] % len(seq)])
        bstate["i"] += 1
    rig.reset_cache()
    timings.update({f"{name}_sequence{'' if name == 'blendshape' else '_interleaved'}": tm for name, tm in
                    _timeit_interleaved({"rigged": run_seq(False, 0.0), "blendshape": blend_step},
                                        max(args.repeat, len(seq))).items()})

    base, base_p = timings["rigged"]["best_ms"], timings["rigged"]["best_process_ms"]
    print("\nTime per frame (batch 1, float32); speed-up = rigged / method (best wall, best process time)")
    print(f"{'method':36s} {'best ms':>9s} {'median ms':>10s} {'proc ms':>9s} {'speed-up':>9s} {'proc s-u':>9s}")
    for name, tm in timings.items():
        print(f"{name:36s} {tm['best_ms']:9.3f} {tm['median_ms']:10.3f} {tm['best_process_ms']:9.3f} "
              f"{base / tm['best_ms']:9.2f} {base_p / tm['best_process_ms']:9.2f}")
    seq_base = timings["rigged_sequence_nocache"]["best_ms"]
    print("\nCaching on a one-component-at-a-time sequence (ramps to 1 std)")
    print(f"{'cache_tol m':>12s} {'best ms':>9s} {'median ms':>10s} {'moved faces':>12s} {'max err mm':>11s} {'speed-up':>9s}")
    for r in cache_rows:
        print(f"{r['tol_m']:12.0e} {r['best_ms']:9.2f} {r['median_ms']:10.2f} {r['mean_moved_face_fraction']:12.3f} "
              f"{r['max_err_mm']:11.4f} {seq_base / r['best_ms']:9.2f}")

    # ---------------------------------------------------------------- blend-shape error curve
    sweep = _sweep_errors(rig, blend, levels, args.n_random, seed=1)
    print("\nBlend-shape centre error vs rigged (mm)")
    print(f"{'|psi| std':>9s} {'single mean':>12s} {'single worst mean':>18s} {'single max':>11s} "
          f"{'random mean':>12s} {'random max':>11s}")
    for r in sweep:
        print(f"{r['level_std']:9.2f} {r['single_mean_mm']:12.5f} {r['single_worst_mean_mm']:18.5f} "
              f"{r['single_max_mm']:11.4f} {r['random_mean_mm']:12.5f} {r['random_max_mm']:11.4f}")

    # ---------------------------------------------------------------- renders: PSNR and culling
    render_rows: list[dict[str, Any]] = []
    cull_rows: list[dict[str, Any]] = []
    if args.render_views > 0:
        from holo_viewer.display.cameras import make_quilt_cameras
        from holo_viewer.render.api import render_views

        cams48 = make_quilt_cameras(None, focal_center=(0.0, -0.01, 0.0), size=0.16)
        idx = np.unique(np.linspace(0, len(cams48) - 1, args.render_views).round().astype(int))
        cams = cams48[idx]
        for s in (0.0, 1.0, 3.0):
            e = np.zeros(k, np.float32)
            e[:] = s * np.random.default_rng(7).uniform(-1, 1, k)
            ref = render_views(rig.pose(expr=e), cams, backend="fast").images
            img = render_views(blend.pose(e), cams, backend="fast").images
            render_rows.append({"level_std": s, "psnr_db": _psnr(ref, img)})
        from holo_viewer.flame import expressions as fe

        au_map = fe.default_au_map(k)
        for name, e in (("smile", fe.named_expression("smile", 1.0, au_map)), ("pain", fe.pain_expression(1.0, au_map)),
                        ("mouth_open (expr only)", fe.named_expression("mouth_open", 1.0, au_map))):
            e = np.asarray(e, np.float32)
            ref = render_views(rig.pose(expr=e), cams, backend="fast").images
            img = render_views(blend.pose(e), cams, backend="fast").images
            err = (rig.pose(expr=e).means - blend.pose(e).means).norm(dim=-1) * 1e3
            render_rows.append({"expression": name, "psnr_db": _psnr(ref, img), "mean_err_mm": float(err.mean()),
                                "max_err_mm": float(err.max())})
        print("\nBlend-shape vs rigged, rendered PSNR")
        for r in render_rows:
            what = r.get("expression") or f"random |psi_k| <= {r['level_std']:.1f} std"
            extra = f" (centre error mean {r['mean_err_mm']:.4f} mm, max {r['max_err_mm']:.3f} mm)" if "expression" in r else ""
            print(f"  {what:28s} {r['psnr_db']:7.2f} dB{extra}")

        margins = sorted({0.0, args.margin_deg, 20.0, 30.0})
        scenes = [(f"opaque, margin {m:g} deg", None, m) for m in margins]
        scenes.append((f"opacity 0.3, margin {args.margin_deg:g} deg", 0.3, args.margin_deg))
        full_cache: dict[Any, Any] = {}
        named = {"neutral": {}, "smile": {"expr": fe.named_expression("smile", 1.0, au_map)},
                 "pain": {"expr": fe.pain_expression(1.0, au_map)},
                 "mouth_open": {"expr": fe.named_expression("mouth_open", 1.0, au_map),
                                "jaw_pose": fe.jaw_for_expression("mouth_open", 1.0)}}
        batch = {key: np.stack([np.asarray(p.get(key, np.zeros(k if key == "expr" else 3)), np.float32)
                                for p in named.values()]) for key in ("expr", "jaw_pose")}
        for label, opacity, margin in scenes:
            # the four named expressions of the default head, one frame each
            out = rig.flame_model(**batch)
            gs = rig.deform(out.vertices)
            t_mask = _timeit(lambda: cull_backfacing(rig, cams48, margin, vertices=out.vertices[:1]), 5)
            mask = np.concatenate([cull_backfacing(rig, cams48, margin, vertices=v[None]) for v in out.vertices])
            gc = [x.subset(torch.as_tensor(mask[i * len(x):(i + 1) * len(x)])) for i, x in enumerate(gs)]
            g, gc = gs, gc
            if opacity is not None:
                g = [_with_opacity(x, opacity) for x in g]
                gc = [_with_opacity(x, opacity) for x in gc]
            if opacity not in full_cache:
                full_cache[opacity] = (_render_all(render_views, g, cams, 2))
            t_full, full = full_cache[opacity]
            t_cull, culled = _render_all(render_views, gc, cams, 2)
            cull_rows.append({"scene": label, "kept_fraction": float(mask.mean()), "mask_ms": t_mask["best_ms"],
                              "render_full_ms": t_full["best_ms"], "render_culled_ms": t_cull["best_ms"],
                              "render_time_saved_fraction": 1 - t_cull["best_ms"] / t_full["best_ms"],
                              "psnr_db": _psnr(full, culled), "max_abs_err": float(np.abs(full - culled).max()),
                              "views": len(cams), "frames": len(g), "margin_deg": margin})
        print(f"\nBack-face culling over the 48-view cone ({len(cams)} of the views rendered; "
              f"frames: {', '.join(named)})")
        print(f"{'scene':32s} {'kept':>6s} {'mask ms':>8s} {'full ms':>9s} {'culled ms':>10s} {'saved':>6s} "
              f"{'PSNR dB':>8s}")
        for r in cull_rows:
            print(f"{r['scene']:32s} {r['kept_fraction']:6.3f} {r['mask_ms']:8.2f} {r['render_full_ms']:9.0f} "
                  f"{r['render_culled_ms']:10.0f} {r['render_time_saved_fraction']:6.2f} {r['psnr_db']:8.2f}")

    result = {
        "config": {"n_gaussians": rig.n_gaussians, "n_expr": k, "threads": args.threads, "repeat": args.repeat,
                   "levels": levels, "n_random": args.n_random, "dtype": "float32", "batch": 1,
                   "render_views": args.render_views, "margin_deg": args.margin_deg,
                   "blend_representation": blend.representation, "blend_nnz": blend.nnz, "n_faces": n_faces,
                   "generate_s": t_gen, "linearise_s": t_lin},
        "baseline": "rigged (FLAME forward + triangle binding), best-of-N wall time",
        "timings": timings,
        "ratios_to_rigged": {name: base / tm["best_ms"] for name, tm in timings.items()},
        "cache": cache_rows,
        "blendshape_error": sweep,
        "blendshape_render_psnr": render_rows,
        "culling": cull_rows,
    }
    if args.json is not None:
        from holo_viewer.fileio import atomic_write

        with atomic_write(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
