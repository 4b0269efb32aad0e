"""Face realism of the default avatar, measured by an independent landmark detector (issue 17).

The detector is dlib's HOG face detector and 68-point shape predictor (iBUG 300-W layout),
trained on real photographs (packages ``dlib-bin`` and ``face_recognition_models``, the
``realism`` extra). It measures, on renders of the default avatar:

* ``found``: in how many of the 48 quilt views (Gaussians) a face is detected, per expression;
* landmark ratios against neutral (same renderer), each measure the median over the quilt views
  within 2 degrees of 0, -15 and +15 degrees (:func:`view_window`): eye aperture, brow-to-eye gap
  and nose-to-lip gap at pain 1.0, mouth width for a smile (definitions in
  :func:`face_measures` and docs/face_realism.md);
* monotonicity of every measure as pain goes 0 -> 0.25 -> 0.5 -> 1 (same three windows);
* fidelity: PSNR of the Gaussian view against the mesh render with the *same* quilt camera
  (VTK, exact intrinsics including the off-axis principal point, `holo_viewer.flame.preview.render_mesh_cameras`)
  over the mesh's mask, at the views nearest to 0 and +-20 degrees.

Renderers: ``gaussians`` = ``Pipeline.views()`` (the quilt's 48 views, 420x560); ``mesh`` =
the posed FLAME mesh from the same ``Pipeline.mesh()``, textured (``flame.head_textures``; region
colours for a model without UVs) and lit as ``flame.preview`` (the head of ``make demo``'s ``out/head``), through the quilt
cameras; ``mesh_preview_front`` = ``flame.preview.render_mesh`` at 400x480 framed exactly as
``out/head/*_front.png`` (the renders the issue's numbers came from), turned by the front
window's camera angles.

Expressions (``FaceControls``): neutral; smile = named ``smile`` 1.0; pain 0.25 / 0.5 / 1.0 =
``pain``; mouth open = named ``mouth_open`` 1.0 (the intensities of ``flame.preview.HEAD_POSES``).

Usage::

    python bench/face_realism.py [--json bench/results/face_realism.json] [--images DIR] [--sheet FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from holo_viewer.errors import MissingDependencyError  # noqa: E402
from holo_viewer.images import psnr  # noqa: E402  (the one PSNR, shared with the fit)
from holo_viewer.tracking.landmarks import predictor_path  # noqa: E402

#: 68-point (iBUG 300-W, 0-based) index groups; "right" = the subject's right (image left)
RIGHT_EYE = list(range(36, 42))
LEFT_EYE = list(range(42, 48))
RIGHT_BROW = list(range(17, 22))
LEFT_BROW = list(range(22, 27))
#: (upper, lower) lid landmark pairs whose distances make the eye aperture
EYE_LID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))
#: upper-lid landmarks under each brow
RIGHT_UPPER_LID = [37, 38]
LEFT_UPPER_LID = [43, 44]
SUBNASALE = 33  # nose base, centre
UPPER_LIP_TOP = 51  # upper lip outer contour, centre
MOUTH_CORNERS = (48, 54)

MEASURES = ("eye_aperture", "brow_eye_gap", "nose_lip_gap", "mouth_width")

#: the issue's targets: (measure, expression, comparison, threshold) on ratio to neutral
TARGETS = (
    ("eye_aperture", "pain_1", "<=", 0.6),
    ("brow_eye_gap", "pain_1", "<=", 0.85),
    ("nose_lip_gap", "pain_1", "<=", 0.85),
    ("mouth_width", "smile", ">=", 1.1),
)
FOUND_TARGET = 46  # of 48 views
PSNR_TARGET_DB = 30.0
PAIN_LEVELS = (0.0, 0.25, 0.5, 1.0)
LANDMARK_ANGLES = (0.0, -15.0, 15.0)
#: landmark measures are medians over the views within this many degrees of each angle (the
#: predictor's landmarks jitter by several percent between neighbouring views 0.85 deg apart)
WINDOW_DEG = 2.0
FIDELITY_ANGLES = (0.0, -20.0, 20.0)


# =============================================================================== measures (pure)


def inter_ocular(lm: np.ndarray) -> float:
    """Distance between the eye centres (means of landmarks 36-41 and 42-47), pixels. ``lm`` (68, 2)."""
    lm = np.asarray(lm, dtype=np.float64)
    return float(np.linalg.norm(lm[RIGHT_EYE].mean(0) - lm[LEFT_EYE].mean(0)))


def face_measures(lm: np.ndarray) -> dict[str, float]:
    """The four landmark measures of one face, each divided by the inter-ocular distance.

    Parameters
    ----------
    lm : numpy.ndarray
        (68, 2) landmark pixel coordinates, iBUG 300-W order.

    Returns
    -------
    dict
        ``eye_aperture``: mean of the four upper-to-lower lid distances |37-41|, |38-40|,
        |43-47|, |44-46|; ``brow_eye_gap``: mean over both sides of the distance from the brow
        centroid (17-21, 22-26) to the centroid of the upper-lid points below it (37-38,
        43-44); ``nose_lip_gap``: |33-51| (subnasale to the top of the upper lip);
        ``mouth_width``: |48-54| (mouth corners); all over :func:`inter_ocular`.
    """
    lm = np.asarray(lm, dtype=np.float64)
    if lm.shape != (68, 2) or not np.all(np.isfinite(lm)):
        raise ValueError(f"landmarks: expected finite (68, 2), found {lm.shape}")
    iod = inter_ocular(lm)
    if iod <= 0:
        raise ValueError("landmarks: the two eye centres coincide")

    def d(a: Any, b: Any) -> float:
        return float(np.linalg.norm(np.atleast_2d(lm[a]).mean(0) - np.atleast_2d(lm[b]).mean(0)))

    return {
        "eye_aperture": float(np.mean([d(a, b) for a, b in EYE_LID_PAIRS])) / iod,
        "brow_eye_gap": 0.5 * (d(RIGHT_BROW, RIGHT_UPPER_LID) + d(LEFT_BROW, LEFT_UPPER_LID)) / iod,
        "nose_lip_gap": d(SUBNASALE, UPPER_LIP_TOP) / iod,
        "mouth_width": d(MOUTH_CORNERS[0], MOUTH_CORNERS[1]) / iod,
    }


def monotone(values: Sequence[float], direction: int = 0, tol: float = 0.0) -> bool:
    """True when consecutive differences all have one sign (``direction`` -1 / +1 forces it; 0 either),
    a step against that sign of at most ``tol`` (>= 0; the measurement's repeatability) allowed."""
    if not tol >= 0:
        raise ValueError(f"tol: expected >= 0, found {tol}")
    diff = np.diff(np.asarray(values, dtype=np.float64))
    if not np.all(np.isfinite(diff)):
        return False
    if direction < 0:
        return bool(np.all(diff <= tol))
    if direction > 0:
        return bool(np.all(diff >= -tol))
    return bool(np.all(diff <= tol) or np.all(diff >= -tol))


def nearest_views(angles: np.ndarray, targets: Sequence[float]) -> list[int]:
    """Index of the view whose angle (degrees) is nearest to each target (first on ties)."""
    a = np.asarray(angles, dtype=np.float64)
    return [int(np.argmin(np.abs(a - t))) for t in targets]


# =============================================================================== detector


class Detector:
    """dlib HOG face detector (1x upsampling) + 68-point shape predictor on RGB images."""

    def __init__(self, upsample: int = 1) -> None:
        try:
            import dlib
        except ImportError as exc:
            raise MissingDependencyError("dlib-bin", "the face realism measurement", extra="live") from exc
        self._det = dlib.get_frontal_face_detector()
        self._sp = dlib.shape_predictor(str(predictor_path()))  # the tracker's model file (the [live] extra)
        self._rect = dlib.rectangle
        self.upsample = int(upsample)

    def __call__(self, image: np.ndarray) -> tuple[np.ndarray, float] | None:
        """(68, 2) landmarks and HOG score of the highest-scoring face in ``image`` (H, W, 3), or None."""
        img = np.asarray(image)
        if img.dtype != np.uint8:
            img = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        img = np.ascontiguousarray(img[..., :3])
        rects, scores, _ = self._det.run(img, self.upsample, 0.0)
        if not rects:
            return None
        k = int(np.argmax(scores))
        shape = self._sp(img, rects[k])
        lm = np.array([(shape.part(i).x, shape.part(i).y) for i in range(68)], dtype=np.float64)
        return lm, float(scores[k])


# =============================================================================== mesh renders


def camera_angles(cameras: Any, focal_center: np.ndarray) -> np.ndarray:
    """(V,) horizontal angle (degrees, + toward world +x) of each camera centre seen from the focal centre."""
    R, t = cameras.world_to_cam[:, :3, :3], cameras.world_to_cam[:, :3, 3]
    centres = -np.einsum("vji,vj->vi", R, t)
    rel = centres - np.asarray(focal_center)[None]
    return np.degrees(np.arctan2(rel[:, 0], rel[:, 2]))


# =============================================================================== bench


def expressions() -> dict[str, Any]:
    from holo_viewer.pipeline import FaceControls

    out = {"neutral": FaceControls(), "smile": FaceControls(named=(("smile", 1.0),))}
    for p in PAIN_LEVELS[1:]:
        out[f"pain_{p:g}".replace(".", "")] = FaceControls(pain=p)
    out["mouth_open"] = FaceControls(named=(("mouth_open", 1.0),))
    return out


def _draw(image: np.ndarray, lm: np.ndarray | None) -> np.ndarray:
    """``image`` (H, W, 3) float with the 68 landmarks ``lm`` (68, 2) drawn as dots (eyes green,
    brows yellow, the rest red); unchanged when None."""
    if lm is None:
        return image
    from PIL import Image, ImageDraw

    im = Image.fromarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8))
    dr = ImageDraw.Draw(im)
    for k, (x, y) in enumerate(lm):
        c = (0, 255, 0) if 36 <= k < 48 else (255, 255, 0) if 17 <= k < 27 else (255, 0, 0)
        dr.ellipse([x - 1.5, y - 1.5, x + 1.5, y + 1.5], fill=c)
    return np.asarray(im)


