"""Speech features at the video frame rate that mean the same on a microphone as in training.

The listener model hears speech through a few prosodic channels instead of a spectrum: whether
someone speaks, how loud relative to their own level, whether and how high they voice relative to
their own pitch, and how long the current silence and the last stretch of speech have lasted.
None of them depends on the gain, the microphone's colouring or the voice's timbre, which is what
lets a model trained on text-to-speech with noise and reverberation react to a real recording.

Frame ``i`` (25 fps) is the video frame delivered with audio samples ``[0, 640 (i + 1))`` (as in the
live loop); every channel is causal except Praat's pitch path (see ``pitch``)::

    0 vad      silero-vad speech probability of the last complete 512-sample chunk (32 ms) ending
               at or before sample 640 (i + 1); chunks run from sample 0, the model's recurrent
               state over the whole clip (silero-vad, MIT; the model ships in its wheel)
    1 energy   (L_i - level_i) / 20, clipped to [-3, 1]: L_i = 10 log10(mean square of the last
               1024 samples + 1e-10) dB, level_i = the running mean of L over speech frames so far
               (a prior of -26 dB weighted as 5 frames) -- gain-free once someone has spoken
    2 voiced   1 where Praat's autocorrelation pitch (75-500 Hz, 10-ms steps) is voiced at time
               640 (i + 1) / 16000 - 0.02 s, else 0
    3 pitch    log2(f0 / running geometric mean of the voiced speech f0 so far) in octaves, clipped
               to [-1, 1]; 0 where unvoiced.  Praat's path finder looks ahead, so the pitch is found
               in blocks of 4 frames (the listening paths' model step, 0.16 s): block [4j, 4j + 4) from
               Praat over the 2.4 s of audio ending with its last frame -- the same offline and streaming
    4 silence  seconds since speech stopped / 2, clipped to 1; 0 while speaking
    5 speech   length of the latest speech run (ongoing or ended) in seconds / 3, clipped to 1

"Speech" is the VAD probability with hysteresis (on at >= 0.5, off below 0.35, silero's own
defaults) where the level is within 12 dB of the speaker's (silero's probability stays high for
0.1-0.3 s after the voice stops; the level does not); silences shorter than 200 ms do not end a
speech run. The running level follows the VAD alone, so a quiet microphone is not locked out. :func:`pause_onsets` gives the
listener-behaviour pause onsets (>= 200 ms of silence after >= 700 ms of speech; Ward & Tsukahara
2000) and :func:`low_pitch_cues` their low-pitch regions (>= 110 ms below the speaker's 26th pitch
percentile after >= 700 ms of speech).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ..errors import ReactionError
from ..validation import check_array

__all__ = ["SPEECH_FEATURES", "N_SPEECH_FEATURES", "SpeechState", "speech_features", "vad_probabilities",
           "frame_energy_db", "praat_pitch", "speech_mask", "speech_runs", "pause_onsets", "low_pitch_cues",
           "SpeechTracker", "block_pitch", "PITCH_BLOCK", "PauseDetector", "SpeechGate",
           "speech_cues"]

SAMPLE_RATE = 16000
HOP = 640  # samples per 25-fps frame
FPS = 25
CHUNK = 512  # silero-vad's chunk at 16 kHz
ENERGY_WINDOW = 1024
PITCH_FLOOR, PITCH_CEILING, PITCH_STEP = 75.0, 500.0, 0.01
PITCH_DELAY = 0.02  # s: pitch of frame i is read at the end of its audio minus this
VAD_ON, VAD_OFF = 0.5, 0.35
SILENT_REL = -0.6  # energy channel: 12 dB below the speaker's level is silence whatever the VAD says
MIN_SILENCE_S, MIN_SPEECH_S = 0.2, 0.7
LEVEL_PRIOR_DB, PRIOR_FRAMES = -26.0, 5.0
PITCH_PRIOR_HZ = 150.0
STREAM_PITCH_S = 2.4  # trailing audio Praat runs over for each block
PITCH_BLOCK = 4  # frames per pitch block (decoding.LISTENING_STRIDE: the model steps at block ends)

#: channel names of :func:`speech_features`, in column order
SPEECH_FEATURES: tuple[str, ...] = ("vad", "energy", "voiced", "pitch", "silence", "speech")
N_SPEECH_FEATURES = len(SPEECH_FEATURES)


def _frames_for(min_seconds: float) -> int:
    return int(np.ceil(min_seconds * FPS - 1e-9))


# ---- the three measurements ---------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _silero_path() -> str:
    from importlib import resources

    return str(resources.files("silero_vad").joinpath("data", "silero_vad.jit"))


def _load_vad():
    """A fresh silero-vad model (TorchScript from its wheel; no download)."""
    try:
        import torch
        from silero_vad import load_silero_vad  # noqa: F401  (checks the package is installed)
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise ReactionError("silero-vad is not installed: pip install silero-vad (no extras)") from exc
    import warnings

    with warnings.catch_warnings():  # torch 2.13 deprecates TorchScript loading; silero ships TorchScript
        warnings.simplefilter("ignore", DeprecationWarning)
        model = torch.jit.load(_silero_path(), map_location="cpu")
    model.eval()
    return model


def vad_probabilities(waves: np.ndarray, model=None) -> np.ndarray:
    """silero-vad speech probability of each consecutive 512-sample chunk.

    Parameters
    ----------
    waves : numpy.ndarray, shape (L,) or (B, L), 16 kHz, in [-1, 1]
    model : a silero-vad model to continue (its state is carried); default a fresh one

    Returns
    -------
    numpy.ndarray, shape (n_chunks,) or (B, n_chunks), float32, ``n_chunks = L // 512``
    """
    import torch

    x = np.asarray(waves, dtype=np.float32)
    single = x.ndim == 1
    x = np.atleast_2d(x)
    n = x.shape[1] // CHUNK
    if model is None:
        model = _load_vad()
        model.reset_states()
    out = np.zeros((x.shape[0], n), np.float32)
    t = torch.from_numpy(np.ascontiguousarray(x[:, :n * CHUNK]))
    with torch.no_grad():
        for j in range(n):
            out[:, j] = model(t[:, j * CHUNK:(j + 1) * CHUNK], SAMPLE_RATE).reshape(-1).numpy()
    return out[0] if single else out


def frame_energy_db(wave: np.ndarray, n_frames: int) -> np.ndarray:
    """Level (dB re full scale) of the last 1024 samples of each frame's audio, shape (n_frames,)."""
    x = np.asarray(wave, dtype=np.float64)
    need = n_frames * HOP
    x = np.concatenate([np.zeros(ENERGY_WINDOW), x[:need], np.zeros(max(0, need - x.shape[0]))])
    c = np.concatenate([[0.0], np.cumsum(x * x)])
    ends = ENERGY_WINDOW + HOP * (np.arange(n_frames) + 1)
    ms = (c[ends] - c[ends - ENERGY_WINDOW]) / ENERGY_WINDOW
    return 10.0 * np.log10(np.maximum(ms, 0.0) + 1e-10)


