"""``holo-viewer export-mesh``: write the posed FLAME head as OBJ / PLY / GLB.

Examples::

    holo-viewer export-mesh --out head.obj                       # neutral default head
    holo-viewer export-mesh --pain 0.8 --jaw 10 --out pain.glb   # pain face, jaw open 10 degrees
    holo-viewer export-mesh --expr AU12=2.5 3=-1.0 --out smile.ply
    holo-viewer export-mesh --flame-model generic_model.pkl --au-map my_aus.json --pain 1 --out p.obj

``--expr`` entries are ``NAME=VALUE`` (a name from the model's ``expression_names``)
or ``INDEX=VALUE`` (0-based component index), each within +-10 (``flame.params.EXPR_LIMIT``, as in Python);
they are the base expression coefficients, and ``--pain`` *adds* the pain face to them, as
``FaceControls(expr=..., pain=...)`` does in Python (the head is posed by the same pipeline
stage). ``--jaw`` opens the jaw (rotation about the head's x axis, degrees, in [-45, 90]).
The file format follows the suffix.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import ExportError, InputError
from ..flame.expressions import PAIN_RANGE
from ..flame.params import EXPR_LIMIT, JAW_LIMITS_DEG
from ..validation import check_finite_scalar

__all__ = ["add_arguments", "run", "parse_expr_assignments", "FORMATS"]

FORMATS = (".obj", ".ply", ".glb")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command-line options of ``export-mesh``."""
    parser.add_argument("--flame-model", metavar="PKL|NPZ", type=Path, default=None,
                        help="FLAME 2020/2023 .pkl or holo_viewer .npz (default: the embedded default head)")
    parser.add_argument("--expr", metavar="NAME=VALUE", nargs="+", action="extend", default=[],
                        help=f"expression coefficients by component name or 0-based index, within +-{EXPR_LIMIT:g} "
                             "(repeatable); --pain adds to them")
    parser.add_argument("--jaw", metavar="DEG", type=float, default=0.0,
                        help=f"jaw opening in degrees (rotation about the x axis, in [{JAW_LIMITS_DEG[0]:g}, "
                             f"{JAW_LIMITS_DEG[1]:g}]; default 0)")
    parser.add_argument("--pain", metavar="P", type=float, default=None,
                        help="pain intensity in [0, 1] (canonical pain face via the AU map)")
    parser.add_argument("--au-map", metavar="JSON", type=Path, default=None,
                        help="AU -> expression-coefficient map; needed for --pain with a user FLAME model")
    parser.add_argument("--teeth", action="store_true", help="add GaussianAvatars-style teeth")
    from .avatar_args import add_avatar_argument

    add_avatar_argument(parser, kinds=("default", "patient", "npz"), help="whose head (a fitted .npz: the head it "
                        "was fitted to)")
    parser.add_argument("--out", metavar="FILE", type=Path, required=True,
                        help="output mesh: .obj, .ply or .glb")


def parse_expr_assignments(items: Sequence[str], names: Sequence[str] | None, n_expr: int) -> dict[int, float]:
    """Parse ``NAME=VALUE`` / ``INDEX=VALUE`` strings into {component index: value}.

    Raises
    ------
    InputError
        Malformed entry, unknown name, index out of range, a non-finite value or one outside
        [-EXPR_LIMIT, EXPR_LIMIT].
    """
    out: dict[int, float] = {}
    lookup = {n: i for i, n in enumerate(names or [])}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise InputError(f"--expr: expected NAME=VALUE or INDEX=VALUE, found {item!r}")
        if key in lookup:
            idx = lookup[key]
        else:
            try:
                idx = int(key)
            except ValueError:
                shown = ", ".join(list(lookup)[:30]) + (" ..." if len(lookup) > 30 else "")
                raise InputError(f"--expr: unknown expression component {key!r}; expected one of "
                                 f"[{shown}] or an index in [0, {n_expr})" if lookup else
                                 f"--expr: the model has no expression_names; expected an index in "
                                 f"[0, {n_expr}), found {key!r}") from None
            if not 0 <= idx < n_expr:
                raise InputError(f"--expr: expected a component index in [0, {n_expr}), found {idx}")
        out[idx] = check_finite_scalar(raw, f"--expr {key}", low=-EXPR_LIMIT, high=EXPR_LIMIT)
    return out


