"""3DGS PLY I/O: round trips, endianness, ASCII, extras, corrupt files."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.avatar import Gaussians, load_ply
from holo_viewer.errors import PlyError


def _random_gaussians(n: int = 50, degree: int = 2, seed: int = 0) -> Gaussians:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Gaussians(
        rng.normal(size=(n, 3)).astype(np.float32), q,
        rng.normal(-4, 1, size=(n, 3)).astype(np.float32), rng.normal(size=n).astype(np.float32),
        rng.normal(size=(n, (degree + 1) ** 2, 3)).astype(np.float32),
        extra={"binding_0": rng.integers(0, 100, n).astype(np.float32)})


def _same(a: Gaussians, b: Gaussians) -> None:
    for f in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape, f
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), f
    assert set(a.extra) == set(b.extra)
    for k in a.extra:
        assert np.array_equal(a.extra[k], b.extra[k]), k


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_bit_exact(tmp_path, degree):
    g = _random_gaussians(degree=degree, seed=degree)
    p = tmp_path / "a.ply"
    g.save_ply(p)
    g2 = load_ply(p)
    assert g2.sh_degree == degree
    _same(g, g2)
    g2.save_ply(tmp_path / "b.ply")
    assert (tmp_path / "b.ply").read_bytes() == p.read_bytes()


def _plyfile_write(path, g: Gaussians, text: bool, byte_order: str, scale_quat: float = 1.0) -> None:
    plyfile = pytest.importorskip("plyfile")
    n = len(g)
    m = g.sh.shape[1] - 1
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{k}" for k in range(3 * m)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "binding_0"]
    rest = g.sh[:, 1:].transpose(0, 2, 1).reshape(n, -1)
    cols = [g.means, np.zeros((n, 3), np.float32), g.sh[:, 0], rest, g.opacity_logits[:, None], g.log_scales,
            g.quats * scale_quat, g.extra["binding_0"][:, None]]
    data = np.concatenate(cols, axis=1).astype(np.float32)
    arr = np.empty(n, dtype=[(k, "f4") for k in names])
    for j, k in enumerate(names):
        arr[k] = data[:, j]
    el = plyfile.PlyElement.describe(arr, "vertex")
    plyfile.PlyData([el], text=text, byte_order=byte_order).write(str(path))


@pytest.mark.parametrize("text,order", [(False, "<"), (False, ">"), (True, "=")])
def test_reads_plyfile_written_formats(tmp_path, text, order):
    g = _random_gaussians(degree=3)
    p = tmp_path / "x.ply"
    _plyfile_write(p, g, text, order)
    g2 = load_ply(p)
    assert g2.sh_degree == 3 and "binding_0" in g2.extra and "nx" not in g2.extra
    tol = 1e-6 if text else 0
    for f in ("means", "log_scales", "opacity_logits", "sh"):
        np.testing.assert_allclose(getattr(g2, f), getattr(g, f), rtol=tol, atol=tol)
    np.testing.assert_allclose(g2.quats, g.quats, atol=1e-6)


def test_quaternions_normalised_on_load(tmp_path):
    g = _random_gaussians(degree=1)
    p = tmp_path / "q.ply"
    _plyfile_write(p, g, False, "<", scale_quat=3.0)
    g2 = load_ply(p)
    np.testing.assert_allclose(np.linalg.norm(g2.quats, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(g2.quats, g.quats, atol=1e-6)
    raw = load_ply(p, normalize_quats=False)
    np.testing.assert_allclose(np.linalg.norm(raw.quats, axis=1), 3.0, rtol=1e-6)


def test_extras_kept_multi_column(tmp_path):
    g = _random_gaussians(degree=0)
    g = g.replace(extra={"transform": np.arange(len(g) * 3, dtype=np.int32).reshape(-1, 3),
                         "flag": np.ones(len(g), np.uint8)})
    p = tmp_path / "e.ply"
    g.save_ply(p)
    g2 = load_ply(p)
    assert g2.extra["flag"].dtype == np.uint8
    np.testing.assert_array_equal(g2.extra["transform_1"], g.extra["transform"][:, 1])


def test_torch_gaussians_save(tmp_path):
    torch = pytest.importorskip("torch")
    g = _random_gaussians(degree=1)
    p = tmp_path / "t.ply"
    g.torch().save_ply(p)
    _same(g, load_ply(p))
    assert torch is not None


# --------------------------------------------------------------------------- corrupt files
def test_truncated_names_file_and_field(tmp_path):
    g = _random_gaussians(degree=1)
    p = tmp_path / "t.ply"
    g.save_ply(p)
    data = p.read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-10])
    with pytest.raises(PlyError, match=r"cut\.ply: truncated.*vertex 49, field 'rot_2'"):
        load_ply(tmp_path / "cut.ply")
    (tmp_path / "hdr.ply").write_bytes(data[:40])
    with pytest.raises(PlyError, match=r"hdr\.ply.*end_header"):
        load_ply(tmp_path / "hdr.ply")


def test_wrong_vertex_count(tmp_path):
    g = _random_gaussians(degree=0)
    p = tmp_path / "w.ply"
    g.save_ply(p)
    data = p.read_bytes().replace(b"element vertex 50", b"element vertex 40")
    p.write_bytes(data)
    with pytest.raises(PlyError, match="wrong vertex count.*40"):
        load_ply(p)


def test_missing_field(tmp_path):
    g = _random_gaussians(degree=0)
    p = tmp_path / "m.ply"
    g.save_ply(p)
    data = p.read_bytes().replace(b"property float opacity", b"property float opacityx")
    p.write_bytes(data)
    with pytest.raises(PlyError, match=r"m\.ply.*missing field.*'opacity'"):
        load_ply(p)


def test_bad_f_rest_count(tmp_path):
    g = _random_gaussians(degree=1)
    p = tmp_path / "r.ply"
    g.save_ply(p)
    p.write_bytes(p.read_bytes().replace(b"property float f_rest_8\n", b"property float zz_8\n"))
    with pytest.raises(PlyError, match="f_rest"):
        load_ply(p)


def test_nan_rows_rejected_with_indices(tmp_path):
    g = _random_gaussians(degree=1)
    p = tmp_path / "n.ply"
    _plyfile_write(p, g, False, "<")
    pf = pytest.importorskip("plyfile")
    d = pf.PlyData.read(str(p), mmap=False)
    d["vertex"].data["scale_1"][7] = np.nan
    d["vertex"].data["x"][31] = np.inf
    p = tmp_path / "n2.ply"
    d.write(str(p))
    with pytest.raises(PlyError, match=r"2 vertices hold NaN/inf \(indices \[7, 31\]"):
        load_ply(p)


def test_zero_quaternion_rejected(tmp_path):
    g = _random_gaussians(degree=0)
    p = tmp_path / "z.ply"
    _plyfile_write(p, g, False, ">", scale_quat=0.0)
    with pytest.raises(PlyError, match="rot_0..3.*zero"):
        load_ply(p)


def test_not_a_ply_and_missing_file(tmp_path):
    (tmp_path / "junk.ply").write_bytes(b"hello world")
    with pytest.raises(PlyError, match="junk.ply.*'ply'"):
        load_ply(tmp_path / "junk.ply")
    with pytest.raises(PlyError, match="nope.ply: cannot read"):
        load_ply(tmp_path / "nope.ply")


def test_ascii_short_line(tmp_path):
    g = _random_gaussians(n=3, degree=0)
    p = tmp_path / "a.ply"
    _plyfile_write(p, g, True, "=")
    lines = p.read_text().splitlines()
    lines[-1] = " ".join(lines[-1].split()[:-3])
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(PlyError, match="vertex 2: expected .* values"):
        load_ply(p)