def praat_pitch(wave: np.ndarray, n_frames: int, first_frame: int = 0, offset_samples: int = 0) -> np.ndarray:
    """Praat autocorrelation f0 (Hz, 0 = unvoiced) of frames ``first_frame .. first_frame + n_frames - 1``.

    ``wave`` holds the clip's samples from ``offset_samples`` on. Frame i is read at
    ``640 (i + 1) / 16000 - 0.02`` s (the nearest 10-ms Praat frame; unvoiced outside the analysis).
    """
    import parselmouth

    x = np.asarray(wave, dtype=np.float64)
    f0 = np.zeros(n_frames)
    if x.shape[0] < int(3 / PITCH_FLOOR * SAMPLE_RATE) + 2:
        return f0
    snd = parselmouth.Sound(x, SAMPLE_RATE)
    pitch = snd.to_pitch_ac(time_step=PITCH_STEP, pitch_floor=PITCH_FLOOR, pitch_ceiling=PITCH_CEILING)
    freq = np.nan_to_num(pitch.selected_array["frequency"])
    if freq.size == 0:
        return f0
    times = (HOP * (first_frame + np.arange(n_frames) + 1) - offset_samples) / SAMPLE_RATE - PITCH_DELAY
    idx = np.rint((times - pitch.x1) / pitch.dx).astype(np.int64)
    ok = (idx >= 0) & (idx < freq.size)
    f0[ok] = freq[idx[ok]]
    return f0


