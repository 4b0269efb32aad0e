"""Real spherical harmonics up to degree 3 (3DGS convention), float64 numpy reference.

Colour of a Gaussian seen along the unit direction ``dir = normalise(mean - cam_pos)``
(docs/design.md, 3DGS forward pass)::

    rgb = max(sum_k basis_k(dir) * sh[k] + 0.5, 0)

with the basis ordered as graphdeco-inria's ``computeColorFromSH`` (degree 1: -C1 y, C1 z,
-C1 x; then the degree 2 and 3 terms below). Used by the reference, fast and torch backends.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..validation import is_torch

__all__ = ["C0", "C1", "C2", "C3", "sh_basis", "eval_sh", "sh_to_rgb"]

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(degree: int, dirs: np.ndarray) -> np.ndarray:
    """SH basis values for unit directions.

    Parameters
    ----------
    degree : int
        0..3.
    dirs : numpy.ndarray or torch.Tensor
        (..., 3) unit directions (x, y, z) in world space. A torch tensor gives a torch
        result on its device (the torch backend uses this same function).

    Returns
    -------
    numpy.ndarray or torch.Tensor
        (..., (degree+1)^2) basis values, same dtype as ``dirs``.
    """
    if degree not in (0, 1, 2, 3):
        raise InputError(f"sh degree: expected 0..3, found {degree!r}")
    if is_torch(dirs):
        import torch

        d, stack = dirs, (lambda parts: torch.stack(parts, dim=-1))
        full = torch.full_like
    else:
        d = np.asarray(dirs)
        stack = (lambda parts: np.stack(parts, axis=-1))
        full = np.full_like
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out = [full(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2.0 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3.0 * xx - yy), C3[1] * xy * z, C3[2] * y * (4.0 * zz - xx - yy),
                C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), C3[4] * x * (4.0 * zz - xx - yy),
                C3[5] * z * (xx - yy), C3[6] * x * (xx - 3.0 * yy)]
    return stack(out)


def eval_sh(degree: int, sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Evaluate SH of ``degree`` (uses the first (degree+1)^2 coefficients of ``sh``).

    Parameters
    ----------
    degree : int
        0..3, at most the degree ``sh`` holds.
    sh : numpy.ndarray
        (N, K, 3) coefficients, K >= (degree+1)^2.
    dirs : numpy.ndarray
        (..., N, 3) unit directions.

    Returns
    -------
    numpy.ndarray
        (..., N, 3) float64 SH values (before the +0.5 offset and clamp; see :func:`sh_to_rgb`).
    """
    sh = np.asarray(sh, dtype=np.float64)
    k = (degree + 1) ** 2
    if sh.ndim != 3 or sh.shape[2] != 3 or sh.shape[1] < k:
        raise InputError(f"sh: expected (N, >= {k}, 3) for degree {degree}, found {sh.shape}")
    basis = sh_basis(degree, np.asarray(dirs, dtype=np.float64))  # (..., N, k)
    if basis.shape[-2] != sh.shape[0]:
        raise InputError(f"dirs: expected (..., {sh.shape[0]}, 3), found {np.shape(dirs)}")
    return np.einsum("...nk,nkc->...nc", basis, sh[:, :k])


def sh_to_rgb(values: np.ndarray) -> np.ndarray:
    """``max(values + 0.5, 0)``: the 3DGS colour from SH values (not clamped above)."""
    return np.maximum(values + 0.5, 0.0)
