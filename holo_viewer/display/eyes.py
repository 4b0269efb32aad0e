"""What a tracked viewer's eyes receive from the panel, and error measured where it is seen.

Pure array code on the optics of :class:`~holo_viewer.display.simulate.VirtualDisplay` (docs/design.md
"What a viewer actually sees"). An eye at horizontal position ``xe`` (metres from the panel centre,
``xe = d tan(angle)``) and distance ``d`` looks at screen column ``x`` under
``phi(x) = atan((xe - x) / d)``, i.e. at the view coordinate ``t(x) = (phi / cone + 1/2)(N - 1)``.
A subpixel of lens view coordinate ``zeta`` sends it the weight ``exp(-(Delta / sigma)^2 / 2)``,
``Delta`` the circular distance (period N) between ``zeta`` and ``t(x)``; the weight exceeds
``threshold`` when ``|Delta| < D0 = sigma sqrt(2 ln(1 / threshold))``.

The interleave makes a subpixel of coordinate ``zeta`` read view ``round(zeta)`` (``nearest``) or
views ``floor(zeta)`` and ``floor(zeta) + 1`` (``blend``), all within ``h = 1/2`` (resp. 1) of
``zeta``. So view ``k`` is read by a received subpixel in native column ``x`` only if
``k`` lies within ``D0 + h`` of ``t(x)`` (circularly): :func:`view_columns` evaluates this for every
native column, over the eye positions a head can reach during one frame (``motion_m`` sideways,
``motion_distance_m`` in depth; ``t`` is monotone in both, so the corners of that box bound it), and
maps native columns to the quilt tile's texel columns exactly as the interleaver does
(``floor((c + 1/2) / W * tile_width)``). Tests check it against :meth:`VirtualDisplay.weights` and
the interleaver's gather indices, sample by sample.

Error where it is seen: :func:`eye_images` gives the per-eye images of a native image (the virtual
display), :func:`head_psnr` the PSNR over the head region (the bounding box of the pixels that
differ from the background in the reference), :func:`eye_psnr` the worse of the two eyes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..errors import InputError
from ..images import psnr  # the one PSNR (re-exported: eyes.psnr)
from ..validation import check_finite_scalar
from ..camera import Cameras
from .calibration import DisplayCalibration
from .simulate import VirtualDisplay

__all__ = ["TrackedViewer", "eye_positions", "view_columns", "view_segments", "eye_view_bounds", "reach_views",
           "column_tile_mask", "received_subpixels",
           "received_samples", "quilt_samples",
           "eye_cameras", "eye_view_coordinates", "scatter_eye_images", "eye_images", "head_psnr", "eye_psnr",
           "psnr", "ConeSweep", "CONE_ANGLES_DEG", "CONE_DISTANCES_M"]

#: the coarse sweep of eye positions where a group stands (issue 37): -20..20 degrees, 0.4-1.0 m
CONE_ANGLES_DEG = (-20.0, -15.0, -10.0, -5.0, 0.0, 5.0, 10.0, 15.0, 20.0)
CONE_DISTANCES_M = (0.4, 1.0)

Mode = Literal["nearest", "blend"]


@dataclass(frozen=True)
class TrackedViewer:
    """A tracked viewer's head: horizontal angle, distance and inter-pupillary distance.

    Parameters
    ----------
    angle_deg : float
        Angle of the point between the eyes to the panel normal, degrees (+ = toward the panel's
        right as the viewer sees it; the convention of :meth:`VirtualDisplay.weights`).
    distance_m : float
        Distance from the panel plane, metres (> 0).
    ipd_m : float
        Inter-pupillary distance, metres (~0.063 for adults; 0 for a single eye).
    """

    angle_deg: float = 0.0
    distance_m: float = 0.6
    ipd_m: float = 0.063

    def __post_init__(self) -> None:
        check_finite_scalar(self.angle_deg, "angle_deg", low=-80.0, high=80.0)
        check_finite_scalar(self.distance_m, "distance_m", low=0.0, low_open=True)
        check_finite_scalar(self.ipd_m, "ipd_m", low=0.0, high=0.2)

    @property
    def centre_x_m(self) -> float:
        """Sideways position of the head centre, metres: ``d tan(angle)``."""
        return self.distance_m * math.tan(math.radians(self.angle_deg))


def eye_positions(viewer: TrackedViewer) -> list[tuple[float, float]]:
    """[(angle_deg, distance_m)] of the left and right eye (one entry when ``ipd_m == 0``)."""
    xs = [viewer.centre_x_m] if viewer.ipd_m == 0 else [viewer.centre_x_m - viewer.ipd_m / 2,
                                                        viewer.centre_x_m + viewer.ipd_m / 2]
    return [(math.degrees(math.atan2(x, viewer.distance_m)), viewer.distance_m) for x in xs]


def _view_coordinate(cal: DisplayCalibration, n_views: int, x_m: np.ndarray, xe: float, d: float) -> np.ndarray:
    phi = np.degrees(np.arctan((xe - x_m) / d))
    return (phi / cal.view_cone + 0.5) * (n_views - 1)


def view_columns(calibration: DisplayCalibration, viewer: TrackedViewer, tile_width: int, *,
                 n_views: int | None = None, mode: Mode = "nearest", sigma_views: float = 0.5,
                 threshold: float = 0.01, motion_m: float = 0.02, motion_distance_m: float = 0.05) -> np.ndarray:
    """Per view, the quilt-tile texel columns that the tracked eyes can receive light from.

    Parameters
    ----------
    calibration : DisplayCalibration
    viewer : TrackedViewer
    tile_width : int
        Width of one view's tile in the quilt (pixels).
    n_views : int, optional
        Views in the quilt (default: the calibration's).
    mode : {"nearest", "blend"}
        The interleave mode (blend reads two views per subpixel).
    sigma_views : float
        Beam width of the virtual display (:class:`VirtualDisplay`), in view spacings.
    threshold : float
        Light weight above which a subpixel counts as received (0 < threshold < 1).
    motion_m, motion_distance_m : float
        Head motion margin during one frame: sideways and in distance (metres, >= 0).

    Returns
    -------
    numpy.ndarray
        (n_views, tile_width) bool: True where a received subpixel may read that texel column.
    """
    cal = calibration
    n = cal.n_views if n_views is None else int(n_views)
    if int(tile_width) < 1:
        raise InputError(f"tile_width: expected >= 1, found {tile_width}")
    near = _near_views(cal, viewer, n, mode, sigma_views, threshold, motion_m, motion_distance_m)
    near = near.any(axis=0)  # (n, W): either eye
    W = cal.screen_w
    tex_col = np.minimum(np.floor((np.arange(W) + 0.5) / W * tile_width), tile_width - 1).astype(np.int64)
    out = np.zeros((n, int(tile_width)), dtype=bool)
    vi, ci = np.nonzero(near)
    out[vi, tex_col[ci]] = True
    return out


def eye_view_bounds(calibration: DisplayCalibration, viewer: TrackedViewer, *, n_views: int | None = None,
                    motion_m: float = 0.02, motion_distance_m: float = 0.05) -> np.ndarray:
    """(E, 2, W) float64 ``t_lo``, ``t_hi``: the range of the view coordinate each eye looks at
    through every native column while the head moves within the margin (``t`` is monotone in the
    eye's sideways position and distance, so the four corners of the margin bound it)."""
    cal = calibration
    n = cal.n_views if n_views is None else int(n_views)
    check_finite_scalar(motion_m, "motion_m", low=0.0)
    check_finite_scalar(motion_distance_m, "motion_distance_m", low=0.0)
    if n < 2:
        raise InputError(f"n_views: expected >= 2, found {n}")
    W = cal.screen_w
    x_m = ((np.arange(W, dtype=np.float64) + 0.5) / W - 0.5) * cal.physical_size_m[0]  # (W,)
    d_lo = max(viewer.distance_m - motion_distance_m, 1e-3)
    d_hi = viewer.distance_m + motion_distance_m
    eyes_ = eye_positions(viewer)
    out = np.empty((len(eyes_), 2, W))
    for e, (angle, d) in enumerate(eyes_):
        xe0 = d * math.tan(math.radians(angle))
        corners = [_view_coordinate(cal, n, x_m, xe, dd) for xe in (xe0 - motion_m, xe0 + motion_m)
                   for dd in (d_lo, d_hi)]
        out[e, 0] = np.minimum.reduce(corners)
        out[e, 1] = np.maximum.reduce(corners)
    return out


def reach_views(sigma_views: float, threshold: float) -> float:
    """``D0 = sigma sqrt(2 ln(1 / threshold))``: a subpixel of lens coordinate ``zeta`` sends an
    eye at view coordinate ``t`` a weight > ``threshold`` iff ``|zeta - t| < D0`` (circularly)."""
    check_finite_scalar(threshold, "threshold", low=0.0, high=0.999, low_open=True)
    check_finite_scalar(sigma_views, "sigma_views", low=0.0, low_open=True)
    return sigma_views * math.sqrt(2.0 * math.log(1.0 / threshold))


def _view_reach(mode: Mode, sigma_views: float, threshold: float, n: int) -> float:
    """How far (views) a view may lie from an eye's view coordinate and still be shown by a
    subpixel that sends it more than ``threshold``: ``D0`` + 1/2 (nearest) or + 1 (blend)."""
    if mode not in ("nearest", "blend"):
        raise InputError(f"mode: expected 'nearest' or 'blend', found {mode!r}")
    return reach_views(sigma_views, threshold) + (0.5 if mode == "nearest" else 1.0) + 1e-9 * n  # (zeta rounding)


def _near_views(cal: DisplayCalibration, viewer: TrackedViewer, n: int, mode: Mode, sigma_views: float,
                threshold: float, motion_m: float, motion_distance_m: float) -> np.ndarray:
    """(E, n, W) bool: view k is within reach of eye e's view coordinates at native column x over
    the motion box (see :func:`view_columns`)."""
    reach = _view_reach(mode, sigma_views, threshold, n)
    bounds = eye_view_bounds(cal, viewer, n_views=n, motion_m=motion_m, motion_distance_m=motion_distance_m)
    k = np.arange(n, dtype=np.float64)[:, None]  # (n, 1)
    E, _, W = bounds.shape
    near = np.zeros((E, n, W), dtype=bool)
    for e in range(E):
        t_lo, t_hi = bounds[e, 0][None, :], bounds[e, 1][None, :]  # (1, W)
        for shift in (-n, 0, n):  # circular distance in views
            kk = k + shift
            gap = np.maximum(t_lo - kk, kk - t_hi)  # distance from kk to [t_lo, t_hi] (<= 0 inside)
            near[e] |= gap < reach
    return near


def view_segments(calibration: DisplayCalibration, viewer: TrackedViewer, *, n_views: int | None = None,
                  mode: Mode = "nearest", sigma_views: float = 0.5, threshold: float = 0.01,
                  motion_m: float = 0.02, motion_distance_m: float = 0.05,
                  bounds: np.ndarray | None = None, lobes: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Per eye and view, the native columns where a subpixel showing that view can send light to
    the eye (weight > ``threshold``) over the head-motion margin: the rule of :func:`view_columns`
    at native-column resolution, per eye. ``bounds``: the :func:`eye_view_bounds` of this viewer
    and margin when the caller has them (else computed here).

    Returns
    -------
    numpy.ndarray
        (S, 4) int64 rows (eye, view, x0, x1): native columns ``x0 <= x < x1``; eye 0 is the left
        (:func:`eye_positions`). One eye's rows of a view are disjoint; the two eyes' may overlap
        (where a subpixel's lens coordinate decides which eye it lights).
    numpy.ndarray, with ``lobes``
        (S,) int64 per row: 0 where the eye's view coordinate reaches view k itself, -1 / +1
        where it reaches it as k - n / k + n, across the lobe boundary (near the cone's edge).
    """
    cal = calibration
    n = cal.n_views if n_views is None else int(n_views)
    reach = _view_reach(mode, sigma_views, threshold, n)
    if bounds is None:
        bounds = eye_view_bounds(cal, viewer, n_views=n, motion_m=motion_m, motion_distance_m=motion_distance_m)
    elif bounds.shape != (want := (len(eye_positions(viewer)), 2, cal.screen_w)):
        raise InputError(f"bounds: expected {want}, found {bounds.shape}")
    # t_lo, t_hi fall with the column (the view coordinate turns away from the eye across the
    # panel), so view k (or k -+ n, circularly) is within reach on one run of columns:
    # t_hi(x) > k - reach on a prefix, t_lo(x) < k + reach on a suffix (the rule of view_columns)
    rows = []
    k = np.arange(n, dtype=np.float64)
    for e in range(bounds.shape[0]):
        lo_desc, hi_desc = bounds[e, 0], bounds[e, 1]
        if not (np.all(np.diff(lo_desc) <= 0) and np.all(np.diff(hi_desc) <= 0)):
            raise InputError("view_segments: the eye's view coordinate is not monotone over the panel")
        for shift in (-n, 0, n):
            kk = k + shift
            # prefix end: first column with t_hi <= kk - reach; suffix start: first with t_lo < kk + reach
            x1 = np.searchsorted(-hi_desc, -(kk - reach), side="left")
            x0 = np.searchsorted(-lo_desc, -(kk + reach), side="right")
            ok = x0 < x1
            m = int(ok.sum())
            rows.append(np.stack([np.full(m, e), np.flatnonzero(ok), x0[ok], x1[ok], np.full(m, shift // n)], axis=1))
    out = np.concatenate(rows).astype(np.int64) if rows else np.zeros((0, 5), np.int64)
    out = out[np.lexsort((out[:, 2], out[:, 1], out[:, 0]))]
    return (np.ascontiguousarray(out[:, :4]), out[:, 4].copy()) if lobes else np.ascontiguousarray(out[:, :4])


def column_tile_mask(columns: np.ndarray, tile_height: int, tile: int = 16) -> np.ndarray:
    """(V, tiles_y, tiles_x) bool renderer tile mask covering the True texel columns of each view.

    ``columns``: (V, tile_width) bool from :func:`view_columns`; every tile row is included
    (the eyes integrate whole columns of the panel)."""
    cols = np.asarray(columns, dtype=bool)
    V, W = cols.shape
    tx, ty = -(-W // tile), -(-int(tile_height) // tile)
    pad = np.zeros((V, tx * tile), dtype=bool)
    pad[:, :W] = cols
    per_tile = pad.reshape(V, tx, tile).any(axis=2)  # (V, tx)
    return np.repeat(per_tile[:, None, :], ty, axis=1)


def eye_cameras(cameras: Cameras, calibration: DisplayCalibration, viewer: TrackedViewer) -> Cameras:
    """One perspective camera per eye, interpolated from the quilt cameras (left eye first).

    Quilt camera ``k`` (Algorithm 1) sits at ``x_k = D tan(alpha_k)`` along the shared right axis
    with its principal point sheared so the focal plane (the panel) stays centred; both are affine
    in ``s = tan(alpha)``. An eye at ``(xe, d)`` sees the panel centre under ``tan(phi) = xe / d``,
    so its camera is the affine fit of the V cameras evaluated at ``s = xe / d`` (``alpha_k`` from
    the calibration's view cone, the optics of :class:`VirtualDisplay`).

    Raises
    ------
    InputError
        If the cameras are not one row of off-axis cameras sharing one rotation (fit residual).
    """
    V = len(cameras)
    if V < 2:
        raise InputError(f"cameras: expected >= 2 quilt cameras, found {V}")
    R = cameras.R
    if np.abs(R - R[0]).max() > 1e-9:
        raise InputError("cameras: expected quilt cameras sharing one rotation")
    alpha = np.radians((np.arange(V) / (V - 1) - 0.5) * calibration.view_cone)
    A = np.stack([np.ones(V), np.tan(alpha)], axis=1)  # (V, 2)
    pos = cameras.positions  # (V, 3)
    cx = cameras.K[:, 0, 2]
    coef_p, *_ = np.linalg.lstsq(A, pos, rcond=None)
    coef_c, *_ = np.linalg.lstsq(A, cx, rcond=None)
    scale = max(float(np.abs(pos - pos.mean(axis=0)).max()), 1e-12)
    if np.abs(A @ coef_p - pos).max() > 1e-6 * scale + 1e-12:
        raise InputError("cameras: positions are not affine in tan(view angle) of the calibration's view cone "
                         f"({calibration.view_cone} deg): not this calibration's quilt cameras")
    w2c, K = [], []
    for angle, dist in eye_positions(viewer):
        s_e = math.tan(math.radians(angle))  # = xe / d
        p = coef_p[0] + coef_p[1] * s_e
        M = np.eye(4)
        M[:3, :3] = R[0]
        M[:3, 3] = -R[0] @ p
        k = cameras.K[0].copy()
        k[0, 2] = coef_c[0] + coef_c[1] * s_e
        w2c.append(M)
        K.append(k)
    return Cameras(np.array(w2c), np.array(K), cameras.width, cameras.height, cameras.near, cameras.far)


def eye_view_coordinates(calibration: DisplayCalibration, viewer: TrackedViewer, n_views: int | None = None
                         ) -> np.ndarray:
    """(n_eyes, screen_w) view coordinate ``t(x)`` each eye looks at through every native column."""
    cal = calibration
    n = cal.n_views if n_views is None else int(n_views)
    W = cal.screen_w
    x_m = ((np.arange(W, dtype=np.float64) + 0.5) / W - 0.5) * cal.physical_size_m[0]
    return np.stack([_view_coordinate(cal, n, x_m, d * math.tan(math.radians(a)), d)
                     for a, d in eye_positions(viewer)])


_SCATTER = None


def scatter_eye_images(native: np.ndarray, zeta: np.ndarray, t_eyes: np.ndarray, texel: np.ndarray,
                       images: np.ndarray, n_views: int, reach: float) -> int:
    """Eye-centred output: write each eye's own image into the subpixels whose light reaches it.

    Parameters
    ----------
    native : numpy.ndarray
        (H, W, 3) uint8 native image, updated in place.
    zeta : numpy.ndarray
        (H, W, 3) float32 lens view coordinate of every subpixel (``VirtualDisplay.zeta``).
    t_eyes : numpy.ndarray
        (E, W) view coordinate each eye looks at per native column (:func:`eye_view_coordinates`).
    texel : numpy.ndarray
        (H W 3,) int32 flat index into one (h, w, 3) view of the texel (and channel) each
        subpixel samples (the interleaver's lookup, the same for every view).
    images : numpy.ndarray
        (E, h, w, 3) uint8 per-eye images.
    n_views : int
    reach : float
        A subpixel is written when its circular distance in views to the nearest eye's ``t`` is
        below ``reach`` (``sigma sqrt(2 ln(1/threshold))`` for weight > threshold); the eye with
        the smaller distance wins.

    Returns
    -------
    int
        Subpixels written.
    """
    global _SCATTER
    if _SCATTER is None:
        import numba

        @numba.njit(parallel=True, cache=True, boundscheck=False)
        def scatter(out, zeta, t, tex, imgs, W, n, reach):  # pragma: no cover - compiled
            m = out.shape[0]
            ne = t.shape[0]
            nchunks = 64
            per = (m + nchunks - 1) // nchunks
            written = np.zeros(nchunks, dtype=np.int64)
            for c in numba.prange(nchunks):
                cnt = 0
                for s in range(c * per, min(m, c * per + per)):
                    col = (s // 3) % W
                    best = reach
                    eb = -1
                    for e in range(ne):
                        d = zeta[s] - t[e, col] + 0.5 * n
                        d = d - math.floor(d / n) * n - 0.5 * n
                        d = abs(d)
                        if d < best:
                            best = d
                            eb = e
                    if eb >= 0:
                        out[s] = imgs[eb, tex[s]]
                        cnt += 1
                written[c] = cnt
            return written.sum()

        _SCATTER = scatter
    H, W, _ = native.shape
    if not (native.dtype == np.uint8 and native.flags.c_contiguous and zeta.shape == native.shape):
        raise InputError(f"native, zeta: expected a C-contiguous uint8 (H, W, 3) image and (H, W, 3) zeta, found "
                         f"{native.shape} {native.dtype}, {zeta.shape}")
    imgs = np.ascontiguousarray(images, dtype=np.uint8)
    return int(_SCATTER(native.reshape(-1), np.ascontiguousarray(zeta, dtype=np.float32).reshape(-1),
                        np.ascontiguousarray(t_eyes, dtype=np.float64), texel, imgs.reshape(len(imgs), -1),
                        W, int(n_views), float(reach)))


def received_subpixels(display: VirtualDisplay, viewer: TrackedViewer, threshold: float = 0.01) -> np.ndarray:
    """(H, W, 3) bool: native subpixels whose light weight at either eye exceeds ``threshold``
    (:meth:`VirtualDisplay.weights`; slow, ~0.3 s per eye: for tests and benchmarks)."""
    out = np.zeros((display.cal.screen_h, display.cal.screen_w, 3), dtype=bool)
    for angle, dist in eye_positions(viewer):
        out |= display.weights(angle, dist) > threshold
    return out


def quilt_samples(interleaver: Any, subpixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(view, row, column) in the view's tile (row 0 at the top) of every quilt value that the
    listed flat native subpixels read (both views of a blended subpixel: twice as many entries)."""
    i0, i1, _ = interleaver.gather_indices()
    sub = np.asarray(subpixels, dtype=np.int64)
    idx = i0[sub] if i1 is None else np.concatenate([i0[sub], i1[sub]])
    Hq, Wq, _ = interleaver.quilt_shape
    tw, th = Wq // interleaver.cols, Hq // interleaver.rows
    pix = idx.astype(np.int64) // 3
    qr, qc = pix // Wq, pix % Wq
    r_from_bottom = (Hq - 1 - qr) // th
    view = qc // tw + interleaver.cols * r_from_bottom
    return view, qr - (Hq - (r_from_bottom + 1) * th), qc % tw


def received_samples(display: VirtualDisplay, interleaver: Any, viewer: TrackedViewer, threshold: float = 0.01
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (view, row, column) quilt samples either eye receives with light weight > ``threshold``:
    :func:`received_subpixels` mapped through the interleaver's gather indices (repeats included)."""
    return quilt_samples(interleaver, np.flatnonzero(received_subpixels(display, viewer, threshold).reshape(-1)))


def eye_images(display: VirtualDisplay, native: np.ndarray, viewer: TrackedViewer) -> list[np.ndarray]:
    """Per-eye perceived images (:meth:`VirtualDisplay.see`) of a native image, left eye first."""
    return [display.see(native, a, d) for a, d in eye_positions(viewer)]


def head_psnr(ref: np.ndarray, test: np.ndarray, background: tuple[float, float, float] = (0.0, 0.0, 0.0),
              pad: int = 4) -> float:
    """PSNR over the head region: the bounding box (grown by ``pad`` pixels) of the pixels where
    the reference ``ref`` (H, W, 3) in [0, 1] differs from ``background`` by more than 2/255
    (the whole image when none does)."""
    ref = np.asarray(ref, dtype=np.float64)
    test = np.asarray(test, dtype=np.float64)
    if ref.shape != test.shape or ref.ndim != 3:
        raise InputError(f"head_psnr: expected two (H, W, 3) images of one shape, found {ref.shape}, {test.shape}")
    fg = np.abs(ref - np.asarray(background, dtype=np.float64)).max(axis=2) > 2.0 / 255.0
    if fg.any():
        rows, cols = np.flatnonzero(fg.any(axis=1)), np.flatnonzero(fg.any(axis=0))
        r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, ref.shape[0])
        c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, ref.shape[1])
        ref, test = ref[r0:r1, c0:c1], test[r0:r1, c0:c1]
    return psnr(ref, test)


def eye_psnr(display: VirtualDisplay, ref_native: np.ndarray, test_native: np.ndarray, viewer: TrackedViewer,
             background: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> float:
    """Head-region PSNR of the per-eye images of ``test_native`` against ``ref_native``: the worse eye."""
    pairs = [display.see_many([ref_native, test_native], a, d) for a, d in eye_positions(viewer)]
    return min(head_psnr(r, t, background) for r, t in pairs)


class ConeSweep:
    """The images single eyes at fixed positions of the viewing cone perceive
    (:meth:`VirtualDisplay.see`), with each position's light weights computed once: the error of a
    live frame where a group stands, against the present full-quality frame.

    Each position keeps the subpixels that send it more than ``cutoff`` of the strongest weight
    (~9 % of the panel) and their window sums; :meth:`see` then costs a scatter and the window
    sums of one image (about half of ``VirtualDisplay.see``), and differs from it by less than
    ``cutoff`` (relative) per pixel (tested).

    Parameters
    ----------
    display : VirtualDisplay
    positions : sequence of (angle_deg, distance_m)
        Default: every pair of :data:`CONE_ANGLES_DEG` x :data:`CONE_DISTANCES_M`.
    cutoff : float
        Relative weight below which a subpixel is left out.
    """

    def __init__(self, display: VirtualDisplay, positions: Any = None, cutoff: float = 1e-4) -> None:
        from .simulate import _box

        if positions is None:
            positions = [(a, d) for d in CONE_DISTANCES_M for a in CONE_ANGLES_DEG]
        self.display = display
        self.positions = [(float(a), float(d)) for a, d in positions]
        if not self.positions:
            raise InputError("positions: expected at least one (angle_deg, distance_m), found none")
        self._w: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for a, d in self.positions:
            w = display.weights(a, d).astype(np.float32)
            idx = np.flatnonzero(w.reshape(-1) > cutoff).astype(np.int64)
            den = _box(w, display.window, display.downsample)
            self._w.append((idx, w.reshape(-1)[idx], den))

    def see(self, native: np.ndarray, k: int) -> np.ndarray:
        """(h, w, 3) float32 in [0, 1]: what an eye at ``positions[k]`` perceives of ``native``."""
        from .simulate import _box

        H, W = self.display.cal.screen_h, self.display.cal.screen_w
        img = np.asarray(native)
        if img.shape != (H, W, 3):
            raise InputError(f"native: expected shape ({H}, {W}, 3), found {img.shape}")
        idx, w, den = self._w[k]
        vals = img.reshape(-1)[idx].astype(np.float32)
        if img.dtype == np.uint8:
            vals *= np.float32(1.0 / 255.0)
        dense = np.zeros(H * W * 3, dtype=np.float32)
        dense[idx] = w * vals
        num = _box(dense.reshape(H, W, 3), self.display.window, self.display.downsample)
        res = np.divide(num, den, out=np.zeros_like(num), where=den > 1e-12)
        return np.clip(res, 0.0, 1.0).astype(np.float32)

    def psnr(self, ref_native: np.ndarray, test_native: np.ndarray,
             background: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """(P,) head-region PSNR (:func:`head_psnr`) of each position's image of ``test_native``
        against its image of ``ref_native`` (the present full-quality frame)."""
        return np.array([head_psnr(self.see(ref_native, k), self.see(test_native, k), background)
                         for k in range(len(self.positions))])
