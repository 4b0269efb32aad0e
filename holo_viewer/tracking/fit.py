"""Fit the face state to 68 detected landmarks: regularised Gauss-Newton (numpy reference; compiled steps in
:mod:`.fit_fast`, the default).

Unknowns (``LandmarkHeadModel.n_params`` = n_au + 7): AU state ``a`` in [0, 1] (intensity /
scale, the reaction model's units), jaw pitch ``j`` (rad, in [-0.05, 0.5]), head rotation
``r`` (axis-angle, rad) and the head's position ``T`` in camera coordinates (metres).

Cost, with landmark weights ``w_i``, the face's inter-ocular distance ``s`` in pixels (so the
weights below do not depend on image size), the previous frame's solution ``p_prev`` and the
model's projected landmarks ``x_i(p)``::

    E(p) = sum_i w_i |x_i(p) - l_i|^2 / s^2 + au_reg |a|^2 + jaw_reg j^2 + rot_reg |r|^2
           + temporal_reg (|a - a_prev|^2 + (j - j_prev)^2)

minimised by a few Levenberg-Marquardt-damped Gauss-Newton steps from ``p_prev`` (or from a
closed-form initial pose on the first frame); the Jacobian is a forward difference evaluated
as one batch of n_params + 1 forward passes; AU and jaw steps are clipped to their bounds
(projected Gauss-Newton). Many AUs move no landmark (AU5, AU6, AU7, AU43 on this detector's
points), so ``au_reg`` keeps them near 0 rather than letting them absorb noise.

Reduced parameters. Many AUs move the 68 detector points by a pixel or two, or in the same
direction as another AU (measured on renders of the default head: docs/live.md), so only
``TrackerFitConfig.aus`` are unknowns (the others stay 0), and AU26 (jaw drop) is tied to the jaw
pitch, ``AU26 state = au26_per_jaw * jaw``: the project's speaker model opens the mouth with
both together (AU26 intensity 3.5 and jaw 0.3 rad at full opening: 0.7 / 0.3 = 7/3), and the
landmarks cannot tell them apart. The fit solves for ``q`` with ``params = M q``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError, TrackingError
from ..validation import check_array, check_finite_scalar
from .head_model import CAMERA_FROM_FLAME, N_POSE_PARAMS, LandmarkHeadModel
from .landmarks import LEFT_EYE, RIGHT_EYE

__all__ = ["TrackerFitConfig", "TrackerFit", "fit_landmarks", "initial_params", "reduction", "JAW_RANGE"]

#: jaw pitch bounds (rad): slightly closed .. wide open
JAW_RANGE = (-0.05, 0.5)


@dataclass(frozen=True)
class TrackerFitConfig:
    """Weights and iteration count of :func:`fit_landmarks` (see the module docstring)."""

    iterations: int = 4
    aus: tuple[str, ...] = ("AU1", "AU2", "AU4", "AU10", "AU12", "AU15", "AU17", "AU20", "AU25")
    au26_per_jaw: float = 7.0 / 3.0
    au_reg: float = 2e-3
    jaw_reg: float = 1e-3
    rot_reg: float = 1e-4
    temporal_reg: float = 1e-3
    damping: float = 1e-4
    fd_step: float = 1e-4

    def __post_init__(self) -> None:
        if int(self.iterations) < 1:
            raise InputError(f"TrackerFitConfig.iterations: expected >= 1, found {self.iterations}")
        for name in ("au_reg", "jaw_reg", "rot_reg", "temporal_reg", "damping"):
            check_finite_scalar(getattr(self, name), f"TrackerFitConfig.{name}", low=0.0)
        check_finite_scalar(self.fd_step, "TrackerFitConfig.fd_step", low=0.0, low_open=True)
        check_finite_scalar(self.au26_per_jaw, "TrackerFitConfig.au26_per_jaw", low=0.0)
        if "AU26" in self.aus and self.au26_per_jaw > 0:
            raise InputError("TrackerFitConfig.aus: AU26 is tied to the jaw (au26_per_jaw > 0); leave it out or set "
                             "au26_per_jaw=0")


def reduction(model: LandmarkHeadModel, config: TrackerFitConfig) -> np.ndarray:
    """(n_params, n_q) matrix ``M`` with ``params = M q`` (see the module docstring)."""
    names = list(model.au_names)
    missing = [a for a in config.aus if a not in names]
    if missing:
        raise InputError(f"TrackerFitConfig.aus: {missing} not in the model's AUs {names}")
    na = model.n_au
    cols = [names.index(a) for a in config.aus]
    nq = len(cols) + N_POSE_PARAMS
    M = np.zeros((model.n_params, nq))
    for j, i in enumerate(cols):
        M[i, j] = 1.0
    M[na:, len(cols):] = np.eye(N_POSE_PARAMS)
    if config.au26_per_jaw > 0 and "AU26" in names:
        M[names.index("AU26"), len(cols)] = config.au26_per_jaw
    return M


def _reduction_pair(model: LandmarkHeadModel, config: TrackerFitConfig) -> tuple[np.ndarray, np.ndarray]:
    """(M, pinv(M)) of :func:`reduction`, kept on the model per config (read-only): the pseudo-inverse's
    SVD was ~10 % of a warm frame's fit, the same every frame (issue 37: the tracker's CPU)."""
    cache = model.__dict__.setdefault("_reduction_pairs", {})
    pair = cache.get(config)
    if pair is None:
        M = reduction(model, config)
        pair = (M, np.linalg.pinv(M))
        for a in pair:
            a.setflags(write=False)
        cache[config] = pair
    return pair


@dataclass(frozen=True)
class TrackerFit:
    """One fitted frame.

    Attributes
    ----------
    params : numpy.ndarray, shape (n_params,)   AU state, jaw pitch, rotation (3), translation (3)
    rms_px : float                              weighted RMS landmark residual in pixels
    """

    params: np.ndarray
    rms_px: float


def _eyes_mid(points: np.ndarray) -> np.ndarray:
    return 0.5 * (points[..., RIGHT_EYE, :].mean(axis=-2) + points[..., LEFT_EYE, :].mean(axis=-2))


def initial_params(model: LandmarkHeadModel, landmarks: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Closed-form start: neutral face, no rotation, depth from the inter-ocular distance.

    ``T_z = f * iod_model / iod_px``; the eye midpoint's ray then fixes ``T_x, T_y``.
    """
    p = np.zeros(model.n_params)
    pts = model.points_flame(p)[0]
    iod_model = float(np.linalg.norm(pts[RIGHT_EYE].mean(0) - pts[LEFT_EYE].mean(0)))
    iod_px = float(np.linalg.norm(landmarks[RIGHT_EYE].mean(0) - landmarks[LEFT_EYE].mean(0)))
    if iod_px < 1.0:
        raise TrackingError(f"landmarks: inter-ocular distance {iod_px:.2f} px is too small to fit")
    f = 0.5 * (K[0, 0] + K[1, 1])
    z = f * iod_model / iod_px
    mid_px = _eyes_mid(landmarks)
    mid_cam = np.array([(mid_px[0] - K[0, 2]) * z / K[0, 0], (mid_px[1] - K[1, 2]) * z / K[1, 1], z])
    mid_model = CAMERA_FROM_FLAME @ (_eyes_mid(pts) - model.root_rest)
    p[model.n_au + 4:] = mid_cam - mid_model
    return p


