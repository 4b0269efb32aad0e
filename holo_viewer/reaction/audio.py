"""Speaker audio features at the video frame rate: log-mel frames computed with torch.

Frame ``i`` of a clip is the short-time spectrum centred on sample ``i * hop`` (time ``i / 25`` s,
the timestamp of video frame ``i``): Hann window (periodic) of ``n_fft`` samples, reflect
padding of ``n_fft // 2`` at both ends (``torch.stft(center=True)``), power spectrum,
an HTK-mel triangular filter bank, ``log(mel + eps)``.

:func:`log_mel` is the torch fast path; :func:`log_mel_reference` is the direct numpy
computation (explicit frame loop, ``numpy.fft.rfft``) it is tested against.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, ReactionError
from ..validation import check_array

__all__ = ["AudioConfig", "mel_filter_bank", "log_mel", "log_mel_reference", "read_wav", "write_wav",
           "check_audio_length"]


@dataclass(frozen=True)
class AudioConfig:
    """Log-mel settings. ``hop = sample_rate / fps`` samples (640 at 16 kHz, 25 fps)."""

    sample_rate: int = 16000
    fps: int = 25
    n_fft: int = 1024
    n_mels: int = 40
    fmin: float = 60.0
    fmax: float = 7600.0
    eps: float = 1e-6

    @property
    def hop(self) -> int:
        """Samples per video frame."""
        return self.sample_rate // self.fps


def _hz_to_mel(f: np.ndarray) -> np.ndarray:
    return 2595.0 * np.log10(1.0 + np.asarray(f, dtype=np.float64) / 700.0)


def _mel_to_hz(m: np.ndarray) -> np.ndarray:
    return 700.0 * (10.0 ** (np.asarray(m, dtype=np.float64) / 2595.0) - 1.0)


def mel_filter_bank(config: AudioConfig = AudioConfig()) -> np.ndarray:
    """HTK-mel triangular filters, shape (n_fft // 2 + 1, n_mels), float64, peak 1 per filter."""
    n_bins = config.n_fft // 2 + 1
    freqs = np.arange(n_bins) * config.sample_rate / config.n_fft
    mel_pts = np.linspace(_hz_to_mel(config.fmin), _hz_to_mel(config.fmax), config.n_mels + 2)
    hz = _mel_to_hz(mel_pts)
    lo, ce, hi = hz[:-2], hz[1:-1], hz[2:]
    up = (freqs[:, None] - lo[None, :]) / (ce - lo)[None, :]
    down = (hi[None, :] - freqs[:, None]) / (hi - ce)[None, :]
    return np.clip(np.minimum(up, down), 0.0, None)


def check_audio_length(n_samples: int, n_frames: int, config: AudioConfig, name: str = "audio") -> None:
    """Raise :class:`ReactionError` unless ``n_samples`` covers ``n_frames`` video frames within one frame."""
    expected = n_frames * config.hop
    if abs(n_samples - expected) > config.hop:
        raise ReactionError(
            f"{name}: length mismatch: {n_frames} video frames at {config.fps} fps need "
            f"{expected} samples ({expected / config.sample_rate:.3f} s) at {config.sample_rate} Hz, "
            f"found {n_samples} samples ({n_samples / config.sample_rate:.3f} s)")


def _validate(audio, sample_rate: int, n_frames: int | None, config: AudioConfig) -> tuple[np.ndarray | object, int]:
    if int(sample_rate) != config.sample_rate:
        raise ReactionError(f"sample_rate: expected {config.sample_rate} Hz, found {sample_rate} Hz; "
                            f"resample the speaker audio to {config.sample_rate} Hz mono first")
    audio = check_array(audio, "audio", ("L",))
    n = int(audio.shape[0])
    if n_frames is None:
        n_frames = n // config.hop
    else:
        check_audio_length(n, int(n_frames), config)
    if n_frames < 1 or n <= config.n_fft // 2:
        raise ReactionError(f"audio: expected at least {config.n_fft // 2 + 1} samples "
                            f"({(config.n_fft // 2 + 1) / config.sample_rate:.3f} s), found {n}")
    return audio, int(n_frames)


def _fit_length(x, n_frames: int, hop: int, xp):
    need = n_frames * hop
    if x.shape[0] >= need:
        return x[:need]
    if xp is np:
        return np.concatenate([x, np.zeros(need - x.shape[0], dtype=x.dtype)])
    import torch

    return torch.cat([x, x.new_zeros(need - x.shape[0])])


def log_mel(audio, sample_rate: int, n_frames: int | None = None, config: AudioConfig = AudioConfig()):
    """Log-mel frames of a mono waveform with ``torch.stft``.

    Parameters
    ----------
    audio : numpy.ndarray or torch.Tensor, shape (L,)
        Mono waveform in [-1, 1] at ``sample_rate``.
    sample_rate : int
        Must equal ``config.sample_rate`` (16 kHz); other rates raise :class:`ReactionError`.
    n_frames : int, optional
        Number of video frames the audio belongs to; the audio must span them within one
        frame (``|L - n_frames * hop| <= hop``) and is cut or zero-padded to exactly that.
        Default ``L // hop``.
    config : AudioConfig

    Returns
    -------
    torch.Tensor, shape (n_frames, n_mels), float32
        ``log(mel power + eps)`` per video frame.

    Raises
    ------
    ReactionError
        Wrong sample rate, audio/frames length mismatch, audio too short.
    InputError
        NaN/inf samples or a non-1-D array.
    """
    import torch

    audio, n_frames = _validate(audio, sample_rate, n_frames, config)
    x = audio if isinstance(audio, torch.Tensor) else torch.from_numpy(np.asarray(audio, dtype=np.float32))
    x = _fit_length(x.to(torch.float32), n_frames, config.hop, torch)
    window = torch.hann_window(config.n_fft, periodic=True, dtype=torch.float32)
    spec = torch.stft(x, n_fft=config.n_fft, hop_length=config.hop, win_length=config.n_fft, window=window,
                      center=True, pad_mode="reflect", return_complex=True)  # (F, frames)
    power = spec.real ** 2 + spec.imag ** 2
    fb = torch.from_numpy(mel_filter_bank(config).astype(np.float32))
    mel = power[:, :n_frames].T @ fb
    return torch.log(mel + config.eps)


def log_mel_reference(audio: np.ndarray, sample_rate: int, n_frames: int | None = None,
                      config: AudioConfig = AudioConfig()) -> np.ndarray:
    """Direct float64 numpy log-mel (explicit frame loop); the reference for :func:`log_mel`."""
    audio, n_frames = _validate(np.asarray(audio), sample_rate, n_frames, config)
    x = _fit_length(np.asarray(audio, dtype=np.float64), n_frames, config.hop, np)
    half = config.n_fft // 2
    padded = np.pad(x, half, mode="reflect")
    n = np.arange(config.n_fft)
    window = 0.5 - 0.5 * np.cos(2.0 * np.pi * n / config.n_fft)
    fb = mel_filter_bank(config)
    out = np.empty((n_frames, config.n_mels))
    for i in range(n_frames):
        seg = padded[i * config.hop: i * config.hop + config.n_fft] * window
        p = np.abs(np.fft.rfft(seg)) ** 2
        out[i] = np.log(p @ fb + config.eps)
    return out


def _check_data_chunk(p: Path) -> None:
    """Refuse a RIFF/WAVE file with a chunk (``fmt``, ``data``, ...) declaring more bytes than the file holds.

    scipy allocates the declared size before reading (a 1.6 kB file declaring 268 MB of
    samples allocated 268 MB); checked here first, from the chunk headers alone.
    """
    import struct

    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(12)
        if len(head) < 12 or head[:4] != b"RIFF" or head[8:12] != b"WAVE":
            return  # scipy reports what it is
        pos = 12
        for _ in range(1000):  # chunk headers, never the samples
            fh.seek(pos)
            chunk = fh.read(8)
            if len(chunk) < 8:
                return
            cid, csize = chunk[:4], struct.unpack("<I", chunk[4:])[0]
            if csize > size - pos - 8:
                name = cid.decode("latin1")
                raise ReactionError(f"{p}: truncated WAV file (its {name!r} chunk declares {csize:,} bytes, the "
                                    f"file holds {size - pos - 8:,} after the chunk header)")
            if cid == b"data":
                return
            pos += 8 + csize + (csize & 1)


def read_wav(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """Read a WAV file as mono float32 in [-1, 1] and its sample rate.

    Integer PCM is scaled by its full range; stereo is averaged to mono.

    Raises
    ------
    ReactionError
        Missing, unreadable, corrupt or truncated file (whatever scipy's parser raises).
    InputError
        NaN/inf samples.
    """
    from scipy.io import wavfile

    p = Path(path)
    if not p.is_file():
        raise ReactionError(f"{p}: audio file not found")
    _check_data_chunk(p)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", wavfile.WavFileWarning)
            sr, data = wavfile.read(p)
        for w in caught:
            if "EOF prematurely" in str(w.message):
                raise ReactionError(f"{p}: truncated WAV file ({w.message})")
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    except ReactionError:
        raise
    except MemoryError as exc:
        raise ReactionError(f"{p}: not a readable WAV file (its header claims more data than fits in memory)") from exc
    except Exception as exc:  # noqa: BLE001 - scipy's parser of untrusted bytes raises ValueError, OSError,
        # EOFError, struct.error, IndexError and even UnboundLocalError (seen on a corrupt fmt chunk)
        raise ReactionError(f"{p}: not a readable WAV file ({type(exc).__name__}: {exc})") from exc
    if data.dtype == np.uint8:
        x = (data.astype(np.float32) - 128.0) / 128.0
    elif np.issubdtype(data.dtype, np.integer):
        x = data.astype(np.float32) / float(np.iinfo(data.dtype).max)
    else:
        x = data.astype(np.float32)
    if x.ndim == 2:
        x = x.mean(axis=1)
    if x.ndim != 1 or x.size == 0:
        raise ReactionError(f"{p}: expected a mono or stereo waveform, found shape {data.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(f"{p}: audio holds {int((~np.isfinite(x)).sum())} NaN/inf samples")
    return x, int(sr)


def write_wav(path: str | os.PathLike, audio: np.ndarray, sample_rate: int) -> Path:
    """Write mono float audio in [-1, 1] as 16-bit PCM WAV, atomically."""
    from scipy.io import wavfile

    from ..fileio import atomic_path

    x = np.asarray(check_array(audio, "audio", ("L",)), dtype=np.float64)
    if x.size and np.abs(x).max() > 1.0:
        raise InputError(f"audio: expected samples in [-1, 1] for 16-bit PCM, found peak {np.abs(x).max():.4f}")
    pcm = np.clip(np.rint(x * 32767.0), -32768, 32767).astype(np.int16)
    with atomic_path(path) as tmp:
        wavfile.write(tmp, int(sample_rate), pcm)
    return Path(path)