# ---- causal recurrences over frames -------------------------------------------------------------
@dataclass
class SpeechState:
    """What the causal channels carry from frame to frame."""

    frame: int = 0
    vad_on: bool = False  # the VAD's hysteresis state
    speaking: bool = False
    last_speech: int = -10**9  # last frame judged speech
    run_start: int = -10**9  # first frame of the current / last speech run
    level_sum: float = LEVEL_PRIOR_DB * PRIOR_FRAMES
    level_n: float = PRIOR_FRAMES
    pitch_sum: float = float(np.log2(PITCH_PRIOR_HZ)) * PRIOR_FRAMES
    pitch_n: float = PRIOR_FRAMES
    extra: dict = field(default_factory=dict)


def _recurrences(vad: np.ndarray, energy_db: np.ndarray, f0: np.ndarray, state: SpeechState) -> np.ndarray:
    """Feature rows (n, 6) for consecutive frames, advancing ``state`` in place."""
    n = vad.shape[0]
    out = np.zeros((n, N_SPEECH_FEATURES), np.float32)
    gap = _frames_for(MIN_SILENCE_S)
    for j in range(n):
        i = state.frame
        p = float(vad[j])
        state.vad_on = p >= VAD_ON or (state.vad_on and p >= VAD_OFF)
        if state.vad_on:
            state.level_sum += float(energy_db[j])
            state.level_n += 1.0
        rel = float(np.clip((energy_db[j] - state.level_sum / state.level_n) / 20.0, -3.0, 1.0))
        state.speaking = state.vad_on and rel > SILENT_REL
        if state.speaking:
            if i - state.last_speech - 1 >= gap:
                state.run_start = i
            state.last_speech = i
        voiced = f0[j] > 0
        if voiced and state.speaking:
            state.pitch_sum += float(np.log2(f0[j]))
            state.pitch_n += 1.0
        out[j, 0] = p
        out[j, 1] = rel
        out[j, 2] = 1.0 if voiced else 0.0
        out[j, 3] = np.clip(np.log2(f0[j]) - state.pitch_sum / state.pitch_n, -1.0, 1.0) if voiced else 0.0
        since = (i - state.last_speech) / FPS if not state.speaking and state.last_speech >= 0 else 0.0
        out[j, 4] = min(since / 2.0, 1.0)
        run = (state.last_speech - state.run_start + 1) / FPS if state.last_speech >= 0 else 0.0
        out[j, 5] = min(run / 3.0, 1.0)
        state.frame += 1
    return out


def _frame_vad(chunk_probs: np.ndarray, n_frames: int, first_frame: int = 0, first_chunk: int = 0) -> np.ndarray:
    """Per frame, the probability of the last chunk ending at or before the frame's last sample."""
    j = (HOP * (first_frame + np.arange(n_frames) + 1)) // CHUNK - 1 - first_chunk
    j = np.clip(j, 0, max(chunk_probs.shape[0] - 1, 0))
    return chunk_probs[j] if chunk_probs.size else np.zeros(n_frames, np.float32)


