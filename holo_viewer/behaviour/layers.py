"""The no-data behaviour layers of a listening patient: gaze, blinks, breathing, idle sway, pain.

Each layer is a small seeded state machine stepped once per frame (25 fps) that returns plain
numbers; :mod:`holo_viewer.behaviour.compose` turns them into FLAME parameters. Pure Python and
numpy, no I/O. Every random draw comes from the layer's own ``numpy.random.Generator`` (seeded from
``SeedSequence([seed, layer])``) and happens inside :meth:`step`, so a whole clip and the same
frames streamed one by one give identical output, and one layer switched off leaves the others'
draws unchanged.

Anchors (docs/behaviour.md): listeners look at the speaker 60-80 % of listening time with brief
aversions and small saccades (Argyle & Cook 1976; Kendon 1967); spontaneous blinks 10-25 per
minute lasting 100-400 ms (Bentivoglio et al. 1997; Doughty 2001), listeners' blinks cluster at
the speaker's pauses (Nakano & Kitazawa 2010); listeners answer a pause with a backchannel
(a nod, a smile, a brow raise: Ward & Tsukahara 2000; Chovil 1991); breathing 12-20 per minute; pain in episodes with
a fast onset (apex within ~1 s), a hold and an easing (Prkachin & Solomon 2008).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["GazeLayer", "GazeSample", "BlinkLayer", "BrowLayer", "NodLayer", "BreathingLayer", "SwayLayer",
           "PainDynamics", "blink_profile", "smoothstep"]

FPS = 25.0


def smoothstep(x: float) -> float:
    """0 below 0, 1 above 1, ``3x^2 - 2x^3`` between (zero slope at both ends)."""
    x = min(1.0, max(0.0, x))
    return x * x * (3.0 - 2.0 * x)


def _rng(seed: int, layer: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 36, int(layer)]))


def _pole(dt: float, tau: float) -> float:
    """Per-step gain of a one-pole filter with time constant ``tau`` (1 when tau <= 0)."""
    return 1.0 if tau <= 0 else 1.0 - math.exp(-dt / tau)


# ============================================================================ gaze
@dataclass(frozen=True)
class GazeSample:
    """One frame of gaze: the eyes' angular offset from the target direction (degrees, yaw + =
    toward the patient's left (+x), pitch + = up) and whether the fixation is on the target."""

    yaw_deg: float
    pitch_deg: float
    on_target: bool


class GazeLayer:
    """Fixations on the target with micro-saccades, broken by aversions.

    On the target for a gamma-distributed interval (mean ``on_s``; shorter while the speaker is
    silent: ``on_silent_s``), micro-saccades every 0.3-1.2 s to a point within ~1 deg of it;
    then an aversion of 6-15 deg (mostly down and to the side, sometimes up) for a log-normal
    interval (median ``aversion_s``, 0.4-3 s). The eyes jump between fixations with a ~20 ms
    time constant (a saccade lasts one to two frames at 25 fps).
    """

    def __init__(self, seed: int = 0, on_s: float = 4.5, on_silent_s: float = 3.3, aversion_s: float = 1.3,
                 fps: float = FPS) -> None:
        self.rng = _rng(seed, 1)
        self.dt = 1.0 / fps
        self.on_s, self.on_silent_s, self.aversion_s = on_s, on_silent_s, aversion_s
        self.t = 0.0
        self.on = True
        self.fix = (0.0, 0.0)  # current fixation offset (deg)
        self.eye = [0.0, 0.0]
        self.state_end = self._on_duration(True)
        self.next_micro = self.t + float(self.rng.uniform(0.3, 1.2))

    def _on_duration(self, speaking: bool) -> float:
        mean = self.on_s if speaking else self.on_silent_s
        return self.t + max(0.8, float(self.rng.gamma(3.0, mean / 3.0)))

    def step(self, speaking: bool = True) -> GazeSample:
        self.t += self.dt
        if self.t >= self.state_end:
            if self.on:  # start an aversion: mostly down-left / down-right / sideways, rarely up
                self.on = False
                ang = float(self.rng.choice([200.0, 240.0, 270.0, 300.0, 340.0, 20.0, 160.0, 90.0],
                                            p=[0.16, 0.16, 0.14, 0.16, 0.14, 0.08, 0.08, 0.08]))
                ang += float(self.rng.uniform(-15.0, 15.0))
                mag = float(self.rng.uniform(6.0, 15.0))
                self.fix = (mag * math.cos(math.radians(ang)), mag * math.sin(math.radians(ang)))
                dur = float(np.clip(self.rng.lognormal(math.log(self.aversion_s), 0.45), 0.4, 3.0))
                self.state_end = self.t + dur
            else:
                self.on = True
                self.fix = (float(self.rng.normal(0.0, 0.3)), float(self.rng.normal(0.0, 0.3)))
                self.state_end = self._on_duration(speaking)
            self.next_micro = self.t + float(self.rng.uniform(0.3, 1.2))
        elif self.t >= self.next_micro:  # micro-saccade around the current fixation
            cy, cp = (0.0, 0.0) if self.on else self.fix
            self.fix = (cy + float(np.clip(self.rng.normal(0.0, 0.4), -1.0, 1.0)),
                        cp + float(np.clip(self.rng.normal(0.0, 0.4), -1.0, 1.0)))
            self.next_micro = self.t + float(self.rng.uniform(0.3, 1.2))
        a = _pole(self.dt, 0.02)
        self.eye[0] += a * (self.fix[0] - self.eye[0])
        self.eye[1] += a * (self.fix[1] - self.eye[1])
        return GazeSample(self.eye[0], self.eye[1], self.on)


