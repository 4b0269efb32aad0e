"""FLAME pickles cannot corrupt memory, exhaust it or overflow the stack (issue 31, cases 1-3).

Every crafted pickle uses only allowed globals. Cases that crash the interpreter on the old
loader (a segfault in scipy's ``csr_todense`` or in ``Unpickler.load``) run in a subprocess
under an address-space limit, so a regression fails the test instead of killing pytest or
the machine. The budget checks are asserted to run before the allocation they guard (a spy on
the builder), not by timing.
"""

from __future__ import annotations

import json
import os
import pickle
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

from holo_viewer.errors import FlameError
from holo_viewer.flame import io as flame_io
from holo_viewer.flame.io import load_flame_arrays
from holo_viewer.flame.synthetic import random_flame_arrays

ROOT = Path(__file__).resolve().parents[1]
#: address space a loader subprocess may add to what it has after its imports
_AS_HEADROOM = 2 << 30

_RUNNER = textwrap.dedent("""
    import json, resource, sys
    from holo_viewer.errors import HoloViewerError
    from holo_viewer.flame.io import load_flame_arrays
    with open("/proc/self/statm") as fh:
        vsz = int(fh.read().split()[0]) * resource.getpagesize()
    resource.setrlimit(resource.RLIMIT_AS, (vsz + int(sys.argv[2]), resource.RLIM_INFINITY))
    try:
        load_flame_arrays(sys.argv[1])
        rc, msg = 0, "loaded"
    except HoloViewerError as exc:
        rc, msg = 1, str(exc)
    # VmHWM is this process's own peak RSS; ru_maxrss is not: exec copies the parent's high-water mark into it
    # (an xdist worker that once held 2.9 GB made every child "peak" at 2.9 GB)
    with open("/proc/self/status") as fh:
        peak = next(int(line.split()[1]) for line in fh if line.startswith("VmHWM:")) * 1024
    print(json.dumps({"msg": msg, "peak": peak}))
    sys.exit(rc)
""")


