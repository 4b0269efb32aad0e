"""The viewer's geometry helpers that need no window: the live-step vertex normals (numba fast path)
against the float64 reference :func:`holo_viewer.geometry.vertex_normals`."""

from __future__ import annotations

import numpy as np


def test_live_vertex_normals_match_the_float64_reference():
    from holo_viewer.geometry import vertex_normals
    from holo_viewer.gui.scene import live_vertex_normals, unit_icosphere

    pts, tri = unit_icosphere(2)
    rng = np.random.default_rng(3)
    verts = pts * (1.0 + 0.2 * rng.random((len(pts), 1)))  # irregular areas: the weighting matters
    verts = np.vstack([verts, [[5.0, 5.0, 5.0]]])  # a vertex no triangle uses: zero normal
    faces = np.vstack([tri, [[0, 0, 1]]]).astype(np.int32)  # a degenerate triangle adds nothing
    ref = vertex_normals(verts, faces)
    out = np.full((len(verts), 3), np.nan)
    got = live_vertex_normals(verts, faces, out=out)
    assert got is out
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    assert np.all(got[-1] == 0.0)
    # can fail: unweighted (unit face normals) averaging, as vtkPolyDataNormals does, is measurably different
    fn = np.cross(verts[tri[:, 1]] - verts[tri[:, 0]], verts[tri[:, 2]] - verts[tri[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    unweighted = np.zeros_like(verts)
    for c in range(3):
        np.add.at(unweighted, tri[:, c], fn)
    unweighted[:-1] /= np.linalg.norm(unweighted[:-1], axis=1, keepdims=True)
    assert np.abs(unweighted[:-1] - got[:-1]).max() > 1e-3


def test_overlay_cut_keeps_every_visible_part_outside_the_head_box_and_nothing_inside():
    """scene.cut_segments_at_box (the overlay lines over the splats) against dense float64 sampling: no
    drawn point projects inside the rectangle, every point in front of the camera and outside it is drawn."""
    from holo_viewer.gui.scene import cut_segments_at_box

    rng = np.random.default_rng(0)
    n, f, c = 0.1, 10.0, 1.0 / np.tan(np.radians(20.0))  # a 40 deg perspective camera looking down -z
    P = np.array([[c, 0, 0, 0], [0, c, 0, 0], [0, 0, -(f + n) / (f - n), -2 * f * n / (f - n)], [0, 0, -1, 0]])
    a = rng.normal(size=(60, 3)) * 2 + [0, 0, -2]  # some behind the camera (z > 0)
    b = rng.normal(size=(60, 3)) * 2 + [0, 0, -2]
    box = (-0.3, -0.2, 0.4, 0.3)
    s, e, src = cut_segments_at_box(a, b, P, box)
    T = np.linspace(0.0, 1.0, 1001)

    def ndc(X):
        h = np.c_[X, np.ones(len(X))] @ P.T
        return h[:, :2] / h[:, 3:4], h[:, 3]

    def inside(q, w, tol=0.0):
        return (w > 1e-6) & (q[:, 0] > box[0] + tol) & (q[:, 0] < box[2] - tol) & (q[:, 1] > box[1] + tol) & \
            (q[:, 1] < box[3] - tol)
    crossed = 0
    for i in range(len(a)):
        d = b[i] - a[i]
        q, w = ndc(a[i] + T[:, None] * d)
        crossed += inside(q, w).any()
        covered = np.zeros(len(T), bool)
        for k in np.flatnonzero(src == i):
            Y = s[k] + T[:, None] * (e[k] - s[k])
            assert not inside(*ndc(Y), tol=1e-9).any(), i
            t = (Y - a[i]) @ d / (d @ d)
            covered |= (T >= t.min() - 1e-9) & (T <= t.max() + 1e-9)
        assert not ((w > 1e-6) & ~inside(q, w) & ~covered).any(), i
    assert crossed >= 3 and len(src) != len(a)  # the sample does cut lines: the test can fail


def test_decimated_stand_in_uses_the_mesh_points_and_stays_on_its_surface():
    """The face-drag stand-in (gui/scene.py: decimated_faces) on a sphere: about the asked fraction of the
    triangles removed, every triangle over the mesh's own vertices (so it follows the live LBS by index),
    and its surface still the sphere's (triangle centroids near radius 1)."""
    from holo_viewer.gui.scene import decimated_faces, unit_icosphere

    pts, tri = unit_icosphere(3)  # 1280 triangles
    verts = pts * 1.0
    out = decimated_faces(verts, tri, 0.5)
    assert 0.4 * len(tri) <= len(out) <= 0.6 * len(tri), len(out)
    assert out.dtype == np.int64 and out.min() >= 0 and out.max() < len(verts)
    assert np.all((out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 0] != out[:, 2]))
    r = np.linalg.norm(verts[out].mean(axis=1), axis=1)
    assert r.min() > 0.9 and r.max() <= 1.0
    assert np.array_equal(decimated_faces(verts, tri, 0.0), tri)  # 0: the whole mesh


def test_stand_in_reduction_is_checked():
    import pytest

    from holo_viewer.errors import InputError
    from holo_viewer.gui.viewer_config import ViewerConfig

    with pytest.raises(InputError, match=r"standin_reduction: expected in \[0, 1\), found 1.0"):
        ViewerConfig(standin_reduction=1.0)


def test_camera_drag_frame_waits_for_the_splat_render_longer_after_slow_renders():
    """A camera-drag frame waits for the splat image in flight (SPLAT_HOLD_S), up to 1.5 x the last drag
    render when that was slower (a loaded machine), at most SPLAT_HOLD_MAX_S; then it draws."""
    import time
    from types import SimpleNamespace

    from holo_viewer.gui.splat_view import SPLAT_HOLD_MAX_S, SPLAT_HOLD_S, SplatViewMixin

    class Stub(SplatViewMixin):
        def _camera_moving(self) -> bool:
            return True

    v = Stub()
    v._dirty_parts, v._splat_fresh, v._splat_requested = {"scene"}, False, ("pose",)
    v.timings = SimpleNamespace(splat_drag_ms=None)

    def holding(waited_s: float, last_ms: float | None) -> bool:
        v._splat_requested_at, v.timings.splat_drag_ms = time.perf_counter() - waited_s, last_ms
        return v._holding_for_splat()

    assert holding(0.5 * SPLAT_HOLD_S, None) and not holding(SPLAT_HOLD_S + 0.05, None)
    assert holding(SPLAT_HOLD_S + 0.05, 200.0) and not holding(0.35, 200.0)  # 1.5 x 200 ms
    assert holding(SPLAT_HOLD_MAX_S - 0.05, 2000.0) and not holding(SPLAT_HOLD_MAX_S + 0.05, 2000.0)
    v._splat_fresh = True  # an image arrived: draw it now
    assert not holding(0.0, None)
