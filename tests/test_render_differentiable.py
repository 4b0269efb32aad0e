"""Differentiable CPU rasterizer: forward against the float64 reference, gradients against a dense
pure-torch float64 implementation of the same forward pass (autograd) and finite differences."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")

from holo_viewer.avatar.gaussians import Gaussians  # noqa: E402
from holo_viewer.camera import Cameras, intrinsics, look_at  # noqa: E402
from holo_viewer.render import differentiable as dr  # noqa: E402
from holo_viewer.render import reference  # noqa: E402
from holo_viewer.render.config import RenderConfig  # noqa: E402

W, H = 40, 32


def random_scene(n: int = 200, degree: int = 1, seed: int = 0, size: float = 0.04) -> Gaussians:
    rng = np.random.default_rng(seed)
    return Gaussians.from_arrays(
        rng.normal(0.0, 0.1, (n, 3)), rng.normal(size=(n, 4)),
        np.log(rng.uniform(0.1, 1.0, (n, 3)) * size), rng.normal(1.0, 1.5, n),
        rng.normal(0.0, 0.4, (n, (degree + 1) ** 2, 3)))


def cameras(n_views: int = 3) -> Cameras:
    w2c, Ks = [], []
    for k in range(n_views):
        off = (k - (n_views - 1) / 2) * 0.12
        w2c.append(look_at([off, 0.02, 0.9], [off * 0.5, 0.0, 0.0]))
        Ks.append(intrinsics(55.0, 57.0, W / 2 - 40.0 * off, H / 2 + 0.7))
    return Cameras(np.stack(w2c), np.stack(Ks), W, H)


def _torch_params(g: Gaussians, dtype=torch.float64):
    return [torch.tensor(np.asarray(a, np.float64), dtype=dtype, requires_grad=True)
            for a in (g.means, g.quats, g.log_scales, g.opacity_logits, g.sh)]


CONFIGS = [
    RenderConfig(),
    RenderConfig(background=(0.2, 0.3, 0.4)),
    RenderConfig(alpha_threshold=0.05, t_min=0.3, radius_sigmas=2.0, dilation=0.1, alpha_cap=0.9),
    RenderConfig(background=(1.0, 1.0, 1.0), sh_degree=0),
]


@pytest.mark.parametrize("ci", range(len(CONFIGS)))
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_forward_matches_reference(ci: int, dtype) -> None:
    """float64: equal to the reference to 1e-9 per pixel; float32: to 2e-4 (single-precision rounding)."""
    config = CONFIGS[ci]
    g, cams = random_scene(seed=ci), cameras(3)
    ref = reference.render(g, cams, RenderConfig(**{**config.__dict__, "clip_output": False})).images
    p = _torch_params(g, dtype)
    with torch.no_grad():
        got = dr.render_gaussians(Gaussians(*p), cams, config=config).double().numpy()
    tol = 1e-9 if dtype == torch.float64 else 2e-4
    # the reference returns float32 images: compare against its rounding
    assert np.abs(got - ref).max() <= max(tol, 1e-6), np.abs(got - ref).max()
    assert np.abs(ref).max() > 0.1  # the scene is visible


# ----------------------------------------------------------------------------- dense float64 oracle
def dense_render(means, quats, log_scales, opacity_logits, sh, w2c, K, config: RenderConfig, degree: int):
    """Pure torch float64 implementation of the forward pass over all pixels (autograd gives the gradient).

    The discrete choices (depth order, pixel box, power > 0, alpha < threshold, the t_min stop) are
    taken on detached values; everything else is differentiable torch math written independently of
    the numba kernels (dense (N, H, W) maps)."""
    near = 0.01
    cov = dr.covariance(quats, log_scales)
    uv, conic, depth, radius, valid = dr.project(means, cov, w2c, K, W, H, near, config.dilation,
                                                 config.radius_sigmas)
    cam_pos = torch.as_tensor(-w2c[:3, :3].T @ w2c[:3, 3])
    col = dr.sh_rgb(means, sh, degree, cam_pos)
    op = torch.sigmoid(opacity_logits)
    idx = np.flatnonzero(valid)
    order = idx[np.argsort(depth[idx], kind="stable")]
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64) + 0.5, torch.arange(W, dtype=torch.float64) + 0.5,
                            indexing="ij")
    C = torch.zeros(H, W, 3, dtype=torch.float64)
    T = torch.ones(H, W, dtype=torch.float64)
    done = torch.zeros(H, W, dtype=torch.bool)
    for g in order:
        u, v = uv[g, 0], uv[g, 1]
        r = radius[g]
        ud, vd = float(u.detach()), float(v.detach())
        x0, x1 = max(int(np.ceil(ud - r - 0.5)), 0), min(int(np.floor(ud + r - 0.5)) + 1, W)
        y0, y1 = max(int(np.ceil(vd - r - 0.5)), 0), min(int(np.floor(vd + r - 0.5)) + 1, H)
        inbox = torch.zeros(H, W, dtype=torch.bool)
        if x0 < x1 and y0 < y1:
            inbox[y0:y1, x0:x1] = True
        dx, dy = xs - u, ys - v
        power = -0.5 * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) - conic[g, 1] * dx * dy
        alpha = torch.clamp(op[g] * torch.exp(power), max=config.alpha_cap)
        use = inbox & (power.detach() <= 0) & (alpha.detach() >= config.alpha_threshold) & ~done
        stop = use & ((T * (1 - alpha)).detach() < config.t_min)  # blended, then the pixel stops
        done = done | stop
        a = torch.where(use, alpha, torch.zeros_like(alpha))
        C = C + (a * T)[..., None] * col[g]
        T = T * (1 - a)
    return C + T[..., None] * torch.as_tensor(config.background, dtype=torch.float64)


@pytest.mark.parametrize("ci", [0, 1, 2])
def test_gradients_match_dense_autograd(ci: int) -> None:
    """Gradients of a random linear loss wrt every parameter: numba backward vs dense torch autograd,
    float64, relative error <= 1e-7 of each gradient's largest entry."""
    config = CONFIGS[ci]
    g, cams = random_scene(n=60, seed=10 + ci, size=0.06), cameras(2)
    rng = np.random.default_rng(ci)
    weight = torch.as_tensor(rng.normal(size=(H, W, 3)))
    for v in range(len(cams)):
        w2c, K = cams.world_to_cam[v], cams.K[v]
        pa = _torch_params(g)
        img = dr.render_view(*pa, w2c, K, W, H, 0.01, config)
        (img * weight).sum().backward()
        pb = _torch_params(g)
        ref = dense_render(*pb, w2c, K, config, degree=1)
        (ref * weight).sum().backward()
        assert torch.allclose(img, ref, atol=1e-10)
        for name, a, b in zip(("means", "quats", "log_scales", "opacity", "sh"), pa, pb):
            scale = float(b.grad.abs().max())
            assert scale > 0, name
            err = float((a.grad - b.grad).abs().max())
            assert err <= 1e-7 * scale, (name, err, scale)


