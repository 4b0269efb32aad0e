"""The stage table: every stage of the pipeline, what it consumes and reads, in data-flow order.

This table is the one list of stages. :class:`~holo_viewer.pipeline.Pipeline` walks it to
decide what to recompute, :class:`StageTimings` has one field per row, and the demo's and
the streaming app's timing tables iterate over it.

::

    FaceControls ─► params ─► mesh ─► gaussians ─┐
                  shape ─► framing ─► cameras ───┴─► views ─► quilt ─► native

Each row names the stage, the stages whose values it consumes (``deps``, passed to its
compute function in this order), the pipeline settings it reads (``reads``: fingerprinted
into the stage's cache key; ``"face.shape"`` is an attribute path of the pipeline), and the
module that does the work (``module``), so one parameter can be followed from the controls to
the pixels one file at a time.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

__all__ = ["Stage", "STAGE_TABLE", "STAGES", "STREAM_OUTPUTS", "StageTimings"]


@dataclass(frozen=True)
class Stage:
    """One row of the stage table.

    Attributes
    ----------
    name : str
        Stage name (``Pipeline.get(name)``; a :class:`StageTimings` field).
    deps : tuple of str
        Upstream stages whose values the stage consumes, in argument order.
    reads : tuple of str
        Pipeline settings the stage reads (attribute paths of the pipeline, see
        ``Pipeline._read``); a change to any of them, or to a dependency, recomputes the stage.
    module : str
        Where the stage's work is done.
    doc : str
        What the stage produces.
    """

    name: str
    deps: tuple[str, ...]
    reads: tuple[str, ...]
    module: str
    doc: str


#: every stage, in data-flow order (dependencies before the stages that consume them)
STAGE_TABLE: tuple[Stage, ...] = (
    Stage("params", (), ("face", "model", "au_map"), "flame/expressions.py",
          "FaceControls -> FLAME parameters (named expressions and pain resolved to coefficients)"),
    Stage("mesh", ("params",), ("model",), "flame/model.py",
          "FLAME linear blend skinning -> (V, 3) posed vertices"),
    Stage("gaussians", ("mesh", "params"), ("avatar",), "avatar/rigged.py | avatar/blendshape.py",
          "world Gaussians of the avatar (rigged to the mesh, or blend shapes of the parameters)"),
    Stage("framing", (), ("face.shape", "view.framing_margin", "model", "avatar"), "pipeline/core.py",
          "focal-plane centre and half-height that frame the neutral head"),
    Stage("cameras", ("framing",), ("view.viewer_distance", "view.view_cone", "view.viewer_angle",
                                    "view.tile_scale", "calibration"), "display/cameras.py",
          "the quilt's cameras (Algorithm 1)"),
    Stage("views", ("gaussians", "cameras"), ("backend", "render_config"), "render/api.py",
          "(n_views, H, W, 3) float32 images splatted from the Gaussians"),
    Stage("quilt", ("views",), ("calibration.layout",), "display/quilt.py",
          "(rows*H, cols*W, 3) uint8 quilt, view 0 bottom-left"),
    Stage("native", ("quilt",), ("view.blend", "calibration"), "display/lenticular.py",
          "(screenH, screenW, 3) uint8 lenticular native image of the panel"),
)

#: stage names in data-flow order
STAGES: tuple[str, ...] = tuple(s.name for s in STAGE_TABLE)
#: stages a stream can stop at, once per frame (the others do not change from frame to frame)
STREAM_OUTPUTS: tuple[str, ...] = tuple(s for s in STAGES if s not in ("params", "framing", "cameras"))


def _check_table() -> None:
    seen: set[str] = set()
    for s in STAGE_TABLE:
        missing = [d for d in s.deps if d not in seen]
        if missing:  # a programming error in the table above, caught at import
            raise RuntimeError(f"stage table: {s.name} consumes {missing} before they are computed")
        seen.add(s.name)


_check_table()


class _TimingsBase:
    """Methods of :class:`StageTimings` (its fields come from the stage table)."""

    @property
    def total(self) -> float:
        """Sum of the stages that ran (seconds)."""
        return float(sum(v for v in dataclasses.astuple(self) if v is not None))  # type: ignore[call-overload]

    def recomputed(self) -> list[str]:
        """Names of the stages that ran."""
        return [s for s in STAGES if getattr(self, s) is not None]

    def add(self, other: "StageTimings") -> None:
        """Accumulate ``other`` into self (stages that ran in either)."""
        for s in STAGES:
            a, b = getattr(self, s), getattr(other, s)
            if b is not None:
                setattr(self, s, (a or 0.0) + b)

    def as_dict(self) -> dict[str, float | None]:
        """``{stage: seconds or None}`` in data-flow order."""
        return {s: getattr(self, s) for s in STAGES}


#: Seconds spent in each stage by one request; None = served from the cache (one field per stage).
StageTimings = dataclasses.make_dataclass(
    "StageTimings", [(s, "float | None", dataclasses.field(default=None)) for s in STAGES], bases=(_TimingsBase,),
    namespace={"__doc__": "Seconds spent in each stage by one request; None = served from the cache.\n\n"
                          "One field per row of :data:`STAGE_TABLE` (``params``, ``mesh``, ... ``native``).",
               "__module__": __name__})
