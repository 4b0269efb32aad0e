"""The embedded default head at run time: find and load ``assets/default_head.npz``.

FLAME cannot be redistributed, so holo_viewer ships its own FLAME-format head: a conversion of ICT
Face Model Light (ICT-FaceKit, MIT; ``assets/LICENSE-ICT-FaceKit.txt``) made by build-time code in
:mod:`holo_viewer.assets_build.head` and committed as ``assets/default_head.npz``;
``scripts/build_default_head.py`` regenerates it from ``ict_facekit_light.npz`` (see
:func:`ict_facekit_path`) and the tests check that a rebuild reproduces it. If the asset is missing
(e.g. a stripped checkout), :func:`load_default_model` rebuilds it when the ICT source is present and
writes it there (or, if that folder is read-only, to :func:`holo_viewer.cache.cache_dir`); without
the source it raises a :class:`FlameError` saying so.

Format: FLAME's keys ``v_template`` (V, 3), ``shapedirs`` (V, 3, n_shape + n_expr),
``posedirs`` (V, 3, 36), ``J_regressor`` (5, V), ``weights`` (V, 5),
``kintree_table`` (2, 5), ``f`` (F, 3), plus ``n_shape``, ``n_expr``,
``expression_names``, ``shape_names``, ``holo_viewer_default_head``, ``has_teeth`` (the mesh has
its own teeth: ``add_teeth`` adds none), ``vertex_region`` + ``region_names``, ``uv`` (U, 2) +
``faces_uv`` (F, 3) (UDIM-style texture coordinates per triangle corner), ``landmark_vertices``
(68 dlib landmarks), ``jaw_open_angle`` and ``builder_version``. Units and conventions:
docs/default_head.md.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..cache import keep_recent
from ..errors import FlameError

__all__ = ["default_head_path", "load_default_model", "ict_facekit_path", "ASSET_NAME", "EXPRESSION_NAMES",
           "ICT_ENV", "ICT_NAME"]

ASSET_NAME = "default_head.npz"
#: The default head's expression components, in the asset's order (coefficient 1 = full action-unit
#: intensity); the builder generates them in this order and ``flame.expressions`` maps AUs onto them.
EXPRESSION_NAMES: tuple[str, ...] = (
    "AU1_L", "AU1_R", "AU2_L", "AU2_R", "AU4", "AU5", "AU6", "AU7", "AU9", "AU10", "AU12_L", "AU12_R", "AU14",
    "AU15", "AU16", "AU17", "AU18", "AU20", "AU23", "AU24", "AU25", "AU26", "AU43_L", "AU43_R")

#: Environment variable naming the ICT-FaceKit source npz, and its file name.
ICT_ENV = "HOLO_VIEWER_ICT_FACEKIT"
ICT_NAME = "ict_facekit_light.npz"


def _repo_asset() -> Path:
    return Path(__file__).resolve().parents[2] / "assets" / ASSET_NAME


def ict_facekit_path(required: bool = False) -> Path | None:
    """The ICT-FaceKit source the head is built from: ``$HOLO_VIEWER_ICT_FACEKIT``, else the copy
    shipped in the checkout, ``assets/ICT-FaceKit/ict_facekit_light.npz`` (licence, source commit and
    checksum beside it).

    Parameters
    ----------
    required : bool
        Raise :class:`FlameError` (saying where it was looked for) instead of returning None.
    """
    env = os.environ.get(ICT_ENV)
    candidates = [Path(env)] if env else []
    candidates.append(_repo_asset().parent / "ICT-FaceKit" / ICT_NAME)
    for c in candidates:
        if c.is_file():
            return c
    if required:
        raise FlameError(f"ICT-FaceKit source not found (looked for {', '.join(str(c) for c in candidates)}); "
                         f"it is needed to build the default head. Point ${ICT_ENV} at {ICT_NAME} "
                         f"(ICT Face Model Light, see docs/default_head.md) or restore assets/{ASSET_NAME}")
    return None


def _missing_source_message() -> str:
    try:
        ict_facekit_path(required=True)
    except FlameError as exc:
        return str(exc)
    return ""


def default_head_path(build_if_missing: bool = True) -> Path:
    """Path of the default head asset (``assets/default_head.npz`` of the checkout).

    Parameters
    ----------
    build_if_missing : bool
        Build and write the asset when it does not exist (to ``assets/`` or, if that
        cannot be written, to :func:`holo_viewer.cache.cache_dir`: ``$HOLO_VIEWER_CACHE``, else
        ``$XDG_CACHE_HOME/holo_viewer``, else ``~/.cache/holo_viewer``).

    Returns
    -------
    pathlib.Path
    """
    asset = _repo_asset()
    if asset.exists() or not build_if_missing:
        return asset
    from ..cache import cache_dir

    cache = cache_dir() / ASSET_NAME
    if cache.exists():
        return cache
    if ict_facekit_path() is None:
        raise FlameError(f"default head: {asset} is missing and cannot be rebuilt: "
                         + str(_missing_source_message()))
    from ..assets_build.head import build_default_head, write_default_head  # rebuild a missing asset (build time)

    arrays = build_default_head()
    for target in (asset, cache):
        try:
            return write_default_head(target, arrays)
        except OSError:
            continue
    raise FlameError(f"default head: cannot write {asset} nor {cache}")


def load_default_model(n_shape: int | None = None, n_expr: int | None = None, add_teeth: bool = False,
                       dtype: Any = None, device: Any = "cpu"):
    """Load the default head as a :class:`~holo_viewer.flame.model.FlameModel`.

    Parameters
    ----------
    n_shape, n_expr : int, optional
        Components to keep (None = all in the file: 20 identity, 24 expression).
    add_teeth : bool
        Ignored: the default head has its own teeth (kept for callers that pass it for any model).
    dtype : torch.dtype, optional
        Default torch.float32.
    device : str or torch.device

    Returns
    -------
    FlameModel
        A new model each call (a deep copy of the one this process read the file into: the file is read
        again when it changed).
    """
    import copy

    import torch

    from .model import FlameModel

    path = default_head_path()
    dtype = torch.float32 if dtype is None else dtype
    st = path.stat()
    # this process's loaded models (reading and checking the file: ~0.1 s of CPU a call; a deep copy of the
    # model: ~3 ms), keyed by the arguments and the file's identity, so a changed file is read again
    key = (str(path), st.st_ino, st.st_size, st.st_mtime_ns, n_shape, n_expr, bool(add_teeth), dtype, str(device))
    model = _LOADED.get(key)
    if model is None:
        model = FlameModel.load(path, n_shape=n_shape, n_expr=n_expr, add_teeth=add_teeth, dtype=dtype,
                                device=device)
        keep_recent(_LOADED, key, model, _LOADED_KEPT)
    return copy.deepcopy(model)  # each caller its own model: the kept one is never handed out


#: load_default_model's models of this process (the last few), never handed out: callers get deep copies
_LOADED: dict = {}
_LOADED_KEPT = 4
