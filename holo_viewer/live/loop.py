"""The live session loop: sources -> tracker and reaction threads -> renderer (latest wins).

Threads (docs/design.md "A live loop that never waits")::

    tracker thread   newest video frame -> FaceTracker -> latest speaker state + ViewerTracker pose
    reaction thread  25 fps clock: audio up to the frame + latest speaker state -> ReactionStream
                     (one model step every k frames) -> listener frame t, recorded in the session
    main thread      latest listener frame + viewer pose + pain -> LiveAvatarRenderer -> panel window /
                     preview window / native.mkv; keys; stops when the sources end, at --frames,
                     on q/Esc or Ctrl-C

Pause (space) stops the session clock (:meth:`LiveSession.now`): the reaction thread, the audio it
reads, the scenario, the tracker and the recording wait where they are, the preview shows
"PAUSED" on the last frame, and the session resumes where it stopped. native.mkv holds each
displayed frame once, lossless, at the session time it was shown (:mod:`holo_viewer.media`).

Nothing queues between them: each publishes its newest result into a slot and the consumer takes
whatever is newest when it is free, so a slow renderer shows fewer frames but never delays the
reaction stream. Every result carries its media time, so latency is measured end to end.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import ExportError, HoloViewerError, InputError
from ..media import CODECS
from ..reaction.decoding import DEFAULT_TEMPERATURE, DEFAULT_TOP_K
from ..tracking.viewer import ViewerPose
from .controls import Controls, Scenario
from .session import NATIVE_VIDEO, SessionRecorder

__all__ = ["LiveSessionConfig", "LiveSession", "speech_gate", "session_behaviour", "starting_image"]

FPS = 25
#: the session video's encoder flags: the lossless policy's, on one encoder thread. x264's default
#: frame threads cost 57 instead of 36 ms of CPU a 2048x1536 native frame (the same file size; issue
#: 37, docs/live.md), CPU the live render needs on 2 cores
SESSION_VIDEO_PARAMS = (*CODECS["lossless"]["output_params"], "-threads", "1")
#: the session video's codec (``live --native-codec``) -> its media.CODECS policy, each on one encoder thread:
#: FFVHuff (the default: bit-exact, ~9 ms less CPU a displayed frame than x264 in the live session, +0.5
#: displayed fps on 2 cores, for ~2.4x the disk; ``holo-viewer compact`` re-encodes it to x264 afterwards)
#: or x264 (the smallest file); issue 37, docs/live.md "The session video's CPU"
SESSION_VIDEO_CODECS = {"x264": "lossless", "ffvhuff": "lossless-fast"}
#: MB a displayed 2048x1536 native frame, measured in live sessions (bench/session_codecs.py --live,
#: bench/results/session_codecs_live.json): for the disk estimate ``live`` prints before it starts
SESSION_VIDEO_MB_PER_FRAME = {"x264": 1.8, "ffvhuff": 4.3}
#: and it runs this much nicer than the session: in the render's gaps, its frames queued meanwhile
SESSION_VIDEO_NICE = 5
#: seconds without a new tracked frame after which the speaker face decays to neutral
STALE_S = 0.5


def recording_minutes(free_bytes: float, codec: str, displayed_fps: float = 12.0) -> tuple[float, float]:
    """The session video's disk rate (GB a minute at ``displayed_fps``, one native frame each) with
    ``codec`` (a key of :data:`SESSION_VIDEO_CODECS`) and the minutes ``free_bytes`` hold at that rate."""
    if codec not in SESSION_VIDEO_MB_PER_FRAME:
        raise InputError(f"native_codec: expected one of {sorted(SESSION_VIDEO_MB_PER_FRAME)}, found {codec!r}")
    gb_per_min = SESSION_VIDEO_MB_PER_FRAME[codec] * 1e6 * displayed_fps * 60 / 1e9
    return gb_per_min, max(0.0, float(free_bytes)) / 1e9 / gb_per_min


@dataclass(frozen=True)
class LiveSessionConfig:
    """Settings of a live session (see ``holo-viewer live --help``)."""

    out: str = "session"
    frames: int | None = None
    tile_scale: float = 1.0
    native: bool = True
    preview: bool = False
    panel: bool = False
    monitor: int | None = None
    video_fps: float = 10.0
    write_native_video: bool = True
    record_video: bool = False
    flush_s: float = 5.0
    pain: float = 0.0
    temperature: float = DEFAULT_TEMPERATURE  # the reaction model's default decoding (0 = argmax)
    seed: int = 0
    hfov_deg: float = 60.0
    mount: Any = None
    viewer_mode: str = "nearest"
    #: render for where the tracked viewer will be when the frame is shown (the pose extrapolated
    #: over the smoothing's lag, the pose's age and the expected render time; ViewerPose.predicted)
    predict_viewer: bool = True
    #: track at most this many webcam frames a second (None: every frame, 25 fps on a webcam); the
    #: others are skipped (still recorded). The viewer pose keeps its prediction from the tracked ones
    track_fps: float | None = None
    #: the viewer's rate: at most this many tracked frames a second look for faces and at every face (the
    #: HOG detector every ``redetect_every``-th of them, the other faces' landmarks, the viewer pose of all
    #: faces); on the frames between, the speaker's face alone (its landmarks and fit: the speaker's
    #: features keep the webcam's rate) and, while one face is tracked, its viewer pose. None: every
    #: tracked frame looks at every face (issue 37: the tracker's CPU; docs/live.md)
    viewer_fps: float | None = 5.0
    #: render up to this many frames at once, each on a renderer of its own in a thread of its own, shown in
    #: the order started (holo_viewer.live.inflight). Only renderers whose frames do not depend on earlier
    #: ones (LiveAvatarRenderer.frames_independent); others render one frame at a time in this thread. 1 by
    #: default: since group frames draw no eye slices, one frame keeps the 2 cores busy and a second one in
    #: flight cost CPU and latency (quiet A/B, docs/live.md: 7.75 against 7.38 displayed fps, 414 against
    #: 582 ms to a visible change)
    frames_in_flight: int = 1
    #: the face tracker's dlib in a child process (TrackerConfig.detector_process: the same landmarks, and the
    #: ~2 ms of each shape prediction no longer holds this process's GIL, which the render's thread needs between
    #: its kernels; ~0.7 ms more CPU a tracked frame for the pipe). Off until a quiet A/B shows the displayed fps
    #: gain (`bench/live_latency.py --ab-tracker`; issue 37, docs/live.md)
    tracker_process: bool = False
    #: each renderer's threads while frames are in flight (None: the cores over frames_in_flight, at least 1)
    render_threads_in_flight: int | None = None
    scenario: Any = None
    #: the no-data behaviour layers (a holo_viewer.behaviour.BehaviourConfig; "default": all on, seeded
    #: by ``seed``; None: the reaction model alone, conditioned on the pain level)
    behaviour: Any = "default"
    max_seconds: float | None = None
    #: native.mkv's lossless codec, a key of SESSION_VIDEO_CODECS ("ffvhuff" or "x264")
    native_codec: str = "ffvhuff"
    settings: dict = field(default_factory=dict)


    def __post_init__(self) -> None:
        if self.native_codec not in SESSION_VIDEO_CODECS:
            raise InputError(f"native_codec: expected one of {sorted(SESSION_VIDEO_CODECS)}, found {self.native_codec!r}")
        if isinstance(self.frames_in_flight, bool) or not isinstance(self.frames_in_flight, int) or \
                self.frames_in_flight < 1:
            raise InputError(f"frames_in_flight: expected an integer >= 1, found {self.frames_in_flight!r}")
        for name in ("track_fps", "viewer_fps"):
            f = getattr(self, name)
            if f is not None and not (isinstance(f, (int, float)) and math.isfinite(f) and f > 0):
                raise InputError(f"{name}: expected frames a second > 0 or None, found {f!r}")


def _fast_fit_ready() -> bool:
    """Whether the live tracker fits with the compiled steps (:mod:`holo_viewer.tracking.fit_fast`, ~0.85 ms of
    CPU less a tracked frame, issue 37): yes when numba has them cached (scripts/setup.sh compiles them;
    loading takes milliseconds). On a cold cache the session fits with the numpy reference (compiling would
    stall the first tracked face ~6 s of CPU) and a child compiles them at nice 19 for the next session
    (none with ``HOLO_VIEWER_BACKGROUND_BUILDS=0`` or ``HOLO_VIEWER_PRECOMPILE=0``)."""
    import os
    import subprocess
    import sys

    from ..tracking.fit_fast import kernel_cached

    if kernel_cached():
        return True
    if os.environ.get("HOLO_VIEWER_BACKGROUND_BUILDS", "1") != "0" and os.environ.get("HOLO_VIEWER_PRECOMPILE", "1") != "0":
        try:
            subprocess.Popen(["nice", "-n", "19", sys.executable, "-m", "holo_viewer.tracking.fit_fast"],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        except OSError:
            pass
    return False


def session_behaviour(behaviour: Any, seed: int, renderer: Any = None) -> Any:
    """The session's :class:`~holo_viewer.behaviour.ListenerBehaviour` (``behaviour``: a BehaviourConfig or
    "default", seeded with ``seed``), with the rendered avatar's own AU map (``renderer.pipeline.au_map``:
    its pain gains, as its pain slider and the legibility bench use them); no renderer: the default head's."""
    from ..behaviour import BehaviourConfig, ListenerBehaviour

    bcfg = BehaviourConfig(seed=seed) if isinstance(behaviour, str) else behaviour
    au_map = renderer.pipeline.au_map if renderer is not None and hasattr(renderer, "pipeline") else None
    return ListenerBehaviour(bcfg, au_map=au_map)


