"""The one views -> uint8 quilt -> native function (display.native.views_to_native).

* Refactor only: on fixed random views every form gives the bytes the callers' own code gave before
  they were moved onto it (SHA-256 prefixes saved from that code: ``tile_quilt(as_uint8=True)`` +
  ``Interleaver``; the tracked frames' column loop + ``update_columns`` / ``update(readers)``; the
  synthesized frames' source tiles; ``DeviceInterleaver`` on CPU torch). Exact.
* Against the plain definition: the quilt is ``clip(rint(255 x))`` tiled view 0 bottom-left, and a
  column update leaves the native image equal to a full interleave of the updated quilt. Exact.
* A spy on the function, run through every caller (the pipeline's quilt and native stages, the GUI's
  exports, the live frames of every mode, the device path, quilt-to-native and show's quilt files),
  sees each of them call it; synthesized frames only with ``warp_native`` off (on, the default, the warp
  writes the native image itself: the same bytes, checked here and in tests/test_view_synthesis.py).
"""

from __future__ import annotations

import dataclasses
import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.scenes import random_scene  # noqa: E402
from holo_viewer.display import native as native_mod  # noqa: E402
from holo_viewer.display.calibration import DisplayCalibration  # noqa: E402
from holo_viewer.display.native import ColumnUpdate, views_to_native  # noqa: E402
from holo_viewer.display.lenticular import Interleaver  # noqa: E402
from holo_viewer.errors import InputError  # noqa: E402

#: the Portrait's optics on a 384 x 512 panel (cheap interleaves), 105 x 140 quilt tiles
SMALL = dataclasses.replace(DisplayCalibration.load(None), screen_w=384, screen_h=512).with_quilt(8, 6, 840, 840)
#: outputs of the callers' code before the refactor (tests/test_views_to_native.py's inputs, commit 8c813ec)
BEFORE = {
    "blend_columns_sparse0_native": "2faa6da8fe24143b", "blend_columns_sparse0_quilt": "39e9a68f40aff323",
    "blend_columns_sparse1_native": "2faa6da8fe24143b", "blend_columns_sparse1_quilt": "39e9a68f40aff323",
    "blend_device": "4a2d2e2d9ab35302", "blend_native": "4a2d2e2d9ab35302", "blend_quilt": "19aea10eedeb2ebd",
    "nearest_columns_sparse0_native": "de4748f4817374f1", "nearest_columns_sparse0_quilt": "39e9a68f40aff323",
    "nearest_columns_sparse1_native": "de4748f4817374f1", "nearest_columns_sparse1_quilt": "39e9a68f40aff323",
    "nearest_device": "d7728c6dca3a8934", "nearest_native": "d7728c6dca3a8934", "nearest_quilt": "19aea10eedeb2ebd",
    "tiles_quilt": "4c9d7d8d3c8d17fb",
}
SOURCES = [0, 5, 10, 15, 20, 25, 30, 35, 40, 45, 47]


def _h(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(np.asarray(a)).tobytes()).hexdigest()[:16]


def _inputs():
    rng = np.random.default_rng(32)
    a = (rng.random((48, 140, 105, 3)) * 1.1 - 0.05).astype(np.float32)  # values outside [0, 1] clip
    a[0, 0, :3, 0] = [0.5 / 255, 1.5 / 255, 2.5 / 255]  # halves round to even
    b = (rng.random((48, 140, 105, 3)) * 1.1 - 0.05).astype(np.float32)
    mask = rng.random((48, 7)) < 0.15
    return a, b, mask


@pytest.mark.parametrize("mode", ["nearest", "blend"])
def test_every_form_gives_the_bytes_of_before(mode):
    a, b, mask = _inputs()
    il = Interleaver(SMALL, (840, 840, 3), cols=8, rows=6, mode=mode)
    full = views_to_native(a, il)
    assert _h(full.quilt) == BEFORE[f"{mode}_quilt"] and _h(full.native) == BEFORE[f"{mode}_native"]
    ref = np.clip(np.rint(a * np.float32(255.0)), 0, 255).astype(np.uint8)  # the plain definition (float32)
    np.testing.assert_array_equal(full.quilt[-140:, :105], ref[0])  # view 0 bottom-left
    np.testing.assert_array_equal(full.quilt[:140, -105:], ref[47])  # the last view top-right
    assert views_to_native(None, il, quilt=full.quilt).native.tobytes() == full.native.tobytes()
    for sparse in (False, True):
        q, n = full.quilt.copy(), full.native.copy()
        res = views_to_native(b, il, quilt=q, native=n, columns=ColumnUpdate(mask, 16, sparse))
        assert res.quilt is q and res.native is n
        assert _h(q) == BEFORE[f"{mode}_columns_sparse{int(sparse)}_quilt"]
        assert _h(n) == BEFORE[f"{mode}_columns_sparse{int(sparse)}_native"]
        np.testing.assert_array_equal(n, il(q))  # every subpixel as a full interleave of the new quilt
    torch = pytest.importorskip("torch")
    from holo_viewer.display.device import DeviceInterleaver

    dev = views_to_native(torch.from_numpy(a), DeviceInterleaver(il, 48, 140, 105))
    assert dev.quilt is None and _h(dev.native) == BEFORE[f"{mode}_device"]