def _ratio(a: dict | None, b: dict | None, key: str) -> float | None:
    if a is None or b is None:
        return None
    return a[key] / b[key]


def view_window(angles: np.ndarray, target: float, half_width: float = WINDOW_DEG) -> list[int]:
    """Views whose angle (degrees) lies within ``half_width`` of ``target``; the nearest one if none does."""
    a = np.asarray(angles, dtype=np.float64)
    idx = np.nonzero(np.abs(a - target) <= half_width)[0]
    return [int(i) for i in idx] if len(idx) else nearest_views(a, [target])


def median_measures(per_view: Sequence[dict | None]) -> dict[str, float] | None:
    """Per-measure median over the views where a face was found (None when in none)."""
    got = [m for m in per_view if m is not None]
    if not got:
        return None
    return {k: float(np.median([m[k] for m in got])) for k in MEASURES}


#: rows of the contact sheet (``--sheet``): expression keys of :func:`expressions` and their labels
SHEET_ROWS = (("neutral", "neutral"), ("smile", "smile"), ("pain_05", "pain 0.5"), ("pain_1", "pain 1.0"),
              ("mouth_open", "mouth open"))


def head_box(masks: Sequence[np.ndarray], margin: int = 12) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) pixel box around the union of ``masks``, grown by ``margin`` and clipped."""
    union = np.any(np.stack([np.asarray(m, bool) for m in masks]), axis=0)
    if not union.any():
        return 0, union.shape[0], 0, union.shape[1]
    rows, cols = np.nonzero(union)
    h, w = union.shape
    return (max(int(rows.min()) - margin, 0), min(int(rows.max()) + 1 + margin, h),
            max(int(cols.min()) - margin, 0), min(int(cols.max()) + 1 + margin, w))


def contact_sheet_image(res: dict[str, Any], scale: float = 1.0) -> np.ndarray:
    """Labelled sheet: a row per :data:`SHEET_ROWS` expression, *mesh | Gaussians* per fidelity view, PSNR under each pair."""
    from PIL import Image, ImageDraw, ImageFont

    pairs, fid = res["sheet_pairs"], list(res["fid_views"])
    names = [(k, label) for k, label in SHEET_ROWS if k in pairs]
    top, bottom, left, right = head_box([pairs[k][i][2] for k, _ in names for i in fid])
    tile_h, tile_w = bottom - top, right - left
    size = max(11, tile_h // 22)  # legible after the sheet is scaled down for the README
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    head_w, label_h, pad = 8 * size, 2 * size, 4
    cols = [(i, which) for i in fid for which in (1, 0)]  # mesh then Gaussians per view
    H = label_h + len(names) * (tile_h + label_h + pad)
    W = head_w + len(cols) * (tile_w + pad)
    sheet = Image.new("RGB", (W, H), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for c, (i, which) in enumerate(cols):
        x = head_w + c * (tile_w + pad)
        draw.text((x + 2, 2), f"{'mesh' if which else 'Gaussians'} v{i} ({res['angles'][i]:+.0f} deg)", fill=(0, 0, 0),
                  font=font)
    for r, (key, label) in enumerate(names):
        y = label_h + r * (tile_h + label_h + pad)
        draw.text((4, y + tile_h // 2), label, fill=(0, 0, 0), font=font)
        for c, (i, which) in enumerate(cols):
            x = head_w + c * (tile_w + pad)
            img = np.clip(pairs[key][i][which][top:bottom, left:right], 0, 1)
            sheet.paste(Image.fromarray((img * 255 + 0.5).astype(np.uint8)), (x, y))
            if which == 0:
                db = res["per_expression"][key]["psnr_db"][int(i)]
                draw.text((x - tile_w // 2 - 3 * size, y + tile_h + 2), f"PSNR {db:.1f} dB", fill=(0, 0, 0),
                          font=font)
    if scale != 1.0:
        sheet = sheet.resize((int(W * scale), int(H * scale)), Image.LANCZOS)
    return np.asarray(sheet)


def run(images_dir: Path | None = None) -> dict[str, Any]:
    from holo_viewer.fileio import save_image
    from holo_viewer.flame.preview import render_mesh, render_mesh_cameras
    from holo_viewer.pipeline import Pipeline

    det = Detector()
    load_before = os.getloadavg()[0]
    t_start = time.perf_counter()
    pipe = Pipeline()
    model = pipe.model
    faces = model.faces.cpu().numpy()
    from holo_viewer.avatar.default_gaussians import appearance_colors
    from holo_viewer.flame.head_textures import head_appearance

    appearance = head_appearance(model)  # the textured mesh
    colors = appearance_colors(model) if appearance is None else None  # region colours for an untextured head
    cams = pipe.cameras()
    (framing,), _ = pipe.compute("framing")
    centre = np.asarray(framing[0])
    angles = camera_angles(cams, centre)
    windows = {f"{t:+g} deg": view_window(angles, t) for t in LANDMARK_ANGLES}
    lm_views = sorted({i for w in windows.values() for i in w})
    fid_views = nearest_views(angles, FIDELITY_ANGLES)
    mesh_views = sorted(set(lm_views) | set(fid_views))
    preview_yaws = [float(angles[i]) for i in windows[f"{LANDMARK_ANGLES[0]:+g} deg"]]

    per: dict[str, Any] = {}
    sheet_pairs: dict[str, dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    for name, face in expressions().items():
        pipe.set_face(face)
        views = pipe.views()
        verts = pipe.mesh()
        found, scores, meas, marks = 0, [], {}, {}
        for i in range(len(cams)):
            r = det(views[i])
            if r is not None:
                found += 1
                scores.append(r[1])
                if i in lm_views:
                    meas[i] = face_measures(r[0])
                    marks[("g", i)] = r[0]
        mimg, mmask = render_mesh_cameras(verts, faces, cams, mesh_views, colors=colors, appearance=appearance)
        mesh_meas = {}
        for k, i in enumerate(mesh_views):
            r = det(mimg[k])
            mesh_meas[i] = None if r is None else face_measures(r[0])
            if r is not None:
                marks[("m", i)] = r[0]
        psnrs = {int(i): psnr(views[i], mimg[mesh_views.index(i)], mask=mmask[mesh_views.index(i)])
                for i in fid_views}
        # the out/head front framing (flame.preview.write_head_renders), same posed vertices, turned by
        # the front window's camera angles
        lo, hi = verts.min(0), verts.max(0)
        prevs = render_mesh(verts, faces, views=[(y, 0.0) for y in preview_yaws], size=(400, 480), colors=colors,
                            target=0.5 * (lo + hi), distance=0.95, appearance=appearance)
        prev_det = [det(im) for im in prevs]
        prev_meas = [None if r is None else face_measures(r[0]) for r in prev_det]
        entry: dict[str, Any] = {"found": found, "score_median": float(np.median(scores)) if scores else None}
        for renderer, table in (("gaussians", meas), ("mesh", mesh_meas)):
            entry[renderer] = {label: {"views": w, "per_view": {int(i): table.get(i) for i in w},
                                       "median": median_measures([table.get(i) for i in w])}
                               for label, w in windows.items()}
        entry["mesh_preview_front"] = {"yaw_deg": preview_yaws, "per_view": prev_meas,
                                       "median": median_measures(prev_meas)}
        entry["psnr_db"] = psnrs
        per[name] = entry
        sheet_pairs[name] = {int(i): (views[i], mimg[mesh_views.index(i)], mmask[mesh_views.index(i)])
                             for i in fid_views}
        if images_dir is not None:
            images_dir.mkdir(parents=True, exist_ok=True)
            for i in mesh_views:
                k = mesh_views.index(i)
                pair = np.concatenate([_draw(views[i], marks.get(("g", i))), _draw(mimg[k], marks.get(("m", i)))],
                                      axis=1)
                save_image(images_dir / f"{name}_view{i:02d}_gauss_mesh.png", pair)
            mid = len(prevs) // 2
            r = prev_det[mid]
            save_image(images_dir / f"{name}_preview_yaw{preview_yaws[mid]:+.1f}.png",
                       _draw(prevs[mid], None if r is None else r[0]))
        print(f"  {name}: found {found}/48, PSNR " + ", ".join(f"v{i} {p:.1f}" for i, p in psnrs.items()),
              flush=True)
    seconds = time.perf_counter() - t_start
    return {"per_expression": per, "sheet_pairs": sheet_pairs, "angles": angles, "windows": windows, "fid_views": fid_views,
            "preview_yaws": preview_yaws, "seconds": seconds, "load_before": load_before,
            "load_after": os.getloadavg()[0], "n_gaussians": len(pipe.avatar), "tile": [cams.width, cams.height]}


def evaluate(res: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows (measure, renderer, view, value, target, pass) from :func:`run`'s result."""
    per, angles = res["per_expression"], res["angles"]
    rows: list[dict[str, Any]] = []
    for name, e in per.items():
        if name in ("neutral", "smile", "pain_1", "mouth_open"):
            rows.append({"measure": "faces_found", "renderer": "gaussians", "expression": name, "view": "all 48",
                         "value": e["found"], "target": f">= {FOUND_TARGET}", "pass": e["found"] >= FOUND_TARGET})
    sources = [(r, label) for r in ("gaussians", "mesh") for label in res["windows"]] + \
              [("mesh_preview_front", None)]
    for renderer, label in sources:
        def m(expr: str) -> dict | None:
            e = per[expr][renderer]
            return (e if label is None else e[label])["median"]
        if label is None:
            view = f"front, yaw {min(res['preview_yaws']):+.1f}..{max(res['preview_yaws']):+.1f}"
        else:
            w = res["windows"][label]
            view = f"{label} (v{w[0]}-{w[-1]})"
        for measure, expr, op, thr in TARGETS:
            v = _ratio(m(expr), m("neutral"), measure)
            ok = v is not None and (v <= thr if op == "<=" else v >= thr)
            rows.append({"measure": f"{measure} ratio", "renderer": renderer, "expression": expr, "view": view,
                         "value": v, "target": f"{op} {thr}", "pass": bool(ok)})
        for measure in MEASURES:
            seq = [m(n) for n in ("neutral", "pain_025", "pain_05", "pain_1")]
            vals = [None if s is None else s[measure] for s in seq]
            direction = 0 if measure == "mouth_width" else -1
            ok = all(x is not None for x in vals) and monotone(vals, direction)
            rows.append({"measure": f"{measure} monotone over pain", "renderer": renderer, "expression": "pain",
                         "view": view, "value": vals, "target": "non-increasing" if direction < 0 else "monotone",
                         "pass": bool(ok)})
    for name in ("neutral", "smile", "pain_1", "mouth_open"):
        for i, p in per[name]["psnr_db"].items():
            rows.append({"measure": "PSNR gaussians vs mesh (mask)", "renderer": "both", "expression": name,
                         "view": f"v{i} ({angles[i]:+.1f} deg)", "value": p, "target": f">= {PSNR_TARGET_DB}",
                         "pass": p >= PSNR_TARGET_DB})
    return rows


