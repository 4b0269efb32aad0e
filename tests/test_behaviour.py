"""The no-data behaviour layers (holo_viewer.behaviour): statistics over long seeded runs, determinism,
streaming == whole clip, each layer off when switched off, gaze geometry, pain dynamics and the
pain-timeline schema."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from holo_viewer.behaviour import (DEFAULT_FRAMING, DEFAULT_JOINTS, PANEL_HEIGHT_M, BehaviourConfig,
                                   ListenerBehaviour, PainTimeline, apply_behaviour, default_target,
                                   eye_directions, viewer_target)
from holo_viewer.behaviour.layers import (BlinkLayer, BreathingLayer, BrowLayer, GazeLayer, NodLayer, PainDynamics,
                                          SwayLayer)
from holo_viewer.errors import InputError

FPS = 25


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, length) of each run of True."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]]).astype(int)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - np.flatnonzero(d == 1)))


def _still(T: int, n_expr: int = 24) -> dict[str, np.ndarray]:
    return {"expr": np.zeros((T, n_expr)), "rotation": np.zeros((T, 3)), "jaw_pose": np.zeros((T, 3)),
            "neck_pose": np.zeros((T, 3)), "eyes_pose": np.zeros((T, 6)), "translation": np.zeros((T, 3))}


# ------------------------------------------------------------------ layers: statistics (30 min seeded runs)
@pytest.mark.parametrize("seed", [0, 7])
def test_blinks_rate_and_duration(seed):
    b = BlinkLayer(seed)
    x = np.array([b.step(0.0, pause_onset=(i % 125 == 0)) for i in range(FPS * 1800)])
    shut = _runs(x >= 0.8)
    assert 10 <= len(shut) / 30 <= 25  # per minute (Bentivoglio 1997; Doughty 2001)
    ms = np.array([n for _, n in shut]) * 1000 / FPS
    assert ms.min() >= 100 and ms.max() <= 400
    moving = _runs(x > 0)
    assert max(n for _, n in moving) * 1000 / FPS <= 400
    assert x.max() == 1.0


def test_blinks_follow_pauses_and_pain():
    b = BlinkLayer(3)
    onsets = set(range(50, FPS * 1800, 150))
    x = np.array([b.step(0.0, pause_onset=i in onsets) for i in range(FPS * 1800)])
    starts = [s for s, _ in _runs(x > 0)]
    after = np.mean([any(0 < s - o <= 12 for o in onsets) for s in starts])
    b0 = BlinkLayer(3)
    y = np.array([b0.step(0.0) for _ in range(FPS * 1800)])
    starts0 = [s for s, _ in _runs(y > 0)]
    after0 = np.mean([any(0 < s - o <= 12 for o in onsets) for s in starts0])
    assert after > 2 * after0  # blinks cluster 0.1-0.5 s after pause onsets
    hurt = BlinkLayer(3)
    z = np.array([hurt.step(1.0) for _ in range(FPS * 1800)])
    assert len(_runs(z > 0)) > 1.2 * len(starts0)


@pytest.mark.parametrize("speaking, lo, hi", [(True, 0.70, 0.80), (False, 0.62, 0.76)])
def test_gaze_on_target_share_and_aversions(speaking, lo, hi):
    g = GazeLayer(5)
    s = [g.step(speaking) for _ in range(FPS * 1800)]
    on = np.array([x.on_target for x in s])
    assert lo <= on.mean() <= hi  # 60-80 % of listening time (Argyle & Cook 1976)
    aversions = _runs(~on)
    assert 6 <= len(aversions) / 30 <= 16
    off = np.hypot([x.yaw_deg for x in s], [x.pitch_deg for x in s])
    assert np.median(off[on]) < 1.5 and np.median(off[~on]) > 5.0
    # micro-saccades: the fixation moves while on target
    assert np.std(np.array([x.yaw_deg for x in s])[on]) > 0.1


def _answers_to_pauses(layer):
    """A pause-cued layer stepped over 30 min with a pause onset every 3.75 s (16 / min): the cues, its
    values, its runs (start, length), their starts and each start's lag (s) after the cue before it."""
    cue = np.zeros(FPS * 1800, bool)
    cue[::int(3.75 * FPS)] = True
    v = np.array([layer.step(bool(c)) for c in cue])
    runs = _runs(v > 0)
    starts = np.array([a for a, _ in runs])
    c = np.flatnonzero(cue)
    return cue, v, runs, starts, (starts - c[np.searchsorted(c, starts) - 1]) / FPS


