"""Torch multi-view backend against the float64 reference; gsplat backend's CUDA gate."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from holo_viewer.avatar.gaussians import Gaussians  # noqa: E402
from holo_viewer.camera import Cameras, intrinsics, look_at  # noqa: E402
from holo_viewer.errors import RenderError  # noqa: E402
from holo_viewer.render import reference, torch_backend  # noqa: E402
from holo_viewer.render.config import RenderConfig  # noqa: E402

W, H = 40, 32


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def random_scene(n: int = 250, degree: int = 3, seed: int = 0) -> Gaussians:
    rng = np.random.default_rng(seed)
    return Gaussians.from_arrays(
        rng.normal(0.0, 0.1, (n, 3)), rng.normal(size=(n, 4)),
        np.log(rng.uniform(0.004, 0.04, (n, 3))), rng.normal(1.0, 1.5, n),
        rng.normal(0.0, 0.4, (n, (degree + 1) ** 2, 3)))


def quilt(n_views: int = 3, shared: bool = True) -> Cameras:
    """Sheared quilt-like cameras (shared orientation) or cameras turned toward the origin."""
    w2c, Ks = [], []
    for k in range(n_views):
        off = (k - (n_views - 1) / 2) * 0.12
        if shared:
            w2c.append(look_at([off, 0.02, 0.9], [off, 0.02, 0.0]))
            Ks.append(intrinsics(55.0, 55.0, W / 2 - 55.0 * off / 0.9, H / 2))
        else:
            w2c.append(look_at([off, 0.05, 0.9], [0.0, 0.0, 0.0]))
            Ks.append(intrinsics(55.0, 57.0, W / 2 + 1.3, H / 2 - 0.7))
    return Cameras(np.stack(w2c), np.stack(Ks), W, H)


CONFIGS = [
    RenderConfig(),
    RenderConfig(background=(0.2, 0.3, 0.4), shared_sh=True, tile_size=8),
    RenderConfig(sh_degree=1, alpha_threshold=0.05, t_min=0.3, radius_sigmas=2.0, dilation=0.1),
    RenderConfig(cull_margin=0.0, alpha_cap=0.9, background=(1.0, 1.0, 1.0)),
]


@pytest.mark.parametrize("ci", range(len(CONFIGS)))
def test_float32_matches_reference(ci: int) -> None:
    config = CONFIGS[ci]
    g, cams = random_scene(seed=ci), quilt(3)
    ref = reference.render(g, cams, config).images
    out = torch_backend.render(g, cams, config)
    assert out.images.shape == (3, H, W, 3) and out.images.dtype == np.float32
    assert np.isfinite(out.images).all()
    for v in range(len(cams)):
        assert psnr(out.images[v], ref[v]) >= 45.0, f"view {v}"
    assert np.abs(out.images - ref).max() < 2e-3
    assert out.backend == "torch/cpu"
    assert set(out.timings) >= {"preprocess", "sort", "bin", "composite", "total"}


def test_float64_reproduces_reference() -> None:
    g, cams = random_scene(seed=7), quilt(2)
    config = RenderConfig(background=(0.1, 0.5, 0.9))
    ref = reference.render(g, cams, config).images
    out = torch_backend.render(g, cams, config, dtype=torch.float64).images
    assert np.abs(out - ref).max() < 1e-6  # float32 output rounding only


def test_unshared_orientation_sorts_per_view() -> None:
    g, cams = random_scene(seed=3), quilt(3, shared=False)
    assert not cams.shared_orientation
    ref = reference.render(g, cams).images
    out = torch_backend.render(g, cams)
    assert out.stats["shared_orientation"] == 0
    assert min(psnr(out.images[v], ref[v]) for v in range(3)) >= 45.0


def test_memory_bound_chunks_do_not_change_the_picture() -> None:
    """A tiny max_chunk_bytes forces many tile-row bands and one-tile batches: same image."""
    g, cams = random_scene(n=400, seed=5), quilt(2)
    big = torch_backend.render(g, cams, RenderConfig())
    small = torch_backend.render(g, cams, RenderConfig(max_chunk_bytes=2**20))
    assert np.abs(big.images - small.images).max() < 1e-6


def test_torch_input_and_render_views() -> None:
    from holo_viewer.render.api import render_views

    g, cams = random_scene(seed=11), quilt(2)
    ref = reference.render(g, cams).images
    out = render_views(g.torch(dtype=torch.float32), cams, backend="torch")
    assert out.backend == "torch/cpu"
    assert "validate" in out.timings
    assert min(psnr(out.images[v], ref[v]) for v in range(2)) >= 45.0


def test_near_plane_and_extreme_scales_stay_finite() -> None:
    """Splats behind, at and across the near plane, tiny and huge scales: no NaN, matches reference."""
    rng = np.random.default_rng(2)
    n = 60
    means = rng.normal(0.0, 0.05, (n, 3))
    means[:10, 2] = 0.9 - 0.01  # exactly at the near plane of the centre camera (near = 0.01)
    means[10:20, 2] = 1.2  # behind the cameras
    means[20:25, 2] = 0.88  # just in front of the near plane
    log_s = np.log(rng.uniform(0.005, 0.05, (n, 3)))
    log_s[25:30] = np.log(1e-7)
    log_s[30:33] = np.log(10.0)
    log_s[33:36, 2] = np.log(1e-9 * 0.02)  # near-degenerate covariance
    g = Gaussians.from_arrays(means, rng.normal(size=(n, 4)), log_s, rng.normal(1, 1, n),
                              rng.normal(0, 0.3, (n, 4, 3)))
    cams = quilt(3)
    ref = reference.render(g, cams).images
    out = torch_backend.render(g, cams).images
    assert np.isfinite(out).all()
    assert min(psnr(out[v], ref[v]) for v in range(3)) >= 45.0


def test_empty_scene_is_background() -> None:
    g = random_scene(n=5, seed=1).replace(means=np.full((5, 3), 5.0))  # all behind the cameras
    out = torch_backend.render(g, quilt(2), RenderConfig(background=(0.25, 0.5, 0.75)))
    assert np.allclose(out.images, np.array([0.25, 0.5, 0.75], np.float32))
    assert out.stats["n_visible"] == 0


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA present: the CPU-only error path does not apply")
def test_cuda_request_without_cuda_is_a_clear_error() -> None:
    with pytest.raises(RenderError, match="CUDA is not available"):
        torch_backend.render(random_scene(n=5), quilt(1), device="cuda")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_reference() -> None:
    g, cams = random_scene(seed=4), quilt(3)
    ref = reference.render(g, cams).images
    out = torch_backend.render(g.torch(device="cuda"), cams)
    assert out.backend == "torch/cuda"
    assert min(psnr(out.images[v], ref[v]) for v in range(3)) >= 45.0


def test_auto_backend_is_gsplat_where_it_runs_else_fast() -> None:
    """"auto" = gsplat (CUDA) when usable for the config, else the fast CPU backend, never the
    pure-torch one (6 s per quilt on an H100 against the CPU backend's 0.5 s)."""
    from holo_viewer.render import gsplat_backend, render_views

    g, cams = random_scene(seed=5), quilt(2)
    ref = reference.render(g, cams).images
    out = render_views(g, cams, "auto")
    want = "gsplat" if gsplat_backend.is_available() else "fast"
    assert out.backend.startswith(want)
    assert min(psnr(out.images[v], ref[v]) for v in range(2)) >= (35.0 if want == "gsplat" else 45.0)
    # a knob gsplat cannot honour sends "auto" to the fast backend
    out = render_views(g, cams, "auto", RenderConfig(alpha_threshold=0.01))
    assert out.backend.startswith("fast")


def test_gsplat_backend_gate() -> None:
    from holo_viewer.render import gsplat_backend

    if gsplat_backend.is_available():
        out = gsplat_backend.render(random_scene(seed=6), quilt(2))
        ref = reference.render(random_scene(seed=6), quilt(2)).images
        assert min(psnr(out.images[v], ref[v]) for v in range(2)) >= 35.0
    else:
        with pytest.raises(RenderError, match="gsplat backend needs CUDA"):
            gsplat_backend.render(random_scene(n=5), quilt(1))
