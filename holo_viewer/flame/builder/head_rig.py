"""Skinning of the default head: joints, skinning weights, joint regressor, jaw corrective.

Pure numpy, deterministic. Joints follow FLAME: 0 global (root, at the neck base),
1 neck (top of the neck), 2 jaw (hinge midpoint, level with the ears below the
temples), 3 eye at +x (the subject's left), 4 eye at -x; parents [-1, 0, 1, 1, 1].

Weights (rows sum to 1):

* eyeballs: one-hot to their eye joint;
* ``head`` share h(v): a smooth step across a plane tilted forward under the chin
  (root below, head above), so the neck rotation bends the neck band only;
* jaw share, a product of smooth masks in the grid's (theta, phi) parameters:
  below the jaw line (the mouth line at the front, rising to the hinge at the sides;
  the lower lip and the lower side of the mouth slit get 1, the upper lip 0),
  in front of the ramus, and above the throat; the mouth bag's lower half follows
  the jaw; the rest of the head share goes to the neck joint.

The joint regressor is a convex combination of a few surface vertices per joint
solved by non-negative least squares so that it reproduces the rest joints exactly
(eyes: the midpoint of the eyeball's front and back poles = the eyeball centre).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from .head_sculpt import (EYE_CENTRES, HINGE, NECK_JOINT_POS, ROOT_JOINT_POS, HeadMesh, _angles_of,
                          smoothstep)

__all__ = ["skin_weights", "joint_regressor", "jaw_corrective_posedirs", "KINTREE", "rest_joints"]

#: FLAME kinematic tree (2, 5): parents then joint ids; parent of the root is -1 (stored as
#: 4294967295 in FLAME's uint32 table, here int64 -1).
KINTREE = np.array([[-1, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64)


def rest_joints() -> np.ndarray:
    """(5, 3) rest joint positions in metres."""
    return np.stack([ROOT_JOINT_POS, NECK_JOINT_POS, HINGE, EYE_CENTRES[0], EYE_CENTRES[1]])


def jaw_mask(head: HeadMesh) -> np.ndarray:
    """(V,) float64 in [0, 1]: how much each vertex belongs to the lower jaw."""
    v = head.vertices
    n = len(v)
    w = np.zeros(n)
    grid_ids = np.where(np.isfinite(head.theta))[0]
    th, ph = head.theta[grid_ids], np.abs(head.phi[grid_ids])
    r_m, c0, c1 = head.mouth_slit
    theta_m = float(head.theta[head.grid[r_m, c0]])
    phi_c = float(np.abs(head.phi[head.grid[r_m, c1]]))
    theta_h, phi_h = _angles_of(HINGE + np.array([0.062, 0.0, 0.0]))
    rise = smoothstep(ph, phi_c, abs(phi_h) - 0.15)
    theta_line = theta_m - (theta_m - theta_h) * rise
    band = 0.004 + 0.11 * smoothstep(ph, phi_c - 0.05, phi_c + 0.45)
    d = th - theta_line
    w_up = smoothstep(d, -band, band)
    on_line = np.abs(d) < 1e-9
    slit = on_line & (ph < phi_c - 1e-9)
    w_up[slit] = 0.0
    w_up[head.lower_lip_side[grid_ids]] = 1.0  # the mouth slit only: never the lower-lid rims
    m_back = 1.0 - smoothstep(ph, 1.3, 1.62)
    p = v[grid_ids]
    m_low = smoothstep(p[:, 1] + 0.6 * p[:, 2], -0.108, -0.086)
    w[grid_ids] = w_up * m_back * m_low
    w[head.parts["bag"]] = head.bag_lower
    return w


def head_share(v: np.ndarray) -> np.ndarray:
    """(V,) share of the head (neck joint and its children) versus the root, smooth in y and z."""
    s = v[:, 1] + 0.4 * (v[:, 2] + 0.02)
    return smoothstep(s, -0.128, -0.078)


def skin_weights(head: HeadMesh) -> np.ndarray:
    """(V, 5) float64 skinning weights, rows summing to 1."""
    n = len(head.vertices)
    h = head_share(head.vertices)
    jaw = np.minimum(jaw_mask(head), 1.0) * h
    w = np.zeros((n, 5))
    w[:, 0] = 1.0 - h
    w[:, 2] = jaw
    w[:, 1] = h - jaw
    for e, j in ((0, 3), (1, 4)):
        ids = head.parts[f"eyeball_{e}"]
        w[ids] = 0.0
        w[ids, j] = 1.0
    return w


def _convex_weights(points: np.ndarray, target: np.ndarray, lam: float = 10.0) -> np.ndarray:
    a = np.vstack([points.T, lam * np.ones((1, len(points)))])
    b = np.concatenate([target, [lam]])
    x, res = nnls(a, b)
    if res > 1e-9:
        raise RuntimeError(f"default head: joint {target} is not inside its regressor vertices (res {res:.2e})")
    return x


def joint_regressor(head: HeadMesh) -> np.ndarray:
    """(5, V) dense regressor with J_regressor @ v_template == rest_joints()."""
    v = head.vertices
    n = len(v)
    jr = np.zeros((5, n))
    grid_ids = np.where(np.isfinite(head.theta))[0]
    targets = rest_joints()
    for j in range(3):
        t = targets[j]
        slab = grid_ids[np.abs(v[grid_ids, 1] - t[1]) < 0.006]
        # deterministic choice: the slab vertices nearest the joint from each of 8 sectors
        rel = v[slab] - t
        ang = np.arctan2(rel[:, 0], rel[:, 2])
        sector = np.floor((ang + np.pi) / (2 * np.pi) * 8).astype(int) % 8
        pick = []
        for s in range(8):
            for above in (True, False):
                cand = slab[(sector == s) & ((v[slab, 1] >= t[1]) == above)]
                if len(cand):
                    pick.append(cand[np.argmin(np.linalg.norm(v[cand] - t, axis=1))])
        pick = np.array(sorted(pick))
        jr[j, pick] = _convex_weights(v[pick], t)
    for e, j in ((0, 3), (1, 4)):
        ids = head.parts[f"eyeball_{e}"]  # UV sphere: first id = front pole, last = back pole
        jr[j, ids[0]] = jr[j, ids[-1]] = 0.5
    return jr


def jaw_corrective_posedirs(head: HeadMesh, weights: np.ndarray) -> np.ndarray:
    """(V, 3, 36) pose correctives: only the jaw's x rotation (mouth opening) has one.

    With the jaw opened by angle a about x, ``R[2, 1] = -R[1, 2] = sin a`` (features
    16 and 14 of the row-major ``vec(R_k - I)``). Per unit ``sin a`` the corrective
    pulls the cheeks beside the mouth 4 mm inward (they hollow when the mouth opens;
    cut off smoothly to exactly zero 30 mm above the mouth line, below the nose tip)
    and brings the lower lip 10 mm forward (it rolls back less than a rigid
    rotation would make it; jaw-weighted, so zero wherever the jaw weight is).
    """
    v = head.vertices
    n = len(v)
    pd = np.zeros((n, 3, 36))
    jaw = weights[:, 2]
    r_m, c0, c1 = head.mouth_slit
    corner_x = abs(float(v[head.grid[r_m, c1], 0]))
    mouth_y = float(v[head.grid[r_m, 0 + (c0 + c1) // 2], 1])
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    # compact support in y: exactly zero from just below the nose tip up (never near the eyes)
    cheek = (np.exp(-((np.abs(x) - corner_x - 0.015) / 0.012) ** 2 - ((y - mouth_y) / 0.018) ** 2)
             * (1.0 - smoothstep(y, mouth_y + 0.012, mouth_y + 0.03)) * (z > 0.0) * np.isfinite(head.theta))
    lip = jaw * np.exp(-(x / (1.2 * corner_x)) ** 2 - ((y - mouth_y + 0.005) / 0.008) ** 2) * (z > 0.04)
    d = np.zeros((n, 3))
    d[:, 0] = -np.sign(x) * 0.004 * cheek
    d[:, 2] = 0.010 * lip
    pd[:, :, 9 + 7] = 0.5 * d
    pd[:, :, 9 + 5] = -0.5 * d
    return pd
