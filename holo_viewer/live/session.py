"""The session folder of a live run: written as it goes, complete up to any interruption.

::

    SESSION/
      session.json   settings, sources, timings summary (rewritten at every flush and at the end)
      tracks.npz     per 25 fps frame: time_s, viewer_angle_deg, viewer_distance_m, pain (the instructor's
                     level), pain_shown (the pain in listener_expr from the behaviour layers; -1 without them),
                     speaker_found, speaker_{expr,jaw_pose,rotation}, listener_{expr,jaw_pose,rotation,
                     neck_pose,eyes_pose,translation} (GaussianAvatars flame_param keys), window;
                     per displayed frame: display_time_s, display_frame, render_ms and the render call's
                     render_angle_deg, render_distance_m, render_tracked, render_others ((MAX_OTHERS, 2) the
                     other faces' angle and distance, NaN-padded) (replay --quality live)
      audio.wav      the input audio (16 kHz mono; appended at each flush, valid up to the last one)
      native.mkv     the native images shown: each displayed frame once, lossless RGB (libx264rgb crf 0;
                     FFVHuff with live --native-codec ffvhuff; ``holo-viewer compact`` re-encodes that to x264 later),
                     at the session time it was shown (variable frame rate, plays in step with audio.wav;
                     decode at 25 fps with holo_viewer.media.read_frames(path, fps=25))
      webcam.mkv     only with --record-video (faces are private by default; lossy preview)

session.json (schema ``holo_viewer.session``, :data:`SCHEMA_VERSION`) holds everything replay needs, so
a session folder can be moved and replayed anywhere: ``settings`` (the command's options),
``scenario`` (the script itself, not its path), ``mount`` (the webcam mount), ``avatar`` (name:
``default`` or the patient's, docs/patients.md; digest of the Gaussians replay must find again), ``render`` (mode, tile scale, backend), ``keys``
(every key press: session time, key, action) and ``ratings`` (trainees' pain ratings: session
time, trainee, rating 0-10), plus ``pain_timeline`` (the instructor's levels, the schema of
:mod:`holo_viewer.behaviour.timeline`) and the timing summary. Per-frame numbers are float64, so
replay renders from exactly the values the live frames were rendered from.

tracks.npz and session.json are written atomically (temp + rename) at each flush (every ``flush_s`` seconds) and at
the end, so an interrupted session keeps everything up to its last flush, and ``Ctrl-C`` (which
ends the loop through ``finally``) keeps everything.
"""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

from ..fileio import atomic_write, save_npz
from ..tracking.viewer import MAX_OTHERS

__all__ = ["SessionRecorder", "TRACK_KEYS", "DISPLAY_KEYS", "NATIVE_VIDEO", "SCHEMA", "SCHEMA_VERSION",
           "avatar_record", "add_ratings_csv", "load_session"]

#: session.json's schema name and version (1: before the version field; 2: self-contained)
SCHEMA = "holo_viewer.session"
SCHEMA_VERSION = 2

#: the session's native-image video (lossless, timed; holo_viewer.media)
NATIVE_VIDEO = "native.mkv"
#: per displayed frame (tracks.npz)
DISPLAY_KEYS = ("display_time_s", "display_frame", "render_ms", "render_angle_deg", "render_distance_m",
                "render_tracked", "render_others")

LISTENER_KEYS = ("expr", "jaw_pose", "rotation", "neck_pose", "eyes_pose", "translation")
SPEAKER_KEYS = ("expr", "jaw_pose", "rotation")
_CHUNK = 250
TRACK_KEYS = ("time_s", "viewer_angle_deg", "viewer_distance_m", "pain", "pain_shown", "speaker_found", "window") + tuple(
    f"speaker_{k}" for k in SPEAKER_KEYS) + tuple(f"listener_{k}" for k in LISTENER_KEYS) + ("scenario_time_s",)
#: tracks recorded since a version-2 session first shipped (older sessions replay without them):
#: ``scenario_time_s``, the scenario time of each frame (the step keys move it off the session time)
OPTIONAL_TRACK_KEYS = ("scenario_time_s",)


