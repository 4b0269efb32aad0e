"""Pure-torch multi-view 3DGS rasterizer (CPU or CUDA), memory-bounded.

The same forward pass as the float64 reference (docs/design.md "3DGS forward pass",
:mod:`holo_viewer.render.projection`), written with torch tensor ops so that it runs
wherever torch runs: on the CPU (a portable, slower cousin of the numba/C++ ``fast``
backend) and on CUDA, where it is the GPU path of :func:`render_views` when gsplat is
not installed.

Pipeline per quilt
------------------
1. Per Gaussian, once: 3D covariance ``R S S^T R^T``, opacity, SH coefficients.
2. One depth order for all views when the cameras share one orientation (the quilt
   case: view depth differs only by a per-view constant), else one sort per view.
3. Per view: EWA projection (Jacobian clamped as in ``projection.py``), conic, radius
   ``ceil(radius_sigmas sqrt(lambda_max))``, pixel box, SH colour toward this camera
   (or toward the mean camera position with ``shared_sh``).
4. Binning: every (tile, Gaussian) pair whose pixel box touches the tile, sorted by
   tile then depth, built one band of tile rows at a time so the pair list stays below
   ``config.max_chunk_bytes``.
5. Compositing: batches of tiles x chunks of K Gaussians x the tile's pixels, front to
   back with a running transmittance, the 1/255 alpha skip, the 0.99 cap and the
   ``t_min`` early stop (a pixel that stopped stays stopped). No tensor ever has
   N x pixels entries: the largest is (tiles in batch, K, tile pixels).

Precision: per-splat preprocessing (projection, conic, pixel box, SH, sort) runs in
float64, which is cheap (O(N) per view) and keeps knife-edge decisions (a centre at the
near plane, a pixel on a box edge) identical to the reference; compositing, the
O(pixels x blends) part, runs in ``dtype`` = ``torch.float32`` by default (PSNR > 45 dB
against the float64 reference on the test scenes); ``torch.float64`` reproduces the
reference to float32 output rounding.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from ..camera import Cameras
from ..errors import RenderError
from .config import RenderConfig, RenderResult
from .projection import CLAMP_WIDEN
from .sh import C0, sh_basis

__all__ = ["render", "resolve_device", "sh_colors", "BACKEND_NAME"]

BACKEND_NAME = "torch"

#: Gaussians per compositing chunk (the K axis of the (tiles, K, pixels) blocks)
CHUNK_GAUSSIANS = 128
#: bytes per element of the (tiles, K, pixels) temporaries (about a dozen live at once)
_BLOCK_BYTES_PER_ELEM = 64
#: bytes per (tile, Gaussian) pair while binning (keys, sort, gather)
_PAIR_BYTES = 48


def _torch() -> Any:
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - torch is a core dependency
        raise RenderError("torch backend: cannot import torch; install torch") from exc
    return torch


def resolve_device(gaussians: Any, device: Any = None) -> Any:
    """The torch device to render on: ``device`` if given, else the Gaussians' device (CPU for numpy).

    Raises
    ------
    RenderError
        A CUDA device was requested but CUDA is not available.
    """
    torch = _torch()
    dev = torch.device(device) if device is not None else (
        torch.device(gaussians.device) if gaussians.is_torch else torch.device("cpu"))
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise RenderError(f"torch backend: device {dev} requested but CUDA is not available "
                          f"(torch {torch.__version__}, cuda {torch.version.cuda})")
    return dev


# --------------------------------------------------------------------------- SH
def sh_colors(means: Any, sh: Any, degree: int, cam_pos: Any) -> Any:
    """(N, 3) colours ``max(SH(n(mean - cam_pos)) + 0.5, 0)`` of degree ``degree``.

    Parameters
    ----------
    means : torch.Tensor
        (N, 3) world centres (m).
    sh : torch.Tensor
        (N, K, 3) coefficients, K >= (degree+1)^2.
    degree : int
        0..3.
    cam_pos : torch.Tensor
        (3,) camera position (m).
    """
    torch = _torch()
    k = (degree + 1) ** 2
    if degree == 0:
        return torch.clamp_min(sh[:, 0] * C0 + 0.5, 0.0)
    d = means - cam_pos
    d = d / torch.linalg.norm(d, dim=-1, keepdim=True).clamp_min(1e-30)
    basis = sh_basis(degree, d)  # (N, k), the numpy reference's formula on torch tensors
    return torch.clamp_min(torch.einsum("nk,nkc->nc", basis, sh[:, :k]) + 0.5, 0.0)


# ------------------------------------------------------------------- projection
def _project(means: Any, cov3d: Any, w2c: Any, K: np.ndarray, width: int, height: int, near: float,
             config: RenderConfig) -> dict[str, Any]:
    """EWA projection of N Gaussians into one view (same math as ``projection.project_gaussians``)."""
    torch = _torch()
    Rw = w2c[:3, :3]
    t = means @ Rw.T + w2c[:3, 3]
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    tz = t[:, 2]
    front = tz > near
    tzs = torch.where(front, tz, torch.ones_like(tz))
    u = fx * t[:, 0] / tzs + cx
    v = fy * t[:, 1] / tzs + cy
    lo_x, hi_x = (-cx - CLAMP_WIDEN * width) / fx, ((1.0 + CLAMP_WIDEN) * width - cx) / fx
    lo_y, hi_y = (-cy - CLAMP_WIDEN * height) / fy, ((1.0 + CLAMP_WIDEN) * height - cy) / fy
    txc = torch.clamp(t[:, 0] / tzs, lo_x, hi_x) * tzs
    tyc = torch.clamp(t[:, 1] / tzs, lo_y, hi_y) * tzs
    zero = torch.zeros_like(tzs)
    J = torch.stack([torch.stack([fx / tzs, zero, -fx * txc / (tzs * tzs)], -1),
                     torch.stack([zero, fy / tzs, -fy * tyc / (tzs * tzs)], -1)], dim=-2)  # (N, 2, 3)
    M = J @ Rw
    S = M @ cov3d @ M.transpose(1, 2)
    a = S[:, 0, 0] + config.dilation
    b = S[:, 0, 1]
    c = S[:, 1, 1] + config.dilation
    det = a * c - b * b
    ok = det > 0
    safe = torch.where(ok, det, torch.ones_like(det))
    mid = 0.5 * (a + c)
    lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.0))
    radius = torch.ceil(config.radius_sigmas * torch.sqrt(torch.clamp_min(lam, 0.0)))
    finite = torch.isfinite(a) & torch.isfinite(b) & torch.isfinite(c) & torch.isfinite(u) & torch.isfinite(v)
    valid = front & ok & finite
    # pixel box: columns [x0, x1), rows [y0, y1) whose centres lie within radius of (u, v)
    x0 = torch.clamp(torch.ceil(u - radius - 0.5), min=0)
    x1 = torch.clamp(torch.floor(u + radius - 0.5) + 1, max=width)
    y0 = torch.clamp(torch.ceil(v - radius - 0.5), min=0)
    y1 = torch.clamp(torch.floor(v + radius - 0.5) + 1, max=height)
    valid = valid & (x0 < x1) & (y0 < y1)
    return dict(depth=tz, u=u, v=v, A=c / safe, B=-b / safe, C=a / safe, valid=valid,
                box=torch.stack([x0, x1, y0, y1], dim=-1))


# -------------------------------------------------------------------- binning
def _band_pairs(box_t: Any, band: tuple[int, int], tiles_x: int) -> tuple[Any, Any]:
    """(tile-in-band, splat) pairs for splats in depth order whose tile box meets tile rows ``band``.

    Parameters
    ----------
    box_t : torch.Tensor
        (M, 4) int64 tile boxes (tx0, tx1, ty0, ty1), inclusive, of the M visible splats in
        depth order (front first).
    band : (int, int)
        Tile rows [r0, r1).

    Returns
    -------
    tile : (P,) int64 tile index within the band (row-major), sorted, then by depth.
    splat : (P,) int64 index into the M splats.
    """
    torch = _torch()
    r0, r1 = band
    ty0 = torch.clamp(box_t[:, 2], min=r0)
    ty1 = torch.clamp(box_t[:, 3], max=r1 - 1)
    nx = box_t[:, 1] - box_t[:, 0] + 1
    ny = torch.clamp(ty1 - ty0 + 1, min=0)
    counts = nx * ny
    splat = torch.repeat_interleave(torch.arange(box_t.shape[0], device=box_t.device), counts)
    if splat.numel() == 0:
        return splat, splat
    starts = torch.cumsum(counts, 0) - counts
    local = torch.arange(splat.numel(), device=box_t.device) - starts[splat]
    wx = nx[splat]
    tx = box_t[splat, 0] + local % wx
    ty = ty0[splat] + local // wx
    tile = (ty - r0) * tiles_x + tx
    key = tile * box_t.shape[0] + splat  # splat index = depth rank: sorts by tile, then front to back
    key, perm = torch.sort(key)
    return tile[perm], splat[perm]


# ----------------------------------------------------------------- compositing
def _composite_band(out: Any, feats: Any, tile: Any, splat: Any, band: tuple[int, int], tiles_x: int,
                    width: int, height: int, config: RenderConfig, counter: list[int]) -> None:
    """Composite the tiles of one band into ``out`` (H, W, 3) and its transmittance into ``out_T``."""
    torch = _torch()
    dev, dtype = feats.device, feats.dtype
    ts = config.tile_size
    r0, r1 = band
    n_tiles = (r1 - r0) * tiles_x
    counts = torch.bincount(tile, minlength=n_tiles)
    starts = torch.cumsum(counts, 0) - counts
    P = ts * ts
    K = CHUNK_GAUSSIANS
    batch = max(1, int(config.max_chunk_bytes // (_BLOCK_BYTES_PER_ELEM * K * P)))
    order = torch.argsort(counts, descending=True)  # similar list lengths share a batch
    counts_sorted = counts[order].tolist()
    py, px = torch.meshgrid(torch.arange(ts, device=dev), torch.arange(ts, device=dev), indexing="ij")
    py, px = py.reshape(-1), px.reshape(-1)
    bg = torch.as_tensor(config.background, dtype=dtype, device=dev)
    ar = torch.arange(K, device=dev)
    for b0 in range(0, n_tiles, batch):
        tb = order[b0:b0 + batch]
        nb = tb.numel()
        col = (tb % tiles_x)[:, None] * ts + px[None, :]  # (B, P) pixel column
        row = (tb // tiles_x + r0)[:, None] * ts + py[None, :]  # (B, P) pixel row
        xc = col.to(dtype) + 0.5
        yc = row.to(dtype) + 0.5
        color = torch.zeros(nb, P, 3, dtype=dtype, device=dev)
        T = torch.ones(nb, P, dtype=dtype, device=dev)
        done = torch.zeros(nb, P, dtype=torch.bool, device=dev)
        maxlen = counts_sorted[b0] if b0 < len(counts_sorted) else 0
        st = starts[tb][:, None]
        cnt = counts[tb][:, None]
        for k0 in range(0, maxlen, K):
            idx = k0 + ar[None, :]  # (B, K)
            live = idx < cnt
            g = splat[torch.clamp(st + idx, max=splat.numel() - 1)]
            f = feats[g]  # (B, K, 13)
            counter[0] += int(live.sum())
            dx = xc[:, None, :] - f[..., 0:1]
            dy = yc[:, None, :] - f[..., 1:2]
            power = -0.5 * (f[..., 2:3] * dx * dx + f[..., 4:5] * dy * dy) - f[..., 3:4] * dx * dy
            alpha = torch.clamp(f[..., 5:6] * torch.exp(power), max=config.alpha_cap)
            inbox = ((col[:, None, :] >= f[..., 9:10]) & (col[:, None, :] < f[..., 10:11])
                     & (row[:, None, :] >= f[..., 11:12]) & (row[:, None, :] < f[..., 12:13]))
            use = inbox & live[:, :, None] & (power <= 0) & (alpha >= config.alpha_threshold)
            alpha = torch.where(use, alpha, torch.zeros_like(alpha))
            T_after = torch.cumprod(1.0 - alpha, dim=1) * T[:, None, :]
            T_before = torch.cat([T[:, None, :], T_after[:, :-1]], dim=1)
            # a splat blends while T before it is >= t_min (the one that takes T below t_min
            # blends, then the pixel stops)
            keep = (T_before >= config.t_min) & ~done[:, None, :]
            w = torch.where(keep, alpha * T_before, torch.zeros_like(alpha))
            color += torch.einsum("bkp,bkc->bpc", w, f[..., 6:9])
            T = torch.where(keep, T_after, T[:, None, :]).amin(dim=1)
            done |= (keep & (T_after < config.t_min)).any(dim=1)
            if bool(done.all()):
                break
        color += T[..., None] * bg
        inside = (col < width) & (row < height)
        out[row[inside], col[inside]] = color[inside]


# ------------------------------------------------------------------------ render
def render(gaussians: Any, cameras: Cameras, config: RenderConfig | None = None, *,
           device: Any = None, dtype: Any = None) -> RenderResult:
    """Render V views with torch on the CPU or CUDA.

    Parameters
    ----------
    gaussians : holo_viewer.avatar.Gaussians
        N Gaussians, numpy or torch (validated by the caller, ``render_views``).
    cameras : Cameras
        V cameras of one size W x H.
    config : RenderConfig, optional
        Every semantic knob is honoured as in the reference; ``tile_size`` and
        ``max_chunk_bytes`` bound the working set; ``num_threads`` sets torch's CPU threads
        for the call; ``kernel`` is ignored.
    device : str or torch.device, optional
        Default: the Gaussians' device (CPU for numpy Gaussians).
    dtype : torch.dtype, optional
        Compute precision, default ``torch.float32``.

    Returns
    -------
    RenderResult
        ``images`` (V, H, W, 3) float32 numpy, row 0 at the top; timings "preprocess",
        "sort", "bin", "composite", "total"; stats "n_input", "n_visible",
        "mean_evaluated_per_pixel" (splat-pixel pairs evaluated per pixel, an upper bound
        of the blends).
    """
    torch = _torch()
    t_start = time.perf_counter()
    config = config or RenderConfig()
    dev = resolve_device(gaussians, device)
    dtype = dtype or torch.float32
    threads = torch.get_num_threads()
    if config.num_threads is not None and dev.type == "cpu":
        torch.set_num_threads(int(config.num_threads))
    try:
        with torch.no_grad():
            return _render(gaussians, cameras, config, dev, dtype, t_start)
    finally:
        torch.set_num_threads(threads)


def _tensor(x: Any, dtype: Any, dev: Any) -> Any:
    """A torch copy of numpy ``x`` (camera arrays are read-only; torch wants writable memory)."""
    return _torch().tensor(np.array(x, dtype=np.float64), dtype=dtype, device=dev)


def _sync(dev: Any) -> None:
    if dev.type == "cuda":
        _torch().cuda.synchronize(dev)


def _render(gaussians: Any, cameras: Cameras, config: RenderConfig, dev: Any, dtype: Any,
            t_start: float) -> RenderResult:
    torch = _torch()
    timings = {"preprocess": 0.0, "sort": 0.0, "bin": 0.0, "composite": 0.0}
    t0 = time.perf_counter()
    pdt = torch.float64  # per-splat preprocessing: cheap, and exact at knife edges (near plane, box edges)
    g = gaussians.torch(device=dev, dtype=pdt)
    from ..geometry import quat_to_rotmat

    means = g.means
    Rq = quat_to_rotmat(g.quats)
    Ms = Rq * torch.exp(g.log_scales)[:, None, :]
    cov3d = Ms @ Ms.transpose(1, 2)
    opac = torch.sigmoid(g.opacity_logits)
    degree = g.sh_degree if config.sh_degree is None else min(g.sh_degree, int(config.sh_degree))
    sh = g.sh
    near = cameras.near if config.near is None else float(config.near)
    keep = opac >= config.alpha_threshold  # never passes the alpha test otherwise
    positions = _tensor(cameras.positions, pdt, dev)
    shared_rgb = sh_colors(means, sh, degree, positions.mean(dim=0)) if config.shared_sh or degree == 0 else None
    _sync(dev)
    timings["preprocess"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    shared = cameras.shared_orientation
    # all views share R, so view depth = R[2] . mean + t_z(view): one order serves every view
    order_all = torch.argsort(means @ _tensor(cameras.R[0, 2], pdt, dev),
                              stable=True) if shared else None
    _sync(dev)
    timings["sort"] += time.perf_counter() - t0

    W, H, ts = cameras.width, cameras.height, config.tile_size
    tiles_x, tiles_y = math.ceil(W / ts), math.ceil(H / ts)
    images = np.empty((len(cameras), H, W, 3), dtype=np.float32)
    counter = [0]
    n_visible = torch.zeros(len(means), dtype=torch.bool, device=dev)
    for i in range(len(cameras)):
        t0 = time.perf_counter()
        w2c = _tensor(cameras.world_to_cam[i], pdt, dev)
        p = _project(means, cov3d, w2c, cameras.K[i], W, H, near, config)
        vis = p["valid"] & keep
        if config.cull_margin is not None:  # centre culling per view, as the reference does
            m = float(config.cull_margin)
            vis &= (p["u"] >= -m * W) & (p["u"] <= (1 + m) * W) & (p["v"] >= -m * H) & (p["v"] <= (1 + m) * H)
        rgb = shared_rgb if shared_rgb is not None else sh_colors(means, sh, degree, positions[i])
        _sync(dev)
        timings["preprocess"] += time.perf_counter() - t0

        t0 = time.perf_counter()
        if shared:
            order = order_all[vis[order_all]]
        else:
            idx = torch.nonzero(vis).squeeze(1)
            order = idx[torch.argsort(p["depth"][idx], stable=True)]
        n_visible[order] = True
        _sync(dev)
        timings["sort"] += time.perf_counter() - t0

        box = p["box"][order]
        # 13 features per splat, gathered once per chunk: u v A B C o r g b x0 x1 y0 y1
        feats = torch.cat([p["u"][order, None], p["v"][order, None], p["A"][order, None], p["B"][order, None],
                           p["C"][order, None], opac[order, None], rgb[order], box], dim=1).to(dtype)
        box_t = torch.stack([box[:, 0] // ts, (box[:, 1] - 1) // ts, box[:, 2] // ts, (box[:, 3] - 1) // ts],
                            dim=1).to(torch.int64)
        out = torch.empty(H, W, 3, dtype=dtype, device=dev)
        rows_per_band = _rows_per_band(box_t, tiles_x, tiles_y, config.max_chunk_bytes)
        for r0 in range(0, tiles_y, rows_per_band):
            band = (r0, min(r0 + rows_per_band, tiles_y))
            t0 = time.perf_counter()
            tile, splat = _band_pairs(box_t, band, tiles_x)
            _sync(dev)
            timings["bin"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            _composite_band(out, feats, tile, splat, band, tiles_x, W, H, config, counter)
            _sync(dev)
            timings["composite"] += time.perf_counter() - t0
        if config.clip_output:
            out.clamp_(0.0, 1.0)
        images[i] = out.to("cpu", torch.float32).numpy()
    timings["total"] = time.perf_counter() - t_start
    stats = {"n_input": len(means), "n_visible": int(n_visible.sum()), "sh_degree": degree,
             "shared_orientation": int(shared),
             "mean_evaluated_per_pixel": counter[0] * config.tile_size ** 2 / max(1, len(cameras) * W * H)}
    name = f"{BACKEND_NAME}/{dev.type}"
    return RenderResult(images=images, timings=timings, stats=stats, backend=name)


def _rows_per_band(box_t: Any, tiles_x: int, tiles_y: int, max_bytes: int) -> int:
    """Tile rows per band so that one band's (tile, splat) pairs stay below ``max_bytes``."""
    if box_t.shape[0] == 0:
        return tiles_y
    total = int(((box_t[:, 1] - box_t[:, 0] + 1) * (box_t[:, 3] - box_t[:, 2] + 1)).sum())
    n_bands = max(1, math.ceil(total * _PAIR_BYTES / max(1, max_bytes // 2)))
    return max(1, math.ceil(tiles_y / n_bands))