def test_tiles_and_layout_only():
    _, b, _ = _inputs()
    q = views_to_native(b[SOURCES], (8, 6), tiles=SOURCES).quilt
    assert _h(q) == BEFORE["tiles_quilt"]
    assert not q[:140, 105:210].any()  # tile 41 (not a source) untouched: zero
    with pytest.raises(InputError, match="tiles"):
        views_to_native(b[:2], (8, 6), tiles=[0, 48])
    with pytest.raises(InputError, match="quilt"):
        views_to_native(b[:2], (8, 6), quilt=np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(InputError, match="quilt"):
        views_to_native(None, Interleaver(SMALL, (840, 840, 3), cols=8, rows=6))


@pytest.fixture
def spy(monkeypatch):
    """Every call of views_to_native, as the form it took: 'views', 'tiles', 'columns', 'quilt->native',
    'device'; plus whether a native image was asked for."""
    calls: list[tuple[str, bool]] = []
    real = native_mod.views_to_native

    def record(views, target, **kw):
        if views is None:
            form = "quilt->native"
        elif type(views).__module__.startswith("torch"):
            form = "device"
        else:
            form = "columns" if kw.get("columns") is not None else "tiles" if kw.get("tiles") is not None else "views"
        calls.append((form, not isinstance(target, tuple)))
        return real(views, target, **kw)

    monkeypatch.setattr(native_mod, "views_to_native", record)
    return calls


def test_every_caller_goes_through_the_one_function(spy, monkeypatch, tmp_path):
    from holo_viewer.display.cameras import make_quilt_cameras
    from holo_viewer.display.eyes import TrackedViewer
    from holo_viewer.gui import viewer as gui_viewer
    from holo_viewer.pipeline import Pipeline, ViewSettings
    from holo_viewer.pipeline.live import NativeFrameConfig, NativeFrameRenderer
    from holo_viewer.testing import random_flame_model, random_rigged_avatar

    def ran(fn) -> list[tuple[str, bool]]:
        spy.clear()
        fn()
        return list(spy)

    model = random_flame_model()
    pipe = Pipeline(model=model, avatar=random_rigged_avatar(model, n=300), view=ViewSettings(tile_scale=0.1))
    assert ran(pipe.quilt) == [("views", False)]  # the quilt stage
    assert ran(pipe.native) == [("quilt->native", True)]  # the native stage, on the cached quilt

    class Job:
        def progress(self, done, total, unit=""):
            seen.append((done, total, unit))

    seen: list = []
    assert ran(lambda: gui_viewer._export_image(pipe, Job(), native=False)) == [("views", False)]
    assert ran(lambda: gui_viewer._export_image(pipe, Job(), native=True)) == [("views", True)]
    assert seen[-1] == (1, 1, "native") and ("views" in {u for _, _, u in seen}) and (48, 48, "tiles") in seen

    cams = make_quilt_cameras(SMALL, focal_center=(0.0, 0.0, 0.0), size=0.12, near=0.01, far=10.0)
    g = random_scene(800, degree=1, seed=1, extent=(0.1, 0.13, 0.06), scale_range=(-6.0, -4.0))
    viewer = TrackedViewer(0.0, 0.6)
    exact = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=1, tracked="bands"))
    assert ran(lambda: exact.frame(g, mode="full_quilt")) == [("views", True)]
    assert ran(lambda: exact.frame(g, viewer, "tracked")) == [("columns", True)]
    synth = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=3))
    synth.warp_native = False  # the reference of synthesized frames: the sources' tiles, the warp, the interleave
    assert ran(lambda: synth.frame(g, mode="all_views")) == [("tiles", False), ("quilt->native", True)]
    ref = synth.native.copy()
    synth.warp_native = True  # the default: the warp straight into the native image (the same bytes), no chain
    assert ran(lambda: synth.frame(g, mode="all_views")) == ([] if synth._targets else
                                                             [("tiles", False), ("quilt->native", True)])
    np.testing.assert_array_equal(synth.native, ref)
    from holo_viewer.display import slices as slices_mod

    # the slices' own scatter is no views -> native chain (per-eye images into the subpixels): stubbed out
    # here (its one-off tables take seconds), the frame's exact refresh columns are what the spy looks for
    monkeypatch.setattr(slices_mod, "subpixel_buckets", lambda *args: None)
    monkeypatch.setattr(slices_mod, "scatter_slices", lambda *args, **kw: 0)
    slices = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(view_step=1, tracked="slices", refresh_columns=2))
    slices.frame(g, mode="full_quilt")
    assert ("columns", True) in ran(lambda: slices.frame(g, viewer, "tracked"))  # the exact refresh columns

    # quilt files: quilt-to-native and show interleave them through the function too
    from holo_viewer.cli import main
    from holo_viewer.commands import show
    from holo_viewer.fileio import save_image

    quilt_png = tmp_path / "q_qs8x6a0.75.png"
    save_image(quilt_png, np.full((96, 96, 3), 128, np.uint8))  # 8 x 6 tiles of 12 x 16
    assert ran(lambda: main(["quilt-to-native", str(quilt_png), "--out", str(tmp_path / "n.png")])) == [
        ("quilt->native", True)]
    shown = ran(lambda: next(show.frame_source(quilt_png, SMALL, None, None, False)[0]()))
    assert shown == [("quilt->native", True)]

    torch = pytest.importorskip("torch")
    from holo_viewer.render import fast, gsplat_backend

    def cpu_render_device(gg, cameras, config=None, views_per_call=None):  # CPU torch stands in for gsplat
        return torch.as_tensor(fast.render(gg, cameras, config).images.copy())

    monkeypatch.setattr(gsplat_backend, "render_device", cpu_render_device)
    device = NativeFrameRenderer(SMALL, cams, NativeFrameConfig(backend="gsplat"))
    assert ran(lambda: device.frame(g, mode="all_views")) == [("device", True)]