def test_brow_raises_answer_pauses():
    """30 min with a pause onset every 3.75 s (16 / min): 2-6 raises / min, each starting 0.05-0.3 s
    after its cue, 0.75-1.55 s long, >= 4 s apart, apex 0.4-0.65; none without pauses."""
    cue, v, runs, starts, lags = _answers_to_pauses(BrowLayer(seed=2))
    assert 2 * 30 <= len(runs) <= 6 * 30
    assert lags.min() >= 0.04 and lags.max() <= 0.34
    lengths = np.array([n for _, n in runs]) / FPS
    assert lengths.min() >= 0.7 and lengths.max() <= 1.6 and np.diff(starts).min() >= 4 * FPS
    assert 0.4 <= min(v[a:a + n].max() for a, n in runs) and v.max() <= 0.65
    quiet = BrowLayer(seed=2)
    assert not any(quiet.step(False) for _ in range(FPS * 120))


def test_brow_raises_on_the_face_and_off_when_switched_off():
    from holo_viewer.flame.expressions import default_au_map, estimate_aus

    T = FPS * 24
    po = np.zeros(T, bool)
    po[::FPS * 3] = True
    au = default_au_map(24)
    params = _still(T)
    params["expr"] = np.tile(au.matrix[list(au.names).index("AU12")] * 2.0, (T, 1))  # the model's smile stays
    on = estimate_aus(apply_behaviour(params, BehaviourConfig(seed=1), pause_onsets=po)["expr"], au)
    off = estimate_aus(apply_behaviour(params, BehaviourConfig(seed=1, brows=False), pause_onsets=po)["expr"], au)
    i1, i2, i12 = (list(au.names).index(n) for n in ("AU1", "AU2", "AU12"))
    raised = 0.5 * (on[:, i1] + on[:, i2])
    assert len(_runs(raised >= 1.0)) >= 1 and np.allclose(on[:, i1], on[:, i2], atol=1e-6)
    assert np.abs(off[:, [i1, i2]]).max() < 1e-6 and np.allclose(on[:, i12], 2.0, atol=1e-5)


def test_backchannel_nods_answer_pauses_after_a_reaction_time():
    """30 min with a pause onset every 3.75 s: 0.3 of the cues answered (binomial bounds), each nod
    starting 0.15-0.45 s after its cue (a listener's reaction time, spread over that range: never the
    50-ms reactions of the first version), 0.4-0.7 s long, 3-6 deg deep; none without pauses; seeded."""
    cue, v, runs, starts, lags = _answers_to_pauses(NodLayer(seed=3))
    n_cues = int(cue.sum())  # 480: 0.3 of them = 144, sd 10
    assert 0.3 * n_cues - 35 <= len(runs) <= 0.3 * n_cues + 35
    assert lags.min() >= 0.15 and lags.max() <= 0.49
    assert np.percentile(lags, 10) <= 0.22 and np.percentile(lags, 90) >= 0.40  # spread, not bunched
    lengths = np.array([n for _, n in runs]) / FPS
    assert lengths.min() >= 0.36 and lengths.max() <= 0.72
    depth = np.array([v[a:a + n].max() for a, n in runs])
    assert depth.min() >= 2.5 and v.max() <= 6.0
    again = NodLayer(seed=3)
    assert np.array_equal(v, [again.step(bool(x)) for x in cue])
    quiet = NodLayer(seed=3)
    assert not any(quiet.step(False) for _ in range(FPS * 120))


def test_backchannel_nods_on_the_head_and_off_when_switched_off():
    """The nod turns the face down (+ pitch, measured as the bench does) and only with the layer on;
    switching it off leaves every other layer's output unchanged."""
    from holo_viewer.reaction.listening import detect_nods, head_angles_deg

    T = FPS * 40
    po = np.zeros(T, bool)
    po[::FPS * 2] = True
    cfg = BehaviourConfig(seed=1).without("sway", "breathing", "gaze")
    on = apply_behaviour(_still(T), cfg, pause_onsets=po)
    off = apply_behaviour(_still(T), cfg.without("nods"), pause_onsets=po)
    pitch = head_angles_deg(on["rotation"], on["neck_pose"])[:, 0]
    nods = detect_nods(pitch)
    assert len(nods) >= 3 and pitch.max() >= 2.5 and pitch.min() >= -1e-6
    assert np.abs(off["neck_pose"]).max() == 0.0
    assert len(detect_nods(head_angles_deg(off["rotation"], off["neck_pose"])[:, 0])) == 0
    assert np.array_equal(on["expr"], off["expr"]) and np.array_equal(on["eyes_pose"], off["eyes_pose"])


