"""Per-frame facial feature layouts of the reaction module (pure math, no I/O).

Three views of one face frame are used (25 fps everywhere):

``state``  (S,)  the model's compact face state, ``S = n_au + 6``::

        [ AU intensities of ``au_map.names`` divided by their scale (5, AU43: 1) ,
          jaw pose (3, axis-angle, rad) , head rotation (3, axis-angle, rad) ]

    A state maps *linearly* to the FLAME features below (``expr = aus @ au_map.matrix``)
    and back (``estimate_aus``, least squares), so the model can consume and produce
    FLAME parameters of the default head while working in a small, interpretable space.

``flame``  (n_expr + 6,)  FLAME features of the default head: ``[expr (n_expr), jaw_pose (3), rotation (3)]``
    with GaussianAvatars' key names when written to ``flame_param.npz``.

``attributes`` (25,)  the REACT 2023/2024 attribute layout::

        0:15  AU1 AU2 AU4 AU6 AU7 AU9 AU10 AU12 AU14 AU15 AU17 AU23 AU24 AU25 AU26  (intensity / 5, in [0, 1])
        15    valence in [-1, 1]
        16    arousal in [-1, 1]
        17:25 probabilities of Neutral Happy Sad Surprise Fear Disgust Anger Contempt (sum 1)

    computed from the 15 AU intensities with the documented map :func:`attributes_from_react_aus`
    (docs/reaction.md, "Attribute map").
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InputError, ReactionError
from ..validation import check_array

__all__ = [
    "FPS",
    "REACT_AU_NAMES",
    "EXPRESSION_CLASSES",
    "ATTRIBUTE_DIM",
    "DTW_GROUPS",
    "au_scales",
    "attributes_from_react_aus",
    "react_aus_from_state",
    "attributes_from_state",
    "flame_from_state",
    "state_from_flame",
    "state_dim",
]

#: frame rate of every per-frame feature (frames per second)
FPS = 25
#: the 15 AUs of the REACT attribute layout, in column order
REACT_AU_NAMES: tuple[str, ...] = ("AU1", "AU2", "AU4", "AU6", "AU7", "AU9", "AU10", "AU12", "AU14", "AU15",
                                   "AU17", "AU23", "AU24", "AU25", "AU26")
#: the 8 expression classes of the REACT attribute layout, in column order
EXPRESSION_CLASSES: tuple[str, ...] = ("Neutral", "Happy", "Sad", "Surprise", "Fear", "Disgust", "Anger",
                                       "Contempt")
ATTRIBUTE_DIM = 25
#: official REACT DTW groups (start, stop, weight): AUs, valence/arousal, expression probabilities
DTW_GROUPS: tuple[tuple[int, int, float], ...] = ((0, 15, 1.0 / 15.0), (15, 17, 1.0), (17, 25, 1.0 / 8.0))

# ---- attribute map (documented in docs/reaction.md; change both together) -------------------------
#: valence = tanh(VALENCE_GAIN * sum_au w_au * a_au), a = intensity / 5
VALENCE_WEIGHTS: dict[str, float] = {"AU12": 1.0, "AU6": 0.5, "AU4": -1.0, "AU15": -0.8, "AU9": -0.5,
                                     "AU10": -0.5, "AU17": -0.3}
VALENCE_GAIN = 1.5
#: arousal = tanh(AROUSAL_GAIN * sum_au w_au * a_au + AROUSAL_BIAS)
AROUSAL_WEIGHTS: dict[str, float] = {"AU1": 0.5, "AU2": 0.5, "AU4": 0.3, "AU7": 0.5, "AU25": 0.4, "AU26": 0.6}
AROUSAL_GAIN = 1.5
AROUSAL_BIAS = -0.3
#: expression score = mean of its AUs' a; Neutral has the constant score NEUTRAL_SCORE;
#: probabilities = softmax(EXPRESSION_BETA * scores)
EXPRESSION_AUS: dict[str, tuple[str, ...]] = {
    "Happy": ("AU6", "AU12"),
    "Sad": ("AU1", "AU4", "AU15", "AU17"),
    "Surprise": ("AU1", "AU2", "AU25", "AU26"),
    "Fear": ("AU1", "AU2", "AU4", "AU7", "AU25"),
    "Disgust": ("AU9", "AU10", "AU17"),
    "Anger": ("AU4", "AU7", "AU23", "AU24"),
    "Contempt": ("AU14",),
}
NEUTRAL_SCORE = 0.25
EXPRESSION_BETA = 8.0


def _weights_matrix() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    idx = {n: i for i, n in enumerate(REACT_AU_NAMES)}
    wv = np.zeros(15)
    for n, w in VALENCE_WEIGHTS.items():
        wv[idx[n]] = w
    wa = np.zeros(15)
    for n, w in AROUSAL_WEIGHTS.items():
        wa[idx[n]] = w
    we = np.zeros((15, 7))  # columns: EXPRESSION_CLASSES[1:] (Neutral has a constant score)
    for c, aus in EXPRESSION_AUS.items():
        for n in aus:
            we[idx[n], EXPRESSION_CLASSES.index(c) - 1] = 1.0 / len(aus)
    return wv, wa, we


_WV, _WA, _WE = _weights_matrix()


def attributes_from_react_aus(aus01: np.ndarray) -> np.ndarray:
    """25-D REACT attributes from the 15 REACT AU intensities.

    Parameters
    ----------
    aus01 : numpy.ndarray, shape (..., 15)
        AU intensities divided by 5 (in [0, 1]; values outside are clipped), columns in
        :data:`REACT_AU_NAMES` order.

    Returns
    -------
    numpy.ndarray, shape (..., 25), float64
        ``[aus01 (15), valence, arousal, 8 expression probabilities]``.
    """
    a = np.clip(np.asarray(check_array(aus01, "aus01", (..., 15)), dtype=np.float64), 0.0, 1.0)
    val = np.tanh(VALENCE_GAIN * (a @ _WV))
    aro = np.tanh(AROUSAL_GAIN * (a @ _WA) + AROUSAL_BIAS)
    scores = a @ _WE
    scores = np.concatenate([np.full(a.shape[:-1] + (1,), NEUTRAL_SCORE), scores], axis=-1) * EXPRESSION_BETA
    scores -= scores.max(axis=-1, keepdims=True)
    e = np.exp(scores)
    probs = e / e.sum(axis=-1, keepdims=True)
    return np.concatenate([a, val[..., None], aro[..., None], probs], axis=-1)


def au_scales(names: Sequence[str]) -> np.ndarray:
    """Intensity scale of each AU: 5 (FACS A..E as 1..5), AU43 (eye closure, as in PSPI): 1."""
    return np.array([1.0 if n == "AU43" else 5.0 for n in names])


def state_dim(au_names: Sequence[str]) -> int:
    """Length of a face state for the given AU list: ``len(au_names) + 6``."""
    return len(au_names) + 6


def react_aus_from_state(state: np.ndarray, au_names: Sequence[str]) -> np.ndarray:
    """The 15 REACT AU columns (intensity / 5) of face states.

    Parameters
    ----------
    state : numpy.ndarray, shape (..., len(au_names) + 6)
    au_names : sequence of str
        AU order of the state (``au_map.names``); must contain every REACT AU.

    Returns
    -------
    numpy.ndarray, shape (..., 15)
    """
    state = check_array(state, "state", (..., state_dim(au_names)))
    missing = [n for n in REACT_AU_NAMES if n not in au_names]
    if missing:
        raise ReactionError(f"au_names: the AU map lacks REACT AUs {missing}; found {list(au_names)}")
    cols = [list(au_names).index(n) for n in REACT_AU_NAMES]
    scales = au_scales(au_names)[cols] / 5.0  # state holds intensity/scale; REACT wants intensity/5
    return np.asarray(state)[..., cols] * scales


def attributes_from_state(state: np.ndarray, au_names: Sequence[str]) -> np.ndarray:
    """25-D REACT attributes of face states, shape (..., S) -> (..., 25)."""
    return attributes_from_react_aus(react_aus_from_state(state, au_names))


def flame_from_state(state: np.ndarray, au_map) -> dict[str, np.ndarray]:
    """FLAME parameters (GaussianAvatars key names) of face states.

    Parameters
    ----------
    state : numpy.ndarray, shape (T, n_au + 6)
    au_map : holo_viewer.flame.expressions.AUMap
        Gives the AU order (``names``) and ``matrix`` (n_au, n_expr): expression
        coefficients per unit AU intensity.

    Returns
    -------
    dict
        ``expr`` (T, n_expr), ``jaw_pose`` (T, 3), ``rotation`` (T, 3), float32.
    """
    matrix = np.asarray(check_array(au_map.matrix, "au_map.matrix", ("A", None)), dtype=np.float64)
    n_au = matrix.shape[0]
    state = np.asarray(check_array(state, "state", ("T", n_au + 6)), dtype=np.float64)
    intensities = state[:, :n_au] * au_scales(au_map.names)
    return {
        "expr": (intensities @ matrix).astype(np.float32),
        "jaw_pose": state[:, n_au:n_au + 3].astype(np.float32),
        "rotation": state[:, n_au + 3:n_au + 6].astype(np.float32),
    }


def state_from_flame(expr: np.ndarray, jaw_pose: np.ndarray, rotation: np.ndarray, au_map) -> np.ndarray:
    """Face states from FLAME parameters of the default head (least-squares AU estimate).

    Parameters
    ----------
    expr : numpy.ndarray, shape (T, n_expr)
    jaw_pose, rotation : numpy.ndarray, shape (T, 3)
    au_map : holo_viewer.flame.expressions.AUMap

    Returns
    -------
    numpy.ndarray, shape (T, n_au + 6)
        AU intensities / scale (clipped to the valid range by ``estimate_aus``), jaw, rotation.
    """
    from ..flame.expressions import estimate_aus

    n_expr = int(au_map.matrix.shape[1])
    sizes: dict[str, int] = {}
    expr = check_array(expr, "expr", ("T", None), sizes=sizes)
    if expr.shape[1] > n_expr:
        raise InputError(f"expr: expected at most {n_expr} coefficients (the AU map's n_expr), "
                         f"found {expr.shape[1]}")
    if expr.shape[1] < n_expr:
        expr = np.concatenate([expr, np.zeros((expr.shape[0], n_expr - expr.shape[1]))], axis=1)
    jaw_pose = check_array(jaw_pose, "jaw_pose", ("T", 3), sizes=sizes)
    rotation = check_array(rotation, "rotation", ("T", 3), sizes=sizes)
    aus = np.asarray(estimate_aus(np.asarray(expr, dtype=np.float64), au_map), dtype=np.float64)
    aus = aus / au_scales(au_map.names)
    return np.concatenate([aus, np.asarray(jaw_pose, np.float64), np.asarray(rotation, np.float64)], axis=1)
