"""The live mode table (pipeline/live_modes.py) names methods that exist, and the renderers follow it."""

from __future__ import annotations

import pytest

from holo_viewer.errors import InputError
from holo_viewer.pipeline.live import MODES, NativeFrameRenderer
from holo_viewer.pipeline.live_modes import (FRAME_MODE, FRAME_MODES, SESSION_MODE, SESSION_MODES, TRACKED_METHODS,
                                             frame_mode)


def test_every_row_names_a_method_of_the_renderer():
    for row in FRAME_MODES:
        assert callable(getattr(NativeFrameRenderer, row.method)), row
    for method in TRACKED_METHODS.values():
        assert callable(getattr(NativeFrameRenderer, method)), method
    for s in SESSION_MODES:
        assert all(callable(getattr(NativeFrameRenderer, p)) for p in s.prepare), s
        assert s.tracked in FRAME_MODE or s.tracked is None
    assert MODES == ("auto",) + tuple(FRAME_MODE)


def test_frame_mode_resolves_auto_and_checks_the_viewer():
    assert frame_mode("auto", None).name == "group"  # issue 37: every viewer sees the present frame
    assert frame_mode("auto", object()).name == "group"
    with pytest.raises(InputError, match="needs a viewer"):
        frame_mode("eye_centred", None)
    with pytest.raises(InputError, match="expected one of auto, full_quilt"):
        frame_mode("eyes", None)


def test_session_modes_choose_the_frame_modes():
    """What a live session renders while a face is tracked / while none is (the table, spelled out)."""
    chosen = {s.name: (s.tracked, s.untracked) for s in SESSION_MODES}
    assert chosen == {"auto": ("group", "group"), "tracked": ("tracked", "tracked"),
                      "all_views": ("all_views", "all_views"), "cone": (None, None)}
    assert SESSION_MODE["auto"].prepare == ("prepare_tracked", "prepare_all_views")
