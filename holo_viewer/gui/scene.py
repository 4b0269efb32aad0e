"""Geometry of the inspection scene: FLAME mesh, Gaussian ellipsoid glyphs, camera frusta.

The ``*_arrays`` functions are pure numpy (testable without VTK) and return points,
connectivity and per-element scalars; the ``*_polydata`` wrappers turn them into
``pyvista.PolyData`` (pyvista is imported lazily, inside them).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError
from ..geometry import quat_to_rotmat_np
from ..validation import check_array

__all__ = [
    "frusta_arrays", "cut_segments_at_box", "focal_plane_corners", "ellipsoid_glyph_arrays", "subsample_indices",
    "unit_icosphere", "mesh_polydata", "frusta_polydata", "focal_plane_polydata", "glyph_polydata",
    "image_plane", "view_colors", "glyph_selection", "glyph_colors", "GLYPH_COLOR_MODES",
    "AU_DESCRIPTIONS", "au_label", "scene_bounds", "live_vertex_normals", "decimated_faces",
]

#: FACS action-unit names (Ekman & Friesen) of the default head's expression components
AU_DESCRIPTIONS: dict[str, str] = {
    "AU1": "inner brow raiser", "AU2": "outer brow raiser", "AU4": "brow lowerer", "AU5": "upper lid raiser",
    "AU6": "cheek raiser", "AU7": "lid tightener", "AU9": "nose wrinkler", "AU10": "upper lip raiser",
    "AU12": "lip corner puller", "AU14": "dimpler", "AU15": "lip corner depressor", "AU16": "lower lip depressor",
    "AU17": "chin raiser", "AU18": "lip pucker", "AU20": "lip stretcher", "AU23": "lip tightener",
    "AU24": "lip pressor", "AU25": "lips part", "AU26": "jaw drop", "AU43": "eyes closed",
}

#: how the ellipsoid glyphs are coloured: their own (DC) colour, their opacity, their largest sigma
GLYPH_COLOR_MODES: tuple[str, ...] = ("colour", "opacity", "size")


def au_label(name: str) -> str:
    """Slider title of an expression component: ``"AU9"`` -> ``"AU9 nose wrinkler"``,
    ``"AU2_L"`` -> ``"AU2 outer brow raiser (left)"``; other names are returned as they are."""
    base, _, side = str(name).partition("_")
    desc = AU_DESCRIPTIONS.get(base)
    if desc is None:
        return str(name)
    return f"{base} {desc}" + {"L": " (left)", "R": " (right)"}.get(side, "")


# ============================================================================ numpy


def focal_plane_corners(cameras: Any, focal_center: np.ndarray, view: int | None = None) -> np.ndarray:
    """(4, 3) world corners of the image rectangle of ``view`` at the focal-plane depth.

    Order: top-left, top-right, bottom-right, bottom-left (image orientation). ``view``
    None = the middle view. With Algorithm 1's sheared cameras every view's rectangle at
    the focal depth is the same focal plane.
    """
    c = np.asarray(focal_center, dtype=np.float64).reshape(3)
    i = len(cameras) // 2 if view is None else int(view)
    R, t, K = cameras.R[i], cameras.t[i], cameras.K[i]
    depth = float((R @ c + t)[2])
    if not depth > 0:
        raise InputError(f"focal_center: expected in front of camera {i}, found depth {depth:.4g} m")
    W, H = cameras.width, cameras.height
    px = np.array([[0.0, 0.0], [W, 0.0], [W, H], [0.0, H]])
    x = (px[:, 0] - K[0, 2]) / K[0, 0] * depth
    y = (px[:, 1] - K[1, 2]) / K[1, 1] * depth
    pc = np.stack([x, y, np.full(4, depth)], axis=1)
    return (pc - t) @ R  # R^T (pc - t)


def frusta_arrays(cameras: Any, focal_center: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line segments of every camera's frustum from its centre to the focal plane.

    Returns
    -------
    points : numpy.ndarray
        (V * 5, 3) camera centre then the 4 focal-plane corners of each view.
    lines : numpy.ndarray
        (V * 8, 2) point-index pairs: 4 edges apex->corner and the 4 rectangle edges.
    view_index : numpy.ndarray
        (V * 8,) int view index of each segment.
    """
    V = len(cameras)
    pts = np.empty((V, 5, 3))
    pts[:, 0] = cameras.positions
    for i in range(V):
        pts[i, 1:] = focal_plane_corners(cameras, focal_center, i)
    base = (np.arange(V) * 5)[:, None, None]
    local = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]])
    lines = (base + local[None]).reshape(-1, 2)
    return pts.reshape(-1, 3), lines, np.repeat(np.arange(V), 8)


