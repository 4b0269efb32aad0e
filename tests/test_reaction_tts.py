"""Text-to-speech training speakers (reaction.tts, reaction.data with voices="tts")."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.errors import ReactionError
from holo_viewer.reaction.data import SyntheticConfig, listener_cues, make_synthetic_split
from holo_viewer.reaction.speech import N_SPEECH_FEATURES, pause_onsets
from holo_viewer.reaction.train import train_config_from_dict
from holo_viewer.reaction.tts import HELD_OUT_VOICES, TRAIN_VOICES, espeak_available, sentence, tts_clip

needs_espeak = pytest.mark.skipif(not espeak_available(), reason="espeak-ng not installed (apt-get install espeak-ng)")


def test_held_out_voices_never_drawn():
    variants = {v.split("+")[1] for v in TRAIN_VOICES}
    assert not variants & {v.split("+")[1] for v in HELD_OUT_VOICES}
    rng = np.random.default_rng(0)
    assert all("{" not in sentence(rng) for _ in range(50))


@needs_espeak
def test_tts_split_is_deterministic_and_listeners_follow_detected_pauses():
    cfg = SyntheticConfig(seconds=8.0, train_contexts=1, listeners_per_context=3, voices="tts",
                          audio_features="speech", still_face_fraction=1.0)
    a = make_synthetic_split("train", cfg)
    b = make_synthetic_split("train", cfg)
    np.testing.assert_array_equal(a.audio, b.audio)
    np.testing.assert_array_equal(a.listener_state, b.listener_state)
    assert a.audio.shape == (1, 200, N_SPEECH_FEATURES)
    assert not a.speaker_state.any()  # still faces
    assert "mirror" not in a.style  # nothing to mirror on a still face
    n_au = len(a.au_names)
    for i in range(a.n_clips):
        feats = a.audio[a.context[i]]
        cues = listener_cues(feats)
        assert set(pause_onsets(feats[:, 0], feats[:, 1])) <= set(cues)
        pitch = a.listener_state[i, :, n_au + 3]
        lag = int(round(float(a.lag_s[i]) * 25))
        # a backchannel nod (0.08-0.15 rad) peaks 0.4 s after cue + lag at most frames
        peaks = [pitch[min(c + lag + 10, 199)] for c in cues if c + lag + 10 < 200]
        if peaks:
            assert max(peaks) > 0.05


@needs_espeak
def test_tts_clip_length_and_level():
    x, voice = tts_clip(np.random.default_rng(3), 5.0)
    assert x.shape == (80000,) and x.dtype == np.float32 and voice in TRAIN_VOICES
    assert 10 ** (-30 / 20) * 0.99 <= np.abs(x).max() <= 10 ** (-1 / 20) * 1.01


def test_unknown_data_kinds_are_named():
    with pytest.raises(ReactionError, match="data.voices.*'tts'.*'robot'"):
        train_config_from_dict({"data": {"voices": "robot"}})
    with pytest.raises(ReactionError, match="data.audio_features"):
        train_config_from_dict({"data": {"audio_features": "mfcc"}})


@needs_espeak
def test_live_synthetic_speaker_is_heard_as_speech(monkeypatch):
    """``live --synthetic`` and the talking-head clip speak with a text-to-speech voice the model hears
    (VAD speech, pause onsets); without espeak-ng the harmonic voice comes with a warning naming it."""
    from holo_viewer.pipeline.live_support import SyntheticSpeaker, speaker_clip
    from holo_viewer.reaction.speech import speech_features

    syn = SyntheticSpeaker(10.0, seed=1)
    assert syn.waveform.shape == (250 * 640,) and syn.states.shape[0] == 250
    f = speech_features(syn.waveform, 16000)
    assert 0.3 < np.mean(f[:, 0] >= 0.5) < 0.95 and len(pause_onsets(f[:, 0], f[:, 1])) >= 1
    assert np.ptp(syn.states[:, :-6], axis=0).max() > 0.5  # its face moves with the voice
    monkeypatch.setattr("holo_viewer.reaction.tts.shutil.which", lambda name: None)
    with pytest.warns(RuntimeWarning, match="espeak-ng not found.*harmonic voice"):
        sp = speaker_clip(10.0, 1, 16)
    assert sp.waveform.shape[0] >= 250 * 640


@needs_espeak
def test_speaker_clip_is_synthesized_once_per_process_and_each_caller_gets_a_copy():
    """speaker_clip keeps this process's clips: the same arguments give equal arrays without synthesizing again,
    and a caller writing into its copy changes no other caller's."""
    from holo_viewer.pipeline import live_support

    a = live_support.speaker_clip(10.0, 0, 16)
    key = (10.0, 0, 16, True)
    assert key in live_support._CLIPS
    b = live_support.speaker_clip(4.0, 0, 16)  # at least 10 s are synthesized: the same clip
    for name in ("waveform", "state", "talking", "pause_onsets", "smile", "brow"):
        assert getattr(a, name) is not getattr(b, name)
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    b.waveform[:] = 0.0
    b.state[:] = 0.0
    c = live_support.speaker_clip(10.0, 0, 16)
    np.testing.assert_array_equal(c.waveform, a.waveform)
    np.testing.assert_array_equal(c.state, a.state)
    assert np.abs(a.waveform).max() > 0.01  # a voice, not the zeros written into b
