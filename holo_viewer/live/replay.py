"""Re-render a recorded session (the same renderer, the recorded inputs: deterministic).

Two qualities:

``live``
    The live renderer as the session used it (mode, tile scale, the fast CPU backend, the
    visible-Gaussian mask when session.json ``render.visible`` says the frames skipped the Gaussians
    nobody sees: loaded from the cache or built again, deterministic, and refused when its digest is
    not the recorded one; the per-view (V, N) mask when it says ``per_view``, else the (N,) union every
    view drew before 2026-11-28 19:30; sessions without the field draw every Gaussian, as they did), called
    exactly as the live loop called it (its warm-up, then each displayed frame with the recorded
    listener parameters, pain, named expressions and viewer pose): the frames of ``native.mkv``
    again, bit-exact on the same build, from any working folder; written at the times they were
    shown (a timed, lossless video). A session rendered on gsplat is re-rendered on the CPU.
``full``
    Every 25 fps frame with every view of the default cone rendered (``all_views``, no warps;
    ``cone`` sessions: the viewer's cone): the exact quilt the live frames approximate.

Everything comes from the session folder (session.json states the scenario itself, not a path);
a session whose avatar digest differs from this build's avatar is refused.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from .session import LISTENER_KEYS, load_session

__all__ = ["replay_frames", "replay_timed_frames", "replay_session", "QUALITIES"]

QUALITIES = ("full", "live")


def _scenario(session: Path, meta: dict):
    """The session's scenario (None without one); a version-1 session names a file, which must exist."""
    from ..errors import InputError
    from .controls import Scenario

    if meta.get("scenario") is not None:
        return Scenario.from_json(meta["scenario"], f"{session / 'session.json'}: scenario")
    path = meta.get("settings", {}).get("scenario")
    if path and "version" not in meta:
        if not Path(path).is_file():
            raise InputError(f"{session / 'session.json'}: settings.scenario: expected the scenario file {path!r} "
                             f"(sessions before version 2 name it by path), found none: replay would drop its "
                             f"named expressions; run it from the folder the session was recorded in")
        return Scenario.load(path)
    return None


def _visible(session: Path, render: dict) -> dict | None:
    """session.json ``render.visible`` (None in sessions recorded before it: every Gaussian drawn), checked."""
    from ..errors import InputError

    visible = render.get("visible")
    if visible is None:
        return None
    where = f"{session / 'session.json'}: render.visible"
    if not isinstance(visible, dict) or not isinstance(visible.get("used"), bool):
        raise InputError(f"{where}: expected an object with a boolean 'used', found {visible!r:.80}")
    if visible["used"] and not (isinstance(visible.get("digest"), str) and len(visible["digest"]) == 32):
        raise InputError(f"{where}.digest: expected the mask's digest (32 hex digits), found {visible.get('digest')!r:.80}")
    if not isinstance(visible.get("per_view", False), bool):  # absent: the (N,) mask of sessions before it
        raise InputError(f"{where}.per_view: expected true or false, found {visible.get('per_view')!r:.80}")
    return visible


def _renderer(session: Path, meta: dict, quality: str, tile_scale: float | None, render_threads: int | None = None):
    """The renderer for ``quality``, after checking the session's avatar is this build's."""
    from ..errors import InputError
    from .render import LiveAvatarRenderer
    from .session import avatar_record

    if quality not in QUALITIES:
        raise InputError(f"quality: expected one of {', '.join(QUALITIES)}, found {quality!r}")
    settings = meta.get("settings", {})
    render = meta.get("render") or {}
    scale = float(tile_scale if tile_scale is not None else render.get("tile_scale", settings.get("tile_scale", 1.0)))
    mode = str(render.get("mode", settings.get("render_mode", "cone")))
    recorded = meta.get("avatar")
    avatar = str(recorded.get("name", "default")) if isinstance(recorded, dict) else "default"  # a patient's name
    if quality == "live":
        visible = _visible(session, render)
        renderer = LiveAvatarRenderer(tile_scale=scale, native=True, preview=False, backend="fast", mode=mode,
                                      avatar=avatar, render_threads=render_threads,
                                      visible_only="build" if visible and visible["used"] else False,
                                      visible_per_view=bool(visible and visible.get("per_view", False)))
        if visible and visible["used"] and scale == float(render.get("tile_scale", scale)):
            mine = renderer.visible_record()
            if mine["digest"] != visible["digest"]:
                what = "per-view visible-Gaussian mask" if visible.get("per_view") else "visible-Gaussian mask"
                raise InputError(f"{session / 'session.json'}: render.visible.digest: the session's frames drew the "
                                 f"{what} {visible['digest']} ({visible.get('kept')} of "
                                 f"{visible.get('gaussians')} Gaussians), this build's mask is {mine['digest']} "
                                 f"({mine['kept']} of {mine['gaussians']}): replay would not show what the trainees "
                                 f"saw; use --quality full (every Gaussian)")
    else:
        renderer = LiveAvatarRenderer(tile_scale=scale, native=True, preview=False, backend="fast",  # exact, any machine
                                      mode="all_views" if mode in ("tracked", "auto") else mode,
                                      view_step=1, avatar=avatar)  # offline: every view rendered, no synthesis
    if recorded is not None:
        mine = avatar_record(renderer.pipeline, str(recorded.get("name", "default")))
        if mine["digest"] != recorded.get("digest"):
            raise InputError(f"{session / 'session.json'}: avatar: the session was recorded with avatar "
                             f"{recorded.get('name')!r} digest {recorded.get('digest')} ({recorded.get('gaussians')} "
                             f"Gaussians), this build's {mine['name']!r} has digest {mine['digest']} "
                             f"({mine['gaussians']} Gaussians): replay would not show what the trainees saw")
    return renderer


