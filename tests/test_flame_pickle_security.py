"""FLAME pickles cannot run code, touch files or import modules (issue 19, items 1 and 2).

Each crafted pickle names one (module, name) pair and calls it. The loader must refuse
the pair before importing anything: no command runs, no file changes, no module with
import side effects is loaded, and the CLI exits 1 without writing its output.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

from holo_viewer.cli import main
from holo_viewer.errors import FlameError
from holo_viewer.flame.io import load_flame_arrays
from holo_viewer.flame.synthetic import random_flame_arrays

SENTINEL = "HOLO_VIEWER_PAYLOAD_SENTINEL"


def _op_value(value: object) -> bytes:
    """Protocol-0 opcodes pushing a str, int, list or tuple."""
    if isinstance(value, str):
        return b"V" + value.encode("raw_unicode_escape") + b"\n"
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, (list, tuple)):
            body = b"(" + b"".join(_op_value(v) for v in value)
            return body + (b"l" if isinstance(value, list) else b"t")
        raise TypeError(value)
    return b"I" + str(value).encode() + b"\n"


def call_opcodes(module: str, name: str, *args: object) -> bytes:
    """Protocol-0 opcodes calling ``module.name(*args)`` (GLOBAL, MARK, args, TUPLE, REDUCE)."""
    return b"c" + module.encode() + b"\n" + name.encode() + b"\n(" + b"".join(_op_value(a) for a in args) + b"tR"


def model_pickle(payload: bytes | None = None) -> bytes:
    """A valid FLAME-format pickle (protocol 0); ``payload`` replaces the value of its extra key."""
    arrays = random_flame_arrays(n_vertices=60, n_shape=4, n_expr=3, seed=2)
    arrays["J_regressor"] = scipy.sparse.csc_matrix(arrays["J_regressor"])
    arrays["extra"] = SENTINEL
    data = pickle.dumps(arrays, protocol=0)
    marker = b"V" + SENTINEL.encode() + b"\n"
    assert data.count(marker) == 1
    return data if payload is None else data.replace(marker, payload)


def _payloads(tmp: Path) -> list[tuple[str, str, tuple]]:
    touch = f"touch {tmp / 'pwned'}"
    return [
        ("numpy.distutils.fcompiler.gnu", "Popen", (["sh", "-c", touch],)),  # subprocess.Popen re-exported
        ("numpy.distutils.exec_command", "exec_command", (touch,)),
        ("subprocess", "Popen", (["sh", "-c", touch],)),
        ("subprocess", "check_call", (["sh", "-c", touch],)),
        ("os", "system", (touch,)),
        ("posix", "system", (touch,)),
        ("builtins", "eval", (f"__import__('os').system({touch!r})",)),
        ("builtins", "exec", (f"__import__('os').system({touch!r})",)),
        ("__builtin__", "eval", (f"__import__('os').system({touch!r})",)),
        ("builtins", "getattr", ("os", "system")),
        ("builtins", "__import__", ("os",)),
        ("builtins", "open", (str(tmp / "pwned"), "w")),
        ("numpy", "load", (str(tmp / "pwned"),)),
        ("numpy", "ndarray.__reduce_ex__", (2,)),  # dotted names are not walked
        ("numpy.f2py.__main__", "main", ()),  # importing this module starts f2py
        ("numpy.f2py", "run_main", (["-h"],)),
        ("scipy.sparse", "load_npz", (str(tmp / "pwned"),)),
        ("torch", "load", (str(tmp / "pwned"),)),
        ("chumpy.ch", "Ch.__init__.__globals__", ()),
    ]


@pytest.mark.parametrize("index", range(19))
def test_crafted_reference_is_refused(tmp_path: Path, index: int) -> None:
    module, name, args = _payloads(tmp_path)[index]
    path = tmp_path / "evil.pkl"
    path.write_bytes(call_opcodes(module, name, *args) + b".")
    with pytest.raises(FlameError, match="refusing"):
        load_flame_arrays(path)
    assert not (tmp_path / "pwned").exists()


def test_memmap_cannot_truncate_a_file(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious data\n" * 100)
    before = victim.read_bytes()
    for payload in (
        call_opcodes("numpy", "memmap", str(victim), "uint8", "w+", 0, (4,)),
        call_opcodes("numpy.core.memmap", "memmap", str(victim), "uint8", "w+", 0, (4,)),
        call_opcodes("numpy._core.memmap", "memmap", str(victim), "uint8", "w+", 0, (4,)),
        # a memmap smuggled in as the subtype of the array reconstructor
        call_opcodes("numpy.core.multiarray", "_reconstruct", "SUBTYPE", (0,), "b").replace(
            b"VSUBTYPE\n", b"cnumpy\nmemmap\n"),
    ):
        path = tmp_path / "evil.pkl"
        path.write_bytes(model_pickle(payload))
        with pytest.raises(FlameError, match=r"memmap.*refusing"):
            load_flame_arrays(path)
        assert victim.read_bytes() == before


def test_codecs_encode_is_latin1_only(tmp_path: Path) -> None:
    path = tmp_path / "codec.pkl"
    path.write_bytes(model_pickle(call_opcodes("_codecs", "encode", "abc", "rot13")))
    with pytest.raises(FlameError, match=r"latin1"):
        load_flame_arrays(path)
    path.write_bytes(model_pickle(call_opcodes("_codecs", "encode", "abc", "latin1")))
    assert load_flame_arrays(path)["extra"] == b"abc"


def test_hidden_extra_key_fails_the_cli_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    good = tmp_path / "good.pkl"
    good.write_bytes(model_pickle())
    assert main(["export-mesh", "--flame-model", str(good), "--out", str(tmp_path / "ok.obj")]) == 0
    assert (tmp_path / "ok.obj").exists()

    out_dir = tmp_path / "out"
    out_dir.mkdir()
    marker = tmp_path / "pwned"
    for module, name in [("numpy.distutils.fcompiler.gnu", "Popen"), ("subprocess", "Popen")]:
        evil = tmp_path / "evil.pkl"
        evil.write_bytes(model_pickle(call_opcodes(module, name, ["sh", "-c", f"touch {marker}"])))
        capsys.readouterr()
        rc = main(["export-mesh", "--flame-model", str(evil), "--out", str(out_dir / "head.obj")])
        err = capsys.readouterr().err
        assert rc == 1
        assert f"references {module}.{name}" in err and "evil.pkl" in err
        assert not marker.exists()
        assert os.listdir(out_dir) == []


def test_no_module_outside_the_allow_list_is_imported(tmp_path: Path) -> None:
    """In a fresh interpreter: every crafted pickle is refused and imports nothing new."""
    cases = [(m, n, list(a)) for m, n, a in _payloads(tmp_path)]
    script = f"""
