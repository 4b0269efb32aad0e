"""Quilt tiling/splitting, file naming, PNG and mp4 export."""

import numpy as np
import pytest

from holo_viewer.display.export import load_quilt, save_native_png, save_quilt_png, write_quilt_video
from holo_viewer.display.quilt import parse_quilt_filename, quilt_filename, split_quilt, tile_quilt, to_uint8
from holo_viewer.errors import ExportError, InputError


@pytest.mark.parametrize("cols,rows,n", [(8, 6, 48), (3, 2, 6), (5, 9, 45), (4, 3, 10), (1, 1, 1)])
def test_round_trip_and_bottom_left_is_view0(cols, rows, n):
    rng = np.random.default_rng(cols * 10 + rows)
    views = rng.integers(0, 256, (n, 7, 5, 3), dtype=np.uint8)
    q = tile_quilt(views, cols, rows)
    assert q.shape == (rows * 7, cols * 5, 3)
    assert np.array_equal(split_quilt(q, cols, rows, n), views)
    assert np.array_equal(q[-7:, :5], views[0])  # bottom-left tile
    if n == cols * rows:
        assert np.array_equal(q[:7, -5:], views[-1])  # top-right tile
    if n > 1 and cols > 1:
        assert np.array_equal(q[-7:, 5:10], views[1])  # left to right first


def test_non_multiple_quilt_reads_from_bottom_left():
    views = np.arange(6)[:, None, None, None] * np.ones((6, 4, 3, 1), np.uint8)
    q = tile_quilt(views, 3, 2)
    padded = np.concatenate([np.full((1, 9, 1), 99, np.uint8), q], axis=0)  # extra top row
    padded = np.concatenate([padded, np.full((9, 2, 1), 99, np.uint8)], axis=1)  # extra right columns
    assert np.array_equal(split_quilt(padded, 3, 2), views)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n", [6, 4])
def test_uint8_quilt_converts_tile_by_tile_like_converting_first(dtype, n):
    rng = np.random.default_rng(n)
    views = (rng.random((n, 7, 5, 3)) * 1.2 - 0.1).astype(dtype)  # values outside [0, 1] clip
    views[0, 0, 0] = [0.5 / 255, 1.5 / 255, 2.5 / 255]  # halves round to even
    q = tile_quilt(views, 3, 2, as_uint8=True)
    assert q.dtype == np.uint8
    expected = tile_quilt(np.clip(np.rint(views * 255.0), 0, 255).astype(np.uint8), 3, 2)
    assert np.array_equal(q, expected)
    assert np.array_equal(q[-7:, :5][0, 0], [0, 2, 2])
    assert not q[:7, 5 * (n - 3):].any()  # unused tiles are zero
    u8 = expected[-7:, :5][None].repeat(2, axis=0)  # uint8 views pass through unchanged
    assert np.array_equal(split_quilt(tile_quilt(u8, 2, 1, as_uint8=True), 2, 1), u8)


def test_to_uint8_writes_into_a_strided_tile():
    img = np.linspace(-0.5, 1.5, 4 * 3 * 3).reshape(4, 3, 3)
    out = np.full((6, 8, 3), 7, np.uint8)
    res = to_uint8(img, out=out[1:5, 2:5])
    assert res.base is out
    assert np.array_equal(out[1:5, 2:5], np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8))
    assert (out[0] == 7).all() and (out[:, :2] == 7).all()
    with pytest.raises(InputError, match="out: expected shape"):
        to_uint8(img, out=out)
    for src in (img, img.astype(np.float32), np.zeros((4, 3, 3), np.uint8)):  # every path
        with pytest.raises(InputError, match="out: expected uint8"):
            to_uint8(src, out=np.zeros((4, 3, 3), np.float32))


def test_names():
    assert quilt_filename("face", 8, 6, 0.75) == "face_qs8x6a0.75.png"
    assert quilt_filename("x", 5, 9, 16 / 9) == "x_qs5x9a1.7778.png"
    assert parse_quilt_filename("/a/b/face_qs8x6a0.75.png") == (8, 6, 0.75)
    assert parse_quilt_filename("my_qs2x2a1_qs11x6a0.5625.mp4") == (11, 6, 0.5625)
    with pytest.raises(InputError, match="_qs"):
        parse_quilt_filename("face.png")
    with pytest.raises(InputError):
        tile_quilt(np.zeros((7, 2, 2, 3)), 3, 2)


def test_png_export_and_reload(tmp_path):
    rng = np.random.default_rng(1)
    views = rng.integers(0, 256, (48, 8, 6, 3), dtype=np.uint8)
    p = save_quilt_png(tmp_path / "face", views, 8, 6, 0.75)
    assert p.name == "face_qs8x6a0.75.png"
    back, layout = load_quilt(p)
    assert layout == (8, 6, 0.75)
    assert np.array_equal(np.rint(back * 255).astype(np.uint8), views)
    assert save_quilt_png(tmp_path, views, 8, 6, 0.75).name == "quilt_qs8x6a0.75.png"
    with pytest.raises(ExportError, match="name says"):
        save_quilt_png(tmp_path / "x_qs4x4a1.png", views, 8, 6, 0.75)
    assert save_native_png(tmp_path / "n.png", views[0]).exists()
    with pytest.raises(ExportError, match="png"):
        save_native_png(tmp_path / "n.jpg", views[0])
    assert sorted(f.name for f in tmp_path.iterdir()) == ["face_qs8x6a0.75.png", "n.png", "quilt_qs8x6a0.75.png"]


def test_video_export(tmp_path):
    import imageio.v2 as imageio

    frames = [np.full((21, 30, 3), 40 * i, np.uint8) for i in range(5)]  # odd height
    frames[2][3, 4] = (255, 0, 17)  # one odd subpixel: lossless RGB keeps it (yuv420p would smear it)
    p = write_quilt_video(tmp_path / "q_qs3x3a1.mp4", frames, fps=10, progress=False, preset="ultrafast")
    got = [f for f in imageio.get_reader(str(p))]  # (list() asks len(), which is inf for mp4)
    assert len(got) == 5 and got[0].shape == (21, 30, 3)  # RGB needs no even sides
    assert all(np.array_equal(a, b) for a, b in zip(frames, got))  # lossless by default
    assert [f.name for f in tmp_path.iterdir()] == ["q_qs3x3a1.mp4"]  # no temp files left
    with pytest.raises(ExportError, match="frame 1"):
        write_quilt_video(tmp_path / "bad.mp4", [frames[0], np.zeros((4, 4, 3), np.uint8)], progress=False)
    assert not (tmp_path / "bad.mp4").exists()
