"""Blend-shape Gaussian avatar (the seed paper, Fig. 2): Gaussians as a linear function of expression.

Per Gaussian the primitive parameters ``p = [mean (3), quat (4), log_scale (3)]`` are blended::

    B*(psi) = B_0 + sum_k psi_k B_k

with ``B_0`` the rigged avatar at ``psi = 0`` (identity shape, zero pose) and ``B_k`` the
**analytic** first derivative ``d p / d psi_k`` at ``psi = 0``, obtained by forward-mode
automatic differentiation (``torch.func.jvp``) of the rigged avatar (FLAME expression blend
shapes + LBS + triangle binding) in float64. Optionally the jaw pose (3 axis-angle
components) is linearised the same way and appended to the coefficients. Opacity and SH are
constant. Quaternions come out unnormalised (renderers normalise them).

Global head rotation and translation are applied exactly afterwards as the rigid motion FLAME
gives them (rotation about the root joint ``J_0``, then translation).

Evaluation is one sparse matrix product: ``[1, psi] @ [B_0; B]`` with ``B`` stored sparse
(entries whose parameters move by less than ``drop_tol`` per unit coefficient are dropped;
with localised expression components most Gaussians depend on only a few coefficients).
A numba kernel evaluates it Gaussian by Gaussian; the dense torch product is the reference
(and the fallback without numba). The approximation is exact at ``psi = 0`` and first-order
accurate near it; ``bench/deform_tradeoff.py`` measures its error against the rigged avatar.
"""

from __future__ import annotations

import copy
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import AvatarError, InputError
from ..fileio import save_npz
from ..geometry import quat_multiply
from .gaussians import Gaussians
from .rigged import RiggedAvatar

__all__ = ["BlendshapeAvatar"]

_P = 10  # parameters per Gaussian: mean 3, quat 4, log-scale 3
_FORMAT = "holo_viewer.blendshape_avatar.v1"


@dataclass(frozen=True)
class _Sparse:
    """B (K, N, 10) stored Gaussian-major: rows of Gaussian i are ``ptr[i]:ptr[i+1]``."""

    ptr: np.ndarray  # (N + 1,) int64
    comp: np.ndarray  # (nnz,) int32 component index
    vals: np.ndarray  # (nnz, 10) float32

    @staticmethod
    def from_dense(dense: np.ndarray, mask: np.ndarray) -> "_Sparse":
        """dense (K, N, 10), mask (K, N) of kept entries."""
        gi, ki = np.nonzero(mask.T)  # Gaussian-major order
        ptr = np.zeros(mask.shape[1] + 1, np.int64)
        np.cumsum(np.bincount(gi, minlength=mask.shape[1]), out=ptr[1:])
        return _Sparse(ptr, ki.astype(np.int32), np.ascontiguousarray(dense[ki, gi], np.float32))

    def to_dense(self, k: int) -> np.ndarray:
        n = self.ptr.shape[0] - 1
        out = np.zeros((k, n, _P), np.float32)
        gi = np.repeat(np.arange(n), np.diff(self.ptr))
        out[self.comp, gi] = self.vals
        return out


def _kernel() -> Any:
    try:
        from ._blend_kernel import blend_nb
    except ImportError:
        return None
    return blend_nb


