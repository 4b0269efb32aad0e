"""Reference reactions of the REACT challenge (GT, Random, Mime, MeanFr, MeanSeq), in the 25-D layout.

All return ``preds`` of shape (N, K, T, 25) for the metrics of :mod:`holo_viewer.reaction.metrics`.
"""

from __future__ import annotations

import numpy as np

from ..validation import check_array

__all__ = ["gt_baseline", "random_baseline", "mime_baseline", "mean_frame_baseline", "mean_sequence_baseline",
           "all_baselines", "state_baselines"]


def gt_baseline(listener_gt: np.ndarray, k: int) -> np.ndarray:
    """The ground-truth listener reaction repeated K times (an upper reference; FRDiv = 0)."""
    x = check_array(listener_gt, "listener_gt", ("N", "T", "D"))
    return np.repeat(np.asarray(x)[:, None], k, axis=1)


def random_baseline(n: int, k: int, t: int, d: int = 25, seed: int = 0) -> np.ndarray:
    """Independent U[0, 1) values for every frame and dimension (seeded)."""
    return np.random.default_rng(seed).random((n, k, t, d))


def mime_baseline(speaker_gt: np.ndarray, k: int) -> np.ndarray:
    """The speaker's own attributes as the listener reaction, repeated K times."""
    x = check_array(speaker_gt, "speaker_gt", ("N", "T", "D"))
    return np.repeat(np.asarray(x)[:, None], k, axis=1)


def mean_frame_baseline(train_listener: np.ndarray, n: int, k: int, t: int) -> np.ndarray:
    """The mean training listener frame (25,) for every frame (constant over time)."""
    x = np.asarray(check_array(train_listener, "train_listener", ("M", "T", "D")), dtype=np.float64)
    return np.broadcast_to(x.mean(axis=(0, 1)), (n, k, t, x.shape[2])).copy()


def mean_sequence_baseline(train_listener: np.ndarray, n: int, k: int, t: int) -> np.ndarray:
    """The mean training listener sequence (mean over clips at each frame index; T must match)."""
    x = np.asarray(check_array(train_listener, "train_listener", ("M", t, "D")), dtype=np.float64)
    return np.broadcast_to(x.mean(axis=0), (n, k, t, x.shape[2])).copy()


def all_baselines(listener_gt: np.ndarray, speaker_gt: np.ndarray, train_listener: np.ndarray, k: int,
                  seed: int = 0) -> dict[str, np.ndarray]:
    """``{"GT", "Random", "Mime", "MeanFr", "MeanSeq"}`` predictions (N, K, T, D) for one split."""
    n, t, d = np.shape(listener_gt)
    return {
        "GT": gt_baseline(listener_gt, k),
        "Random": random_baseline(n, k, t, d, seed),
        "Mime": mime_baseline(speaker_gt, k),
        "MeanFr": mean_frame_baseline(train_listener, n, k, t),
        "MeanSeq": mean_sequence_baseline(train_listener, n, k, t),
    }


def state_baselines(listener_state: np.ndarray, speaker_state: np.ndarray, train_listener_state: np.ndarray,
                    n_au: int, k: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The same baselines as face states (N, K, T, S), for rendering (FRRea).

    Random draws AU values U[0, 1) (intensity / scale) with a neutral pose; the others are the
    face-state counterparts of :func:`all_baselines`.
    """
    n, t, s = np.shape(listener_state)
    rnd = np.zeros((n, k, t, s))
    rnd[..., :n_au] = np.random.default_rng(seed).random((n, k, t, n_au))
    return {
        "GT": gt_baseline(listener_state, k),
        "Random": rnd,
        "Mime": mime_baseline(speaker_state, k),
        "MeanFr": mean_frame_baseline(train_listener_state, n, k, t),
        "MeanSeq": mean_sequence_baseline(train_listener_state, n, k, t),
    }
