"""The live group frame's per-frame CPU savings (issue 37) give the same bytes as the work they replace:
the fused drawn-Gaussian deform, the warp's plan kept between frames, and the pixel table the warp trusts."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pytest

from holo_viewer.display.calibration import DisplayCalibration
from holo_viewer.display.cameras import make_quilt_cameras
from holo_viewer.errors import InputError
from holo_viewer.render import view_synthesis as vs

bk = pytest.importorskip("holo_viewer.avatar._bind_kernels")


def _mesh(rng: np.random.Generator, n_verts: int = 60, n_faces: int = 90, n_gauss: int = 400):
    verts = rng.normal(0.0, 0.05, (n_verts, 3)).astype(np.float32)
    faces = rng.integers(0, n_verts, (n_faces, 3)).astype(np.int64)
    faces[3] = (7, 7, 9)  # degenerate: two corners in one vertex
    faces[4] = (11, 12, 13)
    verts[13] = verts[11] + 2.0 * (verts[12] - verts[11])  # degenerate: collinear
    binding = rng.integers(0, n_faces, n_gauss).astype(np.int64)  # not ordered by face, as the avatar's
    binding[:2] = (3, 4)  # Gaussians on the degenerate faces
    mu = rng.normal(0.0, 0.3, (n_gauss, 3)).astype(np.float32)
    ql = rng.normal(0.0, 1.0, (n_gauss, 4)).astype(np.float32)
    ls = rng.normal(-4.0, 0.5, (n_gauss, 3)).astype(np.float32)
    return verts, faces, binding, mu, ql, ls


def test_fused_drawn_deform_writes_the_frames_then_bind_subset_rows_bit_for_bit() -> None:
    """bind_faces_nb (each face's frame applied at once to its Gaussians, the live renderer's drawn deform)
    against face_frames_nb over the drawn faces then bind_subset_nb: the same rows, degenerate faces
    included, and the Gaussians not drawn untouched."""
    rng = np.random.default_rng(4)
    verts, faces, binding, mu, ql, ls = _mesh(rng)
    n = binding.size
    index = np.union1d(rng.choice(n, 250, replace=False), [0, 1])
    mask = np.zeros(len(faces), dtype=bool)
    mask[binding[index]] = True
    frame, deg = bk.frames(verts, faces, 1e-12, mask)
    assert deg[3] and deg[4] and deg.sum() < 10
    ref = [np.full((n, c), 7.0, np.float32) for c in (3, 4, 3)]
    bk.bind_subset_nb(frame, binding, mu, ql, ls, index, *ref)
    tables = bk.face_order(binding, index, mu, ql, ls)
    face_list, starts, by_face = tables[:3]
    np.testing.assert_array_equal(face_list, np.unique(binding[index]))
    np.testing.assert_array_equal(np.sort(by_face), index)
    assert (np.diff(binding[by_face]) >= 0).all() and starts[-1] == index.size
    out = [np.full((n, c), 7.0, np.float32) for c in (3, 4, 3)]
    bk.bind_faces_nb(verts, faces, 1e-12, *tables, *out)
    for a, b in zip(ref, out):
        np.testing.assert_array_equal(a, b)  # drawn rows equal, the others still 7
    assert (out[0][np.setdiff1d(np.arange(n), index)] == 7.0).all()


@pytest.fixture(scope="module")
def small_rig():
    cal = DisplayCalibration.load(None).with_quilt(8, 1, 8 * 24, 16)  # 8 views of 24 x 16 pixels
    cams = make_quilt_cameras(cal, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)
    return cams, vs.rig_of(cams)


def _warp_inputs(cams, rng: np.random.Generator):
    V, H, W = len(cams), cams.height, cams.width
    sources = vs.source_views(V, 3)
    images = rng.uniform(size=(sources.size, H, W, 3)).astype(np.float32)
    wmaps = rng.uniform(0.6, 1.4, size=(sources.size, H, W)).astype(np.float32)
    tiles = np.array([[0, k * W] for k in range(V)], dtype=np.int64)
    return sources, images, wmaps, tiles


def test_warp_trusts_only_sampled_columns_tables_and_replans_a_changed_rig(small_rig) -> None:
    """warp_views skips its range check of the pixel table for sampled_columns' own (SampledColumns, a
    2-tuple), checks any other pair (a bad column raises), warps the same either way, and its plan kept
    between calls follows a rig whose cameras moved (the same quilt as with no plan kept)."""
    cams, rig = small_rig
    rng = np.random.default_rng(8)
    V, H, W = len(cams), cams.height, cams.width
    sources, images, wmaps, tiles = _warp_inputs(cams, rng)
    table = vs.sampled_columns(rng.uniform(size=(V, H, W)) < 0.5)
    assert isinstance(table, vs.SampledColumns) and len(table) == 2 and table.shape == (V, H, W)
    for twin in (copy.deepcopy(table), pickle.loads(pickle.dumps(table))):  # rebuilt whole, shape included
        assert isinstance(twin, vs.SampledColumns) and twin.shape == table.shape
        assert all(np.array_equal(a, b) for a, b in zip(twin, table))
    offsets, columns = table
    quilts = []
    for pixels in (table, (offsets, columns)):
        q = np.full((H, V * W, 3), 7, np.uint8)
        vs.warp_views(images, wmaps, sources, rig, quilt=q, tiles=tiles, pixels=pixels)
        quilts.append(q)
    np.testing.assert_array_equal(quilts[0], quilts[1])
    assert (quilts[0] != 7).any()
    bad = columns.copy()
    bad[3] = W
    with pytest.raises(InputError, match="pixels: expected sampled_columns"):
        vs.warp_views(images, wmaps, sources, rig, quilt=quilts[1], tiles=tiles, pixels=(offsets, bad))
    # another rig of the same size (the cameras moved): its own plan, not the kept one
    moved = dataclasses.replace(rig, tx=rig.tx * 1.5, cx=rig.cx + 0.75)
    got = np.full((H, V * W, 3), 7, np.uint8)
    vs.warp_views(images, wmaps, sources, moved, quilt=got, tiles=tiles, pixels=table)
    vs._PLANS.clear()
    fresh = np.full((H, V * W, 3), 7, np.uint8)
    vs.warp_views(images, wmaps, sources, moved, quilt=fresh, tiles=tiles, pixels=table)
    np.testing.assert_array_equal(got, fresh)
    assert not np.array_equal(got, quilts[0])


def _cells_to_pixels_plain(zb: np.ndarray, cell: int, H: int, W: int, w_zero: float) -> np.ndarray:
    """view_synthesis._cells_to_pixels as first written (every cell visited by the hole filling), in Python."""
    zb = zb.copy()
    h, w = zb.shape
    for _ in range(3):
        zn = zb.copy()
        for y in range(h):
            for x in range(w):
                if zb[y, x] != np.inf:
                    continue
                acc, n = 0.0, 0
                for yy in range(max(0, y - 1), min(h, y + 2)):
                    for xx in range(max(0, x - 1), min(w, x + 2)):
                        if zb[yy, xx] != np.inf:
                            acc += zb[yy, xx]
                            n += 1
                if n >= 3:
                    zn[y, x] = acc / n
        zb[:, :] = zn
    zb = np.where(zb != np.inf, 1.0 / zb, w_zero)

    def taps(i: int, n: int) -> tuple[int, int, float]:
        f = (i + 0.5) / cell - 0.5
        c0 = min(max(int(np.floor(f)), 0), n - 1)
        return c0, min(c0 + 1, n - 1), min(max(f - c0, 0.0), 1.0)

    rows = np.empty((h, W))
    for x in range(W):
        x0, x1, ax = taps(x, w)
        for y in range(h):
            rows[y, x] = (1.0 - ax) * zb[y, x0] + ax * zb[y, x1]
    out = np.empty((H, W), np.float32)
    for y in range(H):
        y0, y1, ay = taps(y, h)
        for x in range(W):
            out[y, x] = (1.0 - ay) * rows[y0, x] + ay * rows[y1, x]
    return out


def test_depth_cells_hole_filling_skips_only_cells_without_a_filled_neighbour() -> None:
    """_cells_to_pixels visits, per pass, only the cells near a filled one: the same inverse depths bit for
    bit as visiting every cell, for a blob with holes (filled over the passes), isolated cells and rows with
    nothing, a blob at the border, an empty and a full grid."""
    rng = np.random.default_rng(12)
    h, w, cell = 17, 13, 3
    H, W = h * cell - 1, w * cell - 2
    yy, xx = np.mgrid[0:h, 0:w]
    blob = ((yy - 8) / 6.0) ** 2 + ((xx - 5) / 4.0) ** 2 < 1.0
    grids = []
    for k in range(3):
        z = np.where(blob & (rng.random((h, w)) < 0.7), rng.uniform(0.5, 0.7, (h, w)), np.inf)
        z[rng.integers(0, h), rng.integers(0, w)] = 0.6  # an isolated cell
        if k == 1:
            z[:, :3] = np.where(rng.random((h, 3)) < 0.5, 0.55, np.inf)  # at the left border
        grids.append(z)
    grids += [np.full((h, w), np.inf), rng.uniform(0.5, 0.7, (h, w))]
    for z in grids:
        out = np.empty((H, W), np.float32)
        vs._cells_to_pixels(z.copy(), h, w, cell, H, W, 1.25, out)
        np.testing.assert_array_equal(out, _cells_to_pixels_plain(z, cell, H, W, 1.25))


def test_visible_count_of_one_chunk_equals_the_union_over_chunks(small_rig) -> None:
    """fast.render's stats n_visible: counted from the one chunk's drawn splats (the live frames' case) or
    as the union over chunks of views (a small max_chunk_bytes): the same count, the same images."""
    from holo_viewer.render import fast
    from holo_viewer.render.config import RenderConfig
    from holo_viewer.testing import random_gaussians

    cams, _ = small_rig
    g = random_gaussians(6000, sh_degree=1, seed=3)
    means = np.asarray(g.means) * 0.4
    means[:500, 0] += 3.0  # out of every view
    g = g.replace(means=means)
    one = fast.render(g, cams, RenderConfig())
    many = fast.render(g, cams, RenderConfig(max_chunk_bytes=2**20))  # 1 MiB: one view a chunk
    assert 0 < one.stats["n_visible"] < 6000
    assert one.stats["n_visible"] == many.stats["n_visible"]
    np.testing.assert_array_equal(one.images, many.images)
