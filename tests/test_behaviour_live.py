"""The behaviour layers in a live session: eyes on the viewer, a pain level change visible within
0.5 s (down as well as up), the session report's pain timeline, the switches, the scenario schema."""

from __future__ import annotations

import json

import numpy as np
import pytest

from holo_viewer.errors import InputError


def _session(tmp_path, name, scenario, behaviour="default", seconds=3.2):
    from holo_viewer.live import sources
    from holo_viewer.live.controls import Scenario
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.pipeline.live_support import SyntheticSpeaker

    f = tmp_path / f"{name}.json"
    f.write_text(json.dumps(scenario))
    syn = SyntheticSpeaker(seconds)
    cfg = LiveSessionConfig(out=str(tmp_path / name), scenario=Scenario.load(f), behaviour=behaviour)
    session = LiveSession(cfg, sources.ArrayAudio(syn.waveform), None, syn)
    summary = session.run(None)
    with np.load(tmp_path / name / "tracks.npz") as z:
        tr = {k: z[k] for k in z.files}
    meta = json.loads((tmp_path / name / "session.json").read_text())
    return summary, tr, meta


def test_live_pain_change_shows_within_half_a_second_and_eyes_follow_the_viewer(tmp_path):
    from holo_viewer.flame.expressions import default_au_map, pain_expression, pspi

    scenario = {"pain_timeline": [{"t": 0, "level": 0.2}, {"t": 1.0, "level": 0.7}, {"t": 2.0, "level": 0.4}]}
    summary, tr, meta = _session(tmp_path, "on", scenario)
    t = tr["time_s"]
    T = len(t)
    assert T >= 75
    s = pspi(tr["listener_expr"].astype(np.float64), default_au_map())
    i_up, i_down = 25, 50
    target = {lv: pspi(pain_expression(0.85 * lv, default_au_map()), default_au_map()) for lv in (0.2, 0.7, 0.4)}
    # within 0.5 s (12 frames) of each change the face is within 10 % of the new level's face (flares aside: up)
    assert s[i_up + 12] >= 0.9 * target[0.7]
    assert s[i_down + 12] <= target[0.4] * 1.1 + 0.6 * 0.85 * 0.4 * 5  # a flare may ride on the background
    assert s[i_down + 12] < s[i_down - 1] - 0.5 * (target[0.7] - target[0.4])
    shown = tr["pain_shown"]
    assert abs(shown[i_up + 12] - 0.85 * 0.7) < 0.6 * 0.85 * 0.7 + 0.02 and shown[i_down + 12] < shown[i_down - 1]
    assert np.allclose(tr["pain"][[0, i_up, i_down]], [0.2, 0.7, 0.4])
    # the eyes follow the (synthetic) viewer as it moves, and the session report holds the timeline
    from holo_viewer.behaviour import eye_directions

    _, d = eye_directions(tr["listener_rotation"], tr["listener_neck_pose"], tr["listener_eyes_pose"],
                          tr["listener_translation"])
    yaw = np.degrees(np.arctan2(d.mean(1)[:, 0], d.mean(1)[:, 2]))
    assert np.ptp(tr["viewer_angle_deg"]) > 5 and np.corrcoef(yaw, tr["viewer_angle_deg"])[0, 1] > 0.8
    tl = meta["summary"]["pain_timeline"]
    assert [(k["t"], k["level"], k["source"]) for k in tl] == [(0.0, 0.2, "scenario"), (1.0, 0.7, "scenario"),
                                                               (2.0, 0.4, "scenario")]
    from holo_viewer.behaviour import PainTimeline

    assert PainTimeline.from_json(tl).level_at(1.5) == 0.7


@pytest.mark.slow
def test_live_without_behaviour_is_the_model_alone(tmp_path):
    _, tr, _ = _session(tmp_path, "off", {"events": [{"t": 0, "pain": 0.3}]}, behaviour=None, seconds=1.2)
    assert not np.any(tr["listener_eyes_pose"]) and np.all(tr["pain_shown"] == -1)


def test_scenario_pain_timeline_schema(tmp_path):
    from holo_viewer.live.controls import Scenario

    f = tmp_path / "s.json"
    f.write_text(json.dumps({"pain_timeline": [{"t": 0, "level": 0.1}, {"t": 4, "level": 0.7}],
                             "events": [{"t": 5, "expression": "smile", "intensity": 0.5}]}))
    sc = Scenario.load(f)
    assert sc.pain_at(3.9) == 0.1 and sc.pain_at(4.0) == 0.7 and sc.named_at(5.5) == (("smile", 0.5),)
    f.write_text(json.dumps({"pain_timeline": [{"t": 0, "level": 1.7}]}))
    with pytest.raises(InputError, match=r"pain_timeline\[0\].level"):
        Scenario.load(f)
    f.write_text(json.dumps({"pain_timeline": [{"t": 0, "level": 0.1}], "events": [{"t": 1, "pain": 0.2}]}))
    with pytest.raises(InputError, match="both"):
        Scenario.load(f)


def test_the_live_renderer_poses_eyes_neck_and_translation():
    """The live frame carries the layers' eyes_pose, neck_pose and translation to the face (they were dropped)."""
    from types import SimpleNamespace

    from holo_viewer.live.render import LiveAvatarRenderer

    seen = []
    pipe = SimpleNamespace(model=SimpleNamespace(n_expr=24), set_face=seen.append, set_view=lambda **kw: None,
                           gaussians=lambda: None)
    stub = SimpleNamespace(pipeline=pipe, _live=None, _drawn=None, native_enabled=False, preview_enabled=False)
    stub.deform = lambda *a: LiveAvatarRenderer.deform(stub, *a)  # render() poses the face through deform()
    frame = {"expr": np.zeros(24), "jaw_pose": np.zeros(3), "rotation": np.zeros(3),
             "neck_pose": np.array([0.01, 0.02, 0.0]), "eyes_pose": np.arange(6) / 100.0,
             "translation": np.array([0.0, 0.001, 0.0])}
    LiveAvatarRenderer.render(stub, frame, 0.0, (), 0.0, 0.6)
    face = seen[-1]
    assert np.allclose(face.eyes_pose, frame["eyes_pose"]) and np.allclose(face.neck_pose, frame["neck_pose"])
    assert np.allclose(face.translation, frame["translation"])