def _fmt(v: Any) -> str:
    if v is None:
        return "no face"
    if isinstance(v, list):
        return " > ".join("-" if x is None else f"{x:.3f}" for x in v)
    if isinstance(v, float):
        return f"{v:.3f}"
    return str(v)


#: the pain legibility levels of ``--quick`` (issue 36: monotone from 0.2 to 1.0 at the centre views)
QUICK_PAIN_LEVELS = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)


def run_quick(levels: Sequence[float] = QUICK_PAIN_LEVELS) -> dict[str, Any]:
    """Pain legibility only: the Gaussians' centre views (the +0 deg window), measures per pain level
    as ratios to neutral, and whether each measure is monotone over the levels (~1 min instead of ~2)."""
    from holo_viewer.pipeline import FaceControls, Pipeline

    det = Detector()
    t0 = time.perf_counter()
    pipe = Pipeline()
    cams = pipe.cameras()
    (framing,), _ = pipe.compute("framing")
    views = view_window(camera_angles(cams, np.asarray(framing[0])), 0.0)
    per = {}
    for p in levels:
        pipe.set_face(FaceControls(pain=float(p)))
        got = []
        for i in views:
            r = det(pipe.render_view(i))
            got.append(None if r is None else face_measures(r[0]))
        per[float(p)] = median_measures(got)
    base = per[float(levels[0])]
    ratios = {m: [None if per[float(p)] is None else per[float(p)][m] / base[m] for p in levels] for m in MEASURES}
    mono = {m: monotone([x for x in ratios[m][1:]], -1 if m != "mouth_width" else 0) and None not in ratios[m]
            for m in MEASURES}
    return {"levels": list(levels), "views": views, "ratios_to_neutral": ratios, "monotone_from_0.2": mono,
            "raw": {str(k): v for k, v in per.items()}, "seconds": time.perf_counter() - t0}


