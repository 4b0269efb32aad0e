"""The per-process caches of set-up work (the default head's model, the interleaver's tables, dlib's models):
a cached result equals a fresh build, and each caller gets its own copy (changing it changes no later caller's)."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import torch

from holo_viewer.display import lenticular
from holo_viewer.display.calibration import DisplayCalibration
from holo_viewer.flame import default_head
from holo_viewer.flame.model import FlameModel

# the Portrait's optics on a tiny screen and quilt (tests/test_table_cache.py's)
TINY = dataclasses.replace(DisplayCalibration.load(None), screen_w=64, screen_h=48).with_quilt(8, 6, 96, 96)


def test_default_model_is_read_once_and_each_caller_gets_a_copy(monkeypatch):
    fresh = FlameModel.load(default_head.default_head_path(), n_shape=None, n_expr=None, add_teeth=True)
    default_head._LOADED.clear()
    reads = []
    real = FlameModel.load
    monkeypatch.setattr(FlameModel, "load", lambda *a, **k: reads.append(a) or real(*a, **k))
    a = default_head.load_default_model(add_teeth=True)
    b = default_head.load_default_model(add_teeth=True)
    assert len(reads) == 1
    for (name, x), (_, y) in zip(fresh.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), name
    a.v_template.add_(1.0)  # a caller changing its model
    a.metadata["n_expr"] = -1
    c = default_head.load_default_model(add_teeth=True)
    assert torch.equal(c.v_template, fresh.v_template) and c.metadata["n_expr"] == fresh.metadata["n_expr"]
    assert default_head.load_default_model(add_teeth=True, dtype=torch.float64).dtype == torch.float64
    assert len(reads) == 2  # another dtype: another model


def test_interleaver_tables_are_built_once_and_each_interleaver_gets_a_copy(monkeypatch):
    rng = np.random.default_rng(0)
    shape = (96, 96, 3)
    builds = []
    real = lenticular.Interleaver._build_tables
    monkeypatch.setattr(lenticular.Interleaver, "_build_tables", lambda self: builds.append(1) or real(self))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # nominal preset calibration
        for mode in ("nearest", "blend"):
            lenticular._TABLES.clear()
            first = lenticular.Interleaver(TINY, shape, mode=mode)
            again = lenticular.Interleaver(TINY, shape, mode=mode)
            assert len(builds) == 1
            lenticular._TABLES.clear()
            fresh = lenticular.Interleaver(TINY, shape, mode=mode)
            assert len(builds) == 2
            builds.clear()
            assert not np.shares_memory(first._idx0, again._idx0)
            first._idx0[:] = 0  # an interleaver's tables are its own
            for quilt in (rng.integers(0, 256, shape, dtype=np.uint8), rng.random(shape, dtype=np.float32)):
                np.testing.assert_array_equal(again(quilt), fresh(quilt))
            np.testing.assert_array_equal(again.view_index, fresh.view_index)


def test_face_detectors_share_dlibs_models():
    """dlib's detector and shape predictor are loaded once per process (~0.5 s of CPU each time otherwise)."""
    pytest.importorskip("dlib", reason="face tracking needs the [live] extra (dlib-bin)")
    from holo_viewer.tracking.landmarks import LandmarkDetector

    a, b = LandmarkDetector(), LandmarkDetector(redetect_every=3)
    assert a._predictor is b._predictor is not None and a._detector is b._detector
