"""FLAME file I/O: chumpy-free .pkl, .npz round trip, and every kind of bad file."""

from __future__ import annotations

import copy
import os
import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse
import torch

from holo_viewer.errors import FlameError
from holo_viewer.flame.io import REQUIRED_KEYS, load_flame_arrays, save_flame_npz
from holo_viewer.flame.model import FlameModel
from holo_viewer.flame.synthetic import random_flame_arrays


@pytest.fixture()
def arrays() -> dict:
    return random_flame_arrays(n_vertices=120, n_shape=300, n_expr=8, seed=1, write_split=False)


def _fake_chumpy() -> tuple[types.ModuleType, types.ModuleType]:
    """Modules standing in for chumpy while pickling: a Ch whose pickled state mimics chumpy's."""
    pkg = types.ModuleType("chumpy")
    ch_mod = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x: np.ndarray) -> None:
            self.x = np.asarray(x, dtype=np.float64)
            self._dirty_vars = set()
            self._itr = None
            self._depends_on_deps = {}
            self._make_dense = False
            self._make_sparse = False
            self._parents = {}  # removed by __getstate__, like chumpy's weak dictionaries
            self._cache = {"r": None}

        def __getstate__(self) -> dict:
            state = copy.copy(self.__dict__)
            del state["_parents"], state["_cache"]
            return state

    class Select(Ch):  # a derived chumpy op: pickles its terms, not an array
        def __init__(self) -> None:
            self.a = None
            self.idxs = [1, 2]
            self._parents = {}
            self._cache = {}

    Ch.__module__ = Select.__module__ = "chumpy.ch"
    Ch.__qualname__, Select.__qualname__ = "Ch", "Select"
    ch_mod.Ch, ch_mod.Select = Ch, Select
    pkg.ch, pkg.Ch = ch_mod, Ch
    return pkg, ch_mod


def write_flame_pkl(path: Path, arrays: dict, protocol: int = 2, chumpy_shapedirs: bool = True,
                    extra: dict | None = None, drop: str | None = None) -> None:
    """Write a FLAME-2020-like pickle: chumpy shapedirs, sparse J_regressor, uint32 kintree_table."""
    pkg, ch_mod = _fake_chumpy()
    saved = {k: sys.modules.get(k) for k in ("chumpy", "chumpy.ch")}
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = pkg, ch_mod
    try:
        kin = arrays["kintree_table"].astype(np.int64)
        kin[0, 0] = 2 ** 32 - 1
        data = {
            "v_template": arrays["v_template"],
            "shapedirs": ch_mod.Ch(arrays["shapedirs"]) if chumpy_shapedirs else arrays["shapedirs"],
            "posedirs": arrays["posedirs"],
            "J_regressor": scipy.sparse.csc_matrix(arrays["J_regressor"]),
            "weights": arrays["weights"],
            "kintree_table": kin.astype(np.uint32),
            "f": arrays["f"].astype(np.uint32),
            "J": arrays["J_regressor"] @ arrays["v_template"],
            "bs_style": "lbs",
            "bs_type": "lrotmin",
        }
        data.update(extra or {})
        if drop:
            del data[drop]
        with open(path, "wb") as fh:
            pickle.dump(data, fh, protocol=protocol)
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


# --------------------------------------------------------------------------- good files


@pytest.mark.parametrize("protocol", [0, 2, 4])
def test_chumpy_pickle_loads_without_chumpy_and_matches_npz(tmp_path: Path, arrays: dict, protocol: int) -> None:
    pkl = tmp_path / "generic_model.pkl"
    write_flame_pkl(pkl, arrays, protocol=protocol)
    assert "chumpy" not in sys.modules
    loaded = load_flame_arrays(pkl)
    assert "chumpy" not in sys.modules  # the loader never imports chumpy
    for key in REQUIRED_KEYS:
        assert isinstance(loaded[key], np.ndarray), key
    np.testing.assert_array_equal(loaded["shapedirs"], arrays["shapedirs"])
    np.testing.assert_array_equal(loaded["J_regressor"], arrays["J_regressor"])
    assert loaded["kintree_table"][0].tolist() == [-1, 0, 1, 1, 1]
    assert str(loaded["bs_style"]) == "lbs"

    npz = tmp_path / "model.npz"
    save_flame_npz(npz, arrays)
    rng = np.random.default_rng(0)
    params = {"shape": rng.normal(size=(2, 300)), "expr": rng.normal(size=(2, 8)),
              "jaw_pose": rng.normal(scale=0.3, size=(2, 3)), "neck_pose": rng.normal(scale=0.3, size=(2, 3))}
    from_pkl = FlameModel.load(pkl, dtype=torch.float64)
    from_npz = FlameModel.load(npz, dtype=torch.float64)
    assert (from_pkl.n_shape, from_pkl.n_expr) == (300, 8)
    torch.testing.assert_close(from_pkl(**params).vertices, from_npz(**params).vertices, atol=1e-15, rtol=0)
    torch.testing.assert_close(from_pkl.faces, from_npz.faces)


