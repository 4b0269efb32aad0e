"""A streaming energy gate for the behaviour layers: is the speaker talking, has a pause just begun?

Per 40 ms frame (640 samples at 16 kHz): the frame's RMS level in dB; the gate opens when the level
is within ``range_db`` of a slowly decaying peak (the loudest recent speech) and above an absolute
floor, and closes after ``hangover_s`` below it. A **pause onset** is the frame where the gate has
been closed for ``pause_s`` (200 ms) after at least ``speech_s`` (700 ms) of speech: the
definition the listener bench uses (issue 36). This is only the layers' cue for blinks and
gaze; the reaction model's speech features (voice activity, pitch) are its own.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SpeechGate", "speech_cues"]


class SpeechGate:
    """Step once per frame with that frame's samples; see the module docstring."""

    def __init__(self, range_db: float = 25.0, floor_db: float = -55.0, hangover_s: float = 0.12,
                 pause_s: float = 0.2, speech_s: float = 0.7, fps: float = 25.0) -> None:
        self.range_db, self.floor_db = float(range_db), float(floor_db)
        self.dt = 1.0 / float(fps)
        self.hangover, self.pause_s, self.speech_s = hangover_s, pause_s, speech_s
        self.peak = floor_db
        self.open = False
        self.quiet = 0.0  # seconds below the gate
        self.talk = 0.0  # seconds of the current (or last) stretch of speech
        self.fired = False

    def step(self, samples: np.ndarray) -> tuple[bool, bool]:
        """(speaking, pause_onset) for this frame."""
        x = np.asarray(samples, dtype=np.float64).reshape(-1)
        rms = math.sqrt(float(np.mean(x * x))) if x.size else 0.0
        db = 20.0 * math.log10(max(rms, 1e-9))
        self.peak = max(db, self.peak - 1.0 * self.dt)  # the peak decays 1 dB/s
        loud = db > max(self.floor_db, self.peak - self.range_db)
        onset = False
        if loud:
            if self.quiet >= self.pause_s:
                self.talk = 0.0
            self.quiet = 0.0
            self.talk += self.dt
            self.open = True
            self.fired = False
        else:
            self.quiet += self.dt
            if self.quiet >= self.hangover:
                self.open = False
            if not self.fired and self.quiet >= self.pause_s - 1e-9 and self.talk >= self.speech_s - 1e-9:
                onset, self.fired = True, True
        return self.open, onset


def speech_cues(audio: np.ndarray, n_frames: int, hop: int = 640) -> tuple[np.ndarray, np.ndarray]:
    """(speaking, pause_onset), each (n_frames,) bool: :class:`SpeechGate` over a whole clip (frame
    ``t`` sees samples ``[hop t, hop (t + 1))``, as the live loop delivers them)."""
    a = np.asarray(audio, dtype=np.float64).reshape(-1)
    g = SpeechGate()
    sp = np.zeros(int(n_frames), bool)
    po = np.zeros(int(n_frames), bool)
    for t in range(int(n_frames)):
        sp[t], po[t] = g.step(a[t * hop:(t + 1) * hop])
    return sp, po