def test_gradient_matches_finite_differences() -> None:
    """Central differences (h = 1e-6) of the float64 image sum agree with the backward (rel. 1e-4)."""
    config = RenderConfig(background=(0.1, 0.2, 0.3))
    g, cams = random_scene(n=30, seed=3, size=0.06), cameras(1)
    w2c, K = cams.world_to_cam[0], cams.K[0]
    rng = np.random.default_rng(5)
    weight = torch.as_tensor(rng.normal(size=(H, W, 3)))
    p = _torch_params(g)
    (dr.render_view(*p, w2c, K, W, H, 0.01, config) * weight).sum().backward()
    h = 1e-6
    checked = 0
    for pi, prm in enumerate(p):
        flat = prm.detach().reshape(-1)
        for j in rng.choice(flat.numel(), size=min(12, flat.numel()), replace=False):
            vals = []
            for s in (h, -h):
                q = [x.detach().clone() for x in p]
                q[pi].reshape(-1)[j] += s
                with torch.no_grad():
                    vals.append(float((dr.render_view(*q, w2c, K, W, H, 0.01, config) * weight).sum()))
            fd = (vals[0] - vals[1]) / (2 * h)
            an = float(p[pi].grad.reshape(-1)[j])
            assert abs(fd - an) <= 1e-4 * max(1.0, abs(an)), (pi, j, fd, an)
            checked += 1
    assert checked > 40
