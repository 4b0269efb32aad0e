"""Small random objects for tests, examples and benchmarks (no files, no weights).

Everything is seeded and small enough that a whole pipeline run takes milliseconds::

    model = random_flame_model()                     # a FLAME-format model, 300 vertices
    avatar = random_rigged_avatar(model, n=400)      # Gaussians bound to its triangles
    Pipeline(model=model, avatar=avatar, view=ViewSettings(tile_scale=0.1)).native()

``tests/conftest.py`` wraps them in fixtures. The FLAME arrays themselves come from
:func:`holo_viewer.flame.synthetic.random_flame_arrays`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .avatar.gaussians import Gaussians
    from .avatar.rigged import RiggedAvatar
    from .flame.model import FlameModel

__all__ = ["random_flame_model", "random_gaussians", "random_rigged_avatar"]


def random_flame_model(n_vertices: int = 300, n_shape: int = 8, n_expr: int = 6, seed: int = 1) -> "FlameModel":
    """A random FLAME-format model (5 joints, FLAME's kinematic tree) of ``n_vertices`` vertices."""
    from .flame.model import FlameModel
    from .flame.synthetic import random_flame_arrays

    return FlameModel.from_arrays(random_flame_arrays(n_vertices=n_vertices, n_shape=n_shape, n_expr=n_expr,
                                                      seed=seed))


def random_gaussians(n: int = 400, sh_degree: int = 1, seed: int = 0, scale: float = 0.2) -> "Gaussians":
    """``n`` random Gaussians (float32 numpy).

    Means ~ N(0, ``scale``) metres (N, 3); unnormalised random quaternions (N, 4); scales uniform in
    [0.05, 0.3] ``scale`` (log-scales (N, 3)); opacity logits ~ N(1, 0.5) (N,); SH coefficients
    ~ N(0, 0.5) (N, (sh_degree + 1)**2, 3).
    """
    from .avatar.gaussians import Gaussians

    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    return Gaussians(
        means=rng.normal(scale=scale, size=(n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=np.log(rng.uniform(0.05, 0.3, size=(n, 3)) * scale / 0.2).astype(np.float32),
        opacity_logits=rng.normal(1.0, 0.5, size=n).astype(np.float32),
        sh=rng.normal(scale=0.5, size=(n, k, 3)).astype(np.float32),
    )


def random_rigged_avatar(model: "FlameModel", n: int = 400, seed: int = 0) -> "RiggedAvatar":
    """``n`` random local Gaussians bound to random triangles of ``model`` (a rigged avatar)."""
    from .avatar import RiggedAvatar

    local = random_gaussians(n, sh_degree=1, seed=seed)
    faces = int(model.faces.shape[0])
    binding = np.random.default_rng(seed + 1).integers(0, faces, size=n).astype(np.int64)
    return RiggedAvatar(model, local.replace(extra={"binding": binding}))