def fit_landmarks(model: LandmarkHeadModel, landmarks: np.ndarray, K: np.ndarray, prev: np.ndarray | None = None,
                  config: TrackerFitConfig = TrackerFitConfig(), fast: bool = True) -> TrackerFit:
    """Fit one frame's landmarks (see the module docstring).

    Parameters
    ----------
    model : LandmarkHeadModel
    landmarks : numpy.ndarray, shape (68, 2)   detected pixel coordinates
    K : numpy.ndarray, shape (3, 3)            camera intrinsics
    prev : numpy.ndarray, shape (n_params,), optional
        Previous frame's solution: the start point and the temporal prior (None: first frame).
    config : TrackerFitConfig
    fast : bool
        The compiled steps (:mod:`.fit_fast`, ~10x less CPU; the default) or this numpy reference (False);
        the same steps, equal to rounding (tested to 1e-7 in the parameters).

    Returns
    -------
    TrackerFit
    """
    lm = np.asarray(check_array(landmarks, "landmarks", (68, 2)), dtype=np.float64)
    K = np.asarray(check_array(K, "K", (3, 3)), dtype=np.float64)
    n, na = model.n_params, model.n_au
    M, Mpinv = _reduction_pair(model, config)
    nq = M.shape[1]
    nqa = nq - N_POSE_PARAMS  # fitted AUs
    if prev is None:
        q = Mpinv @ initial_params(model, lm, K)
        prior = None
    else:
        q = Mpinv @ np.asarray(check_array(prev, "prev", (n,)), np.float64)
        prior = q.copy()
    iod_px = float(np.linalg.norm(lm[RIGHT_EYE].mean(0) - lm[LEFT_EYE].mean(0)))
    sw = np.sqrt(model.weights)[:, None] / iod_px  # (68, 1)

    reg_w = np.zeros(nq)
    reg_w[:nqa] = config.au_reg
    reg_w[nqa] = config.jaw_reg
    reg_w[nqa + 1:nqa + 4] = config.rot_reg
    tw = np.zeros(nq)
    if prior is not None:
        tw[:nqa + 1] = config.temporal_reg
    lo = np.full(nq, -np.inf)
    hi = np.full(nq, np.inf)
    lo[:nqa], hi[:nqa] = 0.0, 1.0
    lo[nqa], hi[nqa] = JAW_RANGE
    if config.au26_per_jaw > 0:  # AU26 = au26_per_jaw * jaw must stay in [0, 1]
        lo[nqa] = max(lo[nqa], 0.0)
        hi[nqa] = min(hi[nqa], 1.0 / config.au26_per_jaw)
    iterations = int(config.iterations) * (3 if prev is None else 1)  # a cold start needs more steps
    if fast:
        from .fit_fast import gauss_newton, model_arrays

        q, x = gauss_newton(q, prior if prior is not None else q, prior is not None, M, lm, np.ascontiguousarray(sw[:, 0]),
                            reg_w, tw, lo, hi, float(config.damping), float(config.fd_step), iterations,
                            float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), *model_arrays(model))
        p = M @ q
        res = np.linalg.norm(x - lm, axis=1)
        rms = float(np.sqrt(np.sum(model.weights * res ** 2) / max(np.sum(model.weights), 1e-12)))
        return TrackerFit(params=p, rms_px=rms)
    eye = np.eye(nq) * config.fd_step
    for _ in range(iterations):
        batch = np.concatenate([q[None], q[None] + eye], axis=0) @ M.T  # (nq + 1, n)
        x = model.project(batch, K)  # (nq + 1, 68, 2)
        r0 = ((x[0] - lm) * sw).ravel()
        J = (((x[1:] - x[0]) * sw).reshape(nq, -1) / config.fd_step).T  # (136, nq)
        A = J.T @ J + np.diag(reg_w + tw + config.damping)
        g = J.T @ r0 + reg_w * q + (tw * (q - prior) if prior is not None else 0.0)
        try:
            step = np.linalg.solve(A, -g)
        except np.linalg.LinAlgError as exc:  # pragma: no cover - A is SPD by construction
            raise TrackingError(f"landmark fit: singular normal equations ({exc})") from exc
        q = np.clip(q + step, lo, hi)
    p = M @ q
    x = model.project(p, K)[0]
    res = np.linalg.norm(x - lm, axis=1)
    rms = float(np.sqrt(np.sum(model.weights * res ** 2) / max(np.sum(model.weights), 1e-12)))
    return TrackerFit(params=p, rms_px=rms)
