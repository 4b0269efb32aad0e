"""Using a trained reaction model: speaker files in, listener FLAME parameters out.

``speaker.npz`` format (documented in docs/reaction.md): per-frame FLAME parameters of the
speaker at 25 fps with GaussianAvatars' key names, ``expr`` (T, n_expr) of the default head
(fewer columns are zero-padded), ``jaw_pose`` (T, 3) and ``rotation`` (T, 3) axis-angle in
radians; optional ``fps`` (scalar, must be 25). The speaker WAV must be 16 kHz and span the
same T frames (within one frame).

The output is a ``flame_param.npz``-style dict: ``expr`` (T, n_expr), ``jaw_pose`` (T, 3),
``rotation`` (T, 3), ``neck_pose`` (T, 3), ``eyes_pose`` (T, 6), ``translation`` (T, 3) (zeros
where the model does not predict), ``shape`` (n_shape,) zeros (the default head's identity).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError, ReactionError
from ..fileio import read_npz
from ..validation import check_array, check_finite_scalar
from .audio import AudioConfig, log_mel
from .decoding import DEFAULT_TEMPERATURE, DEFAULT_TOP_K, listening_stride
from .features import FPS, flame_from_state, state_from_flame
from .model import generate
from .train import ReactionBundle, load_checkpoint

__all__ = ["default_checkpoint_path", "load_default_bundle", "load_speaker_npz", "react", "flame_params_from_states",
           "generate_demo_reaction", "smooth_states", "ANIMATION_SMOOTHING_S"]

#: Default time constant (seconds) of the causal smoothing applied to animation output. The model
#: decodes one codebook token per frame and consecutive frames of a k-frame window usually share
#: a code, so raw output is piecewise constant with jumps at window edges; a one-pole filter with
#: this time constant turns the jumps into ~0.3 s transitions (lag ~0.12 s, below the 0.2-1 s
#: listener lags). Metrics (``evaluate``) always use the raw model output.
ANIMATION_SMOOTHING_S = 0.12


def smooth_states(states: np.ndarray, time_constant: float = ANIMATION_SMOOTHING_S, fps: float = FPS,
                  initial: np.ndarray | None = None) -> np.ndarray:
    """Causal one-pole (exponential) smoothing of per-frame face states.

    ``y[t] = y[t-1] + a (x[t] - y[t-1])`` with ``a = 1 - exp(-1 / (fps * time_constant))`` and
    ``y[-1] = initial`` (default ``x[0]``). Causal, so streaming window by window gives the same
    result as one call when the last output row is passed on as ``initial``.

    Parameters
    ----------
    states : numpy.ndarray, shape (T, S)
    time_constant : float >= 0, seconds (0 returns a copy of ``states``)
    fps : float > 0
    initial : numpy.ndarray, shape (S,), optional

    Returns
    -------
    numpy.ndarray, shape (T, S), same dtype as ``states``
    """
    x = np.asarray(check_array(states, "states", ("T", "S")))
    tc = check_finite_scalar(time_constant, "time_constant", low=0.0)
    fps = check_finite_scalar(fps, "fps", low=0.0, low_open=True)
    if tc == 0.0 or x.shape[0] == 0:
        return x.copy()
    a = 1.0 - np.exp(-1.0 / (fps * tc))
    y = np.empty_like(x)
    prev = x[0] if initial is None else np.asarray(check_array(initial, "initial", (x.shape[1],)), dtype=x.dtype)
    for t in range(x.shape[0]):
        prev = prev + a * (x[t] - prev)
        y[t] = prev
    return y


def default_checkpoint_path() -> Path:
    """``assets/reaction_default.pt`` of the repository (the shipped small checkpoint)."""
    return Path(__file__).resolve().parents[2] / "assets" / "reaction_default.pt"


@functools.lru_cache(maxsize=2)
def _cached(path: str, mtime: float) -> ReactionBundle:
    return load_checkpoint(path)


def load_default_bundle(path: str | os.PathLike | None = None) -> ReactionBundle:
    """Load (and cache) a reaction checkpoint; default: the shipped one."""
    p = Path(path) if path is not None else default_checkpoint_path()
    if not p.is_file():
        raise ReactionError(f"{p}: reaction checkpoint not found; train one with "
                            f"`holo-viewer train-reaction --out {p}`")
    return _cached(str(p), p.stat().st_mtime)


def _default_n_shape() -> int:
    from ..flame.default_head import default_head_path

    with np.load(default_head_path(), allow_pickle=False) as z:
        return int(z["n_shape"]) if "n_shape" in z.files else 0


def load_speaker_npz(path: str | os.PathLike, au_map) -> np.ndarray:
    """Speaker face states (T, S) from a speaker.npz (see the module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise ReactionError(f"{p}: speaker file not found")
    z = read_npz(p, ReactionError, "speaker FLAME parameters")
    missing = [k for k in ("expr", "jaw_pose", "rotation") if k not in z]
    if missing:
        raise ReactionError(f"{p}: missing keys {missing}; expected expr (T, n_expr), jaw_pose (T, 3), "
                            f"rotation (T, 3); found {sorted(z)}")
    if "fps" in z and float(z["fps"]) != FPS:
        raise ReactionError(f"{p}: fps: expected {FPS}, found {float(z['fps'])}")
    try:
        return state_from_flame(z["expr"], z["jaw_pose"], z["rotation"], au_map)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from exc


def flame_params_from_states(states: np.ndarray, au_map, n_shape: int | None = None) -> dict[str, np.ndarray]:
    """GaussianAvatars ``flame_param.npz`` arrays (float32) of listener face states (T, S).

    The npz form of :class:`holo_viewer.flame.params.FlameParams`: every per-frame key (zeros where
    the model predicts nothing) and ``shape`` (n_shape,) zeros, the default head's identity.
    """
    from ..flame.params import FlameParams

    fl = flame_from_state(states, au_map)
    n_shape = _default_n_shape() if n_shape is None else int(n_shape)
    return FlameParams.from_frames(shape=np.zeros(n_shape, np.float32), **fl).as_dict()


def speaker_audio_features(audio: np.ndarray, sample_rate: int, n_frames: int, config) -> torch.Tensor:
    """What a model with ModelConfig ``config`` hears of a clip: (n_frames, n_mels) float32 tensor,
    log-mel bands or the speech channels of :mod:`.speech` (``config.audio_features``)."""
    if getattr(config, "audio_features", "log_mel") == "speech":
        from .speech import speech_features

        return torch.from_numpy(speech_features(audio, sample_rate, n_frames))
    return log_mel(audio, sample_rate, n_frames, AudioConfig(n_mels=config.n_mels))


def react(bundle: ReactionBundle, audio: np.ndarray, sample_rate: int, speaker_state: np.ndarray,
          pain: float = 0.0, listener_past: np.ndarray | None = None, temperature: float = 0.0,
          top_k: int | None = None, seed: int = 0, smoothing: float = 0.0, stride: int | None = None) -> np.ndarray:
    """Listener face states (T, S) reacting to a speaker clip, streamed ``stride`` frames at a time.

    Parameters
    ----------
    bundle : ReactionBundle
    audio : numpy.ndarray, shape (L,), mono at ``sample_rate`` (must be 16 kHz), L ~ T * 640
    sample_rate : int
    speaker_state : numpy.ndarray, shape (T, S)
    pain : float in [0, 1]
    listener_past : numpy.ndarray, shape (P, S), optional
        Listener frames before the clip (the most recent ``listener_window`` are used); P = 0
        is the same as no past.
    temperature, top_k, seed : decoding (temperature 0 = argmax)
    smoothing : float >= 0
        Time constant in seconds of :func:`smooth_states` applied to the output (0 = raw model
        output, as the metrics use; animation callers pass :data:`ANIMATION_SMOOTHING_S`).
    stride : int, optional
        Frames between model steps (each predicts k frames and keeps the first ``stride``); default
        :data:`~holo_viewer.reaction.decoding.LISTENING_STRIDE` (4) or k if smaller, as
        :class:`~holo_viewer.reaction.stream.ReactionStream` (``live``) steps.
    """
    cfg = bundle.model.config
    S = cfg.state_dim
    speaker_state = check_array(speaker_state, "speaker_state", ("T", S))
    T = speaker_state.shape[0]
    pain = check_finite_scalar(pain, "pain", low=0.0, high=1.0)
    feats = speaker_audio_features(audio, sample_rate, T, cfg)
    past = None
    if listener_past is not None:
        lp = check_array(listener_past, "listener_past", ("P", S))
        if lp.shape[0]:  # an empty past is no past
            past = torch.from_numpy(np.asarray(lp, dtype=np.float32))[None]
    out = generate(bundle.model, bundle.centroids(), feats[None],
                   torch.from_numpy(np.asarray(speaker_state, dtype=np.float32))[None],
                   torch.tensor([pain], dtype=torch.float32), listener_past=past, temperature=temperature,
                   top_k=top_k, seed=seed, stride=listening_stride(cfg.k) if stride is None else stride)
    initial = None if past is None else past[0, -1].numpy()  # continue smoothly from the listener's past
    return smooth_states(out[0].numpy(), smoothing, initial=initial)


#: generate_demo_reaction's speakers of this process, (frames, seed, text-to-speech, AU names) -> SpeakerClip
_DEMO_SPEAKERS: dict = {}


def generate_demo_reaction(seconds: float = 2.0, pain: float = 0.5, seed: int = 0,
                           temperature: float = DEFAULT_TEMPERATURE, top_k: int | None = DEFAULT_TOP_K, checkpoint: str | os.PathLike | None = None,
                           warmup: float = 4.0, smoothing: float = ANIMATION_SMOOTHING_S) -> dict[str, np.ndarray]:
    """Listener FLAME parameters reacting to a synthesized speaker clip, with the shipped checkpoint.

    The speaker is a text-to-speech voice with a face moving with it (:func:`.data.tts_speaker`) when
    the model hears speech features and espeak-ng is installed, else the harmonic synthetic speaker
    (:func:`.data.synth_speaker`; a speech-feature model does not hear it as speech: a RuntimeWarning
    says so).

    Parameters
    ----------
    seconds : float > 0
        Clip length; T = round(seconds * 25) frames.
    pain : float in [0, 1]
        Requested pain level.
    seed : int
        Seeds the synthetic speaker and the sampling.
    temperature, top_k : decoding (temperature 0 = argmax; default :mod:`.decoding`'s)
    checkpoint : path, optional (default ``assets/reaction_default.pt``)
    warmup : float >= 0
        Seconds of conversation streamed before the returned clip (the speaker talks and the
        listener reacts from a neutral start; only the last ``seconds`` are returned), so the
        clip shows a listener already engaged rather than the first quiet second.
    smoothing : float >= 0
        Time constant (s) of the causal output smoothing (:func:`smooth_states`; 0 = raw tokens).

    Returns
    -------
    dict
        ``flame_param.npz`` arrays: ``expr`` (T, n_expr), ``jaw_pose``/``rotation``/``neck_pose``/
        ``translation`` (T, 3), ``eyes_pose`` (T, 6), ``shape`` (n_shape,), float32.
    """
    from ..flame.expressions import default_au_map, jaw_for_expression
    from .data import SyntheticConfig, synth_speaker

    seconds = check_finite_scalar(seconds, "seconds", low=0.0, low_open=True)
    if seconds > 600:
        raise InputError(f"seconds: expected at most 600, found {seconds}")
    bundle = load_default_bundle(checkpoint)
    au_map = default_au_map()
    if tuple(au_map.names) != tuple(bundle.au_names):
        raise ReactionError(f"checkpoint AU order {list(bundle.au_names)} differs from the default head's "
                            f"{list(au_map.names)}; retrain the reaction model")
    warmup = check_finite_scalar(warmup, "warmup", low=0.0, high=60.0)
    T = max(1, int(round(seconds * FPS)))
    W = int(round(warmup * FPS))
    cfg = SyntheticConfig(seconds=(T + W) / FPS)
    hears_speech = getattr(bundle.model.config, "audio_features", "log_mel") == "speech"
    from .tts import espeak_available

    tts = hears_speech and espeak_available()
    if hears_speech and not tts:
        import warnings

        warnings.warn("espeak-ng not found: the demo speaker is the harmonic synthetic voice, which the "
                      "reaction model does not hear as speech (apt-get install espeak-ng)", RuntimeWarning,
                      stacklevel=2)
    # the same speaker for the same length, seed and voice kind: synthesized once per process (text-to-speech
    # and voice detection, ~1 s of CPU for a 6 s clip); each call gets its own copy
    key = (T + W, int(seed), tts, tuple(au_map.names))
    if key not in _DEMO_SPEAKERS:
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
        jaw_unit = np.asarray(jaw_for_expression("mouth_open", 1.0), dtype=np.float64)
        if tts:
            from dataclasses import replace

            from .data import tts_speaker

            sp, _ = tts_speaker(rng, replace(cfg, still_face_fraction=0.0), au_map.names, jaw_unit)
        else:
            sp = synth_speaker(rng, cfg, au_map.names, jaw_unit)
        from ..cache import keep_recent

        keep_recent(_DEMO_SPEAKERS, key, sp, 4)
    import copy

    sp = copy.deepcopy(_DEMO_SPEAKERS[key])
    states = react(bundle, sp.waveform, cfg.audio.sample_rate, sp.state, pain=pain, temperature=temperature,
                   top_k=top_k, seed=seed, smoothing=smoothing)
    return flame_params_from_states(states[W:], au_map)
