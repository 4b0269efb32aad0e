"""gsplat backend: nerfstudio's CUDA rasterizer, used only when gsplat and CUDA both work.

gsplat (``pip install gsplat``, the ``bench``/``cuda`` extra) follows the same 3DGS
forward pass as our reference: EWA projection with ``eps2d`` = our ``dilation``, alpha
``min(0.99, o e^power)`` skipped below 1/255, early stop at T < 1e-4, SH colour
``max(SH(n(mean - cam)) + 0.5, 0)``. Its rasterizer is CUDA-only (its torch projection
runs on the CPU, its rasterizer does not), so this backend raises :class:`RenderError`
without CUDA; ``render_views(backend="auto")`` then falls back to the CPU paths.

Known differences to the reference (documented, not hidden): gsplat's Jacobian clamp
limits and its tile culling differ slightly at the image border; colours are not
clipped per splat either; the output is clipped to [0, 1] here when
``config.clip_output``. ``alpha_threshold``, ``alpha_cap``, ``t_min`` and ``radius_sigmas`` are gsplat's
compiled constants (1/255, 0.99, 1e-4, 3): a config that changes them raises RenderError
rather than silently rendering something else. gsplat stops a pixel *before* the splat that
would take T below 1e-4 (3DGS's rule); the CPU backends blend that splat, then stop
(docs/renderer.md, "Early termination"): they differ by at most T alpha there.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..camera import Cameras
from ..errors import RenderError
from .config import RenderConfig, RenderResult

__all__ = ["render", "render_device", "is_available", "check_config", "BACKEND_NAME"]

BACKEND_NAME = "gsplat"

#: views rasterized per gsplat call (bounds GPU memory for large quilts)
VIEWS_PER_CALL = 16


def _import() -> tuple[Any, Any]:
    """(torch, gsplat) when gsplat imports and CUDA works; RenderError otherwise."""
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - torch is a core dependency
        raise RenderError("gsplat backend needs torch with CUDA; torch is not installed") from exc
    if not torch.cuda.is_available():
        raise RenderError("gsplat backend needs CUDA (an NVIDIA GPU and a CUDA build of torch); "
                          f"found torch {torch.__version__} with cuda={torch.version.cuda}, no GPU available. "
                          "Use backend='fast' or 'torch' on the CPU.")
    try:
        import gsplat
    except ImportError as exc:
        raise RenderError("gsplat backend needs CUDA and the gsplat package; gsplat is not installed "
                          "(pip install gsplat)") from exc
    return torch, gsplat


def is_available() -> bool:
    """True when gsplat imports and a CUDA device is usable."""
    try:
        _import()
    except RenderError:
        return False
    return True


def check_config(config: RenderConfig) -> None:
    """RenderError when ``config`` changes a constant compiled into gsplat's kernels."""
    fixed = {"alpha_threshold": 1.0 / 255.0, "alpha_cap": 0.99, "t_min": 1e-4, "radius_sigmas": 3.0}
    for name, value in fixed.items():
        if abs(getattr(config, name) - value) > 1e-12:
            raise RenderError(f"gsplat backend: RenderConfig.{name} is fixed at {value:.6g} in gsplat's kernels, "
                              f"found {getattr(config, name)!r}; use backend='torch' or 'fast' for other values")


