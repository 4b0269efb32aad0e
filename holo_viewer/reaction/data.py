"""Seeded synthetic dyadic dataset (speaker audio + faces, listener reactions, pain).

Everything is generated from ``SyntheticConfig.seed``: the same config gives the same arrays
bit for bit. The generative story (docs/reaction.md, "Synthetic data") in short:

* **Speaker.** Alternating talk (1.0-2.8 s) and pause (0.4-1.2 s) segments. During talk a
  syllable envelope (3.5-5.5 Hz, random syllable strengths) modulates a harmonic voice
  whose pitch ``f0`` (95-220 Hz per speaker) has slow drift, declination per phrase and pitch
  accents; the harmonics are shaped by a mouth-opening formant; breath noise is added.
  16 kHz mono. The face moves with the speech: AU25/AU26 and the jaw follow the envelope,
  brows (AU1/AU2) rise on pitch accents, smile (AU6/AU12) and frown (AU4/AU15) episodes,
  head pitch bobs with speech energy, slow head sway.
* **Listeners.** Each speaker context is heard by several listeners (``listeners_per_context``),
  each with a style and a lag ``L ~ U(0.2, 1.0) s`` (per cue ``L + U(-J, J)`` reflected into
  [0.2, 1.0] s when ``cue_lag_jitter_s`` J > 0):
  ``mirror`` (smile and brows copy the speaker's, delayed by L), ``backchannel`` (at each
  pause onset + L a head nod with p = 0.85 and a smile with p = 0.7, ``cue_smile_prob``), ``mixed`` (0.6 x both).
  All listeners of one context are mutually appropriate: the neighbour matrix is 1 where two
  clips share the speaker context.
* **Pain.** Each clip has a pain level ``p`` (0 with probability ``pain_zero_fraction``, else
  U(0, 1)); the listener's AUs are the element-wise max of the reaction AUs and
  ``pain_aus(p(t))`` with ``p(t) = p (0.85 + 0.15 s(t))`` for a slow ``s(t)`` in [0, 1].

Per-frame features at 25 fps are face states (:mod:`holo_viewer.reaction.features`); the
25-D REACT attributes come from :func:`~holo_viewer.reaction.features.attributes_from_state`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..errors import ReactionError
from .audio import AudioConfig, log_mel
from .features import FPS, attributes_from_state, au_scales

__all__ = ["SyntheticConfig", "ReactionSplit", "STYLES", "make_synthetic_split", "make_synthetic_dataset",
           "synth_speaker", "SpeakerClip", "tts_speaker", "listener_cues", "audio_features", "check_data_kinds",
           "VOICES", "AUDIO_FEATURES"]

STYLES: tuple[str, ...] = ("mirror", "backchannel", "mixed")
_SPLIT_IDS = {"train": 0, "val": 1, "test": 2}


@dataclass(frozen=True)
class SyntheticConfig:
    """Size and seed of the synthetic dataset (defaults: the shipped checkpoint's data)."""

    seed: int = 0
    seconds: float = 10.0
    train_contexts: int = 60
    val_contexts: int = 8
    test_contexts: int = 12
    listeners_per_context: int = 4
    pain_zero_fraction: float = 0.25
    audio: AudioConfig = field(default_factory=AudioConfig)
    #: speaker voices: "harmonic" (the synthetic voice below) or "tts" (espeak-ng voices in rooms,
    #: :mod:`.tts`, listeners reacting to the pauses and low-pitch regions detected in that audio)
    voices: str = "harmonic"
    #: what the model hears: "log_mel" (:func:`.audio.log_mel`) or "speech" (:func:`.speech.speech_features`)
    audio_features: str = "log_mel"
    #: tts voices: the share of speaker contexts whose face stays still (as a user's still video)
    still_face_fraction: float = 0.5
    #: backchannel timing spread within one listener, seconds: 0 = every cue answered at the listener's
    #: own lag L; J > 0 = each cue's lag is L + U(-J, J), reflected into [0.2, 1.0] s (people's
    #: backchannels vary from cue to cue as well as between listeners: Blomsma et al. 2024)
    cue_lag_jitter_s: float = 0.0
    #: probability that a backchannel listener smiles at a cue (a nod: 0.85)
    cue_smile_prob: float = 0.7

    @property
    def n_frames(self) -> int:
        """Frames per clip (25 fps)."""
        return int(round(self.seconds * FPS))

    def contexts(self, split: str) -> int:
        """Number of speaker contexts of a split."""
        return {"train": self.train_contexts, "val": self.val_contexts, "test": self.test_contexts}[split]


@dataclass(frozen=True)
class SpeakerClip:
    """One synthetic speaker: waveform, face states and the latent signals listeners react to."""

    waveform: np.ndarray  # (L,) float32, 16 kHz
    state: np.ndarray  # (T, S) face states
    talking: np.ndarray  # (T,) bool
    pause_onsets: np.ndarray  # (P,) frame indices where a pause starts
    smile: np.ndarray  # (T,) in [0, 1]
    brow: np.ndarray  # (T,) in [0, 1]


@dataclass(frozen=True)
class ReactionSplit:
    """One split of a dyadic dataset; clip ``i`` pairs speaker context ``context[i]`` with a listener.

    Attributes
    ----------
    name : str
    au_names : tuple of str
        AU order of the face states.
    audio : numpy.ndarray, shape (C, T, n_mels) float32
        Speaker log-mel frames per speaker context.
    context : numpy.ndarray, shape (N,) int
    speaker_state, listener_state : numpy.ndarray, shape (N, T, S) float32
    speaker_attr, listener_attr : numpy.ndarray, shape (N, T, 25) float32
    pain : numpy.ndarray, shape (N,) float32, requested pain level in [0, 1]
    neighbour : numpy.ndarray, shape (N, N) int8, 1 = appropriate (diagonal 1)
    style : tuple of str, length N
    lag_s : numpy.ndarray, shape (N,) float32, listener lag in seconds
    waveforms : numpy.ndarray or None, shape (C, L) float32, speaker audio per context
    """

    name: str
    au_names: tuple[str, ...]
    audio: np.ndarray
    context: np.ndarray
    speaker_state: np.ndarray
    listener_state: np.ndarray
    speaker_attr: np.ndarray
    listener_attr: np.ndarray
    pain: np.ndarray
    neighbour: np.ndarray
    style: tuple[str, ...]
    lag_s: np.ndarray
    waveforms: np.ndarray | None = None

    @property
    def n_clips(self) -> int:
        """Number of clips N."""
        return int(self.context.shape[0])

    @property
    def n_frames(self) -> int:
        """Frames per clip T."""
        return int(self.listener_state.shape[1])

    def clip_audio(self) -> np.ndarray:
        """Per-clip speaker log-mel, shape (N, T, n_mels)."""
        return self.audio[self.context]


# ---------------------------------------------------------------------------------------------
def _slow(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    """Smooth noise with unit standard deviation (Gaussian-filtered white noise, sigma in samples)."""
    x = gaussian_filter1d(rng.standard_normal(n + int(6 * sigma)), sigma)[int(3 * sigma):int(3 * sigma) + n]
    return x / (x.std() + 1e-12)


def _bumps(t: np.ndarray, starts, durations, amps) -> np.ndarray:
    """Sum of raised-sine bumps ``a sin^2(pi (t - s) / d)`` on ``[s, s + d]``."""
    out = np.zeros_like(t)
    for s, d, a in zip(starts, durations, amps):
        m = (t >= s) & (t < s + d)
        out[m] += a * np.sin(np.pi * (t[m] - s) / d) ** 2
    return out


def _episodes(rng, seconds: float, rate: float, dur: tuple[float, float], amp: tuple[float, float]):
    n = rng.poisson(rate * seconds)
    starts = rng.uniform(-1.0, seconds, n)
    return starts, rng.uniform(*dur, n), rng.uniform(*amp, n)


def _segments(rng, seconds: float) -> list[tuple[float, float]]:
    """Talk segments (start, end) in seconds, separated by pauses."""
    segs, t = [], rng.uniform(0.0, 0.6)
    while t < seconds:
        d = rng.uniform(1.0, 2.8)
        segs.append((t, min(t + d, seconds)))
        t += d + rng.uniform(0.4, 1.2)
    return segs


def _set_aus(state: np.ndarray, au_names, values: dict[str, np.ndarray]) -> None:
    idx = {n: i for i, n in enumerate(au_names)}
    scales = au_scales(au_names)
    for n, v in values.items():
        if n not in idx:
            raise ReactionError(f"au_map.names: the AU map lacks {n}, needed by the synthetic data; "
                                f"found {list(au_names)}")
        state[:, idx[n]] = np.maximum(state[:, idx[n]], np.clip(v, 0.0, None) / scales[idx[n]])


def synth_speaker(rng: np.random.Generator, config: SyntheticConfig, au_names, jaw_unit: np.ndarray) -> SpeakerClip:
    """Generate one speaker: speech-like waveform and a face that moves with it.

    Parameters
    ----------
    rng : numpy.random.Generator
    config : SyntheticConfig
    au_names : sequence of str
        AU order of the face state.
    jaw_unit : numpy.ndarray, shape (3,)
        Jaw pose (axis-angle) of a fully open mouth; the jaw is ``openness * jaw_unit``.
    """
    ac = config.audio
    T, sr, hop = config.n_frames, ac.sample_rate, ac.hop
    L = T * hop
    ts = np.arange(L) / sr
    segs = _segments(rng, config.seconds)
    talk = np.zeros(L)
    for s, e in segs:
        talk[(ts >= s) & (ts < e)] = 1.0
    ramp = np.hanning(int(0.04 * sr))
    talk_s = np.convolve(talk, ramp / ramp.sum(), mode="same")
    # syllables: slowly varying rate, random strengths
    f_syl = rng.uniform(3.5, 5.5) * (1.0 + 0.15 * _slow(rng, L // 160, 40.0).repeat(160)[:L])
    ph = 2 * np.pi * np.cumsum(f_syl) / sr
    strength = np.interp(ph / (2 * np.pi), np.arange(int(ph[-1] / (2 * np.pi)) + 2),
                         rng.uniform(0.35, 1.0, int(ph[-1] / (2 * np.pi)) + 2))
    env = ((0.5 - 0.5 * np.cos(ph)) ** 1.5) * strength * talk_s
    # pitch: speaker base, slow drift, declination per phrase, accents (which also raise the brows)
    base = rng.uniform(95.0, 220.0)
    drift = 0.08 * _slow(rng, L // 160, 60.0).repeat(160)[:L]
    decl = np.zeros(L)
    acc_t, acc_d, acc_a = [], [], []
    for s, e in segs:
        m = (ts >= s) & (ts < e)
        decl[m] = -0.12 * (ts[m] - s) / max(e - s, 1e-3)
        for _ in range(rng.poisson(0.5 * (e - s)) + 1):
            acc_t.append(rng.uniform(s, max(s, e - 0.3)))
            acc_d.append(0.45)
            acc_a.append(rng.uniform(0.5, 1.0))
    accent = _bumps(ts, acc_t, acc_d, acc_a)
    f0 = base * (1.0 + drift + decl + 0.25 * accent)
    phase = 2 * np.pi * np.cumsum(f0) / sr
    f1 = 300.0 + 550.0 * np.clip(env, 0, 1)
    f2 = 1300.0 + 400.0 * _slow(rng, L // 160, 30.0).repeat(160)[:L]
    wave = np.zeros(L)
    for h in range(1, 21):
        fh = h * f0
        amp = (1.0 / h) * (1.0 + 3.0 * np.exp(-((fh - f1) / 150.0) ** 2) + 2.0 * np.exp(-((fh - f2) / 250.0) ** 2))
        amp = np.where(fh < 0.45 * sr, amp, 0.0)
        wave += amp * np.sin(h * phase)
    wave = env * wave + 0.3 * env * rng.standard_normal(L) + 0.01 * rng.standard_normal(L)
    wave = (0.9 * wave / (np.abs(wave).max() + 1e-9)).astype(np.float32)

    # face at 25 fps
    tf = np.arange(T) / FPS
    open_ = np.clip(env.reshape(T, hop).mean(axis=1) / 0.45, 0.0, 1.0)
    talking = talk.reshape(T, hop).mean(axis=1) > 0.5
    onsets = np.flatnonzero(talking[:-1] & ~talking[1:]) + 1
    smile = np.clip(_bumps(tf, *_episodes(rng, config.seconds, 0.15, (1.5, 3.5), (0.4, 1.0))), 0, 1)
    brow = np.clip(_bumps(tf, np.asarray(acc_t) - 0.05, np.full(len(acc_t), 0.8), acc_a), 0, 1)
    frown = np.clip(_bumps(tf, *_episodes(rng, config.seconds, 0.05, (1.0, 2.5), (0.3, 0.8))), 0, 1)
    S = len(au_names) + 6
    state = np.zeros((T, S))
    noise = lambda: 0.08 * np.abs(_slow(rng, T, 2.0))  # noqa: E731
    _set_aus(state, au_names, {
        "AU25": 4.0 * np.minimum(1.0, 1.5 * open_), "AU26": 3.5 * open_,
        "AU12": 4.0 * smile + noise(), "AU6": 2.5 * smile, "AU1": 3.0 * brow + noise(), "AU2": 2.5 * brow,
        "AU4": 2.0 * frown + noise(), "AU15": 1.2 * frown,
    })
    n_au = len(au_names)
    state[:, n_au:n_au + 3] = open_[:, None] * jaw_unit[None, :]
    bob = gaussian_filter1d(open_, 2.0)
    state[:, n_au + 3] = 0.06 * bob + 0.03 * _slow(rng, T, 12.0)
    state[:, n_au + 4] = 0.10 * _slow(rng, T, 25.0)
    state[:, n_au + 5] = 0.03 * _slow(rng, T, 25.0)
    return SpeakerClip(wave, state.astype(np.float32), talking, onsets, smile, brow)


def _pain_table(au_names) -> tuple[np.ndarray, np.ndarray]:
    """``pain_aus(p)`` tabulated on p = 0, 0.05, ..., 1 for every AU of ``au_names`` (intensity units)."""
    from ..flame.expressions import pain_aus

    grid = np.linspace(0.0, 1.0, 21)
    table = np.zeros((grid.size, len(au_names)))
    for i, p in enumerate(grid):
        aus = pain_aus(float(p))
        for j, n in enumerate(au_names):
            table[i, j] = float(aus.get(n, 0.0))
    return grid, table


#: the rule listeners' backchannel lag after a cue, seconds (people: 0.2-1.0 s, Ward & Tsukahara 2000)
LAG_RANGE_S = (0.2, 1.0)


def cue_lags(lag_s: float, n: int, jitter_s: float, rng: np.random.Generator | None) -> np.ndarray:
    """Per-cue backchannel lags (n,) of a listener with lag ``lag_s``: all ``lag_s`` when ``jitter_s`` is 0,
    else ``lag_s + U(-jitter_s, jitter_s)`` reflected into [LAG_RANGE_S] (so a listener's mean stays near
    its own lag and the pooled lags stay spread over the whole range)."""
    lo, hi = LAG_RANGE_S
    if jitter_s <= 0 or n == 0:
        return np.full(n, float(lag_s))
    x = lag_s + rng.uniform(-jitter_s, jitter_s, n) - lo
    w = hi - lo
    x = np.mod(x, 2 * w)
    return lo + np.where(x > w, 2 * w - x, x)


def _listener(rng, sp: SpeakerClip, style: str, lag_s: float, pain: float, config: SyntheticConfig,
              au_names, pain_grid, pain_table, jitter_rng: np.random.Generator | None = None) -> np.ndarray:
    T = config.n_frames
    tf = np.arange(T) / FPS
    lag = int(round(lag_s * FPS))
    shifted = lambda x: np.concatenate([np.zeros(lag), x[:T - lag]])  # noqa: E731
    smile = 0.02 * np.abs(_slow(rng, T, 6.0))
    brow = 0.02 * np.abs(_slow(rng, T, 6.0))
    pitch = 0.01 * _slow(rng, T, 15.0)
    w_m, w_b = {"mirror": (1.0, 0.0), "backchannel": (0.0, 1.0), "mixed": (0.6, 0.6)}[style]
    if w_m > 0:
        g = rng.uniform(0.7, 1.0)
        smile = smile + w_m * g * shifted(sp.smile)
        brow = brow + w_m * 0.7 * shifted(sp.brow)
    if w_b > 0:
        t0 = sp.pause_onsets / FPS + cue_lags(lag_s, sp.pause_onsets.size, config.cue_lag_jitter_s, jitter_rng)
        nod = rng.random(t0.size) < 0.85
        smi = rng.random(t0.size) < config.cue_smile_prob
        pitch = pitch + w_b * _bumps(tf, t0[nod], np.full(nod.sum(), 0.8), rng.uniform(0.08, 0.15, nod.sum()))
        smile = smile + w_b * _bumps(tf, t0[smi], np.full(smi.sum(), 1.6), rng.uniform(0.5, 0.9, smi.sum()))
    smile, brow = np.clip(smile, 0, 1), np.clip(brow, 0, 1)
    S = len(au_names) + 6
    state = np.zeros((T, S))
    _set_aus(state, au_names, {"AU12": 4.0 * smile, "AU6": 2.5 * smile, "AU1": 3.0 * brow, "AU2": 2.5 * brow})
    p_t = pain * (0.85 + 0.15 * (0.5 + 0.5 * np.tanh(_slow(rng, T, 20.0))))
    scales = au_scales(au_names)
    for j in range(len(au_names)):
        state[:, j] = np.maximum(state[:, j], np.interp(p_t, pain_grid, pain_table[:, j]) / scales[j])
    n_au = len(au_names)
    state[:, n_au + 3] = pitch
    state[:, n_au + 4] = 0.03 * _slow(rng, T, 25.0)
    return state.astype(np.float32)


VOICES: tuple[str, ...] = ("harmonic", "tts")
AUDIO_FEATURES: tuple[str, ...] = ("log_mel", "speech")


def check_data_kinds(config: SyntheticConfig, source: str = "config") -> None:
    """Raise :class:`ReactionError` unless ``voices`` / ``audio_features`` name known kinds."""
    if config.voices not in VOICES:
        raise ReactionError(f"{source}: data.voices: expected one of {list(VOICES)}, found {config.voices!r}")
    if config.audio_features not in AUDIO_FEATURES:
        raise ReactionError(f"{source}: data.audio_features: expected one of {list(AUDIO_FEATURES)}, "
                            f"found {config.audio_features!r}")


def audio_features(waveform: np.ndarray, config: SyntheticConfig, speech: np.ndarray | None = None) -> np.ndarray:
    """What the model hears of a clip, (T, F) float32: log-mel or the speech channels (``config.audio_features``)."""
    if config.audio_features == "speech":
        from .speech import speech_features

        f = speech if speech is not None else speech_features(waveform, config.audio.sample_rate, config.n_frames)
        return np.asarray(f, dtype=np.float32)
    return log_mel(waveform, config.audio.sample_rate, config.n_frames, config.audio).numpy()


def listener_cues(speech: np.ndarray, min_gap_s: float = 1.5) -> np.ndarray:
    """Frames a listener reacts to: every pause onset, plus low-pitch cues at least ``min_gap_s`` from
    any pause onset and from each other (:func:`.speech.pause_onsets`, :func:`.speech.low_pitch_cues`)."""
    from .speech import low_pitch_cues, pause_onsets

    pauses = pause_onsets(speech[:, 0], speech[:, 1])
    cues = list(pauses)
    gap = min_gap_s * FPS
    for c in low_pitch_cues(speech):
        if all(abs(int(c) - int(o)) >= gap for o in cues):
            cues.append(int(c))
    return np.asarray(sorted(cues), dtype=np.int64)


def tts_speaker(rng: np.random.Generator, config: SyntheticConfig, au_names,
                jaw_unit: np.ndarray) -> tuple[SpeakerClip, np.ndarray]:
    """A text-to-speech speaker (:func:`.tts.tts_clip`) and its speech channels.

    The face is still (all zeros) for a share ``still_face_fraction`` of the speakers; otherwise it
    moves with the detected speech: mouth (AU25/AU26, jaw) with the level while the VAD hears speech,
    brows on pitch accents (> 0.3 octave above the running mean), smile and frown episodes, head bobs
    with the mouth and slow sway. ``pause_onsets`` of the returned clip are :func:`listener_cues`.
    """
    from .speech import speech_features, speech_mask
    from .tts import tts_clip

    T = config.n_frames
    wave, _voice = tts_clip(rng, T / FPS)
    speech = speech_features(wave, config.audio.sample_rate, T)
    talking = speech_mask(speech[:, 0], speech[:, 1])
    S = len(au_names) + 6
    state = np.zeros((T, S))
    smile = np.zeros(T)
    brow = np.zeros(T)
    if rng.random() >= config.still_face_fraction:
        tf = np.arange(T) / FPS
        open_ = gaussian_filter1d(np.clip((speech[:, 1] + 0.6) / 0.8, 0.0, 1.0) * talking, 1.0)
        accents = np.flatnonzero((speech[:, 3] > 0.3) & talking)
        brow = np.clip(gaussian_filter1d(np.isin(np.arange(T), accents).astype(float), 4.0) * 6.0, 0, 1)
        smile = np.clip(_bumps(tf, *_episodes(rng, config.seconds, 0.15, (1.5, 3.5), (0.4, 1.0))), 0, 1)
        frown = np.clip(_bumps(tf, *_episodes(rng, config.seconds, 0.05, (1.0, 2.5), (0.3, 0.8))), 0, 1)
        _set_aus(state, au_names, {"AU25": 4.0 * np.minimum(1.0, 1.5 * open_), "AU26": 3.5 * open_,
                                   "AU12": 4.0 * smile, "AU6": 2.5 * smile, "AU1": 3.0 * brow, "AU2": 2.5 * brow,
                                   "AU4": 2.0 * frown, "AU15": 1.2 * frown})
        n_au = len(au_names)
        state[:, n_au:n_au + 3] = open_[:, None] * jaw_unit[None, :]
        state[:, n_au + 3] = 0.06 * gaussian_filter1d(open_, 2.0) + 0.03 * _slow(rng, T, 12.0)
        state[:, n_au + 4] = 0.10 * _slow(rng, T, 25.0)
        state[:, n_au + 5] = 0.03 * _slow(rng, T, 25.0)
    clip = SpeakerClip(wave, state.astype(np.float32), talking, listener_cues(speech), smile, brow)
    return clip, speech


def make_synthetic_split(name: str, config: SyntheticConfig = SyntheticConfig(), au_map=None,
                         keep_waveforms: bool = False) -> ReactionSplit:
    """Generate one split ("train", "val" or "test") of the synthetic dataset.

    Parameters
    ----------
    name : {"train", "val", "test"}
    config : SyntheticConfig
    au_map : AUMap, optional
        Defaults to ``default_au_map()`` of the default head.
    keep_waveforms : bool
        Keep the speaker waveforms (C, L) in the result (memory: C * seconds * 64 kB).

    Returns
    -------
    ReactionSplit
    """
    from ..flame.expressions import default_au_map, jaw_for_expression

    if name not in _SPLIT_IDS:
        raise ReactionError(f"split: expected one of {sorted(_SPLIT_IDS)}, found {name!r}")
    check_data_kinds(config)
    au_map = default_au_map() if au_map is None else au_map
    au_names = tuple(au_map.names)
    jaw_unit = np.asarray(jaw_for_expression("mouth_open", 1.0), dtype=np.float64).reshape(3)
    grid, table = _pain_table(au_names)
    n_ctx, n_l = config.contexts(name), config.listeners_per_context
    feats, waves, sp_states, l_states, ctx, pains, styles, lags = [], [], [], [], [], [], [], []
    for c in range(n_ctx):
        if config.voices == "tts":
            rng = np.random.default_rng(np.random.SeedSequence([config.seed, _SPLIT_IDS[name], c, 1]))
            sp, speech = tts_speaker(rng, config, au_names, jaw_unit)
        else:
            rng = np.random.default_rng(np.random.SeedSequence([config.seed, _SPLIT_IDS[name], c]))
            sp, speech = synth_speaker(rng, config, au_names, jaw_unit), None
        feats.append(audio_features(sp.waveform, config, speech))
        if keep_waveforms:
            waves.append(sp.waveform)
        order = list(rng.permutation(len(STYLES)))
        for j in range(n_l):
            style = STYLES[order[j % len(STYLES)]]
            if style == "mirror" and not sp.state.any():  # a still face: nothing to mirror
                style = "backchannel"
            lag = float(rng.uniform(*LAG_RANGE_S))
            pain = 0.0 if rng.random() < config.pain_zero_fraction else float(rng.uniform(0.0, 1.0))
            # the per-cue jitter draws from its own stream, so jitter 0 leaves the data bit for bit as before
            jit = (np.random.default_rng(np.random.SeedSequence([config.seed, _SPLIT_IDS[name], c, j, 2]))
                   if config.cue_lag_jitter_s > 0 else None)
            l_states.append(_listener(rng, sp, style, lag, pain, config, au_names, grid, table, jit))
            sp_states.append(sp.state)
            ctx.append(c)
            pains.append(pain)
            styles.append(style)
            lags.append(lag)
    ctx_a = np.asarray(ctx, dtype=np.int64)
    sp_a, l_a = np.stack(sp_states), np.stack(l_states)
    return ReactionSplit(
        name=name, au_names=au_names, audio=np.stack(feats).astype(np.float32), context=ctx_a,
        speaker_state=sp_a, listener_state=l_a,
        speaker_attr=attributes_from_state(sp_a, au_names).astype(np.float32),
        listener_attr=attributes_from_state(l_a, au_names).astype(np.float32),
        pain=np.asarray(pains, dtype=np.float32),
        neighbour=(ctx_a[:, None] == ctx_a[None, :]).astype(np.int8),
        style=tuple(styles), lag_s=np.asarray(lags, dtype=np.float32),
        waveforms=np.stack(waves) if keep_waveforms else None,
    )


def make_synthetic_dataset(config: SyntheticConfig = SyntheticConfig(), au_map=None) -> dict[str, ReactionSplit]:
    """All three splits: ``{"train": ..., "val": ..., "test": ...}``."""
    return {s: make_synthetic_split(s, config, au_map) for s in ("train", "val", "test")}
