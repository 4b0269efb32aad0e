"""Instructor controls (keys) and the standardized-patient scenario timeline (pure, thread-safe)."""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..fileio import read_json
from ..validation import check_json_number

__all__ = ["Controls", "Scenario", "ScenarioEvent", "KEYS", "KEY_HELP", "LAYER_KEYS", "TRAINEES"]

#: key symbol (VTK / X11 names) -> action: the one key map of a live session (shown on ``h``)
KEYS = {"Up": "pain_up", "plus": "pain_up", "equal": "pain_up", "Down": "pain_down", "minus": "pain_down",
        "space": "pause", "p": "pause", "m": "mute", "r": "recentre", "c": "recentre", "h": "help",
        "question": "help", "t": "trainee", "x": "rate", "q": "quit", "Escape": "quit",
        "g": "toggle_gaze", "b": "toggle_blinks", "a": "toggle_breathing", "s": "toggle_sway",
        "Right": "scenario_next", "bracketright": "scenario_next", "Left": "scenario_previous",
        "bracketleft": "scenario_previous", **{str(d): "rate" for d in range(10)}}
#: the behaviour layers (holo_viewer.behaviour.BehaviourConfig switches) the toggle_* keys turn on and off
LAYER_KEYS = ("gaze", "blinks", "breathing", "sway")
#: the key map as the preview shows it on ``h`` (keys, what they do)
KEY_HELP = (("Up / + , Down / -", "pain up / down by 0.1"), ("space / p", "pause / resume (clock, audio, "
            "scenario, recording)"), ("m", "mute: the patient hears nothing"), ("r / c", "recentre the viewer"),
            ("t", "next trainee (A..H)"), ("0-9, x", "the trainee's pain rating 0-9, x = 10"),
            ("g / b / a / s", "gaze / blinks / breathing / sway on or off"),
            ("Right / ], Left / [", "scenario: next / previous step"),
            ("h / ?", "show / hide this key map"), ("q / Esc", "quit"))
#: trainee labels the ``t`` key cycles through
TRAINEES = "ABCDEFGH"
PAIN_STEP = 0.1


class Controls:
    """What the instructor set: pain, pause, recentre request, quit (shared by the loop's threads)."""

    def __init__(self, pain: float = 0.0) -> None:
        self._lock = threading.Lock()
        self.pain = float(pain)
        self.paused = False
        self.muted = False
        self.show_help = False
        #: the trainee whose ratings the number keys enter, and the last rating entered
        self.trainee = TRAINEES[0]
        self.last_rating: int | None = None
        #: behaviour layers to switch, oldest first (the reaction thread takes them)
        self._layer_toggles: list[str] = []
        #: scenario steps to jump, oldest first (+1 next, -1 previous; the reaction thread takes them)
        self._scenario_steps: list[int] = []
        self.quit = False
        self._recentre = False
        #: key actions applied, oldest first (for the session record and tests)
        self.log: list[str] = []

    def key(self, keysym: str) -> str | None:
        """Apply a key (see :data:`KEYS`); returns the action or None for other keys."""
        action = KEYS.get(keysym)
        if action is None:
            return None
        with self._lock:
            if action == "pain_up":
                self.pain = min(1.0, round(self.pain + PAIN_STEP, 6))
            elif action == "pain_down":
                self.pain = max(0.0, round(self.pain - PAIN_STEP, 6))
            elif action == "pause":
                self.paused = not self.paused
            elif action == "mute":
                self.muted = not self.muted
            elif action == "help":
                self.show_help = not self.show_help
            elif action == "trainee":
                self.trainee = TRAINEES[(TRAINEES.index(self.trainee) + 1) % len(TRAINEES)]
            elif action == "rate":
                self.last_rating = 10 if keysym == "x" else int(keysym)
            elif action in ("scenario_next", "scenario_previous"):
                self._scenario_steps.append(1 if action == "scenario_next" else -1)
            elif action.startswith("toggle_"):
                self._layer_toggles.append(action[len("toggle_"):])
            elif action == "recentre":
                self._recentre = True
            elif action == "quit":
                self.quit = True
            self.log.append(action)
        return action

    def set_pain(self, pain: float) -> None:
        with self._lock:
            self.pain = min(1.0, max(0.0, float(pain)))

    def take_layer_toggles(self) -> list[str]:
        """The behaviour layers switched since the last call (names of :data:`LAYER_KEYS`)."""
        with self._lock:
            t, self._layer_toggles = self._layer_toggles, []
            return t

    def take_scenario_steps(self) -> list[int]:
        """The scenario step keys pressed since the last call (+1 next, -1 previous)."""
        with self._lock:
            s, self._scenario_steps = self._scenario_steps, []
            return s

    def take_recentre(self) -> bool:
        """True once after a recentre key."""
        with self._lock:
            r, self._recentre = self._recentre, False
            return r


@dataclass(frozen=True)
class ScenarioEvent:
    """At ``t`` seconds: set ``pain`` (if given) and/or show ``expression`` at ``intensity`` for ``duration`` s."""

    t: float
    pain: float | None = None
    expression: str | None = None
    intensity: float = 1.0
    duration: float = 2.0


