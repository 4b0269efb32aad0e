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
