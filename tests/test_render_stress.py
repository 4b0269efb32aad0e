"""Numerical stress tests of the splat renderers (docs/design.md "Known traps").

In every survivable case the fast path agrees with the float64 reference within the
tolerances of test_render_fast.py (PSNR >= 50 dB, max abs error <= 0.01 per view) and no
NaN/inf reaches an image; bad inputs raise InputError naming the field.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.scenes import quilt_cameras, random_quats, random_scene  # the repository root is on sys.path (conftest)
from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.camera import Cameras, intrinsics
from holo_viewer.errors import InputError
from holo_viewer.render import RenderConfig, render_views

ROOT = Path(__file__).resolve().parents[1]
from holo_viewer.render import fast  # noqa: E402

PSNR_MIN, MAX_ERR = 50.0, 0.01
KERNELS = ["numba"] + (["cpp"] if fast.cpp_available() else [])


def compare(g: Gaussians, cams: Cameras, kernel: str, **cfg) -> None:
    ref = render_views(g, cams, "reference", RenderConfig(**cfg)).images.astype(np.float64)
    out = render_views(g, cams, "fast", RenderConfig(kernel=kernel, **cfg)).images
    assert np.isfinite(ref).all() and np.isfinite(out).all()
    mse = np.mean((out - ref) ** 2, axis=(1, 2, 3))
    psnr = 10 * np.log10(1.0 / np.maximum(mse, 1e-20))
    err = np.abs(out - ref).max()
    assert psnr.min() >= PSNR_MIN and err <= MAX_ERR, f"PSNR {psnr}, max err {err}"


def scene(means, log_scales, seed=0, degree=1, opacity_logit=None) -> Gaussians:
    rng = np.random.default_rng(seed)
    n = len(means)
    sh = np.zeros((n, (degree + 1) ** 2, 3))
    sh[:, 0] = rng.uniform(-1.5, 1.5, (n, 3))
    sh[:, 1:] = rng.normal(scale=0.3, size=(n, (degree + 1) ** 2 - 1, 3))
    logits = rng.normal(0.5, 2, n) if opacity_logit is None else np.full(n, opacity_logit)
    return Gaussians.from_arrays(np.asarray(means, float), random_quats(rng, n), np.asarray(log_scales, float),
                                 logits, sh)


CAMS = quilt_cameras(2, 64, 48, use_display=False)


@pytest.mark.parametrize("kernel", KERNELS)
def test_scales_from_1e7_to_10_m(kernel):
    rng = np.random.default_rng(1)
    n = 160
    means = rng.uniform(-0.1, 0.1, (n, 3))
    log_scales = rng.uniform(np.log(1e-7), np.log(10.0), (n, 3))
    compare(scene(means, log_scales), CAMS, kernel)
    # each extreme alone: all tiny (only the 0.3 px^2 dilation is left), all huge (covers the view)
    compare(scene(means, np.full((n, 3), np.log(1e-7))), CAMS, kernel)
    compare(scene(means[:5], np.full((5, 3), np.log(10.0)), opacity_logit=-3.0), CAMS, kernel)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("thin_axes", [1, 2])
def test_near_degenerate_covariances(kernel, thin_axes):
    rng = np.random.default_rng(2)
    n = 200
    means = rng.uniform(-0.1, 0.1, (n, 3))
    s = np.log(rng.uniform(2e-3, 2e-2, (n, 1)))
    log_scales = np.repeat(s, 3, axis=1)
    log_scales[:, 3 - thin_axes:] += np.log(1e-9)  # flat discs (1 thin axis) or needles (2)
    compare(scene(means, log_scales), CAMS, kernel)


@pytest.mark.parametrize("kernel", KERNELS)
def test_gaussians_at_behind_and_crossing_the_near_plane(kernel):
    near = 0.2
    K = intrinsics(50.0, 50.0, 32.0, 24.0)
    cams = Cameras(np.stack([np.eye(4), np.eye(4)]), np.stack([K, K]), 64, 48, near=near, far=10.0)
    rng = np.random.default_rng(3)
    z = np.concatenate([np.full(20, near), near + rng.uniform(-1e-6, 1e-6, 20), near + rng.uniform(1e-4, 0.02, 40),
                        near - rng.uniform(1e-4, 0.05, 20), rng.uniform(0.3, 2.0, 60)])
    xy = rng.uniform(-0.3, 0.3, (z.size, 2)) * z[:, None]
    means = np.column_stack([xy, z])
    log_scales = np.log(rng.uniform(1e-3, 0.1, (z.size, 3)))  # some reach across the near plane
    g = scene(means, log_scales, opacity_logit=0.0)
    compare(g, cams, kernel)
    # exactly at the near plane is culled (t.z <= near): alone it renders nothing
    only_at = scene(np.column_stack([np.zeros((3, 2)), np.full(3, near)]), np.full((3, 3), np.log(0.01)))
    img = render_views(only_at, cams, "fast", RenderConfig(kernel=kernel)).images
    assert np.all(img == 0)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("cx_factor", [-4.0, 5.0])
def test_extreme_off_axis_principal_point(kernel, cx_factor):
    w, h, f = 64, 48, 60.0
    cx = cx_factor * w
    K = intrinsics(f, f, cx, h / 2)
    cams = Cameras(np.eye(4)[None], K[None], w, h)
    # put the scene where this camera looks: x/z = (W/2 - cx) / f
    rng = np.random.default_rng(4)
    z = rng.uniform(0.5, 1.5, 300)
    x = (w / 2 - cx) / f * z + rng.uniform(-0.4, 0.4, 300) * z
    y = rng.uniform(-0.3, 0.3, 300) * z
    g = scene(np.column_stack([x, y, z]), np.log(rng.uniform(5e-3, 5e-2, (300, 3))))
    compare(g, cams, kernel)
    # and the 48 sheared quilt views with a very wide cone (cx far outside the image)
    wide = quilt_cameras(48, 48, 64, cone_deg=100.0, use_display=False)
    assert abs(wide.cx[0] - 24) > 5 * 48
    compare(random_scene(300, degree=2, seed=9), wide[[0, 47]], kernel)


@pytest.mark.parametrize("field,value,match", [
    ("means", np.nan, "means"), ("means", np.inf, "means"), ("log_scales", -np.inf, "log_scales"),
    ("opacity_logits", np.nan, "opacity_logits"), ("sh", np.inf, "sh"), ("quats", np.nan, "quats"),
])
@pytest.mark.parametrize("backend", ["reference", "fast"])
def test_nan_inf_inputs_rejected(field, value, match, backend):
    g = random_scene(10)
    arr = np.array(getattr(g, field), dtype=float)
    arr.reshape(10, -1)[3, 0] = value
    with pytest.raises(InputError, match=match):
        render_views(g.replace(**{field: arr}), CAMS, backend)


def test_zero_quaternion_and_overflowing_scale_rejected():
    g = random_scene(10)
    q = np.array(g.quats)
    q[2] = 0
    with pytest.raises(InputError, match="quats"):
        render_views(g.replace(quats=q), CAMS, "fast")
    ls = np.array(g.log_scales)
    ls[4, 1] = 800.0  # e^800 overflows
    with pytest.raises(InputError, match="log_scales"):
        render_views(g.replace(log_scales=ls), CAMS, "fast")
    with pytest.raises(InputError, match="world_to_cam"):
        Cameras(np.full((4, 4), np.nan), np.eye(3), 8, 8)


def test_torch_gaussians_render_like_numpy():
    torch = pytest.importorskip("torch")
    g = random_scene(200, degree=1, seed=12)
    a = render_views(g, CAMS, "fast").images
    b = render_views(g.torch(dtype=torch.float32), CAMS, "fast").images
    assert np.abs(a - b).max() <= MAX_ERR


_MEMORY_SCRIPT = r"""
import json, resource, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from bench.scenes import quilt_cameras, random_scene
from holo_viewer.render import RenderConfig, render_views
cams = quilt_cameras(2, 320, 240, use_display=False)
small = random_scene(1000, degree=0, seed=1)
render_views(small, cams, "fast", RenderConfig(kernel=sys.argv[2]))   # compile / load kernels first
g = random_scene(1_000_000, degree=0, seed=2, scale_range=(-8.0, -6.0))
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
r = render_views(g, cams, "fast", RenderConfig(kernel=sys.argv[2], max_chunk_bytes=256 * 2**20))
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"growth_kb": after - before, "finite": bool(np.isfinite(r.images).all()),
                  "visible": r.stats["n_visible"], "mean": float(r.images.mean())}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("kernel", KERNELS[-1:])