def _frame_inputs(tr: dict, t: int, scenario) -> tuple[dict, float, tuple]:
    """(listener FLAME arrays, pain to add, named expressions) of 25 fps frame ``t``, as the live loop had them."""
    lf = {k: tr[f"listener_{k}"][t] for k in LISTENER_KEYS}
    # the scenario time the live loop had (the step keys move it; sessions before them: the session time)
    ts = float(tr["scenario_time_s"][t]) if "scenario_time_s" in tr else t / 25
    named = scenario.named_at(ts) if scenario is not None else ()
    # pain_shown >= 0: the behaviour layers drew the pain into listener_expr, add none on top
    pain = 0.0 if "pain_shown" in tr and tr["pain_shown"][t] >= 0 else float(tr["pain"][t])
    return lf, pain, named


def replay_frames(session: str | os.PathLike, tile_scale: float | None = None, every: int = 1) -> Iterator[np.ndarray]:
    """Native images (H, W, 3) uint8 of every ``every``-th recorded 25 fps frame, in full quality."""
    meta, tr = load_session(session)
    scenario = _scenario(Path(session), meta)
    renderer = _renderer(Path(session), meta, "full", tile_scale)
    for t in range(0, len(tr["time_s"]), int(every)):
        lf, pain, named = _frame_inputs(tr, t, scenario)
        yield renderer.render(lf, pain, named, float(tr["viewer_angle_deg"][t]),
                              float(tr["viewer_distance_m"][t])).native


def replay_timed_frames(session: str | os.PathLike, tile_scale: float | None = None,
                        render_threads: int | None = None) -> Iterator[tuple[float, np.ndarray]]:
    """(display time s, native image) of every displayed frame, rendered as the live loop rendered it
    (``render_threads``: the renderer's threads, default all cores; another count, like another
    machine, may round differently: tests/test_sessions.py measures it)."""
    from ..errors import InputError

    meta, tr = load_session(session)
    if "render_angle_deg" not in tr:
        raise InputError(f"{Path(session) / 'tracks.npz'}: render_angle_deg: expected the render calls' viewer poses "
                         f"(sessions of version 2), found none; use --quality full")
    scenario = _scenario(Path(session), meta)
    renderer = _renderer(Path(session), meta, "live", tile_scale, render_threads)
    renderer.render({"expr": np.zeros(1)}, float((meta.get("render") or {}).get("warmup_pain", 0.0)), (), 0.0, 0.6)
    for i, t in enumerate(tr["display_frame"]):
        lf, pain, named = _frame_inputs(tr, int(t), scenario)
        # the other faces a group frame served (as the live loop passed them: only when there were any)
        others = tuple((float(a), float(d)) for a, d in tr["render_others"][i] if np.isfinite(a)) \
            if "render_others" in tr else ()
        yield float(tr["display_time_s"][i]), renderer.render(
            lf, pain, named, float(tr["render_angle_deg"][i]), float(tr["render_distance_m"][i]),
            bool(tr["render_tracked"][i]), **({"others": others} if others else {})).native


def replay_session(session: str | os.PathLike, out: str | os.PathLike, tile_scale: float | None = None,
                   every: int = 1, quality: str = "full") -> int:
    """Write the re-rendered session to ``out`` (lossless RGB; ``full``: 25 / every fps, ``live``: each
    displayed frame at the time it was shown); returns the frame count."""
    from tqdm import tqdm

    from ..media import ThreadedWriter, VideoWriter

    # verified before the rename (ffmpeg's exit status, frame count): a full disk is an error
    if quality == "live":
        meta, tr = load_session(session)
        last = float(tr["display_time_s"][-1]) + 0.001 if len(tr["display_time_s"]) else 0.0
        end_s = max(float(meta.get("end_s", 0.0)), len(tr["time_s"]) / 25, last)  # as long as the session
        from .loop import SESSION_VIDEO_NICE, SESSION_VIDEO_PARAMS

        # the session video's encoder settings: one x264 thread (36 instead of 57 ms of CPU a native
        # frame), nicer than the render, which on 2 cores is every frame's critical path
        writer = ThreadedWriter(VideoWriter(Path(out), 25.0, timed=True, what="replay video",
                                            output_params=SESSION_VIDEO_PARAMS, nice=SESSION_VIDEO_NICE))
        try:
            for t, img in tqdm(replay_timed_frames(session, tile_scale), desc="replay", unit="frame",
                               total=len(tr["display_frame"])):
                writer.write(img, t=t)  # the frame's own array (RenderedFrame.native), piped while the next renders
        except BaseException:
            writer.abort()
            raise
        return writer.close(end_s=end_s)
    with VideoWriter(Path(out), 25.0 / every, what="replay video") as writer:
        for img in tqdm(replay_frames(session, tile_scale, every), desc="replay", unit="frame"):
            writer.write(img)
    return writer.frames

