"""The behaviour switches shared by ``react``, ``live``, ``render-batch`` and ``demo`` (docs/behaviour.md)."""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_behaviour_arguments", "behaviour_from_args", "pain_from_args"]


def add_behaviour_arguments(parser: argparse.ArgumentParser, pain_timeline: bool = True) -> None:
    """``--no-behaviour``, ``--no-gaze`` ``--no-blinks`` ``--no-brows`` ``--no-nods`` ``--no-breathing``
    ``--no-sway`` ``--no-flares`` (and ``--pain-timeline F.json``)."""
    from ..behaviour import LAYERS

    g = parser.add_argument_group("listener behaviour (all on by default; docs/behaviour.md)")
    g.add_argument("--no-behaviour", action="store_true",
                   help="the reaction model alone: no gaze, blinks, breathing, sway or pain dynamics "
                        "(the model is then conditioned on the pain level)")
    what = {"gaze": "eyes (and a little head) on the viewer, aversions, saccades",
            "blinks": "spontaneous blinks (AU43)", "brows": "brow raises (AU1 + AU2) after the speaker's pauses",
            "nods": "backchannel head nods after the speaker's pauses",
            "breathing": "breathing", "sway": "idle head sway",
            "flares": "pain flares over the level (the level itself still shows)"}
    for name in LAYERS:
        g.add_argument(f"--no-{name}", action="store_true", help=f"switch off {what[name]}")
    if pain_timeline:
        g.add_argument("--pain-timeline", metavar="F.json",
                       help='the pain level over time, [{"t": 0, "level": 0.2}, {"t": 5, "level": 0.7}] '
                            "(overrides --pain)")


def behaviour_from_args(args: argparse.Namespace, seed: int = 0) -> Any:
    """The :class:`~holo_viewer.behaviour.BehaviourConfig` the flags ask for (None: ``--no-behaviour``)."""
    from ..behaviour import LAYERS, BehaviourConfig

    if getattr(args, "no_behaviour", False):
        return None
    off = [name for name in LAYERS if getattr(args, f"no_{name}", False)]
    return BehaviourConfig(seed=int(seed)).without(*off)


def pain_from_args(args: argparse.Namespace) -> Any:
    """``--pain-timeline`` read and validated, else ``--pain``."""
    path = getattr(args, "pain_timeline", None)
    if path:
        from ..behaviour import PainTimeline

        return PainTimeline.load(path)
    return args.pain
