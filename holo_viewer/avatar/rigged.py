"""Rigged Gaussian avatar (GaussianAvatars): Gaussians bound to the triangles of a FLAME mesh.

:class:`RiggedAvatar` wraps a :class:`~holo_viewer.flame.model.FlameModel` and Gaussians in
triangle-local coordinates (see :mod:`holo_viewer.avatar.binding` for the formulas and the
degenerate-face fallback). ``deform`` maps posed mesh vertices to world Gaussians, ``pose``
runs FLAME first.

Batching: ``deform`` accepts (B, V, 3) vertices. For B == 1 it returns one
:class:`~holo_viewer.avatar.gaussians.Gaussians`; for B > 1 a list of B of them (each
backed by torch tensors; opacity and SH tensors are shared with the avatar, not copied).
:meth:`RiggedAvatar.deform_tensors` returns the raw batched (B, N, ...) tensors.

Caching: ``deform(..., cache=True)`` remembers, per face, the vertex positions the face's
Gaussians were last computed from and recomputes only Gaussians whose face has a vertex
that moved by more than ``cache_tol`` metres (per coordinate) since then; the others are
reused. With ``cache_tol = 0`` the result equals the uncached one exactly; a positive
tolerance trades a bounded error (stale Gaussians of faces that moved < tol) for speed.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from torch import Tensor

from ..errors import AvatarError, InputError
from ..validation import check_array
from .binding import DEGENERATE_EPS, bind_to_world, face_frames
from .gaussians import Gaussians

__all__ = ["RiggedAvatar"]

#: When more than this fraction of faces moved, a cached deform recomputes everything.
_CACHE_FULL_FRACTION = 0.6


def _kernels() -> Any:
    """The numba kernels module, or None when numba is not installed."""
    try:
        from . import _bind_kernels
    except ImportError:  # numba missing: torch path
        return None
    return _bind_kernels


def _binding_from(local: Gaussians, binding: Any, n_faces: int, context: str) -> Tensor:
    if binding is None:
        for key in ("binding", "binding_0"):
            if key in local.extra:
                binding = local.extra[key]
                break
        else:
            raise AvatarError(f"{context}: expected a binding (argument, or extra 'binding' / 'binding_0'), found none")
    b = binding.detach().cpu().numpy() if isinstance(binding, Tensor) else np.asarray(binding)
    if b.ndim != 1 or b.shape[0] != len(local):
        raise AvatarError(f"{context}: binding: expected shape ({len(local)},), found {b.shape}")
    if b.dtype.kind == "f":
        if not np.all(np.isfinite(b)) or np.any(b != np.round(b)):
            bad = np.flatnonzero(~np.isfinite(b) | (b != np.round(b)))
            raise AvatarError(f"{context}: binding: expected integer face indices, found non-integers at "
                              f"{bad[:8].tolist()}")
    b = b.astype(np.int64)
    if b.size and (b.min() < 0 or b.max() >= n_faces):
        bad = np.flatnonzero((b < 0) | (b >= n_faces))
        raise AvatarError(f"{context}: binding: expected face indices in [0, {n_faces}), found "
                          f"{b[bad[:5]].tolist()} at Gaussians {bad[:5].tolist()} (max {int(b.max())}); a "
                          "GaussianAvatars PLY needs the FLAME model loaded with add_teeth=True")
    return torch.as_tensor(b)


class RiggedAvatar:
    """Gaussians bound to FLAME triangles.

    Parameters
    ----------
    flame_model : FlameModel
        The mesh model (its ``faces`` index the binding).
    local : Gaussians
        N Gaussians in triangle-local coordinates (numpy or torch; converted to torch in the
        model's dtype/device). Local quaternions are normalised once here.
    binding : array-like, optional
        (N,) parent face per Gaussian; default ``local.extra["binding"]`` or ``["binding_0"]``.
    identity : mapping, optional
        Per-subject FLAME parameters used by :meth:`pose` when not passed (e.g. ``shape``,
        ``static_offset`` from a GaussianAvatars ``flame_param.npz``).

    Attributes
    ----------
    local : Gaussians
        Torch Gaussians in local coordinates (unit quaternions).
    binding : Tensor
        (N,) int64 face indices.
    """

    def __init__(self, flame_model: Any, local: Gaussians, binding: Any = None,
                 identity: Mapping[str, Any] | None = None) -> None:
        if not isinstance(local, Gaussians):
            raise InputError(f"local: expected Gaussians, found {type(local).__name__}")
        self.flame_model = flame_model
        faces = flame_model.faces
        self.faces: Tensor = faces
        self.binding = _binding_from(local, binding, int(faces.shape[0]), "RiggedAvatar").to(faces.device)
        extra = {k: v for k, v in local.extra.items() if k not in ("binding", "binding_0")}
        loc = local.replace(extra=extra).torch(device=flame_model.device, dtype=flame_model.dtype)
        loc.validate(context="RiggedAvatar local Gaussians")
        q = loc.quats / torch.linalg.norm(loc.quats, dim=-1, keepdim=True)
        self.local = loc.replace(quats=q.contiguous())
        self.identity = dict(identity or {})
        self._cache: dict[str, Tensor] | None = None
        rest = flame_model.v_template[None]
        self._n_degenerate = int(face_frames(rest, faces)[3].sum())
        self.last_cache_fraction: float | None = None
        #: "auto" (numba on CPU without autograd, else torch) or "torch"
        self.backend = "auto"
        self._np_cache: tuple[np.ndarray, ...] | None = None
        #: above this fraction of moved faces a cached deform recomputes everything (cheaper)
        self.cache_full_fraction = _CACHE_FULL_FRACTION

    # ------------------------------------------------------------------ properties
    def __len__(self) -> int:
        return len(self.local)

    @property
    def n_gaussians(self) -> int:
        return len(self.local)

    @property
    def n_degenerate_faces(self) -> int:
        """Faces that used the degenerate fallback frame in the last deform (in any frame of the
        batch), or in the rest mesh before any deform."""
        return self._n_degenerate

    # ------------------------------------------------------------------ deformation
    def _vertices(self, vertices: Any) -> Tensor:
        verts = getattr(vertices, "vertices", vertices)
        if not isinstance(verts, Tensor):
            verts = torch.as_tensor(np.asarray(verts))
        if verts.ndim == 2:
            verts = verts[None]
        nv = int(self.flame_model.n_vertices)
        check_array(verts, "vertices", ("B", nv, 3), finite=True)
        return verts.to(device=self.flame_model.device, dtype=self.flame_model.dtype)

    def deform_tensors(self, vertices: Any) -> tuple[Tensor, Tensor, Tensor]:
        """World means (B, N, 3), unit wxyz quats (B, N, 4) and log-scales (B, N, 3).

        Parameters
        ----------
        vertices : Tensor, numpy.ndarray or FlameOutput
            (B, V, 3) or (V, 3) posed mesh vertices, metres.
        """
        verts = self._vertices(vertices)
        if self._use_fast(verts):
            return self._deform_fast(verts)
        rot, scale, centre, degenerate = face_frames(verts, self.faces)
        self._n_degenerate = int(degenerate.any(dim=0).sum())
        loc = self.local
        return bind_to_world(loc.means, loc.quats, loc.log_scales, self.binding, rot, scale, centre)

    # ------------------------------------------------------------------ numba fast path
    def _use_fast(self, verts: Tensor) -> bool:
        if self.backend == "torch" or verts.device.type != "cpu" or verts.requires_grad:
            return False
        return _kernels() is not None

    def _np_local(self) -> tuple[np.ndarray, ...]:
        if self._np_cache is None:
            loc = self.local
            self._np_cache = (self.faces.cpu().numpy().astype(np.int64), self.binding.cpu().numpy(),
                              loc.means.detach().cpu().numpy(), loc.quats.detach().cpu().numpy(),
                              loc.log_scales.detach().cpu().numpy())
        return self._np_cache

    def _deform_fast(self, verts: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        k = _kernels()
        faces, binding, mu, ql, ls = self._np_local()
        b, n = verts.shape[0], binding.shape[0]
        dt = verts.dtype
        means, quats, log_scales = (torch.empty((b, n, c), dtype=dt) for c in (3, 4, 3))
        n_deg = np.zeros(faces.shape[0], bool)
        for i in range(b):
            frame, deg = k.frames(verts[i].detach().contiguous().numpy(), faces, DEGENERATE_EPS)
            n_deg |= deg
            k.bind_nb(frame, binding, mu, ql, ls, means[i].numpy(), quats[i].numpy(), log_scales[i].numpy())
        self._n_degenerate = int(n_deg.sum())
        return means, quats, log_scales

    def _wrap(self, means: Tensor, quats: Tensor, log_scales: Tensor) -> Gaussians:
        loc = self.local
        return Gaussians(means, quats, log_scales, loc.opacity_logits, loc.sh)

    def deform(self, vertices: Any, cache: bool = False, cache_tol: float = 0.0) -> Gaussians | list[Gaussians]:
        """World Gaussians for posed mesh vertices.

        Parameters
        ----------
        vertices : Tensor, numpy.ndarray or FlameOutput
            (B, V, 3) or (V, 3) posed vertices, metres.
        cache : bool
            Reuse Gaussians of faces that did not move since they were last computed (frames of
            a batch are processed in order). See the module docstring.
        cache_tol : float
            Per-coordinate vertex motion (metres) below which a face counts as unmoved.

        Returns
        -------
        Gaussians or list of Gaussians
            One (torch) Gaussians for B == 1, else a list of B.
        """
        verts = self._vertices(vertices)
        if cache:
            if not (cache_tol >= 0.0 and np.isfinite(cache_tol)):
                raise InputError(f"cache_tol: expected a finite value >= 0, found {cache_tol}")
            out = [self._wrap(*self._deform_cached(verts[i], float(cache_tol))) for i in range(verts.shape[0])]
        else:
            m, q, s = self.deform_tensors(verts)
            out = [self._wrap(m[i], q[i], s[i]) for i in range(verts.shape[0])]
        return out[0] if len(out) == 1 else out

    def reset_cache(self) -> None:
        """Forget the cached frame (the next cached deform recomputes everything)."""
        self._cache = None

    def _deform_cached(self, verts: Tensor, tol: float) -> tuple[Tensor, Tensor, Tensor]:
        if self._use_fast(verts):
            return self._deform_cached_fast(verts, tol)
        face_verts = verts[self.faces]  # (F, 3, 3)
        c = self._cache
        if c is not None:
            moved = (face_verts - c["face_verts"]).abs().amax(dim=(1, 2)) > tol
            n_moved = int(moved.sum())
            self.last_cache_fraction = n_moved / moved.shape[0]
            if n_moved == 0:
                return c["means"], c["quats"], c["log_scales"]
            if self.last_cache_fraction <= self.cache_full_fraction:
                face_idx = torch.nonzero(moved).squeeze(1)
                rot, scale, centre, degenerate = face_frames(verts[None], self.faces[face_idx])
                self._n_degenerate = int(degenerate.sum())  # faces recomputed this frame
                remap = torch.full((moved.shape[0],), -1, dtype=torch.int64, device=verts.device)
                remap[face_idx] = torch.arange(face_idx.shape[0], device=verts.device)
                g_idx = torch.nonzero(moved[self.binding]).squeeze(1)
                loc = self.local
                m, q, s = bind_to_world(loc.means[g_idx], loc.quats[g_idx], loc.log_scales[g_idx],
                                        remap[self.binding[g_idx]], rot, scale, centre)
                means, quats, log_scales = c["means"].clone(), c["quats"].clone(), c["log_scales"].clone()
                means[g_idx] = m[0]
                quats[g_idx] = q[0]
                log_scales[g_idx] = s[0]
                fv = torch.where(moved[:, None, None], face_verts, c["face_verts"])
                self._cache = {"face_verts": fv, "means": means, "quats": quats, "log_scales": log_scales}
                return means, quats, log_scales
        else:
            self.last_cache_fraction = 1.0
        m, q, s = self.deform_tensors(verts[None])
        self._cache = {"face_verts": face_verts, "means": m[0], "quats": q[0], "log_scales": s[0]}
        return m[0], q[0], s[0]

    def _deform_cached_fast(self, verts: Tensor, tol: float) -> tuple[Tensor, Tensor, Tensor]:
        """Numba version: fused moved-face test, frames of all faces, and copy-or-recompute per Gaussian."""
        k = _kernels()
        faces, binding, mu, ql, ls = self._np_local()
        v = verts.detach().contiguous().numpy()
        c = self._cache
        if c is None or "ref" not in c:
            self.last_cache_fraction = 1.0
            m, q, s = self._deform_fast(verts[None])
            self._cache = {"ref": v[faces].astype(np.float64), "means": m[0], "quats": q[0], "log_scales": s[0]}
            return m[0], q[0], s[0]
        moved = np.empty(faces.shape[0], np.bool_)
        k.moved_faces_nb(v, faces, c["ref"], tol, moved)  # updates ref for moved faces
        n_moved = int(moved.sum())
        self.last_cache_fraction = n_moved / moved.shape[0]
        if n_moved == 0:
            return c["means"], c["quats"], c["log_scales"]
        frame, deg = k.frames(v, faces, DEGENERATE_EPS, moved)
        self._n_degenerate = int(deg.sum())  # among the recomputed faces
        n, dt = binding.shape[0], verts.dtype
        means, quats, log_scales = (torch.empty((n, d), dtype=dt) for d in (3, 4, 3))
        k.bind_cached_nb(frame, moved, binding, mu, ql, ls, c["means"].numpy(), c["quats"].numpy(),
                         c["log_scales"].numpy(), means.numpy(), quats.numpy(), log_scales.numpy())
        c.update(means=means, quats=quats, log_scales=log_scales)
        return means, quats, log_scales

    def pose(self, cache: bool = False, cache_tol: float = 0.0, **flame_params: Any) -> Gaussians | list[Gaussians]:
        """Run the FLAME model with ``flame_params`` (``identity`` fills missing keys), then deform.

        Parameters
        ----------
        cache, cache_tol
            As in :meth:`deform`.
        **flame_params
            ``shape``, ``expr``, ``rotation``, ``neck_pose``, ``jaw_pose``, ``eyes_pose``,
            ``translation``, ``static_offset`` (see ``FlameModel.forward``); ``dynamic_offset``
            (B, V, 3) is added to ``static_offset``.
        """
        params = {**self.identity, **{k: v for k, v in flame_params.items() if v is not None}}
        dyn = params.pop("dynamic_offset", None)
        if dyn is not None:
            st = params.get("static_offset")
            dyn_t = torch.as_tensor(np.asarray(dyn) if not isinstance(dyn, Tensor) else dyn)
            params["static_offset"] = dyn_t if st is None else (
                torch.as_tensor(np.asarray(st) if not isinstance(st, Tensor) else st) + dyn_t)
        with torch.no_grad():
            out = self.flame_model(**params)
            return self.deform(out.vertices, cache=cache, cache_tol=cache_tol)

    def rest(self) -> Gaussians:
        """World Gaussians on the rest mesh (identity parameters, zero expression and pose)."""
        return self.pose()

    # ------------------------------------------------------------------ I/O
    def local_gaussians(self) -> Gaussians:
        """Local Gaussians (torch) with ``extra["binding_0"]`` as float32 (the GaussianAvatars layout)."""
        return self.local.replace(extra={**self.local.extra, "binding_0": self.binding.to(torch.float32)})

    def save_ply(self, path: str | os.PathLike) -> Path:
        """Write the local Gaussians + ``binding_0`` as a GaussianAvatars ``point_cloud.ply`` (atomic)."""
        from .ply import save_ply

        comments = ["holo_viewer_default_head"] if getattr(self.flame_model, "is_default_head", False) else []
        return save_ply(self.local_gaussians(), path, comments=comments)
