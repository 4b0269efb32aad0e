"""Eye slices: what one tracked eye sees of the quilt's light field, rendered as one image.

The quilt cameras are a horizontal rig (:func:`holo_viewer.render.view_synthesis.rig_of`) whose
camera x translation and principal column are affine in ``s = tan(view angle)`` (Algorithm 1
places camera ``k`` at ``D tan(alpha_k)`` and shears its principal point to keep the focal plane):

    tx(s) = p0 + p1 s,   cx(s) = c0 + c1 s.

An eye at ``(xe, d)`` (metres; sideways from the panel centre, distance) looks through native
column ``x`` under ``phi = atan((xe - x) / d)``, where the panel shows it view coordinate ``t(x)``,
i.e. the camera at angle ``phi``: ``s = (xe - x) / d``, affine in ``x`` and so in the texel
coordinate ``xi`` of a view's image (``x = (xi / w - 1/2) width``): ``s(xi) = A + B xi``. The eye's
**slice** of the light field is the image whose column ``xi`` is seen from camera ``s(xi)``. A point
``(X, Y, Z)`` of the rig frame (``R p + (0, ty, tz)``; view ``k`` adds ``tx_k`` to ``X``) lands in
camera ``s`` at ``fx (X + tx(s)) / Z + cx(s)``, so in the slice at the column solving that with
``s = s(xi)``:

    xi = (fx X + (c0 + c1 A) Z + fx (p0 + p1 A)) / ((1 - c1 B) Z - fx p1 B),   v = fy Y / Z + cy

(a crossed-slit camera: projective in ``(X, Z)`` horizontally, pinhole vertically; identical to
the pinhole of view ``k`` on the focal plane). Nothing in the fast renderer changes: each centre
moves to ``X' = (xi - cxm) Z / fx`` (same depth, so the depth order holds) and its covariance by
that move's Jacobian, and a pinhole with principal column ``cxm`` then splats it with the
footprint ``J_pinhole(X') J_move Sigma (...)^T = J_slit Sigma J_slit^T``: EWA's first-order
footprint for the slit camera (:func:`slice_pass`, a :class:`~holo_viewer.render.fast.SplatPass`
sharing the render's depth sort). A splat's colour is its SH seen from camera ``s(xi*)`` of its
centre's column, as view ``k`` sees it from camera ``k``.

The subpixels the eye receives show quilt views ``k`` near ``t(x)``, not exactly the slice; a
point of inverse depth ``w`` seen at view ``k``'s texel column ``u`` (centre ``u + 1/2``) sits in
the slice at

    xi = (u + 1/2 + fx (p0 + p1 A - tx_k) w + c0 + c1 A - cx_k) / (1 - B c1 - B fx p1 w)

(exact for the point; ``w`` is read in the slice at ``xi``, a fixed point as in
:mod:`~holo_viewer.render.view_synthesis`), which :func:`holo_viewer.display.slices.scatter_slices`
uses to write those subpixels. Inverse depths come from a z-buffer of the centres
(:func:`slice_depth`).

Pure math, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from ..camera import Cameras
from ..errors import InputError
from . import view_synthesis
from .fast import SlitViews, SortedSplats, SplatPass
from .fast_kernels import _sh_basis

__all__ = ["SliceRig", "EyeSlice", "slice_rig", "eye_slices", "slice_columns", "slice_cameras", "slice_pass", "slit_views",
           "transform_splats", "slice_depth", "warp_coefficients", "column_camera"]


@dataclass(frozen=True)
class SliceRig:
    """What eye slices need of the quilt cameras and the panel (see :func:`slice_rig`).

    Attributes
    ----------
    R : (3, 3) shared rotation.  ty, tz : shared camera y, z translations (m).
    fx, fy, cy : shared intrinsics (px).  width, height : view size (px).
    tx, cx : (V,) each view's camera x translation (m) and principal column (px).
    p0, p1, c0, c1 : ``tx(s) = p0 + p1 s``, ``cx(s) = c0 + c1 s``, ``s = tan(view angle)``.
    w_zero : inverse depth of the plane where every view agrees (background).
    panel_width_m : physical width of the panel (m).  near : near plane (m).
    """

    R: np.ndarray
    ty: float
    tz: float
    fx: float
    fy: float
    cy: float
    width: int
    height: int
    tx: np.ndarray
    cx: np.ndarray
    p0: float
    p1: float
    c0: float
    c1: float
    w_zero: float
    panel_width_m: float
    near: float

    @property
    def cxm(self) -> float:
        """Principal column of the pinhole that splats the moved centres (the image centre)."""
        return 0.5 * self.width


@dataclass(frozen=True)
class EyeSlice:
    """One eye's slice: column ``xi`` (texel coordinate, pixel centres at +1/2) is seen from the
    camera ``s = A + B xi``; ``xe``, ``d`` the eye (m)."""

    A: float
    B: float
    xe: float
    d: float

    def coefficients(self, rig: SliceRig) -> tuple[float, float, float, float, float]:
        """(a, b, c, e, f) of ``xi = (a X + b Z + c) / (e Z + f)`` (rig frame X, Z)."""
        return (rig.fx, rig.c0 + rig.c1 * self.A, rig.fx * (rig.p0 + rig.p1 * self.A), 1.0 - rig.c1 * self.B,
                -rig.fx * rig.p1 * self.B)


def slice_rig(cameras: Cameras, calibration: Any, tol: float = 1e-6) -> SliceRig:
    """The :class:`SliceRig` of quilt ``cameras`` on ``calibration``'s panel.

    Raises
    ------
    InputError
        If the cameras are not a horizontal rig, or their x translations and principal columns
        are not affine in the tangent of the calibration's view angles (not its quilt cameras).
    """
    try:
        rig = view_synthesis.rig_of(cameras)
    except InputError as exc:
        raise InputError(f"eye slices need the calibration's quilt cameras: {exc}") from None
    V = len(cameras)
    if V < 2:
        raise InputError(f"cameras: expected >= 2 quilt cameras, found {V}")
    alpha = np.radians((np.arange(V) / (V - 1) - 0.5) * float(calibration.view_cone))
    M = np.stack([np.ones(V), np.tan(alpha)], axis=1)
    (p0, p1), *_ = np.linalg.lstsq(M, rig.tx, rcond=None)
    (c0, c1), *_ = np.linalg.lstsq(M, rig.cx, rcond=None)
    res_t = float(np.abs(M @ np.array([p0, p1]) - rig.tx).max())
    res_c = float(np.abs(M @ np.array([c0, c1]) - rig.cx).max())
    scale_t = max(float(np.abs(rig.tx).max()), 1e-9)
    if res_t > tol * scale_t or res_c > tol * max(float(np.abs(rig.cx).max()), 1.0):
        raise InputError(f"eye slices: cameras: x offsets / principal columns are not affine in tan(view angle) of the "
                         f"calibration's {calibration.view_cone} deg cone (residuals {res_t:.3g} m, {res_c:.3g} px): "
                         "not this calibration's quilt cameras")
    t0 = cameras.t[0]
    return SliceRig(R=np.ascontiguousarray(cameras.R[0], dtype=np.float64), ty=float(t0[1]), tz=float(t0[2]),
                    fx=rig.fx, fy=float(cameras.fy[0]), cy=float(cameras.cy[0]), width=int(cameras.width),
                    height=int(cameras.height), tx=rig.tx, cx=rig.cx, p0=float(p0), p1=float(p1), c0=float(c0),
                    c1=float(c1), w_zero=rig.w_zero, panel_width_m=float(calibration.physical_size_m[0]),
                    near=float(cameras.near))


def eye_slices(rig: SliceRig, positions: Any) -> list[EyeSlice]:
    """The slices of eyes at ``positions``: (angle_deg, distance_m) pairs, e.g.
    :func:`holo_viewer.display.eyes.eye_positions` of a tracked viewer (left eye first)."""
    out = []
    for angle, d in positions:
        xe = d * math.tan(math.radians(angle))
        out.append(EyeSlice(A=(xe + 0.5 * rig.panel_width_m) / d, B=-rig.panel_width_m / (rig.width * d),
                            xe=xe, d=d))
    return out


def slice_columns(rig: SliceRig, eye: EyeSlice, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Float64 reference: slice column ``xi`` of rig-frame points (X, Z); NaN where the slit
    camera has the point behind it (denominator <= 0)."""
    a, b, c, e, f = eye.coefficients(rig)
    X = np.asarray(X, dtype=np.float64)
    Z = np.asarray(Z, dtype=np.float64)
    den = e * Z + f
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, (a * X + b * Z + c) / den, np.nan)


