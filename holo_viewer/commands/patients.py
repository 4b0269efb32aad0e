"""``holo-viewer patients``: the shipped patients, one a line, name first (docs/patients.md).

Each line: name, sex, age, Fitzpatrick skin type, the folder's size, and the fitted avatar's worst
view PSNR against the textured mesh when it is known (``not fitted yet`` until ``avatar.npz``
exists). ``--json`` prints the same rows as JSON; ``--sheet F.png`` writes a thumbnail sheet of the
heads (the textured mesh, front, neutral and pain 1), one column per patient.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_arguments", "run", "format_rows", "write_sheet"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print the rows as JSON")
    parser.add_argument("--sheet", metavar="F.png", type=Path, default=None,
                        help="also write a thumbnail sheet of the patients' heads (neutral and pain 1)")
    parser.add_argument("--size", type=int, default=200, metavar="PX", help="thumbnail width (default 200)")


def format_rows(rows: list[dict]) -> list[str]:
    """One line per patient, its name first."""
    out = []
    for r in rows:
        fit = "not fitted yet" if not r["fitted"] else (
            "fitted" if r["psnr_min_db"] is None else f"fitted, worst view {r['psnr_min_db']:.1f} dB")
        out.append(f"{r['name']:<8} {r['sex']:<6} {r['age']:>3}  type {r['fitzpatrick']:<3} "
                   f"{r['size_mb']:5.1f} MB  {fit}  ({r['description']})")
    return out


def write_sheet(path: Path, names: list[str], width: int = 200) -> Path:
    """Front renders of each patient's textured head, neutral over pain 1, names underneath."""
    import numpy as np
    import torch
    from PIL import Image, ImageDraw

    from ..avatar.patients import load_patient_model
    from ..errors import InputError
    from ..fileio import save_image
    from ..flame.expressions import au_map_for, pain_expression
    from ..flame.head_textures import head_appearance
    from ..flame.preview import render_mesh

    if not 64 <= width <= 800:
        raise InputError(f"--size: expected 64..800 pixels, found {width}")
    height = int(round(width * 1.2))
    cols = []
    for name in names:
        model = load_patient_model(name)
        app = head_appearance(model)
        expr = torch.as_tensor(pain_expression(1.0, au_map_for(model)), dtype=model.dtype).reshape(1, -1)
        with torch.no_grad():
            poses = [model().vertices[0].numpy(), model(expr=expr).vertices[0].numpy()]
        f = model.faces.numpy()
        ims = [render_mesh(v, f, views=("front",), size=(width, height), appearance=app)[0] for v in poses]
        label = Image.new("RGB", (width, 22), (255, 255, 255))
        ImageDraw.Draw(label).text((6, 5), name, fill=(0, 0, 0))
        lab = np.asarray(label)
        if ims[0].dtype.kind == "f":  # renders in [0, 1]: the label too (uint8 would clip to white)
            lab = lab.astype(ims[0].dtype) / 255.0
        cols.append(np.concatenate(ims + [lab], axis=0))
    if not cols:
        raise InputError("--sheet: no patients are shipped (assets/patients/ is empty)")
    return save_image(path, np.concatenate(cols, axis=1))


def run(args: argparse.Namespace) -> int:
    import json

    from ..avatar.patients import list_patients, patient_summary

    infos = list_patients()
    rows = [patient_summary(i) for i in infos]
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        for line in format_rows(rows):
            print(line)
    if args.sheet is not None:
        path = write_sheet(args.sheet, [i.name for i in infos], args.size)
        print(f"wrote {path}")
    return 0
