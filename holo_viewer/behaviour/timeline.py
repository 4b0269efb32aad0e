"""The pain timeline: one JSON schema for live scenarios, render-batch manifests and session reports.

Schema (a JSON array of keys, times strictly increasing)::

    [{"t": 0, "level": 0.2},
     {"t": 6.5, "level": 0.7, "source": "key"},
     {"t": 14, "level": 0.4}]

* ``t``: seconds from the start of the clip / session, a number >= 0;
* ``level``: the instructor's pain level from ``t`` on (until the next key), a number in [0, 1];
* ``source`` (optional): who set it, one of ``start``, ``cli``, ``key``, ``scenario``, ``manifest``
  (session reports write it; readers ignore it).

Before the first key the level is 0. The level is what the instructor asks for; the pain *shown*
comes from :class:`~holo_viewer.behaviour.layers.PainDynamics` (the level's background plus flares,
a level change visible within 0.3 s). Where a file is expected, the array may also be wrapped as
``{"pain_timeline": [...]}``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..errors import InputError

__all__ = ["PainKey", "PainTimeline", "SOURCES"]

SOURCES = ("start", "cli", "key", "scenario", "manifest")


@dataclass(frozen=True)
class PainKey:
    """From ``t`` seconds on, the instructor's pain level is ``level``."""

    t: float
    level: float
    source: str | None = None

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"t": self.t, "level": self.level}
        if self.source is not None:
            d["source"] = self.source
        return d


def _number(v: Any, where: str, lo: float, hi: float | None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise InputError(f"{where}: expected a finite number, found {v!r}")
    x = float(v)
    if x < lo or (hi is not None and x > hi):
        rng = f"[{lo:g}, {hi:g}]" if hi is not None else f">= {lo:g}"
        raise InputError(f"{where}: expected a number {rng}, found {v!r}")
    return x


class PainTimeline:
    """A validated pain timeline (module docstring); immutable."""

    def __init__(self, keys: Iterable[PainKey]) -> None:
        self.keys: tuple[PainKey, ...] = tuple(keys)
        for a, b in zip(self.keys, self.keys[1:]):
            if not b.t > a.t:
                raise InputError(f"pain_timeline: expected times strictly increasing, found {a.t} then {b.t}")
        self._t = np.array([k.t for k in self.keys])
        self._v = np.array([k.level for k in self.keys])

    @classmethod
    def constant(cls, level: float, source: str | None = None) -> "PainTimeline":
        """One key at t = 0."""
        return cls([PainKey(0.0, _number(level, "pain", 0.0, 1.0), source)])

    @classmethod
    def from_json(cls, value: Any, source: str = "pain_timeline") -> "PainTimeline":
        """Validate the JSON value (an array of keys, or ``{"pain_timeline": [...]}``); errors name
        ``source`` and the key's index and field."""
        if isinstance(value, dict) and set(value) == {"pain_timeline"}:
            value = value["pain_timeline"]
            source = f"{source}.pain_timeline"
        if not isinstance(value, list) or not value:
            raise InputError(f'{source}: expected a non-empty array of {{"t": seconds, "level": 0..1}} keys, '
                             f"found {value!r:.80}")
        keys = []
        for i, k in enumerate(value):
            where = f"{source}[{i}]"
            if not isinstance(k, dict):
                raise InputError(f'{where}: expected an object {{"t": seconds, "level": 0..1}}, found {k!r:.60}')
            missing = [f for f in ("t", "level") if f not in k]
            if missing:
                raise InputError(f"{where}: missing {', '.join(missing)} (expected t in seconds >= 0 and level "
                                 f"in [0, 1])")
            unknown = sorted(set(k) - {"t", "level", "source"})
            if unknown:
                raise InputError(f"{where}: unknown keys {unknown}; expected t, level and optionally source")
            src = k.get("source")
            if src is not None and src not in SOURCES:
                raise InputError(f"{where}.source: expected one of {', '.join(SOURCES)}, found {src!r}")
            t = _number(k["t"], f"{where}.t", 0.0, None)
            if keys and not t > keys[-1].t:
                raise InputError(f"{where}.t: expected a time after the previous key's {keys[-1].t:g} s, found {t:g}")
            keys.append(PainKey(t, _number(k["level"], f"{where}.level", 0.0, 1.0), src))
        return cls(keys)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "PainTimeline":
        """Read a JSON file holding a timeline."""
        from ..fileio import read_json

        p = Path(path)
        return cls.from_json(read_json(p, InputError, "pain timeline JSON"), source=str(p))

    def to_json(self) -> list[dict[str, Any]]:
        return [k.to_dict() for k in self.keys]

    def level_at(self, t: float) -> float:
        """The level at ``t`` seconds (0 before the first key)."""
        i = int(np.searchsorted(self._t, float(t), side="right")) - 1
        return float(self._v[i]) if i >= 0 else 0.0

    def levels(self, n_frames: int, fps: float = 25.0) -> np.ndarray:
        """(n_frames,) the level at each frame time ``k / fps``."""
        times = np.arange(int(n_frames)) / float(fps)
        i = np.searchsorted(self._t, times + 1e-9, side="right") - 1
        return np.where(i >= 0, self._v[np.clip(i, 0, None)], 0.0)

    def max_level(self) -> float:
        return float(self._v.max()) if self._v.size else 0.0

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PainTimeline) and [(k.t, k.level) for k in self.keys] == \
            [(k.t, k.level) for k in other.keys]

    def __repr__(self) -> str:
        return f"PainTimeline({self.to_json()})"
