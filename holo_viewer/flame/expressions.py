"""Facial action units (AUs), pain and named expressions for FLAME-format models.

Pure numpy apart from :meth:`AUMap.load_json` / :meth:`AUMap.to_json`.

AU intensities use the FACS-like 0..5 scale (A = 1 ... E = 5); AU43 (eyes closed)
uses 0..1 as in PSPI. An :class:`AUMap` turns intensities into expression
coefficients of one model, linearly: ``expr = intensities @ matrix`` with
``matrix`` of shape (n_au, n_expr).

AU map JSON format
------------------
::

    {
      "n_expr": 100,                      # expression coefficients of the model
      "aus": {                            # AU name -> coefficients for intensity 1
        "AU4":  [0.0, 0.12, ..., 0.0],    # exactly n_expr finite numbers
        "AU12": [...],
        ...
      }
    }

AU names must come from :data:`AU_NAMES`; AUs left out cannot be expressed.
Coefficients are per unit intensity on the 0..5 scale (per unit for AU43), so
intensity 5 of "AU12" adds ``5 * aus["AU12"]`` to the expression vector. Pass
such a file as ``--au-map FILE`` on the command line, or ``au_map_path=`` to
:func:`au_map_for`. The default head needs none: its expression basis is named
(``AU12_L`` ...), coefficient 1.0 = full intensity 5.

Pain
----
PSPI = AU4 + max(AU6, AU7) + max(AU9, AU10) + AU43 (0..16) [Prkachin & Solomon].
:func:`pain_aus` maps pain p in [0, 1] to a canonical pain face dominated by the
PSPI action units (brow lowering, orbital tightening, levator contraction, eye
closure) with lighter AU20/AU25/AU26; PSPI(p = 1) = 14.05, PSPI(0) = 0, strictly
increasing in p. Each AU grows as ``peak x p^e`` (:data:`PAIN_EXPONENT`): the brows lead
(e = 0.8), orbital tightening and the nose wrinkle follow (1.2, 1.5; AU9 1.2), the upper-lip raise
comes last (AU10 2.0: no bared teeth at low levels, the lip follows the other action units), so that the
landmark detector's eye aperture, brow-to-eye and nose-to-lip gaps fall monotonically from
pain 0.2 to 1.0 (docs/behaviour.md). The eyes narrow to a slit (orbital tightening AU6/AU7 at full
intensity, the most reliable pain sign: the lower lids rise) rather than shutting: full closure reads as
sleep, an independent landmark detector reads a squeezed slit as narrower than closed lids, and a
lowered upper lid (AU43) widens the brow-to-lid gap that the brow lowerer narrows, so that with AU43 at
0.3 p^3 the gap turned back up between pain 0.8 and 1 on every head (docs/face_realism.md).

Identity normalisation (issue 35)
---------------------------------
ICT's expression deltas are shared by every identity, so the same lid displacement closes a large eye
by a smaller *fraction* than a small one. :func:`identity_pain_gains` measures, on a head's own 68
landmark vertices (float64, the neutral head and the canonical pain face at p = 1, no renderer and no
detector), the two fractions PSPI's orbital tightening and brow lowering are about: eye aperture and
brow-to-upper-lid gap at pain 1 over neutral (:func:`landmark_pain_fractions`). It then finds gains on
the AU groups of :data:`PAIN_GAIN_GROUPS` (AU6/AU7/AU43 for the eyes, AU4 for the brows) that bring
both fractions to the reference head's (:data:`PAIN_REFERENCE_FRACTIONS`, the default head with the
shared deltas). Gains only lift: a head whose geometry already closes or descends by more than the
reference keeps gain 1 (the shared deltas), and no gain exceeds :data:`PAIN_GAIN_MAX`.
``au_map_for(model, normalise_pain=True)`` attaches the gains to a head's :class:`AUMap`
(``pain_gains``), which :func:`pain_expression` and the listener's behaviour layers apply; the AU
intensities (:func:`pain_aus`, PSPI) are unchanged. Off by default (:data:`PAIN_NORMALISE_IDENTITY`):
on amara, the widest eye, the detector of ``bench/face_realism.py`` reads the eye squeezed to the
reference's fraction as more open than the shared face's (docs/face_realism.md).

The default head's own brows (issue 35)
---------------------------------------
The default head alone (the shipped ``assets/default_head.npz`` or a copy of its bytes at any path, not the
patients built in its format)
lowers its brows further than the shared face: :data:`DEFAULT_HEAD_PAIN_GAINS` (AU4 x 1.186, within
:data:`PAIN_GAIN_MAX`) brings its brow-to-upper-lid gap at pain 1 to :data:`DEFAULT_HEAD_BROW_FRACTION`
of neutral on its landmark vertices (0.787 with the shared face; 0.755 is the strongest descent of the
shared face on the ward's heads, kwame's). Why: the landmark detector reads every head's squeezed slit as
shorter than it is (inter-ocular distance -9 % at pain 1 against -2.3 % on the vertices), which inflates
the brow gap it reports by ~7 %, and the default's front views sat at the 0.85 line (docs/face_realism.md).
:func:`au_map_for` attaches these gains to the default head's map; the identity normalisation's reference
(:data:`PAIN_REFERENCE_FRACTIONS`) stays the default head with the shared deltas.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import FlameError, InputError
from ..fileio import atomic_write
from .params import EXPR_LIMIT

__all__ = ["AU_NAMES", "AU_MAX", "REACT_AUS", "AUMap", "default_au_map", "au_map_for", "expression_from_aus",
           "pain_aus", "pain_expression", "estimate_aus", "pspi", "pspi_from_aus", "named_expression",
           "jaw_for_expression", "EXPRESSION_NAMES_KNOWN", "NAMED_EXPRESSIONS", "PAIN_PEAK", "PAIN_EXPONENT",
           "PAIN_RANGE", "PAIN_GAIN_GROUPS", "PAIN_REFERENCE_FRACTIONS", "PAIN_GAIN_MAX", "PAIN_NORMALISE_IDENTITY",
           "DEFAULT_HEAD_BROW_FRACTION", "DEFAULT_HEAD_PAIN_GAINS", "landmark_pain_measures",
           "landmark_pain_fractions", "identity_pain_gains"]

AU_NAMES: tuple[str, ...] = ("AU1", "AU2", "AU4", "AU5", "AU6", "AU7", "AU9", "AU10", "AU12", "AU14", "AU15",
                             "AU16", "AU17", "AU18", "AU20", "AU23", "AU24", "AU25", "AU26", "AU43")
#: The 15 AUs of the REACT challenge features (all expressible on the default head).
REACT_AUS = ("AU1", "AU2", "AU4", "AU6", "AU7", "AU9", "AU10", "AU12", "AU14", "AU15", "AU17", "AU23",
             "AU24", "AU25", "AU26")
#: Maximum intensity per AU (5 on the FACS-like scale; AU43 is 0..1).
AU_MAX = {name: (1.0 if name == "AU43" else 5.0) for name in AU_NAMES}

#: Default-head expression components driven by each AU (coefficient 1 = intensity 5; AU43: 1 = 1).
_DEFAULT_COMPONENTS = {
    "AU1": ("AU1_L", "AU1_R"), "AU2": ("AU2_L", "AU2_R"), "AU4": ("AU4",), "AU5": ("AU5",), "AU6": ("AU6",),
    "AU7": ("AU7",), "AU9": ("AU9",), "AU10": ("AU10",), "AU12": ("AU12_L", "AU12_R"), "AU14": ("AU14",),
    "AU15": ("AU15",), "AU16": ("AU16",), "AU17": ("AU17",), "AU18": ("AU18",), "AU20": ("AU20",),
    "AU23": ("AU23",), "AU24": ("AU24",), "AU25": ("AU25",), "AU26": ("AU26",), "AU43": ("AU43_L", "AU43_R"),
}

#: Canonical pain face at p = 1 (PSPI = 5 + 5 + 4 + 0.05 = 14.05). The eyes narrow by orbital
#: tightening (AU6 + AU7 at full intensity: the lower lids and cheeks rise), not by lowering the upper
#: lids (AU43 only a trace): a lowered upper lid widens the brow-to-lid gap that AU4 narrows.
PAIN_PEAK = {"AU4": 5.0, "AU6": 5.0, "AU7": 5.0, "AU9": 3.0, "AU10": 4.0, "AU43": 0.05,
             "AU20": 1.0, "AU25": 1.5, "AU26": 1.0}
#: pain_aus(p)[au] = PAIN_PEAK[au] * p ** PAIN_EXPONENT[au] (brows lead, the upper lip follows);
#: every curve rises monotonically and saturates at p = 1
PAIN_EXPONENT = {"AU4": 0.8, "AU6": 1.2, "AU7": 1.5, "AU9": 1.2, "AU10": 2.0, "AU43": 2.0,
                 "AU20": 1.5, "AU25": 2.0, "AU26": 2.0}
_PSPI_CORE = ("AU4", "AU43")

#: The named expressions, declared once: name -> (AU intensities at intensity 1, jaw opening in
#: radians at intensity 1). "pain" is the canonical pain face of :func:`pain_aus` (None here) and
#: opens no jaw beyond its AU25/AU26: pain has one meaning, ``pain_expression(p)``, whether it is
#: asked for as ``FaceControls(pain=p)``, as the named expression "pain", or by ``--pain``.
NAMED_EXPRESSIONS: dict[str, tuple[dict[str, float] | None, float]] = {
    "neutral": ({}, 0.0),
    "smile": ({"AU6": 2.5, "AU12": 4.0, "AU25": 1.0}, 0.03),
    "pain": (None, 0.0),
    "surprise": ({"AU1": 4.0, "AU2": 4.0, "AU5": 3.0, "AU25": 2.5, "AU26": 2.0}, 0.14),
    "frown": ({"AU4": 4.0, "AU15": 3.0, "AU17": 2.5}, 0.0),
    "mouth_open": ({"AU25": 3.0, "AU26": 1.5}, 0.30),
}
#: names of :data:`NAMED_EXPRESSIONS`
EXPRESSION_NAMES_KNOWN: tuple[str, ...] = tuple(NAMED_EXPRESSIONS)
#: pain intensities are in [PAIN_RANGE[0], PAIN_RANGE[1]]; named-expression intensities too
PAIN_RANGE = (0.0, 1.0)

#: identity normalisation of pain (module docstring): measure -> the AUs whose gain sets it
PAIN_GAIN_GROUPS: dict[str, tuple[str, ...]] = {"eye_aperture": ("AU6", "AU7", "AU43"), "brow_eye_gap": ("AU4",)}
#: pain 1 / neutral of the two measures on the reference head (the default head, shared deltas, its 68
#: landmark vertices; tests/test_pain_identity.py recomputes them from assets/default_head.npz)
PAIN_REFERENCE_FRACTIONS: dict[str, float] = {"eye_aperture": 0.2938124758067685, "brow_eye_gap": 0.7869665808599443}
#: no AU group's pain gain exceeds this (beyond it ICT's deltas extrapolate far past their data)
PAIN_GAIN_MAX = 1.5
#: :func:`au_map_for` attaches the gains only when asked (``normalise_pain=True``): measured on amara
#: (docs/face_realism.md, "Identity normalisation of pain"), the landmark detector reads her eyes squeezed
#: to the reference's fraction as *more* open (33 of 40 rows against 38 with the shared face)
PAIN_NORMALISE_IDENTITY = False
#: the default head's brow-to-upper-lid gap at pain 1 / neutral on its landmark vertices with its own gains
#: (module docstring, "The default head's own brows"); the ward's strongest with the shared face: kwame 0.755
DEFAULT_HEAD_BROW_FRACTION = 0.755
#: the default head's own pain gains: ``identity_pain_gains(default head, reference={"eye_aperture":
#: PAIN_REFERENCE_FRACTIONS["eye_aperture"], "brow_eye_gap": DEFAULT_HEAD_BROW_FRACTION})`` (brows only: the
#: stronger brow lowerer narrows the eye a little, so the eyes keep gain 1); tests/test_pain_identity.py
#: recomputes it from assets/default_head.npz
DEFAULT_HEAD_PAIN_GAINS: Mapping[str, float] = MappingProxyType({"AU4": 1.1858465061355663})


@dataclass(frozen=True)
class AUMap:
    """Linear map from AU intensities to a model's expression coefficients.

    Attributes
    ----------
    names : tuple of str
        AU names (a subset of :data:`AU_NAMES`, in that order).
    matrix : numpy.ndarray
        (n_au, n_expr) float64; ``expr = intensities @ matrix``.
    """

    names: tuple[str, ...]
    matrix: np.ndarray
    #: per-AU gains of this head's pain face (:func:`identity_pain_gains`); None = the shared face
    pain_gains: Mapping[str, float] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, dtype=np.float64)
        names = tuple(str(n) for n in self.names)
        for n in names:
            if n not in AU_NAMES:
                raise InputError(f"AUMap: unknown AU {n!r}; expected names from {', '.join(AU_NAMES)}")
        if len(set(names)) != len(names):
            raise InputError(f"AUMap: duplicate AU names in {names}")
        if m.ndim != 2 or m.shape[0] != len(names):
            raise InputError(f"AUMap: matrix: expected shape ({len(names)}, n_expr), found {m.shape}")
        bad = ~np.isfinite(m)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise InputError(f"AUMap: aus.{names[i]}[{j}]: expected a finite number, found {m[i, j]}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "matrix", m)
        if self.pain_gains is not None:
            gains = {}
            for k, v in dict(self.pain_gains).items():
                if k not in names:
                    raise InputError(f"AUMap: pain_gains: {k!r} is not an AU of this map ({', '.join(names)})")
                g = float(v)
                if not math.isfinite(g) or g < 1.0 or g > PAIN_GAIN_MAX:
                    raise InputError(f"AUMap: pain_gains[{k!r}]: expected a gain in [1, {PAIN_GAIN_MAX:g}], "
                                     f"found {v!r}")
                gains[k] = g
            object.__setattr__(self, "pain_gains", MappingProxyType(gains) if gains else None)

    def with_pain_gains(self, gains: Mapping[str, float] | None) -> "AUMap":
        """The same map with ``pain_gains`` (None or all 1: the shared pain face)."""
        kept = {k: float(v) for k, v in (gains or {}).items() if float(v) != 1.0}
        return replace(self, pain_gains=kept or None)

    @property
    def n_expr(self) -> int:
        """Number of expression coefficients."""
        return int(self.matrix.shape[1])

    def row(self, name: str) -> np.ndarray:
        """(n_expr,) coefficients of one AU per unit intensity."""
        if name not in self.names:
            raise InputError(f"AU map: {name} is not in this map (it has {', '.join(self.names)})")
        return self.matrix[self.names.index(name)]

    @classmethod
    def from_dict(cls, data: Any, n_expr: int | None = None, source: str = "<dict>") -> "AUMap":
        """Build from the JSON structure (see the module docstring); errors name the field."""
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected a JSON object with 'n_expr' and 'aus', found {type(data).__name__}")
        if "n_expr" not in data:
            raise InputError(f"{source}: n_expr: missing (expected the number of expression coefficients, "
                             f"an integer)")
        ne = data["n_expr"]
        if isinstance(ne, bool) or not isinstance(ne, int) or ne < 1:
            raise InputError(f"{source}: n_expr: expected a positive integer, found {ne!r}")
        if n_expr is not None and ne != int(n_expr):
            raise InputError(f"{source}: n_expr: expected {int(n_expr)} (the model's expression coefficients), "
                             f"found {ne}")
        aus = data.get("aus")
        if not isinstance(aus, Mapping) or not aus:
            raise InputError(f"{source}: aus: expected a non-empty object mapping AU names to coefficient "
                             f"lists, found {aus!r:.60}")
        rows = {}
        for name, values in aus.items():
            if name not in AU_NAMES:
                raise InputError(f"{source}: aus.{name}: unknown AU; expected one of {', '.join(AU_NAMES)}")
            if not isinstance(values, (list, tuple)):
                raise InputError(f"{source}: aus.{name}: expected a list of {ne} numbers, found "
                                 f"{type(values).__name__}")
            if len(values) != ne:
                raise InputError(f"{source}: aus.{name}: expected {ne} coefficients (n_expr), found {len(values)}")
            row = np.empty(ne)
            for j, x in enumerate(values):
                if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                    raise InputError(f"{source}: aus.{name}[{j}]: expected a finite number, found {x!r}")
                if abs(x) * AU_MAX[name] > EXPR_LIMIT:  # one AU at full intensity must stay within the limit
                    raise InputError(f"{source}: aus.{name}[{j}]: expected |coefficient| <= {EXPR_LIMIT / AU_MAX[name]:g} "
                                     f"(at the AU's full intensity {AU_MAX[name]:g} the expression stays within "
                                     f"+-{EXPR_LIMIT:g}, flame.params.EXPR_LIMIT), found {x:g}")
                row[j] = float(x)
            rows[name] = row
        names = tuple(n for n in AU_NAMES if n in rows)
        return cls(names=names, matrix=np.stack([rows[n] for n in names]))

    @classmethod
    def load_json(cls, path: str | os.PathLike, n_expr: int | None = None) -> "AUMap":
        """Read an AU map JSON file (format in the module docstring).

        Parameters
        ----------
        path : path
            The JSON file.
        n_expr : int, optional
            The model's expression count; the file's ``n_expr`` must equal it.

        Raises
        ------
        InputError
            Unreadable JSON, or a field with the wrong type, length or value (named).
        """
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError as exc:
            raise InputError(f"{p}: AU map file not found") from exc
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"{p}: cannot read the AU map ({exc})") from exc
        from ..fileio import parse_json

        data = parse_json(text, InputError, str(p), "the AU map")
        return cls.from_dict(data, n_expr=n_expr, source=str(p))

    def to_dict(self) -> dict[str, Any]:
        """The JSON structure."""
        return {"n_expr": self.n_expr, "aus": {n: [float(x) for x in self.matrix[i]] for i, n in enumerate(self.names)}}

    def to_json(self, path: str | os.PathLike) -> Path:
        """Write the map as JSON (atomically); floats round-trip exactly."""
        target = Path(path)
        with atomic_write(target, "w") as fh:
            json.dump(self.to_dict(), fh, indent=1)
        return target


def default_au_map(n_expr: int | None = None) -> AUMap:
    """AU map of the embedded default head (expression order of ``default_head.EXPRESSION_NAMES``).

    Parameters
    ----------
    n_expr : int, optional
        Expression count of the loaded model (columns beyond the 24 named components are
        zero; a smaller count drops the components past it).
    """
    from .default_head import EXPRESSION_NAMES

    k = len(EXPRESSION_NAMES) if n_expr is None else int(n_expr)
    if k < 1:
        raise InputError(f"n_expr: expected a positive integer, found {n_expr!r}")
    m = np.zeros((len(AU_NAMES), k))
    for i, au in enumerate(AU_NAMES):
        for comp in _DEFAULT_COMPONENTS[au]:
            j = EXPRESSION_NAMES.index(comp)
            if j < k:
                m[i, j] = 1.0 / AU_MAX[au]
    return AUMap(names=AU_NAMES, matrix=m)


def au_map_for(model: Any, au_map_path: str | os.PathLike | None = None, *,
               normalise_pain: bool | None = None) -> AUMap:
    """The AU map for a loaded model: a JSON file if given, the default map for the default head.

    ``normalise_pain`` (default :data:`PAIN_NORMALISE_IDENTITY`, off): attach the head's
    :func:`identity_pain_gains` (a head of the default head's format: the default and the patients).
    The default head's map (its file's bytes, at any path) always carries :data:`DEFAULT_HEAD_PAIN_GAINS`; a
    patient's head
    (``holo_viewer.avatar.patients.load_patient_model``) its own ``patient.json`` ``pain_gains``, which
    the loader puts in ``model.metadata["pain_gains"]`` (docs/patients.md).

    Raises
    ------
    FlameError
        A user FLAME model and no AU map file (the message says how to supply one).
    """
    n_expr = int(model.n_expr)
    if au_map_path is not None:
        return AUMap.load_json(au_map_path, n_expr=n_expr)
    if getattr(model, "is_default_head", False):
        from .default_head import EXPRESSION_NAMES

        names = model.expression_names
        if names is not None and list(names) != list(EXPRESSION_NAMES[:len(names)]):
            raise FlameError(f"{getattr(model, 'source', 'model')}: expression_names do not match this version "
                             f"of the default head ({names[:4]}... vs {list(EXPRESSION_NAMES[:4])}...); "
                             f"rebuild it with scripts/build_default_head.py")
        base = default_au_map(n_expr)
        own = DEFAULT_HEAD_PAIN_GAINS if _is_shipped_default_head(model) else dict(
            (getattr(model, "metadata", None) or {}).get("pain_gains") or {})  # a patient's, from patient.json
        if not (PAIN_NORMALISE_IDENTITY if normalise_pain is None else normalise_pain):
            return base.with_pain_gains(own)
        # identity_pain_gains of the default head itself is {} (it is the reference): its own gains stay
        return base.with_pain_gains({**own, **identity_pain_gains(model, base)})
    raise FlameError(
        f"{getattr(model, 'source', 'model')}: this FLAME model has no AU map, so action units and pain "
        f"cannot be turned into its {n_expr} expression coefficients. Supply a JSON file with --au-map FILE "
        f"(or au_map_path=FILE), format: {{\"n_expr\": {n_expr}, \"aus\": {{\"AU4\": [{n_expr} numbers], "
        f"\"AU12\": [...], ...}}}} giving the expression coefficients per unit AU intensity (0..5 scale; "
        f"AU43 0..1); see holo_viewer/flame/expressions.py and docs/default_head.md.")


def _is_shipped_default_head(model: Any) -> bool:
    """The model was loaded from a file with the default head's bytes: the checkout's
    ``assets/default_head.npz`` (or its rebuilt copy in the cache, :func:`~holo_viewer.flame.default_head.
    default_head_path`) or a copy of it anywhere, recognised by its sha256 rather than its path; a patient's
    head in the same format has other bytes (its gains come from its ``patient.json``)."""
    src = getattr(model, "source", None)
    if not getattr(model, "is_default_head", False) or not src:
        return False
    from ..cache import cache_dir
    from .default_head import ASSET_NAME, default_head_path

    try:
        own = _file_digest(Path(src))
        return any(p.is_file() and _file_digest(p) == own
                   for p in (default_head_path(build_if_missing=False), cache_dir() / ASSET_NAME))
    except (OSError, TypeError, ValueError):
        return False


_DIGESTS: dict = {}  # (path, size, mtime) -> sha256 (cache.keep_recent)


def _file_digest(path: Path) -> str:
    """A file's sha256, kept per process while its size and modification time stay (a 6 MB head: 4 ms)."""
    from ..cache import keep_recent
    from ..fileio import file_sha256

    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    return _DIGESTS[key] if key in _DIGESTS else keep_recent(_DIGESTS, key, file_sha256(path), 16)