def test_flame_2023_style_pickle_without_chumpy_objects(tmp_path: Path, arrays: dict) -> None:
    pkl = tmp_path / "flame2023.pkl"
    write_flame_pkl(pkl, arrays, chumpy_shapedirs=False)
    loaded = load_flame_arrays(pkl)
    np.testing.assert_array_equal(loaded["shapedirs"], arrays["shapedirs"])


def test_npz_round_trip_passes_extras_through(tmp_path: Path, arrays: dict) -> None:
    arrays = dict(arrays)
    arrays["expression_names"] = np.array(["AU1", "AU2", "AU4", "AU6", "AU7", "AU9", "AU10", "AU12"])
    arrays["holo_viewer_default_head"] = np.array(1)
    arrays["J_regressor"] = scipy.sparse.csr_matrix(arrays["J_regressor"])
    path = save_flame_npz(tmp_path / "head.npz", arrays)
    loaded = load_flame_arrays(path)
    assert sorted(loaded) == sorted(arrays)
    np.testing.assert_array_equal(loaded["J_regressor"], arrays["J_regressor"].toarray())
    model = FlameModel.load(path)
    assert model.expression_names == list(arrays["expression_names"])
    assert model.is_default_head
    # suffix-less files are recognised by content
    plain = tmp_path / "model_file"
    plain.write_bytes(path.read_bytes())
    assert sorted(load_flame_arrays(plain)) == sorted(arrays)


def test_save_is_atomic(tmp_path: Path, arrays: dict) -> None:
    path = tmp_path / "head.npz"
    save_flame_npz(path, arrays)
    before = path.read_bytes()
    bad = dict(arrays)
    bad["weights"] = bad["weights"][:-1]
    with pytest.raises(FlameError, match="weights"):
        save_flame_npz(path, bad)
    with pytest.raises(FlameError, match="objects"):
        save_flame_npz(path, {**arrays, "extra": {"a": 1}})
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["head.npz"]


# --------------------------------------------------------------------------- bad files


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_missing_pkl_key(tmp_path: Path, arrays: dict, key: str) -> None:
    pkl = tmp_path / "m.pkl"
    write_flame_pkl(pkl, arrays, drop=key)
    with pytest.raises(FlameError, match=rf"m\.pkl: missing key '{key}'"):
        FlameModel.load(pkl)


