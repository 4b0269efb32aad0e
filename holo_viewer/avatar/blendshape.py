"""Blend-shape Gaussian avatar (the seed paper, Fig. 2): Gaussians as a linear function of expression.

Per Gaussian the primitive parameters ``p = [mean (3), quat (4), log_scale (3)]`` are blended::

    B*(psi) = B_0 + sum_k psi_k B_k

with ``B_0`` the rigged avatar at ``psi = 0`` (identity shape, zero pose) and ``B_k`` the
**analytic** first derivative ``d p / d psi_k`` at ``psi = 0``, obtained by forward-mode
automatic differentiation (``torch.func.jvp``) of the rigged avatar (FLAME expression blend
shapes + LBS + triangle binding) in float64. Optionally the jaw pose (3 axis-angle
components) is linearised the same way and appended to the coefficients. Opacity and SH are
constant. Quaternions come out unnormalised (renderers normalise them).

**Storage: B factored through the faces.** A Gaussian bound to face ``f`` with local
parameters ``(mu, q_l, l_l)`` has ``p = A_i f + a_i`` for the 17 face quantities
``f = [M = s R (9), c (3), q_f (4), log s (1)]``, where ``A_i`` is the fixed linear map
``f -> [M mu + c, q_f (x) q_l, log s (1, 1, 1)]`` and ``a_i = [0, 0, l_l]``. The chain rule
gives ``B_0,i = A_i F_0,f + a_i`` and ``B_k,i = A_i F_k,f`` with ``F_0`` the face quantities
at ``psi = 0`` and ``F_k = d f / d psi_k = [ds R + s dR, dc, dq_f, ds / s]``. A face moves
rigidly-plus-scale, so ``F_k`` is itself a fixed linear image of a 7-number face *twist*
``t_k = [sigma = ds / s, omega, dc]`` (``dR = R [omega]_x``, ``dq_f = q_f (x) (0, omega / 2)``)::

    F_k = G_f t_k:  d(sR) = M_0 (sigma I + [omega]_x),  dc,  q_0 (x) (0, omega / 2),  sigma

So the stored model is the face twists ``t_k`` (about 10k faces, sparse: only the (face,
component) pairs whose Gaussians move), ``F_0``, and each Gaussian's ``(mu, q_l, l_l)``.
Evaluation: ``t(psi) = sum_k psi_k t_k``, ``f(psi) = F_0 + G_f t(psi)``,
``p_i = A_i f(psi) + a_i``: a chain of linear maps of ``psi``, i.e. still *one* affine map
``B*(psi) = B_0 + sum_k psi_k B_k`` with ``B_k,i = A_i G_f t_k,f``, exactly the seed paper's
blend (the factorisation only changes how B is stored, by rank <= 7 per face). This reads
40 bytes per Gaussian instead of ``B_0`` plus ~2.2 sparse rows of 10 floats. Faces without
entries ("static": their Gaussians' B_k rows are all zero) store their Gaussians' ``B_0`` rows
instead of ``(mu, q_l, l_l)`` and are copied (the default head: 44% of the faces, 63% of the
Gaussians).
:meth:`BlendshapeAvatar.blend_shapes` materialises ``B_0`` and ``B`` (the torch backend's
dense product is the reference).

Global head rotation and translation are applied exactly afterwards as the rigid motion FLAME
gives them (rotation about the root joint ``J_0``, then translation).

``exact_jvp=True`` differentiates the whole per-Gaussian pipeline instead and stores a
per-Gaussian sparse ``B`` (the v1 layout, still readable). The approximation is exact at
``psi = 0`` and first-order accurate near it; ``bench/deform_tradeoff.py`` measures its error
against the rigged avatar.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import AvatarError, InputError
from ..fileio import read_npz, save_npz
from ..geometry import quat_multiply, quat_multiply_np
from .gaussians import Gaussians
from .rigged import RiggedAvatar

__all__ = ["BlendshapeAvatar"]

_P = 10  # parameters per Gaussian: mean 3, quat 4, log-scale 3
_Q = 17  # face quantities: M = s R column-major 9, centre 3, quat 4, log s 1
_T = 7  # face twist: sigma = ds / s, omega 3, dc 3
_FORMAT_V1 = "holo_viewer.blendshape_avatar.v1"  # per-Gaussian sparse B
_FORMAT = "holo_viewer.blendshape_avatar.v2"  # face-factorised B


def _check_ptr(ptr: np.ndarray, n_rows: int, n_items: int, name: str) -> None:
    if ptr.shape != (n_rows + 1,) or (ptr.size and (ptr[0] != 0 or ptr[-1] != n_items)) or np.any(np.diff(ptr) < 0):
        raise AvatarError(f"{name}: expected a non-decreasing ({n_rows + 1},) pointer from 0 to {n_items}, "
                          f"found shape {ptr.shape}")


@dataclass(frozen=True)
class _Sparse:
    """Per-Gaussian B (K, N, 10) stored Gaussian-major: rows of Gaussian i are ``ptr[i]:ptr[i+1]``, plus B_0."""

    base: np.ndarray  # (N, 10) float32
    ptr: np.ndarray  # (N + 1,) int64
    comp: np.ndarray  # (nnz,) int32 component index
    vals: np.ndarray  # (nnz, 10) float32

    def __post_init__(self) -> None:
        if self.base.ndim != 2 or self.base.shape[1] != _P or self.vals.ndim != 2 or self.vals.shape[1] != _P:
            raise AvatarError(f"base/vals: expected (N, {_P}) and (nnz, {_P}), found {self.base.shape} / "
                              f"{self.vals.shape}")
        if self.comp.shape != (self.vals.shape[0],):
            raise AvatarError("ptr/comp/vals: inconsistent sparse structure")
        try:
            _check_ptr(self.ptr, self.base.shape[0], self.comp.shape[0], "ptr")
        except AvatarError:
            raise AvatarError("ptr/comp/vals: inconsistent sparse structure") from None

    @property
    def n(self) -> int:
        return int(self.base.shape[0])

    @staticmethod
    def from_dense(base: np.ndarray, dense: np.ndarray, mask: np.ndarray) -> "_Sparse":
        """base (N, 10), dense (K, N, 10), mask (K, N) of kept entries."""
        gi, ki = np.nonzero(mask.T)  # Gaussian-major order
        ptr = np.zeros(mask.shape[1] + 1, np.int64)
        np.cumsum(np.bincount(gi, minlength=mask.shape[1]), out=ptr[1:])
        return _Sparse(np.ascontiguousarray(base, np.float32), ptr, ki.astype(np.int32),
                       np.ascontiguousarray(dense[ki, gi], np.float32))

    def blend_shapes(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        out = np.zeros((k, self.n, _P), np.float64)
        gi = np.repeat(np.arange(self.n), np.diff(self.ptr))
        out[self.comp, gi] = self.vals
        return self.base.astype(np.float64), out

    def arrays(self) -> dict[str, np.ndarray]:
        return {"base": self.base, "ptr": self.ptr, "comp": self.comp, "vals": self.vals}


def _expand_twist(f0: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """G_f: face twists (M, 7) ``[sigma, omega, dc]`` -> face-quantity derivatives (M, 17), float64."""
    m0 = f0[:, :9].reshape(-1, 3, 3).transpose(0, 2, 1)  # M_0 (row i, column j)
    sg, om = tau[:, 0], tau[:, 1:4]
    skew = np.zeros((tau.shape[0], 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -om[:, 2], om[:, 1], -om[:, 0]
    skew -= skew.transpose(0, 2, 1)
    dm = m0 @ (sg[:, None, None] * np.eye(3) + skew)
    dq = quat_multiply_np(f0[:, 12:16], np.concatenate([np.zeros((tau.shape[0], 1)), 0.5 * om], axis=1))
    return np.concatenate([dm.transpose(0, 2, 1).reshape(-1, 9), tau[:, 4:7], dq, sg[:, None]], axis=1)


def _apply_local(face_q: np.ndarray, local: np.ndarray, affine: bool) -> np.ndarray:
    """The per-Gaussian map A_i (float64): face quantities (M, 17) and local (M, 10) -> (M, 10).

    ``affine`` adds ``a_i = [0, 0, l_l]`` (for B_0; derivatives are the linear part only).
    """
    mat = face_q[:, :9].reshape(-1, 3, 3)  # rows = columns of M
    mean = np.einsum("nji,nj->ni", mat, local[:, :3]) + face_q[:, 9:12]
    quat = quat_multiply_np(face_q[:, 12:16], local[:, 3:7])
    ls = np.repeat(face_q[:, 16:17], 3, axis=1) + (local[:, 7:] if affine else 0.0)
    return np.concatenate([mean, quat, ls], axis=1)


@dataclass(frozen=True)
class _FaceBlend:
    """Face-factorised blend shapes (module docstring); Gaussians stored sorted by face."""

    f0: np.ndarray  # (F, 17) float32 face quantities at psi = 0
    fptr: np.ndarray  # (F + 1,) int64: entries of face f are fptr[f]:fptr[f+1]
    fcomp: np.ndarray  # (nnz,) int32 component index
    fvals: np.ndarray  # (nnz, 7) float32 face twist t_k = [sigma, omega, dc]
    local: np.ndarray  # (N, 10) float32 per Gaussian, sorted by face: [mu, q_l, l_l], or B_0 on static faces
    gptr: np.ndarray  # (F + 1,) int64: sorted Gaussians of face f are gptr[f]:gptr[f+1]
    perm: np.ndarray  # (N,) int64 original index of sorted Gaussian j, or (0,) when already sorted

    def __post_init__(self) -> None:
        nf, n = self.f0.shape[0], self.local.shape[0]
        if self.f0.ndim != 2 or self.f0.shape[1] != _Q or self.fvals.ndim != 2 or self.fvals.shape[1] != _T:
            raise AvatarError(f"f0/fvals: expected (F, {_Q}) and (nnz, {_T}), found {self.f0.shape} / "
                              f"{self.fvals.shape}")
        if self.local.ndim != 2 or self.local.shape[1] != _P:
            raise AvatarError(f"local: expected (N, {_P}), found {self.local.shape}")
        if self.fcomp.shape != (self.fvals.shape[0],):
            raise AvatarError(f"fcomp: expected ({self.fvals.shape[0]},), found {self.fcomp.shape}")
        _check_ptr(self.fptr, nf, self.fcomp.shape[0], "fptr")
        _check_ptr(self.gptr, nf, n, "gptr")
        if self.perm.shape not in ((0,), (n,)) or (
                self.perm.size and not np.array_equal(np.sort(self.perm), np.arange(n))):
            raise AvatarError(f"perm: expected a permutation of 0..{n - 1} (or empty), found shape {self.perm.shape}")

    @property
    def n(self) -> int:
        return int(self.local.shape[0])

    def static_gaussians(self) -> np.ndarray:
        """(N,) bool, sorted order: on a face without blend entries (``local`` holds its B_0 row)."""
        return (np.diff(self.fptr) == 0)[self.face_of_sorted()]

    def face_of_sorted(self) -> np.ndarray:
        return np.repeat(np.arange(self.f0.shape[0]), np.diff(self.gptr))

    def unsort(self, rows: np.ndarray) -> np.ndarray:
        """(..., N, c) rows in face-sorted order -> original Gaussian order."""
        if not self.perm.size:
            return rows
        out = np.empty_like(rows)
        out[..., self.perm, :] = rows
        return out

    @staticmethod
    def build(f0: np.ndarray, tau: np.ndarray, local: np.ndarray, binding: np.ndarray,
              drop_tol: float) -> "_FaceBlend":
        """From float64 F_0 (F, 17), face twists t_k (K, F, 7), local (N, 10) and the binding (N,).

        A (face, component) pair is kept when one of the face's Gaussians moves by at least
        ``drop_tol`` metres (mean) or ``1000 drop_tol`` (quaternion, log-scale) per unit coefficient.
        """
        nf = f0.shape[0]
        order = np.argsort(binding, kind="stable")
        sorted_ = bool(np.all(order == np.arange(order.shape[0])))
        loc = local[order]
        gptr = np.zeros(nf + 1, np.int64)
        np.cumsum(np.bincount(binding, minlength=nf), out=gptr[1:])
        face = binding[order]
        keep = np.zeros((tau.shape[0], nf), bool)
        for k in range(tau.shape[0]):
            d = _apply_local(_expand_twist(f0, tau[k])[face], loc, affine=False)
            big = (np.abs(d[:, :3]).max(1) >= drop_tol) | (np.abs(d[:, 3:]).max(1) >= 1e3 * drop_tol)
            keep[k] = np.bincount(face, weights=big, minlength=nf) > 0
        fi, ki = np.nonzero(keep.T)  # face-major
        fptr = np.zeros(nf + 1, np.int64)
        np.cumsum(np.bincount(fi, minlength=nf), out=fptr[1:])
        # static faces (no entries) do not move: store their Gaussians' B_0 rows, copied at evaluation
        static = (np.diff(fptr) == 0)[face]
        loc = loc.copy()
        loc[static] = _apply_local(f0[face[static]], loc[static], affine=True)
        return _FaceBlend(np.ascontiguousarray(f0, np.float32), fptr, ki.astype(np.int32),
                          np.ascontiguousarray(tau[ki, fi], np.float32), np.ascontiguousarray(loc, np.float32),
                          gptr, np.zeros(0, np.int64) if sorted_ else order.astype(np.int64))

    def base(self) -> np.ndarray:
        """Materialised B_0 (N, 10), float64, original Gaussian order."""
        loc = self.local.astype(np.float64)
        base = _apply_local(self.f0.astype(np.float64)[self.face_of_sorted()], loc, affine=True)
        static = self.static_gaussians()
        base[static] = loc[static]  # stored as is; B_k rows of static Gaussians are 0 (no entries on their faces)
        return self.unsort(base)

    def blend_shapes(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Materialised B_0 (N, 10) and B (K, N, 10), float64, original Gaussian order."""
        face = self.face_of_sorted()
        loc = self.local.astype(np.float64)
        dense = np.zeros((k, self.n, _P), np.float64)
        fi = np.repeat(np.arange(self.f0.shape[0]), np.diff(self.fptr))
        f0 = self.f0.astype(np.float64)
        for c in range(k):
            tau = np.zeros((self.f0.shape[0], _T), np.float64)
            sel = self.fcomp == c
            tau[fi[sel]] = self.fvals[sel]
            dense[c] = _apply_local(_expand_twist(f0, tau)[face], loc, affine=False)
        return self.base(), self.unsort(dense)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"f0": self.f0, "fptr": self.fptr, "fcomp": self.fcomp, "fvals": self.fvals, "local": self.local,
                "gptr": self.gptr, "perm": self.perm}


