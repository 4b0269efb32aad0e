"""Moved to :mod:`holo_viewer.pipeline.scene` (headless code lives below the GUI); kept for old imports."""

from __future__ import annotations

from ..pipeline.scene import Scene, StaticAvatar, load_scene

__all__ = ["Scene", "load_scene", "StaticAvatar"]
