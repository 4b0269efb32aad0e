"""Recolour a fitted patient avatar's eye Gaussians for repainted eye textures, without a refit.

Usage::

    python scripts/recolour_eyes.py NAME --old DIR --out FILE

``DIR`` holds the patient's previous textures (``albedo.json`` and its PNGs) and the ``avatar.npz`` fitted
to them; the patient's folder (``assets/patients/NAME``) holds the repainted ones (``build_patients.py``).
Only the Gaussians bound to the eye materials change, and only where the eye albedo at their surface point
changed: their colour becomes shading x new albedo, the shading being the fitted colour over the old albedo
where that was bright (the sclera: the fit's baked lighting) and the eye's median shading where it was dark
(there the ratio is unreliable: e.g. the over-large irises that texture_painter.eye_axis painted before
5fc486c). Higher SH bands scale with the colour (clamped to 4x). Every other field of the file is kept
byte for byte (the ``info`` JSON gains ``eyes_recoloured``). Used for kwame (docs/face_realism.md, "The
irises"); a refit from the clone (``scripts/fit_patients.py``) fits the new eyes directly instead.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def recolour(name: str, old: Path, out: Path, eps: float = 0.03, bright: float = 0.5) -> dict:
    from holo_viewer.assets_build import fit_avatar as fa
    from holo_viewer.avatar import patients
    from holo_viewer.avatar.default_gaussians import load_fitted_avatar
    from holo_viewer.fileio import atomic_write
    from holo_viewer.flame.appearance import MATERIALS

    c0 = time.process_time()
    info = patients.patient_info(name)
    model = patients.load_patient_model(name)
    app_old, app_new = fa.folder_appearance(model, old), fa.folder_appearance(model, info.folder)
    local, binding, keys = load_fitted_avatar(old / "avatar.npz")
    faces = model.faces.cpu().numpy()
    vs = model.v_template.detach().cpu().double().numpy()
    mat = np.asarray(app_old.face_material)
    eye = np.isin(mat, [MATERIALS.index("eye_left"), MATERIALS.index("eye_right")])
    sel = np.nonzero((binding < len(mat)) & eye[np.minimum(binding, len(mat) - 1)])[0]
    sub = local.subset(sel)
    bary = fa.surface_points(sub, binding[sel], vs, faces)
    a_old = np.clip(np.asarray(app_old.albedo_at(binding[sel], bary), np.float64), 0, 1)
    a_new = np.clip(np.asarray(app_new.albedo_at(binding[sel], bary), np.float64), 0, 1)
    sh = np.asarray(sub.sh, np.float64).copy()
    c = np.clip(sh[:, 0] * fa.SH_C0 + 0.5, 0, 1)
    lit = a_old.mean(1) > bright
    shade_med = np.median(c[lit] / (a_old[lit] + eps), axis=0)
    shade = np.where(lit[:, None], c / (a_old + eps), shade_med[None, :])
    changed = np.abs(a_new - a_old).max(1) > 1.5 / 255
    c_new = np.clip(shade * (a_new + eps), 0, 1)
    ratio = np.clip((c_new + eps) / (c + eps), 0, 4.0)
    sh[changed, 1:] *= ratio[changed][:, None, :]
    sh[changed, 0] = (c_new[changed] - 0.5) / fa.SH_C0
    z = np.load(old / "avatar.npz")
    arrays = {k: z[k] for k in z.files}
    sh16 = arrays["sh"].copy()
    sh16[sel[changed]] = sh[changed].astype(np.float16)
    arrays["sh"] = sh16
    note = dict(keys["info"])
    note["eyes_recoloured"] = (f"{int(changed.sum())} Gaussians on the eye materials recoloured for repainted eye "
                               f"textures (scripts/recolour_eyes.py: shading x new albedo, eye median shading "
                               f"{[round(float(x), 3) for x in shade_med]})")
    arrays["info"] = np.array(json.dumps(note))
    with atomic_write(out) as fh:
        np.savez_compressed(fh, **arrays)
    return {"eye_gaussians": int(len(sel)), "changed": int(changed.sum()), "of": int(len(local)),
            "median_shading": [float(x) for x in shade_med], "cpu_seconds": time.process_time() - c0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("name")
    ap.add_argument("--old", type=Path, required=True, help="folder with the previous textures and avatar.npz")
    ap.add_argument("--out", type=Path, required=True, help="the recoloured avatar file")
    args = ap.parse_args(argv)
    r = recolour(args.name, args.old, args.out)
    print(f"{args.name}: {r['changed']} of {r['eye_gaussians']} eye Gaussians recoloured ({r['of']} in all), eye "
          f"shading {np.round(r['median_shading'], 3).tolist()}; {r['cpu_seconds']:.1f} s CPU; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
