"""``holo-viewer render-ply``: PLY + cameras JSON -> view_000.png ...; clear errors (exit 1)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.avatar.ply import save_ply
from holo_viewer.camera import Cameras, intrinsics, look_at
from holo_viewer.cli import main
from holo_viewer.fileio import load_image
from holo_viewer.render import reference
from holo_viewer.render.config import RenderConfig

W, H = 32, 24


@pytest.fixture()
def scene(tmp_path: Path) -> tuple[Path, Path, Gaussians, Cameras]:
    rng = np.random.default_rng(0)
    n = 80
    g = Gaussians.from_arrays(rng.normal(0, 0.08, (n, 3)).astype(np.float32),
                              rng.normal(size=(n, 4)).astype(np.float32),
                              np.log(rng.uniform(0.005, 0.03, (n, 3))).astype(np.float32),
                              rng.normal(1, 1, n).astype(np.float32),
                              rng.normal(0, 0.4, (n, 4, 3)).astype(np.float32))
    ply = save_ply(g, tmp_path / "scene.ply")
    offs = (-0.05, 0.0, 0.05)
    cams = Cameras(np.stack([look_at([o, 0, 0.8], [o, 0, 0]) for o in offs]),
                   np.stack([intrinsics(40, 40, W / 2 - 40 * o / 0.8, H / 2) for o in offs]), W, H)
    cams_path = tmp_path / "cams.json"
    cams_path.write_text(json.dumps(cams.to_dicts()))
    return Path(ply), cams_path, g, cams


def test_renders_every_view_like_the_reference(scene, tmp_path: Path, capsys) -> None:
    ply, cams_path, g, cams = scene
    out = tmp_path / "out"
    code = main(["render-ply", str(ply), "--cameras", str(cams_path), "--out", str(out),
                 "--renderer", "reference", "--background", "0.2,0.3,0.4", "--batch", "2"])
    assert code == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["view_000.png", "view_001.png", "view_002.png"]  # no temp files left behind
    ref = reference.render(g, cams, RenderConfig(background=(0.2, 0.3, 0.4))).images
    for i in range(3):
        img = load_image(out / f"view_{i:03d}.png")
        assert img.shape == (H, W, 3)
        assert np.abs(img - ref[i]).max() <= 0.5 / 255 + 1e-6  # uint8 rounding only
    assert "wrote 3 views" in capsys.readouterr().out


def test_torch_backend_and_defaults(scene, tmp_path: Path) -> None:
    ply, cams_path, g, cams = scene
    out = tmp_path / "t"
    assert main(["render-ply", str(ply), "--cameras", str(cams_path), "--out", str(out), "--renderer", "torch",
                 "--quiet"]) == 0
    ref = reference.render(g, cams).images
    img = load_image(out / "view_002.png")
    assert np.abs(img - ref[2]).max() <= 1.5 / 255


@pytest.mark.parametrize("text, needle", [
    ("[{", "invalid JSON at line 1"),
    ("{}", "expected a non-empty list"),
    (json.dumps([{"width": 32, "height": 24, "fx": 40, "fy": 40, "cx": 16,
                  "world_to_cam": np.eye(4).tolist()}]), "[0].cy: missing"),
    (json.dumps([{"width": 32, "height": 24, "fx": 40, "fy": 40, "cx": 16, "cy": 12,
                  "world_to_cam": [[1, 0, 0], [0, 1, 0]]}]), "[0].world_to_cam"),
])
def test_bad_cameras_json_exits_1_naming_file_and_field(scene, tmp_path: Path, capsys, text: str,
                                                        needle: str) -> None:
    ply = scene[0]
    bad = tmp_path / "bad_cams.json"
    bad.write_text(text)
    code = main(["render-ply", str(ply), "--cameras", str(bad), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1
    assert "bad_cams.json" in err and needle in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


@pytest.mark.parametrize("bg", ["1,2", "0.5,0.5,2", "a,b,c", "0,0,nan"])
def test_bad_background_exits_1(scene, tmp_path: Path, capsys, bg: str) -> None:
    ply, cams_path, _, _ = scene
    code = main(["render-ply", str(ply), "--cameras", str(cams_path), "--out", str(tmp_path / "o"),
                 f"--background={bg}", "--quiet"])
    assert code == 1
    assert "--background" in capsys.readouterr().err


def test_missing_files_exit_1(scene, tmp_path: Path, capsys) -> None:
    ply, cams_path, _, _ = scene
    assert main(["render-ply", str(tmp_path / "nope.ply"), "--cameras", str(cams_path),
                 "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "nope.ply" in capsys.readouterr().err
    assert main(["render-ply", str(ply), "--cameras", str(tmp_path / "nocams.json"),
                 "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "nocams.json: file not found" in capsys.readouterr().err


def test_corrupt_ply_exits_1(scene, tmp_path: Path, capsys) -> None:
    _, cams_path, _, _ = scene
    bad = tmp_path / "corrupt.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x00")
    assert main(["render-ply", str(bad), "--cameras", str(cams_path), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "corrupt.ply" in capsys.readouterr().err