def test_breathing_rate_and_sway_amplitude():
    br = BreathingLayer(2)
    y = np.array([br.step() for _ in range(FPS * 600)])
    assert 12 <= len(_runs(y > 0.5)) / 10 <= 20 and y.min() >= 0 and y.max() <= 1
    sw = SwayLayer(2)  # the defaults: pitch 0.25 deg (small: it blurs the nods), yaw 0.7, roll 0.35, x/z 2 mm
    a = np.array([sw.step() for _ in range(FPS * 1800)])
    assert np.allclose(a.std(axis=0), [0.25, 0.7, 0.35, 2.0, 2.0], rtol=0.25)
    assert BehaviourConfig().sway_deg == (0.25, 0.7, 0.35)
    assert np.abs(np.diff(a[:, :3], axis=0)).max() < 0.15  # smooth: < 4 deg/s


def test_pain_dynamics_flares_and_level_changes():
    pd = PainDynamics(4)
    p = np.array([pd.step(0.6) for _ in range(FPS * 600)])
    base = 0.85 * 0.6
    flares = _runs(p > base + 0.05)
    assert 1.0 <= len(flares) / 10 <= 4  # 3 x 0.6 per minute, less the time inside flares
    for s, n in flares:  # apex within ~1 s of the onset
        seg = p[max(0, s - 25):s + n]
        assert np.argmax(seg) - np.argmax(seg > base + 0.005) <= FPS
    assert p.max() <= 1.0 and p.min() >= base - 1e-9
    # a level change shows within 0.5 s, down as well as up, even during a flare
    for lv0, lv1 in ((0.7, 0.4), (0.2, 0.8), (0.7, 0.0)):
        d = PainDynamics(1)
        q = [d.step(lv0) for _ in range(FPS * 20)]
        q += [d.step(lv1) for _ in range(FPS * 2)]
        after = np.array(q[FPS * 20 + int(0.5 * FPS)])
        assert abs(after - 0.85 * lv1) <= 0.6 * 0.85 * max(lv0, lv1) * 0.1 + 0.6 * 0.85 * lv1 + 0.02
        assert abs(q[FPS * 20 + int(0.5 * FPS)] - q[FPS * 20 - 1]) > 0.8 * abs(0.85 * (lv1 - lv0)) - 0.6 * 0.85 * max(lv0, lv1)
    off = PainDynamics(4, flares=False)
    q = np.array([off.step(0.6) for _ in range(FPS * 60)])
    assert np.allclose(q, 0.6)


def test_pain_drop_visible_within_half_a_second_without_flares():
    d = PainDynamics(0, flares=False)
    q = [d.step(0.7) for _ in range(50)] + [d.step(0.4) for _ in range(13)]
    assert abs(q[50 + 12] - 0.4) < 0.02 and q[50] < 0.65  # 95 % of the step by 0.48 s, begun at once


# ------------------------------------------------------------------ composition
def test_deterministic_and_streaming_equals_clip():
    T = 200
    rng = np.random.default_rng(0)
    params = _still(T)
    params["rotation"] = rng.normal(0, 0.02, (T, 3))
    cfg = BehaviourConfig(seed=3)
    a = apply_behaviour(params, cfg, pain=0.5)
    b = apply_behaviour(params, cfg, pain=0.5)
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    beh = ListenerBehaviour(cfg, n_expr=24)
    for t in range(T):
        o = beh.step({k: v[t] for k, v in params.items()}, 0.5)
        assert np.allclose(o["eyes_pose"], a["eyes_pose"][t], atol=1e-6)
        assert np.allclose(o["expr"], a["expr"][t], atol=1e-6)
    c = apply_behaviour(params, BehaviourConfig(seed=4), pain=0.5)
    assert not np.array_equal(a["eyes_pose"], c["eyes_pose"])


