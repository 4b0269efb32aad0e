"""The shipped checkpoint: `holo-viewer react`, the demo function, pain following and the acceptance table."""

from __future__ import annotations

import numpy as np
import pytest

from holo_viewer.cli import main
from holo_viewer.flame.expressions import default_au_map, jaw_for_expression, pspi
from holo_viewer.reaction.api import default_checkpoint_path, flame_params_from_states, load_default_bundle
from holo_viewer.reaction.audio import write_wav
from holo_viewer.reaction.data import SyntheticConfig, make_synthetic_split, synth_speaker

pytestmark = pytest.mark.skipif(not default_checkpoint_path().is_file(),
                                reason="assets/reaction_default.pt missing (train it with holo-viewer train-reaction)")

FLAME_KEYS = {"expr", "jaw_pose", "rotation", "neck_pose", "eyes_pose", "translation", "shape"}


@pytest.fixture(scope="module")
def speaker_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("speaker")
    au = default_au_map()
    cfg = SyntheticConfig(seconds=2.0)
    sp = synth_speaker(np.random.default_rng(11), cfg, au.names, jaw_for_expression("mouth_open", 1.0))
    write_wav(d / "s.wav", sp.waveform, 16000)
    write_wav(d / "s8k.wav", sp.waveform[::2], 8000)
    write_wav(d / "short.wav", sp.waveform[:16000], 16000)
    fl = flame_params_from_states(sp.state, au)
    np.savez(d / "s.npz", **fl)
    np.savez(d / "past.npz", **flame_params_from_states(sp.state[:10] * 0.5, au))
    bad = dict(fl)
    bad["expr"] = fl["expr"].copy()
    bad["expr"][3, 0] = np.nan
    np.savez(d / "nan.npz", **bad)
    return d


def test_react_cli_writes_flame_params(speaker_files, tmp_path):
    d = speaker_files
    out = tmp_path / "out.npz"
    rc = main(["react", "--audio", str(d / "s.wav"), "--speaker", str(d / "s.npz"), "--pain", "0.7",
               "--listener-past", str(d / "past.npz"), "--out", str(out)])
    assert rc == 0
    z = np.load(out)
    assert set(z.files) == FLAME_KEYS | {"pain_shown"}  # the pain in the face per frame (behaviour layers)
    au = default_au_map()
    assert z["expr"].shape == (50, au.matrix.shape[1])
    assert z["jaw_pose"].shape == z["rotation"].shape == (50, 3) and z["eyes_pose"].shape == (50, 6)
    assert all(np.all(np.isfinite(z[k])) for k in z.files)
    assert float(pspi(z["expr"].astype(np.float64), au).mean()) > 4.0  # pain 0.7 shows


def test_react_cli_behaviour_by_default_and_switches(speaker_files, tmp_path):
    """Gaze, blinks, breathing and sway are on by default; each flag and --no-behaviour switch them off."""
    d = speaker_files
    base = ["react", "--audio", str(d / "s.wav"), "--speaker", str(d / "s.npz"), "--pain", "0.3"]
    outs = {}
    for name, flags in (("on", []), ("off", ["--no-behaviour"]), ("nogaze", ["--no-gaze", "--no-breathing"]),
                        ("side", ["--viewer-angle", "20"])):
        outs[name] = tmp_path / f"{name}.npz"
        assert main(base + flags + ["--out", str(outs[name])]) == 0
    on, off, nogaze, side = (np.load(outs[k]) for k in ("on", "off", "nogaze", "side"))
    assert np.ptp(on["eyes_pose"], axis=0).max() > 1e-3 and np.ptp(on["neck_pose"], axis=0).max() > 1e-3
    assert np.ptp(on["translation"][:, 1]) > 5e-4  # breathing
    assert not np.any(off["eyes_pose"]) and not np.any(off["neck_pose"]) and "pain_shown" not in off.files
    assert not np.any(nogaze["eyes_pose"]) and np.ptp(nogaze["translation"][:, 1]) < np.ptp(on["translation"][:, 1])
    assert side["eyes_pose"][:, 1].mean() > on["eyes_pose"][:, 1].mean() + 0.1  # eyes turn to +x (yaw)
    tl = tmp_path / "tl.json"
    tl.write_text('[{"t": 0, "level": 0.0}, {"t": 1.0, "level": 0.8}]')
    out = tmp_path / "tl.npz"
    assert main(base + ["--pain-timeline", str(tl), "--out", str(out)]) == 0
    shown = np.load(out)["pain_shown"]
    assert shown[:25].max() == 0.0 and shown[25 + 12] > 0.6