# --------------------------------------------------------------------- identity normalisation of pain
_EYE_LID_PAIRS = ((37, 41), (38, 40), (43, 47), (44, 46))  # iBUG 300-W, 0-based (bench/face_realism.py)
_BROW_LID = ((tuple(range(17, 22)), (37, 38)), (tuple(range(22, 27)), (43, 44)))


def landmark_pain_measures(points: Any) -> dict[str, float]:
    """Eye aperture and brow-to-upper-lid gap of 68 landmark points (iBUG 300-W order), in the head's
    frame (y up, the face toward +z), divided by the inter-ocular distance (eye centre to eye centre,
    x and y). Both are *vertical* (y) distances, the openings themselves: ``eye_aperture`` the mean of
    y(upper lid) - y(lower lid) over the four lid pairs 37-41, 38-40, 43-47, 44-46 (negative if the lids
    cross), ``brow_eye_gap`` the mean over the sides of y(brow centroid 17-21 / 22-26) - y(upper-lid
    centroid 37-38 / 43-44). (``bench/face_realism.py`` measures the same pairs on the detector's 2-D
    points as Euclidean distances, which keep the lid pairs' sideways offset when the eye is shut.)"""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[0] != 68 or pts.shape[1] not in (2, 3) or not np.all(np.isfinite(pts)):
        raise InputError(f"landmarks: expected finite (68, 2) or (68, 3) points, found shape {pts.shape}")
    xy = pts[:, :2]
    iod = float(np.linalg.norm(xy[36:42].mean(0) - xy[42:48].mean(0)))
    if not iod > 0:
        raise InputError("landmarks: the two eye centres coincide (inter-ocular distance 0)")
    y = xy[:, 1]
    eye = float(np.mean([y[a] - y[b] for a, b in _EYE_LID_PAIRS]))
    brow = float(np.mean([y[list(b)].mean() - y[list(lid)].mean() for b, lid in _BROW_LID]))
    return {"eye_aperture": eye / iod, "brow_eye_gap": brow / iod}


