"""Tokenizer, model, decoding, streaming, training with resume, checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holo_viewer.errors import InputError, ReactionError
from holo_viewer.reaction.data import SyntheticConfig, make_synthetic_split
from holo_viewer.reaction.model import ModelConfig, ReactionModel, generate, sample_tokens, state_shapes
from holo_viewer.reaction.tokens import fit_codebook
from holo_viewer.reaction.train import load_checkpoint, train, train_config_from_dict

TINY_DATA = {"seed": 5, "seconds": 3.2, "train_contexts": 3, "val_contexts": 1, "test_contexts": 1,
             "listeners_per_context": 2}
TINY_MODEL = {"d_model": 16, "n_heads": 2, "enc_layers": 1, "dec_layers": 1, "ff_dim": 32, "speaker_window": 16,
              "listener_window": 8, "k": 4, "dropout": 0.1}


@pytest.fixture(scope="module")
def tiny_splits():
    cfg = SyntheticConfig(**TINY_DATA)
    return {s: make_synthetic_split(s, cfg) for s in ("train", "val")}


def test_codebook_round_trip_and_errors():
    rng = np.random.default_rng(0)
    centres = rng.random((8, 5))
    x = centres[rng.integers(0, 8, 400)] + 0.001 * rng.standard_normal((400, 5))
    cb = fit_codebook(x, n_codes=8, iters=10)
    rec = cb.decode(cb.encode(x))
    assert np.abs(rec - x).max() < 0.02
    assert cb.encode(x.reshape(20, 20, 5)).shape == (20, 20)
    with pytest.raises(ReactionError, match="tokens"):
        cb.decode(np.array([8]))
    with pytest.raises(ReactionError, match="n_codes"):
        fit_codebook(x[:5], n_codes=8)


def test_sample_tokens_argmax_topk_and_coupling():
    g = torch.Generator().manual_seed(0)
    logits = torch.randn(64, 4, 30, generator=g)
    assert torch.equal(sample_tokens(logits, 0.0), logits.argmax(-1))
    assert torch.equal(sample_tokens(logits, 1.0, top_k=1, generator=g), logits.argmax(-1))
    top5 = torch.topk(logits, 5, dim=-1).indices
    s = sample_tokens(logits, 1.0, top_k=5, generator=g, coupled=False)
    assert bool((top5 == s[..., None]).any(-1).all())
    same = logits[:, :1].expand(-1, 4, -1)  # identical frames: coupled sampling picks one token per row
    c = sample_tokens(same, 1.0, generator=g)
    assert bool((c == c[:, :1]).all())
    assert len(set(c[:, 0].tolist())) > 3  # but rows differ
    with pytest.raises(InputError, match="temperature"):
        sample_tokens(logits, -1.0)
    with pytest.raises(InputError, match="top_k"):
        sample_tokens(logits, 1.0, top_k=0)


def _model(S=26, n_codes=32, seed=0):
    torch.manual_seed(seed)
    m = ReactionModel(ModelConfig(state_dim=S, n_codes=n_codes, **TINY_MODEL))
    return m.eval()


def test_model_shapes_and_streaming_is_causal():
    m = _model()
    B, T, S = 2, 40, 26
    g = torch.Generator().manual_seed(1)
    audio = torch.randn(B, T, 40, generator=g)
    sp = torch.rand(B, T, S, generator=g)
    cent = torch.rand(32, S, generator=g)
    logits = m(audio[:, :16], sp[:, :16], torch.rand(B, 8, S, generator=g), torch.tensor([0.0, 1.0]))
    assert logits.shape == (B, 4, 32)
    out = generate(m, cent, audio, sp, torch.tensor([0.2, 0.9]))
    assert out.shape == (B, T, S)
    # frames of window j (frames 4j .. 4j+3) only use speaker frames < 4j: change frames >= 16
    audio2, sp2 = audio.clone(), sp.clone()
    audio2[:, 16:] += 5.0
    sp2[:, 16:] = 0.0
    out2 = generate(m, cent, audio2, sp2, torch.tensor([0.2, 0.9]))
    torch.testing.assert_close(out2[:, :16], out[:, :16])
    assert not torch.allclose(out2, out)
    # sampling: seeded, reproducible, and diverse across seeds
    a = generate(m, cent, audio, sp, torch.tensor([0.2, 0.9]), temperature=1.0, seed=3)
    b = generate(m, cent, audio, sp, torch.tensor([0.2, 0.9]), temperature=1.0, seed=3)
    c = generate(m, cent, audio, sp, torch.tensor([0.2, 0.9]), temperature=1.0, seed=4)
    torch.testing.assert_close(a, b)
    assert not torch.allclose(a, c)
    # a window of streaming: the next k frames from a listener past
    nxt = generate(m, cent, audio, sp, torch.tensor([0.2, 0.9]), listener_past=out[:, :20], start=20, n_frames=4)
    assert nxt.shape == (B, 4, S)


@pytest.mark.parametrize("overrides", [{}, TINY_MODEL, {"d_model": 24, "n_heads": 3, "enc_layers": 3, "dec_layers": 1,
                                                  "ff_dim": 40, "n_mels": 6, "state_dim": 7, "n_codes": 9, "k": 3}])
def test_state_shapes_match_a_built_model(overrides):
    """The arithmetic shapes the checkpoint check uses equal a real model's state dict, key for key."""
    cfg = ModelConfig(**overrides)
    real = {k: tuple(v.shape) for k, v in ReactionModel(cfg).state_dict().items()}
    assert state_shapes(cfg) == real
    with pytest.raises(ReactionError, match="n_heads"):
        state_shapes(ModelConfig(**{**overrides, "n_heads": cfg.d_model + 1}))
    with pytest.raises(ReactionError, match="speaker_window"):
        state_shapes(ModelConfig(**{**overrides, "speaker_window": 7}))


