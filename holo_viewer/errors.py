"""Exception hierarchy of holo_viewer.

Every error the package raises on bad input derives from :class:`HoloViewerError`.
Messages name the file or field, what was expected and what was found, e.g.::

    InputError: expr: expected shape (B, 100), found (4, 120)

Subclasses group errors by area so callers can catch one area at a time.
``InputError`` also derives from :class:`ValueError` and the file errors from
:class:`OSError`-agnostic ``HoloViewerError`` so that generic handlers still work.
"""

from __future__ import annotations

__all__ = [
    "HoloViewerError",
    "InputError",
    "FlameError",
    "AvatarError",
    "PlyError",
    "RenderError",
    "CalibrationError",
    "DeviceError",
    "DisplayError",
    "ReactionError",
    "ExportError",
    "MissingDependencyError",
    "ManifestError",
    "TrackingError",
]


class HoloViewerError(Exception):
    """Base class of every error raised by holo_viewer."""


class InputError(HoloViewerError, ValueError):
    """An argument has the wrong shape, dtype, range, or holds NaN/inf."""


class FlameError(HoloViewerError):
    """A FLAME model file is missing keys, has inconsistent sizes, or cannot be read."""


class AvatarError(HoloViewerError):
    """A Gaussian avatar is inconsistent (bindings, sizes, blend shapes)."""


class PlyError(AvatarError):
    """A PLY file is truncated, corrupt, or lacks the fields 3DGS needs."""


class RenderError(HoloViewerError):
    """A renderer backend cannot render the given scene or cameras."""


class CalibrationError(HoloViewerError):
    """A display calibration (visual.json or preset) is missing or invalid."""


class DeviceError(HoloViewerError):
    """A Looking Glass device could not be found, opened or read."""


class DisplayError(HoloViewerError):
    """The native image cannot be shown (no matching monitor, no display)."""


class ReactionError(HoloViewerError):
    """Bad data or configuration for the listener-reaction model."""


class ExportError(HoloViewerError):
    """A quilt, image or video could not be written."""


class ManifestError(InputError):
    """A batch manifest row is malformed: its message names the file, line, field, expected and found."""


class TrackingError(HoloViewerError):
    """Face tracking failed or got bad frames, landmarks or tracking settings."""


class MissingDependencyError(HoloViewerError, ImportError):
    """An optional dependency needed by the requested feature is not installed."""

    def __init__(self, package: str, feature: str, extra: str | None = None) -> None:
        hint = (f'pip install -e ".[{extra}]" in a source checkout (pip install "holo_viewer[{extra}]" from '
                f'an index)' if extra else f"pip install {package}")
        super().__init__(f"{feature} needs the optional package '{package}', which is not installed; "
                         f"install it with: {hint}")
        self.package = package
