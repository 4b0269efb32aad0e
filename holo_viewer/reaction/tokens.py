"""Facial-feature tokenizer: a learned codebook (k-means) over per-frame face states.

Each frame's face state ``x`` (S,) is mapped to the index of its nearest centroid in a
weighted metric ``|w * (x - c)|`` and decoded back to that centroid. The training code uses
fixed weights (:func:`state_weights`): 1 per AU unit (intensity / 5) and 5 per radian of jaw
and head rotation, so codes are spent on expression changes that matter for the REACT
attributes and on visible head motion (nods, 0.1 rad = 0.5 units) rather than on small,
unpredictable head sway. Why a k-means codebook rather than FSQ
(docs/reaction.md, "Tokenizer"): the codes sit where the data is (an FSQ grid spends most of
its 8*5*5*5 cells on face states that never occur), the fit is a few seconds of Lloyd
iterations with no autoencoder to train (the 10-minute CPU budget), it is deterministic
given the seed, and dead codes are re-seeded so none collapse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ReactionError
from ..validation import check_array

__all__ = ["Codebook", "fit_codebook", "state_weights"]


def state_weights(n_au: int, pose_weight: float = 5.0) -> np.ndarray:
    """Metric weights (n_au + 6,): 1 for AU dimensions, ``pose_weight`` per radian for jaw and rotation."""
    return np.concatenate([np.ones(n_au), np.full(6, pose_weight)]).astype(np.float32)


@dataclass(frozen=True)
class Codebook:
    """Centroids (C, S) float32 and the metric weights (S,) float32."""

    centroids: np.ndarray
    weights: np.ndarray

    @property
    def n_codes(self) -> int:
        """Number of tokens C."""
        return int(self.centroids.shape[0])

    @property
    def state_dim(self) -> int:
        """Face-state size S."""
        return int(self.centroids.shape[1])

    def encode(self, states: np.ndarray, chunk: int = 8192) -> np.ndarray:
        """Nearest-centroid tokens of face states, shape (..., S) -> (...,) int64."""
        x = np.asarray(check_array(states, "states", (..., self.state_dim)), dtype=np.float32)
        flat = torch.from_numpy(x.reshape(-1, self.state_dim) * self.weights)
        cw = torch.from_numpy(self.centroids * self.weights)
        out = np.empty(flat.shape[0], dtype=np.int64)
        for s in range(0, flat.shape[0], chunk):
            out[s:s + chunk] = torch.cdist(flat[s:s + chunk], cw).argmin(dim=1).numpy()
        return out.reshape(x.shape[:-1])

    def decode(self, tokens: np.ndarray) -> np.ndarray:
        """Face states of tokens, shape (...,) -> (..., S) float32."""
        t = np.asarray(tokens)
        if not np.issubdtype(t.dtype, np.integer) or (t.size and (t.min() < 0 or t.max() >= self.n_codes)):
            raise ReactionError(f"tokens: expected integers in [0, {self.n_codes}), found dtype {t.dtype}"
                                + (f", range [{t.min()}, {t.max()}]" if t.size else ""))
        return self.centroids[t]

    def to_tensors(self) -> dict[str, torch.Tensor]:
        """For checkpoints (``torch.load(weights_only=True)`` compatible)."""
        return {"centroids": torch.from_numpy(self.centroids), "weights": torch.from_numpy(self.weights)}

    @classmethod
    def from_tensors(cls, d: dict) -> "Codebook":
        """Inverse of :meth:`to_tensors`."""
        return cls(np.asarray(d["centroids"], dtype=np.float32), np.asarray(d["weights"], dtype=np.float32))


def fit_codebook(states: np.ndarray, n_codes: int = 1024, iters: int = 20, max_points: int = 40000,
                 seed: int = 0, weights: np.ndarray | None = None) -> Codebook:
    """Fit a k-means codebook (k-means++ init, Lloyd iterations, dead codes re-seeded).

    Parameters
    ----------
    states : numpy.ndarray, shape (M, S)
        Training frames.
    n_codes : int
        Codebook size C (<= number of distinct frames).
    iters : int
        Lloyd iterations.
    max_points : int
        Frames used for the fit (a seeded random subset when M is larger).
    seed : int
    weights : numpy.ndarray, shape (S,), optional
        Metric weights; default ``1 / max(std, 0.02)`` of each dimension of the fitted frames.

    Returns
    -------
    Codebook
    """
    x = np.asarray(check_array(states, "states", ("M", "S")), dtype=np.float32)
    rng = np.random.default_rng(seed)
    if x.shape[0] > max_points:
        x = x[rng.choice(x.shape[0], max_points, replace=False)]
    if x.shape[0] < n_codes:
        raise ReactionError(f"states: need at least n_codes={n_codes} frames to fit the codebook, found {x.shape[0]}")
    if weights is None:
        w = (1.0 / np.maximum(x.std(axis=0), 0.02)).astype(np.float32)
    else:
        w = np.asarray(check_array(weights, "weights", (x.shape[1],)), dtype=np.float32)
    xw = torch.from_numpy(x * w)
    # k-means++
    first = int(rng.integers(x.shape[0]))
    cent = [xw[first]]
    d2 = ((xw - xw[first]) ** 2).sum(dim=1)
    for _ in range(1, n_codes):
        p = d2.numpy().astype(np.float64)
        tot = p.sum()
        i = int(rng.choice(x.shape[0], p=p / tot)) if tot > 0 else int(rng.integers(x.shape[0]))
        cent.append(xw[i])
        d2 = torch.minimum(d2, ((xw - xw[i]) ** 2).sum(dim=1))
    c = torch.stack(cent)
    for _ in range(iters):
        assign = torch.cdist(xw, c).argmin(dim=1)
        counts = torch.bincount(assign, minlength=n_codes)
        sums = torch.zeros_like(c).index_add_(0, assign, xw)
        alive = counts > 0
        c[alive] = sums[alive] / counts[alive, None].to(c.dtype)
        dead = torch.nonzero(~alive)[:, 0]
        if dead.numel():
            far = torch.cdist(xw, c).min(dim=1).values.argsort(descending=True)[:dead.numel()]
            c[dead] = xw[far]
    return Codebook((c.numpy() / w).astype(np.float32), w)
