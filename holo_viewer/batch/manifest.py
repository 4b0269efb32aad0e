"""Batch manifests: one render job per row (JSON Lines or CSV), validated, and the job content hash.

A row names

* the **avatar**: ``avatar`` = ``default`` (the embedded head and its 100k-Gaussian avatar), a fitted
  patient's name (docs/patients.md; its head and avatar files go into the job hash), a fitted avatar
  ``.npz``, or a PLY
  (a GaussianAvatars ``point_cloud.ply`` with ``flame_model`` and optionally ``avatar_params``, its
  ``flame_param.npz`` identity; or a plain 3DGS PLY, shown as it is);
* what **drives** it, exactly one of

  - ``flame_params``: a ``flame_param.npz`` sequence (optionally ``start``/``stop`` frames, ``fps``),
  - ``speaker_audio`` + ``speaker_params``: a 16 kHz speaker WAV and its ``speaker.npz``, run through
    the listener-reaction model (``seed``, ``temperature``; ``pain`` conditions the model),
  - ``seconds``: a synthesized speaker clip of that length through the reaction model (``seed``),
  - none of these: a still face held for ``frames`` frames (``expressions``, ``pain``);

* the **face**: ``pain`` in [0, 1], ``scenario`` (``constant`` | ``rising`` | ``falling`` | ``pulse``:
  the pain level over the clip; sequences and stills only) or ``pain_timeline`` (the pain-timeline
  schema of :mod:`holo_viewer.behaviour.timeline`, ``[{"t": 0, "level": 0.2}, ...]``, or a path to
  a JSON file holding one; in CSV a path or the JSON text; it replaces ``pain``) and
  ``expressions`` (``{"smile": 0.8}``; in CSV ``smile=0.8;mouth_open=0.2``);
* the **behaviour** of a reaction (reaction drivers only): ``behaviour``, an object of
  :class:`~holo_viewer.behaviour.BehaviourConfig` settings (``{"gaze": false}``; in CSV its JSON
  text), or ``false`` for the reaction model alone; default: every layer on, seeded by ``seed``;
  ``viewer_angle`` (degrees, -60..60) and ``viewer_distance`` (metres) place the viewer the eyes look
  at (default 0 and 0.6: in front of the panel);
* the **display**: ``calibration`` (a ``visual.json`` or a preset name; default the shipped
  Portrait), ``tile_scale`` (quilt tile size relative to the calibration's), ``renderer``;
* the **outputs**: ``outputs``, a list of ``quilt_mp4``, ``native_mp4``, ``quilt_png``,
  ``native_png`` (CSV: ``quilt_mp4;native_png``; default ``quilt_mp4``), ``crf`` of the quilt video
  (default 18) and ``native_crf`` of the native video (default 0 = lossless RGB);
* optionally an ``id`` (a label for the summary; it does not change the job's hash).

Relative paths are relative to the manifest's folder. Unknown fields are errors (a typo must not
silently render the wrong job). Each bad row becomes a :class:`RowError` naming the file, the line,
the field, what was expected and what was found; the other rows still run.

:func:`job_hash` fingerprints everything that determines a job's pixels: the row's settings (not
``id``), the *contents* of every file it reads (not their names), the shipped assets it uses
(default head and fitted default avatar, reaction checkpoint, Portrait calibration), the renderer
settings its frames use (:func:`render_settings`), the package's code (:func:`code_digest`: any
change to the renderer, the behaviour layers, the reaction decoding or the encoders re-renders), the
package version and :data:`FORMAT_VERSION`. Outputs are stored under this hash, so a re-run finds
finished jobs.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import hashlib
import io
import json
import math
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable

from ..errors import ManifestError
from ..fileio import MAX_JSON_DEPTH, file_sha256, json_depth

__all__ = ["JobSpec", "RowError", "read_manifest", "job_hash", "FORMAT_VERSION", "OUTPUT_KINDS", "SCENARIOS",
           "EXPRESSIONS", "FileDigests", "SHIPPED_ASSETS", "assets_dir", "code_digest", "render_settings"]

#: bump when the meaning of a job's fields or the output layout changes (invalidates finished jobs);
#: 2: the hash also covers the code, the renderer settings and the fitted default avatar
FORMAT_VERSION = 2
#: bump when the behaviour layers' output changes (invalidates finished reaction jobs only)
BEHAVIOUR_VERSION = 4  # 2: brow raises at pauses, the one pause-onset definition; 3: backchannel nods; 4: nod reaction time
#: what a job can ask for
OUTPUT_KINDS: tuple[str, ...] = ("quilt_mp4", "native_mp4", "quilt_png", "native_png")
#: pain over the clip: factor of ``pain`` at clip time t in [0, 1]
SCENARIOS: dict[str, Callable[[float], float]] = {
    "constant": lambda t: 1.0,
    "rising": lambda t: t,
    "falling": lambda t: 1.0 - t,
    "pulse": lambda t: 1.0 - abs(2.0 * t - 1.0),
}
#: named expressions a row may add (those of ``FaceControls.named``)
EXPRESSIONS: tuple[str, ...] = ("smile", "pain", "surprise", "frown", "mouth_open", "neutral")
_MAX_FRAMES = 100_000


@dataclass(frozen=True)
class JobSpec:
    """One validated manifest row. Paths are absolute; ``None`` = the documented default.

    Attributes
    ----------
    line : int
        1-based line (JSON Lines) or data row + 1 (CSV, the header is line 1) in the manifest.
    id : str
        Label of the job (default ``line{N}``); not part of the hash.
    driver : {"flame_params", "reaction", "synthetic_reaction", "still"}
        What drives the face (inferred from the fields present).
    """

    line: int
    id: str
    driver: str
    avatar: str = "default"
    flame_model: str | None = None
    avatar_params: str | None = None
    flame_params: str | None = None
    start: int = 0
    stop: int | None = None
    speaker_audio: str | None = None
    speaker_params: str | None = None
    seconds: float | None = None
    frames: int = 1
    seed: int = 0
    temperature: float | None = None
    pain: float = 0.0
    scenario: str = "constant"
    expressions: tuple[tuple[str, float], ...] = ()
    calibration: str | None = None
    tile_scale: float = 1.0
    renderer: str = "fast"
    fps: float = 25.0
    outputs: tuple[str, ...] = ("quilt_mp4",)
    crf: int = 18
    native_crf: int = 0
    #: reaction drivers: the BehaviourConfig as sorted (key, value) pairs; None = the model alone
    behaviour: tuple[tuple[str, Any], ...] | None = None
    #: the pain timeline as ((t, level), ...); None = ``pain`` (and ``scenario``)
    pain_timeline: tuple[tuple[float, float], ...] | None = None
    #: reaction drivers: the viewer the eyes look at (degrees, metres); None = 0 deg, 0.6 m
    viewer_angle: float | None = None
    viewer_distance: float | None = None

    @property
    def label(self) -> str:
        """``line N (id)`` for messages."""
        return f"line {self.line} ({self.id})"

    def files(self) -> dict[str, str]:
        """The input files the job reads, by field name."""
        out = {k: getattr(self, k) for k in ("flame_model", "avatar_params", "flame_params", "speaker_audio",
                                              "speaker_params")}
        if self.avatar != "default" and not _is_patient(self.avatar):
            out["avatar"] = self.avatar
        if self.calibration is not None and os.path.exists(self.calibration):
            out["calibration"] = self.calibration
        return {k: v for k, v in out.items() if v is not None}


@dataclass(frozen=True)
class RowError:
    """A manifest row that could not be turned into a job."""

    line: int
    id: str
    error: str


# =============================================================================== reading


def read_manifest(path: str | os.PathLike) -> list[JobSpec | RowError]:
    """Parse and validate a manifest; one entry per job row, in file order.

    Parameters
    ----------
    path : path-like
        ``.jsonl`` / ``.ndjson`` (one JSON object per line; blank lines and lines starting with ``#``
        are skipped) or ``.csv`` (a header row of field names; empty cells = default).

    Returns
    -------
    list of JobSpec or RowError
        A :class:`RowError` for each bad row (the rest still run).

    Raises
    ------
    ManifestError
        The file is missing, unreadable, of an unknown type, or holds no job rows.
    """
    p = Path(path)
    if not p.is_file():
        raise ManifestError(f"{p}: manifest not found (expected a .jsonl or .csv file)")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ManifestError(f"{p}: cannot read the manifest ({exc})") from None
    suffix = p.suffix.lower()
    raw: list[tuple[int, dict[str, Any] | str]] = []
    if suffix in (".jsonl", ".ndjson"):
        for n, line in enumerate(text.splitlines(), start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            if json_depth(s) > MAX_JSON_DEPTH:
                raw.append((n, f"expected a JSON object, found JSON nested {json_depth(s)} levels deep (at most "
                               f"{MAX_JSON_DEPTH}, fileio.MAX_JSON_DEPTH)"))
                continue
            try:
                obj = json.loads(s)
            except json.JSONDecodeError as exc:
                raw.append((n, f"expected a JSON object, found invalid JSON ({exc.msg} at column {exc.colno})"))
                continue
            raw.append((n, obj if isinstance(obj, dict) else f"expected a JSON object, found {type(obj).__name__}"))
        from_csv = False
    elif suffix == ".csv":
        reader = csv.DictReader(io.StringIO(text))
        if not reader.fieldnames:
            raise ManifestError(f"{p}: expected a CSV header row of field names, found an empty file")
        for n, row in enumerate(reader, start=2):
            if None in row:
                raw.append((n, f"expected {len(reader.fieldnames)} cells (the header's), found more"))
                continue
            cells = {k.strip(): v.strip() for k, v in row.items() if k is not None and v is not None and v.strip()}
            if cells:
                raw.append((n, cells))
        from_csv = True
    else:
        raise ManifestError(f"{p}: expected a .jsonl, .ndjson or .csv manifest, found suffix {p.suffix!r}")
    if not raw:
        raise ManifestError(f"{p}: expected at least one job row, found none")
    out: list[JobSpec | RowError] = []
    for n, obj in raw:
        ident = f"line{n}"
        if isinstance(obj, str):
            out.append(RowError(n, ident, f"{p} line {n}: {obj}"))
            continue
        ident = str(obj.get("id", ident))
        try:
            out.append(_parse_row(obj, n, p.parent.resolve(), from_csv))
        except ManifestError as exc:
            out.append(RowError(n, ident, f"{p} line {n} ({ident}): {exc}"))
    return out


_FIELDS = {f.name for f in fields(JobSpec)} - {"line", "driver"}


def _parse_row(row: dict[str, Any], line: int, base: Path, from_csv: bool) -> JobSpec:
    unknown = sorted(set(row) - _FIELDS)
    if unknown:
        raise ManifestError(f"unknown field(s) {unknown}; expected some of {sorted(_FIELDS)}")
    r = _Row(row, base, from_csv)
    kw: dict[str, Any] = {"line": line, "id": r.str("id", f"line{line}")}
    avatar = r.str("avatar", "default")
    if _is_patient(avatar.lower()):
        from ..pipeline.scene import patient_files

        if not patient_files(avatar.lower())[0]:
            raise ManifestError(f"avatar: patient {avatar.lower()!r} is not fitted yet (no avatar.npz); a batch "
                                "renders Gaussians")
        kw["avatar"] = avatar.lower()
    else:
        kw["avatar"] = "default" if avatar.lower() == "default" else r.path("avatar", must_exist=True)
    for key in ("flame_model", "avatar_params"):
        kw[key] = r.path(key, must_exist=True) if key in row else None
    if (kw["avatar"] == "default" or _is_patient(kw["avatar"])) and (kw["flame_model"] or kw["avatar_params"]):
        raise ManifestError("flame_model/avatar_params: expected them only with a PLY avatar, found them with "
                            "avatar 'default' (the default avatar is bound to the embedded head)")

    has = {k for k in ("flame_params", "speaker_audio", "speaker_params", "seconds") if k in row}
    if "flame_params" in has:
        driver = "flame_params"
    elif has & {"speaker_audio", "speaker_params"}:
        driver = "reaction"
    elif "seconds" in has:
        driver = "synthetic_reaction"
    else:
        driver = "still"
    allowed = {"flame_params": {"flame_params"}, "reaction": {"speaker_audio", "speaker_params"},
               "synthetic_reaction": {"seconds"}, "still": set()}[driver]
    if has - allowed:
        raise ManifestError(f"driver: expected one of flame_params | speaker_audio + speaker_params | seconds, "
                            f"found {sorted(has)} together")
    kw["driver"] = driver
    if driver == "flame_params":
        kw["flame_params"] = r.path("flame_params", must_exist=True)
        kw["start"] = r.int("start", 0, 0, _MAX_FRAMES)
        stop = r.int("stop", -1, 1, _MAX_FRAMES) if "stop" in row else None
        if stop is not None and stop <= kw["start"]:
            raise ManifestError(f"stop: expected a frame after start={kw['start']}, found {stop}")
        kw["stop"] = stop
    elif driver == "reaction":
        if not {"speaker_audio", "speaker_params"} <= has:
            raise ManifestError("speaker_audio, speaker_params: expected both (a 16 kHz WAV and its speaker.npz), "
                                f"found only {sorted(has)}")
        kw["speaker_audio"] = r.path("speaker_audio", must_exist=True)
        kw["speaker_params"] = r.path("speaker_params", must_exist=True)
    elif driver == "synthetic_reaction":
        kw["seconds"] = r.float("seconds", 2.0, 0.04, 600.0)
    else:
        kw["frames"] = r.int("frames", 1, 1, _MAX_FRAMES)
    for key in ("start", "stop") if driver != "flame_params" else ():
        if key in row:
            raise ManifestError(f"{key}: expected only with flame_params, found it with a {driver} driver")
    if "frames" in row and driver != "still":
        raise ManifestError(f"frames: expected only for a still face, found it with a {driver} driver "
                            "(the clip length comes from the driver)")
    kw["seed"] = r.int("seed", 0, 0, 2**63 - 1)
    kw["temperature"] = r.float("temperature", 0.0, 0.0, 10.0) if "temperature" in row else None
    if kw["temperature"] is not None and driver not in ("reaction", "synthetic_reaction"):
        raise ManifestError(f"temperature: expected only with a reaction driver, found it with {driver}")
    kw["pain"] = r.float("pain", 0.0, 0.0, 1.0)
    scenario = r.str("scenario", "constant")
    if scenario not in SCENARIOS:
        raise ManifestError(f"scenario: expected one of {sorted(SCENARIOS)}, found {scenario!r}")
    if scenario != "constant" and driver in ("reaction", "synthetic_reaction"):
        raise ManifestError(f"scenario: the reaction model takes one pain level per clip; expected 'constant' "
                            f"with a reaction driver, found {scenario!r}")
    kw["scenario"] = scenario
    kw["expressions"] = r.expressions("expressions")
    cal = r.str("calibration", "")
    kw["calibration"] = None if cal in ("", "default") else (
        r.path("calibration", must_exist=True) if cal.lower().endswith(".json") or os.sep in cal else cal)
    kw["tile_scale"] = r.float("tile_scale", 1.0, 0.02, 4.0)
    kw["renderer"] = r.str("renderer", "fast")
    if driver in ("reaction", "synthetic_reaction") and "fps" in row:
        raise ManifestError("fps: the reaction model runs at 25 fps; expected no fps with a reaction driver")
    kw["fps"] = r.float("fps", 25.0, 0.1, 240.0)
    kw["outputs"] = r.outputs("outputs")
    kw["crf"] = r.int("crf", 18, 0, 51)
    kw["native_crf"] = r.int("native_crf", 0, 0, 51)
    kw["pain_timeline"] = r.pain_timeline("pain_timeline") if "pain_timeline" in row else None
    if kw["pain_timeline"] is not None and ("pain" in row or scenario != "constant"):
        raise ManifestError("pain_timeline: expected it instead of pain/scenario, found both")
    if driver in ("reaction", "synthetic_reaction"):
        kw["behaviour"] = r.behaviour("behaviour", kw["seed"])
        if "viewer_angle" in row:
            kw["viewer_angle"] = r.float("viewer_angle", 0.0, -60.0, 60.0)
        if "viewer_distance" in row:
            kw["viewer_distance"] = r.float("viewer_distance", 0.6, 0.05, 20.0)
    else:
        for key in ("behaviour", "viewer_angle", "viewer_distance"):
            if key in row:
                raise ManifestError(f"{key}: expected only with a reaction driver, found it with {driver}")
    return JobSpec(**kw)


class _Row:
    """Typed access to one row's cells (CSV cells are strings, JSON values are typed)."""

    def __init__(self, row: dict[str, Any], base: Path, from_csv: bool) -> None:
        self.row, self.base, self.csv = row, base, from_csv

    def _raw(self, key: str, default: Any) -> Any:
        return self.row.get(key, default)

    def str(self, key: str, default: str) -> str:
        v = self._raw(key, default)
        if not isinstance(v, str):
            raise ManifestError(f"{key}: expected a string, found {v!r}")
        return v.strip()

    def path(self, key: str, must_exist: bool) -> str:
        v = self.str(key, "")
        if not v:
            raise ManifestError(f"{key}: expected a file path, found an empty value")
        p = Path(v).expanduser()
        p = p if p.is_absolute() else self.base / p
        if must_exist and not p.is_file():
            raise ManifestError(f"{key}: file not found: {p}")
        return str(p.resolve())

    def float(self, key: str, default: float, low: float, high: float) -> float:
        v = self._raw(key, default)
        if isinstance(v, str) and self.csv:
            try:
                v = float(v)
            except ValueError:
                raise ManifestError(f"{key}: expected a number, found {v!r}") from None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ManifestError(f"{key}: expected a finite number, found {v!r}")
        if not low <= v <= high:
            raise ManifestError(f"{key}: expected a value in [{low:g}, {high:g}], found {v!r}")
        return float(v)

    def int(self, key: str, default: int, low: int, high: int) -> int:
        v = self._raw(key, default)
        if isinstance(v, str) and self.csv:
            try:
                v = int(v)
            except ValueError:
                raise ManifestError(f"{key}: expected an integer, found {v!r}") from None
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int):
            raise ManifestError(f"{key}: expected an integer, found {v!r}")
        if not low <= v <= high:
            raise ManifestError(f"{key}: expected an integer in [{low}, {high}], found {v}")
        return v

    def expressions(self, key: str) -> tuple[tuple[str, float], ...]:
        v = self._raw(key, {})
        if isinstance(v, str):
            pairs: dict[str, Any] = {}
            for item in filter(None, (s.strip() for s in v.replace(",", ";").split(";"))):
                name, sep, w = item.partition("=")
                if not sep:
                    raise ManifestError(f"{key}: expected NAME=VALUE items separated by ';', found {item!r}")
                try:
                    pairs[name.strip()] = float(w)
                except ValueError:
                    raise ManifestError(f"{key}: {name.strip()}: expected a number, found {w!r}") from None
            v = pairs
        if not isinstance(v, dict):
            raise ManifestError(f"{key}: expected an object like {{\"smile\": 0.8}}, found {v!r}")
        out = []
        for name, w in sorted(v.items()):
            if name not in EXPRESSIONS:
                raise ManifestError(f"{key}: expected names in {EXPRESSIONS}, found {name!r}")
            if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0.0 <= w <= 1.0:
                raise ManifestError(f"{key}: {name}: expected an intensity in [0, 1], found {w!r}")
            out.append((name, float(w)))
        return tuple(out)

    def _json_or_text(self, key: str) -> Any:
        v = self._raw(key, None)
        if isinstance(v, str) and self.csv and (v.strip()[:1] in ("[", "{") or v.strip() in ("true", "false")):
            try:
                return json.loads(v)
            except json.JSONDecodeError as exc:
                raise ManifestError(f"{key}: expected JSON, found {v!r:.60} ({exc})") from None
        return v

    def pain_timeline(self, key: str) -> tuple[tuple[float, float], ...]:
        from ..behaviour import PainTimeline
        from ..errors import InputError

        v = self._json_or_text(key)
        try:
            tl = PainTimeline.load(self.path(key, must_exist=True)) if isinstance(v, str) else \
                PainTimeline.from_json(v, source=key)
        except ManifestError:
            raise
        except InputError as exc:
            raise ManifestError(str(exc)) from None
        return tuple((k.t, k.level) for k in tl.keys)

    def behaviour(self, key: str, seed: int) -> tuple[tuple[str, Any], ...] | None:
        from ..behaviour import BehaviourConfig
        from ..errors import InputError

        v = self._json_or_text(key)
        if v is False:
            return None
        if v is None or v is True:
            v = {}
        if not isinstance(v, dict):
            raise ManifestError(f"{key}: expected an object of behaviour settings or false, found {v!r:.60}")
        try:
            cfg = BehaviourConfig.from_dict({"seed": seed, **v}, source=key)
        except InputError as exc:
            raise ManifestError(str(exc)) from None
        return _behaviour_items(cfg)

    def outputs(self, key: str) -> tuple[str, ...]:
        v = self._raw(key, ["quilt_mp4"])
        if isinstance(v, str):
            v = [s.strip() for s in v.replace(",", ";").split(";") if s.strip()]
        if not isinstance(v, list) or not v or not all(isinstance(s, str) for s in v):
            raise ManifestError(f"{key}: expected a non-empty list of {OUTPUT_KINDS}, found {v!r}")
        bad = [s for s in v if s not in OUTPUT_KINDS]
        if bad:
            raise ManifestError(f"{key}: expected items of {OUTPUT_KINDS}, found {bad}")
        return tuple(k for k in OUTPUT_KINDS if k in v)  # canonical order: the hash ignores list order


