"""The default avatar: deterministic, coloured by region, opaque when rendered; numba vs torch binding."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holo_viewer.avatar import Gaussians, RiggedAvatar, default_avatar
from holo_viewer.camera import Cameras, intrinsics, look_at


@pytest.fixture(scope="module")
def small():
    return default_avatar(n_gaussians=20_000, use_disk_cache=False)


def test_size_regions_and_determinism(small):
    assert small.n_gaussians == 20_000 and small.local.sh_degree == 1
    again = default_avatar(n_gaussians=20_000, use_disk_cache=False)
    assert torch.equal(again.local.means, small.local.means) and torch.equal(again.binding, small.binding)
    counts = {nm: int((small.region == i).sum()) for i, nm in enumerate(small.region_names)}
    for nm in ("skin", "scalp", "brows", "lips", "eyeball_left", "eyeball_right", "iris", "mouth_interior",
               "teeth"):
        assert counts.get(nm, 0) > 0, (nm, counts)
    g = small.rest()
    g.validate()
    assert small.n_degenerate_faces == 0


def test_region_colours(small):
    g = small.rest()
    rgb = g.colors_dc()
    names = list(small.region_names)

    def mean(nm):
        return rgb[small.region == names.index(nm)].mean(0)

    hair_region = "hair" if "hair" in names else "scalp"
    skin, lips, hair, sclera, teeth = (mean(k) for k in ("skin", "lips", hair_region, "eyeball_left", "teeth"))
    assert lips[0] / lips[1] > skin[0] / skin[1]  # lips redder than skin
    assert hair.sum() < 0.5 * skin.sum()  # hair dark
    assert sclera.sum() > skin.sum() and teeth.sum() > skin.sum()
    # eye: pupil darker than iris darker than sclera (by angle from the optical axis)
    eye_ids = [names.index(k) for k in ("eyeball_left", "eyeball_right", "iris", "pupil")]
    eye = np.isin(small.region, eye_ids)
    lum = rgb[eye].sum(1)
    assert lum.min() < 0.15 and np.percentile(lum, 90) > 2.0
    # degree-1 SH: brighter when seen along the normal than from the side
    assert float(g.sh[:, 1:].abs().max()) > 0


def _opacity_error(gauss: Gaussians, cams: Cameras) -> np.ndarray:
    from holo_viewer.render.api import render_views
    from holo_viewer.render.config import RenderConfig

    black = render_views(gauss, cams, backend="fast", config=RenderConfig(background=(0, 0, 0))).images
    white = render_views(gauss, cams, backend="fast", config=RenderConfig(background=(1, 1, 1))).images
    return (white - black).max(-1)  # = transmittance left at each pixel


@pytest.mark.slow
def test_default_avatar_renders_opaque():
    av = default_avatar()  # the shipped file: the generator's 100k + 2000 on the lashes (scripts/fit_patients.py default)
    assert av.n_gaussians == 102_000
    assert np.sum(av.region == list(av.region_names).index("lashes")) >= 2000
    # stored front to back (the renderers' per-frame depth-ordered copies then read in sequence)
    z = av.rest().numpy().means[:, 2]
    assert np.all(np.diff(z) <= 0)
    assert len(av.region) == av.n_gaussians
    W, H = 210, 280  # half of the 420 x 560 quilt tile (same angular Gaussian size relative to pixels x2)
    f = 0.5 * H / np.tan(np.deg2rad(14))
    w2c = [look_at([0.6 * np.sin(np.deg2rad(a)), -0.01, 0.6 * np.cos(np.deg2rad(a))], [0, -0.01, 0]) for a in (0, 30)]
    cams = Cameras(np.stack(w2c), intrinsics(f, f, W / 2, H / 2), W, H)
    trans = _opacity_error(av.rest(), cams)
    # inside the face (forehead to chin, between the cheeks) nothing of the background shows
    face = trans[:, int(0.25 * H):int(0.75 * H), int(0.38 * W):int(0.62 * W)]
    assert face.max() < 0.05, face.max()


def test_numba_and_torch_binding_agree(small):
    torch_av = RiggedAvatar(small.flame_model, small.local, binding=small.binding)
    torch_av.backend = "torch"
    params = dict(expr=np.linspace(-1, 1, small.flame_model.n_expr), jaw_pose=[0.2, 0.0, 0.0],
                  rotation=[0.1, 0.3, 0.0], eyes_pose=[0.1, 0.2, 0, 0.1, 0.2, 0])
    a, b = small.pose(**params), torch_av.pose(**params)
    torch.testing.assert_close(a.means, b.means, atol=2e-7, rtol=1e-6)
    torch.testing.assert_close(a.log_scales, b.log_scales, atol=2e-6, rtol=1e-6)
    # same rotation (quaternion sign may differ)
    dot = (a.quats * b.quats).sum(-1).abs()
    assert float((1 - dot).max()) < 1e-6
    # cached path (partial update) agrees too
    small.reset_cache()
    small.cache_full_fraction = 1.0
    small.pose(cache=True)
    c = small.pose(cache=True, jaw_pose=[0.2, 0.0, 0.0])
    d = torch_av.pose(jaw_pose=[0.2, 0.0, 0.0])
    assert small.last_cache_fraction < 0.5
    torch.testing.assert_close(c.means, d.means, atol=2e-7, rtol=1e-6)


def test_disk_cache_round_trip(tmp_path, monkeypatch):
    import importlib

    mod = importlib.import_module("holo_viewer.avatar.default_gaussians")

    monkeypatch.setenv("HOLO_VIEWER_CACHE", str(tmp_path))
    gen = mod._cached_local.__wrapped__
    local, binding, names = gen(3000, 1, 5, True)
    files = list(tmp_path.glob("default_avatar_*.npz"))
    assert len(files) == 1
    again, binding2, _ = gen(3000, 1, 5, True)  # read back from the file
    assert np.array_equal(again.means, local.means) and np.array_equal(binding2, binding)
    raw = files[0].read_bytes()
    files[0].write_bytes(b"garbage")  # a corrupt cache file is regenerated, not trusted
    third, _, _ = gen(3000, 1, 5, True)
    assert np.array_equal(third.sh, local.sh)
    files[0].write_bytes(raw[: len(raw) // 2])  # a truncated zip (an interrupted copy) too
    fourth, _, _ = gen(3000, 1, 5, True)
    assert np.array_equal(fourth.means, local.means)