# ============================================================================ blinks
def blink_profile(u: float, duration: float, closed: float) -> float:
    """Lid closure (0 open .. 1 shut) ``u`` seconds into a blink lasting ``duration`` s that is
    fully shut for ``closed`` s: a 50 ms smoothstep close, the plateau, a smoothstep opening over
    the rest (opening is slower than closing, as in people)."""
    close = 0.05
    if u < 0.0 or u >= duration:
        return 0.0
    if u < close:
        return smoothstep(u / close)
    if u < close + closed:
        return 1.0
    return 1.0 - smoothstep((u - close - closed) / max(1e-6, duration - close - closed))


class BlinkLayer:
    """Spontaneous blinks: gamma-distributed intervals (rate ``rate_per_min`` x (1 + 0.5 pain)),
    at least 0.6 s apart; at a speaker's pause onset a blink follows 0.1-0.4 s later with
    probability ``pause_blink_p`` (listeners blink at pauses). Each blink lasts 250-400 ms from
    the lid leaving to returning to open, fully shut (>= 0.8 on the eyelid channel) for
    ~130-250 ms (3-6 frames at 25 fps)."""

    def __init__(self, seed: int = 0, rate_per_min: float = 14.0, pause_blink_p: float = 0.4,
                 fps: float = FPS) -> None:
        self.rng = _rng(seed, 2)
        self.dt = 1.0 / fps
        self.rate, self.pause_p = rate_per_min, pause_blink_p
        self.t = 0.0
        self.start = -10.0
        self.duration = 0.3
        self.closed = 0.15
        self.next = self._interval(0.0)

    def _interval(self, pain: float) -> float:
        mean = 60.0 / (self.rate * (1.0 + 0.5 * pain))
        return self.t + max(0.6, float(self.rng.gamma(2.5, mean / 2.5)))

    def step(self, pain: float = 0.0, pause_onset: bool = False) -> float:
        """Lid closure of this frame in [0, 1]."""
        self.t += self.dt
        if pause_onset and self.t - self.start > 0.6 and self.rng.uniform() < self.pause_p:
            self.next = min(self.next, self.t + float(self.rng.uniform(0.1, 0.4)))
        if self.t >= self.next:
            self.start = self.t
            self.closed = float(self.rng.uniform(0.10, 0.20))
            self.duration = 0.05 + self.closed + float(self.rng.uniform(0.10, 0.15))
            self.next = max(self._interval(pain), self.start + self.duration + 0.3)
        return blink_profile(self.t - self.start, self.duration, self.closed)


