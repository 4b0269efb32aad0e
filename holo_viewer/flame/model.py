"""FLAME head model in torch: blend shapes + linear blend skinning (docs/design.md section 4).

``FlameModel`` wraps the pure functions of :mod:`holo_viewer.flame.lbs` around the
arrays of a FLAME-format file (real FLAME 2020/2023 ``.pkl`` or our ``.npz``)::

    v_shaped = v_template + shapedirs . [shape; expr] (+ static_offset)
    J        = J_regressor v_shaped
    vertices = LBS(v_shaped, J, [rotation, neck, jaw, eye_l, eye_r]) + translation

Parameter names follow GaussianAvatars' ``flame_param.npz``. Axis-angle in
radians, lengths in metres, world frame +y up, +z out of the face.

Speed: the joint regressor is folded into the blend shapes once (``J = J_template
+ [shape; expr] . J_shapedirs``, exact by linearity), shape and expression bases
are stored as contiguous (K, 3 V) matrices and the pose correctives as (36, 3 V),
so a frame costs two matmuls for the blend shapes and one for skinning.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import torch
from torch import Tensor

from ..errors import FlameError, InputError
from ..validation import check_array
from . import teeth as _teeth
from .io import N_JOINTS, load_flame_arrays, validate_flame_arrays
from .lbs import lbs

__all__ = ["FlameOutput", "FlameModel", "FLAME_N_SHAPE"]

#: Number of shape components at the front of a FLAME file's ``shapedirs`` when
#: the file does not say (FLAME 2020 / 2023: 300 shape + 100 expression).
FLAME_N_SHAPE = 300
_FLAME_N_VERTICES = 5023


@dataclass(frozen=True)
class FlameOutput:
    """Result of :meth:`FlameModel.forward`.

    Attributes
    ----------
    vertices : Tensor
        Posed vertices, shape (B, V, 3), metres (V includes teeth when added).
    joints : Tensor
        Posed joints (0 global, 1 neck, 2 jaw, 3/4 eyes), shape (B, 5, 3), metres.
    """

    vertices: Tensor
    joints: Tensor


def _file_split(metadata: Mapping[str, Any], k_total: int, source: str) -> tuple[int, int]:
    """Numbers of shape and expression components stored in a file."""
    if "n_shape" in metadata:
        try:
            fs = int(np.asarray(metadata["n_shape"]).reshape(()))
            fe = int(np.asarray(metadata["n_expr"]).reshape(())) if "n_expr" in metadata else k_total - fs
        except (TypeError, ValueError) as exc:
            raise FlameError(f"{source}: n_shape / n_expr: expected scalar integers, found "
                             f"{metadata.get('n_shape')!r} / {metadata.get('n_expr')!r}") from exc
        if fs < 0 or fe < 0 or fs + fe > k_total:
            raise FlameError(f"{source}: n_shape + n_expr: expected non-negative counts with a sum <= "
                             f"{k_total} (shapedirs components), found {fs} + {fe}")
        return fs, fe
    if k_total >= FLAME_N_SHAPE:
        return FLAME_N_SHAPE, k_total - FLAME_N_SHAPE
    raise FlameError(f"{source}: shapedirs: expected >= {FLAME_N_SHAPE} components (FLAME: {FLAME_N_SHAPE} shape "
                     f"then expression) or an 'n_shape' key saying where expression components start, "
                     f"found {k_total} components and no 'n_shape'")


def _teeth_anchors(metadata: Mapping[str, Any], n_vertices: int, source: str) -> tuple[np.ndarray, np.ndarray]:
    if "teeth_anchor_upper" in metadata and "teeth_anchor_lower" in metadata:
        up = np.asarray(metadata["teeth_anchor_upper"]).reshape(-1)
        lo = np.asarray(metadata["teeth_anchor_lower"]).reshape(-1)
        for key, a in (("teeth_anchor_upper", up), ("teeth_anchor_lower", lo)):
            if not np.issubdtype(a.dtype, np.integer) or a.size < 2 or a.min() < 0 or a.max() >= n_vertices:
                raise FlameError(f"{source}: {key}: expected >= 2 integer vertex indices in [0, {n_vertices}), "
                                 f"found dtype {a.dtype}, {a.size} entries"
                                 + (f", range [{a.min()}, {a.max()}]" if a.size else ""))
        if up.shape != lo.shape:
            raise FlameError(f"{source}: teeth_anchor_lower: expected as many anchors as teeth_anchor_upper "
                             f"({up.size}), found {lo.size}")
        return up.astype(np.int64), lo.astype(np.int64)
    if n_vertices == _FLAME_N_VERTICES:
        return np.asarray(_teeth.FLAME_LIP_UPPER), np.asarray(_teeth.FLAME_LIP_LOWER)
    raise FlameError(f"{source}: add_teeth: the model has {n_vertices} vertices (not FLAME's {_FLAME_N_VERTICES}) "
                     f"and no 'teeth_anchor_upper' / 'teeth_anchor_lower' keys, so the lips that place the "
                     f"teeth are unknown; add those keys (ordered lip vertex indices) or use add_teeth=False")


class FlameModel(torch.nn.Module):
    """FLAME-format head model: ``forward(params) -> FlameOutput``.

    Build with :meth:`load` (file) or :meth:`from_arrays` (arrays in memory).

    Attributes
    ----------
    faces : Tensor
        (F, 3) int64 triangle indices (teeth faces appended when added).
    has_own_teeth : bool
        The mesh has its own teeth (``metadata["has_teeth"]``, e.g. the default head); ``add_teeth``
        then adds nothing and ``teeth_upper`` / ``teeth_lower`` stay None.
    n_vertices : int
        V, including teeth.
    n_base_vertices : int
        V of the file (without teeth).
    n_shape, n_expr : int
        Components kept (the requested number, or fewer if the file has fewer).
    parents : tuple of int
        Parent of each of the 5 joints, ``(-1, 0, 1, 1, 1)`` for FLAME.
    metadata : dict
        Every extra key of the file (e.g. ``expression_names``, ``vertex_region``).
    expression_names : list of str or None
        Names of the kept expression components, from ``metadata["expression_names"]``.
    is_default_head : bool
        The model is holo_viewer's embedded head (``metadata`` has ``holo_viewer_default_head``).
    teeth_upper, teeth_lower : Tensor or None
        (4 n,) int64 vertex indices of the teeth, when added.
    source : str
        File path or ``"<arrays>"``.
    """

    def __init__(self, arrays: Mapping[str, Any], *, n_shape: int | None = FLAME_N_SHAPE, n_expr: int | None = 100,
                 add_teeth: bool = False, dtype: torch.dtype = torch.float32,
                 device: str | torch.device = "cpu", source: str = "<arrays>") -> None:
        super().__init__()
        if dtype not in (torch.float32, torch.float64):
            raise InputError(f"dtype: expected torch.float32 or torch.float64, found {dtype}")
        for name, val in (("n_shape", n_shape), ("n_expr", n_expr)):
            if val is not None and (not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < 0):
                raise InputError(f"{name}: expected a non-negative int or None, found {val!r}")
        data = validate_flame_arrays(arrays, source=source)
        self.source = source
        self.metadata: dict[str, Any] = {k: v for k, v in data.items() if k not in
                                         ("v_template", "shapedirs", "posedirs", "J_regressor", "weights",
                                          "kintree_table", "f")}
        v_template = data["v_template"]
        shapedirs = data["shapedirs"]
        posedirs = data["posedirs"]
        j_reg = data["J_regressor"]
        weights = data["weights"]
        faces = data["f"]
        self.parents: tuple[int, ...] = tuple(int(p) for p in data["kintree_table"][0])
        fs, fe = _file_split(self.metadata, shapedirs.shape[2], source)
        self.n_shape = fs if n_shape is None else min(int(n_shape), fs)
        self.n_expr = fe if n_expr is None else min(int(n_expr), fe)
        self.n_base_vertices = v_template.shape[0]
        dirs = np.concatenate([shapedirs[:, :, :self.n_shape], shapedirs[:, :, fs:fs + self.n_expr]], axis=2)

        teeth_upper = teeth_lower = None
        # a model with its own teeth (the default head: metadata ``has_teeth`` = 1) gets none added
        if add_teeth and not self.has_own_teeth:
            up, lo = _teeth_anchors(self.metadata, self.n_base_vertices, source)
            t = _teeth.build_teeth(v_template, dirs, self.n_shape, N_JOINTS, up, lo)
            n_t = t.vertices.shape[0]
            v_template = np.concatenate([v_template, t.vertices])
            dirs = np.concatenate([dirs, t.shapedirs])
            posedirs = np.concatenate([posedirs, np.zeros((n_t,) + posedirs.shape[1:])])
            j_reg = np.concatenate([j_reg, np.zeros((j_reg.shape[0], n_t))], axis=1)
            weights = np.concatenate([weights, t.weights])
            faces = np.concatenate([faces, t.faces])
            teeth_upper = torch.as_tensor(t.upper, device=device)
            teeth_lower = torch.as_tensor(t.lower, device=device)

        n_v = v_template.shape[0]
        self.n_vertices = n_v
        k = dirs.shape[2]
        # (K, 3V) bases and their joint images J_reg . dirs (K, 3J), in float64 before the cast.
        dirs_flat = dirs.transpose(2, 0, 1).reshape(k, n_v * 3)
        j_dirs = np.einsum("jv,vck->kjc", j_reg, dirs).reshape(k, N_JOINTS * 3)
        opts = {"dtype": dtype, "device": device}
        self.register_buffer("v_template", torch.as_tensor(v_template, **opts))
        self.register_buffer("j_template", torch.as_tensor(j_reg @ v_template, **opts))
        self.register_buffer("shape_dirs", torch.as_tensor(dirs_flat[:self.n_shape], **opts).contiguous())
        self.register_buffer("expr_dirs", torch.as_tensor(dirs_flat[self.n_shape:], **opts).contiguous())
        self.register_buffer("j_shape_dirs", torch.as_tensor(j_dirs[:self.n_shape], **opts).contiguous())
        self.register_buffer("j_expr_dirs", torch.as_tensor(j_dirs[self.n_shape:], **opts).contiguous())
        self.register_buffer("posedirs", torch.as_tensor(
            posedirs.reshape(n_v * 3, posedirs.shape[2]).T.copy(), **opts))
        self.register_buffer("J_regressor", torch.as_tensor(j_reg, **opts))
        self.register_buffer("lbs_weights", torch.as_tensor(weights, **opts))
        self.register_buffer("faces", torch.as_tensor(faces, dtype=torch.int64, device=device))
        self._shape_cache: tuple | None = None
        self.register_buffer("teeth_upper", teeth_upper)
        self.register_buffer("teeth_lower", teeth_lower)

    # ------------------------------------------------------------------ construction

    @classmethod
    def load(cls, path: str | os.PathLike, n_shape: int | None = FLAME_N_SHAPE, n_expr: int | None = 100,
             add_teeth: bool = False, dtype: torch.dtype = torch.float32,
             device: str | torch.device = "cpu") -> "FlameModel":
        """Read a FLAME 2020/2023 ``.pkl`` (no chumpy needed) or our ``.npz``.

        Parameters
        ----------
        path : str or os.PathLike
            Model file.
        n_shape, n_expr : int or None
            Components to keep; fewer are kept if the file has fewer, ``None`` keeps all.
        add_teeth : bool
            Append GaussianAvatars-style teeth (see :mod:`holo_viewer.flame.teeth`); ignored for a model
            with its own teeth (``has_teeth`` in the file, e.g. the default head).
        dtype : torch.dtype
            ``torch.float32`` or ``torch.float64``.
        device : str or torch.device
            Where the buffers live.

        Raises
        ------
        FlameError
            Unreadable file, missing keys or inconsistent sizes.
        """
        return cls(load_flame_arrays(path), n_shape=n_shape, n_expr=n_expr, add_teeth=add_teeth,
                   dtype=dtype, device=device, source=str(path))

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, Any], n_shape: int | None = FLAME_N_SHAPE,
                    n_expr: int | None = 100, add_teeth: bool = False, dtype: torch.dtype = torch.float32,
                    device: str | torch.device = "cpu", source: str = "<arrays>") -> "FlameModel":
        """Build from FLAME-format arrays in memory (same keys as the files)."""
        return cls(arrays, n_shape=n_shape, n_expr=n_expr, add_teeth=add_teeth, dtype=dtype,
                   device=device, source=source)

    # ------------------------------------------------------------------ properties

    @property
    def dtype(self) -> torch.dtype:
        """Floating dtype of the model buffers."""
        return self.v_template.dtype

    @property
    def device(self) -> torch.device:
        """Device of the model buffers."""
        return self.v_template.device

    @property
    def expression_names(self) -> list[str] | None:
        """Names of the kept expression components, or ``None`` if the file has none."""
        names = self.metadata.get("expression_names")
        if names is None:
            return None
        return [str(n) for n in np.asarray(names).reshape(-1)[: self.n_expr]]

    @property
    def has_own_teeth(self) -> bool:
        """The file's mesh has teeth of its own (``metadata["has_teeth"]`` nonzero): ``add_teeth`` adds none."""
        flag = self.metadata.get("has_teeth")
        try:
            return flag is not None and bool(int(np.asarray(flag).reshape(())))
        except (TypeError, ValueError) as exc:
            raise FlameError(f"{self.source}: has_teeth: expected a scalar integer flag, found {flag!r}") from exc

    @property
    def is_default_head(self) -> bool:
        """True for holo_viewer's embedded default head."""
        return "holo_viewer_default_head" in self.metadata

    def extra_repr(self) -> str:
        return (f"source={self.source!r}, n_vertices={self.n_vertices}, n_faces={self.faces.shape[0]}, "
                f"n_shape={self.n_shape}, n_expr={self.n_expr}, dtype={self.dtype}")

    # ------------------------------------------------------------------ forward

    def _param(self, value: Any, name: str, width: int, batch: list[int], pad_to: int | None = None) -> Tensor | None:
        """Validate one parameter -> (B or 1, width) tensor in the model dtype/device, or None."""
        if value is None:
            return None
        value = _as_numeric(value, name)
        if value.ndim == 1:
            value = value[None]
        if value.ndim != 2:
            raise InputError(f"{name}: expected shape (B, {width}) or ({width},), found {tuple(value.shape)}")
        found_w = value.shape[1]
        if pad_to is not None:
            if found_w > pad_to:
                raise InputError(f"{name}: expected shape (B, <= {pad_to}) (the model keeps {pad_to} components), "
                                 f"found {tuple(value.shape)}")
        elif found_w != width:
            raise InputError(f"{name}: expected shape (B, {width}), found {tuple(value.shape)}")
        check_array(value, name, None, finite=True)
        t = torch.as_tensor(value, dtype=self.dtype, device=self.device)
        if pad_to is not None and found_w < pad_to:
            t = torch.nn.functional.pad(t, (0, pad_to - found_w))
        _bind_batch(batch, t.shape[0], name, tuple(value.shape))
        return t

    def forward(self, shape: Any = None, expr: Any = None, rotation: Any = None, neck_pose: Any = None,
                jaw_pose: Any = None, eyes_pose: Any = None, translation: Any = None,
                static_offset: Any = None) -> FlameOutput:
        """Pose the head.

        Parameters
        ----------
        shape : array-like, optional
            (B, <= n_shape) or (n,) shape coefficients (missing trailing ones are 0).
        expr : array-like, optional
            (B, <= n_expr) or (n,) expression coefficients.
        rotation, neck_pose, jaw_pose : array-like, optional
            (B, 3) or (3,) axis-angle of the global (root), neck and jaw joints, radians.
        eyes_pose : array-like, optional
            (B, 6) or (6,): left eye then right eye axis-angle (joints 3, 4).
        translation : array-like, optional
            (B, 3) or (3,) added to every vertex and joint, metres.
        static_offset : array-like, optional
            (B, V, 3), (1, V, 3) or (V, 3) per-vertex rest offsets added to the shaped
            template before skinning; V may be the base count (teeth offsets 0).

        ``None`` means zeros. Every given parameter has batch size B or 1 (broadcast).
        Tensors or numpy arrays; converted to the model dtype and device.

        Returns
        -------
        FlameOutput
            ``vertices`` (B, V, 3), ``joints`` (B, 5, 3).

        Raises
        ------
        InputError
            Wrong shape, wider coefficients than the model keeps, mismatched batch
            sizes, or NaN/inf; the message names the parameter.
        """
        batch: list[int] = []
        shape_t = self._param(shape, "shape", self.n_shape, batch, pad_to=self.n_shape)
        expr_t = self._param(expr, "expr", self.n_expr, batch, pad_to=self.n_expr)
        poses = [self._param(rotation, "rotation", 3, batch), self._param(neck_pose, "neck_pose", 3, batch),
                 self._param(jaw_pose, "jaw_pose", 3, batch), self._param(eyes_pose, "eyes_pose", 6, batch)]
        transl = self._param(translation, "translation", 3, batch)
        offset = self._static_offset(static_offset, batch)
        b = batch[0] if batch else 1

        n_v = self.n_vertices
        v_flat = self.v_template.reshape(1, n_v * 3)
        j_flat = self.j_template.reshape(1, N_JOINTS * 3)
        if shape_t is not None and self.n_shape:
            v_flat, j_flat = self._shaped_template(shape_t)
        if expr_t is not None and self.n_expr:
            v_flat = v_flat + expr_t @ self.expr_dirs
            j_flat = j_flat + expr_t @ self.j_expr_dirs
        v_shaped = v_flat.reshape(-1, n_v, 3).expand(b, n_v, 3)
        joints = j_flat.reshape(-1, N_JOINTS, 3).expand(b, N_JOINTS, 3)
        if offset is not None:
            v_shaped = v_shaped + offset
            joints = joints + torch.einsum("jv,bvc->bjc", self.J_regressor, offset)
            joints = joints.expand(b, N_JOINTS, 3)

        zeros = torch.zeros(b, 3, dtype=self.dtype, device=self.device)
        parts = []
        for p, width in zip(poses, (3, 3, 3, 6)):
            if p is None:
                parts.append(zeros if width == 3 else torch.zeros(b, 6, dtype=self.dtype, device=self.device))
            else:
                parts.append(p.expand(b, width))
        pose = torch.cat(parts, dim=1).reshape(b, N_JOINTS, 3)

        verts, posed_joints = lbs(v_shaped, joints, pose, self.posedirs, self.lbs_weights, self.parents)
        if transl is not None:
            verts = verts + transl[:, None, :]
            posed_joints = posed_joints + transl[:, None, :]
        return FlameOutput(vertices=verts, joints=posed_joints)

    def _shaped_template(self, shape_t: Tensor) -> tuple[Tensor, Tensor]:
        """``v_template + shape . dirs`` and its joints, flattened; cached for a repeated batch-1 shape.

        The shape of an avatar rarely changes between frames, so the last
        (1, n_shape) result is kept when no gradient is being recorded.
        """
        cacheable = shape_t.shape[0] == 1 and not (torch.is_grad_enabled() and (
            shape_t.requires_grad or self.shape_dirs.requires_grad))
        key = (self.shape_dirs.data_ptr(), self.shape_dirs.dtype, self.shape_dirs.device)
        cached = self._shape_cache
        if cacheable and cached is not None and cached[0] == key and torch.equal(cached[1], shape_t):
            return cached[2], cached[3]
        v_flat = self.v_template.reshape(1, -1) + shape_t @ self.shape_dirs
        j_flat = self.j_template.reshape(1, -1) + shape_t @ self.j_shape_dirs
        if cacheable:
            self._shape_cache = (key, shape_t.detach().clone(), v_flat.detach(), j_flat.detach())
        return v_flat, j_flat

    def _static_offset(self, value: Any, batch: list[int]) -> Tensor | None:
        if value is None:
            return None
        value = _as_numeric(value, "static_offset")
        if value.ndim == 2:
            value = value[None]
        n_found = value.shape[1] if value.ndim == 3 else -1
        if value.ndim != 3 or value.shape[2] != 3 or n_found not in (self.n_vertices, self.n_base_vertices):
            raise InputError(f"static_offset: expected shape (B, {self.n_vertices}, 3) or ({self.n_vertices}, 3)"
                             + (f" (or {self.n_base_vertices} vertices without teeth)"
                                if self.n_base_vertices != self.n_vertices else "")
                             + f", found {tuple(value.shape)}")
        check_array(value, "static_offset", None, finite=True)
        t = torch.as_tensor(value, dtype=self.dtype, device=self.device)
        if n_found < self.n_vertices:
            t = torch.nn.functional.pad(t, (0, 0, 0, self.n_vertices - n_found))
        _bind_batch(batch, t.shape[0], "static_offset", tuple(value.shape))
        return t

    # ------------------------------------------------------------------ helpers

    def rest_vertices(self) -> Tensor:
        """The template (zero shape, expression and pose), shape (V, 3)."""
        return self.v_template


def _as_numeric(value: Any, name: str) -> Any:
    """A real-valued tensor or float ndarray, or InputError naming the parameter."""
    if isinstance(value, Tensor):
        if value.is_floating_point() or not (value.is_complex() or value.dtype == torch.bool):
            return value
        raise InputError(f"{name}: expected a real-valued tensor, found dtype {value.dtype}")
    try:
        arr = np.asarray(value)
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise TypeError(arr.dtype)
        return arr
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected a real-valued array, found {type(value).__name__} "
                         f"({exc})") from exc


def _bind_batch(batch: list[int], b: int, name: str, found: tuple[int, ...]) -> None:
    """Record the batch size; 1 broadcasts, anything else must agree."""
    if b == 1:
        return
    if not batch:
        batch.append(b)
    elif batch[0] != b:
        raise InputError(f"{name}: expected batch size {batch[0]} (or 1) like the other parameters, "
                         f"found {b} in shape {found}")
