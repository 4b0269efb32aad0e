"""Gaussian avatars: the 3D Gaussians container, PLY I/O, rigged and blend-shape avatars.

Importing this package imports numpy only; the rigged / blend-shape avatars (torch) are
loaded on first attribute access.
"""

from __future__ import annotations

import importlib
from typing import Any

from .gaussians import SH_C0, Gaussians, sh_degree_from_count
from .ply import load_ply, save_ply

__all__ = ["Gaussians", "SH_C0", "sh_degree_from_count", "load_ply", "save_ply", "RiggedAvatar",
           "load_gaussian_avatar", "FlameParams", "load_flame_params", "BlendshapeAvatar", "default_avatar",
           "cull_backfacing"]

_LAZY = {"RiggedAvatar": "rigged", "load_gaussian_avatar": "gaussian_avatars", "FlameParams": "gaussian_avatars",
         "load_flame_params": "gaussian_avatars", "BlendshapeAvatar": "blendshape",
         "default_avatar": "default_gaussians", "cull_backfacing": "culling"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        obj = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = obj  # also replaces the submodule attribute that shares the name
        return obj
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