def speech_gate(stream: Any) -> Any:
    """The behaviour layers' pause gate (:class:`~holo_viewer.reaction.speech.SpeechGate`) for a session
    whose reaction stream is ``stream``: reading that stream's silero probabilities when it keeps speech
    channels (silero ran twice per chunk otherwise, ~40 % of the reaction thread's CPU; issue 37), else
    with its own VAD."""
    from ..reaction.speech import SpeechGate, SpeechTracker

    tracker = getattr(stream, "_speech", None)
    return SpeechGate(vad=tracker if isinstance(tracker, SpeechTracker) else None)


class _Slot:
    """Newest value wins (no queue)."""

    def __init__(self, value: Any = None) -> None:
        self._lock = threading.Lock()
        self._v = value

    def put(self, v: Any) -> None:
        with self._lock:
            self._v = v

    def get(self) -> Any:
        with self._lock:
            return self._v


class LiveSession:
    """Run one session; see the module docstring.

    Parameters
    ----------
    config : LiveSessionConfig
    audio : audio source (``sources.ArrayAudio`` / ``WavReplay`` / ``Microphone``)
    video : video source (``sources.VideoReplay`` / ``Webcam``) or None (synthetic speaker / audio only)
    synthetic : holo_viewer.pipeline.live_support.SyntheticSpeaker or None
        Gives the speaker states and viewer pose directly (no tracker).
    clock : callable
        Seconds (``time.perf_counter``).
    """

    def __init__(self, config: LiveSessionConfig, audio: Any, video: Any = None, synthetic: Any = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.config = config
        self.audio = audio
        self.video = video
        self.synthetic = synthetic
        self.clock = clock
        self.controls = Controls(pain=config.pain)
        self.scenario: Scenario | None = config.scenario
        self._speaker = _Slot((0.0, None, False))  # (media time, state or None, found)
        self._viewer = _Slot((0.0, ViewerPose(0.0, 0.6, False)))  # (media time of its webcam frame, pose)
        self._listener = _Slot(None)  # (frame, flame dict, pain, named, media time ready)
        self._stop = threading.Event()
        self._media_done = threading.Event()
        self.tracker_ms: list[float] = []
        self.tracker_cpu_ms: list[float] = []  # the tracker thread's CPU per tracked frame
        self.viewer_updates = 0  # tracked frames that updated the viewer pose
        self.window_ms: list[float] = []
        self.late_windows = 0
        self.late_ms_max = 0.0
        self.late_ticks = 0
        self.render_ms: list[float] = []
        self.status: dict[str, str] = {}
        self.errors: list[BaseException] = []
        self.recorder = SessionRecorder(config.out, {**config.settings})
        self._start = 0.0
        #: (clock() when the current pause began or None, seconds spent paused before it); one tuple,
        #: swapped whole, so the other threads' now() never sees half an update
        self._pause: tuple[float | None, float] = (None, 0.0)
        self._webcam_writer = None
        #: level changes as the pain-timeline schema (holo_viewer.behaviour.timeline), for session.json
        self.pain_log: list[dict] = []
        self._pain_source = "key"
        self._behaviour = None
        self._speech_gate = None
        #: the renderers of run() (holo_viewer.live.inflight.FramesInFlight; None without a renderer)
        self.frames_in_flight = None
        #: called with a line for each start-up step (the live command prints it and shows it on the preview)
        self.progress: Callable[[str], None] = lambda line: None

    # ------------------------------------------------------------------ time
    def now(self) -> float:
        """Media time in seconds since the session started, stopped while paused."""
        paused_at, offset = self._pause
        return (self.clock() if paused_at is None else paused_at) - self._start - offset

    def _update_pause(self) -> bool:
        """Follow the pause key: stop or restart the session clock; True while paused."""
        paused = self.controls.paused
        paused_at, offset = self._pause
        if paused and paused_at is None:
            self._pause = (self.clock(), offset)
        elif not paused and paused_at is not None:
            self._pause = (None, offset + self.clock() - paused_at)
        return paused

    def _sleep_until(self, media_t: float) -> bool:
        while not self._stop.is_set():
            d = media_t - self.now()
            if d <= 0:
                return True
            # one wait to the frame (25 fps: <= 40 ms; 50 ms at most, for a pause) instead of 10 ms sleeps: each
            # wake-up takes the GIL from the render's thread (issue 37); a stop ends it at once
            self._stop.wait(min(d, 0.05))
        return False

    # ------------------------------------------------------------------ tracker thread
    def _wait_video(self) -> None:
        """Until the video source may have a new frame: a replayed file's next frame time (``next_time``),
        a webcam's next frame (``wait_frame``), at most 20 ms (pause, stop); other sources: 3 ms. The
        tracker thread polled every 3 ms before, ~10 wake-ups a 25 fps frame, each taking the GIL from the
        render's thread (issue 37)."""
        nxt = getattr(self.video, "next_time", None)
        if nxt is not None:
            t = nxt()
            d = 0.003 if t is None else t - self.now()
            self._stop.wait(min(max(d, 0.0005), 0.02))  # a stop ends it at once
        elif hasattr(self.video, "wait_frame"):
            self.video.wait_frame(0.02)
        else:
            self._stop.wait(0.003)

    def _tracker_loop(self) -> None:
        from ..tracking.viewer import ViewerTracker, ViewerTrackerConfig

        tracker = self._face_tracker
        viewer = ViewerTracker(self._mount, ViewerTrackerConfig(mode=self.config.viewer_mode))
        last_t = last_tracked = last_full = None
        min_dt = 0.0 if self.config.track_fps is None else 1.0 / float(self.config.track_fps)
        full_dt = 0.0 if self.config.viewer_fps is None else 1.0 / float(self.config.viewer_fps)
        faces_seen = 0  # faces of the last frame that looked at every face
        try:
            while not self._stop.is_set():
                if self.controls.take_recentre():
                    viewer.recentre()
                item = self.video.latest(self.now())
                if item is None or item[0] == last_t:
                    if self.video.finished and item is not None and item[0] == last_t:
                        break
                    self._wait_video()
                    continue
                last_t, frame = item
                if last_tracked is not None and last_t - last_tracked < min_dt - 1e-6:  # track_fps
                    if self.config.record_video:
                        self._record_webcam(frame)
                    continue
                last_tracked = last_t
                # viewer_fps: between the frames that look at every face, the speaker's face alone
                full = last_full is None or last_t - last_full >= full_dt - 1e-6
                t0, c0 = time.perf_counter(), time.thread_time()
                tf = tracker(frame, last_t, speaker_only=not full)
                self.tracker_ms.append(1000 * (time.perf_counter() - t0))
                self.tracker_cpu_ms.append(1000 * (time.thread_time() - c0))
                self._speaker.put((last_t, tf.state, tf.found))
                if tf.all_faces:
                    last_full, faces_seen = last_t, len(tf.faces)
                # every face looked at, or one face: its pose at the webcam's rate, as before
                if tf.all_faces or (faces_seen == 1 and tf.found):
                    self.viewer_updates += 1
                    self._viewer.put((last_t, viewer.update(tf.eye_positions, last_t)))
                if self.config.record_video:
                    self._record_webcam(frame)
                self.status["video"] = self.video.status if tf.found else f"{self.video.status}; no face"
        except BaseException as exc:  # noqa: BLE001 - reported by run()
            self.errors.append(exc)
            self._stop.set()

    # ------------------------------------------------------------------ reaction thread
    def _reaction_loop(self) -> None:
        from ..pipeline.live_support import FaceStates

        import torch

        torch.set_num_threads(1)  # one model step is tiny; a thread pool only adds wake-up latency
        try:
            faces = FaceStates()
            stream = self._stream
            S = stream.S
            end_frames = None
            if self.audio.finished is False and hasattr(self.audio, "duration_s"):
                end_frames = int(math.floor(self.audio.duration_s * FPS + 1e-9))
            if self.config.max_seconds is not None:
                cap = int(self.config.max_seconds * FPS)
                end_frames = cap if end_frames is None else min(end_frames, cap)
            t = 0
            scenario_shift = 0.0  # scenario time - session time (the step keys jump between steps)
            last_state = np.zeros(S)
            gate = self._speech_gate
            beh = self._behaviour
            while not self._stop.is_set() and (end_frames is None or t < end_frames):
                due = (t + 1) / FPS  # audio of frame t is complete (centre + half a window) by then
                if not self._sleep_until(due):
                    break
                if self.now() > due + 1.0 / FPS:
                    self.late_ticks += 1
                samples = self.audio.read(due)
                if self.controls.muted:  # the instructor's voice stays out of the patient's input (and audio.wav)
                    samples = np.zeros_like(samples)
                stream.push_audio(samples)
                self.recorder.add_audio(samples)
                speaking, pause_onset = gate.step(samples)
                if self.audio.status != "ok":
                    self.status["audio"] = self.audio.status
                # speaker state for frame t
                if self.synthetic is not None:
                    state = self.synthetic.states[min(t, len(self.synthetic.states) - 1)]
                    found = True
                    ang, dist = self.synthetic.viewer(t / FPS)
                    self._viewer.put((t / FPS, ViewerPose(ang, dist, True)))
                else:
                    ts, st, found = self._speaker.get()
                    state = last_state if st is None else st
                    if st is not None and t / FPS - ts > STALE_S:  # no new video frames (webcam unplugged,
                        found = False  # video over): keep reacting to the audio, the face decays to neutral
                        state = last_state * math.exp(-1.0 / (FPS * STALE_S))
                        self.status["video"] = "no new video frames"
                last_state = np.asarray(state, dtype=np.float64)
                # pain: scenario events, then keys on top; the step keys move the scenario time
                ts = t / FPS + scenario_shift
                if self.scenario is not None:
                    steps = self.controls.take_scenario_steps()
                    for d in steps:
                        ts = self.scenario.step_from(ts, d)
                    scenario_shift = ts - t / FPS
                    p = self.scenario.pain_changes(ts - 1 / FPS, ts) if t and not steps else self.scenario.pain_at(ts)
                    if p is not None:
                        self.controls.set_pain(p)
                        self._pain_source = "scenario"
                pain = self.controls.pain
                self._log_pain(t / FPS, pain)
                named = self.scenario.named_at(ts) if self.scenario is not None else ()
                t0 = time.perf_counter()
                n_windows = len(stream.windows)
                # with the behaviour layers the pain face is theirs (exact, at once); the model hears pain 0
                listener, window = stream.push_frame(last_state, pain if beh is None else 0.0)
                if len(stream.windows) > n_windows:
                    dt = time.perf_counter() - t0
                    self.window_ms.append(1000 * dt)
                    late = self.now() - (t + 2) / FPS
                    if late > 0:  # the next frame's slot has passed: the window is late (its frames are still
                        self.late_windows += 1  # generated and recorded, only published late)
                        self.late_ms_max = max(self.late_ms_max, 1000 * late)
                lf = faces.listener(listener)
                sf = faces.speaker(last_state)
                _, vp = self._viewer.get()
                ang, dist = vp.angle_deg, vp.distance_m
                shown = -1.0  # no behaviour layers: the renderer adds the pain
                if beh is not None:  # eyes on the tracked viewer, blinks, breathing, sway, pain dynamics
                    from ..behaviour import viewer_target

                    for layer in self.controls.take_layer_toggles():  # the g / b / a / s keys
                        beh.config = dataclasses.replace(beh.config, **{layer: not getattr(beh.config, layer)})

                    lf = beh.step(lf, pain, viewer_target(float(np.clip(ang, -60, 60)), float(np.clip(dist, 0.05, 20))),
                                  speaking, pause_onset)
                    shown = beh.last["pain"]
                self.recorder.add_frame(
                    time_s=t / FPS, scenario_time_s=ts, viewer_angle_deg=ang, viewer_distance_m=dist, pain=pain, pain_shown=shown,
                    speaker_found=found,
                    window=window, **{f"speaker_{k_}": v for k_, v in sf.items()},
                    **{f"listener_{k_}": v for k_, v in lf.items()})
                self._listener.put((t, lf, pain, named, self.now()))
                t += 1
                if t % int(self.config.flush_s * FPS) == 0:
                    self._flush()
                if self.audio.finished and (self.video is None or self.video.finished) and end_frames is None:
                    break
        except BaseException as exc:  # noqa: BLE001 - reported by run()
            self.errors.append(exc)
            self._stop.set()
        finally:
            self._media_done.set()

    # ------------------------------------------------------------------ main (render) loop
    def _flush(self) -> None:
        self.recorder.summary = self.summary()
        try:
            self.recorder.flush()
        except HoloViewerError as exc:  # a full disk etc.: keep running, say so
            self.status["record"] = f"recording failed: {exc}"

    def summary(self) -> dict:
        def stats(x):
            a = np.asarray(list(x), dtype=np.float64)
            if not a.size:
                return None
            return {"n": int(a.size), "median": round(float(np.median(a)), 2), "p95": round(float(np.percentile(a, 95)), 2)}

        return {"pain_timeline": list(self.pain_log),
                "tracker_ms": stats(self.tracker_ms), "reaction_window_ms": stats(self.window_ms),
                "render_ms": stats(self.render_ms), "late_reaction_windows": self.late_windows,
                "late_reaction_window_max_ms": round(self.late_ms_max, 1),
                "late_reaction_ticks": self.late_ticks, "reaction_windows": len(self.window_ms),
                "displayed_frames": len(self.render_ms), "status": dict(self.status),
                **({"frames_in_flight": self.frames_in_flight.n} if self.frames_in_flight is not None else {})}

    def _log_pain(self, t: float, level: float) -> None:
        """Record an instructor level change (the session report's pain timeline, the shared schema)."""
        if not self.pain_log or self.pain_log[-1]["level"] != level:
            src = self._pain_source if self.pain_log or self._pain_source == "scenario" else "start"
            self.pain_log.append({"t": round(t, 3), "level": level, "source": src})
        self._pain_source = "key"

    def _render_pose(self) -> tuple[float, float, bool]:
        """(angle, distance, tracked) to render the next frame for: the newest viewer pose, or
        with ``predict_viewer`` where it will be when that frame is shown (its age now plus the
        median of the last renders)."""
        t_pose, pose = self._viewer.get()
        if self.config.predict_viewer and pose.tracked:
            render_s = float(np.median(self.render_ms[-9:])) / 1000.0 if self.render_ms else 0.0
            pose = pose.predicted(max(0.0, self.now() - t_pose) + render_s)
        return pose.angle_deg, pose.distance_m, pose.tracked

    def run(self, renderer: Any = None, panel: Any = None, preview: Any = None,
            on_frame: Callable[[Any], None] | None = None) -> dict:
        """Run until the sources end, ``frames`` are displayed, quit, or Ctrl-C; returns the summary.

        ``renderer``: a :class:`~holo_viewer.live.render.LiveAvatarRenderer` (None: no rendering, the
        session is still recorded); ``panel``/``preview``: objects with ``show(image)`` (and an
        optional ``poll()`` returning key symbols).
        """
        from ..media import ThreadedWriter, VideoWriter

        cfg = self.config
        out = Path(cfg.out)
        out.mkdir(parents=True, exist_ok=True)
        self._webcam_writer = None
        writer = None
        # load and warm up everything before the clock starts, so the first frames are not late
        self._face_tracker = None
        if self.video is not None and self.synthetic is None:
            from ..tracking.tracker import FaceTracker, TrackerConfig
            from ..tracking.viewer import WebcamMount

            self._mount = cfg.mount or WebcamMount(hfov_deg=cfg.hfov_deg)
            # created first: with tracker_process its dlib child loads dlib and the model while this process loads
            # the rest
            self._face_tracker = FaceTracker(TrackerConfig(hfov_deg=self._mount.hfov_deg, fast_fit=_fast_fit_ready(),
                                                           detector_process=cfg.tracker_process))
            # the compiled fit loaded from numba's cache (~0.4 s of CPU, much of it in LLVM without the GIL) beside
            # the reaction model's load and the renderer's warm-up, not after them
            fit_warm = threading.Thread(target=self._warm_fit, name="fit-warm-up", daemon=True)
            if self._face_tracker.config.fast_fit:
                fit_warm.start()
        from ..reaction.api import load_default_bundle
        from ..reaction.stream import ReactionStream

        self.progress("warming the reaction model")
        self._stream = ReactionStream(load_default_bundle(), temperature=cfg.temperature,
                                      top_k=DEFAULT_TOP_K if cfg.temperature else None, seed=cfg.seed, trace=True)
        self._speech_gate = speech_gate(self._stream)  # the model's speech channels' VAD, if it has them
        if cfg.behaviour is not None:
            self._behaviour = session_behaviour(cfg.behaviour, cfg.seed, renderer)
        from .session import avatar_record

        header = self.recorder.header
        header["scenario"] = self.scenario.to_json() if self.scenario is not None else None
        header["mount"] = dataclasses.asdict(cfg.mount) if dataclasses.is_dataclass(cfg.mount) else None
        if renderer is not None and hasattr(renderer, "pipeline"):
            header["avatar"] = avatar_record(renderer.pipeline, getattr(renderer, "avatar_name", "default"))
            header["render"] = {"mode": renderer.mode, "backend": renderer.backend, "tile_scale": cfg.tile_scale,
                                "warmup_pain": cfg.pain}
            if hasattr(renderer, "visible_record"):  # the visible-Gaussian mask the frames drew (replay draws it)
                header["render"]["visible"] = renderer.visible_record()
        frames = None
        if renderer is not None:  # replay --quality live repeats this call (header["render"]["warmup_pain"])
            self.progress("rendering a first frame")
            warmup = ({"expr": np.zeros(1)}, cfg.pain, (), 0.0, 0.6)
            # up to frames_in_flight frames at once on renderers of their own: their twins are built on the
            # other core from now on (during this warm-up, the tracker's and the first seconds if need be)
            from .inflight import FramesInFlight

            frames = FramesInFlight(renderer, cfg.frames_in_flight, warmup=warmup,
                                    threads_each=cfg.render_threads_in_flight)
            renderer.render(*warmup)
            if "render" in header:
                header["render"]["frames_in_flight"] = frames.n  # the frames are the same for any n (tested)
        self.frames_in_flight = frames
        if self._face_tracker is not None:
            self.progress("warming the face tracker")
            self._face_tracker(np.zeros((64, 64, 3), np.uint8), 0.0)  # warm up (first calls are slow)
            if fit_warm.is_alive():  # the fit's compiled steps loaded before the clock starts, not at the first face
                fit_warm.join()
            self._face_tracker.reset()
        self.progress("starting the session")
        self.audio.start()
        if self.video is not None:
            self.video.start()
        self._start = self.clock()
        threads = [threading.Thread(target=self._reaction_loop, name="reaction", daemon=True)]
        if self.video is not None and self.synthetic is None:
            threads.append(threading.Thread(target=self._tracker_loop, name="tracker", daemon=True))
        for th in threads:
            th.start()
        submitted = -1  # the newest listener frame handed to a renderer
        frames_shown = 0
        last_render = self.clock()
        last_preview = None  # (preview image, fps, pain, pose) of the last frame: shown with "PAUSED"
        paused_shown = False
        t_shown = -1.0
        # Ctrl-C ends the session between frames: the frame being shown completes (native.mkv then holds
        # exactly the frames session.json counts); frames still rendering are dropped, never shown
        interrupted = threading.Event()
        old_sigint = None
        if threading.current_thread() is threading.main_thread():
            old_sigint = signal.signal(signal.SIGINT, lambda signum, frame: interrupted.set())
        try:
            while not self._stop.is_set():
                if interrupted.is_set():
                    raise KeyboardInterrupt
                for src in (panel, preview):
                    if src is not None and hasattr(src, "poll"):
                        for key in src.poll():
                            self._key(key)
                if self.controls.quit:
                    break
                paused = self._update_pause()
                if paused and not paused_shown and preview is not None and last_preview is not None:
                    preview.show(self._overlay(*last_preview))  # the last frame, "PAUSED" on it
                paused_shown = paused
                # 1. the newest listener frame and viewer pose to a free renderer
                item = self._listener.get()
                new = item is not None and item[0] != submitted and not paused
                if new and (frames is None or (frames.can_submit() and (
                        cfg.frames is None or frames_shown + frames.in_flight < cfg.frames))):
                    kwargs: dict = {}
                    frame, lf, pain, named, _ready = item
                    ang, dist, tracked = self._render_pose()
                    submitted = frame
                    if frames is None:  # no renderer: the session is still recorded
                        frames_shown += 1
                        self.recorder.add_display(self.now(), frame, 0.0, render_angle_deg=ang, render_distance_m=dist,
                                                  render_tracked=tracked, render_others=())
                        if cfg.frames is not None and frames_shown >= cfg.frames:
                            break
                        continue
                    # the behaviour layers put the pain in the expressions already: add none on top
                    others = self._viewer.get()[1].others if tracked else ()  # the other faces seen
                    if others:
                        kwargs["others"] = others
                    frames.submit((lf, pain if self._behaviour is None else 0.0, named, ang, dist, tracked),
                                  kwargs, tag=(frame, pain, ang, dist, tracked, others))
                # 2. the oldest frame in flight, once rendered: shown, written, recorded (in the order started;
                # with one renderer it rendered in this thread just now)
                job = frames.take() if frames is not None else None
                if job is None:
                    in_flight = frames.in_flight if frames is not None else 0
                    if self._media_done.is_set() and not in_flight and (item is None or item[0] == submitted):
                        break
                    if in_flight:
                        frames.wait(0.005)
                    else:
                        time.sleep(0.005)
                    continue
                res = job.result
                frame, pain, ang, dist, tracked, others = job.tag
                self.render_ms.append(1000 * res.seconds)
                # each frame once at the session time it is shown (>= 1 ms after the previous one)
                t_shown = max(self.now(), t_shown + 0.001)
                if res.native is not None and cfg.write_native_video:
                    if writer is None:  # lossless RGB, timed Matroska; verified and renamed on close
                        writer = ThreadedWriter(VideoWriter(
                            out / NATIVE_VIDEO, cfg.video_fps, content=SESSION_VIDEO_CODECS[cfg.native_codec],
                            timed=True, output_params=(*CODECS[SESSION_VIDEO_CODECS[cfg.native_codec]]["output_params"],
                                                       "-threads", "1"), what="session video", nice=SESSION_VIDEO_NICE))
                    # handed to the writer's thread (RenderedFrame.native is the frame's own array):
                    # piping it to ffmpeg overlaps the next render
                    writer.write(res.native, t=t_shown)
                if panel is not None and res.native is not None:
                    panel.show(res.native)
                if preview is not None and res.preview is not None:
                    now = self.clock()
                    fps = 1.0 / max(now - last_render, 1e-6)
                    last_render = now
                    last_preview = (res.preview, fps, pain, ang, dist, tracked)
                    preview.show(self._overlay(*last_preview))
                if on_frame is not None:
                    on_frame(res)
                frames_shown += 1
                # with the render call's arguments: replay --quality live repeats the call exactly
                self.recorder.add_display(t_shown, frame, self.render_ms[-1], render_angle_deg=ang,
                                          render_distance_m=dist, render_tracked=tracked, render_others=others)
                if cfg.frames is not None and frames_shown >= cfg.frames:
                    break
        except KeyboardInterrupt:
            self.status["end"] = "interrupted (Ctrl-C)"
        finally:
            if old_sigint is not None:
                signal.signal(signal.SIGINT, old_sigint)
            self._stop.set()
            if frames is not None:
                frames.close()  # the render threads finish the frame they render; it is not shown
                if frames.twin_error is not None:  # the session ran on the renderers it had: say why
                    self.status["render"] = (f"one frame at a time: the second renderer failed "
                                             f"({type(frames.twin_error).__name__}: {frames.twin_error})")
            for th in threads:
                th.join(timeout=5.0)
            if self._face_tracker is not None:
                self._face_tracker.close()  # its dlib child process
            self.audio.stop()
            if self.video is not None:
                self.video.stop()
            end_s = round(max(self.now(), t_shown + 0.001), 3)  # the native video lasts as long as the session
            self.recorder.header["end_s"] = end_s  # session time at the end (replay's video lasts as long)
            for key, video in (("native_video_frames", writer), ("webcam_video_frames", self._webcam_writer)):
                if video is not None:
                    try:  # ffmpeg's exit status and the decoded frame count checked before the rename
                        video.close(end_s=end_s) if video.timed else video.close()
                        self.status[key] = video.frames
                    except ExportError as exc:
                        self.errors.append(exc)
            self.recorder.summary = self.summary()
            self.recorder.close()
        if self.errors:
            raise self.errors[0]
        return self.summary()

    def _warm_fit(self) -> None:
        """Load the tracker's compiled fit (:func:`holo_viewer.tracking.fit_fast.compile_kernel`); if that fails the
        session fits with the numpy reference."""
        from ..tracking.fit_fast import compile_kernel

        tracker = self._face_tracker
        try:
            compile_kernel(tracker.head)
        except Exception as exc:  # noqa: BLE001 - the numpy fit gives the same numbers
            tracker.config = dataclasses.replace(tracker.config, fast_fit=False)
            self.status["tracker"] = f"numpy fit ({type(exc).__name__}: {exc})"

    def _key(self, keysym: str) -> None:
        """Apply an instructor's or trainee's key and record it (session time, key, action; ratings)."""
        action = self.controls.key(keysym)
        if action is None:
            return
        t = round(self.now(), 3)
        self.recorder.keys.append({"t": t, "key": keysym, "action": action})
        if action == "rate":
            self.recorder.ratings.append({"t": t, "trainee": self.controls.trainee,
                                          "rating": self.controls.last_rating, "source": "key"})

    def _record_webcam(self, frame: np.ndarray) -> None:
        """Append a webcam frame to webcam.mkv (streamed to disk: memory stays flat)."""
        from ..media import VideoWriter

        if self._webcam_writer is None:
            self._webcam_writer = VideoWriter(Path(self.config.out) / "webcam.mkv", FPS, content="preview",
                                              what="webcam video")
        self._webcam_writer.write(frame)

    def _overlay(self, view: np.ndarray, fps: float, pain: float, ang: float, dist: float, tracked: bool) -> np.ndarray:
        """The preview view with fps, per-stage latency, pain and device status drawn on it."""
        from PIL import Image, ImageDraw

        img = Image.fromarray((np.clip(view, 0, 1) * 255).astype(np.uint8) if view.dtype != np.uint8 else view)
        d = ImageDraw.Draw(img)
        s = self.summary()

        def med(key):
            v = s.get(key)
            return "-" if not v else f"{v['median']:.0f}"

        lines = [f"{fps:4.1f} fps  render {med('render_ms')} ms  track {med('tracker_ms')} ms  react {med('reaction_window_ms')} ms",
                 f"pain {pain:.1f}  viewer {ang:+.0f} deg {dist:.2f} m {'tracked' if tracked else 'default'}"]
        lines += [f"{k}: {v}" for k, v in self.status.items() if v and v != "ok"]
        if self.controls.muted:
            lines.append("MUTED")
        lines.append(f"trainee {self.controls.trainee}" + ("" if self.controls.last_rating is None else
                                                            f" rated {self.controls.last_rating}"))
        if self.controls.show_help:  # the key map in place of the status lines, so a small preview still shows it
            from .controls import KEY_HELP

            lines = lines[:1] + ["keys:"] + [f"  {k}: {what}" for k, what in KEY_HELP]
        for i, line in enumerate(lines):
            d.text((4, 4 + 12 * i), line, fill=(255, 255, 0))
        if self.controls.paused:
            _centred_text(d, img.size, "PAUSED", (255, 64, 64))
        return np.asarray(img)


def _centred_text(draw: Any, size: tuple[int, int], text: str, fill: tuple[int, int, int]) -> None:
    """``text`` large in the middle of an image of ``size`` (w, h) on a dark box (PAUSED, starting...)."""
    from PIL import ImageFont

    w, h = size
    try:
        font = ImageFont.load_default(size=max(12, w // 10))
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    x0, y0, x1, y1 = draw.textbbox((0, 0), text, font=font)
    x, y = (w - (x1 - x0)) // 2, (h - (y1 - y0)) // 2
    draw.rectangle((x - 6, y - 6 + y0, x + x1 - x0 + 6, y + y1 + 6), fill=(0, 0, 0))
    draw.text((x - x0, y), text, font=font, fill=fill)


def starting_image(width: int, height: int, step: str) -> np.ndarray:
    """(height, width, 3) uint8: "starting..." and the current start-up ``step`` on dark grey (the
    preview before the first frame, instead of black)."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (width, height), (40, 40, 48))
    d = ImageDraw.Draw(img)
    _centred_text(d, img.size, "starting...", (255, 255, 0))
    d.text((8, height - 24), step, fill=(220, 220, 220))
    return np.asarray(img)
