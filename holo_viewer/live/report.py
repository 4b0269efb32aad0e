"""The debrief of a recorded session: one picture and a short text an instructor reads afterwards.

:func:`session_report` reads a session folder (:mod:`holo_viewer.live.session`) and returns a
:class:`SessionReport`: per 25 fps frame the speech activity (RMS of ``audio.wav``), the pain
requested (the instructor's pain timeline, :mod:`holo_viewer.behaviour.timeline`) and shown, nods
(head pitch), blinks (the eyelid channel AU43), gaze (eye yaw), the viewer's angle and distance;
per displayed frame its time and render time; the key presses; and the trainees' ratings against
the pain shown when they rated (each trainee's mean absolute error and bias, on the 0-10 scale).
:func:`plot_report` draws it (one PNG), :meth:`SessionReport.text` is the summary, and
:func:`review_video` writes the native video with the audio muxed in.
"""

from __future__ import annotations

import os
import wave
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .session import NATIVE_VIDEO, load_session

__all__ = ["SessionReport", "TraineeScore", "session_report", "plot_report", "review_video", "BLINK_COLUMNS"]

FPS = 25
#: the default head's eyelid (AU43) expression columns, left and right (holo_viewer.behaviour.compose)
BLINK_COLUMNS = (22, 23)
#: speech is active in a 40 ms frame whose RMS is above this (int16 full scale 1)
SPEECH_RMS = 0.02


@dataclass(frozen=True)
class TraineeScore:
    """One trainee's ratings against the pain shown (0-10 scale): ``error`` mean |rating - shown|,
    ``bias`` mean (rating - shown), positive: rated more pain than shown."""

    trainee: str
    n: int
    error: float
    bias: float


@dataclass
class SessionReport:
    """What :func:`session_report` read and computed (arrays per 25 fps frame unless said)."""

    folder: Path
    time_s: np.ndarray
    speech_rms: np.ndarray
    pain_requested: np.ndarray
    pain_shown: np.ndarray
    nod_deg: np.ndarray
    blink: np.ndarray
    gaze_deg: np.ndarray
    viewer_angle_deg: np.ndarray
    viewer_distance_m: np.ndarray
    display_time_s: np.ndarray  # per displayed frame
    render_ms: np.ndarray  # per displayed frame
    keys: list[dict] = field(default_factory=list)
    ratings: list[dict] = field(default_factory=list)  # each with "shown" (0-10) added
    scores: list[TraineeScore] = field(default_factory=list)
    end_s: float = 0.0

    def text(self) -> str:
        """The short summary (what the picture shows, in numbers)."""
        n, d = len(self.time_s), len(self.display_time_s)
        fps = d / self.end_s if self.end_s > 0 else 0.0
        med = float(np.median(self.render_ms)) if d else float("nan")
        blinks = int(np.sum(np.diff((self.blink > 0.5).astype(int)) == 1)) if n > 1 else 0
        lines = [f"session {self.folder}: {self.end_s:.1f} s, {n} frames at 25 fps, {d} displayed "
                 f"({fps:.1f} frames/s), render median {med:.0f} ms",
                 f"speech {100 * float(np.mean(self.speech_rms > SPEECH_RMS)) if n else 0:.0f} % of the time; "
                 f"pain requested {_span(self.pain_requested)}, shown {_span(self.pain_shown)}; {blinks} blinks",
                 f"viewer angle {_span(self.viewer_angle_deg, '{:+.0f}')} deg, distance "
                 f"{_span(self.viewer_distance_m, '{:.2f}')} m; {len(self.keys)} key presses"]
        lines.append("trainee ratings against the pain shown (0-10; bias > 0: rated more pain than shown):"
                     if self.scores else "no trainee ratings")
        for s in self.scores:
            lines.append(f"  trainee {s.trainee}: {s.n} ratings, mean error {s.error:.1f}, bias {s.bias:+.1f}")
        return "\n".join(lines)


def _span(a: np.ndarray, fmt: str = "{:.2f}") -> str:
    return "-" if not len(a) else f"{fmt.format(float(np.min(a)))}..{fmt.format(float(np.max(a)))}"


