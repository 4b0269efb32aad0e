"""Live sessions: headless end to end from replayed files, missing devices, Ctrl-C, replay, streaming, keys."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from holo_viewer.cli import main
from holo_viewer.live.session import TRACK_KEYS

pytest.importorskip("dlib", reason="live sessions need the [live] extra (dlib-bin)")


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    from holo_viewer.pipeline.live_support import write_talking_head_clip

    return write_talking_head_clip(tmp_path_factory.mktemp("clip"), seconds=1.6, n_gaussians=20_000)


def _check_session(folder: Path, n_frames: int | None = None) -> dict:
    meta = json.loads((folder / "session.json").read_text())
    with np.load(folder / "tracks.npz") as z:
        tr = {k: z[k] for k in z.files}
    for k in TRACK_KEYS:
        assert k in tr, k
        assert np.isfinite(tr[k].astype(np.float64)).all(), k
    T = len(tr["time_s"])
    if n_frames is not None:
        assert T == n_frames
    assert tr["listener_expr"].shape[0] == T and tr["listener_eyes_pose"].shape == (T, 6)
    assert tr["speaker_rotation"].shape == (T, 3)
    np.testing.assert_allclose(tr["time_s"], np.arange(T) / 25, atol=1e-6)
    assert (folder / "audio.wav").stat().st_size > 44
    return {"meta": meta, "tracks": tr}


@pytest.mark.slow
def test_live_headless_from_replayed_files(clip, tmp_path):
    """CI: replayed wav + mp4, no devices or display: runs end to end, ends when the files end."""
    out = tmp_path / "session"
    code = main(["live", "--audio", str(clip["wav"]), "--video", str(clip["video"]), "--headless", "--out", str(out),
                 "--tile-scale", "0.1"])
    assert code == 0
    s = _check_session(out, n_frames=40)
    assert s["tracks"]["speaker_found"].mean() > 0.5  # the tracker saw the rendered head
    assert s["meta"]["settings"]["sources"]["video"].startswith("file:")
    assert s["meta"]["summary"]["reaction_windows"] >= 40 // 8
    assert (out / "native.mkv").stat().st_size > 0
    assert not (out / "webcam.mkv").exists()  # faces are private unless --record-video
    # the session replays deterministically
    from holo_viewer.live.replay import replay_frames

    a = [f for _, f in zip(range(2), replay_frames(out, tile_scale=0.1, every=13))]
    b = [f for _, f in zip(range(2), replay_frames(out, tile_scale=0.1, every=13))]
    assert len(a) == 2 and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert a[0].shape == (2048, 1536, 3)


@pytest.mark.slow
def test_live_synthetic_frames_and_replay_command(tmp_path):
    out = tmp_path / "s"
    assert main(["live", "--synthetic", "--seconds", "1.0", "--headless", "--frames", "2", "--out", str(out),
                 "--tile-scale", "0.1", "--pain", "0.4", "--render-mode", "tracked"]) == 0
    s = _check_session(out)
    assert s["meta"]["displayed_frames"] == 2
    assert np.allclose(s["tracks"]["pain"], 0.4)
    video = tmp_path / "replay.mp4"
    assert main(["replay", str(out), "--out", str(video), "--every", "12", "--tile-scale", "0.1"]) == 0
    assert video.stat().st_size > 0


def test_missing_devices_are_named(tmp_path, capsys, monkeypatch):
    """No microphone / webcam here: exit 1 with the device named, no traceback."""
    monkeypatch.setenv("SD_ENABLE_ASIO", "0")
    code = main(["live", "--headless", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert "microphone" in err or "webcam" in err
    wav = tmp_path / "a.wav"
    from holo_viewer.reaction.audio import write_wav

    write_wav(wav, np.zeros(16000, np.float32), 16000)
    code = main(["live", "--audio", str(wav), "--camera", "97", "--headless", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 1 and "webcam" in err and "97" in err
    assert main(["live", "--audio", str(tmp_path / "none.wav"), "--video", "x.mp4", "--headless"]) == 1
    assert "audio file not found" in capsys.readouterr().err


def test_ctrl_c_keeps_the_session(tmp_path):
    """An interruption mid-session leaves a complete folder up to that point."""
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSessionConfig, LiveSession
    from holo_viewer.pipeline.live_support import SyntheticSpeaker

    syn = SyntheticSpeaker(3.0)
    session = LiveSession(LiveSessionConfig(out=str(tmp_path / "s")), sources.ArrayAudio(syn.waveform), None, syn)

    class Interrupting:  # a renderer that is interrupted on its second real frame (the first is the warm-up)
        calls = 0

        def render(self, *args):
            from holo_viewer.live.render import RenderedFrame

            self.calls += 1
            if self.calls > 2:
                raise KeyboardInterrupt
            time.sleep(0.3)
            return RenderedFrame(native=None, preview=None, seconds=0.3)

    summary = session.run(Interrupting())
    assert summary["status"]["end"] == "interrupted (Ctrl-C)"
    s = _check_session(tmp_path / "s")
    assert 0 < len(s["tracks"]["time_s"]) < 75
    assert s["meta"]["frames"] == len(s["tracks"]["time_s"])


def test_reaction_stream_matches_offline_generation():
    """Streaming k-frame windows from a rolling audio buffer = the offline model on the whole clip
    (argmax, raw tokens: identical frames)."""
    from holo_viewer.pipeline.live_support import SyntheticSpeaker
    from holo_viewer.reaction.api import load_default_bundle, react
    from holo_viewer.reaction.stream import ReactionStream

    syn = SyntheticSpeaker(6.0, seed=3)
    bundle = load_default_bundle()
    offline = react(bundle, syn.waveform, 16000, syn.states, pain=0.3, smoothing=0.0)
    stream = ReactionStream(bundle, smoothing=0.0)
    out = []
    for t in range(len(syn.states)):
        stream.push_audio(syn.waveform[t * 640:(t + 1) * 640])
        out.append(stream.push_frame(syn.states[t], 0.3)[0])
    out = np.array(out)
    same = np.all(np.isclose(out, offline, atol=1e-5), axis=1).mean()
    assert same == 1.0, same
    assert len(stream._audio) <= (stream.Ws + 2) * 640  # memory stays flat


def test_controls_and_scenario(tmp_path):
    from holo_viewer.errors import InputError
    from holo_viewer.live.controls import Controls, Scenario

    c = Controls(pain=0.5)
    for k in ("Up", "Up", "Down", "space", "r", "x"):
        c.key(k)
    assert c.pain == pytest.approx(0.6) and c.paused and c.take_recentre() and not c.take_recentre()
    c.key("q")
    assert c.quit
    p = tmp_path / "sc.json"
    p.write_text(json.dumps({"events": [{"t": 0, "pain": 0.1}, {"t": 2, "pain": 0.8, "expression": "frown",
                                                                 "intensity": 0.5, "duration": 1}]}))
    sc = Scenario.load(p)
    assert sc.pain_at(1.0) == 0.1 and sc.pain_at(2.5) == 0.8 and sc.pain_changes(1.9, 2.1) == 0.8
    assert sc.named_at(2.5) == (("frown", 0.5),) and sc.named_at(3.5) == ()
    p.write_text(json.dumps({"events": [{"t": 0, "expression": "grin"}]}))
    with pytest.raises(InputError, match="expression"):
        Scenario.load(p)


# ----------------------------------------------------------------------------- preview window under Xvfb

_PREVIEW_SCRIPT = r"""
import sys, subprocess, time, threading
import numpy as np
from holo_viewer.live import sources
from holo_viewer.live.loop import LiveSessionConfig, LiveSession
from holo_viewer.live.render import LiveAvatarRenderer
from holo_viewer.live.windows import open_preview
from holo_viewer.pipeline.live_support import SyntheticSpeaker

