"""The avatar behind the pipeline's ``gaussians`` stage: one small protocol, three kinds of avatar.

* a rigged avatar (:class:`~holo_viewer.avatar.RiggedAvatar`, GaussianAvatars binding): Gaussians
  follow the posed FLAME mesh, exactly;
* a blend-shape avatar (:class:`~holo_viewer.avatar.BlendshapeAvatar`, the seed paper's
  ``B* = B_0 + sum_k psi_k B_k``): Gaussians are a linear function of the expression (and jaw)
  coefficients, plus the exact global rotation and translation; fast and approximate;
* a static 3DGS scene (:class:`StaticAvatar`): world Gaussians that do not move.

:func:`as_pipeline_avatar` wraps any of them in the :class:`PipelineAvatar` protocol, which is
all the pipeline uses.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping, Protocol, Union, runtime_checkable

import numpy as np

from ..errors import InputError

if TYPE_CHECKING:  # pragma: no cover
    from ..avatar.blendshape import BlendshapeAvatar
    from ..avatar.gaussians import Gaussians
    from ..avatar.rigged import RiggedAvatar
    from ..flame.model import FlameModel

__all__ = ["PipelineAvatar", "RiggedStage", "BlendshapeStage", "StaticAvatar", "as_pipeline_avatar", "AvatarLike"]


@runtime_checkable
class PipelineAvatar(Protocol):
    """What the pipeline needs from an avatar.

    Attributes
    ----------
    flame_model : FlameModel or None
        The FLAME model the avatar was built on (None: any model; the pipeline uses its own).
    identity : mapping of str to numpy.ndarray
        Per-subject FLAME parameters (``shape`` (n_shape,), ``static_offset`` (V, 3)); may be empty.
    """

    flame_model: "FlameModel | None"
    identity: Mapping[str, np.ndarray]

    def __len__(self) -> int:
        """Number of Gaussians."""
        ...

    def gaussians(self, vertices: np.ndarray, params: Mapping[str, np.ndarray]) -> "Gaussians":
        """World Gaussians for one frame.

        Parameters
        ----------
        vertices : numpy.ndarray
            (V, 3) posed FLAME vertices in metres (the pipeline's ``mesh`` stage).
        params : mapping of str to numpy.ndarray
            The frame's FLAME parameters (the ``params`` stage): ``expr`` (n_expr,), ``jaw_pose``,
            ``rotation``, ``neck_pose``, ``translation`` (3,), ``eyes_pose`` (6,), ``shape``.
        """
        ...


#: what :class:`~holo_viewer.pipeline.Pipeline` and :func:`as_pipeline_avatar` accept
AvatarLike = Union["RiggedAvatar", "BlendshapeAvatar", "StaticAvatar", PipelineAvatar]


def _identity_of(avatar: Any) -> dict[str, np.ndarray]:
    ident = getattr(avatar, "identity", None) or {}
    return {k: np.asarray(v.detach().cpu() if hasattr(v, "detach") else v, dtype=np.float64)
            for k, v in ident.items()}


class RiggedStage:
    """A rigged avatar (Gaussians bound to the mesh's triangles) as a :class:`PipelineAvatar`."""

    def __init__(self, avatar: Any) -> None:
        self.avatar = avatar
        self.flame_model = getattr(avatar, "flame_model", None)
        self.identity = _identity_of(avatar)

    def __len__(self) -> int:
        return len(self.avatar)

    def gaussians(self, vertices: np.ndarray, params: Mapping[str, np.ndarray]) -> "Gaussians":
        return self.avatar.deform(vertices)

    def drawn_deform(self, index: np.ndarray) -> Any:
        """A function ``(vertices, gaussians) -> gaussians`` that rewrites in place, in ``gaussians`` (an (N,)
        torch deform of this avatar, owned by the caller), only the Gaussians ``index`` for the posed
        ``vertices`` (V, 3): the avatar's numba kernels restricted to those Gaussians (``bind_subset_nb``) and
        the faces they sit on (``face_frames_nb``'s mask), so those rows equal :meth:`gaussians`' bit for bit
        (tests/test_live_inflight.py); the other rows keep their values. None where the avatar's deform is not
        that numba path (another avatar type, the torch backend, no numba, a GPU model). The live frames that
        draw a visible mask's Gaussians only use it (issue 37: 12.8 -> 9.0 ms of CPU a frame)."""
        from ..avatar import rigged
        from ..validation import check_array

        av, k = self.avatar, rigged._kernels()
        if not isinstance(av, rigged.RiggedAvatar) or k is None or av.backend == "torch" \
                or av.flame_model.device.type != "cpu":
            return None
        import torch

        faces, binding, mu, ql, ls = av._np_local()
        index = np.ascontiguousarray(index, dtype=np.int64)
        face_mask = np.zeros(faces.shape[0], dtype=bool)
        face_mask[binding[index]] = True
        nv, dtype = int(av.flame_model.n_vertices), av.flame_model.dtype
        # the drawn Gaussians grouped by face, their local rows in that order: each face's frame applied at
        # once to its Gaussians (bind_faces_nb: face_frames_nb + bind_subset_nb's rows bit for bit, without
        # their random reads of the (F, 17) frame table: ~4.3 -> ~3.2 ms of CPU a frame on one thread)
        face_list, starts, by_face, mu_f, ql_f, ls_f = k.face_order(binding, index, mu, ql, ls)

        def deform(vertices: np.ndarray, g: "Gaussians") -> "Gaussians":
            verts = np.asarray(vertices)
            check_array(verts[None], "vertices", ("B", nv, 3), finite=True)  # RiggedAvatar.deform's check
            v = torch.as_tensor(verts).to(dtype=dtype).contiguous().numpy()  # and its conversion
            k.bind_faces_nb(v, faces, rigged.DEGENERATE_EPS, face_list, starts, by_face, mu_f, ql_f, ls_f,
                            g.means.numpy(), g.quats.numpy(), g.log_scales.numpy())
            return g

        deform.index, deform.face_mask = index, face_mask  # type: ignore[attr-defined]
        return deform


class BlendshapeStage:
    """A blend-shape avatar as a :class:`PipelineAvatar`.

    Uses ``expr`` (its first ``n_expr`` coefficients), ``jaw_pose`` (only for avatars built with
    jaw components) and the exact global ``rotation`` / ``translation``. The mesh is not used.
    Parameters the blend shapes cannot represent (neck and eye poses, expression components
    beyond the avatar's, a jaw pose without jaw components) raise :class:`InputError` rather
    than being dropped silently.
    """

    def __init__(self, avatar: Any, flame_model: Any = None) -> None:
        self.avatar = avatar
        self.flame_model = flame_model
        self.identity: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.avatar)

    def gaussians(self, vertices: np.ndarray, params: Mapping[str, np.ndarray]) -> "Gaussians":
        av = self.avatar
        expr = np.asarray(params.get("expr", np.zeros(0)), dtype=np.float64).reshape(-1)
        if np.any(expr[av.n_expr:] != 0):
            raise InputError(f"expr: this blend-shape avatar has {av.n_expr} expression components; found non-zero "
                             f"coefficients beyond them (indices {np.flatnonzero(expr[av.n_expr:])[:5] + av.n_expr})")
        for key in ("neck_pose", "eyes_pose"):
            if np.any(np.asarray(params.get(key, 0.0)) != 0):
                raise InputError(f"{key}: a blend-shape avatar has no {key.split('_')[0]} joint; expected zeros, "
                                 f"found {np.asarray(params[key]).tolist()}")
        jaw = np.asarray(params.get("jaw_pose", np.zeros(3)), dtype=np.float64)
        return av.pose(expr[: av.n_expr], jaw_pose=jaw if av.has_jaw else (None if not np.any(jaw) else jaw),
                       rotation=params.get("rotation"), translation=params.get("translation"))


class StaticAvatar:
    """World-space Gaussians that do not follow the mesh (a plain 3DGS PLY)."""

    def __init__(self, gaussians: "Gaussians") -> None:
        self.gaussians_ = gaussians
        self.flame_model = None
        self.identity: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.gaussians_)

    def gaussians(self, vertices: np.ndarray, params: Mapping[str, np.ndarray]) -> "Gaussians":
        return self.gaussians_

    def deform(self, vertices: Any, **_: Any) -> "Gaussians":
        """The Gaussians, unchanged (the rigged avatars' method name)."""
        return self.gaussians_


def as_pipeline_avatar(avatar: AvatarLike, flame_model: "FlameModel | None" = None) -> PipelineAvatar:
    """Wrap ``avatar`` in the :class:`PipelineAvatar` protocol.

    Parameters
    ----------
    avatar : RiggedAvatar, BlendshapeAvatar, StaticAvatar or PipelineAvatar
    flame_model : FlameModel, optional
        The model a blend-shape avatar was built on (it does not keep one).

    Raises
    ------
    InputError
        For an object that is none of these.
    """
    from ..avatar.blendshape import BlendshapeAvatar

    if isinstance(avatar, BlendshapeAvatar):
        return BlendshapeStage(avatar, flame_model)
    if isinstance(avatar, (RiggedStage, BlendshapeStage, StaticAvatar)):
        return avatar
    if callable(getattr(avatar, "deform", None)):
        return RiggedStage(avatar)
    if isinstance(avatar, PipelineAvatar):
        return avatar
    raise InputError(f"avatar: expected a RiggedAvatar, BlendshapeAvatar, StaticAvatar or an object with "
                     f"gaussians(vertices, params), found {type(avatar).__name__}")
