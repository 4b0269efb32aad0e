"""FRRea: Fréchet distance between rendered real and generated listener frames.

The frames (face states) are rendered by a renderer the caller passes in (the reaction package
never builds an avatar or a renderer itself): normally
:class:`holo_viewer.pipeline.FaceStateRenderer`, which poses the default FLAME head, deforms the
default rigged avatar and renders one frontal camera at a small resolution. Each image is
described by :func:`~holo_viewer.reaction.metrics.simple_image_features` (a hand-made 86-number
descriptor, **not Inception** features, so the values are not comparable with published
FID/FRRea numbers), and :func:`~holo_viewer.reaction.metrics.frechet_distance` compares the two
sets.

Rendering every frame of N x K x T reactions is far beyond a CPU, so a seeded random subset of
frames is rendered (``n_frames`` per set).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import InputError
from ..validation import check_array
from .metrics import frechet_distance, simple_image_features

__all__ = ["frrea", "StateRenderer"]

#: renders face states (B, S) into images (B, H, W, 3) float32 in [0, 1]
StateRenderer = Callable[[np.ndarray], np.ndarray]


def frrea(real_states: np.ndarray, fake_states: np.ndarray, render: StateRenderer, n_frames: int = 64,
          seed: int = 0) -> float:
    """Fréchet distance between simple features of rendered real and generated frames.

    Parameters
    ----------
    real_states : numpy.ndarray
        (..., S) ground-truth listener face states (any leading shape).
    fake_states : numpy.ndarray
        (..., S) generated face states.
    render : callable
        Face states (B, S) -> images (B, H, W, 3), e.g. ``holo_viewer.pipeline.FaceStateRenderer()``.
    n_frames : int
        Frames rendered per set (a seeded random subset).
    seed : int

    Returns
    -------
    float
    """
    real = np.asarray(check_array(real_states, "real_states", (..., None)))
    S = real.shape[-1]
    fake = np.asarray(check_array(fake_states, "fake_states", (..., S)))
    state_dim = getattr(render, "state_dim", S)
    if S != state_dim:
        raise InputError(f"real_states: expected face states of width {state_dim} (the renderer's), found {S}")
    real, fake = real.reshape(-1, S), fake.reshape(-1, S)
    if n_frames < 2:
        raise InputError(f"n_frames: expected >= 2, found {n_frames}")
    rng = np.random.default_rng(seed)
    ri = rng.choice(real.shape[0], min(n_frames, real.shape[0]), replace=False)
    fi = rng.choice(fake.shape[0], min(n_frames, fake.shape[0]), replace=False)
    fr = simple_image_features(render(real[ri]))
    ff = simple_image_features(render(fake[fi]))
    return frechet_distance(fr, ff)