def switch_behaviour_off(spec: JobSpec, layers: tuple[str, ...]) -> JobSpec:
    """``spec`` with behaviour layers off (``"behaviour"``: all, the model alone); non-reaction jobs as they are."""
    from dataclasses import replace

    from ..behaviour import BehaviourConfig

    if spec.behaviour is None:
        return spec
    if "behaviour" in layers:
        return replace(spec, behaviour=None)
    cfg = BehaviourConfig.from_dict(dict(spec.behaviour)).without(*layers)
    return replace(spec, behaviour=_behaviour_items(cfg))


def _behaviour_items(cfg: Any) -> tuple[tuple[str, Any], ...]:
    """A BehaviourConfig as the hashable, JSON-able sorted (key, value) pairs of ``JobSpec.behaviour``."""
    return tuple(sorted((k, tuple(x) if isinstance(x, list) else x) for k, x in cfg.to_dict().items()))


# =============================================================================== hashing


class FileDigests:
    """SHA-256 of file contents, cached by (path, size, mtime) so a PLY used by 1,000 rows is read once."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, int, int], str] = {}

    def __call__(self, path: str | os.PathLike) -> str:
        p = Path(path)
        st = p.stat()
        key = (str(p), st.st_size, st.st_mtime_ns)
        if key not in self._cache:
            self._cache[key] = file_sha256(p)
        return self._cache[key]


#: the shipped inputs a job reads implicitly, all in the repository's ``assets/`` folder (README); the
#: stage modules resolve the same paths (``tests/test_batch.py`` checks that they agree)
SHIPPED_ASSETS = {"default_head": "default_head.npz", "default_avatar": "default_avatar.npz",
                  "reaction_checkpoint": "reaction_default.pt", "calibration": "lkg_portrait_visual.json"}
#: the package's source files that :func:`code_digest` reads
CODE_SUFFIXES = (".py", ".cpp", ".c", ".h", ".hpp")


def assets_dir() -> Path:
    """The repository's ``assets/`` folder (default head, reaction checkpoint, Portrait calibration)."""
    return Path(__file__).resolve().parents[2] / "assets"