class SessionRecorder:
    """Collect per-frame rows and flush them to the session folder (thread-safe appends)."""

    def __init__(self, folder: str | os.PathLike, settings: dict[str, Any]) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.settings = dict(settings)
        #: self-contained fields of session.json (scenario, mount, avatar, render; see the module docstring)
        self.header: dict[str, Any] = {}
        #: key presses and trainee ratings ({"t", "key", "action"}, {"t", "trainee", "rating", "source"})
        self.keys: list[dict] = []
        self.ratings: list[dict] = []
        self._rows: dict[str, list] = {k: [] for k in TRACK_KEYS}
        self._chunks: dict[str, list] = {k: [] for k in TRACK_KEYS}
        self._n = 0
        self._display: dict[str, list] = {k: [] for k in DISPLAY_KEYS}
        self._audio: list[np.ndarray] = []
        self._lock = threading.Lock()
        self.summary: dict[str, Any] = {}
        self._wav: Any = None
        self._audio_samples = 0

    def close(self) -> None:
        """Flush and close the audio file (call once, at the end)."""
        self.flush()
        if self._wav is not None:
            self._wav.close()
            self._wav_file.close()
            self._wav = None

    def add_frame(self, **row: Any) -> None:
        """One 25 fps frame; keys of :data:`TRACK_KEYS`."""
        with self._lock:
            for k in TRACK_KEYS:
                self._rows[k].append(np.asarray(row[k], dtype=np.float64))  # exact: replay renders from them
            self._n += 1
            if len(self._rows["time_s"]) >= _CHUNK:  # pack small per-frame arrays: memory stays flat
                for k in TRACK_KEYS:
                    self._chunks[k].append(np.stack(self._rows[k]))
                    self._rows[k] = []

    def add_display(self, time_s: float, frame: int, render_ms: float, render_angle_deg: float = 0.0,
                    render_distance_m: float = 0.6, render_tracked: bool = False,
                    render_others: tuple[tuple[float, float], ...] = ()) -> None:
        """One displayed frame: when (session s), which 25 fps frame, its render time and the viewer
        poses it was rendered for (the followed one, and the other faces of a group frame)."""
        others = np.full((MAX_OTHERS, 2), np.nan)
        if len(render_others):
            others[:len(render_others)] = np.asarray(render_others, np.float64)[:MAX_OTHERS]
        with self._lock:
            for k, v in zip(DISPLAY_KEYS, (float(time_s), int(frame), float(render_ms), float(render_angle_deg),
                                           float(render_distance_m), bool(render_tracked), others)):
                self._display[k].append(v)

    def add_audio(self, samples: np.ndarray) -> None:
        if len(samples):
            with self._lock:
                self._audio.append((np.clip(samples, -1, 1) * 32767).astype(np.int16))

    @property
    def n_frames(self) -> int:
        return self._n

    def flush(self) -> None:
        """Write tracks.npz, audio.wav and session.json (atomically)."""
        import wave

        with self._lock:
            n = self._n
            arrays = {}
            for k in TRACK_KEYS:
                parts = self._chunks[k] + ([np.stack(self._rows[k])] if self._rows[k] else [])
                arrays[k] = np.concatenate(parts) if parts else np.zeros((0,), np.float32)
            disp = {k: np.asarray(v) for k, v in self._display.items() if k != "render_others"}
            disp["render_others"] = np.stack(self._display["render_others"]) if self._display["render_others"] \
                else np.zeros((0, MAX_OTHERS, 2))
            audio = np.concatenate(self._audio) if self._audio else np.zeros(0, np.int16)
            self._audio = []
        arrays["speaker_found"] = arrays["speaker_found"].astype(bool) if n else np.zeros(0, bool)
        arrays["window"] = arrays["window"].astype(np.int32) if n else np.zeros(0, np.int32)
        arrays["display_time_s"] = disp["display_time_s"].astype(np.float64)
        arrays["display_frame"] = disp["display_frame"].astype(np.int64)
        arrays["render_ms"] = disp["render_ms"].astype(np.float32)
        arrays["render_angle_deg"] = disp["render_angle_deg"].astype(np.float64)  # exactly as rendered
        arrays["render_distance_m"] = disp["render_distance_m"].astype(np.float64)
        arrays["render_tracked"] = disp["render_tracked"].astype(bool)
        arrays["render_others"] = disp["render_others"].astype(np.float64)
        arrays["fps"] = np.array(25)
        save_npz(self.folder / "tracks.npz", **arrays)
        # audio.wav is appended (memory stays flat in long sessions); the wave module patches the
        # header's lengths after every write, so the file is a valid WAV up to the last flush
        if self._wav is None:
            self._wav_file = open(self.folder / "audio.wav", "wb")
            self._wav = wave.open(self._wav_file, "wb")
            self._wav.setnchannels(1)
            self._wav.setsampwidth(2)
            self._wav.setframerate(16000)
        self._wav.writeframes(audio.tobytes())
        self._wav_file.flush()
        self._audio_samples += len(audio)
        doc = {"schema": SCHEMA, "version": SCHEMA_VERSION, **self.header, "keys": list(self.keys),
               "ratings": list(self.ratings), "settings": self.settings, "frames": n, "displayed_frames": int(len(disp["display_time_s"])),
               "audio_seconds": round(self._audio_samples / 16000, 3), "summary": self.summary}
        with atomic_write(self.folder / "session.json", "w") as fh:
            json.dump(doc, fh, indent=2, default=_json_default)