def _speech_rms(folder: Path, n: int) -> np.ndarray:
    """(n,) RMS of audio.wav in each 40 ms frame (0 where the audio ends)."""
    rms = np.zeros(n)
    path = folder / "audio.wav"
    if not path.is_file():
        return rms
    with wave.open(os.fspath(path), "rb") as w:
        rate = w.getframerate()
        audio = np.frombuffer(w.readframes(w.getnframes()), np.int16).astype(np.float64) / 32768.0
    hop = rate // FPS
    m = min(n, len(audio) // hop)
    if m:
        rms[:m] = np.sqrt(np.mean(audio[: m * hop].reshape(m, hop) ** 2, axis=1))
    return rms


def session_report(folder: str | os.PathLike) -> SessionReport:
    """Read a session folder and compute the report (InputError naming the file for a bad folder)."""
    from ..behaviour import PainTimeline

    p = Path(folder)
    meta, tr = load_session(p)
    n = len(tr["time_s"])
    t = np.arange(n) / FPS
    timeline = (meta.get("summary") or {}).get("pain_timeline")
    requested = (PainTimeline.from_json(timeline, source=f"{p / 'session.json'}: summary.pain_timeline").levels(n)
                 if timeline else np.asarray(tr["pain"], np.float64))
    shown = np.asarray(tr["pain_shown"], np.float64)
    shown = np.where(shown >= 0, shown, np.asarray(tr["pain"], np.float64))  # -1: no layers, the level is drawn
    expr = np.asarray(tr["listener_expr"], np.float64)
    blink = expr[:, list(BLINK_COLUMNS)].mean(axis=1) if expr.ndim == 2 and expr.shape[1] > max(BLINK_COLUMNS) \
        else np.zeros(n)
    nod = np.degrees(np.asarray(tr["listener_rotation"], np.float64)[:, 0]
                     + np.asarray(tr["listener_neck_pose"], np.float64)[:, 0])
    gaze = np.degrees(np.asarray(tr["listener_eyes_pose"], np.float64)[:, 1])
    ratings, per = [], {}
    for r in meta.get("ratings") or []:
        k = min(n - 1, max(0, int(round(float(r["t"]) * FPS)))) if n else 0
        r = {**r, "shown": round(10 * float(shown[k]), 2) if n else float("nan")}
        ratings.append(r)
        per.setdefault(str(r["trainee"]), []).append(float(r["rating"]) - r["shown"])
    scores = [TraineeScore(k, len(v), float(np.mean(np.abs(v))), float(np.mean(v))) for k, v in sorted(per.items())]
    disp = np.asarray(tr.get("display_time_s", np.zeros(0)), np.float64)
    end_s = float(meta.get("end_s") or max(n / FPS, disp[-1] if len(disp) else 0.0))
    return SessionReport(p, t, _speech_rms(p, n), requested, shown, nod, blink, gaze,
                         np.asarray(tr["viewer_angle_deg"], np.float64), np.asarray(tr["viewer_distance_m"], np.float64),
                         disp, np.asarray(tr.get("render_ms", np.zeros(0)), np.float64), list(meta.get("keys") or []),
                         ratings, scores, end_s)


def plot_report(report: SessionReport, out: str | os.PathLike) -> Path:
    """Draw the report: six time rows sharing the session time axis (key presses as lines across
    them) and the ratings against the pain shown; written atomically as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..fileio import atomic_path

    r = report
    fig = plt.figure(figsize=(13, 12), dpi=100)
    grid = fig.add_gridspec(6, 3, width_ratios=(3, 3, 2), hspace=0.55, wspace=0.3, left=0.07, right=0.97,
                            top=0.96, bottom=0.05)
    rows = [fig.add_subplot(grid[i, :2]) for i in range(6)]
    for ax in rows[1:]:
        ax.sharex(rows[0])
    ax = rows[0]
    ax.fill_between(r.time_s, 0, r.speech_rms, color="tab:blue", step="mid")
    ax.axhline(SPEECH_RMS, color="grey", lw=0.6, ls=":")
    ax.set_ylabel("speech RMS")
    ax.set_title("the trainee's speech")
    ax = rows[1]
    ax.plot(r.time_s, r.pain_requested, color="black", lw=1.2, drawstyle="steps-post", label="requested")
    ax.plot(r.time_s, r.pain_shown, color="tab:red", lw=1.0, label="shown")
    for i, tr in enumerate(sorted({str(x["trainee"]) for x in r.ratings})):
        pts = [(x["t"], x["rating"] / 10) for x in r.ratings if str(x["trainee"]) == tr]
        ax.scatter(*zip(*pts), s=30, marker="o", color=f"C{i + 2}", zorder=3, label=f"trainee {tr} / 10")
    ax.set_ylim(-0.05, 1.4)  # the legend's band above 1: it covered ratings near 1 (a 9 at 0.9)
    ax.set_yticks([0.0, 0.5, 1.0])
    ax.set_ylabel("pain")
    ax.legend(loc="upper left", fontsize=7, ncol=4)
    ax.set_title("pain requested, shown, and the trainees' ratings")
    ax = rows[2]
    ax.plot(r.time_s, r.nod_deg, color="tab:green", lw=1.0, label="head pitch (nods)")
    ax.plot(r.time_s, r.gaze_deg, color="tab:purple", lw=1.0, label="eye yaw (gaze)")
    ax.set_ylabel("deg")
    ax2 = ax.twinx()
    ax2.fill_between(r.time_s, 0, r.blink, color="tab:orange", alpha=0.4, step="mid")
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("eyelids (AU43)")
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + 0.45 * (hi - lo))  # room for the legend above the curves
    ax.legend(loc="upper left", fontsize=7, ncol=2)
    ax.set_title("the patient: nods, gaze, eyelids (orange: blinks, and a little in the pain face)")
    ax = rows[3]
    ax.plot(r.time_s, r.viewer_angle_deg, color="tab:cyan", lw=1.0)
    ax.set_ylabel("angle (deg)")
    ax2 = ax.twinx()
    ax2.plot(r.time_s, r.viewer_distance_m, color="tab:brown", lw=1.0)
    ax2.set_ylabel("distance (m)")
    ax.set_title("the viewer: angle (cyan) and distance (brown)")
    ax = rows[4]
    if len(r.display_time_s):
        ax.scatter(r.display_time_s, r.render_ms, s=6, color="tab:gray")
        per_s = np.histogram(r.display_time_s, bins=np.arange(0, r.end_s + 1.0, 1.0))[0]
        ax2 = ax.twinx()
        ax2.step(np.arange(len(per_s)) + 0.5, per_s, where="mid", color="tab:blue", lw=1.0)
        ax2.set_ylabel("frames / s")
    ax.set_ylabel("render ms")
    ax.set_title(f"{len(r.display_time_s)} frames displayed (blue: per second) and their render time (grey)")
    ax = rows[5]
    for i, k in enumerate(r.keys):
        ax.text(float(k["t"]), i % 3, str(k["key"]), fontsize=7, ha="center", va="center")
    ax.set_ylim(-0.8, 2.8)
    ax.set_yticks([])
    ax.set_title("key presses")
    ax.set_xlabel("session time (s)")
    ax.set_xlim(0, max(r.end_s, 1.0 / FPS))
    for ax in rows:
        for k in r.keys:
            ax.axvline(float(k["t"]), color="grey", lw=0.4, alpha=0.6)
    ax = fig.add_subplot(grid[0:3, 2])
    for i, tr in enumerate(sorted({str(x["trainee"]) for x in r.ratings})):
        pts = [(x["shown"], x["rating"]) for x in r.ratings if str(x["trainee"]) == tr]
        ax.scatter(*zip(*pts), s=30, color=f"C{i + 2}", label=f"trainee {tr}")
    ax.plot([0, 10], [0, 10], color="grey", lw=0.8, ls="--")
    ax.set_xlim(-0.5, 10.5)
    ax.set_ylim(-0.5, 10.5)
    ax.set_xlabel("pain shown (0-10)")
    ax.set_ylabel("rating (0-10)")
    ax.set_title("ratings against the pain shown")
    if r.ratings:
        ax.legend(fontsize=7)
    ax = fig.add_subplot(grid[3:, 2])
    ax.axis("off")
    ax.text(0, 1, _wrap(r.text()), va="top", ha="left", fontsize=8, family="monospace", transform=ax.transAxes)
    out = Path(out)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return out


def _wrap(text: str, width: int = 38) -> str:
    import textwrap

    return "\n".join(textwrap.fill(line, width) for line in text.splitlines())


def review_video(folder: str | os.PathLike, out: str | os.PathLike) -> Path:
    """The session's native video at 25 fps (each frame held as shown) with ``audio.wav`` muxed in
    (lossless RGB video, AAC audio), verified and atomic (:func:`holo_viewer.media.mux_audio`)."""
    from ..media import mux_audio

    p = Path(folder)
    end_s = load_session(p)[0].get("end_s")  # the review video lasts as long as the session
    return mux_audio(p / NATIVE_VIDEO, p / "audio.wav", out, fps=FPS,
                     duration_s=float(end_s) if end_s else None)