def _shipped_inputs(spec: JobSpec) -> dict[str, Path]:
    """The shipped assets a job reads implicitly (their contents go into the hash)."""
    names = []
    if spec.avatar == "default":
        names += ["default_head", "default_avatar"]
    extra = {}
    if _is_patient(spec.avatar):  # a patient: its head, textures and fitted avatar
        from ..pipeline.scene import patient_files

        extra = {f"patient:{p.name}": p for p in patient_files(spec.avatar)[1]}
    if spec.driver in ("reaction", "synthetic_reaction"):
        names.append("reaction_checkpoint")
    if spec.calibration is None:
        names.append("calibration")
    return {**{k: assets_dir() / SHIPPED_ASSETS[k] for k in names}, **extra}


def _is_patient(name: str) -> bool:
    """Whether ``name`` is a shipped patient's name (not a path)."""
    from ..pipeline.scene import is_patient

    return is_patient(name)


@functools.lru_cache(maxsize=4)
def code_digest(root: str | os.PathLike | None = None) -> str:
    """SHA-256 of the package's own source (default: this ``holo_viewer`` folder): every file ending in
    :data:`CODE_SUFFIXES`, by relative path and contents, in sorted order (compiled files and caches are
    not read: they follow from the sources). Computed once per process."""
    base = Path(__file__).resolve().parents[1] if root is None else Path(root)
    h = hashlib.sha256()
    for path in sorted(p for p in base.rglob("*") if p.suffix in CODE_SUFFIXES and p.is_file()
                       and "__pycache__" not in p.parts):
        h.update(path.relative_to(base).as_posix().encode() + b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def render_settings() -> dict[str, Any]:
    """The renderer settings a job's frames use (the workers' ``RenderConfig`` defaults; the thread count,
    which does not change pixels, left out)."""
    from ..render import config

    settings = dataclasses.asdict(config.RenderConfig())
    settings.pop("num_threads", None)
    return settings


def job_hash(spec: JobSpec, digests: FileDigests | None = None) -> str:
    """32 hex digits fingerprinting what determines the job's outputs (see the module docstring)."""
    from .. import __version__

    digests = digests or FileDigests()
    record: dict[str, Any] = {"format": FORMAT_VERSION, "holo_viewer": __version__, "code": code_digest(),
                              "render": render_settings()}
    files = spec.files()
    for f in fields(JobSpec):
        if f.name in ("line", "id"):
            continue
        value = getattr(spec, f.name)
        if f.name in ("behaviour", "pain_timeline", "viewer_angle", "viewer_distance") and value is None:
            continue  # fields added later: jobs without them keep their hashes
        if f.name == "behaviour":
            record["behaviour_version"] = BEHAVIOUR_VERSION
        record[f.name] = {"sha256": digests(value)} if f.name in files else value
    record["shipped"] = {k: digests(v) if v.is_file() else "missing" for k, v in _shipped_inputs(spec).items()}
    blob = json.dumps(record, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.blake2b(blob, digest_size=16).hexdigest()