syn = SyntheticSpeaker(10.0)  # as cheap as 4 s (10 s are synthesized): the session outlasts the keys; q ends it
preview = open_preview(210, 280)
session = LiveSession(LiveSessionConfig(out=sys.argv[1], tile_scale=0.1, preview=True, pain=0.2),
                      sources.ArrayAudio(syn.waveform), None, syn)
renderer = LiveAvatarRenderer(tile_scale=0.1, native=False, preview=True)
pressed = []
def press(keys):
    end = time.time() + 120  # until the window has shown a frame (it is mapped), not a fixed 1.5 s
    while preview.shown < 1 and time.time() < end:
        time.sleep(0.02)
    subprocess.run(["xdotool", "mousemove", "60", "60"], check=False)
    for i, k in enumerate(keys):  # each key once the loop has acted on the one before, not after a fixed 0.3 s
        subprocess.run(["xdotool", "key", k], check=True)
        while len(session.controls.log) <= i and time.time() < end:
            time.sleep(0.02)
    pressed.append(True)
th = threading.Thread(target=press, args=(["Up", "Up", "r", "q"],), daemon=True)
th.start()
summary = session.run(renderer, preview=preview)
shot = preview.window.screenshot()
print("SHOWN", preview.shown, "LOG", ",".join(session.controls.log), "PAIN", session.controls.pain,
      "BRIGHT", float(shot.mean()))
