"""``holo-viewer export-mesh`` through cli.main: formats, posing options, errors."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from holo_viewer.cli import main
from holo_viewer.flame.io import save_flame_npz
from holo_viewer.flame.model import FlameModel
from holo_viewer.flame.synthetic import random_flame_arrays

N_EXPR = 6
NAMES = [f"E{i}" for i in range(N_EXPR)]


def _has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    arrays = random_flame_arrays(n_vertices=200, n_shape=5, n_expr=N_EXPR, seed=4)
    arrays["expression_names"] = np.array(NAMES)
    return save_flame_npz(tmp_path_factory.mktemp("model") / "model.npz", arrays)


def _load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    kwargs = {"maintain_order": True} if path.suffix == ".obj" else {}
    mesh = trimesh.load(path, force="mesh", process=False, **kwargs)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb"])
def test_writes_posed_mesh(tmp_path: Path, model_path: Path, suffix: str, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / f"head{suffix}"
    rc = main(["export-mesh", "--flame-model", str(model_path), "--expr", "E2=1.5", "4=-0.5",
               "--jaw", "12", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert "wrote" in capsys.readouterr().out
    verts, faces = _load_mesh(out)
    model = FlameModel.load(model_path, dtype=torch.float64)
    expr = np.zeros(N_EXPR)
    expr[2], expr[4] = 1.5, -0.5
    expected = model(expr=expr, jaw_pose=[np.deg2rad(12.0), 0, 0]).vertices[0].numpy()
    neutral = model().vertices[0].numpy()
    assert verts.shape == expected.shape
    np.testing.assert_array_equal(faces, model.faces.numpy())
    np.testing.assert_allclose(verts, expected, atol=1e-6, rtol=0)  # OBJ text / GLB float32
    assert np.abs(expected - neutral).max() > 1e-3  # the options really posed the head


def test_teeth_option(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    arrays = random_flame_arrays(n_vertices=200, n_shape=5, n_expr=N_EXPR, seed=4)
    arrays["teeth_anchor_upper"] = np.arange(0, 15)
    arrays["teeth_anchor_lower"] = np.arange(20, 35)
    path = save_flame_npz(tmp_path / "m.npz", arrays)
    out = tmp_path / "t.ply"
    assert main(["export-mesh", "--flame-model", str(path), "--teeth", "--out", str(out)]) == 0
    verts, faces = _load_mesh(out)
    assert verts.shape == (320, 3) and faces.shape[0] == arrays["f"].shape[0] + 168


@pytest.mark.parametrize("argv,match", [
    (["--expr", "NOPE=1"], "unknown expression component 'NOPE'"),
    (["--expr", "E2"], "expected NAME=VALUE"),
    (["--expr", "E2=abc"], "--expr E2: expected a number"),
    (["--expr", "E2=nan"], "--expr E2: expected a finite number"),
    (["--expr", "6=1"], r"component index in \[0, 6\), found 6"),
    (["--jaw", "120"], "--jaw: expected <= 90"),
    (["--pain", "1.5"], "--pain: expected <= 1"),
])
def test_bad_options(tmp_path: Path, model_path: Path, argv: list, match: str,
                     capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "x.obj"
    rc = main(["export-mesh", "--flame-model", str(model_path), *argv, "--out", str(out)])
    assert rc == 1
    import re

    assert re.search(match, capsys.readouterr().err)
    assert not out.exists() and os.listdir(tmp_path) == []


def test_bad_suffix_and_missing_model(tmp_path: Path, model_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["export-mesh", "--flame-model", str(model_path), "--out", str(tmp_path / "x.stl")]) == 1
    assert "expected a file ending in .obj, .ply, .glb" in capsys.readouterr().err
    assert main(["export-mesh", "--flame-model", str(tmp_path / "none.pkl"), "--out", str(tmp_path / "x.obj")]) == 1
    assert "file not found" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_existing_file_kept_on_failure(tmp_path: Path, model_path: Path) -> None:
    out = tmp_path / "x.obj"
    out.write_text("previous")
    assert main(["export-mesh", "--flame-model", str(model_path), "--expr", "BAD=1", "--out", str(out)]) == 1
    assert out.read_text() == "previous"


@pytest.mark.skipif(not _has("holo_viewer.flame.expressions"), reason="holo_viewer.flame.expressions not built yet")
def test_pain_needs_au_map_for_user_model(tmp_path: Path, model_path: Path, capsys: pytest.CaptureFixture) -> None:
    rc = main(["export-mesh", "--flame-model", str(model_path), "--pain", "0.7", "--out", str(tmp_path / "p.obj")])
    assert rc == 1
    assert "au" in capsys.readouterr().err.lower()


@pytest.mark.skipif(not _has("holo_viewer.flame.expressions"), reason="holo_viewer.flame.expressions not built yet")
def test_pain_with_au_map_json(tmp_path: Path, model_path: Path) -> None:
    from holo_viewer.flame.expressions import AU_NAMES, AUMap, pain_expression

    rng = np.random.default_rng(0)
    matrix = rng.normal(scale=0.2, size=(len(AU_NAMES), N_EXPR))
    au_map = AUMap(names=tuple(AU_NAMES), matrix=matrix)
    json_path = tmp_path / "aus.json"
    au_map.to_json(json_path)
    out = tmp_path / "p.ply"
    assert main(["export-mesh", "--flame-model", str(model_path), "--au-map", str(json_path), "--pain", "0.7",
                 "--out", str(out)]) == 0
    model = FlameModel.load(model_path, dtype=torch.float64)
    expected = model(expr=pain_expression(0.7, AUMap.load_json(json_path, N_EXPR))).vertices[0].numpy()
    verts, _ = _load_mesh(out)
    np.testing.assert_allclose(verts, expected, atol=1e-6, rtol=0)


def _default_head_built() -> bool:
    if not (_has("holo_viewer.flame.default_head") and _has("holo_viewer.flame.expressions")):
        return False
    from holo_viewer.flame.default_head import default_head_path

    return default_head_path(build_if_missing=False).exists()


@pytest.mark.skipif(not _default_head_built(), reason="default head asset / expressions not built yet")
def test_default_head_pain_and_expression_names(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.flame.expressions import DEFAULT_HEAD_PAIN_GAINS, au_map_for, pain_expression

    model = load_default_model(dtype=torch.float64)
    name = model.expression_names[0]
    out = tmp_path / "pain.glb"
    assert main(["export-mesh", "--pain", "1", "--expr", f"{name}=0.5", "--jaw", "8", "--out", str(out)]) == 0, \
        capsys.readouterr().err
    au = au_map_for(model)  # the default head's own pain face (its brow gain)
    assert dict(au.pain_gains) == dict(DEFAULT_HEAD_PAIN_GAINS)
    expr = np.asarray(pain_expression(1.0, au), dtype=np.float64)
    expr[0] = 0.5
    expected = model(expr=expr, jaw_pose=[np.deg2rad(8.0), 0, 0]).vertices[0].numpy()
    verts, faces = _load_mesh(out)
    np.testing.assert_allclose(verts, expected, atol=1e-6, rtol=0)
    assert np.abs(expected - model().vertices[0].numpy()).max() > 1e-3
