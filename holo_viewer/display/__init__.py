"""Looking Glass output: calibration, Algorithm 1 cameras, quilts, lenticular interleave, virtual
display, USB device reading, fullscreen window and export.

Only the pure-math names are imported here (cheap); ``usb``, ``window`` and ``export`` are
imported from their modules when needed.
"""

from .calibration import PRESETS, DevicePreset, DisplayCalibration, QuiltLayout, preset_for_serial
from .cameras import fov_for_viewer_distance, make_quilt_cameras, quilt_cameras_to_opengl, sdk_view_projection
from .lenticular import Interleaver, interleave, interleave_reference, reference_views
from .quilt import parse_quilt_filename, quilt_filename, split_quilt, tile_quilt
from .simulate import VirtualDisplay, identify_bar, id_pattern_views

__all__ = [
    "DisplayCalibration", "QuiltLayout", "DevicePreset", "PRESETS", "preset_for_serial",
    "make_quilt_cameras", "fov_for_viewer_distance", "sdk_view_projection", "quilt_cameras_to_opengl",
    "tile_quilt", "split_quilt", "quilt_filename", "parse_quilt_filename",
    "Interleaver", "interleave", "interleave_reference", "reference_views",
    "VirtualDisplay", "id_pattern_views", "identify_bar",
]
