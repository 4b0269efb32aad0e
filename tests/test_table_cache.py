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
    assert table_cache.keep_count("gather") == 2 and table_cache.keep_count("visible_gaussians") == 24


def _mask(i: int) -> np.ndarray:
    return np.arange(7) % (i % 5 + 2) == 0


def _masks(cache, keys, built: list) -> None:
    """Each key's mask as a separate ``live`` start would get it (this process's kept tables forgotten)."""
    for i, key in keys:
        table_cache._KEPT.clear()
        got = table_cache.cached_tables("visible_gaussians", key, {"keep": ((7,), "bool")},
                                        lambda i=i: built.append(i) or {"keep": _mask(i)})
        assert np.array_equal(got["keep"], _mask(i))


def test_the_wards_masks_all_stay_cached(cache):
    """A course cycling the ward (default + 6 patients) at tile scales 0.5 and 1: 14 visible-Gaussian masks,
    each built once (the old count of 4 per kind rebuilt all 14 at every round)."""
    keys = list(enumerate(table_cache.table_key("visible_gaussians", None, avatar=a, tile_scale=s)
                          for a in range(7) for s in (0.5, 1.0)))
    built: list = []
    for _ in range(3):
        _masks(cache, keys, built)
    assert built == list(range(14))
    assert len(list(cache.glob("visible_gaussians_*.npz"))) == 14


def test_masks_beyond_the_count_go_least_recently_used_first(cache):
    n = table_cache.keep_count("visible_gaussians")
    keys = [(i, table_cache.table_key("visible_gaussians", None, avatar=i)) for i in range(n + 2)]
    built: list = []
    _masks(cache, keys[:n], built)
    _masks(cache, keys[:1], built)  # mask 0 used again: now the most recent
    _masks(cache, keys[n:], built)  # two more: masks 1 and 2 (the least recently used) removed
    left = {p.name for p in cache.glob("visible_gaussians_*.npz")}
    assert left == {f"visible_gaussians_{k}.npz" for i, k in keys if i not in (1, 2)}
    assert built == list(range(n + 2))


def test_two_patients_get_separate_masks(cache, monkeypatch):
    """`holo-viewer live --avatar NAME` (live/render.py): visible_mask keys the mask by the avatar's own Gaussians,
    and the background build runs once per (avatar, tile scale) naming the avatar. The weights are stubbed (the
    real ones: tests/test_visibility.py); tile scale 0.05, ~2 s of CPU, most of it loading the two patients."""
    import subprocess

    from holo_viewer.display.calibration import DisplayCalibration
    from holo_viewer.pipeline import Pipeline, ViewSettings, live_support
    from holo_viewer.pipeline.scene import load_avatar
    from holo_viewer.render import visibility

    def weights(g, cams, per_view=False):  # (V, N): a view-dependent share of each Gaussian's opacity
        g = g.numpy()
        return np.outer(np.linspace(0.001, 1.0, len(cams)), 1.0 / (1.0 + np.exp(-g.opacity_logits.astype(float))))

    monkeypatch.setattr(visibility, "max_weights", weights)
    poses = ({"jaw_pose": (0.3, 0.0, 0.0)},)
    pipes, masks = {}, {}
    for name in ("helen", "james"):
        model, avatar, _, _ = load_avatar(name, need_gaussians=True)
        pipes[name] = Pipeline(calibration=DisplayCalibration.load(None), view=ViewSettings(tile_scale=0.05),
                               model=model, avatar=avatar)
        assert live_support.visible_mask(pipes[name], poses=poses, cached_only=True) is None  # neither shares one
        masks[name] = live_support.visible_mask(pipes[name], poses=poses, per_view=True)
        n = len(pipes[name].gaussians())
        assert masks[name].shape == (len(pipes[name].cameras()), n)
    assert masks["helen"].shape[1] != masks["james"].shape[1]  # 102263 and 97344 Gaussians
    assert len(list(cache.glob("visible_gaussians_*.npz"))) == 2
    for name in ("helen", "james"):
        np.testing.assert_array_equal(live_support.visible_mask(pipes[name], poses=poses, per_view=True,
                                                                cached_only=True), masks[name])
    started = []
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: started.append(a[0]))
    monkeypatch.setattr(live_support, "_later", set())
    monkeypatch.setenv("HOLO_VIEWER_BACKGROUND_BUILDS", "1")
    for name, scale in (("helen", 0.5), ("james", 0.5), ("helen", 0.5), ("helen", 1.0)):
        live_support.build_visible_mask_later(name, scale)
    assert [c[-2:] for c in started] == [["helen", "0.5"], ["james", "0.5"], ["helen", "1.0"]]