def _load_in_child(path: Path) -> tuple[int, str, str, int]:
    """(exit status, error message, stderr, peak RSS bytes) of loading ``path`` in a fresh interpreter."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", _RUNNER, str(path), str(_AS_HEADROOM)], capture_output=True,
                          text=True, env=env, timeout=120)
    lines = proc.stdout.strip().splitlines()
    report = json.loads(lines[-1]) if lines else {"msg": "", "peak": -1}
    return proc.returncode, report["msg"], proc.stderr, report["peak"]


def _model(**replace: object) -> dict:
    arrays = random_flame_arrays(n_vertices=40, n_shape=4, n_expr=3, seed=3)
    arrays.update(replace)
    return arrays


def _tampered_sparse(shape: tuple[int, int], indices: list[int], fmt: str = "csr") -> object:
    """A sparse matrix whose internals were changed after scipy checked them."""
    m = (scipy.sparse.csr_matrix if fmt == "csr" else scipy.sparse.csc_matrix)(np.ones(shape))
    m.indices = np.asarray(indices, dtype=np.int32)
    m.indptr = np.asarray([0] + [len(indices)] * (m.indptr.size - 1), dtype=np.int32)
    m.data = np.ones(len(indices))
    return m


def _write(tmp_path: Path, name: str, data: bytes | dict) -> Path:
    path = tmp_path / name
    path.write_bytes(data if isinstance(data, bytes) else pickle.dumps(data, protocol=2))
    return path


# --------------------------------------------------------------------------- case 1: sparse internals


@pytest.mark.parametrize("index", [100_000_000, 7, 40, -4])
def test_sparse_indices_out_of_range_are_refused_not_written(tmp_path: Path, index: int) -> None:
    """A CSR ``v_template`` whose indices point outside the matrix: a clear error, no write."""
    evil = _tampered_sparse((40, 3), [0, 1, index])
    path = _write(tmp_path, "evil.pkl", _model(v_template=evil))
    rc, msg, err, _ = _load_in_child(path)
    assert rc == 1, (rc, err[-2000:])
    assert "v_template" in msg and "indices" in msg and "evil.pkl" in msg, msg
    assert "Traceback" not in err and "Segmentation" not in err


@pytest.mark.parametrize("indptr, match", [
    ([0, 2, 1, 3], "non-decreasing"),
    ([1, 1, 2, 3], "start at 0"),
    ([0, 1, 2, 9], "nnz"),
    ([0, 1, 3], "length"),
])
def test_sparse_indptr_is_checked(tmp_path: Path, indptr: list[int], match: str) -> None:
    m = scipy.sparse.csc_matrix(np.ones((2, 3)))
    m.indptr = np.asarray(indptr, dtype=np.int32)
    m.indices = np.zeros(3, dtype=np.int32)
    m.data = np.ones(3)
    path = _write(tmp_path, "bad.pkl", _model(J_regressor=m))
    rc, msg, err, _ = _load_in_child(path)  # scipy's toarray on these crashed the old loader
    assert rc == 1 and re.search(rf"bad\.pkl: J_regressor: .*{match}", msg), (rc, msg, err[-2000:])


def test_sparse_shape_and_sizes_are_checked(tmp_path: Path) -> None:
    m = scipy.sparse.csr_matrix(np.ones((5, 40)))
    m.data = np.ones(3)  # fewer values than indices
    rc, msg, err, _ = _load_in_child(_write(tmp_path, "a.pkl", _model(J_regressor=m)))
    assert rc == 1 and re.search(r"J_regressor: .*data", msg), (rc, msg, err[-2000:])
    m = scipy.sparse.coo_matrix(np.ones((5, 40)))
    m.coords = (m.coords[0], m.coords[1] + 1)  # column 40 of 40
    rc, msg, err, _ = _load_in_child(_write(tmp_path, "b.pkl", _model(J_regressor=m)))
    assert rc == 1 and re.search(r"J_regressor: .*column", msg), (rc, msg, err[-2000:])


def test_valid_sparse_matrices_still_load_exactly(tmp_path: Path) -> None:
    """csc, csr and coo (duplicates summed, as scipy does) give the same dense array."""
    arrays = _model()
    dense = arrays["J_regressor"]
    for kind in (scipy.sparse.csc_matrix, scipy.sparse.csr_matrix, scipy.sparse.coo_matrix,
                 scipy.sparse.csr_array):
        loaded = load_flame_arrays(_write(tmp_path, "ok.pkl", _model(J_regressor=kind(dense))))
        np.testing.assert_array_equal(loaded["J_regressor"], dense)
    dup = scipy.sparse.coo_matrix((np.array([0.25, 0.5]), (np.array([1, 1]), np.array([2, 2]))), shape=(5, 40))
    expect = np.zeros((5, 40))
    expect[1, 2] = 0.75
    got = flame_io._sparse_to_dense(_captured(dup), "J_regressor", "dup")
    np.testing.assert_array_equal(got, expect)


def _captured(matrix: object) -> object:
    """The stub the loader captures for a pickled sparse matrix (scipy never touches it)."""
    return flame_io._FlameUnpickler.loads(pickle.dumps(matrix, protocol=2), "<test>")


def test_scipy_is_never_called_on_pickled_sparse_state(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import scipy.sparse._compressed as compressed

    def boom(*args: object, **kwargs: object) -> None:
        raise AssertionError("scipy touched pickled sparse state")

    evil = _write(tmp_path, "evil.pkl", _model(v_template=_tampered_sparse((40, 3), [0, 1, 7])))
    good = _model()
    good["J_regressor"] = scipy.sparse.csr_matrix(good["J_regressor"])
    path = _write(tmp_path, "good.pkl", good)
    monkeypatch.setattr(compressed._cs_matrix, "toarray", boom)
    monkeypatch.setattr(compressed._cs_matrix, "__init__", boom)
    with pytest.raises(FlameError, match="indices"):
        load_flame_arrays(evil)
    np.testing.assert_array_equal(load_flame_arrays(path)["J_regressor"], _model()["J_regressor"])


# --------------------------------------------------------------------------- case 2: memory bombs


def _call(module: str, name: str, *args: int) -> bytes:
    return (b"c" + module.encode() + b"\n" + name.encode() + b"\n("
            + b"".join(b"I%d\n" % a for a in args) + b"tR.")


def test_bytearray_bomb_is_refused_before_allocating(tmp_path: Path) -> None:
    path = _write(tmp_path, "bomb.pkl", _call("builtins", "bytearray", 3_000_000_000))
    assert path.stat().st_size < 70
    rc, msg, err, peak = _load_in_child(path)
    assert rc == 1 and "budget" in msg and "bomb.pkl" in msg, (msg, err[-2000:])
    assert 0 < peak < 2 << 30


@pytest.mark.parametrize("cols", [250_000_000, 100_000_000_000])
def test_huge_sparse_shape_is_refused_before_allocating(tmp_path: Path, cols: int) -> None:
    m = scipy.sparse.csr_matrix((1, 3))
    m._shape = (1, cols)
    path = _write(tmp_path, "wide.pkl", _model(v_template=m))
    rc, msg, err, peak = _load_in_child(path)
    assert rc == 1 and "v_template" in msg and "budget" in msg, (msg, err[-2000:])
    assert "Traceback" not in err
    assert 0 < peak < 2 << 30


def test_budget_check_runs_before_the_dense_build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple] = []
    real = flame_io._build_dense
    monkeypatch.setattr(flame_io, "_build_dense", lambda *a: calls.append(a[0]) or real(*a))
    m = scipy.sparse.csr_matrix((1, 3))
    m._shape = (1, 250_000_000)
    with pytest.raises(FlameError, match="budget"):
        load_flame_arrays(_write(tmp_path, "wide.pkl", _model(v_template=m)))
    assert calls == []
    good = _model()
    good["J_regressor"] = scipy.sparse.csr_matrix(good["J_regressor"])
    load_flame_arrays(_write(tmp_path, "good.pkl", good))
    assert calls == [(5, 40)]


def test_array_reconstruct_and_file_size_are_budgeted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    data = b"cnumpy._core.multiarray\n_reconstruct\n(cnumpy\nndarray\n(I4000000000\ntC\x01btR."
    with pytest.raises(FlameError, match="budget"):
        load_flame_arrays(_write(tmp_path, "rec.pkl", data))
    monkeypatch.setattr(flame_io, "LOAD_BUDGET_BYTES", 10_000)  # list("x" * 1000): an object per character
    data = b"cbuiltins\nlist\n(X" + (1000).to_bytes(4, "little") + b"x" * 1000 + b"tR."
    with pytest.raises(FlameError, match=r"list\(\) of 1000 characters .*budget"):
        load_flame_arrays(_write(tmp_path, "chars.pkl", data))
    monkeypatch.setattr(flame_io, "MAX_PICKLE_BYTES", 1000)
    path = _write(tmp_path, "big.pkl", _model())
    with pytest.raises(FlameError, match=r"big\.pkl: .*bytes.*limit"):
        load_flame_arrays(path)


# --------------------------------------------------------------------------- case 3: recursion bombs


def _nested_tuple_key(depth: int) -> bytes:
    return b"\x80\x02}N" + b"\x85" * depth + b"Ns."


@pytest.mark.parametrize("depth", [20_000, 200_000])
def test_deeply_nested_dict_key_is_refused(tmp_path: Path, depth: int) -> None:
    path = _write(tmp_path, "deep.pkl", _nested_tuple_key(depth))
    rc, msg, err, _ = _load_in_child(path)
    assert rc == 1 and "deep.pkl" in msg and "key" in msg, (rc, msg, err[-2000:])
    assert "Traceback" not in err


def test_deeply_nested_list_as_array_is_refused(tmp_path: Path) -> None:
    depth = 200_000
    nested = b"]" * depth + b"a" * (depth - 1)  # a list nested 200 000 deep, as v_template of a full model
    marker = b"X\x0c\x00\x00\x00NESTEDMARKER"
    data = pickle.dumps(_model(v_template="NESTEDMARKER"), protocol=2)
    assert data.count(marker) == 1
    path = _write(tmp_path, "deep.pkl", data.replace(marker, nested))
    rc, msg, err, _ = _load_in_child(path)
    assert rc == 1 and "deep.pkl" in msg and "nested" in msg, (rc, msg, err[-2000:])
    assert "Traceback" not in err


def test_required_keys_must_be_arrays(tmp_path: Path) -> None:
    with pytest.raises(FlameError, match=r"v_template: expected a numpy array.*found list"):
        load_flame_arrays(_write(tmp_path, "list.pkl", _model(v_template=[[0.0, 0.0, 0.0]] * 40)))


def test_object_arrays_are_refused(tmp_path: Path) -> None:
    with pytest.raises(FlameError, match="object"):
        load_flame_arrays(_write(tmp_path, "obj.pkl", _model(extra=np.array([None, [1]], dtype=object))))



_BATCH = textwrap.dedent("""
    import sys
    import numpy as np
    from holo_viewer.avatar.gaussians import Gaussians
    from holo_viewer.avatar.ply import save_ply
    from holo_viewer.cli import main
    empty = Gaussians(np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32), np.zeros((0, 3), np.float32),
                      np.zeros(0, np.float32), np.zeros((0, 1, 3), np.float32))  # the model fails first
    save_ply(empty, sys.argv[1] + "/avatar.ply")
    sys.exit(main(["render-batch", sys.argv[1] + "/m.jsonl", "--out", sys.argv[1] + "/out", "--in-process"]))