def render(gaussians: Any, cameras: Cameras, config: RenderConfig | None = None) -> RenderResult:
    """Render V views with ``gsplat.rasterization`` on CUDA.

    Parameters
    ----------
    gaussians : holo_viewer.avatar.Gaussians
        N Gaussians (numpy or torch; moved to the CUDA device).
    cameras : Cameras
        V cameras of one size W x H.
    config : RenderConfig, optional
        Honoured: background, sh_degree, shared_sh, tile_size, dilation (``eps2d``), near, clip_output.

    Returns
    -------
    RenderResult
        ``images`` (V, H, W, 3) float32 numpy; timings "preprocess", "rasterize", "total".

    Raises
    ------
    RenderError
        No CUDA, gsplat missing, or a knob gsplat cannot honour.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    out, n_input, degree = _rasterize(gaussians, cameras, config or RenderConfig(), VIEWS_PER_CALL, timings,
                                      to_host=True)
    timings["total"] = time.perf_counter() - t_start
    images = np.ascontiguousarray(np.concatenate(out, axis=0), dtype=np.float32)
    return RenderResult(images=images, timings=timings,
                        stats={"n_input": n_input, "sh_degree": degree}, backend=BACKEND_NAME)


def render_device(gaussians: Any, cameras: Cameras, config: RenderConfig | None = None,
                  views_per_call: int | None = None) -> Any:
    """Render all V views with gsplat and keep them on the GPU.

    One batched ``gsplat.rasterization`` call for all views (``viewmats`` [V, 4, 4]) unless
    ``views_per_call`` splits them. Returns a (V, H, W, 3) float32 CUDA tensor (clipped to
    [0, 1] when ``config.clip_output``), for :class:`holo_viewer.display.device.DeviceInterleaver`.
    """
    import torch

    out, _, _ = _rasterize(gaussians, cameras, config or RenderConfig(), views_per_call or len(cameras), {},
                           to_host=False)
    return out[0] if len(out) == 1 else torch.cat(out, dim=0)


#: the last cameras' device tensors (a live renderer passes the same Cameras every frame)
_CAMERA_CACHE: list[tuple[Any, ...]] = []


def _camera_tensors(torch: Any, cameras: Cameras, background: Any, dev: Any) -> tuple[Any, Any, Any]:
    """(viewmats, Ks, background) as float32 tensors on ``dev``, cached for the last few
    (cameras, background, device): building them is three small host-to-device copies, each a
    synchronisation, every frame otherwise."""
    bg_key = tuple(float(x) for x in np.ravel(background))
    for cams, key, tensors in _CAMERA_CACHE:
        if cams is cameras and key == (bg_key, str(dev)):
            return tensors
    tensors = (torch.tensor(np.array(cameras.world_to_cam), dtype=torch.float32, device=dev),
               torch.tensor(np.array(cameras.K), dtype=torch.float32, device=dev),
               torch.tensor(bg_key, dtype=torch.float32, device=dev))
    _CAMERA_CACHE.insert(0, (cameras, (bg_key, str(dev)), tensors))
    del _CAMERA_CACHE[4:]
    return tensors


def _rasterize(gaussians: Any, cameras: Cameras, config: RenderConfig, per_call: int, timings: dict[str, float],
               to_host: bool) -> tuple[list[Any], int, int]:
    torch, gsplat = _import()
    check_config(config)
    t0 = time.perf_counter()
    dev = torch.device("cuda") if not gaussians.is_torch or gaussians.device.type != "cuda" else gaussians.device
    g = gaussians.torch(device=dev, dtype=torch.float32)
    degree = g.sh_degree if config.sh_degree is None else min(g.sh_degree, int(config.sh_degree))
    sh = g.sh[:, : (degree + 1) ** 2]
    quats = g.quats / torch.linalg.norm(g.quats, dim=-1, keepdim=True)
    scales = torch.exp(g.log_scales)
    opac = torch.sigmoid(g.opacity_logits)
    if config.shared_sh or degree == 0:
        from .torch_backend import sh_colors

        centre = torch.tensor(cameras.positions.mean(axis=0), dtype=torch.float32, device=dev)
        colors, sh_deg_arg = sh_colors(g.means, sh, degree, centre), None
    else:
        colors, sh_deg_arg = sh, degree
    viewmats, Ks, bg = _camera_tensors(torch, cameras, config.background, dev)
    near = cameras.near if config.near is None else float(config.near)
    if to_host:  # (the device path stays asynchronous until its caller copies the result to the host)
        torch.cuda.synchronize(dev)
    timings["preprocess"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    out = []
    with torch.no_grad():
        for v0 in range(0, len(cameras), per_call):
            vm, kk = viewmats[v0:v0 + per_call], Ks[v0:v0 + per_call]
            img, _, _ = gsplat.rasterization(
                g.means, quats, scales, opac, colors, vm, kk, cameras.width, cameras.height,
                near_plane=near, far_plane=cameras.far, eps2d=config.dilation, sh_degree=sh_deg_arg,
                packed=False, tile_size=config.tile_size, backgrounds=bg.expand(vm.shape[0], 3),
                rasterize_mode="classic")
            if config.clip_output:
                img = img.clamp(0.0, 1.0)
            out.append(img.float().cpu().numpy() if to_host else img.float())
    if to_host:
        torch.cuda.synchronize(dev)
    timings["rasterize"] = time.perf_counter() - t0
    return out, len(g), degree

