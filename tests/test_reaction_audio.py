"""Audio features: torch log-mel against the direct numpy computation; bad inputs; WAV I/O."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holo_viewer.errors import InputError, ReactionError
from holo_viewer.reaction.audio import AudioConfig, log_mel, log_mel_reference, mel_filter_bank, read_wav, write_wav


def _tone(seconds: float = 1.0, sr: int = 16000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * sr)) / sr
    env = 0.5 + 0.5 * np.sin(2 * np.pi * 4 * t)
    return (env * np.sin(2 * np.pi * 180 * t) + 0.05 * rng.standard_normal(t.size)).astype(np.float32)


def test_torch_log_mel_matches_numpy_reference():
    x = _tone(1.0)
    got = log_mel(x, 16000).numpy()
    ref = log_mel_reference(x, 16000)
    assert got.shape == ref.shape == (25, 40)
    # float32 STFT vs float64: log-mel values agree to 1e-3 absolute where the band has energy
    np.testing.assert_allclose(got, ref, atol=2e-3, rtol=1e-4)


def test_log_mel_frame_count_and_padding():
    x = _tone(1.0)
    assert log_mel(x, 16000, n_frames=25).shape == (25, 40)
    assert log_mel(x[:-300], 16000, n_frames=25).shape == (25, 40)  # short by < 1 frame: zero-padded
    assert log_mel(torch.from_numpy(x), 16000).dtype == torch.float32


def test_mel_filter_bank_shape_and_peaks():
    fb = mel_filter_bank(AudioConfig())
    assert fb.shape == (513, 40)
    assert np.all(fb >= 0) and np.all(fb.max(axis=0) <= 1.0 + 1e-12)
    assert np.all(fb.sum(axis=0) > 0)  # no empty filter


def test_bad_audio_inputs():
    x = _tone(1.0)
    with pytest.raises(ReactionError, match="sample_rate: expected 16000 Hz, found 44100"):
        log_mel(x, 44100)
    with pytest.raises(ReactionError, match="length mismatch"):
        log_mel(x, 16000, n_frames=50)
    bad = x.copy()
    bad[100] = np.nan
    with pytest.raises(InputError, match="NaN"):
        log_mel(bad, 16000)
    with pytest.raises(InputError, match="audio"):
        log_mel(np.zeros((2, 16000)), 16000)
    with pytest.raises(ReactionError, match="at least"):
        log_mel(np.zeros(100), 16000)


def test_wav_round_trip(tmp_path):
    x = 0.5 * _tone(0.5)
    with pytest.raises(InputError, match="peak"):
        write_wav(tmp_path / "loud.wav", 2.0 * x, 16000)
    p = write_wav(tmp_path / "a.wav", x, 16000)
    y, sr = read_wav(p)
    assert sr == 16000
    np.testing.assert_allclose(y, x, atol=1.0 / 32767 + 1e-6)
    with pytest.raises(ReactionError, match="not found"):
        read_wav(tmp_path / "missing.wav")
    (tmp_path / "junk.wav").write_bytes(b"not a wav")
    with pytest.raises(ReactionError, match="not a readable WAV"):
        read_wav(tmp_path / "junk.wav")