def test_one_million_gaussians_bounded_memory(kernel):
    out = subprocess.run([sys.executable, "-c", _MEMORY_SCRIPT, str(ROOT), kernel], capture_output=True, text=True,
                         timeout=600, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    n_times_pixels_bytes = 1_000_000 * 320 * 240 * 4  # 307 GB: what an N x pixels buffer would take
    growth = res["growth_kb"] * 1024
    assert res["finite"] and res["visible"] > 500_000 and res["mean"] > 0
    assert growth < 1.5 * 2**30, f"peak RSS grew by {growth / 2**20:.0f} MiB"
    assert growth < n_times_pixels_bytes / 100


def test_validation_names_bad_rows_and_accepts_huge_finite_values():
    """The quick finite-sum check never decides alone: a sum that overflows (huge but finite
    values) or a NaN gets the per-Gaussian check, which names the rows."""
    g = random_scene(10)
    sh = np.array(g.sh, dtype=np.float64)
    sh[:, 0, 0] = 1e308  # finite; their sum overflows to inf
    g.replace(sh=sh).validate()
    sh[[1, 7], 0, 1] = np.nan
    with pytest.raises(InputError, match=r"sh: .*2 Gaussians \(indices \[1, 7\]\)"):
        g.replace(sh=sh).validate()
    q = np.array(g.quats, dtype=np.float32)
    q[5] = 1e-13  # |q| = 2e-13 < 1e-12
    with pytest.raises(InputError, match=r"quats: .*indices \[5\]"):
        g.replace(quats=q).validate()
    q[5] = 1e-11
    g.replace(quats=q).validate()
