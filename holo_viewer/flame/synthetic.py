"""Random FLAME-format models for tests and benchmarks (synthetic, clearly labelled).

Not a head: random points on a sphere with valid FLAME-format arrays whose
structure mimics FLAME where the tests depend on it (skinning weights that are
zero for most joints, pose correctives only on vertices a joint influences, a
convex joint regressor, a kinematic tree with parents [-1, 0, 1, 1, 1]).
"""

from __future__ import annotations

import numpy as np

__all__ = ["random_flame_arrays"]


def random_flame_arrays(n_vertices: int = 400, n_shape: int = 12, n_expr: int = 6, n_faces: int | None = None,
                        seed: int = 0, write_split: bool = True) -> dict[str, np.ndarray]:
    """A random, valid FLAME-format model.

    Parameters
    ----------
    n_vertices : int
        V.
    n_shape, n_expr : int
        Components; ``shapedirs`` has ``n_shape + n_expr`` of them, shape first.
    n_faces : int, optional
        F (default about 2 V, like FLAME).
    seed : int
        Random seed (the result is deterministic).
    write_split : bool
        Store ``n_shape`` / ``n_expr`` keys (needed when ``n_shape != 300``).

    Returns
    -------
    dict of numpy.ndarray
        FLAME keys (``J_regressor`` dense), float64 / int64; plus ``n_shape`` and
        ``n_expr`` when ``write_split``. Vertices lie on a 0.1 m sphere; joint 2 (jaw)
        influences the lower front quarter, joints 3/4 (eyes) two small caps.
    """
    rng = np.random.default_rng(seed)
    v = n_vertices
    d = rng.normal(size=(v, 3))
    v_template = 0.1 * d / np.linalg.norm(d, axis=1, keepdims=True)
    x, y, z = v_template.T
    k = n_shape + n_expr
    shapedirs = rng.normal(scale=2e-3, size=(v, 3, k))

    weights = np.zeros((v, 5))
    weights[:, 0] = rng.uniform(0.0, 0.3, v) * (y > 0.05)  # root influences the top
    weights[:, 1] = 1.0
    jaw = (y < -0.02) & (z > 0.0)
    weights[jaw, 2] = rng.uniform(0.5, 3.0, jaw.sum())
    weights[jaw & (y < -0.06), 1] = 0.0  # chin fully on the jaw
    eye_l = np.linalg.norm(v_template - [0.035, 0.03, 0.09], axis=1) < 0.03
    eye_r = np.linalg.norm(v_template - [-0.035, 0.03, 0.09], axis=1) < 0.03
    weights[eye_l] = [0, 0, 0, 1, 0]
    weights[eye_r] = [0, 0, 0, 0, 1]
    weights /= weights.sum(axis=1, keepdims=True)

    posedirs = rng.normal(scale=1e-3, size=(v, 3, 36))
    for j in range(1, 5):  # correctives only where the joint has influence
        posedirs[weights[:, j] == 0, :, 9 * (j - 1):9 * j] = 0.0

    j_reg = np.zeros((5, v))
    for j, mask in enumerate([y > 0.05, np.abs(y) < 0.03, jaw, eye_l, eye_r]):
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            idx = rng.choice(v, 3, replace=False)
        w = rng.uniform(0.5, 1.0, idx.size)
        j_reg[j, idx] = w / w.sum()

    n_f = 2 * v - 4 if n_faces is None else n_faces
    f = np.stack([rng.permutation(v)[:3] for _ in range(min(n_f, 64))] +
                 [rng.integers(0, v, size=3) for _ in range(max(n_f - 64, 0))]).astype(np.int64)
    out = {
        "v_template": v_template,
        "shapedirs": shapedirs,
        "posedirs": posedirs,
        "J_regressor": j_reg,
        "weights": weights,
        "kintree_table": np.array([[-1, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64),
        "f": f,
    }
    if write_split:
        out["n_shape"] = np.array(n_shape)
        out["n_expr"] = np.array(n_expr)
    return out