def _check(audio, sample_rate: int, n_frames: int | None) -> tuple[np.ndarray, int]:
    if int(sample_rate) != SAMPLE_RATE:
        raise ReactionError(f"sample_rate: expected {SAMPLE_RATE} Hz, found {sample_rate} Hz; resample the speaker "
                            f"audio to {SAMPLE_RATE} Hz mono first (the speech features)")
    x = np.asarray(check_array(audio, "audio", ("L",)), dtype=np.float32)
    if n_frames is None:
        n_frames = x.shape[0] // HOP
    if n_frames < 1:
        raise ReactionError(f"audio: expected at least one frame ({HOP} samples), found {x.shape[0]} samples")
    need = n_frames * HOP
    if abs(x.shape[0] - need) > HOP:
        raise ReactionError(f"audio: length mismatch: {n_frames} frames at {FPS} fps need {need} samples, found "
                            f"{x.shape[0]}")
    x = x[:need] if x.shape[0] >= need else np.concatenate([x, np.zeros(need - x.shape[0], np.float32)])
    return x, int(n_frames)


def speech_features(audio: np.ndarray, sample_rate: int = SAMPLE_RATE, n_frames: int | None = None,
                    vad: np.ndarray | None = None) -> np.ndarray:
    """The six speech channels of a clip (see the module docstring), shape (n_frames, 6), float32.

    Parameters
    ----------
    audio : numpy.ndarray, shape (L,), mono 16 kHz in [-1, 1]; must span ``n_frames`` within one frame
    sample_rate : int, must be 16000
    n_frames : int, optional (default ``L // 640``)
    vad : numpy.ndarray, optional
        Precomputed chunk probabilities (:func:`vad_probabilities` of the same audio).

    Raises
    ------
    ReactionError
        Wrong sample rate, too short, length mismatch.
    InputError
        NaN/inf samples.
    """
    x, n_frames = _check(audio, sample_rate, n_frames)
    chunks = vad_probabilities(x) if vad is None else np.asarray(vad, np.float32)
    return _recurrences(_frame_vad(chunks, n_frames), frame_energy_db(x, n_frames), block_pitch(x, n_frames),
                        SpeechState())


def block_pitch(wave: np.ndarray, n_frames: int, first_frame: int = 0, offset_samples: int = 0) -> np.ndarray:
    """f0 (Hz, 0 = unvoiced) of frames ``first_frame ..`` in blocks of :data:`PITCH_BLOCK` frames, each from
    Praat over the :data:`STREAM_PITCH_S` seconds of audio ending with the block (``first_frame`` must
    start a block; ``wave`` holds the clip from sample ``offset_samples``)."""
    keep = int(STREAM_PITCH_S * SAMPLE_RATE)
    x = np.asarray(wave, dtype=np.float64)
    f0 = np.zeros(n_frames)
    for b0 in range(0, n_frames, PITCH_BLOCK):
        b1 = min(b0 + PITCH_BLOCK, n_frames)
        end = HOP * (first_frame + b1)
        lo = max(0, end - keep)
        f0[b0:b1] = praat_pitch(x[lo - offset_samples:end - offset_samples], b1 - b0, first_frame + b0, lo)
    return f0


# ---- segments and listener cues ------------------------------------------------------------------
def speech_mask(vad: np.ndarray, energy: np.ndarray | None = None, on: float = VAD_ON,
                off: float = VAD_OFF) -> np.ndarray:
    """Per-frame speech (bool): VAD probabilities with hysteresis (on at >= on, off below off) and,
    when ``energy`` (channel 1 of :func:`speech_features`) is given, a level above ``SILENT_REL``."""
    p = np.asarray(check_array(vad, "vad", ("T",)), dtype=np.float64)
    e = None if energy is None else np.asarray(check_array(energy, "energy", (p.shape[0],)), dtype=np.float64)
    out = np.zeros(p.shape[0], bool)
    s = False
    for i, v in enumerate(p):
        s = v >= on or (s and v >= off)
        out[i] = s and (e is None or e[i] > SILENT_REL)
    return out