"""


@pytest.mark.gui
@pytest.mark.slow
def test_preview_window_updates_and_keys_work(tmp_path, xvfb_server):
    if shutil.which("xdotool") is None:
        pytest.skip("needs xdotool (apt-get install xdotool)")
    with xvfb_server("800x600x24") as display:
        env = {k: v for k, v in os.environ.items() if k != "VTK_DEFAULT_OPENGL_WINDOW"}
        env["DISPLAY"] = display
        script = tmp_path / "preview.py"
        script.write_text(_PREVIEW_SCRIPT)
        r = subprocess.run([sys.executable, str(script), str(tmp_path / "s")], env=env, capture_output=True,
                           text=True, timeout=300, cwd=str(Path(__file__).resolve().parents[1]))
        assert r.returncode == 0, r.stderr[-3000:]
        line = [x for x in r.stdout.splitlines() if x.startswith("SHOWN")][-1].split()
        shown, log, pain = int(line[1]), line[3], float(line[5])
        assert shown >= 2  # the window updates
        assert log == "pain_up,pain_up,recentre,quit"  # real X key presses reached the loop
        assert pain == pytest.approx(0.4)
        assert float(line[7]) > 5  # something was drawn
        _check_session(tmp_path / "s")  # quit still writes the session


@pytest.mark.slow
def test_webcam_lost_mid_session_degrades(clip, tmp_path):
    """The video stops after 0.4 s (a webcam unplugged): the session goes on with the audio, the face
    is marked lost and the status says so."""
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSessionConfig, LiveSession
    from holo_viewer.tracking.video import iter_video_frames

    frames = [(t, f) for t, f in iter_video_frames(clip["video"]) if t < 0.4]

    class Unplugged:
        name, status, finished = "webcam:test", "ok", False

        def start(self):
            pass

        def stop(self):
            pass

        def latest(self, t):
            seen = [x for x in frames if x[0] <= t]
            if t >= 0.4:
                self.status = "webcam lost"
            return seen[-1] if seen else None

    session = LiveSession(LiveSessionConfig(out=str(tmp_path / "s")), sources.WavReplay(clip["wav"]), Unplugged())
    summary = session.run(None)
    s = _check_session(tmp_path / "s", n_frames=40)
    found = s["tracks"]["speaker_found"]
    assert found[:8].any() and not found[-10:].any()
    assert "no new video frames" in summary["status"]["video"]


def _live_child_interrupted(out: Path, extra: list[str], env: dict | None = None):
    """`holo-viewer live --synthetic --seconds 10 EXTRA`, a real SIGINT 1 s after its first frame is shown;
    (exit code, stdout, stderr). A child that exits by itself first is returned as it ended."""
    import signal
    import threading

    proc = subprocess.Popen([sys.executable, "-m", "holo_viewer", "live", "--synthetic", "--seconds", "10",
                             "--tile-scale", "0.1", "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=str(Path(__file__).resolve().parents[1]))
    lines: list[str] = []
    errors: list[str] = []
    shown = threading.Event()

    def read(stream, into: list[str]) -> None:  # line by line (stdout: the start-up's progress lines)
        for line in stream:
            into.append(line)
            if "first frame shown" in line:
                shown.set()

    readers = [threading.Thread(target=read, args=(proc.stdout, lines), daemon=True),
               threading.Thread(target=read, args=(proc.stderr, errors), daemon=True)]
    for r in readers:
        r.start()
    deadline = time.time() + 300  # start-up: seconds quiet, minutes on a loaded machine
    while time.time() < deadline and not shown.is_set() and proc.poll() is None:
        shown.wait(timeout=0.2)
    if shown.is_set():
        time.sleep(1.0)  # about 25 frames of session
        proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    for r in readers:
        r.join(timeout=10)
    return proc.returncode, "".join(lines), "".join(errors)


@pytest.mark.slow
def test_sigint_keeps_the_session_folder_with_the_panel_window_open(tmp_path, xvfb_server):
    """A real Ctrl-C (SIGINT) to `holo-viewer live --panel` on a Portrait-sized Xvfb screen: --panel opened the
    borderless native-image window and showed frames in it (the show machinery); exit 130, the session folder
    complete up to then. One child for both (each cost a `live` start-up, ~7 s of CPU); without Xvfb or a
    monitor list (xrandr/xdpyinfo) the interruption is checked headless.

    The signal comes 1 s after the first frame is shown, before the first flush (5 s of session; waiting
    for it cost the test 5 s of a busy session): every frame in the folder was written at the interruption."""
    out = tmp_path / "s"
    panel = shutil.which("Xvfb") is not None
    with (xvfb_server("1536x2048x24") if panel else contextlib.nullcontext()) as display:
        if panel:
            env = {k: v for k, v in os.environ.items() if k != "VTK_DEFAULT_OPENGL_WINDOW"}
            env["DISPLAY"] = display
            code, stdout, stderr = _live_child_interrupted(out, ["--panel", "--no-preview"], env)
            if code == 1 and "no monitor" in stderr and "found none" in stderr:  # no xrandr/xdpyinfo
                panel = False
        if not panel:
            code, stdout, stderr = _live_child_interrupted(out, ["--headless"])
    assert "first frame shown" in stdout, (stdout + stderr)[-2000:]
    assert code == 130, stderr[-2000:]
    assert "Traceback" not in stderr
    s = _check_session(out)
    n = len(s["tracks"]["time_s"])
    assert 1 <= n < 250  # some frames, before the end (10 s: the shortest clip the synthetic speaker makes;
    # 30 s cost 1.2 s more CPU of text-to-speech and voice detection): written at the interruption
    assert s["meta"]["summary"]["status"]["end"] == "interrupted (Ctrl-C)"
    assert s["meta"]["displayed_frames"] >= 1  # shown in the panel window (headless: in none)
    assert ("opening the panel window" in stdout) == panel  # the window was opened before the first frame
    with np.load(out / "tracks.npz") as z:
        assert z["display_time_s"].size >= 1


def test_auto_render_mode_renders_group_frames_with_the_tracked_face():
    """The live command's default: group frames (every view, one fill for every viewer), with the
    viewer while the tracker sees a face and without one otherwise."""
    from holo_viewer.live.render import LiveAvatarRenderer

    r = LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, mode="auto")
    calls = []
    frame = r._live.frame
    r._live.frame = lambda g, viewer, mode: calls.append((viewer, mode)) or frame(g, viewer, mode)
    listener = {"expr": np.zeros(10)}
    assert r.render(listener, 0.3, (), 5.0, 0.7, True).native.shape == (2048, 1536, 3)
    r.render(listener, 0.3, (), 5.0, 0.7, False)
    assert calls[0][1] == "group" and calls[0][0].angle_deg == 5.0 and calls[0][0].distance_m == 0.7
    assert calls[1] == (None, "group")
    r.render(listener, 0.3, (), 5.0, 0.7, True, others=((-15.0, 0.9),))  # every face the tracker passes on
    assert calls[2][1] == "group" and [(v.angle_deg, v.distance_m) for v in calls[2][0]] == [(5.0, 0.7), (-15.0, 0.9)]
    from holo_viewer.errors import InputError

    with pytest.raises(InputError, match="auto"):
        LiveAvatarRenderer(tile_scale=0.1, mode="eyes")


def test_live_backend_auto_is_fast_without_cuda_and_gsplat_needs_it(tmp_path, capsys):
    """``--renderer auto`` (the default) falls back to the CPU here; an explicit gsplat without CUDA
    is a clear error (exit 1, no traceback); a misspelt backend is named."""
    from holo_viewer.errors import InputError, RenderError
    from holo_viewer.live.render import resolve_backend
    from holo_viewer.render import gsplat_backend

    if gsplat_backend.is_available():
        pytest.skip("CUDA and gsplat present: auto picks gsplat")
    assert resolve_backend("auto") == "fast" and resolve_backend("fast") == "fast"
    with pytest.raises(RenderError, match="CUDA"):
        resolve_backend("gsplat")
    with pytest.raises(InputError, match="backend"):
        resolve_backend("vulkan")
    assert main(["live", "--synthetic", "--seconds", "1.0", "--headless", "--frames", "1", "--renderer", "gsplat",
                 "--out", str(tmp_path / "s")]) == 1
    err = capsys.readouterr().err
    assert "CUDA" in err and "Traceback" not in err


def test_live_loop_on_gsplat_renders_every_view_on_the_device(monkeypatch):
    """Where gsplat runs, ``auto`` picks it and every live frame is all 48 views rendered and
    interleaved on the device, tracked face or not. Here CPU torch stands in for CUDA and the fast
    renderer for gsplat: the native image must be the CPU path's exact all-views frame (every view
    rendered) up to one level of rounding."""
    torch = pytest.importorskip("torch")
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.render import fast, gsplat_backend

    def cpu_render_device(g, cameras, config=None, views_per_call=None):
        return torch.as_tensor(fast.render(g, cameras, config).images.copy())

    monkeypatch.setattr(gsplat_backend, "is_available", lambda: True)
    monkeypatch.setattr(gsplat_backend, "render_device", cpu_render_device)
    r = LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, mode="auto")
    assert r.backend == "gsplat" and r._live.config.backend == "gsplat"
    calls = []
    frame = r._live.frame
    r._live.frame = lambda g, viewer, mode: calls.append((viewer, mode)) or frame(g, viewer, mode)
    listener = {"expr": np.zeros(10), "jaw_pose": np.array([0.2, 0.0, 0.0])}
    tracked = r.render(listener, 0.6, (), 5.0, 0.7, True).native
    untracked = r.render(listener, 0.6, (), 5.0, 0.7, False).native
    assert calls == [(None, "all_views"), (None, "all_views")]
    exact = LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, mode="all_views", backend="fast", view_step=1)
    ref = exact.render(listener, 0.6, (), 5.0, 0.7, False).native
    for img in (tracked, untracked):
        diff = np.abs(img.astype(int) - ref.astype(int))
        assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
    assert ref.any()


def test_live_backend_auto_falls_back_to_the_cpu_when_gsplat_fails(monkeypatch):
    """gsplat builds its CUDA kernels on first use, which can fail (no compiler, a driver
    mismatch): ``auto`` then renders on the CPU with a warning; an explicit ``gsplat`` says why."""
    from holo_viewer.errors import RenderError
    from holo_viewer.live.render import LiveAvatarRenderer
    from holo_viewer.render import gsplat_backend

    def broken(*args, **kwargs):
        raise RuntimeError("Error building extension 'gsplat_cuda': nvcc not found")

    monkeypatch.setattr(gsplat_backend, "is_available", lambda: True)
    monkeypatch.setattr(gsplat_backend, "_import", lambda: None)
    monkeypatch.setattr(gsplat_backend, "render_device", broken)
    with pytest.warns(RuntimeWarning, match="nvcc not found"):
        r = LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, mode="auto")
    assert r.backend == "fast" and r._live.config.backend == "fast" and r.pipeline.backend == "fast"
    assert r.render({"expr": np.zeros(10)}, 0.3, (), 5.0, 0.7, True).native.shape == (2048, 1536, 3)
    with pytest.raises(RenderError, match="nvcc not found.*--renderer fast"):
        LiveAvatarRenderer(tile_scale=0.1, native=True, preview=False, mode="auto", backend="gsplat")
    monkeypatch.setattr(gsplat_backend, "render", broken)  # cone: the pipeline renders the views
    with pytest.warns(RuntimeWarning, match="nvcc not found"):
        cone = LiveAvatarRenderer(tile_scale=0.1, native=False, preview=True, mode="cone")
    assert cone.backend == cone.pipeline.backend == "fast"


def test_render_pose_predicts_where_the_viewer_will_be(tmp_path):
    """The loop renders for the newest tracked pose extrapolated over its age plus the median of
    the last renders (predict_viewer, the default); without prediction, or for an untracked pose,
    for the pose as it is."""
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSessionConfig, LiveSession
    from holo_viewer.tracking.viewer import ViewerPose

    now = [10.0]
    for predict in (True, False):
        session = LiveSession(LiveSessionConfig(out=str(tmp_path / f"s{int(predict)}"), predict_viewer=predict),
                              sources.ArrayAudio(np.zeros(16000, np.float32)), None, clock=lambda: now[0])
        session._start = 0.0  # media time = clock
        session.render_ms = [50.0, 70.0, 60.0]
        pose = ViewerPose(5.0, 0.6, True, rate=(20.0, -0.1), lag_s=(0.05, 0.02))
        session._viewer.put((9.96, pose))  # its webcam frame is 40 ms old
        ang, dist, tracked = session._render_pose()
        if predict:  # ahead: lag + 40 ms + 60 ms
            assert ang == pytest.approx(5.0 + 20.0 * 0.15) and dist == pytest.approx(0.6 - 0.1 * 0.12)
        else:
            assert (ang, dist) == (5.0, 0.6)
        assert tracked
        session._viewer.put((9.96, ViewerPose(5.0, 0.6, False)))
        assert session._render_pose() == (5.0, 0.6, False)


@pytest.mark.slow
def test_track_fps_skips_webcam_frames_and_keeps_the_face(clip, tmp_path):
    """``track_fps``: at most that many webcam frames a second are tracked (the others skipped, the
    speaker face and viewer pose kept from the tracked ones); a bad rate is named."""
    from holo_viewer.errors import InputError
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig

    session = LiveSession(LiveSessionConfig(out=str(tmp_path / "s"), track_fps=8.0), sources.WavReplay(clip["wav"]),
                          sources.VideoReplay(clip["video"]))
    session.run(None)
    s = _check_session(tmp_path / "s", n_frames=40)
    assert 6 <= len(session.tracker_ms) <= 1.6 * 8 + 1  # every 3rd or 4th of the 25 fps frames, not 40
    assert len(session.tracker_cpu_ms) == len(session.tracker_ms)
    assert s["tracks"]["speaker_found"].mean() > 0.5
    with pytest.raises(InputError, match="track_fps: expected frames a second > 0 or None, found 0"):
        LiveSessionConfig(track_fps=0)


class _EveryFrame:
    """A video source that hands the tracker each frame once, whatever the clock (no frame skipped)."""

    def __init__(self, frames):
        self.frames, self.i, self.finished, self.status = frames, -1, False, "ok"

    def latest(self, t):
        self.i = min(self.i + 1, len(self.frames) - 1)
        self.finished = self.i == len(self.frames) - 1
        return self.frames[self.i]


@pytest.mark.slow
def test_viewer_fps_keeps_the_speaker_features_at_the_webcam_rate(clip, tmp_path):
    """``viewer_fps`` (issue 37): the face search and the other faces run at the viewer's rate, the
    speaker's landmarks and fit on every webcam frame, so the features stay at 25 Hz: on every frame of
    the 1.6 s clip the speaker state is new, the HOG detector runs on the viewer's frames only (once
    here; every 10th frame, 4 times, with ``viewer_fps=None``), and with one face the viewer pose
    follows it on every frame. The tracker thread's loop, driven frame by frame (no clock)."""
    from holo_viewer.errors import InputError
    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig
    from holo_viewer.tracking.tracker import FaceTracker
    from holo_viewer.tracking.video import iter_video_frames
    from holo_viewer.tracking.viewer import WebcamMount

    frames = list(iter_video_frames(clip["video"]))
    assert len(frames) == 40
    tracker = FaceTracker()
    runs = {}
    for viewer_fps in (5.0, None):
        session = LiveSession(LiveSessionConfig(out=str(tmp_path / f"s{viewer_fps}"), viewer_fps=viewer_fps),
                              sources.WavReplay(clip["wav"]), _EveryFrame(frames))
        tracker.reset()
        tracker.detector.n_detections = 0
        session._face_tracker, session._mount = tracker, WebcamMount()
        states = []
        put = session._speaker.put
        session._speaker.put = lambda v, put=put, states=states: (states.append(v), put(v))
        session._tracker_loop()
        assert not session.errors
        runs[viewer_fps] = (states, tracker.detector.n_detections, session.viewer_updates)
    states, detections, updates = runs[5.0]
    assert len(states) == 40 and all(f for _, _, f in states)  # every frame tracked, the face found
    assert all(not np.array_equal(a[1], b[1]) for a, b in zip(states, states[1:]))  # 25 Hz features
    assert detections == 1 and runs[None][1] == 4
    assert updates == 40 == runs[None][2]  # one face: its viewer pose on every frame
    # until the every-frame run's second detection re-frames the face, the same landmarks and states
    np.testing.assert_array_equal(np.stack([st for _, st, _ in states[:10]]),
                                  np.stack([st for _, st, _ in runs[None][0][:10]]))
    with pytest.raises(InputError, match="viewer_fps: expected frames a second > 0 or None, found -1"):
        LiveSessionConfig(viewer_fps=-1)