def _kernels() -> Any:
    try:
        from . import _blend_kernel
    except ImportError:
        return None
    return _blend_kernel


class BlendshapeAvatar:
    """Linear Gaussian blend shapes over expression (and optionally jaw) coefficients.

    Build with :meth:`from_rigged`; evaluate with :meth:`pose` / :meth:`blend_tensors`;
    persist with :meth:`save` / :meth:`load`.

    Attributes
    ----------
    n_components : int
        K coefficients: ``n_expr`` expression components (+ 3 jaw axis-angle ones).
    n_expr : int
        Expression components.
    has_jaw : bool
        Jaw pose is part of the coefficients (last three).
    root : numpy.ndarray
        (3,) root joint J_0 at the linearisation point (centre of global rotation).
    representation : str
        ``"faces"`` (face-factorised B, the default) or ``"gaussians"`` (per-Gaussian sparse B:
        ``exact_jvp`` avatars and v1 files).
    backend : str
        ``"auto"`` (numba kernel when available) or ``"torch"`` (dense product reference).
    """

    def __init__(self, blend: _FaceBlend | _Sparse, n_expr: int, has_jaw: bool, opacity_logits: np.ndarray,
                 sh: np.ndarray, root: np.ndarray, expression_names: list[str] | None = None) -> None:
        self._blend = blend
        self.n_expr = int(n_expr)
        self.has_jaw = bool(has_jaw)
        self.n_components = self.n_expr + (3 if has_jaw else 0)
        self.representation = "faces" if isinstance(blend, _FaceBlend) else "gaussians"
        self._opacity = torch.as_tensor(np.ascontiguousarray(opacity_logits, np.float32))
        self._sh = torch.as_tensor(np.ascontiguousarray(sh, np.float32))
        self.root = np.asarray(root, np.float64)
        self.expression_names = expression_names
        self.backend = "auto"
        self._dense: tuple[torch.Tensor, torch.Tensor] | None = None
        n = blend.n
        if self._opacity.shape[0] != n or self._sh.shape[0] != n:
            raise AvatarError(f"BlendshapeAvatar: inconsistent sizes ({n} Gaussians, opacity "
                              f"{self._opacity.shape[0]}, sh {self._sh.shape[0]})")
        comp = blend.fcomp if isinstance(blend, _FaceBlend) else blend.comp
        if comp.size and (comp.min() < 0 or comp.max() >= self.n_components):
            raise AvatarError(f"BlendshapeAvatar: component indices outside [0, {self.n_components})")

    def __len__(self) -> int:
        return self._blend.n

    @property
    def nnz(self) -> int:
        """Stored (face, component) pairs (``"faces"``) or (Gaussian, component) pairs (``"gaussians"``)."""
        b = self._blend
        return int((b.fcomp if isinstance(b, _FaceBlend) else b.comp).shape[0])

    @property
    def base(self) -> np.ndarray:
        """(N, 10) float32 ``B_0`` = [mean, quat, log_scale] at zero coefficients."""
        b = self._blend
        return b.base if isinstance(b, _Sparse) else b.base().astype(np.float32)

    def blend_shapes(self) -> tuple[np.ndarray, np.ndarray]:
        """Materialised ``B_0`` (N, 10) and ``B`` (K, N, 10), float64, per Gaussian (slow; reference)."""
        return self._blend.blend_shapes(self.n_components)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_rigged(cls, rigged: RiggedAvatar, n_expr: int | None = None, include_jaw: bool = False,
                    drop_tol: float = 1e-7, exact_jvp: bool = False) -> "BlendshapeAvatar":
        """Linearise a rigged avatar at zero expression and pose (forward-mode AD, float64).

        Parameters
        ----------
        rigged : RiggedAvatar
            Its ``identity`` (shape, static offsets) is kept fixed.
        n_expr : int, optional
            Expression components to linearise (default: all the model keeps).
        include_jaw : bool
            Also linearise the jaw pose (3 coefficients appended after the expression ones).
        drop_tol : float
            Per (face, component): dropped when every Gaussian of the face moves by less than
            ``drop_tol`` metres (mean) and ``1000 drop_tol`` (quaternion, log-scale) per unit
            coefficient (per (Gaussian, component) with ``exact_jvp``).
        exact_jvp : bool
            Differentiate the whole per-Gaussian pipeline with ``torch.func.jvp`` and store a
            per-Gaussian sparse B (slow reference). Default: differentiate the per-face
            quantities by ``jvp`` and store B factored through the faces (same derivative).
        """
        model = rigged.flame_model
        k_expr = int(model.n_expr if n_expr is None else n_expr)
        if not 0 <= k_expr <= model.n_expr:
            raise InputError(f"n_expr: expected 0..{model.n_expr}, found {n_expr}")
        m64 = copy.deepcopy(model).to(torch.float64)
        av64 = RiggedAvatar(m64, rigged.local.replace(extra={}), binding=rigged.binding,
                            identity=rigged.identity)
        av64.backend = "torch"
        ident = {k: v for k, v in rigged.identity.items()}
        with torch.no_grad():
            root = m64(**ident).joints[0, 0].numpy()
        loc = rigged.local
        if exact_jvp:
            blend: _FaceBlend | _Sparse = _linearise_exact(m64, av64, ident, k_expr, include_jaw, drop_tol)
        else:
            f0, tau = _face_jets(m64, av64, ident, k_expr, include_jaw)
            lq = av64.local
            ql = lq.quats.detach().numpy()
            local = np.concatenate([lq.means.detach().numpy(), ql / np.linalg.norm(ql, axis=1, keepdims=True),
                                    lq.log_scales.detach().numpy()], axis=1)
            blend = _FaceBlend.build(f0, tau, local, av64.binding.numpy(), drop_tol)
        return cls(blend, k_expr, include_jaw, loc.opacity_logits.detach().cpu().numpy(),
                   loc.sh.detach().cpu().numpy(), root, (model.expression_names or [])[:k_expr] or None)

    # ------------------------------------------------------------------ evaluation
    def _coefficients(self, expr: Any, jaw_pose: Any) -> np.ndarray:
        e = np.asarray(expr.detach().cpu().numpy() if isinstance(expr, torch.Tensor) else expr, np.float32)
        if e.ndim == 1:
            e = e[None]
        if e.ndim != 2 or e.shape[1] > self.n_expr:
            raise InputError(f"expr: expected shape (K,) or (T, K) with K <= {self.n_expr}, found {e.shape}")
        if not np.isfinite(e).all():
            raise InputError("expr: expected finite values, found NaN/inf")
        if self.has_jaw:
            j = np.zeros((1, 3), np.float32) if jaw_pose is None else np.asarray(jaw_pose, np.float32)
            if j.ndim == 1:
                j = j[None]
            if j.ndim != 2 or j.shape[1] != 3 or j.shape[0] not in (1, e.shape[0]) or not np.isfinite(j).all():
                raise InputError(f"jaw_pose: expected finite (3,) or ({e.shape[0]}, 3), found {j.shape}")
        elif jaw_pose is not None and np.any(np.asarray(jaw_pose) != 0):
            raise InputError("jaw_pose: this blend-shape avatar was built without jaw components "
                             "(BlendshapeAvatar.from_rigged(..., include_jaw=True))")
        if e.shape[1] == self.n_components:
            return np.ascontiguousarray(e)
        out = np.zeros((e.shape[0], self.n_components), np.float32)
        out[:, :e.shape[1]] = e
        if self.has_jaw:
            out[:, self.n_expr:] = j
        return out

    def blend_tensors(self, expr: Any, jaw_pose: Any = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Blended means (T, N, 3), quats (T, N, 4, unnormalised) and log-scales (T, N, 3), float32."""
        coeffs = self._coefficients(expr, jaw_pose)
        t, n = coeffs.shape[0], len(self)
        kern = _kernels() if self.backend == "auto" else None
        if kern is None:
            return self._blend_dense(coeffs)
        # one allocation, three contiguous (T, N, c) tensors
        buf = torch.empty(t * n * _P, dtype=torch.float32)
        means = buf[:t * n * 3].view(t, n, 3)
        quats = buf[t * n * 3:t * n * 7].view(t, n, 4)
        log_scales = buf[t * n * 7:].view(t, n, 3)
        b = self._blend
        if isinstance(b, _FaceBlend):
            for i in range(t):
                kern.blend_faces_nb(b.f0, b.fptr, b.fcomp, b.fvals, coeffs[i], b.gptr, b.local, b.perm,
                                    means[i].numpy(), quats[i].numpy(), log_scales[i].numpy())
        else:
            for i in range(t):
                kern.blend_nb(b.base, b.ptr, b.comp, b.vals, coeffs[i], means[i].numpy(), quats[i].numpy(),
                              log_scales[i].numpy())
        return means, quats, log_scales

    def _blend_dense(self, coeffs: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reference: the dense product ``[1, psi] @ [B_0; B]`` (torch addmm, float32)."""
        if self._dense is None:
            base, dense = self.blend_shapes()
            self._dense = (torch.as_tensor(base.astype(np.float32)).reshape(1, -1),
                           torch.as_tensor(dense.astype(np.float32)).reshape(self.n_components, -1))
        flat = torch.addmm(self._dense[0], torch.as_tensor(coeffs), self._dense[1]).reshape(coeffs.shape[0], -1, _P)
        return flat[..., :3], flat[..., 3:7], flat[..., 7:]

    def pose(self, expr: Any, jaw_pose: Any = None, rotation: Any = None,
             translation: Any = None) -> Gaussians | list[Gaussians]:
        """World Gaussians for expression coefficients.

        Parameters
        ----------
        expr : array-like
            (K,) or (T, K) expression coefficients (K <= n_expr; missing ones are 0).
        jaw_pose : array-like, optional
            (3,) or (T, 3) axis-angle, only for avatars built with ``include_jaw``.
        rotation, translation : array-like, optional
            (3,) global head rotation (axis-angle about the root joint) and translation, applied exactly.

        Returns
        -------
        Gaussians or list of Gaussians
            Torch float32; one for T == 1, else a list.
        """
        means, quats, log_scales = self.blend_tensors(expr, jaw_pose)
        if rotation is not None or translation is not None:
            means, quats = self._rigid(means, quats, rotation, translation)
        out = [Gaussians(means[i], quats[i], log_scales[i], self._opacity, self._sh) for i in range(means.shape[0])]
        return out[0] if len(out) == 1 else out

    def _rigid(self, means: torch.Tensor, quats: torch.Tensor, rotation: Any,
               translation: Any) -> tuple[torch.Tensor, torch.Tensor]:
        from ..geometry import rodrigues

        r = torch.as_tensor(np.zeros(3) if rotation is None else np.asarray(rotation, np.float64).reshape(-1, 3))
        t = torch.as_tensor(np.zeros(3) if translation is None else np.asarray(translation, np.float64).reshape(-1, 3))
        if r.shape[0] not in (1, means.shape[0]) or t.shape[0] not in (1, means.shape[0]):
            raise InputError(f"rotation/translation: expected (3,) or ({means.shape[0]}, 3), found "
                             f"{tuple(r.shape)} / {tuple(t.shape)}")
        rot = rodrigues(r.reshape(-1, 3)).to(torch.float32)  # (T|1, 3, 3)
        j0 = torch.as_tensor(self.root, dtype=torch.float32)
        means = (means - j0) @ rot.transpose(-1, -2) + j0 + t.reshape(-1, 1, 3).to(torch.float32)
        from ..geometry import rotmat_to_quat

        rq = rotmat_to_quat(rot)[:, None, :].expand_as(quats)
        return means, quat_multiply(rq, quats)

    # ------------------------------------------------------------------ I/O
    def save(self, path: str | os.PathLike) -> Path:
        """Write an npz (atomic): the blend arrays, opacity, SH, root, names, format tag."""
        names = np.array(self.expression_names or [], dtype=str)
        fmt = _FORMAT if isinstance(self._blend, _FaceBlend) else _FORMAT_V1
        return save_npz(path, format=np.array(fmt), **self._blend.arrays(), n_expr=np.array(self.n_expr),
                        has_jaw=np.array(self.has_jaw), opacity_logits=self._opacity.numpy(), sh=self._sh.numpy(),
                        root=self.root, expression_names=names)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "BlendshapeAvatar":
        """Read :meth:`save` output (v2, or v1 per-Gaussian files); raises AvatarError naming the file and key."""
        path = Path(path)
        data = read_npz(path, AvatarError, "blend-shape avatar")
        fmt = str(data["format"]) if "format" in data else None
        if fmt is not None and fmt not in (_FORMAT, _FORMAT_V1):
            raise AvatarError(f"{path}: format: expected {_FORMAT!r} (or {_FORMAT_V1!r}), found {fmt!r}")
        blend_keys = ("base", "ptr", "comp", "vals") if fmt == _FORMAT_V1 else (
            "f0", "fptr", "fcomp", "fvals", "local", "gptr", "perm")
        keys = ("format",) + blend_keys + ("n_expr", "has_jaw", "opacity_logits", "sh", "root")
        missing = [k for k in keys if k not in data]
        if missing:
            raise AvatarError(f"{path}: missing keys {missing}; expected a file written by BlendshapeAvatar.save")
        floats = ("base", "vals") if fmt == _FORMAT_V1 else ("f0", "fvals", "local")
        for k in floats + ("opacity_logits", "sh", "root"):
            if data[k].dtype.kind != "f" or not np.all(np.isfinite(data[k])):
                raise AvatarError(f"{path}: {k}: holds NaN/inf (or is not floating point)")
        names = [str(s) for s in data.get("expression_names", np.array([], dtype=str))] or None
        try:
            if fmt == _FORMAT_V1:
                blend: _FaceBlend | _Sparse = _Sparse(
                    np.ascontiguousarray(data["base"], np.float32), data["ptr"].astype(np.int64),
                    data["comp"].astype(np.int32), np.ascontiguousarray(data["vals"], np.float32))
            else:
                blend = _FaceBlend(np.ascontiguousarray(data["f0"], np.float32), data["fptr"].astype(np.int64),
                                   data["fcomp"].astype(np.int32), np.ascontiguousarray(data["fvals"], np.float32),
                                   np.ascontiguousarray(data["local"], np.float32), data["gptr"].astype(np.int64),
                                   data["perm"].astype(np.int64))
            return cls(blend, int(data["n_expr"]), bool(data["has_jaw"]), data["opacity_logits"], data["sh"],
                       data["root"], names)
        except AvatarError as exc:
            raise AvatarError(f"{path}: {exc}") from None


def _face_jets(m64: Any, av64: RiggedAvatar, ident: dict[str, Any], k_expr: int,
               include_jaw: bool) -> tuple[np.ndarray, np.ndarray]:
    """Face quantities F_0 (F, 17) and face twists t_k (K, F, 7), float64 (forward-mode AD).

    ``f = [s R column-major, c, q(R), log s]``; ``t = [ds / s, omega, dc]`` with ``[omega]_x``
    the skew part of ``R^T dR`` (exactly skew for the orthonormal face frame). The jvp of the
    quaternion is not needed: ``dq = q (x) (0, omega / 2)`` (tested against the full jvp).
    """
    from .binding import face_frames
    from ..geometry import rotmat_to_quat

    faces = av64.faces
    n_e = m64.n_expr
    k_tot = k_expr + (3 if include_jaw else 0)

    def face_params(coeffs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        kw: dict[str, Any] = dict(ident)
        kw["expr"] = torch.nn.functional.pad(coeffs[:k_expr], (0, n_e - k_expr))[None]
        if include_jaw:
            kw["jaw_pose"] = coeffs[k_expr:][None]
        verts = m64(**kw).vertices
        rot, scale, centre, _ = face_frames(verts, faces)
        return rot[0], scale[0], centre[0], rotmat_to_quat(rot[0])

    def pack(m: np.ndarray, c: np.ndarray, q: np.ndarray, ls: np.ndarray) -> np.ndarray:
        return np.concatenate([m.transpose(0, 2, 1).reshape(-1, 9), c, q, ls[:, None]], axis=1)

    zero = torch.zeros(k_tot, dtype=torch.float64)
    with torch.no_grad():
        rot, scale, centre, fq = (t.numpy() for t in face_params(zero))
    f0 = pack(scale[:, None, None] * rot, centre, fq, np.log(scale))
    tau = np.zeros((k_tot, f0.shape[0], _T), np.float64)
    for k in range(k_tot):
        tangent = torch.zeros(k_tot, dtype=torch.float64)
        tangent[k] = 1.0
        _, (d_rot, d_scale, d_centre, _) = torch.func.jvp(face_params, (zero,), (tangent,))
        om = rot.transpose(0, 2, 1) @ d_rot.numpy()
        omega = 0.5 * np.stack([om[:, 2, 1] - om[:, 1, 2], om[:, 0, 2] - om[:, 2, 0], om[:, 1, 0] - om[:, 0, 1]], 1)
        tau[k] = np.concatenate([(d_scale.numpy() / scale)[:, None], omega, d_centre.numpy()], axis=1)
    return f0, tau


def _linearise_exact(m64: Any, av64: RiggedAvatar, ident: dict[str, Any], k_expr: int, include_jaw: bool,
                     drop_tol: float) -> _Sparse:
    """Reference: forward-mode AD through the whole per-Gaussian pipeline; per-Gaussian sparse B."""
    n_e = m64.n_expr
    k_tot = k_expr + (3 if include_jaw else 0)

    def params_of(coeffs: torch.Tensor) -> torch.Tensor:
        kw: dict[str, Any] = dict(ident)
        kw["expr"] = torch.nn.functional.pad(coeffs[:k_expr], (0, n_e - k_expr))[None]
        if include_jaw:
            kw["jaw_pose"] = coeffs[k_expr:][None]
        m, q, s = av64.deform_tensors(m64(**kw).vertices)
        return torch.cat([m[0], q[0], s[0]], dim=-1)  # (N, 10)

    zero = torch.zeros(k_tot, dtype=torch.float64)
    with torch.no_grad():
        base = params_of(zero).numpy()
    dense = np.zeros((k_tot, base.shape[0], _P), np.float32)
    for k in range(k_tot):
        tangent = torch.zeros(k_tot, dtype=torch.float64)
        tangent[k] = 1.0
        _, d = torch.func.jvp(params_of, (zero,), (tangent,))
        dense[k] = d.numpy()
    mask = (np.abs(dense[..., :3]).max(-1) >= drop_tol) | (np.abs(dense[..., 3:]).max(-1) >= 1e3 * drop_tol)
    return _Sparse.from_dense(base, dense, mask)