def column_camera(rig: SliceRig, eye: EyeSlice, xi: float) -> Cameras:
    """The pinhole quilt camera the eye looks through at slice column ``xi`` (tests: a slice's
    column equals that camera's render there)."""
    s = eye.A + eye.B * float(xi)
    M = np.eye(4)
    M[:3, :3] = rig.R
    M[:3, 3] = (rig.p0 + rig.p1 * s, rig.ty, rig.tz)
    K = np.array([[rig.fx, 0.0, rig.c0 + rig.c1 * s], [0.0, rig.fy, rig.cy], [0.0, 0.0, 1.0]])
    return Cameras(M[None], K[None], rig.width, rig.height, rig.near, max(rig.near * 10.0, 100.0))


def slice_cameras(rig: SliceRig, n: int) -> Cameras:
    """``n`` pinholes that splat the moved centres (rotation R, translation (0, ty, tz), principal
    column :attr:`SliceRig.cxm`)."""
    M = np.eye(4)
    M[:3, :3] = rig.R
    M[:3, 3] = (0.0, rig.ty, rig.tz)
    K = np.array([[rig.fx, 0.0, rig.cxm], [0.0, rig.fy, rig.cy], [0.0, 0.0, 1.0]])
    return Cameras(np.repeat(M[None], n, axis=0), np.repeat(K[None], n, axis=0), rig.width, rig.height, rig.near,
                   max(rig.near * 10.0, 100.0))


