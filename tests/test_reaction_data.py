"""Synthetic dyadic data, the attribute map, face-state <-> FLAME, and the REACT-format reader."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from holo_viewer.errors import InputError, ReactionError
from holo_viewer.flame.expressions import default_au_map, pspi
from holo_viewer.reaction.data import SyntheticConfig, make_synthetic_split
from holo_viewer.reaction.features import (EXPRESSION_CLASSES, REACT_AU_NAMES, attributes_from_react_aus,
                                           flame_from_state, state_from_flame)
from holo_viewer.reaction.react_format import load_react_split, read_attribute_csv

SMALL = SyntheticConfig(seed=3, seconds=4.0, train_contexts=2, val_contexts=2, test_contexts=3,
                        listeners_per_context=3)


@pytest.fixture(scope="module")
def split():
    return make_synthetic_split("test", SMALL, keep_waveforms=True)


def test_synthetic_split_shapes_and_determinism(split):
    au = default_au_map()
    N, T, S = 9, 100, len(au.names) + 6
    assert split.listener_state.shape == split.speaker_state.shape == (N, T, S)
    assert split.listener_attr.shape == (N, T, 25)
    assert split.audio.shape == (3, T, 40) and split.waveforms.shape == (3, T * 640)
    again = make_synthetic_split("test", SMALL)
    np.testing.assert_array_equal(again.listener_state, split.listener_state)
    np.testing.assert_array_equal(again.audio, split.audio)
    other = make_synthetic_split("test", SyntheticConfig(**{**SMALL.__dict__, "seed": 4}))
    assert not np.allclose(other.listener_state, split.listener_state)


def test_neighbour_matrix_groups_listeners_of_one_context(split):
    nb = split.neighbour
    assert np.all(np.diag(nb) == 1)
    np.testing.assert_array_equal(nb, split.context[:, None] == split.context[None, :])
    assert nb.sum(axis=1).tolist() == [3] * 9
    assert 0.2 <= split.lag_s.min() and split.lag_s.max() <= 1.0
    assert set(split.style) <= {"mirror", "backchannel", "mixed"}


def test_cue_lag_jitter_spreads_each_listeners_backchannels(split):
    """cue_lag_jitter_s 0 keeps one lag per listener (the data bit for bit as without it); J > 0 draws
    each cue's lag around the listener's own, inside [0.2, 1.0] s, and moves only backchannels."""
    from holo_viewer.reaction.data import LAG_RANGE_S, cue_lags

    assert cue_lags(0.37, 5, 0.0, None).tolist() == [0.37] * 5
    rng = np.random.default_rng(0)
    means, stds = [], []
    for lag in np.linspace(0.2, 1.0, 41):
        x = cue_lags(float(lag), 400, 0.3, rng)
        assert LAG_RANGE_S[0] <= x.min() and x.max() <= LAG_RANGE_S[1]
        means.append(abs(x.mean() - lag))
        stds.append(x.std())
    assert np.median(means) < 0.06 and 0.12 < np.median(stds) < 0.18  # U(-0.3, 0.3): std 0.173 before reflection
    pooled = np.concatenate([cue_lags(float(lag), 50, 0.3, rng) for lag in rng.uniform(0.2, 1.0, 400)])
    assert np.histogram(pooled, bins=8, range=LAG_RANGE_S)[0].min() > 0.08 * pooled.size  # still spread over the range
    zero = make_synthetic_split("test", SyntheticConfig(**{**SMALL.__dict__, "cue_lag_jitter_s": 0.0}))
    np.testing.assert_array_equal(zero.listener_state, split.listener_state)
    jit = make_synthetic_split("test", SyntheticConfig(**{**SMALL.__dict__, "cue_lag_jitter_s": 0.3}))
    np.testing.assert_array_equal(jit.speaker_state, split.speaker_state)
    np.testing.assert_array_equal(jit.lag_s, split.lag_s)
    moved = np.abs(jit.listener_state - split.listener_state).max(axis=(1, 2)) > 1e-6
    assert moved.any() and not moved[[s == "mirror" for s in split.style]].any()
    # cue_smile_prob: how often a backchannel listener smiles at a cue (0 = only the mirrored smiles)
    ten = SyntheticConfig(seed=3, seconds=10.0, train_contexts=1, val_contexts=1, test_contexts=2, listeners_per_context=3)
    some, none = (make_synthetic_split("test", SyntheticConfig(**{**ten.__dict__, "cue_smile_prob": p})) for p in (0.7, 0.0))
    au12 = list(some.au_names).index("AU12")
    back = np.asarray([s != "mirror" for s in some.style])
    assert back.any() and some.listener_state[back, :, au12].max() > 0.2  # AU12 / 5: a smile of >= 1
    only = np.asarray([s == "backchannel" for s in some.style])  # mixed listeners also mirror the speaker's smile
    assert only.any() and none.listener_state[only, :, au12].max() < 0.1


def test_speech_like_audio_and_face_follow_speech(split):
    w = split.waveforms[0]
    assert np.abs(w).max() <= 1.0
    # frame energy of the audio correlates with the speaker's jaw opening (face moves with speech)
    energy = np.log((w.reshape(-1, 640) ** 2).mean(axis=1) + 1e-8)
    n_au = len(split.au_names)
    clip = int(np.flatnonzero(split.context == 0)[0])
    jaw = split.speaker_state[clip, :, n_au]
    assert np.corrcoef(energy, jaw)[0, 1] > 0.5
    # pauses exist: some frames are near silent
    assert (energy < energy.max() - 6).mean() > 0.1


def test_pain_raises_pspi(split):
    au = default_au_map()
    expr = np.stack([flame_from_state(s, au)["expr"] for s in split.listener_state])
    mean_pspi = pspi(expr.astype(np.float64), au).mean(axis=1)
    order = np.argsort(split.pain)
    assert np.corrcoef(split.pain, mean_pspi)[0, 1] > 0.9
    assert mean_pspi[order[-1]] > mean_pspi[order[0]] + 2.0


def test_attribute_map_properties():
    a = np.zeros((2, 15))
    a[1, REACT_AU_NAMES.index("AU12")] = 1.0
    a[1, REACT_AU_NAMES.index("AU6")] = 1.0
    out = attributes_from_react_aus(a)
    assert out.shape == (2, 25)
    np.testing.assert_allclose(out[:, 17:].sum(axis=1), 1.0)
    assert np.argmax(out[0, 17:]) == EXPRESSION_CLASSES.index("Neutral")
    assert np.argmax(out[1, 17:]) == EXPRESSION_CLASSES.index("Happy")
    assert out[1, 15] > 0.5 > out[0, 15] == 0.0  # smiling raises valence
    with pytest.raises(InputError, match="aus01"):
        attributes_from_react_aus(np.zeros((3, 14)))


def test_state_flame_round_trip():
    au = default_au_map()
    rng = np.random.default_rng(0)
    S = len(au.names) + 6
    st = rng.random((7, S)) * 0.8
    st[:, len(au.names):] = rng.normal(0, 0.1, (7, 6))
    fl = flame_from_state(st, au)
    back = state_from_flame(fl["expr"], fl["jaw_pose"], fl["rotation"], au)
    np.testing.assert_allclose(back, st, atol=1e-5)
    with pytest.raises(InputError, match="jaw_pose"):
        state_from_flame(fl["expr"], fl["jaw_pose"][:3], fl["rotation"], au)


def _write_csv(path, data, header=True):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        if header:
            w.writerow([f"c{i}" for i in range(data.shape[1])])
        w.writerows(data.tolist())


def test_react_format_reader(tmp_path):
    rng = np.random.default_rng(0)
    root = tmp_path / "react"
    clips = ["NoXI/a/1", "NoXI/b/1"]
    for c in clips:
        _write_csv(root / "val" / "Emotion" / f"{c}.csv", rng.random((12, 25)))
        (root / "val" / "3D_FV_files" / c).parent.mkdir(parents=True, exist_ok=True)
        np.save(root / "val" / "3D_FV_files" / f"{c}.npy", rng.random((12, 1, 58)).astype(np.float32))
    (root / "val.csv").write_text("idx,speaker,listener\n0,NoXI/a/1,NoXI/b/1\n")
    np.save(root / "neighbour_emotion_val.npy", np.eye(2))
    d = load_react_split(root, "val", frames=10)
    assert d.pairs == (("NoXI/a/1", "NoXI/b/1"), ("NoXI/b/1", "NoXI/a/1"))  # mirrored like the official loader
    assert d.speaker_attr.shape == (2, 10, 25) and d.listener_3dmm.shape == (2, 10, 58)
    np.testing.assert_allclose(d.speaker_attr[0], d.listener_attr[1])
    np.testing.assert_allclose(d.speaker_attr[0], read_attribute_csv(root / "val/Emotion/NoXI/a/1.csv")[:10])
    assert d.neighbour.shape == (2, 2)
    with pytest.raises(ReactionError, match="at least 20 frames"):
        load_react_split(root, "val", frames=20)
    np.save(root / "neighbour_emotion_val.npy", np.eye(3))
    with pytest.raises(ReactionError, match=r"expected shape \(2, 2\)"):
        load_react_split(root, "val", frames=10)
    _write_csv(root / "val" / "Emotion" / "NoXI/a/1.csv", rng.random((12, 24)))
    with pytest.raises(ReactionError, match="25 columns"):
        load_react_split(root, "val", frames=10)
    with pytest.raises(ReactionError, match="split list not found"):
        load_react_split(root, "test")