def cut_segments_at_box(a: np.ndarray, b: np.ndarray, clip: np.ndarray, box: tuple[float, float, float, float],
                        eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parts of 3D segments a->b that a perspective camera draws outside a screen rectangle.

    ``clip`` is the (4, 4) world -> clip-space matrix (VTK's composite projection), ``box`` (x0, y0, x1, y1)
    in normalised device coordinates. A segment is first cut to the camera's front (clip w > ``eps``;
    what lies behind is dropped, as the renderer drops it); its projection, a straight 2D segment, is cut by
    the rectangle (Liang-Barsky) and the 2D parameters are mapped back to the 3D segment perspective-
    correctly (t = s wA / ((1 - s) wB + s wA)), so a piece's projection touches the rectangle at most at its
    border. Returns (starts, ends, source) with ``source`` the index of each piece's segment (0, 1 or 2
    pieces a segment).
    """
    A = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    B = np.asarray(b, dtype=np.float64).reshape(-1, 3)
    M = np.asarray(clip, dtype=np.float64)
    ha = A @ M[:, :3].T + M[:, 3]
    hb = B @ M[:, :3].T + M[:, 3]
    wa, wb = ha[:, 3], hb[:, 3]
    keep = (wa > eps) | (wb > eps)
    with np.errstate(divide="ignore", invalid="ignore"):
        tf = np.where(wa == wb, 0.0, (eps - wa) / (wb - wa))[:, None]  # where w crosses eps
    cut_a, cut_b = (wa <= eps)[:, None], (wb <= eps)[:, None]  # cut to the front of the camera
    A, ha, B, hb = (np.where(cut_a, A + tf * (B - A), A), np.where(cut_a, ha + tf * (hb - ha), ha),
                    np.where(cut_b, A + tf * (B - A), B), np.where(cut_b, ha + tf * (hb - ha), hb))
    wa, wb = ha[:, 3], hb[:, 3]
    safe_a, safe_b = np.where(keep, wa, 1.0), np.where(keep, wb, 1.0)
    qa, qb = ha[:, :2] / safe_a[:, None], hb[:, :2] / safe_b[:, None]
    d = qb - qa
    x0, y0, x1, y1 = (float(v) for v in box)
    P = np.stack([-d[:, 0], d[:, 0], -d[:, 1], d[:, 1]], axis=1)  # Liang-Barsky
    Q = np.stack([qa[:, 0] - x0, x1 - qa[:, 0], qa[:, 1] - y0, y1 - qa[:, 1]], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        R = Q / P
    s_in = np.maximum(0.0, np.where(P < 0.0, R, -np.inf).max(axis=1))
    s_out = np.minimum(1.0, np.where(P > 0.0, R, np.inf).min(axis=1))
    miss = ((P == 0.0) & (Q < 0.0)).any(axis=1) | (s_in >= s_out)  # parallel outside an edge, or no overlap

    def at(s: np.ndarray) -> np.ndarray:  # 2D parameter -> point on the 3D segment (perspective-correct)
        t = s * safe_a / ((1.0 - s) * safe_b + s * safe_a)
        return A + t[:, None] * (B - A)
    whole = keep & miss
    first = keep & ~miss & (s_in > 0.0)
    last = keep & ~miss & (s_out < 1.0)
    p_in, p_out = at(np.where(miss, 0.0, s_in)), at(np.where(miss, 1.0, s_out))
    starts = np.concatenate([A[whole], A[first], p_out[last]])
    ends = np.concatenate([B[whole], p_in[first], B[last]])
    idx = np.arange(len(A))
    return starts, ends, np.concatenate([idx[whole], idx[first], idx[last]]).astype(np.int64)


_ICO_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def unit_icosphere(subdivisions: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (P, 3) on the unit sphere and triangles (T, 3) of a subdivided icosahedron."""
    if subdivisions in _ICO_CACHE:
        return _ICO_CACHE[subdivisions]
    p = (1 + 5 ** 0.5) / 2
    v = [[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0], [0, -1, p], [0, 1, p], [0, -1, -p], [0, 1, -p],
         [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts = [np.array(x, dtype=np.float64) / np.linalg.norm(x) for x in v]
    faces = [tuple(x) for x in f]
    for _ in range(subdivisions):
        mid: dict[tuple[int, int], int] = {}

        def midpoint(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in mid:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                mid[key] = len(verts) - 1
            return mid[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    out = (np.array(verts), np.array(faces, dtype=np.int64))
    _ICO_CACHE[subdivisions] = out
    return out


def subsample_indices(n: int, max_count: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``max_count`` of ``n`` items (deterministic random subset)."""
    if max_count <= 0:
        raise InputError(f"max_count: expected > 0, found {max_count}")
    if n <= max_count:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n, size=max_count, replace=False))


def ellipsoid_glyph_arrays(means: np.ndarray, quats: np.ndarray, scales: np.ndarray, *,
                           sigmas: float = 1.0, subdivisions: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Triangle meshes of the ``sigmas``-sigma ellipsoids of N Gaussians.

    Point ``p`` of Gaussian ``n`` is ``means[n] + R_n diag(sigmas * scales[n]) u_p`` for the unit
    icosphere points ``u_p``.

    Parameters
    ----------
    means, scales : numpy.ndarray
        (N, 3) centres (metres) and standard deviations (metres).
    quats : numpy.ndarray
        (N, 4) wxyz rotations.

    Returns
    -------
    points : numpy.ndarray
        (N * P, 3) float64.
    triangles : numpy.ndarray
        (N * T, 3) int64 point indices.
    """
    sizes: dict[str, int] = {}
    means = check_array(np.asarray(means, dtype=np.float64), "means", ("N", 3), sizes=sizes)
    quats = check_array(np.asarray(quats, dtype=np.float64), "quats", ("N", 4), sizes=sizes)
    scales = check_array(np.asarray(scales, dtype=np.float64), "scales", ("N", 3), sizes=sizes)
    unit, tri = unit_icosphere(subdivisions)
    R = quat_to_rotmat_np(quats)  # (N, 3, 3)
    M = R * (sigmas * scales)[:, None, :]  # R diag(s)
    pts = means[:, None, :] + np.einsum("nij,pj->npi", M, unit)
    P = unit.shape[0]
    tris = (np.arange(means.shape[0]) * P)[:, None, None] + tri[None]
    return pts.reshape(-1, 3), tris.reshape(-1, 3)


def glyph_selection(opacities: np.ndarray, count: int, min_opacity: float = 0.0, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most ``count`` Gaussians among those with opacity >= ``min_opacity``.

    A deterministic random subset (``seed``), so the same controls always draw the same glyphs.
    """
    o = np.asarray(opacities, dtype=np.float64).reshape(-1)  # (N,)
    if not 0.0 <= min_opacity < 1.0:
        raise InputError(f"min_opacity: expected in [0, 1), found {min_opacity}")
    keep = np.flatnonzero(o >= min_opacity)
    if keep.size == 0:
        return keep
    return keep[subsample_indices(keep.size, int(count), seed)]


def glyph_colors(gaussians: Any, index: np.ndarray, mode: str = "colour") -> np.ndarray:
    """(len(index), 3) uint8 colour of each drawn glyph.

    ``mode``: ``"colour"`` the Gaussian's DC colour; ``"opacity"`` its opacity on viridis (0 dark
    blue, 1 yellow); ``"size"`` its largest standard deviation on plasma, log scale between the 2nd
    and 98th percentile of the drawn glyphs (small dark blue, large yellow).
    """
    import matplotlib

    g = gaussians.numpy() if gaussians.is_torch else gaussians
    idx = np.asarray(index, dtype=np.int64)
    if mode == "colour":
        rgb = np.clip(g.colors_dc()[idx], 0.0, 1.0)
    elif mode == "opacity":
        rgb = matplotlib.colormaps["viridis"](np.asarray(g.opacities, dtype=np.float64)[idx])[:, :3]
    elif mode == "size":
        s = np.asarray(g.log_scales, dtype=np.float64)[idx].max(axis=1) if idx.size else np.zeros(0)
        lo, hi = (np.percentile(s, [2, 98]) if s.size else (0.0, 1.0))
        t = np.clip((s - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
        rgb = matplotlib.colormaps["plasma"](t)[:, :3]
    else:
        raise InputError(f"glyph colour mode: expected one of {GLYPH_COLOR_MODES}, found {mode!r}")
    return (np.asarray(rgb) * 255 + 0.5).astype(np.uint8)


def scene_bounds(*point_sets: np.ndarray, pad: float = 0.05) -> tuple[float, ...]:
    """(xmin, xmax, ymin, ymax, zmin, zmax) around all the (N, 3) point sets, padded by ``pad`` x the size."""
    pts = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in point_sets], axis=0)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    m = pad * float(np.max(hi - lo))
    return (lo[0] - m, hi[0] + m, lo[1] - m, hi[1] + m, lo[2] - m, hi[2] + m)


def view_colors(n_views: int, cmap: str = "turbo") -> np.ndarray:
    """(n_views, 3) float RGB in [0, 1] of each view index (view 0 = first colour of ``cmap``)."""
    import matplotlib

    cm = matplotlib.colormaps[cmap]
    return np.asarray(cm(np.linspace(0.0, 1.0, max(n_views, 1)))[:, :3], dtype=np.float64)


# ============================================================================ pyvista


def _faces_to_vtk(tri: np.ndarray) -> np.ndarray:
    tri = np.asarray(tri, dtype=np.int64)
    return np.hstack([np.full((tri.shape[0], 1), 3, dtype=np.int64), tri]).ravel()


def _normals_kernel(v, f, out):  # noqa: ANN001, ANN202 - numba kernel (see live_vertex_normals)
    out[:] = 0.0
    for k in range(f.shape[0]):
        a, b, c = f[k, 0], f[k, 1], f[k, 2]
        e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
        e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        for i in (a, b, c):
            out[i, 0] += nx
            out[i, 1] += ny
            out[i, 2] += nz
    for i in range(out.shape[0]):
        n = np.sqrt(out[i, 0] * out[i, 0] + out[i, 1] * out[i, 1] + out[i, 2] * out[i, 2])
        if n > 0.0:
            out[i, 0] /= n
            out[i, 1] /= n
            out[i, 2] /= n
    return out


_NORMALS_NB: Any = None


def live_vertex_normals(vertices: np.ndarray, faces: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The viewer's fast path of :func:`~holo_viewer.geometry.vertex_normals` (the float64 reference:
    same area-weighted sum, same float64 arithmetic, equal to ~1e-15): one serial numba loop over the
    faces, ~10x faster on the default head (31k vertices; a live slider step recomputes them). ``out``:
    a (V, 3) float64 array to fill (returned)."""
    global _NORMALS_NB
    if _NORMALS_NB is None:
        from numba import njit

        _NORMALS_NB = njit(cache=True, error_model="numpy")(_normals_kernel)
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if out is None:
        out = np.empty((v.shape[0], 3), np.float64)
    return _NORMALS_NB(v, f, out)


def decimated_faces(vertices: np.ndarray, faces: np.ndarray, reduction: float) -> np.ndarray:
    """(m, 3) triangles of a decimated copy of the mesh, as indices into ``vertices`` (its points are a
    subset of the mesh's own, so the copy follows any deformation of ``vertices`` by indexing).

    ``vtkDecimatePro`` removes about ``reduction`` of the triangles (topology preserved, no splitting, the
    boundary kept) by collapsing edges onto existing vertices; each kept point carries its index in
    ``vertices`` through the filter. The viewer draws it as the stand-in mesh while a face slider is
    dragged (the mesh's per-triangle cost is most of that frame with software OpenGL)."""
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    v = check_array(np.asarray(vertices, dtype=np.float64), "vertices", ("V", 3))
    f = np.asarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"faces: expected (F, 3) triangle indices, found shape {f.shape}")
    if not 0.0 <= float(reduction) < 1.0:
        raise InputError(f"reduction: expected in [0, 1), found {reduction}")
    if float(reduction) == 0.0 or len(f) == 0:
        return f.copy()
    poly = mesh_polydata(v, f)
    ids = numpy_to_vtk(np.arange(len(v), dtype=np.int64), deep=True)
    ids.SetName("vertex_id")
    poly.GetPointData().AddArray(ids)
    dec = vtk.vtkDecimatePro()
    dec.SetInputData(poly)
    dec.SetTargetReduction(float(reduction))
    dec.PreserveTopologyOn()
    dec.SplittingOff()
    dec.BoundaryVertexDeletionOff()
    dec.Update()
    out = dec.GetOutput()
    kept = vtk_to_numpy(out.GetPointData().GetArray("vertex_id")).astype(np.int64)
    cells = vtk_to_numpy(out.GetPolys().GetConnectivityArray()).astype(np.int64)
    return kept[cells].reshape(-1, 3)


def mesh_polydata(vertices: np.ndarray, faces: np.ndarray, normals: bool = False) -> Any:
    """``pyvista.PolyData`` of a triangle mesh ((V, 3) vertices, (F, 3) faces); ``normals``: with its
    vertex normals (:func:`~holo_viewer.geometry.vertex_normals`) as the active point normals ``Normals``
    (smooth shading without a normals filter in the VTK pipeline)."""
    import pyvista as pv

    v = check_array(np.asarray(vertices, dtype=np.float64), "vertices", ("V", 3))
    poly = pv.PolyData(v.copy(), faces=_faces_to_vtk(faces))
    if normals:
        poly.point_data["Normals"] = live_vertex_normals(v, faces)
        poly.point_data.active_normals_name = "Normals"
    return poly


def frusta_polydata(cameras: Any, focal_center: np.ndarray) -> Any:
    """Frustum line segments with a ``view`` cell array (int view index)."""
    import pyvista as pv

    pts, lines, vid = frusta_arrays(cameras, focal_center)
    cells = np.hstack([np.full((lines.shape[0], 1), 2, dtype=np.int64), lines]).ravel()
    poly = pv.PolyData(pts, lines=cells)
    poly.cell_data["view"] = vid
    return poly


def focal_plane_polydata(cameras: Any, focal_center: np.ndarray) -> Any:
    """The focal plane (zero-parallax plane) as one quad."""
    import pyvista as pv

    c = focal_plane_corners(cameras, focal_center)
    return pv.PolyData(c, faces=np.array([4, 0, 1, 2, 3]))


def glyph_polydata(gaussians: Any, index: np.ndarray, *, sigmas: float = 1.0, subdivisions: int = 1,
                   color_mode: str = "colour") -> Any:
    """Ellipsoid glyphs of the Gaussians ``index`` with an ``rgb`` uint8 point array (:func:`glyph_colors`)."""
    import pyvista as pv

    g = gaussians.numpy() if gaussians.is_torch else gaussians
    idx = np.asarray(index)
    pts, tri = ellipsoid_glyph_arrays(g.means[idx], g.quats[idx], np.exp(g.log_scales[idx]),
                                      sigmas=sigmas, subdivisions=subdivisions)
    poly = pv.PolyData(pts, faces=_faces_to_vtk(tri))
    P = unit_icosphere(subdivisions)[0].shape[0]
    poly.point_data["rgb"] = np.repeat(glyph_colors(g, idx, color_mode), P, axis=0)
    return poly


def image_plane(width: float, height: float) -> Any:
    """A ``width`` x ``height`` textured quad in the z = 0 plane (image row 0 at +y)."""
    import pyvista as pv

    return pv.Plane(center=(0.0, 0.0, 0.0), direction=(0.0, 0.0, 1.0), i_size=width, j_size=height,
                    i_resolution=1, j_resolution=1)