@numba.njit(parallel=True, cache=True)
def _transform(pc, cov, means, sh, m, degree, ty, tz, fx, cxm, near, coef, ab, P0, P1, out_pc, out_cov,
               out_col):  # pragma: no cover - compiled
    """Every eye's moved centres, covariances and colours in one pass over the splats (coef (E, 5)
    rows a, b, c, e, f; ab (E, 2) the slices' A, B; outputs (E, rows, mp))."""
    mp = pc.shape[1]
    E = coef.shape[0]
    nk = (degree + 1) * (degree + 1)
    chunk = 512
    for ci in numba.prange((mp + chunk - 1) // chunk):
        basis = np.empty(16)  # once per chunk (an allocation per splat cost more than the rest)
        for i in range(ci * chunk, min(mp, ci * chunk + chunk)):
            X, Z = pc[0, i], pc[2, i] + tz
            xx, xy, xz, yy, yz, zz = cov[0, i], cov[1, i], cov[2, i], cov[3, i], cov[4, i], cov[5, i]
            for q in range(E):
                a, b, c, e, f = coef[q, 0], coef[q, 1], coef[q, 2], coef[q, 3], coef[q, 4]
                den = e * Z + f
                out_pc[q, 1, i] = pc[1, i]
                if i >= m or not (Z > near and den > 1e-9 * Z):
                    # padding, or behind the slit camera: moved behind the near plane, never drawn
                    out_pc[q, 0, i] = 0.0
                    out_pc[q, 2, i] = -tz - 1.0
                    for r in range(6):
                        out_cov[q, r, i] = cov[r, i]
                    for r in range(3):
                        out_col[q, r, i] = 0.0
                    continue
                xi = (a * X + b * Z + c) / den
                out_pc[q, 0, i] = (xi - cxm) * Z / fx
                out_pc[q, 2, i] = pc[2, i]
                jx = Z / den * (a / fx)
                jz = ((b * f - e * (a * X + c)) / (den * den) * Z + (xi - cxm)) / fx
                out_cov[q, 0, i] = jx * jx * xx + 2.0 * jx * jz * xz + jz * jz * zz
                out_cov[q, 1, i] = jx * xy + jz * yz
                out_cov[q, 2, i] = jx * xz + jz * zz
                out_cov[q, 3, i] = yy
                out_cov[q, 4, i] = yz
                out_cov[q, 5, i] = zz
                s = ab[q, 0] + ab[q, 1] * xi  # the camera of the centre's column
                dx = means[0, i] - (P0[0] + s * P1[0])
                dy = means[1, i] - (P0[1] + s * P1[1])
                dz = means[2, i] - (P0[2] + s * P1[2])
                nrm = math.sqrt(dx * dx + dy * dy + dz * dz)
                inv = 1.0 / nrm if nrm > 0.0 else 1.0
                _sh_basis(degree, dx * inv, dy * inv, dz * inv, basis)
                for ch in range(3):
                    acc = 0.0
                    for j in range(nk):
                        acc += basis[j] * sh[j * 3 + ch, i]
                    out_col[q, ch, i] = max(acc + 0.5, 0.0)


def transform_splats(rig: SliceRig, eyes: list[EyeSlice], splats: SortedSplats,
                     out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moved centres, covariances and colours of ``splats`` for each eye's slice (see the module
    docstring), in the splats' depth order: (E, 3, mp) and (E, 6, mp) float64, (E, 3, mp) float32.
    Written out for :func:`slice_pass`, the reference the in-kernel :func:`slit_views` is tested
    against (the live path never writes them)."""
    mp = splats.pc.shape[1]
    E = len(eyes)
    if out is None:
        out = (np.empty((E, 3, mp)), np.empty((E, 6, mp)), np.empty((E, 3, mp), np.float32))
    coef = np.array([eye.coefficients(rig) for eye in eyes], dtype=np.float64).reshape(E, 5)
    ab = np.array([(eye.A, eye.B) for eye in eyes], dtype=np.float64).reshape(E, 2)
    P0, P1 = _camera_line(rig)
    _transform(splats.pc, splats.cov, splats.means, splats.sh, splats.m, int(splats.degree), rig.ty, rig.tz, rig.fx,
               rig.cxm, rig.near, coef, ab, P0, P1, out[0], out[1], out[2])
    return out


def _camera_line(rig: SliceRig) -> tuple[np.ndarray, np.ndarray]:
    """P0, P1 with the camera position of column parameter s: -R^T (tx(s), ty, tz) = P0 + s P1."""
    return -rig.R.T @ np.array([rig.p0, rig.ty, rig.tz]), -rig.R.T @ np.array([rig.p1, 0.0, 0.0])


def slit_views(rig: SliceRig, eyes: list[EyeSlice], out: np.ndarray, t_min: float | None = None) -> SlitViews:
    """The eyes' slices as :class:`~holo_viewer.render.fast.SlitViews`: projected by the fast
    renderer's kernels in the same pass as the render's cameras, into ``out`` ((E, H, W, 3)
    float32). The same numbers as :func:`slice_pass` (the moved splats drawn by pinholes), bit for
    bit, without writing the moved splats out (tested)."""
    E = len(eyes)
    if out.shape != (E, rig.height, rig.width, 3):
        raise InputError(f"out: expected {(E, rig.height, rig.width, 3)}, found {out.shape}")
    P0, P1 = _camera_line(rig)
    params = np.array([(*eye.coefficients(rig), eye.A, eye.B, *P0, *P1) for eye in eyes], dtype=np.float64)
    return SlitViews(cameras=slice_cameras(rig, E), params=params.reshape(E, 13), out=out, t_min=t_min)


def slice_pass(rig: SliceRig, eyes: list[EyeSlice], out: np.ndarray) -> list[SplatPass]:
    """One :class:`~holo_viewer.render.fast.SplatPass` per eye, drawing its slice into ``out[i]``
    ((E, H, W, 3) float32) from the render's depth-sorted splats moved by :func:`transform_splats`
    (every eye's in the first pass's transform, in one pass over them): the reference the
    in-kernel :func:`slit_views` are tested against."""
    if out.shape != (len(eyes), rig.height, rig.width, 3):
        raise InputError(f"out: expected {(len(eyes), rig.height, rig.width, 3)}, found {out.shape}")
    cams = slice_cameras(rig, 1)
    done: dict[str, Any] = {}

    def make(i: int) -> SplatPass:
        def transform(splats: SortedSplats) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            if done.get("splats") is not splats:
                done["splats"], done["out"] = splats, transform_splats(rig, eyes, splats)
            pc, cov, col = done["out"]
            return pc[i], cov[i], col[i]

        return SplatPass(cameras=cams, transform=transform, out=out[i:i + 1])

    return [make(i) for i in range(len(eyes))]


def slice_depth(means: np.ndarray, opacity: np.ndarray, rig: SliceRig, eyes: list[EyeSlice], *,
                cell: int | None = None, min_opacity: float = 0.5, out: np.ndarray | None = None) -> np.ndarray:
    """(E, H, W) float32 inverse depth (1/m) of the nearest surface per slice pixel: the z-buffer
    of :func:`holo_viewer.render.view_synthesis.inverse_depth` with each centre at its slice
    column; background at the rig's zero-disparity plane."""
    coef = np.array([eye.coefficients(rig) for eye in eyes], dtype=np.float64).reshape(len(eyes), 5)
    return view_synthesis.zbuffer_depth(means, opacity, rig.R, rig.ty, rig.tz, coef, rig.fy, rig.cy, rig.near,
                                        rig.height, rig.width, rig.w_zero, cell=cell, min_opacity=min_opacity,
                                        out=out)


def warp_coefficients(rig: SliceRig, eyes: list[EyeSlice]) -> tuple[np.ndarray, np.ndarray]:
    """The slice -> view warp: (E, V, 2) ``(d0, d1)`` and (E, 2) ``(g, h)`` with
    ``xi = (u + 1/2 + d0 + d1 w) / (g + h w)`` for view ``k``'s texel column ``u``."""
    V = rig.tx.size
    kv = np.zeros((len(eyes), V, 2))
    gh = np.zeros((len(eyes), 2))
    for i, eye in enumerate(eyes):
        kv[i, :, 0] = rig.c0 + rig.c1 * eye.A - rig.cx
        kv[i, :, 1] = rig.fx * (rig.p0 + rig.p1 * eye.A - rig.tx)
        gh[i] = (1.0 - eye.B * rig.c1, -eye.B * rig.fx * rig.p1)
    return kv, gh