def test_all_layers_off_and_no_pain_is_identity():
    T = 150
    params = _still(T)
    params["expr"][:, 8] = 0.3
    cfg = BehaviourConfig().without("gaze", "blinks", "breathing", "sway", "flares")
    out = apply_behaviour(params, cfg, pain=0.0)
    for k in ("expr", "rotation", "neck_pose", "eyes_pose", "translation", "jaw_pose"):
        assert np.array_equal(out[k], params[k].astype(np.float32)), k


@pytest.mark.parametrize("layer, key", [("gaze", "eyes_pose"), ("breathing", "translation"), ("sway", "neck_pose")])
def test_each_layer_off_when_switched_off(layer, key):
    T = 250
    on = apply_behaviour(_still(T), BehaviourConfig())
    others = [x for x in ("gaze", "blinks", "breathing", "sway") if x != layer]
    only = apply_behaviour(_still(T), BehaviourConfig().without(*others))
    off = apply_behaviour(_still(T), BehaviourConfig().without(layer))
    assert np.ptp(only[key], axis=0).max() > 1e-4
    if layer == "gaze":
        assert np.array_equal(off["eyes_pose"], np.zeros((T, 6), np.float32))
    else:
        only_other = apply_behaviour(_still(T), BehaviourConfig().without(layer, "gaze"))
        assert not np.allclose(only_other[key], on[key] - 0 * on[key]) or layer == "gaze"
    # the other layers' draws do not depend on this layer's switch
    assert np.array_equal(off["expr"][:, 22], on["expr"][:, 22])


def test_blinks_on_the_eyelid_channel():
    T = FPS * 60
    out = apply_behaviour(_still(T), BehaviourConfig(seed=1), pain=0.3)
    lid = out["expr"][:, 22]  # AU43_L; AU43_R is column 23
    assert np.array_equal(lid, out["expr"][:, 23])
    assert 8 <= len(_runs(lid >= 0.8)) <= 27 and lid.max() == pytest.approx(1.0)
    off = apply_behaviour(_still(T), BehaviourConfig(seed=1, blinks=False), pain=0.3)
    assert off["expr"][:, 22].max() < 0.1  # only pain's 0.3 p^2 remains


def test_gaze_converges_on_the_target_point():
    T = FPS * 60
    for target in (default_target(), viewer_target(15.0, 0.8), viewer_target(-20.0, 0.5, height_m=0.1)):
        out = apply_behaviour(_still(T), BehaviourConfig(seed=2), target=target)
        c, d = eye_directions(out["rotation"], out["neck_pose"], out["eyes_pose"], out["translation"])
        v = target - c
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        err = np.degrees(np.arccos(np.clip((v * d).sum(-1), -1, 1))).max(axis=1)
        assert 0.62 <= np.mean(err < 5.0) <= 0.85
        assert np.median(err) < 1.0  # both eyes on the point (vergence), not parallel
    # the head turns part of the way toward a viewer at the side
    side = apply_behaviour(_still(T), BehaviourConfig(seed=2, sway=False, breathing=False),
                           target=viewer_target(20.0, 0.6))
    yaw = np.degrees(side["neck_pose"][-FPS * 10:, 1])
    assert 2.0 < np.median(yaw) < 10.0


def test_eye_directions_reference():
    """Forward kinematics against the head model's own LBS of the eyeball vertices."""
    from holo_viewer.flame.default_head import load_default_model
    import torch

    m = load_default_model()
    assert np.allclose(m.j_template.numpy(), DEFAULT_JOINTS, atol=1e-6)
    rot, neck = np.array([[0.1, -0.2, 0.05]]), np.array([[-0.05, 0.3, 0.02]])
    eyes = np.array([[0.1, 0.2, 0.0, -0.1, 0.25, 0.0]])
    tr = np.array([[0.01, -0.02, 0.03]])
    c, d = eye_directions(rot, neck, eyes, tr)
    w = m.lbs_weights.numpy()
    for e in range(2):
        idx = np.flatnonzero(w[:, 3 + e] > 0.999)
        v0 = m.v_template.numpy()[idx]
        rest_axis = v0 - DEFAULT_JOINTS[3 + e]
        front = idx[np.argmax(rest_axis[:, 2] / np.linalg.norm(rest_axis, axis=1))]
        out = m(rotation=torch.tensor(rot, dtype=torch.float32), neck_pose=torch.tensor(neck, dtype=torch.float32),
                eyes_pose=torch.tensor(eyes, dtype=torch.float32), translation=torch.tensor(tr, dtype=torch.float32))
        verts = out.vertices.detach().numpy().astype(np.float64).reshape(-1, 3)
        vec = verts[front] - c[0, e]
        rest = m.v_template.numpy()[front] - DEFAULT_JOINTS[3 + e]
        assert np.linalg.norm(vec) == pytest.approx(np.linalg.norm(rest), abs=1e-5)
        cos_rest = rest[2] / np.linalg.norm(rest)  # the vertex keeps its angle to the eye's axis
        assert float(vec @ d[0, e]) / np.linalg.norm(vec) == pytest.approx(cos_rest, abs=1e-4)