def test_generate_stride_keeps_the_first_frames_of_each_window():
    """stride < k: each step predicts k frames and keeps the first ``stride``; the next step comes
    ``stride`` frames later and sees them (and the speaker up to there); stride = k is the default."""
    m = _model()
    B, T, S = 1, 22, 26
    g = torch.Generator().manual_seed(2)
    audio, sp, cent = torch.randn(B, T, 40, generator=g), torch.rand(B, T, S, generator=g), torch.rand(32, S, generator=g)
    pain = torch.tensor([0.3])
    full = generate(m, cent, audio, sp, pain, temperature=1.0, seed=5)
    torch.testing.assert_close(generate(m, cent, audio, sp, pain, temperature=1.0, seed=5, stride=4), full)
    half = generate(m, cent, audio, sp, pain, temperature=1.0, seed=5, stride=2)
    assert half.shape == (B, T, S)
    torch.testing.assert_close(half[:, :2], full[:, :2])  # the first window: same logits, same variate
    assert not torch.allclose(half, full)
    # causal at the stride: a change of the speaker from frame 6 on reaches frames >= 6 only
    audio2 = audio.clone()
    audio2[:, 6:] += 5.0
    half2 = generate(m, cent, audio2, sp, pain, temperature=1.0, seed=5, stride=2)
    torch.testing.assert_close(half2[:, :6], half[:, :6])
    with pytest.raises(InputError, match="stride"):
        generate(m, cent, audio, sp, pain, stride=5)


def test_generate_rejects_bad_inputs():
    m = _model()
    cent = torch.rand(32, 26)
    audio, sp = torch.randn(1, 20, 40), torch.rand(1, 20, 26)
    with pytest.raises(InputError, match="pain"):
        generate(m, cent, audio, sp, torch.tensor([1.5]))
    with pytest.raises(InputError, match="speaker"):
        generate(m, cent, audio, sp[:, :10], torch.tensor([0.5]))
    with pytest.raises(ReactionError, match="outside the clip"):
        generate(m, cent, audio, sp, torch.tensor([0.5]), n_frames=30)


def _tiny_cfg(steps: int):
    return train_config_from_dict({"data": TINY_DATA, "model": TINY_MODEL, "n_codes": 32, "batch_size": 8,
                                   "max_steps": steps, "eval_every": 2, "val_windows": 16, "patience": 100,
                                   "threads": 1, "warmup": 2})


