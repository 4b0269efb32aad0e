"""Level of detail: keep the Gaussians that contribute most over the view cone (once per avatar).

Score of a Gaussian = its opacity x its largest cross-section area ``pi s1 s2`` (the two largest
scales), i.e. the light it can block or emit seen from any direction of the cone; an avatar
deforms its Gaussians but keeps their identities, so the ranking is computed once (on the rest
pose) and each frame renders ``gaussians.subset(keep)``. The error this costs is measured, not
bounded: bench/live_frame.py reports it against the full set (PSNR of the native image).
"""

from __future__ import annotations

import numpy as np

from ..avatar.gaussians import Gaussians
from ..errors import InputError

__all__ = ["contribution", "lod_keep"]


def contribution(gaussians: Gaussians) -> np.ndarray:
    """(N,) float64 contribution score: ``sigmoid(opacity_logit) * s1 * s2`` (two largest scales)."""
    g = gaussians.numpy()
    s = np.sort(np.exp(np.asarray(g.log_scales, dtype=np.float64)), axis=1)
    op = 1.0 / (1.0 + np.exp(-np.asarray(g.opacity_logits, dtype=np.float64).reshape(-1)))
    return op * s[:, -1] * s[:, -2]


def lod_keep(gaussians: Gaussians, fraction: float) -> np.ndarray:
    """Indices (sorted, int64) of the ``round(fraction N)`` Gaussians with the largest contribution.

    Parameters
    ----------
    gaussians : Gaussians
        The avatar at rest (N Gaussians).
    fraction : float
        In (0, 1]; 1 keeps all.
    """
    if not (0.0 < float(fraction) <= 1.0):
        raise InputError(f"fraction: expected in (0, 1], found {fraction}")
    n = len(gaussians)
    k = max(1, int(round(float(fraction) * n)))
    if k >= n:
        return np.arange(n, dtype=np.int64)
    score = contribution(gaussians)
    keep = np.argpartition(-score, k - 1)[:k]
    return np.sort(keep).astype(np.int64)
