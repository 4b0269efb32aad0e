"""Axis-angle rotations (Rodrigues' formula) for torch and numpy.

Pure math, no I/O. An axis-angle vector ``r`` (3,) encodes a rotation by the angle
``theta = |r|`` (radians) about the unit axis ``r / theta``; rotation matrices act
on column vectors (``x' = R x``).

Rodrigues' formula is written with the *unnormalised* skew matrix ``K = [r]_x``::

    R = I + a(theta) K + b(theta) K @ K,   a = sin(theta) / theta,
                                          b = (1 - cos(theta)) / theta**2

so no axis has to be normalised. ``a`` and ``b`` are evaluated with their Taylor
series below a small angle, which keeps values and gradients finite (and exact to
float64 rounding) at and near ``r = 0``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = ["rodrigues", "rodrigues_np", "skew"]

# Below this angle (radians) the Taylor series of a and b are used. At 1e-3 the
# neglected terms are O(theta**4)/120 ~ 1e-14, below float64 rounding of the
# leading term, and the closed forms are still accurate above it in float64.
_SMALL_ANGLE = 1e-3


def skew(r: Tensor) -> Tensor:
    """Skew-symmetric cross-product matrices.

    Parameters
    ----------
    r : Tensor
        Vectors, shape (..., 3).

    Returns
    -------
    Tensor
        ``K`` with ``K @ x == cross(r, x)``, shape (..., 3, 3).
    """
    x, y, z = r.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*r.shape[:-1], 3, 3)


def _coefficients(theta2: Tensor) -> tuple[Tensor, Tensor]:
    """``sin(t)/t`` and ``(1-cos(t))/t**2`` from ``t**2``, safe at ``t = 0``."""
    small = theta2 < _SMALL_ANGLE ** 2
    # Replace small angles by 1 in the closed-form branch so that neither its value
    # nor its gradient (which torch.where still evaluates) can become NaN.
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    theta = torch.sqrt(safe2)
    a_closed = torch.sin(theta) / theta
    b_closed = (1.0 - torch.cos(theta)) / safe2
    a_taylor = 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0
    b_taylor = 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0
    return torch.where(small, a_taylor, a_closed), torch.where(small, b_taylor, b_closed)


def rodrigues(r: Tensor) -> Tensor:
    """Rotation matrices from axis-angle vectors (Rodrigues' formula).

    Parameters
    ----------
    r : Tensor
        Axis-angle vectors in radians, shape (..., 3), floating point.

    Returns
    -------
    Tensor
        Rotation matrices, shape (..., 3, 3), same dtype and device as ``r``.
        Finite values and gradients for every finite ``r``, including ``r = 0``.
    """
    theta2 = (r * r).sum(-1)
    a, b = _coefficients(theta2)
    k = skew(r)
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def rodrigues_np(r: np.ndarray) -> np.ndarray:
    """NumPy float64 version of :func:`rodrigues` (reference and tests).

    Parameters
    ----------
    r : numpy.ndarray
        Axis-angle vectors in radians, shape (..., 3).

    Returns
    -------
    numpy.ndarray
        Rotation matrices, shape (..., 3, 3), float64.
    """
    r = np.asarray(r, dtype=np.float64)
    theta2 = np.sum(r * r, axis=-1)
    small = theta2 < _SMALL_ANGLE ** 2
    safe2 = np.where(small, 1.0, theta2)
    theta = np.sqrt(safe2)
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2 ** 2 / 120.0, np.sin(theta) / theta)
    b = np.where(small, 0.5 - theta2 / 24.0 + theta2 ** 2 / 720.0, (1.0 - np.cos(theta)) / safe2)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(*r.shape[:-1], 3, 3)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)