# =============================================================================== per patient (issue 35)

#: what an eye receives through the panel (display.simulate.VirtualDisplay): eye angles (deg), stride
EYE_ANGLES = (0.0, -15.0, 15.0)
EYE_DOWNSAMPLE = 2
#: an eye's measures are medians over the eye positions every EYE_STEP_DEG within EYE_WINDOW_DEG of each
#: angle, as the quilt's are over the views within WINDOW_DEG (docs/face_realism.md, "Repeatability")
EYE_WINDOW_DEG = 2.0
EYE_STEP_DEG = 1.0
EYE_EXPRESSIONS = ("neutral", "pain_025", "pain_05", "pain_1")
#: the repeatability of a window's median (inter-ocular distances), per measure: the 95th percentile of the
#: |difference| between two window medians of the same face (quilt windows moved by one view, eye windows by
#: half a step; amara, kwame, rafael and the default x 4 pain levels x 3 angles, 144 pairs a measure;
#: docs/face_realism.md "Repeatability"). A step of the monotonicity test counts as a rise only beyond it.
MONOTONE_TOL = {"eye_aperture": 0.0065, "brow_eye_gap": 0.0083, "nose_lip_gap": 0.0078}


def eye_positions(angle: float, half_width: float = EYE_WINDOW_DEG, step: float = EYE_STEP_DEG) -> list[float]:
    """Eye angles (degrees) every ``step`` within ``half_width`` of ``angle``, ``angle`` itself among them."""
    if not (step > 0 and half_width >= 0):
        raise ValueError(f"eye window: expected step > 0 and half_width >= 0, found {step}, {half_width}")
    n = int(np.floor(half_width / step + 1e-9))
    return [float(angle + k * step) for k in range(-n, n + 1)]
PATIENT_FOUND_EXPRESSIONS = ("neutral", "smile", "pain_1", "mouth_open")


def load_patient_avatar(name: str) -> Any:
    """The fitted avatar of ``default`` or a patient (``holo_viewer.avatar.patients``)."""
    if name == "default":
        from holo_viewer.avatar.default_gaussians import default_avatar

        return default_avatar()
    from holo_viewer.avatar.patients import load_patient_avatar as load

    return load(name)


