"""Build the embedded default head (build time: ``scripts/build_default_head.py``).

:func:`build_default_head` generates our own FLAME-format head by deterministic code (geometry
in :mod:`.head_sculpt`, skinning in :mod:`.head_rig`, blend shapes in :mod:`.head_blendshapes`);
:func:`write_default_head` writes it as ``assets/default_head.npz`` (compressed float32, fixed
zip timestamps, so a rebuild gives the same bytes). The run-time loader,
:mod:`holo_viewer.flame.default_head`, only reads the asset (it calls this module only to
rebuild a missing asset in a stripped checkout). Format: see that module's docstring.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path
from typing import Mapping

import numpy as np

from ...errors import InputError
from ...fileio import atomic_write
from ..default_head import EXPRESSION_NAMES
from .head_blendshapes import N_GENERIC_SHAPE, SHAPE_NAMES, expression_basis, shape_basis
from .head_rig import KINTREE, jaw_corrective_posedirs, joint_regressor, skin_weights
from .head_sculpt import REGION_NAMES, sculpt_head

__all__ = ["build_default_head", "write_default_head", "BUILDER_VERSION"]

#: Bumped whenever the generated head changes (stored in the asset).
BUILDER_VERSION = 2  # 2: jaw / mouth masks no longer catch the lower-lid rims (issue 2)
_FLOAT_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights")


def _grid_size(n_vertices_target: int) -> tuple[int, int]:
    if not isinstance(n_vertices_target, (int, np.integer)) or not 1500 <= n_vertices_target <= 40000:
        raise InputError(f"n_vertices_target: expected an int in [1500, 40000], found {n_vertices_target!r}")
    # ~1000 vertices live outside the grid (eyes, ears, mouth bag) at the default size
    s = np.sqrt(max(n_vertices_target - 856, 500) / (56 * 74))
    return max(int(round(56 * s)), 30), max(int(round(74 * s)), 40)


def build_default_head(n_vertices_target: int = 5000, seed: int = 0) -> dict[str, np.ndarray]:
    """Generate the default head in FLAME's format (deterministic for given arguments).

    Parameters
    ----------
    n_vertices_target : int
        Approximate vertex count (the default gives 5006 vertices).
    seed : int
        Seed of the generic (unnamed) shape components.

    Returns
    -------
    dict of str -> numpy.ndarray
        FLAME keys in float64 / int64 plus the extra keys listed in the module docstring.
    """
    n_rows, n_cols = _grid_size(n_vertices_target)
    head = sculpt_head(n_rows, n_cols)
    weights = skin_weights(head)
    j_reg = joint_regressor(head)
    posedirs = jaw_corrective_posedirs(head, weights)
    shape = shape_basis(head, seed=int(seed))
    expr = expression_basis(head, weights[:, 2])
    return {
        "v_template": head.vertices.astype(np.float64),
        "shapedirs": np.concatenate([shape, expr], axis=2),
        "posedirs": posedirs,
        "J_regressor": j_reg,
        "weights": weights,
        "kintree_table": KINTREE.copy(),
        "f": head.faces.astype(np.int64),
        "n_shape": np.array(shape.shape[2], dtype=np.int64),
        "n_expr": np.array(expr.shape[2], dtype=np.int64),
        "expression_names": np.array(EXPRESSION_NAMES),
        "shape_names": np.array(list(SHAPE_NAMES) + [f"generic_{i}" for i in range(N_GENERIC_SHAPE)]),
        "holo_viewer_default_head": np.array(1, dtype=np.int64),
        "vertex_region": head.region.astype(np.int64),
        "region_names": np.array(REGION_NAMES),
        "teeth_anchor_upper": head.parts["teeth_anchor_upper"].astype(np.int64),
        "teeth_anchor_lower": head.parts["teeth_anchor_lower"].astype(np.int64),
        "builder_version": np.array(BUILDER_VERSION, dtype=np.int64),
        "seed": np.array(int(seed), dtype=np.int64),
    }


def _storage_arrays(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = {}
    for k in sorted(arrays):
        a = np.asarray(arrays[k])
        if k in _FLOAT_KEYS:
            a = a.astype(np.float32)
        elif np.issubdtype(a.dtype, np.integer):
            a = a.astype(np.int32 if k in ("f", "vertex_region", "teeth_anchor_upper", "teeth_anchor_lower")
                         else np.int64)
        out[k] = np.array(a, order="C", copy=True)  # keeps 0-d scalars 0-d
    return out


def write_default_head(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write head arrays as a compressed float32 ``.npz`` with fixed zip metadata (same bytes every time).

    Parameters
    ----------
    path : path
        Target file, written atomically.
    arrays : mapping
        Output of :func:`build_default_head`.

    Returns
    -------
    pathlib.Path
    """
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, a in _storage_arrays(arrays).items():
            member = io.BytesIO()
            np.lib.format.write_array(member, a, allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue(), compresslevel=9)
    target = Path(path)
    with atomic_write(target) as fh:
        fh.write(buf.getvalue())
    return target
