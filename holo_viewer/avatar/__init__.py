"""Gaussian avatars: the 3D Gaussians container, PLY I/O, rigged and blend-shape avatars."""

from .gaussians import Gaussians, SH_C0, sh_degree_from_count

__all__ = ["Gaussians", "SH_C0", "sh_degree_from_count"]
