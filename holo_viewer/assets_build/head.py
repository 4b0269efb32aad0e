"""Build the embedded default head (build time: ``scripts/build_default_head.py``).

:func:`build_default_head` converts ICT Face Model Light (ICT-FaceKit, MIT; :mod:`.ict`) into our
FLAME-format head; :func:`write_default_head` writes it as ``assets/default_head.npz`` (compressed,
fixed zip timestamps, so a rebuild gives the same bytes on one machine); :func:`keep_or_write_head` is what
the build scripts call: it keeps a head file already on disk when the rebuild is within :data:`REBUILD_ULPS`
of it (another CPU's BLAS), so the sha256 that fitted avatars are keyed to holds. The run-time loader,
:mod:`holo_viewer.flame.default_head`, only reads the asset (it calls this module only to rebuild a
missing asset when the ICT source is present). Format: see that module's docstring.
"""

from __future__ import annotations

import io
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from ..fileio import atomic_write, file_sha256
from ..flame.default_head import ict_facekit_path
from .ict import DEFAULT_HAIR, IPD, N_IDENTITY, HairStyle, build_from_ict, load_ict

__all__ = ["build_default_head", "build_patient_head", "write_default_head", "stored_ulp_differences",
           "keep_or_write_head", "HeadWrite", "BUILDER_VERSION", "REBUILD_ULPS"]

#: Bumped whenever the generated head changes (stored in the asset).
BUILDER_VERSION = 3  # 3: converted from ICT Face Model Light (issue 17)
#: a rebuild within this many ulps of the stored type (:func:`stored_ulp_differences`; float32 ulps for the
#: float64 ``jaw_open_angle``) of a head file is that head: an AMD EPYC's rebuilds of the shipped heads gave 0-1
#: (jaw_open_angle 1-25 float64 ulps, under 1e-7 float32 ulps); a changed builder or input moves values by many
REBUILD_ULPS = 4
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
    machine; within one ulp of the stored type (of float32 for the float64 scalars, see below) is what a rebuild
    anywhere must give, while a change to the builder or its inputs moves values by many ulps.

    Parameters
    ----------
    arrays : mapping
        Output of :func:`build_default_head` / :func:`build_patient_head`.
    path : path
        A file written by :func:`write_default_head`.

    Returns
    -------
    dict
        ``{key: largest difference in ulps of the stored dtype (float32 ulps for float64 arrays) at the array's
        largest magnitude}``: 0 where
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
            # have tiny ulps of their own, and a last-bit change there says nothing about the head. float64 values
            # count in float32 ulps: they are results of fits (jaw_open_angle), whose float64 rounding noise is
            # the fit's condition number times eps (1-25 float64 ulps between CPUs on the patients' heads), and
            # the renderer uses float32
            scale = max(float(np.abs(a[finite]).max()), float(np.abs(b[finite]).max()))
            unit = np.float32 if a.dtype == np.float64 else a.dtype.type
            ulp = float(np.spacing(unit(scale)))
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


@dataclass(frozen=True)
class HeadWrite:
    """What :func:`keep_or_write_head` did with a head file."""

    path: Path
    kept: bool  #: the file on disk was kept (the rebuild is within the tolerance of it)
    sha256: str  #: the file's sha256 afterwards
    previous_sha256: str | None  #: before (None: there was no readable file)
    ulps: dict[str, float] = field(default_factory=dict)  #: stored_ulp_differences against the previous file

    def far(self, tolerance: float = REBUILD_ULPS) -> dict[str, float]:
        """The keys beyond ``tolerance`` ulps of the previous file."""
        return {k: d for k, d in self.ulps.items() if d > tolerance}

    def report(self, avatar: str | os.PathLike | None = None, refit: str = "") -> tuple[str, bool]:
        """(one line for the build log, loud): loud when the head changed under an avatar fitted to the old
        bytes (``avatar``: its fitted-avatar ``.npz``; ``refit``: the command that refits it)."""
        short = self.sha256[:12]
        if self.kept:
            worst = max(self.ulps.items(), key=lambda kv: kv[1], default=("", 0.0))
            how = "equals it" if worst[1] == 0 else f"is within {worst[1]:.2g} ulps of it (largest: {worst[0]})"
            return f"{self.path}: kept the file on disk (sha256 {short}...): the rebuild {how}", False
        if self.previous_sha256 is None:
            return f"{self.path}: wrote a new head (sha256 {short}...)", False
        far = ", ".join(f"{k} {d:g}" for k, d in self.far().items()) or "unreadable"
        line = (f"{self.path}: the rebuild differs from the file on disk beyond {REBUILD_ULPS} ulps ({far}); wrote it: "
                f"sha256 {self.previous_sha256[:12]}... -> {short}...")
        keyed = _avatar_head_sha256(avatar) if avatar is not None else None
        if keyed is not None and keyed != self.sha256:
            return (f"WARNING: {line}. {avatar} was fitted to head {keyed[:12]}... and will not load until it is "
                    f"refitted{': ' + refit if refit else ''}"), True
        return f"WARNING: {line}", True


def _avatar_head_sha256(path: str | os.PathLike) -> str | None:
    """The ``head_sha256`` a fitted avatar file is keyed to, or None (no such file / field)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return str(z["head_sha256"]) if "head_sha256" in z.files else None
    except (OSError, ValueError):
        return None


def keep_or_write_head(path: str | os.PathLike, arrays: Mapping[str, np.ndarray],
                       tolerance: float = REBUILD_ULPS) -> HeadWrite:
    """Write a built head unless the file at ``path`` already is that head to ``tolerance`` ulps.

    A fitted avatar is keyed to its head's sha256, and a rebuild on another CPU (another BLAS, another
    summation order) or with another zlib lands a few last bits or compressed bytes away from the shipped file
    while being the same head. So when every array of ``arrays`` is within ``tolerance`` ulps of the stored
    type of the file (:func:`stored_ulp_differences`: same keys, shapes and dtypes, integers and strings equal)
    the file's bytes are kept and every digest keyed to them still holds; otherwise (or when the file is missing
    or unreadable) the new head is written with :func:`write_default_head`.

    Parameters
    ----------
    path : path
        The head file (``assets/default_head.npz``, ``assets/patients/NAME/head.npz``).
    arrays : mapping
        Output of :func:`build_default_head` / :func:`build_patient_head`.
    tolerance : float
        Ulps of the stored type, at each array's largest magnitude.

    Returns
    -------
    HeadWrite
    """
    target = Path(path)
    previous, ulps = None, {}
    if target.is_file():
        previous = file_sha256(target)
        try:
            ulps = stored_ulp_differences(arrays, target)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):
            ulps = {}  # unreadable: written anew
        if ulps and max(ulps.values()) <= tolerance:
            return HeadWrite(target, True, previous, previous, ulps)
    write_default_head(target, arrays)
    return HeadWrite(target, False, file_sha256(target), previous, ulps)