# ============================================================================ brow raises
class BrowLayer:
    """Brow raises (AU1 + AU2, inner and outer brow raiser) as a listener's backchannel.

    At a speaker's pause onset (the cue arrives when 200 ms of silence are complete) a raise
    starts 0.05-0.3 s later with probability ``pause_p``, at most one per ``refractory_s``: rise
    0.15-0.25 s (smoothstep), hold 0.2-0.6 s, fall 0.4-0.7 s, apex ``U(0.4, 0.65)`` of full
    intensity (AU 2-3.3 on the 0-5 scale). Nothing without pauses: a raise answers speech.
    Returns the raise in [0, 1] of full intensity.
    """

    def __init__(self, seed: int = 0, pause_p: float = 0.25, refractory_s: float = 4.0, fps: float = FPS) -> None:
        self.rng = _rng(seed, 6)
        self.dt = 1.0 / fps
        self.pause_p, self.refractory = float(pause_p), float(refractory_s)
        self.t = 0.0
        self.raise_: tuple[float, float, float, float, float] | None = None  # start, rise, hold, fall, amp

    def step(self, pause_onset: bool = False) -> float:
        self.t += self.dt
        if pause_onset:
            u, delay = float(self.rng.uniform()), float(self.rng.uniform(0.05, 0.3))
            shape = (float(self.rng.uniform(0.15, 0.25)), float(self.rng.uniform(0.2, 0.6)),
                     float(self.rng.uniform(0.4, 0.7)), float(self.rng.uniform(0.4, 0.65)))
            free = self.raise_ is None or self.t - self.raise_[0] >= self.refractory
            if free and u < self.pause_p:
                self.raise_ = (self.t + delay, *shape)
        if self.raise_ is None:
            return 0.0
        start, rise, hold, fall, amp = self.raise_
        v = self.t - start
        if v < 0 or v >= rise + hold + fall:
            return 0.0
        if v < rise:
            return amp * smoothstep(v / rise)
        if v < rise + hold:
            return amp
        return amp * (1.0 - smoothstep((v - rise - hold) / fall))


# ============================================================================ backchannel nods
class NodLayer:
    """Head nods as a listener's backchannel, started when the speaker pauses.

    At a speaker's pause onset (the cue arrives when 200 ms of silence are complete) a nod is
    planned ``U(delay_s)`` s later (a listener's reaction time) with probability ``pause_p``, at most
    one per ``refractory_s`` and none while one runs: the head goes down by ``U(3, 6)`` deg in
    0.15-0.25 s (smoothstep) and comes back up in 0.25-0.45 s. Listeners answer pauses with nods
    (Ward & Tsukahara 2000; Gratch et al.'s Rapport Agent 2006 nods at the speaker's pauses).
    Nothing without pauses. Returns the nod's head pitch in degrees (+ = face down).
    """

    def __init__(self, seed: int = 0, pause_p: float = 0.3, refractory_s: float = 2.0,
                 delay_s: tuple[float, float] = (0.15, 0.45), fps: float = FPS) -> None:
        self.rng = _rng(seed, 7)
        self.dt = 1.0 / fps
        self.pause_p, self.refractory = float(pause_p), float(refractory_s)
        self.delay = (float(delay_s[0]), float(delay_s[1]))
        self.t = 0.0
        self.nod: tuple[float, float, float, float] | None = None  # start, down, up, amplitude (deg)

    def step(self, pause_onset: bool = False) -> float:
        self.t += self.dt
        if pause_onset:  # every draw at every cue, taken or not: determinism under switches
            u, delay = float(self.rng.uniform()), float(self.rng.uniform(*self.delay))
            shape = (float(self.rng.uniform(0.15, 0.25)), float(self.rng.uniform(0.25, 0.45)),
                     float(self.rng.uniform(3.0, 6.0)))
            free = self.nod is None or self.t - self.nod[0] >= max(self.refractory, self.nod[1] + self.nod[2])
            if free and u < self.pause_p:
                self.nod = (self.t + delay, *shape)
        if self.nod is None:
            return 0.0
        start, down, up, amp = self.nod
        v = self.t - start
        if v < 0 or v >= down + up:
            return 0.0
        if v < down:
            return amp * smoothstep(v / down)
        return amp * (1.0 - smoothstep((v - down) / up))


# ============================================================================ breathing
class BreathingLayer:
    """Quiet breathing: a rate drawn once in [rate_lo, rate_hi] per minute (+ 4 / min at pain 1),
    each cycle's period jittered +-10 %; inhale 40 % of the cycle, exhale 60 % (both smooth).
    Returns the chest filling in [0, 1] (0 exhaled, 1 inhaled)."""

    def __init__(self, seed: int = 0, rate_lo: float = 13.0, rate_hi: float = 17.0, fps: float = FPS) -> None:
        self.rng = _rng(seed, 3)
        self.dt = 1.0 / fps
        self.rate = float(self.rng.uniform(rate_lo, rate_hi))
        self.phase = float(self.rng.uniform(0.0, 1.0))
        self.period = self._period(0.0)

    def _period(self, pain: float) -> float:
        return 60.0 / (self.rate + 4.0 * pain) * float(self.rng.uniform(0.9, 1.1))

    def step(self, pain: float = 0.0) -> float:
        self.phase += self.dt / self.period
        if self.phase >= 1.0:
            self.phase -= 1.0
            self.period = self._period(pain)
        u = self.phase
        if u < 0.4:
            return 0.5 - 0.5 * math.cos(math.pi * u / 0.4)
        return 0.5 + 0.5 * math.cos(math.pi * (u - 0.4) / 0.6)