def _landmark_basis(model: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """(68, 3) neutral landmark vertices and (n_expr, 68, 3) their expression deltas, float64, of a
    head with ``metadata["landmark_vertices"]`` (None without them). Rest pose: the expression deltas
    add to the template before skinning and every joint rotation is 0, so the points are linear in expr."""
    meta = getattr(model, "metadata", None) or {}
    idx = meta.get("landmark_vertices")
    if idx is None:
        return None
    idx = np.asarray(idx).reshape(-1).astype(np.int64)
    if idx.shape != (68,):
        return None
    vt = model.v_template.detach().cpu().numpy().astype(np.float64)
    dirs = model.expr_dirs.detach().cpu().numpy().astype(np.float64).reshape(-1, vt.shape[0], 3)
    return vt[idx], dirs[:, idx]


def _pain_points(basis: tuple[np.ndarray, np.ndarray], au_map: "AUMap", p: float,
                 gains: Mapping[str, float] | None) -> np.ndarray:
    neutral, dirs = basis
    coef = np.zeros(au_map.n_expr)
    for k, v in _pain_aus(p).items():
        if k in au_map.names:
            coef += v * (gains or {}).get(k, 1.0) * au_map.row(k)
    n = min(len(coef), dirs.shape[0])
    return neutral + np.tensordot(coef[:n], dirs[:n], axes=1)


def landmark_pain_fractions(model: Any, au_map: "AUMap | None" = None,
                            levels: Any = (0.25, 0.5, 0.75, 1.0)) -> dict[str, np.ndarray]:
    """Pain p / neutral of :func:`landmark_pain_measures` on a head's own landmark vertices (float64),
    for each of ``levels``, with ``au_map``'s pain gains (default: :func:`au_map_for`'s map). ``model``:
    a FLAME-format head with ``metadata["landmark_vertices"]``, or a (neutral (68, 3), deltas
    (n_expr, 68, 3)) pair."""
    basis = model if isinstance(model, tuple) else _landmark_basis(model)
    if basis is None:
        raise InputError(f"{getattr(model, 'source', 'model')}: no landmark_vertices (68) in the model's "
                         f"metadata: the pain fractions are measured on them")
    if au_map is None:
        au_map = au_map_for(model)
    lv = np.atleast_1d(_check_p(levels))
    base = landmark_pain_measures(basis[0])
    out = {k: np.empty(len(lv)) for k in PAIN_GAIN_GROUPS}
    for i, p in enumerate(lv):
        m = landmark_pain_measures(_pain_points(basis, au_map, float(p), au_map.pain_gains))
        for k in out:
            out[k][i] = m[k] / base[k]
    return out


def _fractions_at(basis: tuple[np.ndarray, np.ndarray], au_map: "AUMap", g: np.ndarray) -> np.ndarray:
    gains = {au: float(gk) for gk, aus in zip(g, PAIN_GAIN_GROUPS.values()) for au in aus}
    base = landmark_pain_measures(basis[0])
    m = landmark_pain_measures(_pain_points(basis, au_map, 1.0, gains))
    return np.array([m[k] / base[k] for k in PAIN_GAIN_GROUPS])


def _solve_gains(basis: tuple[np.ndarray, np.ndarray], au_map: "AUMap", free: tuple[bool, ...],
                 target: np.ndarray) -> np.ndarray | None:
    """Newton on the free gains (fixed ones at 1) for fractions == target; None if it does not converge."""
    g = np.ones(len(free))
    idx = [i for i, f in enumerate(free) if f]
    if not idx:
        return g
    for _ in range(50):
        r = (_fractions_at(basis, au_map, g) - target)[idx]
        if np.max(np.abs(r)) < 1e-12:
            return g
        J = np.empty((len(idx), len(idx)))
        for c, j in enumerate(idx):
            h = np.zeros_like(g)
            h[j] = 1e-6
            J[:, c] = ((_fractions_at(basis, au_map, g + h) - _fractions_at(basis, au_map, g - h)) / 2e-6)[idx]
        try:
            step = np.linalg.solve(J, r)
        except np.linalg.LinAlgError:
            return None
        g[idx] -= step
        if not np.all(np.isfinite(g)) or np.any(g[idx] <= 0) or np.any(g[idx] > 10):
            return None
    return g if np.max(np.abs((_fractions_at(basis, au_map, g) - target)[idx])) < 1e-9 else None


def identity_pain_gains(model: Any, au_map: "AUMap | None" = None,
                        reference: Mapping[str, float] | None = None) -> dict[str, float]:
    """Per-AU gains that bring a head's pain fractions (:func:`landmark_pain_fractions` at p = 1) to
    the reference's (default :data:`PAIN_REFERENCE_FRACTIONS`), only lifting.

    For each measure of :data:`PAIN_GAIN_GROUPS` either its gain is 1 and the head's fraction is
    already at or below the reference's, or its gain is > 1 and the fraction equals the reference's
    (both measures solved together: the orbital tightening also moves the upper lid, hence the brow
    gap). Gains are capped at :data:`PAIN_GAIN_MAX`. ``{}`` for a head without landmark vertices.

    Parameters
    ----------
    model : FlameModel or (neutral (68, 3), deltas (n_expr, 68, 3))
    au_map : AUMap, optional
        The head's map without gains (default: :func:`default_au_map` sized to the model).
    reference : mapping, optional
        Target fractions per measure (default :data:`PAIN_REFERENCE_FRACTIONS`).
    """
    basis = model if isinstance(model, tuple) else _landmark_basis(model)
    if basis is None:
        return {}
    if au_map is None:
        au_map = default_au_map(basis[1].shape[0])
    au_map = au_map.with_pain_gains(None)
    ref = dict(PAIN_REFERENCE_FRACTIONS if reference is None else reference)
    target = np.array([float(ref[k]) for k in PAIN_GAIN_GROUPS])
    tol = 1e-9
    g = None
    for free in ((True, True), (True, False), (False, True), (False, False)):
        cand = _solve_gains(basis, au_map, free, target)
        if cand is None:
            continue
        f = _fractions_at(basis, au_map, cand)
        if all((cand[i] >= 1.0 - tol) if fr else (f[i] <= target[i] + tol) for i, fr in enumerate(free)):
            g = cand
            break
    if g is None:  # no consistent active set (a degenerate head): the shared face
        return {}
    g = np.clip(g, 1.0, PAIN_GAIN_MAX)
    return {au: float(gk) for gk, aus in zip(g, PAIN_GAIN_GROUPS.values()) for au in aus
            if au in au_map.names and gk > 1.0 + 1e-9}


def _check_intensity(name: str, value: Any) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"aus[{name!r}]: expected a number, found {value!r}") from exc
    if not math.isfinite(x) or x < 0 or x > AU_MAX[name] + 1e-9:
        raise InputError(f"aus[{name!r}]: expected an intensity in [0, {AU_MAX[name]:g}], found {value!r}")
    return x


