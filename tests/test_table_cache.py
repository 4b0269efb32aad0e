"""The on-disk cache of the panel's tables (display/table_cache.py): exact, validated, keyed."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from holo_viewer.display import slices, table_cache
from holo_viewer.display.calibration import DisplayCalibration
from holo_viewer.display.device import view_gather_indices
from holo_viewer.display.lenticular import Interleaver

# same optics as the Portrait, a tiny screen and quilt (tables of 64 x 48 x 3 subpixels)
TINY = dataclasses.replace(DisplayCalibration.load(None), screen_w=64, screen_h=48).with_quilt(8, 6, 96, 96)


def _tables(cal: DisplayCalibration, mode: str) -> dict[str, np.ndarray]:
    """Every cached table of ``cal`` (a fresh interleaver, the in-memory bucket cache emptied)."""
    slices._BUCKETS.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # nominal preset calibration
        il = Interleaver(cal, (96, 96, 3), mode=mode)
    out = dict(zip(("g0", "g1", "gw"), view_gather_indices(il, 48, 16, 12)))
    b = slices.subpixel_buckets(il, 48, 16, 12)
    out.update({f"b_{n}": getattr(b, n) for n in slices.SubpixelBuckets._TABLES})
    out["k0"], out["k1"] = il._block_keys(4)
    out["subs"], out["offsets"] = il._reader_table(4)
    return out


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if a[k] is None:
            assert b[k] is None, k
        else:
            assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_VIEWER_CACHE", str(tmp_path))
    monkeypatch.delenv(table_cache.DISABLE_VAR, raising=False)
    return tmp_path / "display_tables"


@pytest.mark.parametrize("mode", ["nearest", "blend"])
def test_cached_tables_equal_fresh_ones(cache, monkeypatch, mode):
    monkeypatch.setenv(table_cache.DISABLE_VAR, "0")
    fresh = _tables(TINY, mode)
    assert not cache.exists()  # disabled: nothing written
    monkeypatch.delenv(table_cache.DISABLE_VAR)
    _same(_tables(TINY, mode), fresh)  # built and written
    assert len(list(cache.glob("*.npz"))) == 4
    loads = []
    real = table_cache._load
    monkeypatch.setattr(table_cache, "_load", lambda *a: loads.append(a[0]) or real(*a))
    table_cache._KEPT.clear()  # what another process finds: the files
    _same(_tables(TINY, mode), fresh)  # read back
    assert len(loads) == 4
    again = _tables(TINY, mode)
    _same(again, fresh)  # this process kept them: not read again, and each caller gets its own copy
    assert len(loads) == 4
    again["k0"][:] = 0
    _same(_tables(TINY, mode), fresh)


def test_damaged_cache_files_are_rebuilt_with_a_warning(cache):
    fresh = _tables(TINY, "blend")
    files = sorted(cache.glob("*.npz"))
    gather = next(p for p in files if p.name.startswith("gather_"))
    data = bytearray(gather.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one flipped byte inside an index array
    gather.write_bytes(bytes(data))
    buckets = next(p for p in files if p.name.startswith("buckets_"))
    buckets.write_bytes(buckets.read_bytes()[:1000])  # truncated
    with pytest.warns(RuntimeWarning, match="rebuilding") as rec:
        _same(_tables(TINY, "blend"), fresh)
    assert {str(gather), str(buckets)} <= {str(w.message).split(": ")[0] for w in rec}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # rewritten: read back without complaint
        _same(_tables(TINY, "blend"), fresh)


def test_a_foreign_file_under_the_key_is_not_trusted(cache):
    fresh = _tables(TINY, "nearest")
    readers = next(cache.glob("readers_*.npz"))
    with np.load(readers) as z:  # a valid file of the right name whose stored key differs
        np.savez(readers, __key__=np.array("0" * 32), __crc__=z["__crc__"], subs=z["subs"], offsets=z["offsets"])
    with pytest.warns(RuntimeWarning, match="key"):
        _same(_tables(TINY, "nearest"), fresh)
    with np.load(readers) as z:  # the right key, a valid zip, one changed value: the stored CRC-32 refuses it
        subs = z["subs"].copy()
        subs[0] += 1
        np.savez(readers, __key__=z["__key__"], __crc__=z["__crc__"], subs=subs, offsets=z["offsets"])
    with pytest.warns(RuntimeWarning, match="checksum"):
        _same(_tables(TINY, "nearest"), fresh)


def test_a_changed_calibration_misses_the_cache(cache):
    before = _tables(TINY, "nearest")
    names = {p.name for p in cache.glob("*.npz")}
    moved = dataclasses.replace(TINY, center=TINY.center + 0.25)
    after = _tables(moved, "nearest")
    assert {p.name for p in cache.glob("*.npz")} - names  # new files, new keys
    assert not np.array_equal(after["g0"], before["g0"])
    assert table_cache.table_key("gather", moved) != table_cache.table_key("gather", TINY)


def test_the_table_folder_can_be_chosen(cache, tmp_path, monkeypatch):
    monkeypatch.setenv(table_cache.DISABLE_VAR, str(tmp_path / "cold"))
    _tables(TINY, "nearest")
    assert len(list((tmp_path / "cold").glob("*.npz"))) == 4 and not cache.exists()


def test_old_tables_are_pruned(cache, monkeypatch):
    monkeypatch.setattr(table_cache, "KEEP", 2)
    for shift in (0.1, 0.2, 0.3):
        _tables(dataclasses.replace(TINY, center=TINY.center + shift), "nearest")
    assert len(list(cache.glob("gather_*.npz"))) == 2 and len(list(cache.glob("*.npz"))) == 8
