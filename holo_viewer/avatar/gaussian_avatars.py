"""Reading GaussianAvatars output: ``point_cloud.ply`` (+ ``binding_0``) and ``flame_param.npz``.

GaussianAvatars (Qian et al. CVPR'24) stores a trained avatar as a 3DGS PLY whose
means, rotations and log-scales are in the local frames of the FLAME triangles named by
the float property ``binding_0``, and a FLAME parameter sequence ``flame_param.npz``
with (docs/design.md) ``shape`` (300,), ``expr`` (T, 100), ``rotation``, ``neck_pose``,
``jaw_pose``, ``translation`` (T, 3), ``eyes_pose`` (T, 6), ``static_offset`` (1, V, 3)
and optionally ``dynamic_offset`` (T, V, 3). Its FLAME mesh has teeth (5143 vertices,
10144 faces): load your FLAME model with ``add_teeth=True``.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import AvatarError, InputError
from ..fileio import read_npz
from ..flame.params import FRAME_KEYS, FlameParams
from .ply import load_ply, read_ply_header
from .rigged import RiggedAvatar

__all__ = ["FlameParams", "load_flame_params", "load_gaussian_avatar"]

_PER_FRAME = FRAME_KEYS


def load_flame_params(path: str | os.PathLike, n_vertices: int | tuple[int, ...] | None = None) -> FlameParams:
    """Read a GaussianAvatars ``flame_param.npz`` and check its shapes.

    Parameters
    ----------
    path : path-like
        The npz file.
    n_vertices : int or tuple of int, optional
        Expected V (any of them) of ``static_offset`` / ``dynamic_offset`` (the model's, with or without teeth).

    Raises
    ------
    AvatarError
        Missing key, wrong shape, inconsistent frame counts, NaN/inf or a wrong vertex count;
        the message names the file and the key.
    """
    path = Path(path)
    data = read_npz(path, AvatarError, "FLAME parameters")
    if "expr" not in data:
        raise AvatarError(f"{path}: missing key 'expr'; expected keys shape, expr, rotation, neck_pose, jaw_pose, "
                          f"translation, eyes_pose (+ static_offset, dynamic_offset), found {sorted(data)}")
    expr = np.asarray(data["expr"])
    if expr.ndim == 1:
        expr = expr[None]
    if expr.ndim != 2:
        raise AvatarError(f"{path}: expr: expected shape (T, n_expr), found {expr.shape}")
    t = expr.shape[0]
    out: dict[str, Any] = {"expr": expr}
    for key, width in _PER_FRAME.items():
        if key == "expr":
            continue
        if key not in data:
            out[key] = np.zeros((t, width), np.float32)
            continue
        a = np.asarray(data[key])
        if a.ndim == 1:
            a = a[None]
        if a.shape != (t, width):
            raise AvatarError(f"{path}: {key}: expected shape ({t}, {width}) like expr's {t} frames, found {a.shape}")
        out[key] = a
    shape = np.asarray(data.get("shape", np.zeros(0, np.float32)))
    if shape.ndim == 2 and shape.shape[0] == 1:
        shape = shape[0]
    if shape.ndim != 1:
        raise AvatarError(f"{path}: shape: expected shape (n_shape,), found {shape.shape}")
    out["shape"] = shape
    for key, lead in (("static_offset", 1), ("dynamic_offset", t)):
        if key not in data:
            continue
        a = np.asarray(data[key])
        if a.ndim == 2:
            a = a[None]
        if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] not in (1, lead):
            raise AvatarError(f"{path}: {key}: expected shape ({lead}, V, 3), found {a.shape}")
        allowed = (n_vertices,) if isinstance(n_vertices, int) else n_vertices
        if allowed is not None and a.shape[1] not in allowed:
            raise AvatarError(f"{path}: {key}: wrong vertex count: expected {n_vertices}, found {a.shape[1]}")
        out[key] = a
    for key, a in out.items():
        a = np.asarray(a)
        if a.dtype.kind not in "fiu":
            raise AvatarError(f"{path}: {key}: expected a numeric array, found dtype {a.dtype}")
        if not np.all(np.isfinite(a)):
            bad = np.flatnonzero(~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)) if a.ndim > 1 else []
            raise AvatarError(f"{path}: {key}: holds NaN/inf (rows {[int(i) for i in bad[:8]]})")
        out[key] = a.astype(np.float32)
    return FlameParams(**out)


def load_gaussian_avatar(ply_path: str | os.PathLike, flame_param_path: str | os.PathLike | None = None,
                         flame_model: Any = None) -> tuple[RiggedAvatar, FlameParams | None]:
    """Load a GaussianAvatars avatar.

    Parameters
    ----------
    ply_path : path-like
        ``point_cloud.ply`` with local Gaussians and ``binding_0``.
    flame_param_path : path-like, optional
        ``flame_param.npz``; default: the file of that name beside the PLY, if present.
    flame_model : FlameModel or path-like, optional
        The FLAME model the avatar was trained on (GaussianAvatars: FLAME 2023 with
        ``add_teeth=True``); a path is loaded with ``FlameModel.load(path, add_teeth=True)``.
        ``None`` is allowed only for PLYs written by holo_viewer for its default head.

    Returns
    -------
    avatar : RiggedAvatar
        With ``identity`` (shape, static_offset) from the parameter file when given.
    params : FlameParams or None
        The parameter sequence.

    Raises
    ------
    PlyError, AvatarError
        Corrupt PLY, no ``binding_0``, bindings outside the model's faces, bad parameter file.
    """
    from ..flame.model import FlameModel

    ply_path = Path(ply_path)
    local = load_ply(ply_path)
    if "binding_0" not in local.extra and "binding" not in local.extra:
        raise AvatarError(f"{ply_path}: expected a GaussianAvatars PLY with property 'binding_0', found "
                          f"extra properties {sorted(local.extra)}")
    if flame_model is None:
        if "holo_viewer_default_head" not in read_ply_header(ply_path).comments:
            raise AvatarError(f"{ply_path}: flame_model: this PLY is bound to a FLAME mesh; pass the FLAME model it "
                              "was trained on, e.g. flame_model='generic_model.pkl' (loaded with add_teeth=True) "
                              "or FlameModel.load(path, add_teeth=True)")
        from ..flame.default_head import load_default_model

        flame_model = load_default_model()
        binding = np.asarray(local.extra.get("binding_0", local.extra.get("binding")))
        if binding.size and int(binding.max()) >= int(flame_model.faces.shape[0]):  # bound to the teeth too
            flame_model = load_default_model(add_teeth=True)  # as default_avatar() is
    elif isinstance(flame_model, (str, os.PathLike)):
        flame_model = FlameModel.load(flame_model, add_teeth=True)
    if flame_param_path is None and (ply_path.parent / "flame_param.npz").exists():
        flame_param_path = ply_path.parent / "flame_param.npz"
    params = None
    identity: dict[str, Any] = {}
    if flame_param_path is not None:
        nv = (int(flame_model.n_vertices), int(getattr(flame_model, "n_base_vertices", flame_model.n_vertices)))
        params = load_flame_params(flame_param_path, n_vertices=nv)
        params = _fit_widths(params, int(flame_model.n_shape), int(flame_model.n_expr), Path(flame_param_path))
        identity = params.identity()
    try:
        avatar = RiggedAvatar(flame_model, local, identity=identity)
    except AvatarError as exc:
        raise AvatarError(f"{ply_path}: {exc}") from None
    return avatar, params


def _fit_widths(params: FlameParams, n_shape: int, n_expr: int, path: Path) -> FlameParams:
    """Drop trailing shape/expression columns the model does not keep, if they are all zero."""
    changes = {}
    for key, width in (("shape", n_shape), ("expr", n_expr)):
        a = getattr(params, key)
        if a.shape[-1] > width:
            if np.any(a[..., width:] != 0):
                raise InputError(f"{path}: {key}: {a.shape[-1]} components with non-zero values beyond the "
                                 f"model's {width}; load the FLAME model with n_{key} >= {a.shape[-1]}")
            changes[key] = np.ascontiguousarray(a[..., :width])
    return replace(params, **changes) if changes else params
