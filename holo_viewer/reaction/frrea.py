"""FRRea: Fréchet distance between rendered real and generated listener frames.

Frames (face states) are posed on the default FLAME head, their Gaussians are deformed by the
default rigged avatar and rendered by :func:`holo_viewer.render.render_views` from one frontal
camera at a small resolution; each image is described by
:func:`~holo_viewer.reaction.metrics.simple_image_features` (a hand-made 86-number descriptor,
**not Inception** features, so the values are not comparable with published FID/FRRea numbers),
and :func:`~holo_viewer.reaction.metrics.frechet_distance` compares the two sets.

Rendering every frame of N x K x T reactions is far beyond a CPU, so a seeded random subset of
frames is rendered (``n_frames`` per set).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..validation import check_array
from .features import flame_from_state
from .metrics import frechet_distance, simple_image_features

__all__ = ["FrameRenderer", "frrea"]


@dataclass
class FrameRenderer:
    """Renders face states of the default head (one frontal camera, ``size`` x ``size`` pixels)."""

    size: int = 48
    n_gaussians: int = 20000
    backend: str = "fast"

    def __post_init__(self) -> None:
        import torch

        from ..avatar.default_avatar import default_avatar
        from ..camera import Cameras, intrinsics, look_at
        from ..flame.expressions import default_au_map

        self.au_map = default_au_map()
        self.avatar = default_avatar(n_gaussians=self.n_gaussians, sh_degree=1)
        self.flame = self.avatar.flame_model if hasattr(self.avatar, "flame_model") else None
        if self.flame is None:
            from ..flame.default_head import load_default_model

            self.flame = load_default_model(add_teeth=True)
        f = self.size * 2.2
        w2c = look_at((0.0, 0.0, 0.7), (0.0, 0.0, 0.0))[None]
        K = intrinsics(f, f, self.size / 2, self.size / 2)[None]
        self.cameras = Cameras(world_to_cam=w2c, K=K, width=self.size, height=self.size, near=0.05, far=5.0)
        self._torch = torch

    def render(self, states: np.ndarray) -> np.ndarray:
        """Images (B, size, size, 3) float32 of face states (B, S)."""
        from ..render import api as render_api

        torch = self._torch
        fl = flame_from_state(np.asarray(states, dtype=np.float64), self.au_map)
        n_expr = int(getattr(self.flame, "n_expr", fl["expr"].shape[1]))
        expr = np.zeros((fl["expr"].shape[0], n_expr), np.float32)
        m = min(n_expr, fl["expr"].shape[1])
        expr[:, :m] = fl["expr"][:, :m]
        imgs = []
        with torch.no_grad():
            out = self.flame(expr=torch.from_numpy(expr), jaw_pose=torch.from_numpy(fl["jaw_pose"]),
                             rotation=torch.from_numpy(fl["rotation"]))
            for v in out.vertices:
                g = self.avatar.deform(v)
                imgs.append(render_api.render_views(g, self.cameras, backend=self.backend).images[0])
        return np.stack(imgs)


def frrea(real_states: np.ndarray, fake_states: np.ndarray, renderer: FrameRenderer, n_frames: int = 64,
          seed: int = 0) -> float:
    """Fréchet distance between simple features of rendered real and generated frames.

    Parameters
    ----------
    real_states : numpy.ndarray, shape (..., S)   ground-truth listener frames (any leading shape)
    fake_states : numpy.ndarray, shape (..., S)   generated frames
    renderer : FrameRenderer
    n_frames : int   frames rendered per set (a seeded random subset)
    seed : int
    """
    S = renderer.au_map.matrix.shape[0] + 6
    real = np.asarray(check_array(real_states, "real_states", (..., S))).reshape(-1, S)
    fake = np.asarray(check_array(fake_states, "fake_states", (..., S))).reshape(-1, S)
    if n_frames < 2:
        raise InputError(f"n_frames: expected >= 2, found {n_frames}")
    rng = np.random.default_rng(seed)
    ri = rng.choice(real.shape[0], min(n_frames, real.shape[0]), replace=False)
    fi = rng.choice(fake.shape[0], min(n_frames, fake.shape[0]), replace=False)
    fr = simple_image_features(renderer.render(real[ri]))
    ff = simple_image_features(renderer.render(fake[fi]))
    return frechet_distance(fr, ff)
