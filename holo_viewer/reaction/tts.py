"""Text-to-speech speakers for the reaction model's training data: espeak-ng voices in rooms.

A clip is a sequence of sentences from a seeded text generator (a clinician's questions and
remarks, and read prose), spoken by one espeak-ng voice (language variant x voice variant) at a
drawn rate, pitch and word gap, separated by pauses of 0.25-1.5 s, then passed through what a
microphone in a room adds: a room reverberation (exponentially decaying noise, RT60 0.15-0.7 s,
half the clips), a microphone band (high-pass 80-300 Hz, low-pass 3.4-7.5 kHz, half the clips),
noise (white, pink or brown at 5-35 dB SNR, 70 % of the clips) and a gain (peak -30 to -1 dBFS).
espeak-ng (GPL-3, Debian package ``espeak-ng``) runs as a subprocess; nothing is downloaded.
Everything is drawn from the caller's generator, and espeak-ng is deterministic, so a clip is the
same on every run of the same espeak-ng version.
"""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
from scipy.signal import butter, fftconvolve, resample_poly, sosfilt

from ..errors import ReactionError

__all__ = ["TRAIN_VOICES", "HELD_OUT_VOICES", "espeak_available", "synthesize", "sentence", "tts_clip",
           "room_augment"]

SAMPLE_RATE = 16000
_LANGS = ("en-us", "en-gb", "en-gb-scotland", "en-029", "en-gb-x-rp", "en-gb-x-gbclan")
_TRAIN_VARIANTS = ("m1", "m2", "m4", "m5", "m6", "m7", "f1", "f3", "f4", "f5")
#: voices the training data draws from (language + variant)
TRAIN_VOICES: tuple[str, ...] = tuple(f"{lang}+{v}" for lang in _LANGS for v in _TRAIN_VARIANTS)
#: voices kept out of training (their variants m3, f2 are never drawn): the benchmark's TTS voices
HELD_OUT_VOICES: tuple[str, ...] = ("en-us+m3", "en-gb+f2")

_WORDS = {
    "when": ("when", "exactly when", "about what time", "roughly when"),
    "time": ("right now", "at the moment", "this morning", "when you move", "at night", "since yesterday"),
    "action": ("breathe in deeply", "lift your arm", "turn your head", "stand up", "cough", "bend forward",
               "walk", "lie on your side"),
    "proc": ("press gently on your stomach", "check your blood pressure", "listen to your chest",
             "look at the wound", "change the dressing", "move your leg a little", "take a small blood sample"),
    "reassure": ("tell me if it hurts", "it will only take a moment", "just relax if you can",
                 "you're doing really well", "we'll go slowly"),
    "drug": ("paracetamol", "ibuprofen", "anything from the pharmacy", "the tablets your doctor gave you"),
    "part": ("back", "knee", "shoulder", "chest", "stomach", "left hand", "ankle", "neck"),
    "ack": ("Okay.", "I see.", "Right.", "Thank you.", "That's helpful.", "Alright."),
    "name": ("Sarah", "David", "Anna", "Michael", "Priya", "Tom", "Grace", "Omar"),
    "city": ("the old town", "the valley", "Edinburgh", "the harbour", "the village", "the north"),
    "adj": ("so cold", "unusually warm", "grey and quiet", "bright", "wet and windy", "still"),
    "season": ("winter", "spring", "summer", "autumn", "year"),
    "place": ("river", "cliffs", "canal", "shore", "main road", "old railway"),
    "person": ("my grandmother", "the doctor", "her brother", "an old friend", "the neighbour", "the teacher"),
    "thing": ("a letter", "the news", "a small parcel", "the keys", "some bread", "a photograph"),
}
_TEMPLATES = (
    "Hello, I'm {name}, and I'll be looking after you today.",
    "Can you tell me {when} the pain started?",
    "On a scale from one to ten, how bad is it {time}?",
    "Does it hurt more when you {action}?",
    "I'm going to {proc} now. {reassure}.",
    "Have you taken anything for it, like {drug}?",
    "{ack} Let me have a look at your {part}.",
    "Is the pain sharp, or is it more of a dull ache?",
    "{ack} And does it spread anywhere, to your {part} for example?",
    "Have you had anything like this before?",
    "Could you {action} for me, please?",
    "{ack} We'll give you something for the pain, and I'll come back in a few minutes.",
    "When did you last eat or drink anything?",
    "The weather in {city} was {adj} that {season}, and we walked along the {place} until evening.",
    "{person} came by with {thing}, but nobody was home.",
    "It was late when {person} finally arrived, tired, and a little worried.",
    "We had not expected {thing}, so for a while nobody said anything at all.",
    "By the end of the {season}, the road along the {place} was closed again.",
)


def espeak_available() -> bool:
    """True when the ``espeak-ng`` program is on PATH."""
    return shutil.which("espeak-ng") is not None


def sentence(rng: np.random.Generator) -> str:
    """One sentence from the templates with drawn fillers."""
    t = _TEMPLATES[int(rng.integers(len(_TEMPLATES)))]
    out = t
    for key, choices in _WORDS.items():
        while "{" + key + "}" in out:
            out = out.replace("{" + key + "}", choices[int(rng.integers(len(choices)))], 1)
    return out


