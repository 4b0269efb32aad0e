"""Reader for data in the REACT 2023/2024 challenge layout (for users who have the restricted data).

Layout (as used by the official baselines' ``dataset.py``)::

    ROOT/{split}.csv                          header row, then rows "index,speaker_path,listener_path"
    ROOT/{split}/Emotion/<path>.csv           header row, then T rows of the 25 attributes
    ROOT/{split}/3D_FV_files/<path>.npy       (T, 58) or (T, 1, 58) FaceVerse coefficients
    ROOT/{split}/Audio_files/<path>.wav       speaker audio
    ROOT/neighbour_emotion_{split}.npy        (N, N) 0/1 appropriateness matrix

For val/test the official loader appends the mirrored pairs (listener as speaker), so N is
twice the number of rows; ``mirrored`` does the same. Attribute columns follow
:data:`~holo_viewer.reaction.features.REACT_AU_NAMES`, valence, arousal, then
:data:`~holo_viewer.reaction.features.EXPRESSION_CLASSES`.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ReactionError
from ..fileio import read_npy
from .features import ATTRIBUTE_DIM

__all__ = ["ReactSplitData", "read_attribute_csv", "read_pairs", "load_react_split"]


@dataclass(frozen=True)
class ReactSplitData:
    """One split read from REACT-format files.

    Attributes
    ----------
    split : str
    pairs : tuple of (speaker_path, listener_path), length N
    speaker_attr, listener_attr : numpy.ndarray, shape (N, T, 25) float32
    listener_3dmm : numpy.ndarray, shape (N, T, 58) float32, or None when not loaded
    speaker_audio : tuple of pathlib.Path, length N
    neighbour : numpy.ndarray, shape (N, N) int8, or None when the file is absent
    """

    split: str
    pairs: tuple[tuple[str, str], ...]
    speaker_attr: np.ndarray
    listener_attr: np.ndarray
    listener_3dmm: np.ndarray | None
    speaker_audio: tuple[Path, ...]
    neighbour: np.ndarray | None


def read_attribute_csv(path: str | os.PathLike) -> np.ndarray:
    """One clip's 25-D attributes (T, 25) float32 from a REACT emotion CSV (first row is a header)."""
    p = Path(path)
    if not p.is_file():
        raise ReactionError(f"{p}: attribute CSV not found")
    with open(p, newline="") as fh:
        rows = list(csv.reader(fh))
    if len(rows) < 2:
        raise ReactionError(f"{p}: expected a header row and at least one frame, found {len(rows)} rows")
    try:
        data = np.array([[float(v) for v in r] for r in rows[1:] if r], dtype=np.float64)
    except ValueError as exc:
        raise ReactionError(f"{p}: non-numeric value after the header row ({exc})") from exc
    if data.ndim != 2 or data.shape[1] != ATTRIBUTE_DIM:
        raise ReactionError(f"{p}: expected {ATTRIBUTE_DIM} columns per row, found shape {data.shape}")
    if not np.all(np.isfinite(data)):
        raise ReactionError(f"{p}: holds {int((~np.isfinite(data)).sum())} NaN/inf values")
    return data.astype(np.float32)


def read_pairs(root: str | os.PathLike, split: str) -> list[tuple[str, str]]:
    """(speaker_path, listener_path) rows of ``ROOT/{split}.csv`` (header row skipped)."""
    p = Path(root) / f"{split}.csv"
    if not p.is_file():
        raise ReactionError(f"{p}: split list not found (expected the REACT layout under {root})")
    with open(p, newline="") as fh:
        rows = [r for r in csv.reader(fh) if r]
    if len(rows) < 2:
        raise ReactionError(f"{p}: expected a header row and at least one pair, found {len(rows)} rows")
    out = []
    for i, r in enumerate(rows[1:], start=2):
        if len(r) < 3:
            raise ReactionError(f"{p}: line {i}: expected 'index,speaker_path,listener_path', found {r}")
        out.append((r[1].strip(), r[2].strip()))
    return out


def _load_3dmm(path: Path, frames: int) -> np.ndarray:
    if not path.is_file():
        raise ReactionError(f"{path}: 3DMM file not found")
    x = read_npy(path, ReactionError, "3DMM coefficients")
    x = np.asarray(x, dtype=np.float32).reshape(x.shape[0], -1)
    if x.shape[0] < frames:
        raise ReactionError(f"{path}: expected at least {frames} frames, found {x.shape[0]}")
    return x[:frames]


def load_react_split(root: str | os.PathLike, split: str, frames: int = 750, mirrored: bool | None = None,
                     load_3dmm: bool = True) -> ReactSplitData:
    """Read a REACT-format split.

    Parameters
    ----------
    root : path of the dataset root
    split : "train", "val" or "test"
    frames : int
        Frames kept per clip (the official evaluation uses the first 750); shorter clips raise.
    mirrored : bool, optional
        Append the mirrored pairs (default: True for val/test, as the official loader).
    load_3dmm : bool
        Read the listener 3DMM coefficients.

    Raises
    ------
    ReactionError
        Missing files, malformed CSVs, short clips, or a neighbour matrix of the wrong size.
    """
    root = Path(root)
    pairs = read_pairs(root, split)
    if mirrored is None:
        mirrored = split in ("val", "test")
    if mirrored:
        pairs = pairs + [(lp, sp) for sp, lp in pairs]
    base = root / split
    cache: dict[str, np.ndarray] = {}

    def attr(rel: str) -> np.ndarray:
        if rel not in cache:
            a = read_attribute_csv(base / "Emotion" / f"{rel}.csv")
            if a.shape[0] < frames:
                raise ReactionError(f"{base / 'Emotion' / (rel + '.csv')}: expected at least {frames} frames, "
                                    f"found {a.shape[0]}")
            cache[rel] = a[:frames]
        return cache[rel]

    sp_attr = np.stack([attr(s) for s, _ in pairs])
    l_attr = np.stack([attr(lp) for _, lp in pairs])
    l3 = np.stack([_load_3dmm(base / "3D_FV_files" / f"{lp}.npy", frames) for _, lp in pairs]) if load_3dmm else None
    audio = tuple(base / "Audio_files" / f"{s}.wav" for s, _ in pairs)
    nb_path = root / f"neighbour_emotion_{split}.npy"
    nb = None
    if nb_path.is_file():
        nb = read_npy(nb_path, ReactionError, "neighbour matrix")
        if nb.shape != (len(pairs), len(pairs)):
            raise ReactionError(f"{nb_path}: expected shape ({len(pairs)}, {len(pairs)}) for {len(pairs)} clips"
                                f"{' (mirrored)' if mirrored else ''}, found {nb.shape}")
        nb = (np.asarray(nb) > 0).astype(np.int8)
    return ReactSplitData(split, tuple(pairs), sp_attr, l_attr, l3, audio, nb)
