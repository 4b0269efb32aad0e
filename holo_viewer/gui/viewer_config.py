"""The viewer's settings and its key table (what ``h`` shows)."""

from __future__ import annotations

from dataclasses import dataclass


from ..errors import InputError
from .scene import GLYPH_COLOR_MODES

__all__ = ["ViewerConfig", "HELP_TEXT", "KEYS", "MOUSE_HELP"]

KEYS: tuple[tuple[str, str, str], ...] = (
    ("h", "h", "this help on / off"),
    ("q", "q", "quit (waits for running exports)"),
    ("m", "m", "FLAME mesh on / off"),
    ("l", "l", "mesh wireframe on / off"),
    ("g", "g", "Gaussian ellipsoids on / off"),
    ("c", "c", "ellipsoid colour: own / opacity / size"),
    ("o", "o", "cameras, frusta, focal plane on / off"),
    ("s", "s", "splats (Gaussians rendered) behind the scene on / off"),
    ("v", "v", "look through the selected view's camera / free camera"),
    ("p", "p", "upper panel: selected view / native image / eye's view"),
    ("bracketright", "] [", "zoom the native image in / out"),
    ("bracketleft", "", ""),
    ("r", "r", "camera: back to head + all cameras"),
    ("z", "z", "camera: close-up of the head"),
    ("0", "0", "face back to neutral"),
    ("Left", "<- ->", "previous / next view"),
    ("Right", "", ""),
    ("Return", "Return", "type a value (pain 0.6), Esc cancels"),
    ("k", "k", "export the quilt PNG"),
    ("n", "n", "export the native (lenticular) PNG"),
    ("x", "x", "export smile-sweep mp4s (quilt + native)"),
    ("X", "X", "export pain-sweep mp4s (quilt + native)"),
    ("i", "i", "save a screenshot PNG"),
    ("braceright", "} {", "image panels wider / narrower (the scene gives way)"),
    ("braceleft", "", ""),
)


MOUSE_HELP = (
    ("left drag", "rotate"), ("shift + left drag", "pan"), ("ctrl + left drag", "spin"),
    ("right drag, wheel", "zoom"), ("middle drag", "pan"), ("click a camera", "select its view"),
)


def _help_text() -> str:
    lines = ["keys"]
    lines += [f" {shown:<7}{what}" for _, shown, what in KEYS if shown]
    lines += ["mouse (3D scene only)"]
    lines += [f" {k:<18}{v}" for k, v in MOUSE_HELP]
    lines += ["face, camera, view sliders act while dragging;", "Gaussians, preview, quilt on release"]
    return "\n".join(lines)


HELP_TEXT = _help_text()



@dataclass(frozen=True)
class ViewerConfig:
    """Viewer settings.

    Attributes
    ----------
    window_size : (int, int) or None
        Window width, height in pixels (the layout stays readable down to 800 x 450). None (the
        default): sized to the X screen (:func:`~holo_viewer.gui.screen.window_size_for_screen`),
        1400 x 800 offscreen or when the screen size is unknown.
    n_expr_sliders : int
        Number of expression-component sliders: the components named ``expr_names`` when the model
        names its components (the default head: action units, range 0..1.5), else the first ones
        (range +-``expr_range`` standard deviations).
    max_glyphs : int
        Gaussians drawn as ellipsoids (a deterministic random subset keeps it interactive);
        ``holo-viewer view`` and ``snapshot`` use this default.
    glyph_sigmas : float
        Ellipsoid radius in standard deviations.
    glyph_min_opacity : float
        Only Gaussians at least this opaque are drawn (faint ones read as dark speckles).
    glyph_color : str
        ``"colour"`` (own DC colour), ``"opacity"`` or ``"size"`` (:func:`~.scene.glyph_colors`).
    glyph_subdivisions : int
        Icosphere subdivisions of each ellipsoid (0: 20 triangles; software OpenGL pays per triangle).
    preview_scale, thumbnail_scale : float
        Size of the preview view and of the thumbnail quilt's tiles relative to the quilt tile.
    auto_thumbnail : bool
        Re-render the thumbnail quilt after every slider release.
    live_sliders : bool
        Face and camera sliders update the mesh / frusta while dragging (else on release only).
    sweep_frames, sweep_scale, sweep_fps : int, float, float
        Frames, tile scale and frame rate of the expression-sweep video.
    out_dir : str
        Folder of exports.
    show_status : bool
        Show the status line (timings, exports); snapshots leave it out to stay reproducible.
    multi_samples : int
        MSAA samples (pyvista's default 8 costs ~3x per frame with software OpenGL; 0 = off).
    splat_view : bool
        Render the Gaussians from the scene's camera behind the overlays (key ``s``); the mesh and the
        ellipsoids then start hidden (``m``, ``g``) and the scene starts on the face (``z``).
    splat_drag_scale : float
        Splat image resolution while the scene camera is dragged, relative to the scene's pixels.
    partial_present : bool
        A frame copies only the panels it drew to the X window (:mod:`~holo_viewer.gui.present`: ~18 ms
        CPU less per partial frame at 1600 x 928 with software OpenGL); False: VTK copies every frame whole.
    standin_reduction : float
        Fraction of the mesh's triangles left out of the stand-in mesh drawn while a face slider is dragged
        with the splats on (:func:`~holo_viewer.gui.scene.decimated_faces`; the whole mesh returns on
        release). 0: the whole mesh. Meshes under 20,000 triangles are drawn whole.
    """

    window_size: tuple[int, int] | None = None
    n_expr_sliders: int = 4
    expr_names: tuple[str, ...] = ("AU2_L", "AU4", "AU9", "AU20")
    expr_range: float = 2.0
    max_glyphs: int = 2500
    glyph_sigmas: float = 1.5
    glyph_min_opacity: float = 0.5
    glyph_color: str = "colour"
    glyph_subdivisions: int = 0
    preview_scale: float = 0.4
    thumbnail_scale: float = 0.125
    auto_thumbnail: bool = True
    live_sliders: bool = True
    sweep_frames: int = 16
    sweep_scale: float = 0.5
    sweep_fps: float = 8.0
    out_dir: str = "holo_viewer_out"
    title: str = "holo-viewer  (press h for help)"
    show_status: bool = True
    multi_samples: int = 0
    splat_view: bool = True
    splat_drag_scale: float = 0.35
    partial_present: bool = True
    standin_reduction: float = 0.5

    def __post_init__(self) -> None:
        if self.window_size is not None and (len(self.window_size) != 2 or min(self.window_size) < 1):
            raise InputError(f"window_size: expected (width, height) >= 1 pixel, found {self.window_size!r}")
        if not 0.0 <= self.standin_reduction < 1.0:
            raise InputError(f"standin_reduction: expected in [0, 1), found {self.standin_reduction}")
        if not 0.05 <= self.splat_drag_scale <= 1.0:
            raise InputError(f"splat_drag_scale: expected in [0.05, 1], found {self.splat_drag_scale}")
        if self.glyph_color not in GLYPH_COLOR_MODES:
            raise InputError(f"glyph_color: expected one of {GLYPH_COLOR_MODES}, found {self.glyph_color!r}")
        if not 0.0 <= self.glyph_min_opacity < 1.0:
            raise InputError(f"glyph_min_opacity: expected in [0, 1), found {self.glyph_min_opacity}")
        if not self.glyph_sigmas > 0 or self.max_glyphs < 1:
            raise InputError(f"max_glyphs >= 1 and glyph_sigmas > 0 expected, found {self.max_glyphs}, "
                             f"{self.glyph_sigmas}")

