"""Build the embedded default head (build time: ``scripts/build_default_head.py``).

:func:`build_default_head` converts ICT Face Model Light (ICT-FaceKit, MIT; :mod:`.ict`) into our
FLAME-format head; :func:`write_default_head` writes it as ``assets/default_head.npz`` (compressed,
fixed zip timestamps, so a rebuild gives the same bytes). The run-time loader,
:mod:`holo_viewer.flame.default_head`, only reads the asset (it calls this module only to rebuild a
missing asset when the ICT source is present). Format: see that module's docstring.
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path
from typing import Mapping

import numpy as np

from ..fileio import atomic_write
from ..flame.default_head import ict_facekit_path
from .ict import DEFAULT_HAIR, IPD, N_IDENTITY, HairStyle, build_from_ict, load_ict

__all__ = ["build_default_head", "build_patient_head", "write_default_head", "stored_ulp_differences",
           "BUILDER_VERSION"]

#: Bumped whenever the generated head changes (stored in the asset).
BUILDER_VERSION = 3  # 3: converted from ICT Face Model Light (issue 17)
_FLOAT32_KEYS = ("v_template", "J_regressor", "weights", "uv")
_FLOAT16_KEYS = ("shapedirs", "posedirs")  # deltas of at most a few cm: float16 keeps them to < 0.01 mm
_INT32_KEYS = ("f", "vertex_region", "faces_uv", "landmark_vertices")


def build_default_head(ict_path: str | os.PathLike | None = None, n_identity: int = N_IDENTITY
                       ) -> dict[str, np.ndarray]:
    """Convert ICT Face Model Light into the default head (deterministic).

    Parameters
    ----------
    ict_path : path, optional
        ``ict_facekit_light.npz``; default :func:`holo_viewer.flame.default_head.ict_facekit_path`
        (``$HOLO_VIEWER_ICT_FACEKIT``, else the copy in ``assets/ICT-FaceKit/``).
    n_identity : int
        Identity (shape) components kept.

    Returns
    -------
    dict of str -> numpy.ndarray
        FLAME keys in float64 / int64 plus the extra keys listed in ``default_head``'s docstring.
    """
    path = ict_facekit_path(required=True) if ict_path is None else Path(ict_path)
    arrays = build_from_ict(load_ict(path), n_identity=int(n_identity))
    arrays["builder_version"] = np.array(BUILDER_VERSION, dtype=np.int64)
    return arrays


def build_patient_head(identity: np.ndarray, ipd: float = IPD, hair: HairStyle = DEFAULT_HAIR,
                       ict_path: str | os.PathLike | None = None, n_identity: int = N_IDENTITY,
                       ict: dict | None = None) -> dict[str, np.ndarray]:
    """A patient's head (docs/patients.md): ICT's neutral plus ``identity`` (coefficients of ICT's
    identity modes), scaled to ``ipd`` metres between the eyeball centres, with the ``hair`` shell.
    The identity modes stay in the head as its shape components (around the patient). ``ict``: the
    arrays of :func:`~.ict.load_ict`, to convert several patients from one read."""
    if ict is None:
        path = ict_facekit_path(required=True) if ict_path is None else Path(ict_path)
        ict = load_ict(path)
    arrays = build_from_ict(ict, n_identity=int(n_identity), identity=identity, ipd=ipd, hair=hair)
    arrays["builder_version"] = np.array(BUILDER_VERSION, dtype=np.int64)
    return arrays


def _storage_arrays(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = {}
    for k in sorted(arrays):
        a = np.asarray(arrays[k])
        if k in _FLOAT32_KEYS:
            a = a.astype(np.float32)
        elif k in _FLOAT16_KEYS:
            a = a.astype(np.float16)
        elif np.issubdtype(a.dtype, np.floating):
            a = a.astype(np.float64)
        elif np.issubdtype(a.dtype, np.integer):
            a = a.astype(np.int32 if k in _INT32_KEYS else np.int64)
        out[k] = np.array(a, order="C", copy=True)  # keeps 0-d scalars 0-d
    return out


def stored_ulp_differences(arrays: Mapping[str, np.ndarray], path: str | os.PathLike) -> dict[str, float]:
    """How far a rebuilt head is from a written one, in units in the last place of each stored array.

    The build is float64 arithmetic through numpy and its BLAS, whose kernels differ by CPU (an Intel and an
    AMD machine give sums in another order), so a rebuild on another machine can land one float64 ulp away and
    round to the neighbouring float32 or float16 when stored. Equal bytes are therefore a property of one
    machine; within one ulp of the stored type is what a rebuild anywhere must give, while a change to the
    builder or its inputs moves values by many ulps.

    Parameters
    ----------
    arrays : mapping
        Output of :func:`build_default_head` / :func:`build_patient_head`.
    path : path
        A file written by :func:`write_default_head`.

    Returns
    -------
    dict
        ``{key: largest difference in ulps of the stored dtype at the array's largest magnitude}``: 0 where
        bit-equal; ``inf`` where the key is missing on either side, the shapes or dtypes differ, or integer
        arrays differ.
    """
    stored = _storage_arrays(arrays)
    with np.load(path, allow_pickle=False) as z:
        written = {k: z[k] for k in z.files}
    out: dict[str, float] = {}
    for k in sorted(set(stored) | set(written)):
        a, b = stored.get(k), written.get(k)
        if a is None or b is None or a.shape != b.shape or a.dtype != b.dtype:
            out[k] = float("inf")
        elif a.dtype.kind != "f":
            out[k] = 0.0 if np.array_equal(a, b) else float("inf")
        elif not np.array_equal(np.isfinite(a), np.isfinite(b)):
            out[k] = float("inf")
        else:
            finite = np.isfinite(a)
            if not finite.any():
                out[k] = 0.0
                continue
            # one ulp at the array's largest magnitude: near-zero entries (a 1e-12 that is 0 in exact arithmetic)
            # have tiny ulps of their own, and a last-bit change there says nothing about the head
            scale = max(float(np.abs(a[finite]).max()), float(np.abs(b[finite]).max()))
            ulp = float(np.spacing(a.dtype.type(scale)))
            diff = np.abs(a[finite].astype(np.float64) - b[finite].astype(np.float64))
            out[k] = float(diff.max() / ulp) if ulp > 0 else (0.0 if diff.max() == 0 else float("inf"))
    return out


def write_default_head(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write head arrays as a compressed ``.npz`` with fixed zip metadata (same bytes every time).

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