def _load_model(path: Path | None, add_teeth: bool, avatar: str = "default"):
    import torch

    if avatar != "default":
        if path is not None:
            raise InputError(f"--avatar {avatar} and --flame-model {path}: give one head, not both")
        from ..avatar.patients import head_for_avatar_file, patient_info, resolve_avatar
        from ..flame.model import FlameModel

        choice = resolve_avatar(avatar)
        head = patient_info(choice.name).head_path if choice.kind == "patient" else \
            head_for_avatar_file(choice.path)[1]
        model = FlameModel.load(head, n_shape=None, n_expr=None, add_teeth=add_teeth, dtype=torch.float64)
        model.metadata["appearance_dir"] = str(head.parent) if choice.kind == "patient" else None
        return model
    if path is not None:
        from ..flame.model import FlameModel

        return FlameModel.load(path, n_shape=300, n_expr=100, add_teeth=add_teeth, dtype=torch.float64)
    from ..flame.default_head import load_default_model

    return load_default_model(add_teeth=add_teeth, dtype=torch.float64)


def _which(args: argparse.Namespace) -> str:
    avatar = getattr(args, "avatar", "default")
    if args.flame_model is not None:
        return str(args.flame_model)
    return "default head" if avatar == "default" else f"the head of {avatar}"


def run(args: argparse.Namespace) -> int:
    """Pose the head as asked and write the mesh; returns 0."""
    out = Path(args.out)
    if out.suffix.lower() not in FORMATS:
        raise ExportError(f"--out {out}: expected a file ending in {', '.join(FORMATS)}, found {out.suffix!r}")
    jaw_deg = check_finite_scalar(args.jaw, "--jaw", low=JAW_LIMITS_DEG[0], high=JAW_LIMITS_DEG[1])
    pain = None if args.pain is None else check_finite_scalar(args.pain, "--pain", low=PAIN_RANGE[0],
                                                               high=PAIN_RANGE[1])
    from ..pipeline import FaceControls, Pipeline

    model = _load_model(args.flame_model, args.teeth, getattr(args, "avatar", "default"))
    expr = np.zeros(model.n_expr)
    for idx, value in parse_expr_assignments(args.expr, model.expression_names, model.n_expr).items():
        expr[idx] = value
    au_map = None
    if pain is not None:
        from ..flame.expressions import au_map_for

        from ..flame.expressions import pain_expression
        from ..flame.params import check_expr

        au_map = au_map_for(model, args.au_map)  # a user model needs --au-map for pain
        # the +-EXPR_LIMIT rule holds for the expression after the map is applied (pain + --expr)
        check_expr(expr + pain_expression(pain, au_map), name=f"--pain {pain:g} with the AU map "
                   f"{args.au_map or '(default)'}: expression")
    face = FaceControls(expr=expr, jaw_pose=[np.deg2rad(jaw_deg), 0.0, 0.0], pain=pain or 0.0)
    verts = Pipeline(model=model, avatar=False, face=face, au_map=au_map).mesh()
    faces = model.faces.cpu().numpy()
    path = write_mesh(out, verts, faces)
    print(f"wrote {path}: {verts.shape[0]} vertices, {faces.shape[0]} faces "
          f"({_which(args)}"
          f"{f', pain {pain:g}' if pain is not None else ''}{f', jaw {jaw_deg:g} deg' if jaw_deg else ''})")
    return 0


def write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Write a triangle mesh atomically with trimesh; format from the suffix (.obj, .ply, .glb).

    Parameters
    ----------
    path : pathlib.Path
        Target file.
    vertices : numpy.ndarray
        (V, 3) positions, metres.
    faces : numpy.ndarray
        (F, 3) int vertex indices.
    """
    import trimesh

    from ..fileio import atomic_path

    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, dtype=np.float64), faces=np.asarray(faces),
                           process=False)
    file_type = path.suffix.lower().lstrip(".")
    try:
        with atomic_path(path) as tmp:
            mesh.export(tmp, file_type=file_type)
    except (OSError, ValueError) as exc:
        raise ExportError(f"{path}: could not write the mesh ({exc})") from exc
    return path
