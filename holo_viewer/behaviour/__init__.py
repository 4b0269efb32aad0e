"""A listening patient's behaviour that needs no data: gaze, blinks, breathing, idle sway and pain
dynamics, seeded and deterministic, composed on the reaction model's FLAME parameters
(docs/behaviour.md). Pure math on arrays; the pain timeline reads its JSON through ``fileio``."""

from .compose import (DEFAULT_FRAMING, DEFAULT_JOINTS, LAYERS, PANEL_HEIGHT_M, BehaviourConfig, ListenerBehaviour,
                      apply_behaviour, default_target, eye_directions, viewer_target)
from .timeline import SOURCES, PainKey, PainTimeline

__all__ = ["BehaviourConfig", "ListenerBehaviour", "apply_behaviour", "eye_directions", "viewer_target",
           "default_target", "DEFAULT_JOINTS", "DEFAULT_FRAMING", "PANEL_HEIGHT_M", "LAYERS", "PainKey",
           "PainTimeline", "SOURCES"]