def avatar_record(pipeline: Any, name: str = "default") -> dict[str, Any]:
    """``{"name", "digest", "gaussians"}`` of a pipeline's avatar, which replay must find again.

    The digest covers the avatar's stored arrays (its Gaussians, binding, mesh and head model: every
    array or tensor among its attributes, two levels deep, in name order), not values computed from
    them, so it is the same on every machine for the same avatar files.
    """
    import hashlib

    h = hashlib.blake2b(digest_size=16)

    def feed(obj: Any, depth: int) -> None:
        if hasattr(obj, "detach"):  # a torch tensor
            obj = obj.detach().cpu().numpy()
        if isinstance(obj, np.ndarray):
            h.update(f"{obj.dtype}{obj.shape}".encode())
            h.update(np.ascontiguousarray(obj).tobytes())
        elif isinstance(obj, dict):
            for k in sorted(obj, key=str):
                h.update(str(k).encode())
                feed(obj[k], depth)
        elif isinstance(obj, (list, tuple)):
            for x in obj:
                feed(x, depth)
        elif depth > 0 and hasattr(obj, "__dict__"):
            feed({k: v for k, v in vars(obj).items() if not k.startswith("_")}, depth - 1)

    feed(pipeline.avatar, 2)
    return {"name": name, "digest": h.hexdigest(), "gaussians": int(len(pipeline.avatar))}