class BlendshapeAvatar:
    """Linear Gaussian blend shapes over expression (and optionally jaw) coefficients.

    Build with :meth:`from_rigged`; evaluate with :meth:`pose`; persist with :meth:`save` /
    :meth:`load`.

    Attributes
    ----------
    base : numpy.ndarray
        (N, 10) float32 ``B_0`` = [mean, quat, log_scale] at zero coefficients.
    n_components : int
        K coefficients: ``n_expr`` expression components (+ 3 jaw axis-angle ones).
    n_expr : int
        Expression components.
    has_jaw : bool
        Jaw pose is part of the coefficients (last three).
    root : numpy.ndarray
        (3,) root joint J_0 at the linearisation point (centre of global rotation).
    """

    def __init__(self, base: np.ndarray, sparse: _Sparse, n_expr: int, has_jaw: bool, opacity_logits: np.ndarray,
                 sh: np.ndarray, root: np.ndarray, expression_names: list[str] | None = None) -> None:
        self.base = np.ascontiguousarray(base, np.float32)
        self._sparse = sparse
        self.n_expr = int(n_expr)
        self.has_jaw = bool(has_jaw)
        self.n_components = self.n_expr + (3 if has_jaw else 0)
        self._opacity = torch.as_tensor(np.ascontiguousarray(opacity_logits, np.float32))
        self._sh = torch.as_tensor(np.ascontiguousarray(sh, np.float32))
        self.root = np.asarray(root, np.float64)
        self.expression_names = expression_names
        self.backend = "auto"  # "auto" (numba when available) or "torch" (dense product reference)
        self._dense: torch.Tensor | None = None
        n = self.base.shape[0]
        if sparse.ptr.shape[0] != n + 1 or self._opacity.shape[0] != n or self._sh.shape[0] != n:
            raise AvatarError(f"BlendshapeAvatar: inconsistent sizes (base {n}, ptr {sparse.ptr.shape[0] - 1}, "
                              f"opacity {self._opacity.shape[0]}, sh {self._sh.shape[0]})")
        if sparse.comp.size and (sparse.comp.min() < 0 or sparse.comp.max() >= self.n_components):
            raise AvatarError(f"BlendshapeAvatar: component indices outside [0, {self.n_components})")

    def __len__(self) -> int:
        return int(self.base.shape[0])

    @property
    def nnz(self) -> int:
        """Stored (Gaussian, component) pairs."""
        return int(self._sparse.comp.shape[0])

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
            Entries whose mean moves by less than ``drop_tol`` metres and whose quaternion and
            log-scale change by less than ``1000 drop_tol`` per unit coefficient are dropped.
        exact_jvp : bool
            Differentiate the whole per-Gaussian pipeline with ``torch.func.jvp`` (slow reference).
            Default: differentiate the per-face frames (rotation, quaternion, scale, centre) by
            ``jvp`` and apply the chain rule per Gaussian in closed form (same derivative).
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
        k_tot = k_expr + (3 if include_jaw else 0)

        def params_of(coeffs: torch.Tensor) -> torch.Tensor:
            kw: dict[str, Any] = dict(ident)
            expr = torch.zeros(1, model.n_expr, dtype=torch.float64)
            expr = expr + torch.nn.functional.pad(coeffs[:k_expr], (0, model.n_expr - k_expr))[None]
            kw["expr"] = expr
            if include_jaw:
                kw["jaw_pose"] = coeffs[k_expr:][None]
            verts = m64(**kw).vertices
            m, q, s = av64.deform_tensors(verts)
            return torch.cat([m[0], q[0], s[0]], dim=-1)  # (N, 10)

        zero = torch.zeros(k_tot, dtype=torch.float64)
        with torch.no_grad():
            root = m64(**ident).joints[0, 0].numpy()
        if exact_jvp:  # reference: forward-mode AD through the whole rigged avatar
            with torch.no_grad():
                base = params_of(zero).numpy()
            n = base.shape[0]
            dense = np.zeros((k_tot, n, _P), np.float32)
            for k in range(k_tot):
                tangent = torch.zeros(k_tot, dtype=torch.float64)
                tangent[k] = 1.0
                _, d = torch.func.jvp(params_of, (zero,), (tangent,))
                dense[k] = d.numpy()
        else:
            base, dense = _linearise_by_faces(m64, av64, ident, k_expr, include_jaw)
        mask = (np.abs(dense[..., :3]).max(-1) >= drop_tol) | (np.abs(dense[..., 3:]).max(-1) >= 1e3 * drop_tol)
        loc = rigged.local
        return cls(base, _Sparse.from_dense(dense, mask), k_expr, include_jaw,
                   loc.opacity_logits.detach().cpu().numpy(), loc.sh.detach().cpu().numpy(), root,
                   (model.expression_names or [])[:k_expr] or None)

    # ------------------------------------------------------------------ evaluation
    def _coefficients(self, expr: Any, jaw_pose: Any) -> np.ndarray:
        e = np.asarray(expr.detach().cpu().numpy() if isinstance(expr, torch.Tensor) else expr, np.float32)
        if e.ndim == 1:
            e = e[None]
        if e.ndim != 2 or e.shape[1] > self.n_expr:
            raise InputError(f"expr: expected shape (K,) or (T, K) with K <= {self.n_expr}, found {e.shape}")
        if not np.all(np.isfinite(e)):
            raise InputError("expr: expected finite values, found NaN/inf")
        e = np.pad(e, ((0, 0), (0, self.n_expr - e.shape[1])))
        if self.has_jaw:
            j = np.zeros((e.shape[0], 3), np.float32) if jaw_pose is None else np.asarray(jaw_pose, np.float32)
            if j.ndim == 1:
                j = j[None]
            if j.shape[1] != 3 or j.shape[0] not in (1, e.shape[0]) or not np.all(np.isfinite(j)):
                raise InputError(f"jaw_pose: expected finite (3,) or ({e.shape[0]}, 3), found {j.shape}")
            e = np.concatenate([e, np.broadcast_to(j, (e.shape[0], 3))], axis=1)
        elif jaw_pose is not None and np.any(np.asarray(jaw_pose) != 0):
            raise InputError("jaw_pose: this blend-shape avatar was built without jaw components "
                             "(BlendshapeAvatar.from_rigged(..., include_jaw=True))")
        return np.ascontiguousarray(e)

    def blend_tensors(self, expr: Any, jaw_pose: Any = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Blended means (T, N, 3), quats (T, N, 4, unnormalised) and log-scales (T, N, 3), float32."""
        coeffs = self._coefficients(expr, jaw_pose)
        t, n = coeffs.shape[0], len(self)
        kern = _kernel() if self.backend == "auto" else None
        if kern is None:
            if self._dense is None:
                self._dense = torch.as_tensor(self._sparse.to_dense(self.n_components).reshape(self.n_components, -1))
            flat = torch.addmm(torch.as_tensor(self.base).reshape(1, -1), torch.as_tensor(coeffs), self._dense)
            flat = flat.reshape(t, n, _P)
            return flat[..., :3], flat[..., 3:7], flat[..., 7:]
        means, quats, log_scales = (torch.empty((t, n, c), dtype=torch.float32) for c in (3, 4, 3))
        sp = self._sparse
        for i in range(t):
            kern(self.base, sp.ptr, sp.comp, sp.vals, coeffs[i], means[i].numpy(), quats[i].numpy(),
                 log_scales[i].numpy())
        return means, quats, log_scales

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
        from ..flame.rotation import rodrigues

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
        """Write an npz (atomic): B_0, the sparse B, opacity, SH, root, names, format tag."""
        names = np.array(self.expression_names or [], dtype=str)
        return save_npz(path, format=np.array(_FORMAT), base=self.base, ptr=self._sparse.ptr, comp=self._sparse.comp,
                        vals=self._sparse.vals, n_expr=np.array(self.n_expr), has_jaw=np.array(self.has_jaw),
                        opacity_logits=self._opacity.numpy(), sh=self._sh.numpy(), root=self.root,
                        expression_names=names)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "BlendshapeAvatar":
        """Read :meth:`save` output; raises AvatarError naming the file and the key."""
        path = Path(path)
        keys = ("format", "base", "ptr", "comp", "vals", "n_expr", "has_jaw", "opacity_logits", "sh", "root")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise AvatarError(f"{path}: cannot read blend-shape avatar ({exc})") from None
        missing = [k for k in keys if k not in data]
        if missing:
            raise AvatarError(f"{path}: missing keys {missing}; expected a file written by BlendshapeAvatar.save")
        if str(data["format"]) != _FORMAT:
            raise AvatarError(f"{path}: format: expected {_FORMAT!r}, found {str(data['format'])!r}")
        base, vals = data["base"], data["vals"]
        if base.ndim != 2 or base.shape[1] != _P or vals.ndim != 2 or vals.shape[1] != _P:
            raise AvatarError(f"{path}: base/vals: expected (N, {_P}) and (nnz, {_P}), found {base.shape} / {vals.shape}")
        ptr, comp = data["ptr"].astype(np.int64), data["comp"].astype(np.int32)
        if (ptr.shape != (base.shape[0] + 1,) or ptr[0] != 0 or np.any(np.diff(ptr) < 0)
                or ptr[-1] != comp.shape[0] or comp.shape[0] != vals.shape[0]):
            raise AvatarError(f"{path}: ptr/comp/vals: inconsistent sparse structure")
        for k in ("base", "vals", "opacity_logits", "sh", "root"):
            if not np.all(np.isfinite(data[k])):
                raise AvatarError(f"{path}: {k}: holds NaN/inf")
        names = [str(s) for s in data.get("expression_names", np.array([], dtype=str))] or None
        try:
            return cls(base, _Sparse(ptr, comp, np.ascontiguousarray(vals, np.float32)), int(data["n_expr"]),
                       bool(data["has_jaw"]), data["opacity_logits"], data["sh"], data["root"], names)
        except AvatarError as exc:
            raise AvatarError(f"{path}: {exc}") from None


def _linearise_by_faces(m64: Any, av64: RiggedAvatar, ident: dict[str, Any], k_expr: int,
                        include_jaw: bool) -> tuple[np.ndarray, np.ndarray]:
    """B_0 (N, 10) and dense B (K, N, 10), float64 face-level jvp + closed-form chain rule.

    With x = s R mu + c, q = q_f (x) q_l, l = l_l + log s per Gaussian::

        dx = ds R mu + s dR mu + dc,   dq = dq_f (x) q_l,   dl = ds / s
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

    zero = torch.zeros(k_tot, dtype=torch.float64)
    with torch.no_grad():
        rot, scale, centre, fq = (t.numpy() for t in face_params(zero))
    b = av64.binding.numpy()
    loc = av64.local
    mu = loc.means.detach().double().numpy()
    ql = loc.quats.detach().double().numpy()
    ql = ql / np.linalg.norm(ql, axis=1, keepdims=True)
    from ..geometry import quat_multiply_np

    rmu = np.einsum("nij,nj->ni", rot[b], mu)  # R mu
    base = np.concatenate([scale[b, None] * rmu + centre[b], quat_multiply_np(fq[b], ql),
                           loc.log_scales.detach().double().numpy() + np.log(scale[b])[:, None]], axis=1)
    dense = np.zeros((k_tot, b.shape[0], _P), np.float32)
    for k in range(k_tot):
        tangent = torch.zeros(k_tot, dtype=torch.float64)
        tangent[k] = 1.0
        _, (d_rot, d_scale, d_centre, d_q) = torch.func.jvp(face_params, (zero,), (tangent,))
        d_rot, d_scale, d_centre, d_q = d_rot.numpy(), d_scale.numpy(), d_centre.numpy(), d_q.numpy()
        moved = np.flatnonzero((np.abs(d_rot).reshape(len(d_scale), -1).max(1) > 0) | (d_scale != 0)
                               | (np.abs(d_centre).max(1) > 0))
        sel = np.flatnonzero(np.isin(b, moved))
        bs_ = b[sel]
        dx = (d_scale[bs_, None] * rmu[sel] + scale[bs_, None] * np.einsum("nij,nj->ni", d_rot[bs_], mu[sel])
              + d_centre[bs_])
        dq = quat_multiply_np(d_q[bs_], ql[sel])
        dl = np.repeat((d_scale[bs_] / scale[bs_])[:, None], 3, axis=1)
        dense[k, sel] = np.concatenate([dx, dq, dl], axis=1)
    return base, dense