def test_default_framing_matches_the_pipeline():
    from holo_viewer.pipeline import Pipeline

    p = Pipeline(avatar=None)
    centre, half = p.get("framing")
    assert np.allclose(centre, DEFAULT_FRAMING[0], atol=1e-6) and half == pytest.approx(DEFAULT_FRAMING[1], abs=1e-6)
    assert p.calibration.physical_size_m[1] == pytest.approx(PANEL_HEIGHT_M)
    t = viewer_target(0.0, 0.6)
    assert t[2] == pytest.approx(DEFAULT_FRAMING[0][2] + 0.6 * half / (PANEL_HEIGHT_M / 2))


def test_pain_combines_by_maximum_and_follows_a_timeline():
    from holo_viewer.flame.expressions import default_au_map, pain_expression

    T = FPS * 4
    params = _still(T)
    am = default_au_map()
    params["expr"][:] = 5.0 * am.row("AU4")  # the model already frowns fully: pain must not add AU4 on top
    tl = PainTimeline.from_json([{"t": 0, "level": 0.7}, {"t": 2.0, "level": 0.4}])
    cfg = BehaviourConfig().without("gaze", "blinks", "breathing", "sway", "flares")
    out = apply_behaviour(params, cfg, pain=tl)
    assert np.allclose(out["expr"][:, am.names.index("AU4") and 4], 1.0)
    assert out["pain_shown"][FPS * 2 - 1] == pytest.approx(0.7, abs=1e-6)
    assert out["pain_shown"][FPS * 2 + 12] == pytest.approx(0.4, abs=0.01)  # 0.48 s after the drop
    want = pain_expression(0.4, am)
    assert np.allclose(out["expr"][-1, 6:10], want[6:10], atol=2e-3)  # AU6 AU7 AU9 AU10 of pain 0.4



def test_layers_draw_the_avatars_own_pain_face():
    """Issue 35: the layers' pain face is the avatar's (``au_map_for``: the default head's AU4 gain), the face
    its pain slider and the legibility bench draw; a map passed in (a patient's, no gain) is honoured; the live
    session takes the rendered pipeline's map."""
    from types import SimpleNamespace

    from holo_viewer.flame.expressions import default_au_map, pain_expression
    from holo_viewer.live.loop import session_behaviour
    from holo_viewer.pipeline import Pipeline

    pipe = Pipeline(avatar=None)  # the default head, no Gaussians
    own = pipe.au_map
    assert own.pain_gains is not None and own.pain_gains["AU4"] > 1.1
    beh = ListenerBehaviour(BehaviourConfig(seed=0))
    assert dict(beh.au_map.pain_gains) == dict(own.pain_gains)
    assert np.allclose(beh._pain_vector(1.0) @ beh.au_map.matrix, pain_expression(1.0, own), atol=1e-12)
    cfg = BehaviourConfig(seed=3).without("gaze", "blinks", "brows", "breathing", "sway", "nods", "flares")
    shared = default_au_map()
    for am, other in ((None, shared), (shared, own)):
        out = apply_behaviour(_still(FPS * 3), cfg, pain=1.0, au_map=am)
        p = float(out["pain_shown"][-1])
        assert p > 0.5
        assert np.allclose(out["expr"][-1], pain_expression(p, own if am is None else am), atol=1e-5)
        assert not np.allclose(out["expr"][-1], pain_expression(p, other), atol=1e-3)
    # live: the session's layers use the rendered avatar's map (a patient with identity gains here)
    patient = shared.with_pain_gains({"AU6": 1.2})
    live = session_behaviour("default", 5, SimpleNamespace(pipeline=SimpleNamespace(au_map=patient)))
    assert live.au_map is patient and live.config.seed == 5
    assert dict(session_behaviour("default", 5, SimpleNamespace(pipeline=pipe)).au_map.pain_gains) == \
        dict(own.pain_gains)
    assert dict(session_behaviour("default", 5).au_map.pain_gains) == dict(own.pain_gains)  # no renderer