def add_ratings_csv(folder: str | os.PathLike, csv_path: str | os.PathLike) -> int:
    """Add trainees' ratings from a CSV (header ``t,trainee,rating``: session seconds >= 0, a label,
    an integer 0-10) to the session's session.json (source ``csv``; rewritten atomically); returns
    how many. InputError naming the file, row and column for anything else."""
    import csv

    from ..errors import InputError
    from ..fileio import read_json

    p, src = Path(folder), Path(csv_path)
    load_session(p)  # a session folder, readable
    try:
        with open(src, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
            header = set(rows[0]) if rows else set()
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{src}: cannot read the ratings CSV ({exc})") from exc
    if not rows or not {"t", "trainee", "rating"} <= header:
        raise InputError(f"{src}: expected a header with columns t, trainee, rating and at least one row, found "
                         f"{sorted(header) if rows else 'no rows'}")
    new = []
    for i, row in enumerate(rows, start=2):
        try:
            t = float(row["t"])
            rating = float(row["rating"])
        except (TypeError, ValueError):
            raise InputError(f"{src}: row {i}: t and rating: expected numbers, found {row['t']!r}, "
                             f"{row['rating']!r}") from None
        if not (np.isfinite(t) and t >= 0) or not (rating == int(rating) and 0 <= rating <= 10):
            raise InputError(f"{src}: row {i}: expected t >= 0 s and a rating 0-10 (whole numbers), found t {t}, "
                             f"rating {rating}")
        trainee = (row["trainee"] or "").strip()
        if not trainee:
            raise InputError(f"{src}: row {i}: trainee: expected a label, found an empty cell")
        new.append({"t": round(t, 3), "trainee": trainee, "rating": int(rating), "source": "csv"})
    meta = read_json(p / "session.json", InputError, "session metadata")
    meta["ratings"] = sorted(list(meta.get("ratings") or []) + new, key=lambda r: r["t"])
    with atomic_write(p / "session.json", "w") as fh:
        json.dump(meta, fh, indent=2, default=_json_default)
    return len(new)


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def load_session(folder: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """(session.json dict, tracks.npz arrays) of a session folder."""
    from ..errors import InputError
    from ..fileio import read_json, read_npz

    p = Path(folder)
    if not (p / "session.json").is_file() or not (p / "tracks.npz").is_file():
        raise InputError(f"{p}: expected a live session folder with session.json and tracks.npz")
    meta = read_json(p / "session.json", InputError, "session metadata")
    _check_meta(meta, p / "session.json")
    tracks = read_npz(p / "tracks.npz", InputError, "session tracks")
    missing = [k for k in TRACK_KEYS if k not in tracks and k not in OPTIONAL_TRACK_KEYS]
    if missing:
        raise InputError(f"{p / 'tracks.npz'}: missing keys {missing}")
    _check_tracks(tracks, p / "tracks.npz")
    return meta, tracks


def _check_meta(meta: Any, path: Path) -> None:
    """Types of the session.json fields replay reads (a tampered file is refused naming the field)."""
    from ..errors import InputError
    from ..validation import check_json_number

    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a JSON object, found {type(meta).__name__}")
    settings = meta.get("settings", {})
    if not isinstance(settings, dict):
        raise InputError(f"{path}: settings: expected a JSON object, found {type(settings).__name__}")
    if settings.get("tile_scale") is not None:
        check_json_number(settings["tile_scale"], f"{path}: settings.tile_scale", low=0.0, high=4.0, low_open=True)
    for key, kind in (("scenario", dict), ("mount", dict), ("avatar", dict), ("render", dict), ("keys", list),
                      ("ratings", list)):  # the version-2 fields
        if meta.get(key) is not None and not isinstance(meta[key], kind):
            raise InputError(f"{path}: {key}: expected a JSON {'object' if kind is dict else 'array'} or null, "
                             f"found {type(meta[key]).__name__} {meta[key]!r:.60}")
    if meta.get("end_s") is not None:
        check_json_number(meta["end_s"], f"{path}: end_s", low=0.0)
    for key in ("render_mode", "scenario"):
        if settings.get(key) is not None and not isinstance(settings[key], str):
            raise InputError(f"{path}: settings.{key}: expected a string, found {type(settings[key]).__name__} "
                             f"{settings[key]!r:.60}")


def _check_tracks(tracks: dict[str, np.ndarray], path: Path) -> None:
    """Every track numeric, finite where replay uses it, and one row per recorded frame."""
    from ..errors import InputError

    time_s = tracks["time_s"]
    if time_s.ndim != 1:
        raise InputError(f"{path}: time_s: expected a 1-D array (one time per frame), found shape {time_s.shape}")
    n = time_s.shape[0]
    for key in (k for k in TRACK_KEYS if k in tracks):
        arr = tracks[key]
        if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_):
            raise InputError(f"{path}: {key}: expected numbers, found dtype {arr.dtype}")
        if arr.ndim < 1 or arr.shape[0] != n:
            raise InputError(f"{path}: {key}: expected {n} rows (one per time_s entry), found shape {arr.shape}")