def speech_runs(mask: np.ndarray, fps: float = FPS, min_silence: float = MIN_SILENCE_S) -> list[tuple[int, int]]:
    """Speech runs ``[start, stop)`` in frames; silences shorter than ``min_silence`` do not split a run."""
    m = np.asarray(mask, bool)
    gap = int(np.ceil(min_silence * fps - 1e-9))
    runs: list[tuple[int, int]] = []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], m.astype(np.int8), [0]])))
    for a, b in zip(idx[::2], idx[1::2]):
        if runs and a - runs[-1][1] < gap:
            runs[-1] = (runs[-1][0], int(b))
        else:
            runs.append((int(a), int(b)))
    return runs


def pause_onsets(vad: np.ndarray, energy: np.ndarray | None = None, fps: float = FPS,
                 min_silence: float = MIN_SILENCE_S, min_speech: float = MIN_SPEECH_S) -> np.ndarray:
    """Frames where a pause starts: >= ``min_silence`` of silence after >= ``min_speech`` of speech.

    Parameters
    ----------
    vad : numpy.ndarray, shape (T,)
        Per-frame speech probability (channel 0 of :func:`speech_features`) or a 0/1 speech mask.
    energy : numpy.ndarray, shape (T,), optional
        Channel 1 of :func:`speech_features` (see :func:`speech_mask`).

    Returns
    -------
    numpy.ndarray of int64: the first silent frame of each pause (its time is ``frame / fps``); a
    silence that the clip's end cuts below ``min_silence`` is not a pause.
    """
    mask = speech_mask(vad, energy)
    T = mask.shape[0]
    gap = int(np.ceil(min_silence * fps - 1e-9))
    need = int(np.ceil(min_speech * fps - 1e-9))
    out = [b for a, b in speech_runs(mask, fps, min_silence) if b - a >= need and b + gap <= T
           and not mask[b:b + gap].any()]
    return np.asarray(out, dtype=np.int64)


def low_pitch_cues(features: np.ndarray, fps: float = FPS, percentile: float = 26.0, min_low: float = 0.11,
                   min_speech: float = MIN_SPEECH_S) -> np.ndarray:
    """Frames where a low-pitch region has lasted ``min_low`` s after ``min_speech`` s of speech.

    Ward & Tsukahara (2000): listeners backchannel after a region of pitch below the speaker's 26th
    percentile lasting >= 110 ms, after >= 700 ms of speech. ``features`` are :func:`speech_features`
    rows; the percentile is taken over the clip's voiced speech frames (an offline rule for data
    generation and measurement). One cue per low region.
    """
    f = np.asarray(check_array(features, "features", ("T", N_SPEECH_FEATURES)), dtype=np.float64)
    mask = speech_mask(f[:, 0], f[:, 1])
    voiced = (f[:, 2] > 0.5) & mask
    if voiced.sum() < 10:
        return np.zeros(0, np.int64)
    thr = np.percentile(f[voiced, 3], percentile)
    low = voiced & (f[:, 3] <= thr)
    need_low = int(np.ceil(min_low * fps - 1e-9))
    need_speech = int(np.ceil(min_speech * fps - 1e-9))
    out = []
    for a, b in speech_runs(mask, fps):
        run_low = 0
        for i in range(a, b):
            run_low = run_low + 1 if low[i] else 0
            if run_low == need_low and i - a + 1 >= need_speech:
                out.append(i)
    return np.asarray(out, dtype=np.int64)