def test_training_resume_matches_uninterrupted_run(tmp_path, tiny_splits):
    full = train(_tiny_cfg(6), tmp_path / "full.pt", progress=False, splits=tiny_splits, log=lambda m: None)

    class Stop(Exception):
        pass

    def stop_at_4(msg):
        if msg.startswith("step 4"):
            raise Stop

    with pytest.raises(Stop):
        train(_tiny_cfg(6), tmp_path / "cut.pt", progress=False, splits=tiny_splits, log=stop_at_4)
    assert (tmp_path / "cut.pt.partial.pt").is_file() and not (tmp_path / "cut.pt").exists()
    resumed = train(_tiny_cfg(6), tmp_path / "cut.pt", resume=True, progress=False, splits=tiny_splits,
                    log=lambda m: None)
    assert not (tmp_path / "cut.pt.partial.pt").exists()
    for k, v in full.model.state_dict().items():
        torch.testing.assert_close(resumed.model.state_dict()[k], v, msg=k)
    loaded = load_checkpoint(tmp_path / "full.pt")
    assert loaded.meta["steps"] == 6 and len(loaded.meta["history"]) == 3
    np.testing.assert_array_equal(loaded.codebook.centroids, full.codebook.centroids)


def test_time_budget_counts_cpu_not_the_wall_clock(tmp_path, tiny_splits, monkeypatch):
    """A busy machine (the wall clock racing ahead) must not cut the run: the budget is CPU minutes."""
    import time as _time

    real = _time.time
    calls = [0]

    def racing():
        calls[0] += 1
        return real() + 3600.0 * calls[0]  # an hour of wall time per call

    cfg = train_config_from_dict({**_tiny_cfg(4).to_dict(), "max_minutes": 1.0})
    monkeypatch.setattr(_time, "time", racing)
    b = train(cfg, tmp_path / "busy.pt", progress=False, splits=tiny_splits, log=lambda m: None)
    monkeypatch.setattr(_time, "time", real)
    assert b.meta["stopped"] == "max_steps" and b.meta["steps"] == 4 and b.meta["cpu_minutes"] < 1.0
    cut = train(train_config_from_dict({**_tiny_cfg(4).to_dict(), "max_minutes": 1e-9}), tmp_path / "cut.pt",
                progress=False, splits=tiny_splits, log=lambda m: None)
    assert cut.meta["stopped"] == "time_budget" and cut.meta["steps"] == 2


def test_checkpoint_errors(tmp_path):
    with pytest.raises(ReactionError, match="not found"):
        load_checkpoint(tmp_path / "nope.pt")
    (tmp_path / "junk.pt").write_bytes(b"junk")
    with pytest.raises(ReactionError, match="not a readable"):
        load_checkpoint(tmp_path / "junk.pt")
    torch.save({"a": 1}, tmp_path / "other.pt")
    with pytest.raises(ReactionError, match="not a holo_viewer reaction checkpoint"):
        load_checkpoint(tmp_path / "other.pt")
    with pytest.raises(ReactionError, match="unknown keys"):
        train_config_from_dict({"max_step": 3})


def test_smooth_states_is_causal_streamable_and_removes_jumps():
    from holo_viewer.reaction.api import smooth_states

    rng = np.random.default_rng(3)
    # piecewise constant like token output: a new value every 8 frames
    x = np.repeat(rng.normal(size=(6, 4)), 8, axis=0)
    y = smooth_states(x, 0.12, fps=25)
    assert y.shape == x.shape
    assert np.abs(np.diff(y, axis=0)).max() < 0.5 * np.abs(np.diff(x, axis=0)).max()
    # causal: the first k outputs depend only on the first k inputs
    x2 = x.copy()
    x2[20:] += 5.0
    assert np.array_equal(smooth_states(x2, 0.12)[:20], y[:20])
    # streaming in two windows with the carried state equals one call
    a = smooth_states(x[:13], 0.12)
    b = smooth_states(x[13:], 0.12, initial=a[-1])
    assert np.allclose(np.concatenate([a, b]), y, atol=1e-12)
    # converges to a held value; zero time constant is the identity
    held = smooth_states(np.repeat(x[:1] * 0 + 1.0, 60, axis=0), 0.12, initial=np.zeros(4))
    assert abs(held[-1] - 1.0).max() < 1e-6
    assert np.array_equal(smooth_states(x, 0.0), x)


def test_demo_reaction_is_smooth():
    from holo_viewer.reaction.api import generate_demo_reaction

    raw = generate_demo_reaction(seconds=2.0, pain=0.6, seed=0, smoothing=0.0)["expr"]
    smooth = generate_demo_reaction(seconds=2.0, pain=0.6, seed=0)["expr"]
    assert raw.shape == smooth.shape
    assert np.abs(np.diff(smooth, axis=0)).max() < np.abs(np.diff(raw, axis=0)).max()
    assert len(np.unique(smooth.round(5), axis=0)) > len(np.unique(raw.round(5), axis=0))
