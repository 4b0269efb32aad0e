"""The live mode table: every way a live frame is made, what it needs and where its work is done.

Two tables, read top to bottom like :mod:`holo_viewer.pipeline.stages`:

* :data:`FRAME_MODES`, the modes of :meth:`holo_viewer.pipeline.live.NativeFrameRenderer.frame`
  (Gaussians -> the panel's native image). Each row names the renderer method that makes the frame,
  whether it needs a tracked viewer, whether it draws on the previous frame (the first frame of a
  renderer, or the first after a change of avatar, renders ``full_quilt`` instead), and the modules
  that do the work. Every path ends in :func:`holo_viewer.display.native.views_to_native` except
  the per-eye scatters (slices, eye images), which write subpixels straight from per-eye images.
* :data:`SESSION_MODES`, the ``--render-mode`` of ``holo-viewer live``
  (:class:`holo_viewer.live.render.LiveAvatarRenderer`): which frame mode runs while a face is
  tracked and while none is, and which one-off tables are built before the first frame.

::

    face state ─► Pipeline (params, mesh, gaussians) ─► NativeFrameRenderer.frame(mode) ─► native
                                                    └─► (cone) Pipeline.native() for the viewer's cone
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FrameMode", "FRAME_MODES", "FRAME_MODE", "SessionMode", "SESSION_MODES", "SESSION_MODE",
           "TRACKED_METHODS", "frame_mode"]


@dataclass(frozen=True)
class FrameMode:
    """One row of :data:`FRAME_MODES`.

    Attributes
    ----------
    name : str
        The ``mode`` argument of ``NativeFrameRenderer.frame`` (and :attr:`LiveFrame.mode`).
    method : str
        The :class:`~holo_viewer.pipeline.live.NativeFrameRenderer` method that renders it:
        ``method(gaussians, viewer, timings) -> rendered fraction``.
    needs_viewer : bool
        Needs a :class:`~holo_viewer.display.eyes.TrackedViewer`.
    incremental : bool
        Updates the previous frame (kept views, quilt and native image) instead of replacing it.
    modules : str
        Where the work is done.
    doc : str
        What the frame is.
    """

    name: str
    method: str
    needs_viewer: bool
    incremental: bool
    modules: str
    doc: str


#: every frame mode; "auto" is not a row: :func:`frame_mode` resolves it
FRAME_MODES: tuple[FrameMode, ...] = (
    FrameMode("full_quilt", "_full_quilt", False, False, "render/fast.py, display/native.py",
              "every view in full: render -> uint8 quilt -> interleave (the quality reference)"),
    FrameMode("all_views", "_all_views", False, False,
              "render/lod.py, render/fast.py, render/view_synthesis.py, display/native.py",
              "every view of the default cone, untracked: level of detail, every view_step-th view rendered "
              "and the others synthesized by depth; with gsplat all on the GPU (display/device.py)"),
    FrameMode("group", "_group", False, False,
              "render/fast.py, render/crossed_slit.py, render/view_synthesis.py, display/native.py, display/slices.py",
              "every position of the cone sees the present frame: all views (every view_step-th rendered, the "
              "others synthesized by depth) and, over them, the exact eye slices of every tracked viewer (0-6)"),
    FrameMode("tracked", "_tracked", True, True,
              "display/eyes.py, render/crossed_slit.py, display/slices.py | render/fast.py, display/native.py",
              "the native subpixels a tracked viewer's eyes receive, by the renderer's tracked method "
              "(TRACKED_METHODS), plus a round-robin refresh of the other views (everyone else sees older frames)"),
    FrameMode("eye_centred", "_eye_centred", True, True, "display/eyes.py, render/fast.py",
              "one perspective image per eye from the eye's own position, scattered into the subpixels "
              "that reach it"),
)
FRAME_MODE = {m.name: m for m in FRAME_MODES}
#: NativeFrameConfig.tracked -> the renderer method of a tracked frame
TRACKED_METHODS = {"slices": "_tracked_slices", "bands": "_tracked_bands"}


def frame_mode(mode: str, viewer: object) -> FrameMode:
    """The row of ``mode`` (``auto``: ``group``, every position of the cone sees the present frame,
    with exact eye images for the viewers given, if any).

    Raises
    ------
    InputError
        An unknown mode, or a mode that needs a viewer without one.
    """
    from ..errors import InputError

    if mode == "auto":
        mode = "group"
    row = FRAME_MODE.get(mode)
    if row is None:
        raise InputError(f"mode: expected one of auto, {', '.join(FRAME_MODE)}, found {mode!r}")
    if row.needs_viewer and viewer is None:
        raise InputError(f"mode {mode!r} needs a viewer (holo_viewer.display.eyes.TrackedViewer)")
    return row


@dataclass(frozen=True)
class SessionMode:
    """One row of :data:`SESSION_MODES`.

    Attributes
    ----------
    name : str
        ``holo-viewer live --render-mode``.
    tracked, untracked : str or None
        Frame mode while a face is tracked / while none is (None: the whole quilt of a cone centred
        on the viewer, ``Pipeline.native``). With gsplat every frame mode is ``all_views``: all 48 views
        cost less on the GPU than two eyes on the CPU.
    prepare : tuple of str
        ``NativeFrameRenderer`` methods that build the one-off tables before the first frame.
    doc : str
    """

    name: str
    tracked: str | None
    untracked: str | None
    prepare: tuple[str, ...]
    doc: str


SESSION_MODES: tuple[SessionMode, ...] = (
    SessionMode("auto", "group", "group", ("prepare_tracked", "prepare_all_views"),
                "every view each frame, and exact eye images for every tracked face (the default)"),
    SessionMode("tracked", "tracked", "tracked", ("prepare_tracked",),
                "always for the viewer's eyes (the last known position when no face is tracked)"),
    SessionMode("all_views", "all_views", "all_views", ("prepare_all_views",), "every view, untracked"),
    SessionMode("cone", None, None, (), "the 48-view cone follows the viewer: the whole quilt each frame"),
)
SESSION_MODE = {m.name: m for m in SESSION_MODES}


def _check_tables() -> None:
    for s in SESSION_MODES:  # a programming error in the tables above, caught at import
        for m in (s.tracked, s.untracked):
            if m is not None and m not in FRAME_MODE:
                raise RuntimeError(f"session mode {s.name}: frame mode {m!r} is not in FRAME_MODES")


_check_tables()
