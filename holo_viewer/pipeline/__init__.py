"""The one place that chains the stages (docs/design.md section 2).

::

    reaction/ ─► FLAME frames ─► FaceControls ─► params ─► mesh ─► gaussians ─┐
                                                shape ─► framing ─► cameras ───┴─► views ─► quilt ─► native

Nothing outside this package wires one stage package to another: the commands, the GUI and
the apps ask a :class:`Pipeline` (or :func:`render_quilt`) for what they show or write
(``tests/test_architecture.py`` checks the imports).

=========================  ==========================================================================
module                     what
=========================  ==========================================================================
``pipeline.stages``        the stage table (:data:`STAGE_TABLE`): names, inputs, settings read, module
``pipeline.settings``      :class:`FaceControls`, :class:`ViewSettings`, stream results, FLAME frames
``pipeline.core``          :class:`Pipeline`: the cached chain, per-stage timings, streaming
``pipeline.avatars``       :class:`PipelineAvatar`: rigged, blend-shape or static avatars
``pipeline.rendering``     :func:`render_quilt`: Gaussians + cameras -> views -> uint8 quilt
``pipeline.scene``         :func:`load_scene`: a pipeline from files (model, avatar, sequence)
``pipeline.reactions``     listener reactions as FLAME frames; rendering face states for FRRea
``pipeline.live``          :class:`NativeFrameRenderer`, :func:`render_native`: live native frames by mode
                           (tracked viewer / all views / full quilt; docs/live_frame.md)
=========================  ==========================================================================

Importing this package imports numpy only; the stage packages load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from .avatars import PipelineAvatar, StaticAvatar, as_pipeline_avatar
from .core import Pipeline, default_calibration, frame_head, quilt_layout
from .rendering import render_images, render_quilt, tile_views
from .settings import (FLAME_KEYS, FaceControls, FrameResult, StreamReport, ViewSettings, apply_frame,
                       flame_sequence_frames)
from .stages import STAGE_TABLE, STAGES, Stage, StageTimings

__all__ = [
    "STAGES", "STAGE_TABLE", "Stage", "StageTimings", "FaceControls", "ViewSettings", "FrameResult",
    "StreamReport", "Pipeline", "frame_head", "flame_sequence_frames", "apply_frame", "FLAME_KEYS",
    "default_calibration", "quilt_layout", "PipelineAvatar", "StaticAvatar", "as_pipeline_avatar",
    "render_images", "render_quilt", "tile_views", "Scene", "load_scene", "reaction_frames",
    "react_to_speaker", "FaceStateRenderer",
]

_LAZY = {"Scene": "scene", "load_scene": "scene", "reaction_frames": "reactions", "react_to_speaker": "reactions",
         "FaceStateRenderer": "reactions"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        obj = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = obj
        return obj
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