def synthesize(text: str, voice: str, rate: int = 160, pitch: int = 50, word_gap: int = 0) -> np.ndarray:
    """espeak-ng speech of ``text`` at 16 kHz, float32 in [-1, 1].

    Raises
    ------
    ReactionError
        espeak-ng missing (install the Debian package ``espeak-ng``) or failing.
    """
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise ReactionError("espeak-ng: program not found; the reaction model's training data needs it "
                            "(apt-get install espeak-ng; scripts/setup.sh installs it)")
    cmd = [exe, "-v", voice, "-s", str(int(rate)), "-p", str(int(pitch)), "-g", str(int(word_gap)), "--stdout", text]
    try:
        res = subprocess.run(cmd, capture_output=True, timeout=60, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ReactionError(f"espeak-ng: could not run {cmd[:8]} ({exc})") from exc
    raw = res.stdout
    if res.returncode != 0 or len(raw) < 46 or raw[:4] != b"RIFF":
        raise ReactionError(f"espeak-ng -v {voice}: expected a WAV on stdout, found {len(raw)} bytes, exit "
                            f"{res.returncode}: {res.stderr[:200]!r}")
    sr = int.from_bytes(raw[24:28], "little")
    pcm = np.frombuffer(raw[44:44 + (len(raw) - 44) // 2 * 2], dtype="<i2").astype(np.float64) / 32768.0
    if sr != SAMPLE_RATE:
        g = np.gcd(SAMPLE_RATE, sr)
        pcm = resample_poly(pcm, SAMPLE_RATE // g, sr // g)
    return pcm.astype(np.float32)


def _colored_noise(rng: np.random.Generator, n: int, kind: str) -> np.ndarray:
    w = rng.standard_normal(n)
    if kind == "white":
        x = w
    else:
        spec = np.fft.rfft(w)
        f = np.maximum(np.fft.rfftfreq(n, 1.0 / SAMPLE_RATE), 20.0)
        spec /= f ** (0.5 if kind == "pink" else 1.0)
        x = np.fft.irfft(spec, n)
    return x / (x.std() + 1e-12)


def room_augment(rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
    """Reverberation, microphone band, noise and gain (see the module docstring), float32."""
    y = np.asarray(x, dtype=np.float64)
    n = y.shape[0]
    if rng.random() < 0.5:
        rt60 = rng.uniform(0.15, 0.7)
        m = int(rt60 * SAMPLE_RATE)
        t = np.arange(m) / SAMPLE_RATE
        rir = rng.standard_normal(m) * np.exp(-6.9 * t / rt60)  # -60 dB at rt60
        rir *= rng.uniform(0.1, 0.6) / np.sqrt(np.sum(rir ** 2))
        rir[0] = 1.0
        y = fftconvolve(y, rir)[:n]
    if rng.random() < 0.5:
        hp = butter(2, rng.uniform(80.0, 300.0), "highpass", fs=SAMPLE_RATE, output="sos")
        lp = butter(4, rng.uniform(3400.0, 7500.0), "lowpass", fs=SAMPLE_RATE, output="sos")
        y = sosfilt(lp, sosfilt(hp, y))
    if rng.random() < 0.7:
        kind = ("white", "pink", "brown")[int(rng.integers(3))]
        active = y[np.abs(y) > 0.05 * np.abs(y).max()] if np.abs(y).max() > 0 else y
        p_sig = float(np.mean(active ** 2)) if active.size else 1e-6
        snr = rng.uniform(5.0, 35.0)
        y = y + _colored_noise(rng, n, kind) * np.sqrt(p_sig / 10 ** (snr / 10.0))
    peak = np.abs(y).max()
    if peak > 0:
        y = y / peak * 10 ** (rng.uniform(-30.0, -1.0) / 20.0)
    return y.astype(np.float32)


def tts_clip(rng: np.random.Generator, seconds: float, voices=TRAIN_VOICES, augment: bool = True) -> tuple[np.ndarray, str]:
    """A clip of ``seconds`` (16 kHz, exactly ``round(seconds * 16000)`` samples) and the voice used.

    Sentences with pauses of 0.25-1.5 s between them (and 0-0.6 s of silence before the first),
    one voice (drawn from ``voices``) at a rate of 120-200 words per minute, pitch 25-75 and word gap
    0-40 ms, then :func:`room_augment` when ``augment``.
    """
    n = int(round(seconds * SAMPLE_RATE))
    voice = voices[int(rng.integers(len(voices)))]
    rate, pitch, gap = int(rng.integers(120, 201)), int(rng.integers(25, 76)), int(rng.integers(0, 5))
    parts = [np.zeros(int(rng.uniform(0.0, 0.6) * SAMPLE_RATE), np.float32)]
    total = parts[0].shape[0]
    while total < n:
        s = synthesize(sentence(rng), voice, rate, pitch, gap)
        nz = np.flatnonzero(np.abs(s) > 1e-3)
        s = s[nz[0]:nz[-1] + 1] if nz.size else s  # espeak-ng pads with silence: the drawn pauses set it
        pause = np.zeros(int(rng.uniform(0.25, 1.5) * SAMPLE_RATE), np.float32)
        parts += [s, pause]
        total += s.shape[0] + pause.shape[0]
    x = np.concatenate(parts)[:n]
    x = 0.9 * x / max(float(np.abs(x).max()), 1e-9)
    return (room_augment(rng, x) if augment else x.astype(np.float32)), voice
