"""Gaussian avatars: the 3D Gaussians container, PLY I/O, rigged and blend-shape avatars."""

from .gaussians import SH_C0, Gaussians, sh_degree_from_count
from .ply import load_ply, save_ply

__all__ = ["Gaussians", "SH_C0", "sh_degree_from_count", "load_ply", "save_ply"]