import json, sys
from pathlib import Path
import numpy, scipy.sparse
from holo_viewer.errors import FlameError
from holo_viewer.flame.io import load_flame_arrays
sys.path.insert(0, {str(Path(__file__).parent)!r})
from test_flame_pickle_security import call_opcodes, model_pickle
p = Path({str(tmp_path)!r}) / "evil.pkl"
p.write_bytes(model_pickle())
load_flame_arrays(p)  # whatever a valid model needs is imported before the snapshot
datas = []
for module, name, args in json.loads({json.dumps(json.dumps(cases))}):
    datas += [(module, name, call_opcodes(module, name, *args) + b"."),
              (module, name, model_pickle(call_opcodes(module, name, *args)))]
before = set(sys.modules)
results = []
for module, name, data in datas:
    p.write_bytes(data)
    try:
        load_flame_arrays(p)
        results.append(("loaded", module, name))
    except FlameError as exc:
        results.append(("refused" if "refusing" in str(exc) else str(exc), module, name))
print(json.dumps({{"results": results, "new": sorted(set(sys.modules) - before)}}))
"""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert all(r[0] == "refused" for r in report["results"]), report["results"]
    assert len(report["results"]) == 2 * len(cases)
    assert report["new"] == [], report["new"]
    assert not (tmp_path / "pwned").exists()


def test_legacy_module_names_of_flame_2020_still_load(tmp_path: Path) -> None:
    """Python 2 / numpy 1.x / old scipy spellings of the allowed pairs resolve."""
    data = model_pickle()
    legacy = (data.replace(b"cnumpy._core.multiarray\n", b"cnumpy.core.multiarray\n")
              .replace(b"cscipy.sparse._csc\n", b"cscipy.sparse.csc\n"))
    assert legacy != data and b"numpy._core" not in legacy and b"scipy.sparse._csc" not in legacy
    path = tmp_path / "legacy.pkl"
    path.write_bytes(legacy)
    new = tmp_path / "new.pkl"
    new.write_bytes(data)
    a, b = load_flame_arrays(path), load_flame_arrays(new)
    for key in ("v_template", "shapedirs", "J_regressor", "f"):
        np.testing.assert_array_equal(a[key], b[key])