def expression_from_aus(aus: Mapping[str, float], au_map: AUMap) -> np.ndarray:
    """Expression coefficients (n_expr,) for AU intensities ``{"AU12": 3.0, ...}``."""
    expr = np.zeros(au_map.n_expr)
    for name, value in aus.items():
        if name not in AU_NAMES:
            raise InputError(f"aus: unknown AU {name!r}; expected one of {', '.join(AU_NAMES)}")
        x = _check_intensity(name, value)
        if x:
            expr += x * au_map.row(name)
    return expr


def _check_p(p: Any) -> np.ndarray:
    lo, hi = PAIN_RANGE
    arr = np.asarray(p, dtype=np.float64) if not isinstance(p, str) else None
    if arr is None or arr.ndim > 1:
        raise InputError(f"p: expected a pain intensity in [{lo:g}, {hi:g}] or an array (T,), found {p!r:.60}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"p: expected values in [{lo:g}, {hi:g}], found NaN/inf in {arr!r:.60}")
    if np.any(arr < lo) or np.any(arr > hi):
        raise InputError(f"p: expected values in [{lo:g}, {hi:g}], found range [{arr.min()}, {arr.max()}]")
    return arr


def pain_aus(p: float) -> dict[str, float]:
    """AU intensities of the canonical pain face at pain ``p`` in [0, 1].

    Each AU is ``PAIN_PEAK[au] * p ** PAIN_EXPONENT[au]``: brow lowering (AU4) leads, orbital
    tightening (AU6/AU7) and the nose wrinkle (AU9) follow, the upper-lip raise (AU10, the teeth)
    comes last, eye closure (AU43) is a trace, 0.05 p^2. PSPI(p) = 5 p^0.8 + max(5 p^1.2, 5 p^1.5) +
    max(3 p^1.2, 4 p^2) + 0.05 p^2: 0 at p = 0, 14.05 at p = 1, strictly increasing. Every AU is
    non-decreasing in p and largest at p = 1.
    """
    return _pain_aus(float(_check_p(p)))


def _pain_aus(x: float) -> dict[str, float]:
    """:func:`pain_aus` for an already validated ``x``."""
    return {k: v * x ** PAIN_EXPONENT[k] for k, v in PAIN_PEAK.items()}


def pain_expression(p: Any, au_map: AUMap) -> np.ndarray:
    """Expression coefficients of the pain face: p scalar -> (n_expr,), p (T,) -> (T, n_expr).

    With ``au_map.pain_gains`` (a patient's identity normalisation, :func:`identity_pain_gains`) each
    AU's coefficients are scaled by its gain; the AU intensities are :func:`pain_aus`'s."""
    arr = _check_p(p)
    missing = [a for a in _PSPI_CORE if a not in au_map.names]
    if not any(a in au_map.names for a in ("AU6", "AU7")):
        missing.append("AU6 or AU7")
    if not any(a in au_map.names for a in ("AU9", "AU10")):
        missing.append("AU9 or AU10")
    if missing:
        raise InputError(f"AU map: pain needs {', '.join(missing)} (PSPI action units), which the map lacks")

    gains = au_map.pain_gains

    def one(x: float) -> np.ndarray:  # x was validated above, once
        aus = {k: v for k, v in _pain_aus(x).items() if k in au_map.names}
        if not gains:
            return expression_from_aus(aus, au_map)
        expr = np.zeros(au_map.n_expr)  # this head's gains (identity normalisation) on the shared face
        for k, v in aus.items():
            if v:
                expr += v * gains.get(k, 1.0) * au_map.row(k)
        return expr

    if arr.ndim == 0:
        return one(float(arr))
    return np.stack([one(float(x)) for x in arr]) if len(arr) else np.zeros((0, au_map.n_expr))


def estimate_aus(expr: Any, au_map: AUMap) -> np.ndarray:
    """Least-squares AU intensities (..., n_au) from expression coefficients (..., n_expr), clipped to range."""
    e = np.asarray(expr, dtype=np.float64)
    if e.ndim < 1 or e.shape[-1] != au_map.n_expr:
        raise InputError(f"expr: expected shape (..., {au_map.n_expr}), found {e.shape}")
    if not np.all(np.isfinite(e)):
        raise InputError("expr: contains NaN/inf")
    pinv = np.linalg.pinv(au_map.matrix)  # (n_expr, n_au)
    est = e @ pinv
    hi = np.array([AU_MAX[n] for n in au_map.names])
    return np.clip(est, 0.0, hi)


def pspi_from_aus(aus: Mapping[str, float]) -> float:
    """PSPI = AU4 + max(AU6, AU7) + max(AU9, AU10) + AU43 (missing AUs count 0)."""
    g = lambda k: float(aus.get(k, 0.0))  # noqa: E731
    return g("AU4") + max(g("AU6"), g("AU7")) + max(g("AU9"), g("AU10")) + g("AU43")


def pspi(expr: Any, au_map: AUMap | None = None) -> np.ndarray:
    """PSPI (...) estimated from expression coefficients (..., n_expr) via :func:`estimate_aus`.

    ``au_map`` defaults to the default head's map (sized to ``expr``'s last axis).
    """
    e = np.asarray(expr, dtype=np.float64)
    if au_map is None:
        if e.ndim < 1:
            raise InputError(f"expr: expected shape (..., n_expr), found {e.shape}")
        au_map = default_au_map(e.shape[-1])
    est = estimate_aus(e, au_map)
    col = {n: est[..., i] for i, n in enumerate(au_map.names)}
    z = np.zeros(est.shape[:-1])
    g = lambda k: col.get(k, z)  # noqa: E731
    return g("AU4") + np.maximum(g("AU6"), g("AU7")) + np.maximum(g("AU9"), g("AU10")) + g("AU43")


def _check_name(name: str) -> str:
    if name not in EXPRESSION_NAMES_KNOWN:
        raise InputError(f"expression name: expected one of {', '.join(EXPRESSION_NAMES_KNOWN)}, found {name!r}")
    return name


def named_expression(name: str, intensity: float, au_map: AUMap) -> np.ndarray:
    """Expression coefficients (n_expr,) of a named expression at ``intensity`` in [0, 1].

    Names: those of :data:`NAMED_EXPRESSIONS` (combine with :func:`jaw_for_expression` for the
    jaw rotation). ``named_expression("pain", p)`` is ``pain_expression(p)``.
    """
    _check_name(name)
    aus = NAMED_EXPRESSIONS[name][0]
    if aus is None:
        return pain_expression(intensity, au_map)
    x = float(np.asarray(_check_p(intensity)))
    return expression_from_aus({k: v * x for k, v in aus.items()}, au_map)


def jaw_for_expression(name: str, intensity: float) -> np.ndarray:
    """Axis-angle jaw pose (3,) in radians for a named expression (positive x opens the mouth; 0 for pain)."""
    _check_name(name)
    x = float(np.asarray(_check_p(intensity)))
    return np.array([NAMED_EXPRESSIONS[name][1] * x, 0.0, 0.0])