class Scenario:
    """A timeline of pain levels and named expressions (the standardized-patient script).

    JSON::

        {"events": [{"t": 0, "pain": 0.1},
                    {"t": 4, "pain": 0.7, "expression": "frown", "intensity": 0.6, "duration": 3},
                    {"t": 10, "expression": "smile", "intensity": 0.8}]}

    or with the pain levels as a pain timeline (the schema of :mod:`holo_viewer.behaviour.timeline`,
    shared with render-batch manifests and session reports), which become pain events::

        {"pain_timeline": [{"t": 0, "level": 0.1}, {"t": 4, "level": 0.7}],
         "events": [{"t": 10, "expression": "smile", "intensity": 0.8}]}

    ``expression`` is one of the pipeline's named expressions (smile, pain, surprise, frown,
    mouth_open, neutral).
    """

    def __init__(self, events: list[ScenarioEvent]) -> None:
        self.events = sorted(events, key=lambda e: e.t)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Scenario":
        """Read the JSON of the class docstring (InputError naming the file and field)."""
        p = Path(path)
        return cls.from_json(read_json(p, InputError, "scenario JSON"), p)

    def to_json(self) -> dict:
        """``{"events": [...]}`` that :meth:`from_json` reads back to the same scenario (session.json)."""
        return {"events": [{k: v for k, v in vars(e).items() if v is not None} for e in self.events]}

    @classmethod
    def from_json(cls, data: object, p: str | os.PathLike = "scenario") -> "Scenario":
        """The scenario of parsed JSON ``data``; ``p`` names it in errors (a file, ``session.json: scenario``)."""
        if isinstance(data, dict) and "pain_timeline" in data:
            from ..behaviour import PainTimeline

            tl = PainTimeline.from_json(data["pain_timeline"], source=f"{p}: pain_timeline")
            if any(isinstance(e, dict) and e.get("pain") is not None for e in data.get("events") or []):
                raise InputError(f"{p}: events: pain set both in pain_timeline and in events; expected one of them")
            data = {**data, "events": list(data.get("events") or []) + [{"t": k.t, "pain": k.level} for k in tl.keys]}
        if not isinstance(data, dict) or not isinstance(data.get("events"), list):
            raise InputError(f'{p}: expected {{"events": [...]}}, found {type(data).__name__}')
        names = ("smile", "pain", "surprise", "frown", "mouth_open", "neutral")
        events = []
        for i, e in enumerate(data["events"]):
            if not isinstance(e, dict) or "t" not in e:
                raise InputError(f"{p}: events[{i}]: expected an object with 't', found {e!r}")
            unknown = set(e) - {"t", "pain", "expression", "intensity", "duration"}
            if unknown:
                raise InputError(f"{p}: events[{i}]: unknown keys {sorted(unknown)}")
            # JSON types checked: a string, null, boolean or NaN is refused naming the field
            where = f"{p}: events[{i}]"
            ev = ScenarioEvent(check_json_number(e["t"], f"{where}.t", low=0.0),
                               None if e.get("pain") is None else check_json_number(e["pain"], f"{where}.pain"),
                               e.get("expression"), check_json_number(e.get("intensity", 1.0), f"{where}.intensity"),
                               check_json_number(e.get("duration", 2.0), f"{where}.duration", low=0.0, low_open=True))
            if ev.pain is not None and not 0.0 <= ev.pain <= 1.0:
                raise InputError(f"{p}: events[{i}].pain: expected a value in [0, 1], found {ev.pain}")
            if ev.expression is not None and ev.expression not in names:
                raise InputError(f"{p}: events[{i}].expression: expected one of {names}, found {ev.expression!r}")
            if not 0.0 <= ev.intensity <= 1.0 or ev.duration <= 0 or ev.t < 0:
                raise InputError(f"{p}: events[{i}]: expected t >= 0, intensity in [0, 1], duration > 0")
            events.append(ev)
        return cls(events)

    def pain_at(self, t: float) -> float | None:
        """Pain of the last event with a pain value at or before ``t`` (None: no such event)."""
        val = None
        for e in self.events:
            if e.t <= t and e.pain is not None:
                val = e.pain
        return val

    def pain_changes(self, t0: float, t1: float) -> float | None:
        """The pain set by an event in (t0, t1] (None when no event sets pain there)."""
        val = None
        for e in self.events:
            if t0 < e.t <= t1 and e.pain is not None:
                val = e.pain
        return val

    def steps(self) -> tuple[float, ...]:
        """The scenario's steps: the distinct event times, in order."""
        return tuple(sorted({e.t for e in self.events}))

    def step_from(self, t: float, direction: int) -> float:
        """The scenario time after a step key at scenario time ``t``: the next step's time
        (``direction`` > 0; ``t`` itself after the last step) or the previous one's (< 0: the step
        before the one ``t`` is in; ``t`` itself before the first step)."""
        steps = self.steps()
        current = sum(1 for s in steps if s <= t + 1e-9) - 1  # the step t is in (-1: before the first)
        if direction > 0:
            return steps[current + 1] if current + 1 < len(steps) else float(t)
        return steps[max(current - 1, 0)] if current >= 0 else float(t)

    def named_at(self, t: float) -> tuple[tuple[str, float], ...]:
        """Named expressions active at ``t`` (later events win for the same name)."""
        active: dict[str, float] = {}
        for e in self.events:
            if e.expression is not None and e.t <= t < e.t + e.duration:
                active[e.expression] = e.intensity
        return tuple(sorted(active.items()))
