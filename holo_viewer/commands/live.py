"""``holo-viewer live``: the trainee talks, the hologram reacts and follows their viewpoint."""

from __future__ import annotations

import argparse
import math

from ..validation import fps_arg, seed_arg

__all__ = ["add_arguments", "run"]


def _in_flight_arg(text: str) -> int:
    """--frames-in-flight: an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, found {text!r}")
    return n


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``live``."""
    src = parser.add_argument_group("sources (default: microphone + webcam)")
    src.add_argument("--audio", metavar="F.wav", help="replay this 16 kHz WAV in real time instead of the microphone")
    src.add_argument("--video", metavar="F.mp4", help="replay this video in real time instead of the webcam "
                     "(speaker face and viewer tracking)")
    src.add_argument("--synthetic", action="store_true", help="a synthetic speaker and viewer (no devices, no files)")
    src.add_argument("--seconds", type=float, default=None, help="stop after this many seconds (default: when the "
                     "replayed files end; --synthetic: 20 s)")
    src.add_argument("--camera", type=int, default=0, help="webcam index (default 0)")
    src.add_argument("--mount", metavar="MOUNT.json", help="webcam-to-panel offset JSON (docs/live.md)")
    src.add_argument("--hfov", type=float, default=60.0, help="webcam horizontal field of view in degrees (default 60)")
    src.add_argument("--track-fps", type=float, default=None, metavar="FPS",
                     help="track at most FPS webcam frames a second (default: every frame; docs/live.md)")
    out = parser.add_argument_group("output")
    out.add_argument("--out", default=None, metavar="DIR", help="session folder, must not exist yet (default "
                     "./session-YYYYmmdd-HHMMSS; an existing session is never overwritten)")
    out.add_argument("--headless", action="store_true", help="no windows (CI); the session folder and native.mkv "
                     "are still written")
    out.add_argument("--frames", type=int, default=None, help="stop after N displayed frames")
    out.add_argument("--panel", action="store_true", help="fullscreen native image on the Looking Glass monitor")
    out.add_argument("--monitor", type=int, default=None, help="monitor index for --panel")
    out.add_argument("--no-preview", action="store_true", help="no desktop preview window")
    out.add_argument("--tile-scale", type=float, default=1.0, help="quilt tile size relative to the calibration's "
                     "(e.g. 0.5 renders 4x fewer pixels; default 1)")
    from ..live.render import BACKENDS
    from .renderer_args import add_renderer_argument

    add_renderer_argument(out, choices=BACKENDS, default="auto", old_spelling="--backend",
                          help="renderer of the live frames: gsplat (CUDA: all 48 views on the GPU every frame, "
                               "whatever the mode but cone), fast (CPU), or auto (gsplat where a CUDA GPU and the "
                               "gsplat package are present, else fast)")
    out.add_argument("--render-mode", choices=("auto", "cone", "tracked", "all_views"), default="auto",
                     help="auto (default): group frames, every view of the default cone each frame (every 6th "
                     "rendered, the others warped by depth), so every viewer sees the present face; tracked: the "
                     "panel's default cone, only the subpixels the tracked eyes receive redrawn, from one image per "
                     "eye (fastest; everyone else sees older frames); all_views: default cone, every 5th view rendered "
                     "and the others warped by depth; cone: the 48 cameras follow the tracked viewer (Algorithm 1's "
                     "viewer angle and distance), the whole quilt each frame (slowest)")
    out.add_argument("--frames-in-flight", type=_in_flight_arg, default=1, metavar="N",
                     help="render up to N frames at once, each on a renderer of its own (default 1: one frame at a "
                     "time, which keeps 2 cores busy with group frames; 2 may help where one frame leaves cores "
                     "idle, each frame shown a little later). Only modes whose frames do not depend on earlier ones "
                     "(auto, all_views on the CPU)")
    out.add_argument("--video-fps", type=fps_arg, default=10.0, help="nominal frame rate of native.mkv (each displayed "
                     "frame is stored once with the time it was shown; default 10)")
    out.add_argument("--record-video", action="store_true", help="also keep the webcam video (off by default: "
                     "trainees' faces are private)")
    out.add_argument("--native-codec", choices=("ffvhuff", "x264"), default="ffvhuff",
                     help="native.mkv's lossless codec: ffvhuff (default: the least CPU, ~2.4x x264's disk; "
                     "`holo-viewer compact` re-encodes it to x264 after the session) or x264 (the smallest file)")
    ctl = parser.add_argument_group("patient")
    from .avatar_args import add_avatar_argument

    add_avatar_argument(ctl, kinds=("default", "patient", "npz"), fitted=True,
                        help="who the patient is (session.json records it)")
    ctl.add_argument("--pain", type=float, default=0.0, help="initial pain level in [0, 1] (keys Up/Down change it)")
    ctl.add_argument("--scenario", metavar="FILE.json", help="timeline of pain levels and named expressions")
    ctl.add_argument("--group", action="store_true", help="follow the centre of all tracked faces instead of the "
                     "nearest: the patient looks there, and the cone mode and the preview aim there (group frames "
                     "serve every position either way)")
    ctl.add_argument("--no-viewer-prediction", action="store_true", help="render for the smoothed viewer pose as "
                     "tracked, not extrapolated to when the frame is shown")
    from ..reaction.decoding import DEFAULT_TEMPERATURE

    ctl.add_argument("--temperature", type=float, default=DEFAULT_TEMPERATURE,
                     help=f"reaction sampling temperature (0 = argmax; default {DEFAULT_TEMPERATURE})")
    ctl.add_argument("--seed", type=seed_arg, default=0)
    from .behaviour_args import add_behaviour_arguments

    add_behaviour_arguments(parser, pain_timeline=False)  # timelines: --scenario's pain_timeline