@pytest.mark.parametrize("key,value,match", [
    ("weights", lambda a: a["weights"][:-1], r"weights: expected shape \(V, 5\) with V=120, found \(119, 5\)"),
    ("shapedirs", lambda a: a["shapedirs"][:-2], r"shapedirs: expected shape \(V, 3, K\).*found \(118, 3, 308\)"),
    ("posedirs", lambda a: a["posedirs"][:, :, :27], r"posedirs: expected shape \(V, 3, 36\) with V=120.*found \(120, 3, 27\)"),
    ("J_regressor", lambda a: a["J_regressor"][:4], r"J_regressor: expected shape \(5, V\).*found \(4, 120\)"),
    ("kintree_table", lambda a: a["kintree_table"][:, :4], r"kintree_table: expected shape \(2, 5\), found \(2, 4\)"),
    ("kintree_table", lambda a: np.array([[-1, 0, 3, 1, 1], [0, 1, 2, 3, 4]]), r"kintree_table: expected parent of joint 2 in \[0, 2\), found 3"),
    ("v_template", lambda a: a["v_template"][:, :2], r"v_template: expected shape \(V, 3\), found \(120, 2\)"),
    ("f", lambda a: np.concatenate([a["f"], [[0, 1, 120]]]), r"f: expected vertex indices in \[0, 120\), found 120"),
    ("f", lambda a: np.concatenate([a["f"], [[0, -1, 2]]]), r"f: expected vertex indices in \[0, 120\), found -1"),
    ("f", lambda a: a["f"] + 0.5, r"f: expected integer indices"),
    ("v_template", lambda a: np.where(np.arange(120)[:, None] == 7, np.nan, a["v_template"]),
     r"v_template: expected finite values"),
    ("weights", lambda a: a["weights"].astype(str), r"weights: expected a real-valued array"),
])
def test_inconsistent_arrays(tmp_path: Path, arrays: dict, key: str, value, match: str) -> None:
    bad = dict(arrays)
    bad[key] = value(arrays)
    with pytest.raises(FlameError, match=match):
        FlameModel.from_arrays(bad)
    npz = tmp_path / "bad.npz"
    with open(npz, "wb") as fh:  # written directly: save_flame_npz refuses invalid models
        np.savez(fh, **bad)
    with pytest.raises(FlameError, match=r"bad\.npz: " + match):
        load_flame_arrays(npz)


def test_nonexistent_file(tmp_path: Path) -> None:
    with pytest.raises(FlameError, match="file not found"):
        FlameModel.load(tmp_path / "nope.pkl")
    with pytest.raises(FlameError, match="file not found"):
        load_flame_arrays(tmp_path / "nope.npz")


def test_directory_instead_of_file(tmp_path: Path) -> None:
    d = tmp_path / "dir.pkl"
    d.mkdir()
    with pytest.raises(FlameError, match="directory"):
        load_flame_arrays(d)


def test_corrupt_files(tmp_path: Path, arrays: dict) -> None:
    rng = np.random.default_rng(0)
    junk = tmp_path / "junk.pkl"
    junk.write_bytes(rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(FlameError, match=r"junk\.pkl: not a readable FLAME pickle"):
        load_flame_arrays(junk)
    good = tmp_path / "good.pkl"
    write_flame_pkl(good, arrays)
    truncated = tmp_path / "truncated.pkl"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(FlameError, match=r"truncated\.pkl: not a readable FLAME pickle"):
        load_flame_arrays(truncated)
    npz = save_flame_npz(tmp_path / "good.npz", arrays)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(npz.read_bytes()[:1000])
    with pytest.raises(FlameError, match=r"cut\.npz: not a readable \.npz"):
        load_flame_arrays(cut)
    empty = tmp_path / "empty.pkl"
    empty.write_bytes(b"")
    with pytest.raises(FlameError, match=r"empty\.pkl: not a readable FLAME pickle"):
        load_flame_arrays(empty)


def test_pickle_of_wrong_type(tmp_path: Path) -> None:
    path = tmp_path / "list.pkl"
    path.write_bytes(pickle.dumps([1, 2, 3]))
    with pytest.raises(FlameError, match="expected a pickled dict of FLAME arrays, found list"):
        load_flame_arrays(path)


def test_pickle_cannot_run_code(tmp_path: Path) -> None:
    class Evil:
        def __reduce__(self):
            return (os.system, ("echo pwned > " + str(tmp_path / "pwned"),))

    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"v_template": Evil()}))
    with pytest.raises(FlameError, match=r"references (posix|nt|os)\.system.*refusing"):
        load_flame_arrays(path)
    assert not (tmp_path / "pwned").exists()


def test_chumpy_object_without_array(tmp_path: Path, arrays: dict) -> None:
    pkg, ch_mod = _fake_chumpy()
    pkl = tmp_path / "derived.pkl"
    write_flame_pkl(pkl, arrays, extra={})
    # rewrite with a derived chumpy op in place of the shapedirs array
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = pkg, ch_mod
    try:
        data = {k: v for k, v in arrays.items()}
        data["shapedirs"] = ch_mod.Select()
        pkl.write_bytes(pickle.dumps(data, protocol=2))
    finally:
        sys.modules.pop("chumpy"), sys.modules.pop("chumpy.ch")
    with pytest.raises(FlameError, match=r"shapedirs: a pickled chumpy\.ch\.Select object without a stored array"):
        load_flame_arrays(pkl)
