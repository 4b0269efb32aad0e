"""Package-level guarantees: cheap import, CLI conventions, validation messages, atomic writes."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from holo_viewer.cli import SUBCOMMANDS, main
from holo_viewer.errors import ExportError, HoloViewerError, InputError
from holo_viewer.fileio import atomic_write, load_image, save_image, write_json
from holo_viewer.validation import check_array, check_finite_scalar

HEAVY = ("vtk", "vtkmodules", "pyvista", "open3d", "usb", "hid", "matplotlib")


def test_import_is_light():
    code = ("import sys, holo_viewer, holo_viewer.cli; "
            f"bad = [m for m in {HEAVY!r} if m in sys.modules]; print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"import holo_viewer pulled in: {out.stdout.strip()}"


@pytest.mark.parametrize("subpackage", ["flame", "avatar", "render", "display", "reaction"])
def test_subpackage_import_does_not_load_gui_or_usb(subpackage):
    code = (f"import sys, importlib; importlib.import_module('holo_viewer.{subpackage}'); "
            f"bad = [m for m in {HEAVY!r} if m in sys.modules]; print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"holo_viewer.{subpackage} pulled in: {out.stdout.strip()}"


def test_cli_help_lists_every_subcommand():
    out = subprocess.run([sys.executable, "-m", "holo_viewer", "--help"], capture_output=True, text=True)
    assert out.returncode == 0
    for name in SUBCOMMANDS:
        assert name in out.stdout


def test_cli_every_subcommand_has_help(capsys):
    """In process (the process boundary is test_cli_help_lists_every_subcommand's): argparse exits 0 after help."""
    for name in SUBCOMMANDS:
        with pytest.raises(SystemExit) as exit_:
            main([name, "--help"])
        out = capsys.readouterr()
        assert exit_.value.code in (0, None), f"{name} --help failed: {out.err[-2000:]}"
        assert "usage: holo-viewer " + name in out.out


def test_cli_unknown_command_is_usage_error():
    out = subprocess.run([sys.executable, "-m", "holo_viewer", "no-such-command"], capture_output=True, text=True)
    assert out.returncode == 2


def test_check_array_messages():
    with pytest.raises(InputError, match=r"expr: expected shape \(B, 10\), found \(2, 11\)"):
        check_array(np.zeros((2, 11)), "expr", ("B", 10))
    sizes = {}
    check_array(np.zeros((4, 3)), "a", ("N", 3), sizes=sizes)
    with pytest.raises(InputError, match="N=4"):
        check_array(np.zeros((5, 3)), "b", ("N", 3), sizes=sizes)
    with pytest.raises(InputError, match="NaN/inf"):
        check_array(np.array([1.0, np.inf]), "x")
    assert check_array(np.zeros((7, 2, 3)), "p", (..., 3)).shape == (7, 2, 3)
    import torch

    with pytest.raises(InputError, match="t: expected finite"):
        check_array(torch.tensor([0.0, float("nan")]), "t")
    with pytest.raises(InputError, match="pain"):
        check_finite_scalar(1.5, "pain", low=0, high=1)


def test_errors_share_a_base():
    assert issubclass(InputError, HoloViewerError) and issubclass(InputError, ValueError)


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_write(target) as fh:
            fh.write(b"new partial")
            raise RuntimeError("boom")
    assert target.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["out.bin"]  # no temp file left behind
    with atomic_write(target) as fh:
        fh.write(b"new")
    assert target.read_bytes() == b"new"
    fresh = tmp_path / "fresh.bin"
    with atomic_write(fresh) as fh:
        fh.write(b"x")
    umask = os.umask(0)
    os.umask(umask)
    assert fresh.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's owner-only 0600


def test_write_json_makes_the_folder_and_keeps_old_results_on_failure(tmp_path):
    target = write_json(tmp_path / "results" / "bench.json", {"time_s": 0.5})
    assert json.loads(target.read_text()) == {"time_s": 0.5}
    with pytest.raises(TypeError):  # not JSON-serialisable: the earlier result stays whole
        write_json(target, {"time_s": object()})
    assert json.loads(target.read_text()) == {"time_s": 0.5}
    assert sorted(os.listdir(target.parent)) == ["bench.json"]


def test_save_image_round_trip_and_nan_refused(tmp_path):
    img = np.random.default_rng(0).random((6, 5, 3)).astype(np.float32)
    path = save_image(tmp_path / "a.png", img)
    back = load_image(path)
    assert back.shape == (6, 5, 3) and np.abs(back - img).max() <= 0.5 / 255 + 1e-6
    bad = img.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ExportError, match="NaN"):
        save_image(tmp_path / "b.png", bad)
    assert not (tmp_path / "b.png").exists()
    with pytest.raises(ExportError, match="not a readable image"):
        (tmp_path / "c.png").write_bytes(b"not a png")
        load_image(tmp_path / "c.png")