# ------------------------------------------------------------------ the pain-timeline schema
def test_pain_timeline_schema(tmp_path):
    tl = PainTimeline.from_json([{"t": 0, "level": 0.2}, {"t": 1.0, "level": 0.7, "source": "key"}])
    assert tl.level_at(0.99) == 0.2 and tl.level_at(1.0) == 0.7
    assert np.allclose(tl.levels(30), [0.2] * 25 + [0.7] * 5)
    f = tmp_path / "tl.json"
    f.write_text(json.dumps({"pain_timeline": tl.to_json()}))
    assert PainTimeline.load(f) == tl
    assert PainTimeline.from_json([{"t": 2, "level": 0.5}]).level_at(1.0) == 0.0
    bad = [([], "non-empty array"), ([{"t": 0}], "missing level"), ([{"t": -1, "level": 0.1}], "[0].t"),
           ([{"t": 0, "level": 1.5}], "[0].level"), ([{"t": 0, "level": "x"}], "finite number"),
           ([{"t": 1, "level": 0.1}, {"t": 1, "level": 0.2}], "[1].t"), ([{"t": 0, "level": 0.1, "x": 1}], "unknown"),
           ([{"t": 0, "level": True}], "[0].level"), ([{"t": 0, "level": 0.1, "source": "dog"}], "source")]
    for value, msg in bad:
        with pytest.raises(InputError, match=msg.replace("[", r"\[").replace("]", r"\]")):
            PainTimeline.from_json(value, source="scenario.json")
    f.write_text("[1, 2]")
    with pytest.raises(InputError, match=str(f).replace("\\", "\\\\")):
        PainTimeline.load(f)


def test_config_validation():
    assert BehaviourConfig.from_dict(BehaviourConfig(seed=3).to_dict()) == BehaviourConfig(seed=3)
    with pytest.raises(InputError, match="behaviour.gaze"):
        BehaviourConfig(gaze="yes")
    with pytest.raises(InputError, match="unknown keys"):
        BehaviourConfig.from_dict({"gaze": True, "stare": 1})
    with pytest.raises(InputError, match="layers"):
        BehaviourConfig().without("eyes")
    with pytest.raises(InputError, match="pain"):
        apply_behaviour(_still(5), pain=1.5)
    assert math.isfinite(BehaviourConfig().blink_rate_per_min)


# ------------------------------------------------------------------ integration: the demo's reaction frames
def test_reaction_frames_use_the_layers_by_default():
    from holo_viewer.pipeline import reaction_frames
    from holo_viewer.reaction.api import default_checkpoint_path

    if not default_checkpoint_path().is_file():
        pytest.skip("no shipped reaction checkpoint")
    on, fps = reaction_frames(seconds=2.0, pain=0.4, seed=1, warmup=0.5)
    off, _ = reaction_frames(seconds=2.0, pain=0.4, seed=1, warmup=0.5, behaviour=None)
    eyes_on = np.stack([f["eyes_pose"] for f in on])
    assert fps == 25 and np.ptp(eyes_on, axis=0).max() > 1e-3 and "pain" not in on[0]
    assert not np.any(np.stack([f["eyes_pose"] for f in off]))
    nogaze, _ = reaction_frames(seconds=2.0, pain=0.4, seed=1, warmup=0.5, behaviour=BehaviourConfig(gaze=False))
    assert not np.any(np.stack([f["eyes_pose"] for f in nogaze]))


def test_pain_face_upper_lip_follows_the_other_action_units():
    from holo_viewer.flame.expressions import PAIN_PEAK, pain_aus

    for p in (0.2, 0.4):
        rel = {k: v / PAIN_PEAK[k] for k, v in pain_aus(p).items()}
        assert rel["AU10"] < 0.5 * rel["AU4"] and rel["AU10"] < rel["AU7"] < rel["AU4"] and rel["AU9"] < rel["AU4"]
    assert pain_aus(1.0) == PAIN_PEAK