# ============================================================================ idle sway
class SwayLayer:
    """Idle head sway: per axis a sum of three sinusoids of 0.04-0.3 Hz with random phases whose
    standard deviation is exactly ``std_deg`` (pitch, yaw, roll) degrees; plus a body sway of the
    same kind in x and z (``std_mm`` millimetres). A function of time only: stateless given the
    seed. The pitch sway is the smallest (0.25 deg): idle pitch wander at a nod's time scale blurs
    the onsets of the backchannel nods (measured on the tuning speech, docs/behaviour.md)."""

    def __init__(self, seed: int = 0, std_deg: tuple[float, float, float] = (0.25, 0.7, 0.35),
                 std_mm: float = 2.0, fps: float = FPS) -> None:
        rng = _rng(seed, 4)
        self.dt = 1.0 / fps
        self.t = 0.0
        stds = list(std_deg) + [std_mm, std_mm]
        self.freq = rng.uniform(0.04, 0.3, size=(5, 3))
        self.phase = rng.uniform(0.0, 2 * math.pi, size=(5, 3))
        w = rng.uniform(0.5, 1.0, size=(5, 3))
        # sum of sinusoids with amplitudes a_k has variance sum(a_k^2) / 2
        self.amp = w * (np.asarray(stds)[:, None] * math.sqrt(2.0) / np.sqrt((w ** 2).sum(axis=1, keepdims=True)))

    def step(self) -> np.ndarray:
        """(5,): pitch, yaw, roll in degrees, then x, z in millimetres."""
        self.t += self.dt
        return (self.amp * np.sin(2 * math.pi * self.freq * self.t + self.phase)).sum(axis=1)


# ============================================================================ pain
class PainDynamics:
    """Pain shown over time from the instructor's level ``L(t)``.

    ``p(t) = clip(b(t) + f(t), 0, 1)``: the background ``b`` follows ``background x L`` with a
    ~0.1 s time constant (a level change shows within 0.3 s, down as well as up); flares arrive
    as a Poisson process of rate ``flare_rate_per_min x L``, one at a time, each with its own
    envelope: onset 0.3-0.8 s (smoothstep, so the apex comes within ~1 s), hold 0.5-2 s, easing
    1.5-4 s; apex amplitude ``L x U(0.3, 0.6)``, fixed at the onset. A flare never exceeds
    0.6 x the current background, so a drop of the level to 0 ends it as fast as the background.
    With flares off, ``p`` is the smoothed level itself (background 1).
    """

    def __init__(self, seed: int = 0, flares: bool = True, flare_rate_per_min: float = 3.0,
                 background: float = 0.85, tau_s: float = 0.1, fps: float = FPS) -> None:
        self.rng = _rng(seed, 5)
        self.dt = 1.0 / fps
        self.flares = bool(flares)
        self.rate = float(flare_rate_per_min)
        self.bg_factor = float(background) if self.flares else 1.0
        self.tau = float(tau_s)
        self.t = 0.0
        self.bg: float | None = None
        self.flare: tuple[float, float, float, float, float] | None = None  # start, onset, hold, ease, amp
        self.in_flare = False

    def envelope(self) -> float:
        if self.flare is None:
            return 0.0
        start, onset, hold, ease, amp = self.flare
        u = self.t - start
        if u < onset:
            return amp * smoothstep(u / onset)
        if u < onset + hold:
            return amp
        return amp * (1.0 - smoothstep((u - onset - hold) / ease))

    def step(self, level: float) -> float:
        self.t += self.dt
        target = self.bg_factor * level
        self.bg = target if self.bg is None else self.bg + _pole(self.dt, self.tau) * (target - self.bg)
        if self.flares:
            if self.flare is not None and self.t - self.flare[0] >= sum(self.flare[1:4]):
                self.flare = None
            if self.flare is None and level > 0 and self.rng.uniform() < self.rate * level * self.dt / 60.0:
                self.flare = (self.t, float(self.rng.uniform(0.3, 0.8)), float(self.rng.uniform(0.5, 2.0)),
                              float(self.rng.uniform(1.5, 4.0)), level * float(self.rng.uniform(0.3, 0.6)))
        f = min(self.envelope(), 0.6 * self.bg) if self.flares else 0.0
        self.in_flare = f > 0.0
        return min(1.0, max(0.0, self.bg + f))