def run_patient(name: str, images_dir: Path | None = None, renderer: str = "gaussians",
                normalise_pain: bool = False) -> dict[str, Any]:
    """The issue's detector targets for one avatar, on its Gaussians: faces found in the 48 quilt views
    (neutral, smile, pain 1, mouth open), the landmark ratios and monotonicity over pain 0 / 0.25 / 0.5 / 1
    in the three view windows, and the same on what an eye receives through the panel (the native image
    seen by :class:`~holo_viewer.display.simulate.VirtualDisplay` at infinity: per angle of ``EYE_ANGLES``,
    the median over the eye positions of :func:`eye_positions`, raw per position in ``eye_positions``).

    ``renderer="mesh"``: the same, with every quilt view rendered as the avatar's textured mesh (the
    posed head the Gaussians are rigged to, its textures, the quilt cameras; interleaved into the native
    image as the pipeline does): a texture change read before the avatar is refitted to it.
    ``normalise_pain``: pain with the head's identity gains (``au_map_for(normalise_pain=True)``)."""
    from holo_viewer.display.simulate import VirtualDisplay
    from holo_viewer.fileio import save_image
    from holo_viewer.pipeline import Pipeline
    from holo_viewer.pipeline.core import quilt_layout, tile_views

    if renderer not in ("gaussians", "mesh"):
        raise ValueError(f"renderer: expected 'gaussians' or 'mesh', found {renderer!r}")

    det = Detector()
    t0, c0, load0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    pipe = Pipeline(avatar=load_patient_avatar(name))
    if normalise_pain:  # the pain face with the head's identity normalisation (flame.expressions)
        from holo_viewer.flame.expressions import au_map_for

        pipe.set_au_map(au_map_for(pipe.model, normalise_pain=True))
    cams = pipe.cameras()
    (framing,), _ = pipe.compute("framing")
    angles = camera_angles(cams, np.asarray(framing[0]))
    windows = {f"{t:+g} deg": view_window(angles, t) for t in LANDMARK_ANGLES}
    eye = VirtualDisplay(pipe.calibration, downsample=EYE_DOWNSAMPLE)
    if renderer == "mesh":
        from holo_viewer.flame.head_textures import head_appearance
        from holo_viewer.flame.preview import render_mesh_cameras

        appearance, faces = head_appearance(pipe.model), pipe.model.faces.cpu().numpy()
    per: dict[str, Any] = {}
    natives: dict[str, np.ndarray] = {}  # the pain levels' native images, for the eye
    for ename, face in expressions().items():
        pipe.set_face(face)
        if renderer == "mesh":
            imgs, _ = render_mesh_cameras(pipe.mesh(), faces, cams, list(range(len(cams))), appearance=appearance)
            views = np.stack([np.clip(np.asarray(im, np.float32), 0.0, 1.0) for im in imgs])
        else:
            views = pipe.views()
        found, meas = 0, {}
        for i in range(len(cams)):
            r = det(views[i])
            found += r is not None
            meas[i] = None if r is None else face_measures(r[0])
        entry: dict[str, Any] = {"found": int(found), "quilt": {
            label: median_measures([meas[i] for i in w]) for label, w in windows.items()}}
        if ename in EYE_EXPRESSIONS:
            natives[ename] = pipe.native() if renderer != "mesh" else \
                pipe._compute_native(tile_views(views, *quilt_layout(pipe.calibration)))
        if ename in ("neutral", "pain_05", "pain_1"):
            entry["centre_view"] = views[len(cams) // 2]  # the contact sheet's picture (not in the JSON)
            if images_dir is not None:
                images_dir.mkdir(parents=True, exist_ok=True)
                save_image(images_dir / f"{name}_{ename}_view{len(cams) // 2}.png", views[len(cams) // 2])
        per[ename] = entry
        print(f"  {name} {ename}: found {found}/48", flush=True)
    # through the panel: every eye position of each window sees the pain levels' native images (one
    # set of subpixel weights per position), the measures are medians over the positions
    for a in EYE_ANGLES:
        label = f"{a:+g} deg"
        got: dict[str, list[dict[str, float] | None]] = {e: [] for e in natives}
        for pos in eye_positions(a):
            for ename, img in zip(natives, eye.see_many(list(natives.values()), pos)):
                r = det(img)
                got[ename].append(None if r is None else face_measures(r[0]))
                if images_dir is not None and pos == a and ename in ("neutral", "pain_1"):
                    images_dir.mkdir(parents=True, exist_ok=True)
                    save_image(images_dir / f"{name}_{ename}_eye{a:+g}.png", _draw(img, None if r is None else r[0]))
        for ename, vals in got.items():
            per[ename].setdefault("eye", {})[label] = median_measures(vals)
            per[ename].setdefault("eye_positions", {})[label] = vals
    return {"name": name, "renderer": renderer, "normalise_pain": normalise_pain, "per_expression": per,
            "windows": windows,
            "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0, "load_1min": [load0, os.getloadavg()[0]]}


def evaluate_patient(res: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows (measure, where, value, target, pass) of :func:`run_patient`: faces found, the three pain
    ratios and monotonicity (eye aperture, brow gap, nose-lip gap) on quilt windows and eye views."""
    per = res["per_expression"]
    rows: list[dict[str, Any]] = []
    for e in PATIENT_FOUND_EXPRESSIONS:
        rows.append({"measure": "faces found", "where": f"quilt, {e}", "value": per[e]["found"],
                     "target": f">= {FOUND_TARGET}", "pass": per[e]["found"] >= FOUND_TARGET})
    pain = ("neutral", "pain_025", "pain_05", "pain_1")
    for kind in ("quilt", "eye"):
        for label in per["neutral"][kind]:
            seq = [per[e][kind][label] for e in pain]
            for measure, expr, op, thr in TARGETS[:3]:
                v = _ratio(seq[-1], seq[0], measure)
                rows.append({"measure": f"{measure} pain 1 / neutral", "where": f"{kind} {label}", "value": v,
                             "target": f"{op} {thr}", "pass": v is not None and v <= thr})
                vals = [None if s is None else s[measure] for s in seq]
                tol = MONOTONE_TOL[measure]
                ok = all(x is not None for x in vals) and monotone(vals, -1, tol)
                rows.append({"measure": f"{measure} monotone over pain", "where": f"{kind} {label}", "value": vals,
                             "target": f"non-increasing (+{tol:g})", "pass": bool(ok)})
    return rows


def patient_sheet(results: dict[str, dict[str, Any]], width: int = 220, face_fraction: float = 0.74) -> np.ndarray:
    """Columns = avatars, rows = neutral / pain 0.5 / pain 1.0 (centre quilt view, Gaussians), cropped to
    the union of the heads' pixels (its top ``face_fraction``: head and face, not the shoulders), each
    tile ``width`` px wide, labelled."""
    from PIL import Image, ImageDraw, ImageFont

    rows = (("neutral", "neutral"), ("pain_05", "pain 0.5"), ("pain_1", "pain 1.0"))
    imgs = {n: [np.asarray(r["per_expression"][k]["centre_view"]) for k, _ in rows] for n, r in results.items()}
    top, bottom, left, right = head_box([im.max(-1) > 0.02 for v in imgs.values() for im in v], margin=6)
    bottom = top + int(round((bottom - top) * face_fraction))
    tile_w = int(width)
    tile_h = int(round((bottom - top) * tile_w / (right - left)))
    size = max(12, tile_w // 13)
    try:
        font = ImageFont.load_default(size=size)
    except TypeError:
        font = ImageFont.load_default()
    label_w, head_h, pad = 6 * size, int(1.6 * size), 3
    sheet = Image.new("RGB", (label_w + len(imgs) * (tile_w + pad), head_h + len(rows) * (tile_h + pad)),
                      (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for c, name in enumerate(imgs):
        draw.text((label_w + c * (tile_w + pad) + tile_w // 4, 2), name, fill=(0, 0, 0), font=font)
    for r, (_, label) in enumerate(rows):
        y = head_h + r * (tile_h + pad)
        draw.text((4, y + tile_h // 2), label, fill=(0, 0, 0), font=font)
        for c, row in enumerate(imgs.values()):
            tile = Image.fromarray((np.clip(row[r][top:bottom, left:right], 0, 1) * 255 + 0.5).astype(np.uint8))
            sheet.paste(tile.resize((tile_w, tile_h), Image.LANCZOS), (label_w + c * (tile_w + pad), y))
    return np.asarray(sheet)


def sheet_views(name: str) -> dict[str, Any]:
    """Only the contact sheet's pictures of one avatar (centre quilt view at neutral, pain 0.5 and 1)."""
    from holo_viewer.pipeline import FaceControls, Pipeline

    pipe = Pipeline(avatar=load_patient_avatar(name))
    mid = len(pipe.cameras()) // 2
    per = {}
    for key, p in (("neutral", 0.0), ("pain_05", 0.5), ("pain_1", 1.0)):
        pipe.set_face(FaceControls(pain=p))
        per[key] = {"centre_view": pipe.render_view(mid)}
    return {"per_expression": per}


def main_patients(names: Sequence[str], json_path: str, images: str | None, sheet: str | None = None,
                  sheet_only: bool = False, merge: bool = False, renderer: str = "gaussians",
                  normalise_pain: bool = False) -> int:
    if "all" in names:  # every fitted patient, in place of "all" (``all default`` adds the default avatar)
        from holo_viewer.avatar.patients import list_patients

        fitted = [p.name for p in list_patients() if p.fitted]
        names = [x for n in names for x in (fitted if n == "all" else [n])]
        names = list(dict.fromkeys(names))
    if sheet_only:
        from holo_viewer.fileio import save_image

        if not sheet:
            print("error: --sheet-only needs --sheet FILE", file=sys.stderr)
            return 2
        print(f"wrote {save_image(sheet, patient_sheet({n: sheet_views(n) for n in names}))}")
        return 0
    out: dict[str, Any] = {}
    if merge and Path(json_path).is_file():  # keep the other avatars' rows of an earlier run
        with open(json_path) as fh:
            prev = json.load(fh)
        if not isinstance(prev, dict) or not isinstance(prev.get("patients"), dict):
            print(f"error: --merge: {json_path} has no 'patients' object to merge into", file=sys.stderr)
            return 2
        out.update({k: v for k, v in prev["patients"].items() if k not in names})
    results: dict[str, Any] = {}
    for name in names:
        res = run_patient(name, Path(images) if images else None,
                          **({"renderer": renderer} if renderer != "gaussians" else {}),
                          **({"normalise_pain": True} if normalise_pain else {}))
        rows = evaluate_patient(res)
        n_pass = sum(r["pass"] for r in rows)
        print(f"\n{name}: {n_pass}/{len(rows)} pass ({res['seconds']:.0f} s, {res['cpu_seconds']:.0f} s CPU, load "
              f"{res['load_1min'][0]:.1f} -> {res['load_1min'][1]:.1f})")
        for r in rows:
            if not r["pass"] or r["measure"].startswith("faces"):
                print(f"  {r['measure']:<34} {r['where']:<18} {_fmt(r['value']):<34} {r['target']:<15} "
                      f"{'PASS' if r['pass'] else 'fail'}")
        results[name] = res
        raw = {**res, "per_expression": {e: {k: v for k, v in d.items() if k != "centre_view"}
                                         for e, d in res["per_expression"].items()}}
        out[name] = {"rows": rows, "passed": n_pass, "total": len(rows), "raw": raw}
        record = {"config": {"eye_angles_deg": list(EYE_ANGLES), "eye_downsample": EYE_DOWNSAMPLE,
                             "eye_window_half_width_deg": EYE_WINDOW_DEG, "eye_step_deg": EYE_STEP_DEG,
                             "monotone_tolerance_iod": MONOTONE_TOL,
                             "eye_distance": "infinity", "pain": list(PAIN_LEVELS), "window_half_width_deg": WINDOW_DEG,
                             "detector": "dlib HOG (upsample 1) + shape_predictor_68_face_landmarks",
                             "renderer": renderer, "normalise_pain": normalise_pain, "host": platform.node()},
                  "patients": out}
        write_json(json_path, record)
    print(f"wrote {json_path}")
    if sheet:
        from holo_viewer.fileio import save_image

        print(f"wrote {save_image(sheet, patient_sheet(results))}")
    return 0


#: eye offsets (degrees) of the repeatability study: the 1-degree grid of :func:`eye_positions` and the
#: grid moved by half a step, plus +-0.25 deg
REPEAT_OFFSETS = (-2.0, -1.5, -1.0, -0.5, -0.25, 0.0, 0.25, 0.5, 1.0, 1.5, 2.0)


def repeatability(names: Sequence[str]) -> dict[str, Any]:
    """How much the window medians move when the same face is measured again: per avatar and pain level
    (0, 0.25, 0.5, 1), every quilt view's measures and the eye images at each angle + :data:`REPEAT_OFFSETS`.
    Pairs of window medians of one face: a quilt window and the same window moved by one view (either way),
    an eye window on the 1-deg grid and on the grid moved by half a step. Returns per measure the median
    and 95th percentile of |difference| over all pairs (IOD), single-image changes for comparison, and
    the raw measures."""
    from holo_viewer.display.simulate import VirtualDisplay
    from holo_viewer.pipeline import FaceControls, Pipeline

    det = Detector()
    pains = (0.0, 0.25, 0.5, 1.0)
    pairs: dict[str, dict[str, list[float]]] = {k: {m: [] for m in MEASURES[:3]} for k in
                                                ("quilt_window", "eye_window", "quilt_single_view", "eye_single_half_deg")}
    raw: dict[str, Any] = {}
    t0, c0, load0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    for name in names:
        pipe = Pipeline(avatar=load_patient_avatar(name))
        cams = pipe.cameras()
        (framing,), _ = pipe.compute("framing")
        angles = camera_angles(cams, np.asarray(framing[0]))
        eye = VirtualDisplay(pipe.calibration, downsample=EYE_DOWNSAMPLE)
        quilt, natives = {}, []
        for p in pains:
            pipe.set_face(FaceControls(pain=p))
            views = pipe.views()
            natives.append(pipe.native())
            quilt[p] = []
            for i in range(len(cams)):
                r = det(views[i])
                quilt[p].append(None if r is None else face_measures(r[0]))
        eyes: dict[float, dict[float, list]] = {}
        for a in EYE_ANGLES:
            eyes[a] = {p: {} for p in pains}
            for d in REPEAT_OFFSETS:
                for p, img in zip(pains, eye.see_many(natives, a + d)):
                    r = det(img)
                    eyes[a][p][d] = None if r is None else face_measures(r[0])
        for m in MEASURES[:3]:
            for p in pains:
                for t in LANDMARK_ANGLES:
                    w = view_window(angles, t)
                    g0 = median_measures([quilt[p][i] for i in w])
                    for s in (-1, 1):
                        g1 = median_measures([quilt[p][i + s] for i in w])
                        if g0 and g1:
                            pairs["quilt_window"][m].append(g0[m] - g1[m])
                    for i in w[:-1]:
                        if quilt[p][i] and quilt[p][i + 1]:
                            pairs["quilt_single_view"][m].append(quilt[p][i][m] - quilt[p][i + 1][m])
                for a in EYE_ANGLES:
                    e = eyes[a][p]
                    g0 = median_measures([e[d] for d in (-2.0, -1.0, 0.0, 1.0, 2.0)])
                    g1 = median_measures([e[d] for d in (-1.5, -0.5, 0.5, 1.5)])
                    if g0 and g1:
                        pairs["eye_window"][m].append(g0[m] - g1[m])
                    for d in (-0.5, 0.5):
                        if e[0.0] and e[d]:
                            pairs["eye_single_half_deg"][m].append(e[0.0][m] - e[d][m])
        raw[name] = {"quilt": {str(p): v for p, v in quilt.items()},
                     "eye": {f"{a:+g} deg": {str(p): {f"{d:+g}": v for d, v in byd.items()} for p, byd in byp.items()}
                             for a, byp in eyes.items()}}
        print(f"  {name}: {time.process_time() - c0:.0f} s CPU so far", flush=True)

    def stats(x: list[float]) -> dict[str, float]:
        a = np.abs(np.asarray(x, np.float64))
        return {"n": int(a.size), "median": float(np.median(a)), "p95": float(np.percentile(a, 95))}

    summary = {k: {m: stats(v) for m, v in byk.items()} for k, byk in pairs.items()}
    pooled = {m: stats(pairs["quilt_window"][m] + pairs["eye_window"][m]) for m in MEASURES[:3]}
    return {"avatars": list(names), "summary": summary, "window_pooled": pooled, "offsets_deg": list(REPEAT_OFFSETS),
            "differences": pairs,
            "raw": raw, "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
            "load_1min": [load0, os.getloadavg()[0]]}



GEOMETRY_LEVELS = (0.25, 0.5, 0.75, 1.0)


def pain_geometry(names: Sequence[str]) -> dict[str, Any]:
    """Pain on each head's own 68 landmark vertices (float64; no renderer, no detector): neutral eye
    aperture and brow-to-upper-lid gap (IOD; vertical, ``flame.expressions.landmark_pain_measures``)
    and pain p / neutral at :data:`GEOMETRY_LEVELS`, with the shared deltas and with the head's identity
    normalisation (``identity_pain_gains``), plus the gains; also this bench's Euclidean eye / brow /
    nose-lip measures (:func:`face_measures` on the vertices' front projection) with the gains."""
    import torch

    from holo_viewer.flame import expressions as ex

    c0, load0 = time.process_time(), os.getloadavg()[0]
    heads: dict[str, Any] = {}
    for name in names:
        if name == "default":
            from holo_viewer.flame.default_head import load_default_model

            model = load_default_model()
        else:
            from holo_viewer.avatar.patients import load_patient_model

            model = load_patient_model(name)
        am = ex.au_map_for(model, normalise_pain=True)
        shared = am.with_pain_gains(None)
        basis = ex._landmark_basis(model)
        entry: dict[str, Any] = {"gains": dict(am.pain_gains or {}),
                                 "neutral": ex.landmark_pain_measures(basis[0])}
        for label, m in (("shared", shared), ("normalised", am)):
            fr = ex.landmark_pain_fractions(basis, m, levels=GEOMETRY_LEVELS)
            entry[label] = {k: [float(x) for x in v] for k, v in fr.items()}
        idx = np.asarray(model.metadata["landmark_vertices"]).reshape(-1)
        expr = torch.as_tensor(ex.pain_expression(np.array((0.0,) + GEOMETRY_LEVELS), am), dtype=model.dtype)
        with torch.no_grad():
            lm = model(expr=expr).vertices.numpy()[:, idx].astype(np.float64)
        fm = [face_measures(f[:, :2] * [1.0, -1.0]) for f in lm]
        entry["euclidean_normalised"] = {k: [fm[i][k] / fm[0][k] for i in range(1, len(fm))]
                                         for k in ("eye_aperture", "brow_eye_gap", "nose_lip_gap")}
        heads[name] = entry
    return {"levels": list(GEOMETRY_LEVELS), "reference": dict(ex.PAIN_REFERENCE_FRACTIONS), "heads": heads,
            "cpu_seconds": time.process_time() - c0, "load_1min": [load0, os.getloadavg()[0]]}


def write_json(path: str | os.PathLike, record: dict) -> str:
    """Write ``record`` to ``path`` atomically (temp file + rename), indented; return the path."""
    from holo_viewer.fileio import atomic_write

    with atomic_write(path, "w") as fh:
        json.dump(record, fh, indent=1)
    return str(path)

def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "face_realism.json"))
    ap.add_argument("--images", default=None, help="write the measured views (Gaussians | mesh) here")
    ap.add_argument("--sheet", default=None, help="write a labelled contact sheet (mesh | Gaussians per "
                    "expression and fidelity view, PSNR under each pair) to this image file (.png/.jpg)")
    ap.add_argument("--quick", action="store_true", help="pain legibility only: centre views, pain 0, 0.2 ... 1.0 "
                    "(writes bench/results/face_realism_quick.json unless --json is given)")
    ap.add_argument("--patients", nargs="+", default=None, metavar="NAME",
                    help="per avatar (default, patient names, all = every fitted patient; 'all default' adds the "
                         "default avatar): faces found, pain ratios and monotonicity on the quilt and through the panel (writes bench/results/face_realism_patients.json "
                         "unless --json is given)")
    ap.add_argument("--sheet-only", action="store_true", help="with --patients and --sheet: only the contact sheet")
    ap.add_argument("--mesh", action="store_true", help="with --patients: render the textured mesh instead of "
                    "the Gaussians (quilt views and the panel; writes bench/results/face_realism_patients_mesh.json "
                    "unless --json is given): a texture change read before the avatar is refitted")
    ap.add_argument("--merge", action="store_true", help="with --patients: keep the other avatars' entries of the "
                    "JSON file (per-patient runs into one file)")
    ap.add_argument("--repeatability", nargs="+", default=None, metavar="NAME",
                    help="how much the window medians move on the same face (eye moved, window moved by one view): "
                         "writes bench/results/face_realism_repeatability.json unless --json is given; ~100 s CPU each")
    ap.add_argument("--normalise-pain", action="store_true", help="with --patients: pain with each head's "
                    "identity normalisation (flame.expressions.identity_pain_gains; writes "
                    "bench/results/face_realism_patients_normalised.json unless --json is given)")
    ap.add_argument("--pain-geometry", nargs="+", default=None, metavar="NAME",
                    help="pain on each head's landmark vertices (no renderer, no detector), shared deltas and "
                         "identity-normalised, and the gains (writes bench/results/pain_geometry.json unless "
                         "--json is given; 'all' = default and every patient; ~3 s CPU)")
    args = ap.parse_args(argv)

    def out(name: str) -> str:  # --json if given (even the default's value), else bench/results/NAME
        return args.json if "--json" in (argv or sys.argv) else str(Path(__file__).parent / "results" / name)

    if args.pain_geometry:
        names = list(args.pain_geometry)
        if names == ["all"]:
            from holo_viewer.avatar.patients import list_patients

            names = ["default"] + [p.name for p in list_patients()]
        geo = pain_geometry(names)
        lv = " ".join(f"{p:g}" for p in geo["levels"])
        print(f"pain p / neutral at p = {lv} on the landmark vertices (vertical); shared deltas -> normalised")
        for name, h in geo["heads"].items():
            g = h["gains"]
            print(f"{name:<8} gains eye {g.get('AU6', 1.0):.3f} brow {g.get('AU4', 1.0):.3f} | eye "
                  f"{h['neutral']['eye_aperture']:.3f} IOD: " + " ".join(f"{x:.3f}" for x in h["shared"]["eye_aperture"])
                  + " -> " + " ".join(f"{x:.3f}" for x in h["normalised"]["eye_aperture"])
                  + f" | brow {h['neutral']['brow_eye_gap']:.3f} IOD: "
                  + " ".join(f"{x:.3f}" for x in h["shared"]["brow_eye_gap"]) + " -> "
                  + " ".join(f"{x:.3f}" for x in h["normalised"]["brow_eye_gap"]))
        print(f"{geo['cpu_seconds']:.1f} s CPU; wrote {write_json(out('pain_geometry.json'), {**geo, 'host': platform.node()})}")
        return 0
    if args.repeatability:
        rep = repeatability(args.repeatability)
        for m, st in rep["window_pooled"].items():
            print(f"{m:<14} window medians of one face: |diff| median {st['median']:.4f}, p95 {st['p95']:.4f} IOD "
                  f"(n {st['n']}; MONOTONE_TOL {MONOTONE_TOL[m]})")
        print(f"{rep['cpu_seconds']:.0f} s CPU; wrote {write_json(out('face_realism_repeatability.json'), {**rep, 'host': platform.node()})}")
        return 0
    if args.patients:
        default = "face_realism_patients_mesh.json" if args.mesh else "face_realism_patients.json"
        if args.normalise_pain:
            default = default.replace(".json", "_normalised.json")
        return main_patients(args.patients, out(default), args.images, args.sheet, args.sheet_only, args.merge,
                             "mesh" if args.mesh else "gaussians", args.normalise_pain)
    if args.quick:
        q = run_quick()
        print(f"{'measure (ratio to neutral, centre views)':<42} " + " ".join(f"{p:>6g}" for p in q["levels"][1:])
              + "  monotone")
        for m in MEASURES:
            print(f"{m:<42} " + " ".join("     -" if x is None else f"{x:6.3f}" for x in q["ratios_to_neutral"][m][1:])
                  + f"  {q['monotone_from_0.2'][m]}")
        print(f"{q['seconds']:.0f} s; wrote {write_json(out('face_realism_quick.json'), {**q, 'host': platform.node()})}")
        return 0
    res = run(Path(args.images) if args.images else None)
    if args.sheet:
        from holo_viewer.fileio import save_image

        print(f"wrote {save_image(args.sheet, contact_sheet_image(res))}")
    rows = evaluate(res)
    print(f"\n{'measure':<32} {'renderer':<19} {'expr':<10} {'view':<24} {'value':<34} {'target':<15} pass")
    for r in rows:
        print(f"{r['measure']:<32} {r['renderer']:<19} {r['expression']:<10} {r['view']:<24} "
              f"{_fmt(r['value']):<34} {r['target']:<15} {'PASS' if r['pass'] else 'fail'}")
    n_pass = sum(r["pass"] for r in rows)
    print(f"\n{n_pass}/{len(rows)} pass; {res['seconds']:.0f} s, load {res['load_before']:.1f} -> {res['load_after']:.1f}")
    record = {
        "config": {"expressions": {"smile": 1.0, "pain": list(PAIN_LEVELS), "mouth_open": 1.0},
                   "n_gaussians": res["n_gaussians"], "tile": res["tile"],
                   "landmark_windows": {label: {int(i): float(res["angles"][i]) for i in w}
                                        for label, w in res["windows"].items()},
                   "window_half_width_deg": WINDOW_DEG, "preview_yaws_deg": res["preview_yaws"],
                   "fidelity_views": {int(i): float(res["angles"][i]) for i in res["fid_views"]},
                   "detector": "dlib HOG (upsample 1) + shape_predictor_68_face_landmarks",
                   "host": platform.node(), "seconds": res["seconds"],
                   "load_1min": [res["load_before"], res["load_after"]]},
        "rows": rows, "passed": n_pass, "total": len(rows),
        "raw": res["per_expression"],
    }
    print(f"wrote {write_json(args.json, record)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
