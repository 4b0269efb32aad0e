"""Looking Glass display calibration (``visual.json``) and device presets (pure data, no I/O
except :meth:`DisplayCalibration.from_file`).

A calibration describes one physical panel: its lenticular sheet (``pitch`` lenses per inch,
``slope``, ``center`` phase, ``invView`` lens direction, flips), its screen (``screenW`` x
``screenH`` pixels at ``DPI``) and its ``viewCone`` (degrees). The quilt layout (columns, rows,
quilt size) is not part of ``visual.json``; it comes from the device family, chosen by the
serial-number prefix (:data:`PRESETS`).

Sources for the preset table (public; values cross-checked where two sources exist):

* Serial prefix -> quilt size, columns x rows: ``Looking-Glass/looking-glass-webxr``
  ``src/LookingGlassConfig.ts`` (``quiltResolution``, ``quiltWidth``, ``quiltHeight``).
* Portrait lenticular values, 1536x2048 at 324 DPI, 40 deg cone: the public bug-report
  calibration in ``assets/lkg_portrait_visual.json``.
* Gen1 8.9" (2560x1600, 338 DPI, pitch 47.58427, slope -5.420652, center 0.042, cone 40):
  ``dormon/3DApps`` ``holoCalibration.h`` defaults ("our small LKG").
* Go: 1440x2560, aspect 0.5625, view cone 54 deg: Looking Glass Unreal plugin
  ``MakeDefaultCalibration`` ("Looking Glass Go Portrait", serial ``LKG-E``).
* Screen sizes of the 16"/32"/65" and Gen1 4K/8K panels are their marketed 4K/8K UHD
  resolutions; their DPI is derived from the diagonal (noted ``derived`` below).

Preset lenticular values (pitch, slope, center) are *nominal*: every real panel is calibrated
individually and its own ``visual.json`` must be used to drive it. A preset calibration has
``nominal=True``; the interleaver warns when it is given one.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping

from ..errors import CalibrationError

__all__ = ["DisplayCalibration", "QuiltLayout", "DevicePreset", "PRESETS", "preset_for_serial",
           "JSON_FIELDS", "LIMITS", "MAX_SCREEN_SIDE", "MAX_SCREEN_PIXELS"]

#: panel size bounds: the largest Looking Glass (65", 7680 x 4320) with room for portrait
#: orientation; quilt-to-native allocates ~12 bytes per native pixel, so 32768**2 asked for 12 GiB
MAX_SCREEN_SIDE = 8192
MAX_SCREEN_PIXELS = 7680 * 4320

#: visual.json key -> (DisplayCalibration attribute, kind). kind: "float" or "flag".
JSON_FIELDS: dict[str, tuple[str, str]] = {
    "pitch": ("pitch", "float"),
    "slope": ("slope", "float"),
    "center": ("center", "float"),
    "fringe": ("fringe", "float"),
    "viewCone": ("view_cone", "float"),
    "invView": ("inv_view", "flag"),
    "verticalAngle": ("vertical_angle", "float"),
    "DPI": ("dpi", "float"),
    "screenW": ("screen_w", "int"),
    "screenH": ("screen_h", "int"),
    "flipImageX": ("flip_image_x", "flag"),
    "flipImageY": ("flip_image_y", "flag"),
    "flipSubp": ("flip_subp", "flag"),
}
#: Plausible ranges of the lenticular numbers: (low, high, what). Real panels: pitch 40-55 lenticules
#: per inch, DPI 130-500, |slope| 5-8, center (a phase, only its fractional part matters) within +-1.
#: Values outside give a broken native image, so they are refused rather than rendered.
LIMITS: dict[str, tuple[float, float, str]] = {
    "pitch": (1.0, 1000.0, "lenticules per inch"),
    "dpi": (10.0, 5000.0, "pixels per inch"),
    "slope": (0.01, 1000.0, "a lens slope (screen rows per pixel of lens shift)"),
    "center": (-1000.0, 1000.0, "a lens phase"),
}
#: keys that may be absent from a visual.json (older firmware) and their defaults
_OPTIONAL_DEFAULTS = {"fringe": 0.0, "verticalAngle": 0.0, "flipImageX": 0.0, "flipImageY": 0.0,
                      "flipSubp": 0.0}


@dataclass(frozen=True)
class QuiltLayout:
    """Quilt geometry: ``cols`` x ``rows`` tiles in a ``width`` x ``height`` pixel image.

    Tiles are ``tile_width = width // cols`` by ``tile_height = height // rows`` pixels; when the
    quilt is not an exact multiple, the unused pixels are the top rows and right columns
    (tiles start at the bottom-left corner, as in the GL texture with ``viewPortion``).
    """

    cols: int
    rows: int
    width: int
    height: int
    aspect: float

    def __post_init__(self) -> None:
        for name in ("cols", "rows", "width", "height"):
            v = getattr(self, name)
            if not isinstance(v, (int,)) or isinstance(v, bool) or v <= 0:
                raise CalibrationError(f"quilt layout {name}: expected a positive integer, found {v!r}")
        if self.width // self.cols < 1 or self.height // self.rows < 1:
            raise CalibrationError(f"quilt layout: {self.cols}x{self.rows} tiles do not fit in "
                                   f"{self.width}x{self.height} pixels")
        if not (math.isfinite(self.aspect) and self.aspect > 0):
            raise CalibrationError(f"quilt layout aspect: expected a positive number, found {self.aspect!r}")

    @property
    def n_views(self) -> int:
        return self.cols * self.rows

    @property
    def tile_width(self) -> int:
        return self.width // self.cols

    @property
    def tile_height(self) -> int:
        return self.height // self.rows


@dataclass(frozen=True)
class DevicePreset:
    """A device family: serial prefix, screen, nominal optics and the default quilt layout."""

    name: str
    serial_prefix: str
    screen_w: int
    screen_h: int
    dpi: float
    view_cone: float
    quilt: QuiltLayout
    pitch: float
    slope: float
    center: float
    inv_view: bool = True
    source: str = ""


def _layout(cols: int, rows: int, size_w: int, size_h: int, screen_w: int, screen_h: int) -> QuiltLayout:
    return QuiltLayout(cols, rows, size_w, size_h, round(screen_w / screen_h, 4))


_PORTRAIT_LENS = (52.594383239746094, -7.21152925491333, 0.40277382731437683)
_GEN1_LENS = (47.58427, -5.420652, 0.042)

#: Presets keyed by short name. Lenticular values are nominal (see module docstring).
PRESETS: dict[str, DevicePreset] = {
    "portrait": DevicePreset("Looking Glass Portrait", "LKG-P", 1536, 2048, 324.0, 40.0,
                             _layout(8, 6, 3360, 3360, 1536, 2048), *_PORTRAIT_LENS,
                             source="fixture visual.json; webxr LookingGlassConfig.ts"),
    "go": DevicePreset("Looking Glass Go", "LKG-E", 1440, 2560, 490.0, 54.0,
                       _layout(11, 6, 4092, 4092, 1440, 2560), *_PORTRAIT_LENS,
                       source="webxr LookingGlassConfig.ts; Unreal plugin default (cone 54); DPI derived (6.0 in)"),
    "16in-gen2": DevicePreset('Looking Glass 16" Gen2', "LKG-A", 3840, 2160, 283.0, 40.0,
                              _layout(5, 9, 4096, 4096, 3840, 2160), *_GEN1_LENS,
                              source="webxr LookingGlassConfig.ts; DPI derived (15.6 in)"),
    "32in-gen2": DevicePreset('Looking Glass 32" Gen2', "LKG-B", 7680, 4320, 280.0, 40.0,
                              _layout(5, 9, 8192, 8192, 7680, 4320), *_GEN1_LENS,
                              source="webxr LookingGlassConfig.ts; DPI derived (31.5 in)"),
    "65in": DevicePreset('Looking Glass 65"', "LKG-D", 7680, 4320, 136.0, 40.0,
                         _layout(8, 9, 8192, 8192, 7680, 4320), *_GEN1_LENS,
                         source="webxr LookingGlassConfig.ts; DPI derived (65 in)"),
    "gen1-8.9in": DevicePreset('Looking Glass 8.9" (Gen1)', "LKG-2K", 2560, 1600, 338.0, 40.0,
                               _layout(5, 9, 4096, 4096, 2560, 1600), *_GEN1_LENS,
                               source="dormon/3DApps holoCalibration.h; webxr LookingGlassConfig.ts"),
    "gen1-15.6in": DevicePreset('Looking Glass 15.6" (Gen1)', "LKG-4K", 3840, 2160, 283.0, 40.0,
                                _layout(5, 9, 4096, 4096, 3840, 2160), *_GEN1_LENS,
                                source="webxr LookingGlassConfig.ts; DPI derived (15.6 in)"),
    "gen1-8k": DevicePreset('Looking Glass 8K (Gen1)', "LKG-8K", 7680, 4320, 280.0, 40.0,
                            _layout(5, 9, 8192, 8192, 7680, 4320), *_GEN1_LENS,
                            source="webxr LookingGlassConfig.ts; DPI derived (31.5 in)"),
}


def preset_for_serial(serial: str) -> DevicePreset | None:
    """The preset whose serial prefix matches ``serial`` (longest prefix wins), or ``None``."""
    best = None
    for p in PRESETS.values():
        if serial.upper().startswith(p.serial_prefix) and (best is None or len(p.serial_prefix) > len(best.serial_prefix)):
            best = p
    return best


def _unwrap(raw: Mapping[str, Any], key: str, source: str) -> Any:
    val = raw[key]
    if isinstance(val, Mapping):
        if "value" not in val:
            raise CalibrationError(f"{source}: field '{key}': expected a number or {{\"value\": number}}, "
                                   f"found an object without 'value'")
        val = val["value"]
    return val


def _number(raw: Mapping[str, Any], key: str, source: str) -> float:
    if key not in raw:
        if key in _OPTIONAL_DEFAULTS:
            return _OPTIONAL_DEFAULTS[key]
        raise CalibrationError(f"{source}: field '{key}' is missing (expected a number)")
    val = _unwrap(raw, key, source)
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise CalibrationError(f"{source}: field '{key}': expected a number, found {val!r}")
    val = float(val)
    if not math.isfinite(val):
        raise CalibrationError(f"{source}: field '{key}': expected a finite number, found {val}")
    return val


@dataclass(frozen=True)
class DisplayCalibration:
    """One Looking Glass panel: lenticular calibration, screen and quilt layout.

    Attributes
    ----------
    pitch : float
        Lenticules per inch along the lens normal (``visual.json`` ``pitch``).
    slope : float
        Lens slant: screen rows per pixel of horizontal lens shift (non-zero; sign = direction).
    center : float
        Lens phase offset (fraction of one lens period).
    fringe, vertical_angle : float
        Stored but unused by the shader.
    view_cone : float
        Angle in degrees between the first and the last view.
    inv_view : bool
        Lens direction: True when the view index decreases with the lens phase.
    dpi : float
        Pixels per inch of the panel (> 0).
    screen_w, screen_h : int
        Native resolution in pixels (the fullscreen window size).
    flip_image_x, flip_image_y, flip_subp : bool
        Mirror flags (see :mod:`holo_viewer.display.lenticular` for how each is applied).
    serial : str
        Device serial, e.g. ``LKG-P01234``; selects the quilt layout.
    quilt : QuiltLayout
        Default quilt layout of the device family.
    nominal : bool
        True for a preset (not a measured calibration).
    """

    pitch: float
    slope: float
    center: float
    view_cone: float
    dpi: float
    screen_w: int
    screen_h: int
    quilt: QuiltLayout
    inv_view: bool = True
    fringe: float = 0.0
    vertical_angle: float = 0.0
    flip_image_x: bool = False
    flip_image_y: bool = False
    flip_subp: bool = False
    serial: str = ""
    nominal: bool = False
    source: str = ""

    def __post_init__(self) -> None:
        src = self.source or "calibration"
        for name in ("pitch", "slope", "center", "view_cone", "dpi", "fringe", "vertical_angle"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise CalibrationError(f"{src}: field '{name}': expected a finite number, found {v!r}")
            object.__setattr__(self, name, float(v))
        for name, key in (("pitch", "pitch"), ("dpi", "DPI"), ("center", "center")):
            low, high, unit = LIMITS[name]
            v = getattr(self, name)
            if not low <= v <= high:
                raise CalibrationError(f"{src}: field '{key}': expected {unit} in [{low:g}, {high:g}], found {v:g}")
        low, high, unit = LIMITS["slope"]
        if not low <= abs(self.slope) <= high:
            raise CalibrationError(f"{src}: field 'slope': expected {unit} with magnitude in [{low:g}, {high:g}], "
                                   f"found {self.slope:g}")
        if not (0 < self.view_cone < 180):
            raise CalibrationError(f"{src}: field 'viewCone': expected degrees in (0, 180), found {self.view_cone}")
        for name, key in (("screen_w", "screenW"), ("screen_h", "screenH")):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v != int(v) or not (1 <= v <= MAX_SCREEN_SIDE):
                raise CalibrationError(f"{src}: field '{key}': expected a positive integer number of "
                                       f"pixels (<= {MAX_SCREEN_SIDE}), found {v!r}")
            object.__setattr__(self, name, int(v))
        if self.screen_w * self.screen_h > MAX_SCREEN_PIXELS:
            raise CalibrationError(f"{src}: fields 'screenW', 'screenH': expected at most {MAX_SCREEN_PIXELS:,} pixels "
                                   f"(the largest Looking Glass, 7680 x 4320), found {self.screen_w} x {self.screen_h}")
        for name in ("inv_view", "flip_image_x", "flip_image_y", "flip_subp", "nominal"):
            object.__setattr__(self, name, bool(getattr(self, name)))
        lenses = self.pitch * self.screen_w / self.dpi * math.cos(math.atan(1.0 / self.slope))
        if not 1.0 <= lenses <= self.screen_w:
            raise CalibrationError(f"{src}: fields 'pitch', 'DPI', 'slope', 'screenW': expected between 1 and screenW "
                                   f"({self.screen_w}) lenticules across the screen (pitch * screenW / DPI * "
                                   f"cos(atan(1 / slope))), found {lenses:.4g}")
        if not isinstance(self.quilt, QuiltLayout):
            raise CalibrationError(f"{src}: quilt: expected a QuiltLayout, found {type(self.quilt).__name__}")

    # ----------------------------------------------------------------- derived
    @property
    def cols(self) -> int:
        return self.quilt.cols

    @property
    def rows(self) -> int:
        return self.quilt.rows

    @property
    def n_views(self) -> int:
        return self.quilt.n_views

    @property
    def quilt_width(self) -> int:
        return self.quilt.width

    @property
    def quilt_height(self) -> int:
        return self.quilt.height

    @property
    def tile_width(self) -> int:
        return self.quilt.tile_width

    @property
    def tile_height(self) -> int:
        return self.quilt.tile_height

    @property
    def aspect(self) -> float:
        """Width / height of the screen (and of each quilt view)."""
        return self.screen_w / self.screen_h

    @property
    def physical_size_m(self) -> tuple[float, float]:
        """(width, height) of the active area in metres."""
        return self.screen_w / self.dpi * 0.0254, self.screen_h / self.dpi * 0.0254

    @property
    def model(self) -> str:
        p = preset_for_serial(self.serial)
        return p.name if p is not None else "unknown Looking Glass model"

    def with_quilt(self, cols: int, rows: int, width: int | None = None, height: int | None = None) -> "DisplayCalibration":
        """A copy with another quilt layout (same aspect)."""
        w = width if width is not None else self.quilt.width
        h = height if height is not None else self.quilt.height
        return replace(self, quilt=QuiltLayout(int(cols), int(rows), int(w), int(h), self.quilt.aspect))

    def summary(self) -> str:
        """One line: model, serial, screen, lens values and quilt layout."""
        q = self.quilt
        return (f"{self.model} serial={self.serial or '?'} screen={self.screen_w}x{self.screen_h}@{self.dpi:g}dpi "
                f"pitch={self.pitch:.4f} slope={self.slope:.4f} center={self.center:.4f} "
                f"viewCone={self.view_cone:g} invView={int(self.inv_view)} flipX={int(self.flip_image_x)} "
                f"flipY={int(self.flip_image_y)} flipSubp={int(self.flip_subp)} "
                f"quilt={q.cols}x{q.rows} {q.width}x{q.height} tiles {q.tile_width}x{q.tile_height}"
                + (" (nominal preset)" if self.nominal else ""))

    def to_json(self) -> dict[str, Any]:
        """visual.json dictionary (values wrapped as {"value": x})."""
        out: dict[str, Any] = {"configVersion": "3.0", "serial": self.serial}
        for key, (attr, kind) in JSON_FIELDS.items():
            v = getattr(self, attr)
            out[key] = {"value": float(v)}
        return out

    # ------------------------------------------------------------ constructors
    @classmethod
    def from_json(cls, data: Mapping[str, Any] | str, *, source: str = "visual.json",
                  quilt: QuiltLayout | None = None) -> "DisplayCalibration":
        """Parse a visual.json dictionary (values wrapped as ``{"value": x}`` or flat) or JSON text.

        The quilt layout comes from ``quilt`` or the serial-number prefix (Portrait 8x6 when unknown).

        Raises
        ------
        CalibrationError
            Naming the field that is missing, non-numeric or out of range.
        """
        if isinstance(data, (str, bytes)):
            from ..fileio import parse_json

            data = parse_json(data, CalibrationError, source, "calibration JSON")
        if not isinstance(data, Mapping):
            raise CalibrationError(f"{source}: expected a JSON object, found {type(data).__name__}")
        vals: dict[str, Any] = {}
        for key, (attr, kind) in JSON_FIELDS.items():
            v = _number(data, key, source)
            if kind == "flag":
                if v not in (0.0, 1.0):
                    raise CalibrationError(f"{source}: field '{key}': expected 0 or 1, found {v:g}")
                v = bool(v)
            vals[attr] = v
        serial = data.get("serial", "")
        if isinstance(serial, Mapping):
            serial = serial.get("value", "")
        if not isinstance(serial, str):
            raise CalibrationError(f"{source}: field 'serial': expected a string, found {serial!r}")
        if quilt is None:
            p = preset_for_serial(serial) or PRESETS["portrait"]
            quilt = p.quilt
        for key, attr in (("screenW", "screen_w"), ("screenH", "screen_h")):
            v = vals[attr]
            if v != int(v) or v < 1:
                raise CalibrationError(f"{source}: field '{key}': expected a positive integer number of pixels, "
                                       f"found {v:g}")
        quilt = replace(quilt, aspect=round(vals["screen_w"] / vals["screen_h"], 4))
        return cls(quilt=quilt, serial=serial, source=source, **vals)

    @classmethod
    def from_file(cls, path: str | os.PathLike, *, quilt: QuiltLayout | None = None) -> "DisplayCalibration":
        """Read a visual.json file."""
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8-sig")
        except FileNotFoundError as exc:
            raise CalibrationError(f"{p}: calibration file not found") from exc
        except (OSError, UnicodeDecodeError) as exc:
            raise CalibrationError(f"{p}: cannot read calibration ({exc})") from exc
        return cls.from_json(text, source=str(p), quilt=quilt)

    @classmethod
    def preset(cls, name: str) -> "DisplayCalibration":
        """Nominal calibration of a device family (``portrait``, ``go``, ``16in-gen2``, ...).

        ``name`` may also be a serial number or prefix (``LKG-P...``).
        """
        key = name.lower().replace('"', "in").replace(" ", "-")
        p = PRESETS.get(key) or preset_for_serial(name)
        if p is None:
            raise CalibrationError(f"preset: expected one of {sorted(PRESETS)} or a serial prefix, found {name!r}")
        return cls(pitch=p.pitch, slope=p.slope, center=p.center, view_cone=p.view_cone, dpi=p.dpi,
                   screen_w=p.screen_w, screen_h=p.screen_h, quilt=p.quilt, inv_view=p.inv_view,
                   serial=p.serial_prefix, nominal=True, source=f"preset {key}")

    @classmethod
    def for_serial(cls, serial: str) -> "DisplayCalibration":
        """Nominal calibration for a device serial (its family preset, keeping the serial)."""
        p = preset_for_serial(serial)
        if p is None:
            raise CalibrationError(f"serial: no preset matches {serial!r}; known prefixes: "
                                   f"{sorted(q.serial_prefix for q in PRESETS.values())}")
        return replace(cls.preset(p.serial_prefix), serial=serial)

    @classmethod
    def load(cls, spec: "str | os.PathLike | DisplayCalibration | None") -> "DisplayCalibration":
        """A calibration from a file path, a preset name, an instance, or ``None`` (the shipped
        Portrait fixture ``assets/lkg_portrait_visual.json``)."""
        if isinstance(spec, DisplayCalibration):
            return spec
        if spec is None:
            return cls.from_file(default_calibration_path())
        s = str(spec)
        if os.path.exists(s) or s.endswith(".json"):
            return cls.from_file(s)
        return cls.preset(s)


def default_calibration_path() -> Path:
    """Path of the shipped Portrait calibration (``assets/lkg_portrait_visual.json``)."""
    return Path(__file__).resolve().parents[2] / "assets" / "lkg_portrait_visual.json"

