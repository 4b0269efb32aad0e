"""Quilt tiling and lenticular interleave on a torch device, as one gather.

The numpy path is ``views -> to_uint8 -> tile_quilt -> Interleaver``. Every native subpixel reads
one quilt value (``nearest``) or two (``blend``), and every quilt value of a used tile is one value
of one view, so the whole chain is a gather from the views with the interleaver's own indices
(:meth:`Interleaver.gather_indices`) mapped through the tiling once: no quilt is built, and the
native image (uint8) is copied to the host once. Rounding is the numpy path's: ``rint(255 x)``
clipped to [0, 255] (half to even, as ``torch.round``), and in blend mode the same integer blend
``(a (256 - w8) + b w8 + 128) >> 8`` with ``w8 = rint(256 w)``, so both modes are exact.
Tested on CPU torch against the numpy path (tests/test_live_frame.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError
from .lenticular import Interleaver

__all__ = ["view_gather_indices", "DeviceInterleaver", "pinned_native"]


def view_gather_indices(interleaver: Interleaver, n_views: int, height: int, width: int) -> tuple[np.ndarray, ...]:
    """The interleaver's quilt indices mapped to flat indices into (n_views, height, width, 3) views.

    Returns (idx0, idx1, w8): (H W 3,) int64, int64 or None, int32 or None (the blend weight in
    1/256, as the uint8 interleave uses it).
    """
    Hq, Wq, _ = interleaver.quilt_shape
    cols, rows = interleaver.cols, interleaver.rows
    tw, th = Wq // cols, Hq // rows
    if (tw, th) != (width, height) or n_views > interleaver.n_views:
        raise InputError(f"views: expected up to {interleaver.n_views} views of {tw}x{th} (the quilt's tiles), "
                         f"found {n_views} of {width}x{height}")

    def remap(idx: np.ndarray) -> np.ndarray:
        idx = idx.astype(np.int64)
        ch, pix = idx % 3, idx // 3
        qr, qc = pix // Wq, pix % Wq
        r_from_bottom = (Hq - 1 - qr) // th
        k = qc // tw + cols * r_from_bottom
        y = qr - (Hq - (r_from_bottom + 1) * th)
        x = qc % tw
        if k.size and int(k.max()) >= n_views:
            raise InputError(f"views: the interleave reads view {int(k.max())}, only {n_views} given")
        return ((k * height + y) * width + x) * 3 + ch

    def build() -> dict[str, np.ndarray]:
        i0, i1, _ = interleaver.gather_indices()
        out = {"idx0": remap(i0).astype(store)}
        if i1 is not None:
            out["idx1"] = remap(i1).astype(store)
        return out

    # the tables depend on the calibration and the layout alone: cached on disk (display.table_cache)
    from .table_cache import cached_tables, table_key

    n = int(np.prod(interleaver.shape))
    store = np.int32 if n_views * height * width * 3 <= np.iinfo(np.int32).max else np.int64
    blend = interleaver.mode == "blend"
    spec = {name: ((n,), np.dtype(store).name) for name in (("idx0", "idx1") if blend else ("idx0",))}
    key = table_key("gather", interleaver.calibration, quilt_shape=interleaver.quilt_shape, cols=cols,
                    rows=interleaver.rows, il_views=interleaver.n_views, mode=interleaver.mode, n_views=int(n_views),
                    height=int(height), width=int(width))
    t = cached_tables("gather", key, spec, build)
    if not blend:
        return t["idx0"].astype(np.int64), None, None
    return t["idx0"].astype(np.int64), t["idx1"].astype(np.int64), interleaver._w8.astype(np.int32)


class DeviceInterleaver:
    """Float views on a torch device -> uint8 native image on the host, in one gather.

    Parameters
    ----------
    interleaver : Interleaver
        The numpy interleaver of the calibration and quilt (its indices are reused).
    n_views, height, width : int
        Views rendered per frame and their size (the quilt's tile size).
    device : str or torch.device
        Where the views live ("cuda", "cpu").
    """

    def __init__(self, interleaver: Interleaver, n_views: int, height: int, width: int, device: Any = "cpu") -> None:
        import torch

        self.device = torch.device(device)
        self.shape = interleaver.shape
        self.views_shape = (int(n_views), int(height), int(width), 3)
        i0, i1, w8 = view_gather_indices(interleaver, n_views, height, width)
        self._i0 = torch.as_tensor(i0, device=self.device)
        self._i1 = None if i1 is None else torch.as_tensor(i1, device=self.device)
        self._w8 = None if w8 is None else torch.as_tensor(w8, device=self.device)

    def __call__(self, views: Any, to_host: bool = True, out: np.ndarray | None = None) -> Any:
        """Native image of (V, H, W, 3) float views in [0, 1] (a torch tensor on the device).

        Returns a (screen_h, screen_w, 3) uint8 numpy array (``to_host``; written into ``out`` when
        given, which is then returned), else a device tensor. The copy to the host is the frame's
        one synchronisation; into page-locked memory (:func:`pinned_native`) it is a direct DMA.
        """
        import torch

        if tuple(views.shape) != self.views_shape:
            raise InputError(f"views: expected shape {self.views_shape}, found {tuple(views.shape)}")
        flat = views.reshape(-1)
        q = torch.clamp(torch.round(flat[self._i0].float() * 255.0), 0, 255)
        if self._i1 is None:
            res = q.to(torch.uint8)
        else:
            a = q.to(torch.int32)
            b = torch.clamp(torch.round(flat[self._i1].float() * 255.0), 0, 255).to(torch.int32)
            res = ((a * (256 - self._w8) + b * self._w8 + 128) >> 8).to(torch.uint8)
        res = res.reshape(self.shape)
        if not to_host:
            return res
        if out is None:
            return res.cpu().numpy()
        if out.shape != tuple(self.shape) or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise InputError(f"out: expected a C-contiguous uint8 array of shape {tuple(self.shape)}, "
                             f"found {out.dtype} {out.shape}")
        torch.from_numpy(out).copy_(res)
        return out


def pinned_native(shape: tuple[int, ...]) -> tuple[np.ndarray, Any]:
    """A zeroed uint8 host array in page-locked memory (and the torch tensor that owns it; keep it),
    so that a device-to-host copy into it is one DMA instead of a copy through a staging buffer.
    Falls back to ordinary memory (tensor None) where CUDA is unavailable."""
    try:
        import torch

        if torch.cuda.is_available():
            t = torch.zeros(tuple(shape), dtype=torch.uint8).pin_memory()
            return t.numpy(), t
    except (ImportError, RuntimeError):  # no torch, or a driver that refuses page-locked memory
        pass
    return np.zeros(tuple(shape), dtype=np.uint8), None