def check_session_out(out: str | None) -> str:
    """The session folder to write: ``out``, or a new timestamped folder when None.

    Raises
    ------
    InputError
        ``out`` exists and is not an empty directory: a live session never overwrites one.
    """
    import time
    from pathlib import Path

    from ..errors import InputError

    if out is None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        out = f"session-{stamp}"
        n = 2
        while Path(out).exists():
            out, n = f"session-{stamp}-{n}", n + 1
    p = Path(out)
    if p.exists() and (not p.is_dir() or any(p.iterdir())):
        what = "a session folder" if (p / "session.json").exists() else ("a file" if not p.is_dir() else
                                                                         "a folder that is not empty")
        raise InputError(f"--out {p}: {what} already exists there and would be overwritten; choose another with "
                         f"--out DIR, or leave --out out for a new timestamped folder")
    return str(p)


def _say_disk(out: str, codec: str) -> None:
    """Print the session video's disk rate and the minutes the output's file system holds at it (a
    warning on stderr under 30 minutes: a full disk stops the recording, not the session)."""
    import shutil
    import sys
    from pathlib import Path

    from ..live.loop import recording_minutes

    folder = Path(out).resolve()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    gb_per_min, minutes = recording_minutes(shutil.disk_usage(folder).free, codec)
    msg = (f"live: the session video ({codec}) takes ~{gb_per_min:.1f} GB a minute at 12 displayed fps; "
           f"{folder} has room for ~{minutes:.0f} minutes")
    print(msg, flush=True)
    if minutes < 30:
        print(f"live: warning: under 30 minutes of recording fit on {folder}; free space, or "
              f"--native-codec x264 (~{recording_minutes(1, 'x264')[0]:.1f} GB a minute)", file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the session; returns 0, 130 after Ctrl-C (the session folder is complete up to then), or 1
    (through HoloViewerError) for a missing device or bad input."""
    from ..errors import InputError
    from ..live.controls import Scenario
    from ..tracking.viewer import WebcamMount

    if args.synthetic and (args.audio or args.video):
        raise InputError("--synthetic replaces --audio/--video; give one or the other")
    args.out = check_session_out(args.out)
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames: expected >= 1, found {args.frames}")
    if not 0.0 <= args.pain <= 1.0:
        raise InputError(f"--pain: expected a value in [0, 1], found {args.pain}")
    if args.track_fps is not None and not (math.isfinite(args.track_fps) and args.track_fps > 0):
        raise InputError(f"--track-fps: expected frames a second > 0, found {args.track_fps}")
    mount = WebcamMount.load(args.mount) if args.mount else WebcamMount(hfov_deg=args.hfov)
    scenario = Scenario.load(args.scenario) if args.scenario else None
    # first use (empty kernel cache): the view-synthesis kernels compile in a second process meanwhile
    precompile = None
    if args.render_mode != "cone" and args.renderer != "gsplat":
        from ..live.precompile import BackgroundCompile

        precompile = BackgroundCompile()
    try:
        return _run(args, mount, scenario, precompile)
    finally:
        if precompile is not None:
            precompile.close()


def _run(args: argparse.Namespace, mount: object, scenario: object, precompile: object) -> int:
    """:func:`run` after the arguments are checked (``precompile``: the background compile or None)."""
    from ..live.loop import LiveSessionConfig, LiveSession
    from ..live.render import LiveAvatarRenderer
    from ..live import sources
    from ..pipeline.live_support import SyntheticSpeaker
    from .behaviour_args import behaviour_from_args

    preview = None
    if not args.headless and not args.no_preview:  # at once, saying "starting..." (not black) until frame 1
        from ..live.windows import open_preview

        preview = open_preview()
    progress = _Progress(preview)
    synthetic = None
    video = None
    progress("opening devices")
    if args.synthetic:
        synthetic = SyntheticSpeaker(args.seconds or 20.0, seed=args.seed)
        audio = sources.ArrayAudio(synthetic.waveform, name="synthetic")
    else:
        # open every device before starting, so a missing one is reported at once
        audio = sources.WavReplay(args.audio) if args.audio else sources.Microphone()
        video = sources.VideoReplay(args.video) if args.video else sources.Webcam(args.camera)
    settings = {k: v for k, v in vars(args).items() if not k.startswith("_") and k != "command"}
    settings["sources"] = {"audio": audio.name, "video": None if video is None else video.name}
    config = LiveSessionConfig(out=args.out, frames=args.frames, tile_scale=args.tile_scale,
                               preview=not args.headless and not args.no_preview,
                               panel=args.panel and not args.headless, monitor=args.monitor,
                               video_fps=args.video_fps, record_video=args.record_video, pain=args.pain,
                               temperature=args.temperature, seed=args.seed, hfov_deg=mount.hfov_deg, mount=mount,
                               viewer_mode="group" if args.group else "nearest",
                               predict_viewer=not args.no_viewer_prediction, track_fps=args.track_fps,
                               frames_in_flight=args.frames_in_flight,
                               scenario=scenario,
                               max_seconds=args.seconds, settings=settings, native_codec=args.native_codec,
                               behaviour=behaviour_from_args(args, seed=args.seed))
    progress("loading the avatar and compiling the render kernels (cached after the first use"
             + ("; compiling the view-synthesis kernels in a second process" if getattr(precompile, "started", False)
                else "") + ")")
    # the reaction model loads on the other core meanwhile (the renderer's tables are mostly one thread)
    reaction = _ReactionPreload()
    renderer = LiveAvatarRenderer(tile_scale=args.tile_scale, native=True, preview=config.preview,
                                  mode=args.render_mode, backend=args.renderer, avatar=args.avatar, visible_only=True)
    settings["render_backend"] = renderer.backend  # what "auto" chose (session.json)
    reaction.join()  # loaded and cached: the session's "warming the reaction model" finds it
    session = LiveSession(config, audio, video, synthetic)
    session.progress = progress
    _say_disk(args.out, config.native_codec)
    panel = None
    if config.panel:
        from ..live.windows import open_panel

        progress("opening the panel window")
        panel = open_panel(renderer.pipeline.calibration, args.monitor)
    import time

    shown: list[float] = []  # when each frame was handed back: the first is the start-up's end

    def on_frame(_res: object) -> None:
        if not shown:
            progress("first frame shown")
        shown[-1:] = [time.perf_counter()]

    summary = session.run(renderer, panel=panel, preview=preview, on_frame=on_frame)
    if shown:  # quit: the last frame -> the session closed (threads joined, recording flushed, verified)
        print(f"live: closed {time.perf_counter() - shown[-1]:.1f} s after the last frame", flush=True)
    interrupted = str(summary["status"].get("end", "")).startswith("interrupted")
    print(f"session written to {args.out}: {session.recorder.n_frames} frames at 25 fps, "
          f"{summary['displayed_frames']} displayed; reaction windows {summary['reaction_windows']} "
          f"({summary['late_reaction_windows']} late); render {summary['render_ms']}")
    return 130 if interrupted else 0


class _ReactionPreload:
    """Load the shipped reaction model into its cache (``reaction.api.load_default_bundle``) in a
    thread while the renderer is built. An error is left for the session's own load to report."""

    def __init__(self) -> None:
        import threading

        self._thread = threading.Thread(target=self._load, name="reaction-preload", daemon=True)
        self._thread.start()

    @staticmethod
    def _load() -> None:
        try:
            from ..reaction.api import load_default_bundle

            load_default_bundle()
        except Exception:  # noqa: BLE001 - the session loads it again and reports the error
            pass

    def join(self) -> None:
        self._thread.join()


class _Progress:
    """Print each start-up step with the seconds since the command started (flushed at once) and
    show it on the preview window under "starting..."."""

    def __init__(self, preview: object | None) -> None:
        import time

        self._t0 = time.perf_counter()
        self._preview = preview

    def __call__(self, step: str) -> None:
        import time

        print(f"live: {step} ... ({time.perf_counter() - self._t0:.1f} s)", flush=True)
        if self._preview is not None:
            from ..live.loop import starting_image

            w, h = self._preview.window.width, self._preview.window.height
            self._preview.show(starting_image(w, h, step))
            self._preview.poll()  # let the window draw now
