"""Property-based fuzzing of every file reader (issue 31): bad bytes give our error, nothing else.

For each reader (JSON files, ``.npz``, PLY headers, WAV headers, FLAME pickles, reaction
checkpoints, session folders) Hypothesis mutates a valid file or generates hostile structure. The
property: the reader returns, or raises a :class:`~holo_viewer.errors.HoloViewerError`; never
another exception, a crash or a hang. Each example runs under a time budget (Hypothesis'
``deadline``) and a memory budget (peak traced allocation, numpy's buffers included, measured
with ``tracemalloc``). Examples are few and derandomized so the suite stays cheap in CI; run
with ``HOLO_FUZZ_EXAMPLES=2000`` for a longer local search.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import tracemalloc
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from holo_viewer.errors import HoloViewerError  # noqa: E402

#: peak bytes one reader call may allocate (tracemalloc: Python objects and numpy buffers)
MEMORY_BUDGET = 256 << 20
EXAMPLES = int(os.environ.get("HOLO_FUZZ_EXAMPLES", "25"))
FUZZ = settings(max_examples=EXAMPLES, deadline=5000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _within_budget(call: Callable[[], Any]) -> None:
    """Run ``call``: it returns or raises HoloViewerError, and allocates at most MEMORY_BUDGET."""
    tracemalloc.start()
    try:
        call()
    except HoloViewerError:
        pass
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert peak <= MEMORY_BUDGET, f"peak allocation {peak:,} bytes"


def _mutations(valid: bytes) -> st.SearchStrategy[bytes]:
    """Byte-level mutations of ``valid``: overwrite, truncate, insert, or any bytes at all."""
    n = len(valid)
    overwrite = st.tuples(st.integers(0, max(n - 1, 0)), st.binary(min_size=1, max_size=16)).map(
        lambda t: valid[:t[0]] + t[1] + valid[t[0] + len(t[1]):])
    truncate = st.integers(0, n).map(lambda k: valid[:k])
    insert = st.tuples(st.integers(0, n), st.binary(min_size=1, max_size=64)).map(
        lambda t: valid[:t[0]] + t[1] + valid[t[0]:])
    return st.one_of(overwrite, truncate, insert, st.binary(max_size=256))


def _write(tmp: Path, name: str, data: bytes) -> Path:
    path = tmp / name
    path.write_bytes(data)
    return path


# --------------------------------------------------------------------------- JSON readers

_json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=20)


def _json_docs(template: dict) -> st.SearchStrategy[str]:
    """A template with fields replaced by hostile values, hostile documents, and deep nesting."""
    keys = sorted(template)
    swapped = st.tuples(st.sampled_from(keys), _json_values).map(lambda kv: json.dumps({**template, kv[0]: kv[1]}))
    deep = st.integers(1, 3000).map(lambda d: "[" * d + "]" * d)
    return st.one_of(swapped, _json_values.map(json.dumps), deep, st.text(max_size=64))


def _json_readers() -> dict[str, tuple[dict, Callable[[Path], Any]]]:
    from holo_viewer.batch.manifest import read_manifest
    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.flame.expressions import AUMap, default_au_map
    from holo_viewer.live.controls import Scenario
    from holo_viewer.reaction.train import load_train_config
    from holo_viewer.tracking.viewer import WebcamMount

    root = Path(__file__).resolve().parents[1]
    calibration = json.loads((root / "assets" / "lkg_portrait_visual.json").read_text())
    return {
        "calibration": (calibration, DisplayCalibration.from_file),
        "au_map": (default_au_map().to_dict(), AUMap.load_json),
        "scenario": ({"events": [{"t": 1, "pain": 0.5, "duration": 2}]}, Scenario.load),
        "mount": ({"position_m": [0, 0.1, 0], "rotation_deg": [0, 0, 0], "hfov_deg": 60, "mirrored": False},
                  WebcamMount.load),
        "train_config": ({"max_steps": 10, "batch_size": 4, "model": {"d_model": 32}}, load_train_config),
        "manifest": ({"flame_params": "a.npz", "outputs": ["quilt_mp4"]},
                     lambda p: read_manifest(p.rename(p.with_suffix(".jsonl")))),
    }


@pytest.mark.parametrize("reader", ["calibration", "au_map", "scenario", "mount", "train_config", "manifest"])
def test_json_readers_fuzzed(tmp_path: Path, reader: str) -> None:
    template, read = _json_readers()[reader]

    @FUZZ
    @given(_json_docs(template))
    def run(text: str) -> None:
        path = _write(tmp_path, "in.json", text.encode("utf-8", "surrogatepass"))
        _within_budget(lambda: read(path))
        for p in tmp_path.iterdir():
            p.unlink()

    run()


# --------------------------------------------------------------------------- .npz and session folders


def _npz_bytes(**arrays: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.mark.parametrize("suffix", [".npz", ".npy"])
def test_npz_and_npy_readers_fuzzed(tmp_path: Path, suffix: str) -> None:
    from holo_viewer.fileio import read_npy, read_npz

    if suffix == ".npz":
        valid, read = _npz_bytes(a=np.arange(12.0).reshape(3, 4), b=np.array(["x", "yz"])), read_npz
    else:
        buf = io.BytesIO()
        np.save(buf, np.arange(12.0).reshape(3, 4))
        valid, read = buf.getvalue(), read_npy

    @FUZZ
    @given(_mutations(valid))
    def run(data: bytes) -> None:
        path = _write(tmp_path, "f" + suffix, data)
        _within_budget(lambda: read(path))

    run()


def test_session_folders_fuzzed(tmp_path: Path) -> None:
    from holo_viewer.live.session import TRACK_KEYS, load_session

    n = 4
    tracks = {k: np.zeros((n, 3)) if k.startswith(("listener_", "speaker_")) else np.zeros(n) for k in TRACK_KEYS}
    arrays = st.one_of(st.just(np.zeros(n)), st.just(np.zeros(())), st.just(np.zeros((n - 1, 3))),
                       st.just(np.array(["a"] * n)), st.just(np.full(n, np.nan)), st.just(np.zeros((0,))))
    meta = st.one_of(_json_values, st.fixed_dictionaries({"settings": _json_values}),
                     st.fixed_dictionaries({"settings": st.fixed_dictionaries({"tile_scale": _json_values})}))

    @FUZZ
    @given(meta, st.dictionaries(st.sampled_from(TRACK_KEYS), arrays, max_size=3))
    def run(meta_doc: Any, changes: dict) -> None:
        folder = tmp_path / "s"
        folder.mkdir(exist_ok=True)
        (folder / "session.json").write_text(json.dumps(meta_doc))
        np.savez(folder / "tracks.npz", **{**tracks, **changes})
        _within_budget(lambda: load_session(folder))

    run()


# --------------------------------------------------------------------------- PLY and WAV headers


def test_ply_headers_fuzzed(tmp_path: Path) -> None:
    from holo_viewer.avatar.ply import load_ply, save_ply
    from test_hardening import _empty_gaussians

    valid = save_ply(_empty_gaussians(), tmp_path / "ok.ply").read_bytes()
    header_end = valid.index(b"end_header\n") + len(b"end_header\n")
    lines = st.lists(st.sampled_from([b"element vertex 4000000000", b"property float x", b"property list uchar int f",
                                      b"format ascii 1.0", b"format binary_big_endian 1.0", b"element face 3",
                                      b"comment x", b"property double nx", b"element vertex -1"]), max_size=6)
    headers = st.one_of(_mutations(valid[:header_end]),
                        lines.map(lambda ls: b"ply\nformat binary_little_endian 1.0\n" + b"\n".join(ls)
                                  + b"\nend_header\n"))

    @FUZZ
    @given(headers, st.binary(max_size=128))
    def run(header: bytes, body: bytes) -> None:
        path = _write(tmp_path, "f.ply", header + body)
        _within_budget(lambda: load_ply(path))

    run()


def test_wav_headers_fuzzed(tmp_path: Path) -> None:
    from holo_viewer.reaction.audio import read_wav, write_wav

    valid = write_wav(tmp_path / "ok.wav", np.zeros(800, np.float32), 16000).read_bytes()

    @FUZZ
    @given(_mutations(valid[:64]).map(lambda h: h + valid[64:]))
    def run(data: bytes) -> None:
        path = _write(tmp_path, "f.wav", data)
        _within_budget(lambda: read_wav(path))

    run()


# --------------------------------------------------------------------------- pickles and checkpoints


def test_flame_pickles_fuzzed(tmp_path: Path) -> None:
    import scipy.sparse

    from holo_viewer.flame.io import load_flame_arrays
    from holo_viewer.flame.synthetic import random_flame_arrays

    arrays = random_flame_arrays(n_vertices=12, n_shape=2, n_expr=2, n_faces=8, seed=1)
    arrays["J_regressor"] = scipy.sparse.csc_matrix(arrays["J_regressor"])
    valid = pickle.dumps(arrays, protocol=2)
    ops = st.lists(st.sampled_from([b"(", b"t", b"l", b"d", b"}", b"]", b")", b"N", b"\x85", b"\x86", b"a", b"s",
                                    b"u", b"e", b"b", b"R", b"\x81", b"0", b"2", b"K\x05", b"J\xff\xff\xff\x7f",
                                    b"cbuiltins\nbytearray\n", b"cnumpy\ndtype\n", b"cnumpy\nndarray\n",
                                    b"cscipy.sparse._csr\ncsr_matrix\n", b"ccopyreg\n_reconstructor\n",
                                    b"cbuiltins\nset\n", b"X\x01\x00\x00\x00k", b"C\x01b", b"h\x00", b"q\x00"]),
                   max_size=40).map(lambda xs: b"\x80\x02" + b"".join(xs) + b".")

    @FUZZ
    @given(st.one_of(_mutations(valid), ops))
    def run(data: bytes) -> None:
        path = _write(tmp_path, "m.pkl", data)
        _within_budget(lambda: load_flame_arrays(path))

    run()


def test_reaction_checkpoints_fuzzed(tmp_path: Path) -> None:
    import torch

    from holo_viewer.reaction.api import default_checkpoint_path
    from holo_viewer.reaction.train import load_checkpoint

    base = torch.load(default_checkpoint_path(), map_location="cpu", weights_only=True)
    valid = default_checkpoint_path().read_bytes()
    fields = ["d_model", "ff_dim", "n_heads", "enc_layers", "dec_layers", "n_codes", "state_dim", "k"]

    @settings(FUZZ, max_examples=max(EXAMPLES // 3, 5), deadline=None)  # a checkpoint load is ~0.3 s
    @given(st.one_of(
        st.tuples(st.sampled_from(fields), st.one_of(st.integers(-3, 1 << 20), _json_values)).map(lambda kv: ("cfg", kv)),
        _mutations(valid[:4096]).map(lambda head: ("bytes", head + valid[4096:]))))
    def run(case: tuple) -> None:
        kind, value = case
        path = tmp_path / "c.pt"
        if kind == "cfg":
            d = {**base, "train_config": json.loads(json.dumps(base["train_config"]))}
            d["train_config"]["model"][value[0]] = value[1]
            torch.save(d, path)
        else:
            path.write_bytes(value)
        _within_budget(lambda: load_checkpoint(path))

    run()


def test_zip_members_declaring_huge_sizes_fuzzed(tmp_path: Path) -> None:
    """Forged central-directory sizes never make the .npz reader allocate them."""
    from holo_viewer.fileio import read_npz

    valid = _npz_bytes(a=np.zeros(16))

    @FUZZ
    @given(st.integers(0, 2**32 - 1))
    def run(size: int) -> None:
        data = bytearray(valid)
        cd = data.rfind(b"PK\x01\x02")
        data[cd + 24:cd + 28] = size.to_bytes(4, "little")  # uncompressed size in the central directory
        path = _write(tmp_path, "z.npz", bytes(data))
        _within_budget(lambda: read_npz(path))

    run()
    assert zipfile.is_zipfile(io.BytesIO(valid))