# ---- streaming ---------------------------------------------------------------------------------
class SpeechTracker:
    """The speech channels computed as audio arrives (the live loop's and :mod:`.stream`'s path).

    :meth:`push` takes new samples; :meth:`frames` returns the rows of the pitch blocks (4 frames)
    whose audio is complete and not yet returned, equal to :func:`speech_features` rows.
    """

    def __init__(self) -> None:
        self._vad_model = _load_vad()
        self._vad_model.reset_states()
        self._audio = np.zeros(0, np.float32)
        self._start = 0  # global index of self._audio[0]
        self._chunks: list[float] = []  # VAD probabilities of chunks self._chunk0, self._chunk0 + 1, ...
        self._chunk0 = 0
        self._chunk_done = 0  # samples fed to the VAD
        self.state = SpeechState()

    @property
    def samples(self) -> int:
        """Samples received so far."""
        return self._start + self._audio.shape[0]

    @property
    def vad_probability(self) -> float | None:
        """silero-vad's speech probability of the last complete 512-sample chunk (None before the first)."""
        return self._chunks[-1] if self._chunks else None

    def push(self, samples: np.ndarray) -> None:
        """Append 16-kHz mono samples (NaN/inf become 0)."""
        x = np.nan_to_num(np.asarray(samples, dtype=np.float32).reshape(-1))
        self._audio = np.concatenate([self._audio, x])
        n_new = (self.samples - self._chunk_done) // CHUNK
        if n_new:
            lo = self._chunk_done - self._start
            probs = vad_probabilities(self._audio[lo:lo + n_new * CHUNK], model=self._vad_model)
            self._chunks.extend(float(p) for p in probs)
            self._chunk_done += n_new * CHUNK

    def frames(self) -> np.ndarray:
        """Rows (n, 6) of the newly complete pitch blocks (frame i needs samples up to 640 (i + 1))."""
        first = self.state.frame
        n = (self.samples // HOP) // PITCH_BLOCK * PITCH_BLOCK - first
        if n <= 0:
            return np.zeros((0, N_SPEECH_FEATURES), np.float32)
        keep = int(STREAM_PITCH_S * SAMPLE_RATE) + ENERGY_WINDOW
        end = HOP * (first + n)
        vad = _frame_vad(np.asarray(self._chunks, np.float32), n, first, self._chunk0)
        # forget the chunks before the first one the next block reads (the last one stays: vad_probability);
        # the whole list was converted at every block before, a cost that grew with the session (issue 37)
        need = min((HOP * (first + n + 1)) // CHUNK - 1, self._chunk0 + len(self._chunks) - 1)
        if need > self._chunk0:
            del self._chunks[:need - self._chunk0]
            self._chunk0 = need
        energy = self._energy(first, n)
        f0 = block_pitch(self._audio, n, first, self._start)
        rows = _recurrences(vad, energy, f0, self.state)
        # forget audio no longer needed
        drop = max(0, end - keep) - self._start
        if drop > 0:
            self._audio = self._audio[drop:]
            self._start += drop
        return rows

    def _energy(self, first: int, n: int) -> np.ndarray:
        out = np.empty(n)
        for j in range(n):
            hi = HOP * (first + j + 1)
            lo = hi - ENERGY_WINDOW
            seg = self._audio[max(lo, self._start) - self._start:hi - self._start].astype(np.float64)
            out[j] = 10.0 * np.log10(float((seg * seg).sum()) / ENERGY_WINDOW + 1e-10)
        return out


# ---- the one pause-onset definition, streamed ------------------------------------------------------
class PauseDetector:
    """:func:`pause_onsets` frame by frame: step with each frame's VAD probability and level (dB).

    The speech decision is :func:`speech_mask`'s (the recurrence of :func:`speech_features`); a pause
    onset becomes known at the frame that completes ``MIN_SILENCE_S`` of silence after a speech run
    of >= ``MIN_SPEECH_S`` (silences shorter than ``MIN_SILENCE_S`` do not end a run), and
    :meth:`step` then returns the onset's own frame (the first silent one). Over a clip the onsets
    equal ``pause_onsets(features[:, 0], features[:, 1])`` exactly (tested on the real recordings).
    """

    def __init__(self) -> None:
        self.state = SpeechState()
        self._gap = _frames_for(MIN_SILENCE_S)
        self._need = _frames_for(MIN_SPEECH_S)

    def step(self, vad: float, energy_db: float) -> tuple[bool, int | None]:
        """(speaking now, the frame of a pause onset that became known at this frame or None)."""
        s = self.state
        i = s.frame
        _recurrences(np.array([vad], np.float64), np.array([energy_db], np.float64), np.zeros(1), s)
        onset = None
        if (not s.speaking and s.last_speech >= 0 and i - s.last_speech == self._gap
                and s.last_speech - s.run_start + 1 >= self._need):
            onset = s.last_speech + 1
        return s.speaking, onset


class SpeechGate:
    """The speech cues of the behaviour layers (blinks at pauses, gaze, brow raises), streamed.

    :meth:`step` takes the samples of one 25-fps frame (640 at 16 kHz) as the live loop delivers
    them and returns ``(speaking, pause_onset)``: whether the speaker talks now (:func:`speech_mask`
    of the silero-vad probability and the level) and whether a pause onset (:class:`PauseDetector`,
    the definition of :func:`pause_onsets`) became known at this frame, 200 ms after the silence
    began. :func:`speech_cues` is the same over a whole clip.

    ``vad``: a :class:`SpeechTracker` fed the same samples (its :meth:`~SpeechTracker.push` before each
    :meth:`step`): the gate reads that tracker's silero probabilities instead of running silero a second
    time on the same chunks (the live loop's reaction stream; the same numbers, tested).
    """

    def __init__(self, vad: SpeechTracker | None = None) -> None:
        self._vad = vad
        self._vad_model = None
        if vad is None:
            self._vad_model = _load_vad()
            self._vad_model.reset_states()
        self._tail = np.zeros(ENERGY_WINDOW, np.float32)  # the last samples (energy window, VAD chunk rest)
        self._pending = np.zeros(0, np.float32)  # samples not yet in a VAD chunk
        self._prob = 0.0
        self._n = 0  # samples received
        self.detector = PauseDetector()

    @property
    def shares_vad(self) -> bool:
        """Whether the gate reads another :class:`SpeechTracker`'s VAD (``vad``) instead of its own."""
        return self._vad is not None

    def step(self, samples: np.ndarray) -> tuple[bool, bool]:
        """(speaking, pause onset known now) for the next frame; ``samples`` is that frame's audio."""
        x = np.nan_to_num(np.asarray(samples, dtype=np.float32).reshape(-1))
        self._n += x.shape[0]
        if self._vad is not None:
            p = self._vad.vad_probability
            if p is not None:
                self._prob = float(p)
        else:
            self._pending = np.concatenate([self._pending, x])
            n_chunks = self._pending.shape[0] // CHUNK
            if n_chunks:
                probs = vad_probabilities(self._pending[:n_chunks * CHUNK], model=self._vad_model)
                self._prob = float(probs[-1])
                self._pending = self._pending[n_chunks * CHUNK:]
        self._tail = np.concatenate([self._tail, x])[-ENERGY_WINDOW:]
        seg = self._tail.astype(np.float64)
        db = 10.0 * np.log10(float((seg * seg).sum()) / ENERGY_WINDOW + 1e-10)
        speaking, onset = self.detector.step(self._prob, db)
        return speaking, onset is not None


def speech_cues(audio: np.ndarray, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """:class:`SpeechGate` over a whole clip: (speaking, pause_onset), each (n_frames,) bool.

    Frame t sees samples ``[640 t, 640 (t + 1))``; ``pause_onset[t]`` is True where a pause onset
    became known (its first silent frame + 4: 200 ms of silence complete). Offline: the VAD,
    the level and :func:`pause_onsets` of the whole clip; equal to the streamed gate (tested).
    """
    n_frames = int(n_frames)
    x = np.nan_to_num(np.asarray(audio, dtype=np.float32).reshape(-1))
    need = n_frames * HOP
    x = x[:need] if x.shape[0] >= need else np.concatenate([x, np.zeros(need - x.shape[0], np.float32)])
    vad = _frame_vad(vad_probabilities(x), n_frames)
    rows = _recurrences(vad, frame_energy_db(x, n_frames), np.zeros(n_frames), SpeechState())
    speaking = speech_mask(rows[:, 0], rows[:, 1])
    known = np.zeros(n_frames, bool)
    known[pause_onsets(rows[:, 0], rows[:, 1]) + _frames_for(MIN_SILENCE_S) - 1] = True
    return speaking, known