""")


@pytest.mark.slow  # renders the good row in a fresh interpreter: ~3 s
def test_a_bad_model_row_fails_alone_in_render_batch(tmp_path: Path) -> None:
    """The tampered pickle as one row's flame_model: that row fails, the next renders, summary.json is written.

    In process (``--in-process``): the evil row is loaded in the same interpreter that then renders the good
    row, so a crash on it (exit 139, as before the fix) fails the test; Ray's own start-up (~7 s of waiting, a
    local cluster in the child) is not what this checks (test_batch_ray.py runs bad rows on Ray)."""
    _write(tmp_path, "evil.pkl", _model(v_template=_tampered_sparse((40, 3), [0, 1, 100_000_000])))
    rows = [{"id": "evil", "avatar": "avatar.ply", "flame_model": "evil.pkl", "frames": 1, "tile_scale": 0.05,
             "outputs": ["quilt_png"]},
            {"id": "good", "frames": 1, "tile_scale": 0.05, "outputs": ["quilt_png"]}]
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", _BATCH, str(tmp_path)], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode in (0, 1), (proc.returncode, proc.stderr[-2000:])  # 139 before: a segfault
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    status = {j["id"]: (j["status"], j["error"]) for j in summary["jobs"]}
    assert status["good"][0] == "done"
    assert status["evil"][0] == "failed" and "evil.pkl" in status["evil"][1] and "indices" in status["evil"][1]