def test_read_npz_and_npy_errors_name_the_file(tmp_path):
    from holo_viewer.errors import ReactionError
    from holo_viewer.fileio import read_npy, read_npz

    good = tmp_path / "good.npz"
    np.savez(good, a=np.arange(3))
    assert np.array_equal(read_npz(good)["a"], np.arange(3))
    raw = good.read_bytes()
    cases = {"trunc.npz": raw[: len(raw) // 2], "magic.npz": b"PK\x03\x04garbage", "text.npz": b"hello"}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ReactionError, match=rf"{name}: cannot read speaker data"):
            read_npz(tmp_path / name, ReactionError, "speaker data")
    with pytest.raises(ReactionError, match="missing.npz: speaker data not found"):
        read_npz(tmp_path / "missing.npz", ReactionError, "speaker data")
    with pytest.raises(ReactionError, match="found a directory"):
        read_npz(tmp_path, ReactionError, "speaker data")
    np.save(tmp_path / "x.npy", np.eye(2))
    assert np.array_equal(read_npy(tmp_path / "x.npy"), np.eye(2))
    with pytest.raises(HoloViewerError, match="single .npy array"):
        read_npz(tmp_path / "x.npy")
    with pytest.raises(HoloViewerError, match="found an .npz archive"):
        read_npy(good)
    (tmp_path / "cut.npy").write_bytes((tmp_path / "x.npy").read_bytes()[:-8])
    with pytest.raises(HoloViewerError, match="cut.npy: cannot read"):
        read_npy(tmp_path / "cut.npy")


def test_one_uint8_converter_refuses_nan_and_inf():
    """holo_viewer.images.to_uint8 is the only float -> uint8 conversion; NaN/inf raise ExportError."""
    from holo_viewer.display import quilt
    from holo_viewer.display.quilt import tile_quilt
    from holo_viewer.images import to_uint8

    assert quilt.to_uint8 is to_uint8
    a = np.array([[0.0, 0.5 / 255, 1.5 / 255, 1.0, 1.2, -0.1]], dtype=np.float32)
    np.testing.assert_array_equal(to_uint8(a), [[0, 0, 2, 255, 255, 0]])  # half to even, clipped
    for bad in (np.nan, np.inf, -np.inf):
        b = a.copy()
        b[0, 1] = bad
        with pytest.raises(ExportError, match="views\\[1\\]: contains NaN/inf"):
            tile_quilt(np.stack([a, b])[..., None].repeat(3, -1), 2, 1, as_uint8=True)
        with pytest.raises(ExportError, match="image: contains NaN/inf"):
            to_uint8(b)
    with pytest.raises(ExportError, match="NaN/inf"):
        to_uint8(np.array([0.5, 1e30], np.float32))  # finite but no image value (its square overflows)
    np.testing.assert_array_equal(to_uint8(np.array([-3.0, 40.0])), [0, 255])  # out of range: clipped
    with pytest.raises(ExportError, match="dtype int32"):
        to_uint8(np.zeros(3, np.int32))


def test_one_cache_dir_honours_holo_viewer_cache(tmp_path, monkeypatch):
    """HOLO_VIEWER_CACHE, then XDG_CACHE_HOME/holo_viewer, then ~/.cache/holo_viewer, for every cached file."""
    from pathlib import Path

    import importlib

    from holo_viewer.cache import cache_dir

    dav = importlib.import_module("holo_viewer.avatar.default_gaussians")  # the package attribute is the function
    from holo_viewer.flame import default_head

    monkeypatch.setenv("HOLO_VIEWER_CACHE", str(tmp_path / "hv"))
    assert cache_dir() == tmp_path / "hv" and dav._cache_dir() == cache_dir()
    monkeypatch.delenv("HOLO_VIEWER_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "holo_viewer"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_dir() == Path.home() / ".cache" / "holo_viewer"
    # the default head, rebuilt when the asset is missing, goes to the same folder
    monkeypatch.setenv("HOLO_VIEWER_CACHE", str(tmp_path / "hv"))
    (tmp_path / "hv").mkdir()
    (tmp_path / "hv" / default_head.ASSET_NAME).write_bytes(b"placeholder")
    monkeypatch.setattr(default_head, "_repo_asset", lambda: tmp_path / "no-such-asset" / default_head.ASSET_NAME)
    assert default_head.default_head_path() == tmp_path / "hv" / default_head.ASSET_NAME


def test_uint8_fused_pass_equals_numpy():
    """Images of 2 or 3 axes take the compiled pass (scale, round half to even, clip, store,
    fused, on all threads); it gives numpy's multiply, rint and clip exactly, into strided tiles
    too, and refuses NaN/inf and overflowing squares like the numpy path (other shapes)."""
    from holo_viewer.images import to_uint8

    rng = np.random.default_rng(5)
    for dtype in (np.float32, np.float64):
        a = rng.uniform(-0.3, 1.3, (37, 23, 3)).astype(dtype)
        a[0, :10, 0] = (np.arange(10) + 0.5) / 255  # exact halves: to even
        want = np.clip(np.rint(a * dtype(255.0)), 0, 255).astype(np.uint8)
        np.testing.assert_array_equal(to_uint8(a), want)
        np.testing.assert_array_equal(to_uint8(a[..., 1]), want[..., 1])  # 2 axes
        np.testing.assert_array_equal(to_uint8(a.reshape(-1)), want.reshape(-1))  # 1 axis: numpy
        out = np.full((40, 50, 3), 7, np.uint8)
        to_uint8(a, out=out[2:39, 5:28])  # a strided tile
        np.testing.assert_array_equal(out[2:39, 5:28], want)
        assert (out[:2] == 7).all() and (out[:, 28:] == 7).all()
        for bad in (np.nan, np.inf, 1e30 if dtype == np.float32 else 1e200):
            b = a.copy()
            b[20, 3, 2] = bad
            with pytest.raises(ExportError, match="NaN/inf"):
                to_uint8(b)
