"""3D Gaussians: the data every renderer consumes.

A :class:`Gaussians` holds N Gaussians as either numpy arrays or torch tensors (all
fields of one kind). Field layout follows the 3DGS exchange format:

* ``means``          (N, 3) centres in world metres
* ``quats``          (N, 4) rotations, wxyz (need not be normalised; renderers normalise)
* ``log_scales``     (N, 3) natural-log standard deviations along the rotated axes
* ``opacity_logits`` (N,)   logit of opacity (opacity = sigmoid(logit))
* ``sh``             (N, (d+1)^2, 3) real spherical-harmonics coefficients, degree d in 0..3;
  ``sh[:, 0]`` is the DC term (``f_dc``), colour = max(SH(dir) + 0.5, 0)
* ``extra``          mapping name -> (N, ...) per-Gaussian extra PLY properties kept
  through I/O (e.g. ``binding`` for GaussianAvatars)

Construction checks shapes and types (cheap); :meth:`Gaussians.validate` also checks
values (finite, non-zero quaternions) and is called at public boundaries (PLY load,
``render_views``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np

from ..errors import AvatarError, InputError
from ..validation import check_array, is_torch

__all__ = ["Gaussians", "sh_degree_from_count", "SH_C0"]

#: DC spherical-harmonics constant: colour = SH_C0 * sh[:, 0] + 0.5 for degree 0
SH_C0 = 0.28209479177387814

_FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def sh_degree_from_count(n_coeffs: int) -> int:
    """SH degree d from the number of coefficients (d+1)^2; raises InputError otherwise."""
    for d in range(4):
        if (d + 1) ** 2 == n_coeffs:
            return d
    raise InputError(f"sh: expected (d+1)^2 coefficients for d in 0..3 (1, 4, 9 or 16), found {n_coeffs}")


@dataclass(frozen=True, eq=False)
class Gaussians:
    """N anisotropic 3D Gaussians (see module docstring for the layout)."""

    means: Any
    quats: Any
    log_scales: Any
    opacity_logits: Any
    sh: Any
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        kinds = {is_torch(getattr(self, f)) for f in _FIELDS}
        if len(kinds) != 1:
            raise InputError("Gaussians: expected all fields as numpy arrays or all as torch tensors, found a mix")
        sizes: dict[str, int] = {}
        check_array(self.means, "means", ("N", 3), finite=False, sizes=sizes)
        check_array(self.quats, "quats", ("N", 4), finite=False, sizes=sizes)
        check_array(self.log_scales, "log_scales", ("N", 3), finite=False, sizes=sizes)
        check_array(self.opacity_logits, "opacity_logits", ("N",), finite=False, sizes=sizes)
        check_array(self.sh, "sh", ("N", None, 3), finite=False, sizes=sizes)
        sh_degree_from_count(int(self.sh.shape[1]))
        for name, arr in self.extra.items():
            if int(arr.shape[0]) != sizes["N"]:
                raise InputError(f"extra[{name!r}]: expected {sizes['N']} rows, found {arr.shape[0]}")
        object.__setattr__(self, "extra", dict(self.extra))

    # --------------------------------------------------------------- properties
    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def n(self) -> int:
        return len(self)

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_count(int(self.sh.shape[1]))

    @property
    def is_torch(self) -> bool:
        return is_torch(self.means)

    @property
    def dtype(self) -> Any:
        return self.means.dtype

    @property
    def device(self) -> Any:
        return self.means.device if self.is_torch else "cpu"

    @property
    def scales(self) -> Any:
        """(N, 3) standard deviations exp(log_scales)."""
        if self.is_torch:
            return self.log_scales.exp()
        return np.exp(self.log_scales)

    @property
    def opacities(self) -> Any:
        """(N,) opacities sigmoid(opacity_logits)."""
        if self.is_torch:
            return self.opacity_logits.sigmoid()
        return 1.0 / (1.0 + np.exp(-self.opacity_logits))

    # --------------------------------------------------------------- validation
    def validate(self, context: str = "") -> "Gaussians":
        """Check values: every field finite, every quaternion non-zero. Returns self.

        Raises
        ------
        InputError
            Naming the field and the first offending Gaussian indices.
        """
        prefix = f"{context}: " if context else ""
        for name in _FIELDS:
            arr = self._np(getattr(self, name))
            # one flat test on clean data (the avatar's 100k Gaussians: ~0.3 ms for every field in
            # float32, 3x faster than a float64 sum, 10x faster than the per-Gaussian test); only
            # bad data takes the per-Gaussian test, which names the culprits
            if arr.size == 0 or (arr.dtype.kind == "f" and np.isfinite(arr).all()):  # 0 Gaussians: nothing to check
                continue
            bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)
            if bad.any():
                idx = np.flatnonzero(bad)
                raise InputError(f"{prefix}{name}: expected finite values, found NaN/inf in {idx.size} Gaussians "
                                 f"(indices {idx[:8].tolist()}{'...' if idx.size > 8 else ''})")
        q = self._np(self.quats)
        # column by column (numpy's per-row reduction is ~7x slower), in float32 for float32
        # quaternions (1e-24 is a normal float32; no conversion pass)
        qn2 = np.zeros(q.shape[0], dtype=np.float32 if q.dtype == np.float32 else np.float64)
        for j in range(q.shape[1]):
            c = q[:, j]
            qn2 += c * c
        bad = qn2 < 1e-24  # |q| < 1e-12
        if bad.any():
            idx = np.flatnonzero(bad)
            raise InputError(f"{prefix}quats: expected non-zero quaternions, found {idx.size} zero "
                             f"(indices {idx[:8].tolist()}{'...' if idx.size > 8 else ''})")
        return self

    @staticmethod
    def _np(x: Any) -> np.ndarray:
        return x.detach().cpu().numpy() if is_torch(x) else np.asarray(x)

    # --------------------------------------------------------------- conversion
    def replace(self, **changes: Any) -> "Gaussians":
        """A copy with some fields replaced (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def numpy(self, dtype: Any = None) -> "Gaussians":
        """A copy backed by numpy arrays (optionally cast float fields to ``dtype``)."""
        def conv(x: Any) -> np.ndarray:
            a = self._np(x)
            if dtype is not None and np.issubdtype(a.dtype, np.floating):
                a = a.astype(dtype, copy=False)
            return a
        return Gaussians(*(conv(getattr(self, f)) for f in _FIELDS),
                         extra={k: self._np(v) for k, v in self.extra.items()})

    def torch(self, device: Any = None, dtype: Any = None) -> "Gaussians":
        """A copy backed by torch tensors on ``device`` (float fields cast to ``dtype`` if given)."""
        import torch

        def conv(x: Any) -> "torch.Tensor":
            t = x if is_torch(x) else torch.from_numpy(np.ascontiguousarray(x))
            if dtype is not None and t.is_floating_point():
                t = t.to(dtype)
            return t.to(device) if device is not None else t
        return Gaussians(*(conv(getattr(self, f)) for f in _FIELDS),
                         extra={k: conv(v) for k, v in self.extra.items()})

    def to(self, device: Any = None, dtype: Any = None) -> "Gaussians":
        """Alias of :meth:`torch`."""
        return self.torch(device=device, dtype=dtype)

    # --------------------------------------------------------------- selection
    def subset(self, index: Any) -> "Gaussians":
        """Gaussians selected by a boolean mask or an integer index array (numpy or torch)."""
        if self.is_torch:
            import torch

            idx = index if is_torch(index) else torch.as_tensor(np.asarray(index))
            idx = idx.to(self.means.device)
        else:
            idx = self._np(index)
        if getattr(idx, "dtype", None) is not None and str(idx.dtype).endswith("bool"):
            if int(idx.shape[0]) != len(self):
                raise InputError(f"index: expected a boolean mask of length {len(self)}, found {idx.shape[0]}")
        return Gaussians(*(getattr(self, f)[idx] for f in _FIELDS),
                         extra={k: v[idx] for k, v in self.extra.items()})

    @staticmethod
    def concatenate(items: Iterable["Gaussians"]) -> "Gaussians":
        """Concatenate Gaussians of the same backend and SH degree; extras present in all are kept."""
        items = list(items)
        if not items:
            raise InputError("concatenate: expected at least one Gaussians, found none")
        degs = {g.sh_degree for g in items}
        kinds = {g.is_torch for g in items}
        if len(degs) != 1:
            raise AvatarError(f"concatenate: expected one SH degree, found {sorted(degs)}")
        if len(kinds) != 1:
            raise AvatarError("concatenate: expected all numpy or all torch Gaussians, found a mix")
        if items[0].is_torch:
            import torch

            cat = torch.cat
        else:
            cat = np.concatenate
        common = set(items[0].extra)
        for g in items[1:]:
            common &= set(g.extra)
        return Gaussians(*(cat([getattr(g, f) for g in items]) for f in _FIELDS),
                         extra={k: cat([g.extra[k] for g in items]) for k in sorted(common)})

    @classmethod
    def from_arrays(cls, means: Any, quats: Any, log_scales: Any, opacity_logits: Any, sh: Any,
                    extra: Mapping[str, Any] | None = None, *, validate: bool = True) -> "Gaussians":
        """Construct and (by default) validate values."""
        g = cls(means, quats, log_scales, opacity_logits, sh, extra or {})
        return g.validate() if validate else g

    def save_ply(self, path: Any) -> Any:
        """Write a binary 3DGS PLY atomically (see :func:`holo_viewer.avatar.ply.save_ply`)."""
        from .ply import save_ply

        return save_ply(self, path)

    def colors_dc(self) -> np.ndarray:
        """(N, 3) view-independent colour from the DC term only (numpy float)."""
        return np.maximum(self._np(self.sh[:, 0]) * SH_C0 + 0.5, 0.0)