def test_stream_speech_gate_equals_speech_gate():
    """The live loop's pause gate reads the reaction stream's VAD (silero once per chunk instead of twice,
    issue 37): on 8 s of recorded speech, delivered in 25 fps frames and in uneven blocks (a late
    microphone), it gives the standalone SpeechGate's (speaking, pause onset) and probability exactly."""
    from holo_viewer.live.loop import speech_gate
    from holo_viewer.reaction.audio import read_wav
    from holo_viewer.reaction.speech import SpeechGate, SpeechTracker

    x, sr = read_wav(Path(__file__).parent / "data" / "speech" / "librispeech_198-209-0000.wav")
    x = x[:8 * sr]
    for sizes in ((640,), (300, 980, 640)):
        bounds = np.cumsum(np.resize(sizes, x.shape[0] // min(sizes) + 1))
        blocks = np.split(x, bounds[bounds < x.shape[0]])
        tracker, ref = SpeechTracker(), SpeechGate()

        class _Stream:
            _speech = tracker

        gate = speech_gate(_Stream())
        assert gate.shares_vad and not ref.shares_vad and not speech_gate(None).shares_vad
        got, want = [], []
        for b in blocks:
            tracker.push(b)
            got.append((*gate.step(b), gate._prob))
            want.append((*ref.step(b), ref._prob))
        assert got == want
        assert sum(o for _, o, _ in got) >= 2 and sum(s for s, _, _ in got) > len(got) // 3


def test_tracker_sleeps_until_the_next_video_frame(tmp_path):
    """Issue 37: between webcam frames the tracker thread sleeps until the next one (a replayed file's next
    frame time, a webcam's next frame) instead of waking every 3 ms; at most 20 ms (pause, stop). Also
    VideoReplay.next_time on a real file: the next frame's media time, None after the last."""
    import imageio.v2 as imageio

    from holo_viewer.live import sources
    from holo_viewer.live.loop import LiveSession, LiveSessionConfig

    slept, waited = [], []

    class Replay:
        t = None

        def next_time(self):
            return self.t

    class Cam:
        def wait_frame(self, timeout):
            waited.append(timeout)

    s = LiveSession(LiveSessionConfig(out=str(tmp_path / "s")), None, Replay(), clock=lambda: 1.0)
    s._stop = type("Stop", (), {"wait": lambda self, timeout: slept.append(timeout)})()  # a stop would end it
    for t in (1.015, 5.0, 0.5, None):  # the session clock reads 1.0 s
        s.video.t = t
        s._wait_video()
    s.video = Cam()
    s._wait_video()
    s.video = object()  # a source with neither: polled as before
    s._wait_video()
    assert slept == pytest.approx([0.015, 0.02, 0.0005, 0.003, 0.003]) and waited == [0.02]
    s2 = LiveSession(LiveSessionConfig(out=str(tmp_path / "s2")), None, None, clock=lambda: 1.0)
    assert s2._sleep_until(0.5) is True  # due: no wait
    s2._stop.set()
    assert s2._sleep_until(100.0) is False  # stopped: the reaction thread's wait ends
    video = tmp_path / "v.mp4"
    imageio.mimwrite(video, [np.full((32, 32, 3), 40 * i, np.uint8) for i in range(3)], fps=25, macro_block_size=1)
    v = sources.VideoReplay(video)
    assert v.next_time() == 0.0
    assert v.latest(0.05)[0] == pytest.approx(0.04) and v.next_time() == pytest.approx(0.08)
    assert v.latest(1.0)[0] == pytest.approx(0.08) and v.next_time() is None and v.finished


def test_speech_tracker_keeps_only_the_vad_chunks_it_still_reads():
    """Issue 37: the streamed speech channels forget the silero chunks no later frame reads (the whole list
    was converted at every pitch block, a cost that grew with the session); the probability and the rows
    are unchanged (the rows against the offline features: tests/test_reaction_speech.py)."""
    from holo_viewer.reaction.speech import CHUNK, SpeechTracker, vad_probabilities

    x = (np.random.default_rng(3).normal(0, 0.1, 16000 * 4)).astype(np.float32)
    tr = SpeechTracker()
    longest = 0
    for i in range(0, x.shape[0], 640):
        tr.push(x[i:i + 640])
        if (i // 640) % 4 == 3:
            tr.frames()
        longest = max(longest, len(tr._chunks))
    assert longest <= 8 and tr._chunk0 > 100
    assert tr.vad_probability == pytest.approx(float(vad_probabilities(x[:x.shape[0] // CHUNK * CHUNK])[-1]), abs=1e-6)


def test_traced_reaction_stream_equals_the_model(monkeypatch):
    """Issue 37: the live loop's stream runs a TorchScript trace of the model (half its CPU a step): over 4 s of
    speech at the default (sampled, seeded) decoding, every listener frame equals the eager stream's, bit for
    bit; a model that cannot be traced runs as it is and the stream says why."""
    import torch

    from holo_viewer.pipeline.live_support import SyntheticSpeaker
    from holo_viewer.reaction.api import load_default_bundle
    from holo_viewer.reaction.decoding import DEFAULT_TEMPERATURE, DEFAULT_TOP_K
    from holo_viewer.reaction.stream import ReactionStream

    syn = SyntheticSpeaker(4.0, seed=5)
    bundle = load_default_bundle()
    kw = {"temperature": DEFAULT_TEMPERATURE, "top_k": DEFAULT_TOP_K, "seed": 2}
    eager, traced = ReactionStream(bundle, **kw), ReactionStream(bundle, trace=True, **kw)
    assert traced.trace_error is None and traced._run is not traced.model and eager._run is eager.model
    assert ReactionStream(bundle, trace=True, **kw)._run is traced._run  # traced once in this process
    outs = ([], [])
    for t in range(len(syn.states)):
        for stream, out in zip((eager, traced), outs):
            stream.push_audio(syn.waveform[t * 640:(t + 1) * 640])
            out.append(stream.push_frame(syn.states[t], 0.4)[0])
    assert len(traced.windows) >= 20 and np.array_equal(np.array(outs[0]), np.array(outs[1]))
    assert np.ptp(np.array(outs[0]), axis=0).max() > 0.05  # the listener moves: the comparison means something

    def no_trace(*a, **k):
        raise RuntimeError("cannot trace this")

    monkeypatch.setattr(torch.jit, "trace", no_trace)
    import weakref

    from holo_viewer.reaction import stream as stream_module

    monkeypatch.setattr(stream_module, "_TRACES", weakref.WeakKeyDictionary())  # none traced in this process yet
    s = ReactionStream(bundle, trace=True, **kw)
    assert s._run is s.model and s.trace_error == "RuntimeError: cannot trace this"


def test_check_array_fast_path_keeps_every_message() -> None:
    """check_array's one-reduction hot path (numpy, and CPU torch through its numpy view; issue 37's live
    frames) returns clean arrays unchanged and raises the same message as before on NaN/inf, for every kind
    of array it takes (float16/32/64, complex, a tensor that needs grad, bfloat16, a conjugate view)."""
    import torch

    from holo_viewer.errors import InputError
    from holo_viewer.validation import check_array

    msg = "ctx: v: expected finite values, found 6 NaN/inf (flat indices [1, 2, 3, 4, 5]...)"
    base = np.zeros(9)
    base[1:7] = [np.nan, np.inf, -np.inf, np.nan, np.nan, np.inf]
    for x in (base, base.astype(np.float32), base.astype(np.float16), base.astype(np.complex128),
              torch.tensor(base), torch.tensor(base, dtype=torch.float32, requires_grad=True),
              torch.tensor(base, dtype=torch.bfloat16), torch.tensor(base, dtype=torch.complex64).conj()):
        with pytest.raises(InputError) as err:
            check_array(x, "v", ("N",), context="ctx")
        assert str(err.value) == msg, (type(x), x.dtype)
        clean = x[:1] if isinstance(x, np.ndarray) else x.detach()[:1]
        assert check_array(clean, "v", ("N",), context="ctx") is clean
    ints = np.arange(4)
    assert check_array(ints, "i", ("N",)) is ints and check_array(torch.arange(4), "i").shape == (4,)