def test_react_cli_bad_inputs(speaker_files, tmp_path, capsys):
    d = speaker_files
    out = tmp_path / "o.npz"
    assert main(["react", "--audio", str(d / "s8k.wav"), "--speaker", str(d / "s.npz"), "--out", str(out)]) == 1
    assert "sample_rate: expected 16000 Hz, found 8000" in capsys.readouterr().err
    assert main(["react", "--audio", str(d / "short.wav"), "--speaker", str(d / "s.npz"), "--out", str(out)]) == 1
    assert "length mismatch" in capsys.readouterr().err
    assert main(["react", "--audio", str(d / "s.wav"), "--speaker", str(d / "nan.npz"), "--out", str(out)]) == 1
    assert "NaN" in capsys.readouterr().err
    assert main(["react", "--audio", str(d / "s.wav"), "--speaker", str(d / "s.npz"), "--pain", "2",
                 "--out", str(out)]) == 1
    assert "pain" in capsys.readouterr().err
    assert not out.exists()


def test_generate_demo_reaction_follows_pain():
    from holo_viewer.reaction import api, generate_demo_reaction

    lo = generate_demo_reaction(seconds=2.0, pain=0.0, seed=1)
    hi = generate_demo_reaction(seconds=2.0, pain=1.0, seed=1)  # lo's speaker, kept in this process
    assert set(hi) == FLAME_KEYS and hi["expr"].shape[0] == 50
    api._DEMO_SPEAKERS.clear()
    again = generate_demo_reaction(seconds=2.0, pain=1.0, seed=1)  # the speaker synthesized again: the same
    np.testing.assert_array_equal(again["expr"], hi["expr"])
    au = default_au_map()
    assert pspi(hi["expr"].astype(np.float64), au).mean() > pspi(lo["expr"].astype(np.float64), au).mean() + 5.0


@pytest.mark.slow
def test_acceptance_on_synthetic_test_split():
    """Model beats Random, Mime, MeanFr on FRCorr and FRDist, FRDiv > 0; pain Spearman >= 0.9."""
    from holo_viewer.reaction import metrics as M
    from holo_viewer.reaction.baselines import all_baselines
    from holo_viewer.reaction.evaluate import generate_reactions, pain_following
    from holo_viewer.reaction.features import attributes_from_state

    bundle = load_default_bundle()
    cfg = bundle.train_config.data
    test = make_synthetic_split("test", cfg)
    # MeanFr's mean frame is the test split's own (an oracle): the 120-context text-to-speech training split
    # takes minutes to synthesize, and the val split's mean (never trained on either) cost 6 s of CPU to give
    # the same baseline (FRDist 62.5 with it, 63.0 with the test mean, Ours 30.2; FRCorr 0.0 both, K = 10).
    # K = 4 reactions per clip here: the scores per reaction stay (FRCorr / K: Ours 0.075 vs 0.077 at K = 10,
    # Mime 0.034, MeanFr 0.0; FRDist / K: Ours 2.95 vs 2.88, Mime 8.66, MeanFr 6.39; rho 0.983 vs 0.987) for
    # 6.2 instead of 16.0 s of CPU in generation and metrics (the split's synthesis: 9 s)
    K = 4
    states = generate_reactions(bundle, test, k_samples=K, temperature=1.0, top_k=20, seed=0)
    rho, _ = pain_following(states, test.pain, default_au_map())
    assert rho >= 0.9
    ours = attributes_from_state(states, bundle.au_names)
    base = all_baselines(test.listener_attr, test.speaker_attr, test.listener_attr, K)
    gt, nb = test.listener_attr, test.neighbour
    fc = {n: M.frcorr(p, gt, nb) for n, p in [("Ours", ours)] + [(b, base[b]) for b in ("Random", "Mime", "MeanFr")]}
    fd = {n: M.frdist(p, gt, nb) for n, p in [("Ours", ours)] + [(b, base[b]) for b in ("Random", "Mime", "MeanFr")]}
    for b in ("Random", "Mime", "MeanFr"):
        assert fc["Ours"] > fc[b], (b, fc)
        assert fd["Ours"] < fd[b], (b, fd)
    assert M.frdiv(ours) > 0


def test_corrupt_speaker_file_is_a_clear_error(tmp_path):
    from holo_viewer.errors import ReactionError
    from holo_viewer.flame.expressions import default_au_map
    from holo_viewer.reaction.api import load_speaker_npz

    np.savez(tmp_path / "s.npz", expr=np.zeros((5, 24)), jaw_pose=np.zeros((5, 3)), rotation=np.zeros((5, 3)))
    raw = (tmp_path / "s.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ReactionError, match="cut.npz: cannot read speaker FLAME parameters"):
        load_speaker_npz(tmp_path / "cut.npz", default_au_map())
