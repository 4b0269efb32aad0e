"""The PyVista viewer: a real window under Xvfb (started by a fixture) driven by real X input
(xdotool key presses, mouse drags and wheel turns against the window, processed by the viewer's
own event loop), plus direct callback calls; the offscreen (OSMesa) snapshot against a golden
image; the command line (no display, --toolkit, shared ellipsoid options); the Open3D error path.
Tests that need Xvfb or xdotool skip with a message naming the apt package.

The scene is a small seeded FLAME-format model (``flame.synthetic``) with a few hundred Gaussians
bound to its triangles, so the tests run in seconds and do not change when the default head
or avatar is retuned. Regenerate the golden image with ``HOLO_UPDATE_GOLDEN=1``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.gui

GOLDEN = Path(__file__).parent / "golden" / "viewer_snapshot.png"
GOLDEN_SIZE = (640, 360)


def _small_panel():
    """The shipped Portrait calibration's optics on a 384 x 512 panel (1/16 of its subpixels, the same aspect,
    so the same quilt): the exports' and the panel's native images cost 1/16 as much. The tests that use it
    check the viewer's native images against the calibration they were made for, not the Portrait's size
    (test_views_to_native.py and test_golden_images.py check the full-size chain)."""
    import dataclasses

    from holo_viewer.display.calibration import DisplayCalibration

    return dataclasses.replace(DisplayCalibration.load(None), screen_w=384, screen_h=512)


def _small_scene(tile_scale: float = 0.25, seed: int = 0, calibration=None):
    from holo_viewer.avatar import Gaussians, RiggedAvatar
    from holo_viewer.flame.model import FlameModel
    from holo_viewer.flame.synthetic import random_flame_arrays
    from holo_viewer.pipeline import Pipeline, ViewSettings

    model = FlameModel.from_arrays(random_flame_arrays(n_vertices=300, n_shape=8, n_expr=6, seed=1))
    rng = np.random.default_rng(seed)
    n, F = 500, int(model.faces.shape[0])
    local = Gaussians(
        means=rng.normal(scale=0.2, size=(n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        log_scales=np.log(rng.uniform(0.1, 0.4, size=(n, 3))).astype(np.float32),
        opacity_logits=rng.normal(2.0, 0.5, size=n).astype(np.float32),
        sh=rng.normal(scale=0.6, size=(n, 4, 3)).astype(np.float32),
        extra={"binding": rng.integers(0, F, size=n).astype(np.int64)},
    )
    return Pipeline(model=model, avatar=RiggedAvatar(model, local), calibration=calibration,
                    view=ViewSettings(tile_scale=tile_scale))


# ------------------------------------------------------------------ Xvfb fixture


@pytest.fixture(scope="module")
def xvfb(xvfb_server):
    """An Xvfb display for this module, DISPLAY pointed at it (VTK's offscreen override removed)."""
    with xvfb_server("1920x1080x24") as display:
        old = os.environ.get("DISPLAY")
        old_win = os.environ.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
        os.environ["DISPLAY"] = display
        try:
            yield display
        finally:
            if old is None:
                os.environ.pop("DISPLAY", None)
            else:
                os.environ["DISPLAY"] = old
            if old_win is not None:
                os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = old_win


@pytest.fixture()
def window(xvfb, tmp_path):
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    cfg = ViewerConfig(window_size=(960, 540), out_dir=str(tmp_path / "exports"), sweep_frames=3,
                       sweep_scale=0.1, thumbnail_scale=0.1, preview_scale=0.5, splat_view=False)
    viewer = HoloViewer(_small_scene(calibration=_small_panel()), cfg)
    viewer.open()  # map the window without entering the event loop
    viewer.wait_for_thumbnail()  # the window shows it after its first frame; the tests want it there
    yield viewer
    viewer.close()


def _fire_slider(widget, value: float) -> None:
    """What a user's drag-and-release does: set the value, then EndInteractionEvent."""
    widget.GetRepresentation().SetValue(value)
    widget.InvokeEvent("EndInteractionEvent")


def _press(viewer, key: str) -> None:
    """A key event injected into VTK (no X server round trip): KeyPress then Char, as X delivers them."""
    iren = viewer.plotter.iren.interactor
    iren.SetKeySym(key)
    iren.SetKeyCode(key if len(key) == 1 else "\0")
    iren.InvokeEvent("KeyPressEvent")
    iren.InvokeEvent("CharEvent")


# ------------------------------------------------------------------ real X input (xdotool)


@pytest.fixture(scope="module")
def xdotool(xvfb, xdotool_exe):
    return xdotool_exe


@pytest.fixture(scope="module")
def xdotool_exe():
    exe = shutil.which("xdotool")
    if exe is None:
        pytest.skip("xdotool is not installed (apt-get install xdotool); the real-input tests send X key presses "
                    "and mouse drags with it")
    return exe


class XInput:
    """Real X events for a viewer's window: xdotool moves the pointer / presses keys through the
    XTEST extension, the X server delivers them to the window under the pointer, and the viewer's
    event loop (``viewer.run``) processes them."""

    def __init__(self, exe: str, viewer) -> None:
        self.exe, self.viewer = exe, viewer
        self.wid = str(viewer.window_id())

    def xdo(self, *args) -> None:
        subprocess.run([self.exe, *map(str, args)], check=True, timeout=10)

    def settle(self, until=None, timeout: float = 0.4) -> bool:
        return self.viewer.run(until=until, timeout=timeout)

    def sync(self, timeout: float = 5.0) -> None:
        """Run the viewer's loop until every X event sent so far is handled (at most ``timeout`` s), instead of
        a fixed wait. xdotool ends with XCloseDisplay (an XSync): the server has taken its fake input; the
        server handles queued input before the next client request, so the viewer's own XSync reply comes
        after those events, which Xlib then holds (XPending); ``step`` handles them and draws the frame.
        Without an X connection (no ``_input_wait``): the old fixed wait."""
        import ctypes

        w = self.viewer._input_wait
        if w is None:
            self.settle(timeout=0.4)
            return
        w._x11.XSync.argtypes = [ctypes.c_void_p, ctypes.c_int]
        w._x11.XSync(w._display, 0)
        end = time.perf_counter() + timeout
        while self.viewer.step() and w._x11.XPending(w._display) > 0 and time.perf_counter() < end:
            pass
        self.viewer.step()  # the frame the last events asked for (step draws when something is dirty)

    def next_frame(self, timeout: float = 30.0) -> bool:
        """Step the viewer's loop until it draws its next frame (at most ``timeout`` s). A camera drag's frame
        waits for the splat worker's image (``SPLAT_HOLD_S`` up to ``SPLAT_HOLD_MAX_S``; later under load);
        not :meth:`settle`: ``run`` first draws every panel (``HoloViewer.open`` on an open window)."""
        drawn = self.viewer.frames_drawn
        end = time.perf_counter() + timeout
        while self.viewer.frames_drawn == drawn and time.perf_counter() < end:
            self.viewer.step()
            if self.viewer.frames_drawn == drawn:
                self.viewer.wait_for_input(0.004)
        return self.viewer.frames_drawn > drawn

    def move(self, x: int, y: int) -> None:
        self.xdo("mousemove", "--window", self.wid, int(x), int(y))

    def key(self, *keys: str, until=None, timeout: float | None = None) -> bool:
        """Press ``keys``; then the loop runs until ``until()`` (``timeout`` s, default 0.5) or, with neither
        given, until the presses are handled (:meth:`sync`)."""
        for k in keys:
            self.xdo("key", k)
        if until is None and timeout is None:
            self.sync()
            return False
        return self.settle(until, 0.5 if timeout is None else timeout)

    def type(self, text: str) -> None:
        names = {" ": "space", ".": "period", "-": "minus", "_": "underscore"}
        for ch in text:
            self.xdo("key", names.get(ch, ch))

    def drag(self, start, end, button: int = 1, steps: int = 4, during=None) -> None:
        self.move(*start)
        self.xdo("mousedown", button)
        self.sync()
        for k in range(1, steps + 1):
            self.move(start[0] + (end[0] - start[0]) * k // steps, start[1] + (end[1] - start[1]) * k // steps)
            self.sync()
        if during is not None:
            during()
        self.xdo("mouseup", button)
        self.sync()

    def wheel(self, at, clicks: int = 3) -> None:
        self.move(*at)
        for _ in range(clicks):
            self.xdo("click", 4)
            self.xdo("click", 5)
            self.xdo("click", 5)
        self.sync()

    def centre(self, panel: str) -> tuple[int, int]:
        x0, y0, x1, y1 = self.viewer.panel_box(panel)
        H = self.viewer.plotter.ren_win.GetSize()[1]
        return (x0 + x1) // 2, H - 1 - (y0 + y1) // 2


@pytest.fixture()
def xin(window, xdotool):
    x = XInput(xdotool, window)
    x.move(*x.centre("scene"))
    x.settle()
    return x


def _head_screen_box(viewer) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) display pixels around the mesh as the scene camera projects it (y from the bottom)."""
    ren = viewer.scene_renderer
    xy = []
    for p in viewer.pipeline.mesh()[::5]:
        ren.SetWorldPoint(*p, 1.0)
        ren.WorldToDisplay()
        xy.append(ren.GetDisplayPoint()[:2])
    xy = np.array(xy)
    return (*xy.min(axis=0), *xy.max(axis=0))


def _camera_state(renderer):
    cam = renderer.GetActiveCamera()
    return (cam.GetPosition(), cam.GetFocalPoint(), cam.GetViewUp(), cam.GetParallelScale(), cam.GetViewAngle())


# ------------------------------------------------------------------ interactive window


def test_window_opens_on_the_x_display(window, xvfb):
    rw = window.plotter.ren_win
    assert "OSOpenGL" not in rw.GetClassName()  # a real on-screen window, not OSMesa
    assert rw.GetSize()[0] == 960
    img = window.screenshot()
    assert img.shape[:2] == (540, 960)
    assert img.std() > 10  # not a blank window
    assert len(window.sliders) >= 9


def test_slider_changes_mesh_and_preview(window):
    drawn = window.mesh_actor.mapper.dataset  # the polydata VTK draws
    mesh_before = np.array(drawn.points)
    preview_before = window.preview_panel.image.copy()
    shot_before = window.screenshot()
    _fire_slider(window.sliders["expr0"], 1.5)
    assert window.pipeline.face.expr[0] == pytest.approx(1.5)
    moved = np.linalg.norm(np.array(drawn.points) - mesh_before, axis=1)
    assert moved.max() > 1e-4
    np.testing.assert_allclose(np.array(drawn.points), window.pipeline.mesh(), atol=1e-6)
    assert not np.array_equal(window.preview_panel.image, preview_before)
    assert window.timings.mesh_ms > 0 and window.timings.preview_ms >= window.timings.mesh_ms
    # what the window shows changed too (mesh, glyphs and preview panel)
    shot_after = window.screenshot()
    assert np.abs(shot_after.astype(int) - shot_before).max() > 50
    # the thumbnail quilt renders in a worker process and is shown when done
    window.poll_thumbnail(wait=True)
    assert window.thumb_panel.image is not None


def test_view_sliders_move_frusta_not_mesh(window):
    mesh_v = window.pipeline.stage_version("mesh")
    frusta_before = np.array(window.frusta.points)
    _fire_slider(window.sliders["distance"], 1.2)
    assert window.pipeline.view.viewer_distance == pytest.approx(1.2)
    assert not np.allclose(np.array(window.frusta.points), frusta_before)
    assert window.pipeline.stage_version("mesh") == mesh_v
    _fire_slider(window.sliders["view"], 3)
    assert window.selected_view == 3
    positions = np.array(window.camera_points.points)
    _fire_slider(window.sliders["angle"], 12.0)  # Algorithm 1's cone centre follows the viewer
    assert window.pipeline.view.viewer_angle == pytest.approx(12.0)
    assert np.abs(np.array(window.camera_points.points) - positions).max() > 1e-3
    assert window.pipeline.stage_version("mesh") == mesh_v
    assert window._specs["angle"].value_text.GetInput() == "+12.0"
    assert "nan" not in window.status.GetInput()


def test_keys_write_their_files(window, xin, tmp_path):
    """Real key presses k, n, i, x, X: quilt, native image, screenshot, expression and pain sweeps (each a
    quilt video and a panel video); X needs the model's action-unit map (the synthetic one is given one)."""
    from holo_viewer.fileio import load_image
    from holo_viewer.flame.expressions import AU_NAMES, AUMap

    xin.key("k", "n", "i", "x", "X", timeout=0.3)
    window.wait_exports(timeout=120)
    assert "pain sweep: this FLAME model has no action-unit map" in window.errors[-1]  # X: the synthetic model
    n_expr = window.pipeline.model.n_expr
    window.pipeline.set_au_map(AUMap(names=tuple(AU_NAMES),
                                     matrix=np.random.default_rng(4).normal(scale=0.8, size=(len(AU_NAMES), n_expr))))
    xin.key("X", timeout=0.3)
    window.wait_exports(timeout=120)
    out = sorted(p.name for p in (tmp_path / "exports").iterdir())
    quilts = [n for n in out if n.endswith("_qs8x6a0.75.png")]
    natives = [n for n in out if n.endswith("_native.png")]
    shots = [n for n in out if n.startswith("screenshot")]
    videos = [n for n in out if n.startswith("sweep-expression-") and n.endswith("_qs8x6a0.75.mp4")]
    native_videos = [n for n in out if n.startswith("sweep-expression-") and n.endswith("_native.mp4")]
    pain = [n for n in out if n.startswith("sweep-pain-")]
    assert len(quilts) == 1 and len(natives) == 1 and len(shots) == 1 and len(videos) == 1, out
    assert len(native_videos) == 1 and len(pain) == 2, out
    assert not [n for n in out if ".tmp" in n]  # atomic writes leave no temporaries
    q = load_image(tmp_path / "exports" / quilts[0])
    cams = window.pipeline.cameras()
    assert q.shape == (6 * cams.height, 8 * cams.width, 3)
    nat = load_image(tmp_path / "exports" / natives[0])
    cal = window.pipeline.calibration
    assert nat.shape == (cal.screen_h, cal.screen_w, 3)
    import imageio.v3 as iio

    frames = iio.imread(tmp_path / "exports" / videos[0])
    assert frames.shape[0] == 3
    from holo_viewer.display.lenticular import Interleaver

    panel = iio.imread(tmp_path / "exports" / native_videos[0])  # lossless RGB: the interleaved quilts
    assert panel.shape == (3, cal.screen_h, cal.screen_w, 3)
    assert np.array_equal(panel[1], Interleaver(cal, frames[1].shape, cols=cal.cols, rows=cal.rows)(frames[1]))
    pain_quilts = iio.imread(tmp_path / "exports" / next(n for n in pain if n.endswith("_qs8x6a0.75.mp4")))
    pain_panel = iio.imread(tmp_path / "exports" / next(n for n in pain if n.endswith("_native.mp4")))
    assert pain_quilts.shape == frames.shape and pain_panel.shape == (3, cal.screen_h, cal.screen_w, 3)
    assert np.abs(pain_quilts[1].astype(int) - pain_quilts[0]).mean() > 0.5  # pain 0 -> 1: another face
    assert np.array_equal(pain_panel[1], Interleaver(cal, pain_quilts[1].shape, cols=cal.cols,
                                                     rows=cal.rows)(pain_quilts[1]))


def test_toggles_and_help(window):
    assert not window.help_actor.GetVisibility()
    _press(window, "h")
    assert window.help_actor.GetVisibility()
    _press(window, "m")
    assert not window.mesh_actor.GetVisibility()
    _press(window, "o")
    assert not window.frusta_actor.GetVisibility()
    _press(window, "g")
    assert not window.glyph_actor.GetVisibility()
    _press(window, "l")
    assert window.wireframe


# ------------------------------------------------------------------ real X input: bugs 1-5 of issue 20


def test_i_key_saves_a_screenshot_and_leaves_the_sliders_alone(window, xin):
    """Bug 1: 'i' was VTK's slider activation key; a real key press hid the first slider."""
    reps = {k: (w.GetRepresentation().GetPoint1Coordinate().GetValue(), w.GetEnabled())
            for k, w in window.sliders.items()}
    assert xin.key("i", until=lambda: len(window.exports) == 1, timeout=5)
    assert window.exports[0].name.startswith("screenshot") and window.exports[0].exists()
    assert all(w.GetEnabled() for w in window.sliders.values())  # VTK's 'i' used to disable the first one
    xin.key("i", until=lambda: len(window.exports) == 2, timeout=5)
    assert {k: (w.GetRepresentation().GetPoint1Coordinate().GetValue(), w.GetEnabled())
            for k, w in window.sliders.items()} == reps


def test_builtin_vtk_and_pyvista_keys_do_nothing(window, xin):
    """Bug 3: w wireframe, 3 stereo, e quit, f/p camera and picking, Up/Down/+/- zoom (``s`` and ``v`` are
    ours now: splats and look-through)."""
    scene = _camera_state(window.scene_renderer)
    thumb = _camera_state(window.thumb_panel.renderer)
    shot = window.read_pixels("quilt").copy()
    xin.key("w", "3", "f", "p", "j", "t", "u", "e", "Up", "Down", "plus", "minus", timeout=0.6)
    xin.move(*xin.centre("quilt"))  # the zoom keys used to act on the panel under the pointer
    xin.key("Up", "Up", "plus", "w", timeout=0.6)
    assert not window._quit  # the loop is still running ('e' did not quit; the q test shows _quit is set)
    assert window.mesh_actor.GetProperty().GetRepresentation() == 2  # surface
    assert not window.plotter.ren_win.GetStereoRender()
    assert _camera_state(window.scene_renderer) == scene
    assert _camera_state(window.thumb_panel.renderer) == thumb
    assert np.array_equal(window.read_pixels("quilt"), shot)
    assert not window._quit


def test_image_panels_ignore_the_mouse_and_the_scene_takes_it(window, xin):
    """Bug 4: a drag tilted the preview, the wheel zoomed it; only the 3D scene takes the mouse now."""
    panels = {n: _camera_state(r) for n, r in (("preview", window.preview_panel.renderer),
                                                ("quilt", window.thumb_panel.renderer))}
    shot = window.read_pixels("preview").copy()
    for name in ("preview", "quilt"):
        c = xin.centre(name)
        xin.drag(c, (c[0] + 60, c[1] + 40))
        xin.drag(c, (c[0] - 30, c[1] + 50), button=3)
        xin.wheel(c)
        xin.key("w", "s")
    assert {n: _camera_state(r) for n, r in (("preview", window.preview_panel.renderer),
                                              ("quilt", window.thumb_panel.renderer))} == panels
    assert np.array_equal(window.read_pixels("preview"), shot)
    # the scene rotates with a drag, zooms with the wheel, and 'r' brings the default framing back
    home = _camera_state(window.scene_renderer)
    c = xin.centre("scene")
    xin.drag(c, (c[0] + 80, c[1] + 20))
    rotated = _camera_state(window.scene_renderer)
    assert rotated != home
    xin.wheel(c)
    xin.key("r")
    np.testing.assert_allclose(np.array(_camera_state(window.scene_renderer)[0]), np.array(home[0]), atol=1e-9)
    # z: the head close-up; the head grows on screen, the scene's pixels change
    far_box, far_shot = _head_screen_box(window), window.read_pixels("scene").copy()
    assert xin.key("z", until=lambda: _camera_state(window.scene_renderer) != home, timeout=5)
    xin.settle(timeout=0.2)
    near_box = _head_screen_box(window)
    assert near_box[3] - near_box[1] > 2.0 * (far_box[3] - far_box[1]), (far_box, near_box)
    assert np.abs(window.read_pixels("scene").astype(int) - far_shot).mean() > 2


def test_slider_drag_scrubs_the_mesh_live_and_the_preview_on_release(window, xin):
    drawn = window.mesh_actor.mapper.dataset
    mesh0 = np.array(drawn.points)
    preview0 = window.preview_panel.image.copy()
    state = {}

    def during():  # the button is still down
        state["expr0"] = float(window.pipeline.face.expr[0])
        state["moved"] = float(np.abs(np.array(drawn.points) - mesh0).max())
        state["preview_same"] = np.array_equal(window.preview_panel.image, preview0)
        state["live_ms"] = window.timings.live_ms

    start, end = window.slider_point("expr0", 0.0), window.slider_point("expr0", 1.5)
    xin.drag(start, end, during=during)
    assert state["expr0"] > 1.0 and state["moved"] > 1e-4, state  # the mesh followed the knob while dragging
    assert state["preview_same"] and state["live_ms"] is not None  # the Gaussian preview waits for the release
    assert window.pipeline.face.expr[0] == pytest.approx(window._specs["expr0"].value)
    assert not np.array_equal(window.preview_panel.image, preview0)  # released: preview rendered
    np.testing.assert_allclose(np.array(drawn.points), window.pipeline.mesh(), atol=1e-6)
    assert "nan" not in window.status.GetInput()


def test_exports_run_in_the_background_with_progress_in_the_window(window, xin, tmp_path):
    """Bug 5: exports froze the window. A job holds the export thread; keys still act meanwhile."""
    import threading

    gate = threading.Event()

    def slow(job):
        job.progress(1, 3, "steps")
        gate.wait(20)
        job.progress(3, 3, "steps")
        return window._out("slow.txt")

    window._submit("exporting test", slow)
    # k and n queue behind it (the sweep, x, is the same kind of job: test_keys_write_their_files writes it)
    assert xin.key("k", "n", until=lambda: "(+2 queued)" in window.status.GetInput(), timeout=5)
    assert "exporting test: 1/3 steps" in window.status.GetInput()
    assert xin.key("h", until=lambda: window.help_actor.GetVisibility(), timeout=3)  # not blocked
    assert xin.key("m", until=lambda: not window.mesh_actor.GetVisibility(), timeout=3)
    gate.set()
    assert xin.settle(until=lambda: len(window.exports) == 3, timeout=120), window.errors
    assert "wrote" in window.status.GetInput()
    names = sorted(p.name for p in (tmp_path / "exports").iterdir())
    assert any(n.endswith("_qs8x6a0.75.png") for n in names) and any(n.endswith("_native.png") for n in names)


def test_value_entry_arrow_keys_and_reset_to_neutral(window, xin):
    xin.key("Return")
    xin.type("expr0 1.2")
    assert xin.key("Return", until=lambda: window.pipeline.face.expr[0] == pytest.approx(1.2), timeout=3)
    assert window._specs["expr0"].value == pytest.approx(1.2)
    xin.key("Return")
    xin.type("nosuch 1")
    xin.key("Return")
    assert "no slider named 'nosuch'" in window.errors[-1] and window._message.startswith("error: ")
    frusta = window.frusta  # the 48 frusta are moved, never rebuilt
    v0 = window.selected_view
    assert xin.key("Right", until=lambda: window.selected_view == v0 + 1, timeout=3)
    assert "error" not in window._message and "nosuch" not in window.status.GetInput()  # a success clears it
    assert window.frusta is frusta and window.frusta_actor.mapper.dataset is frusta
    np.testing.assert_allclose(np.array(window.selected.points), np.array(frusta.points)[5 * (v0 + 1): 5 * (v0 + 2)])
    assert f"view {v0 + 1}/" in window.preview_panel.title.GetInput()
    assert window._specs["view"].value == v0 + 1
    xin.settle(timeout=0.2)
    preview = window.read_pixels("preview").copy()
    assert xin.key("Left", until=lambda: window.selected_view == v0, timeout=3)  # back along the views
    xin.settle(timeout=0.2)
    np.testing.assert_allclose(np.array(window.selected.points), np.array(frusta.points)[5 * v0: 5 * (v0 + 1)])
    assert f"view {v0}/" in window.preview_panel.title.GetInput() and window._specs["view"].value == v0
    assert np.abs(window.read_pixels("preview").astype(int) - preview).max() > 30  # that view's picture
    assert xin.key("0", until=lambda: not np.any(window.pipeline.face.expr), timeout=3)
    assert window._specs["expr0"].value == 0.0


def test_q_quits_the_event_loop(window, xin):
    assert xin.key("q", timeout=3) is False and window._quit


# ------------------------------------------------------------------ what researchers expect


def test_help_lists_every_key_and_every_listed_key_is_bound(window):
    from holo_viewer.gui.viewer import HELP_TEXT, KEYS

    actions = window._key_actions()
    for keysym, shown, what in KEYS:
        assert keysym in actions, keysym
        if shown:
            assert f" {shown}" in HELP_TEXT and what in HELP_TEXT
    assert set(actions) - {k for k, _, _ in KEYS} <= {"KP_Enter"}
    assert window.hint.GetVisibility() and "h" in window.hint.GetInput()  # the window says how to get help
    assert "h for help" in window.plotter.ren_win.GetWindowName()


def test_default_framing_shows_the_head_and_all_cameras(window):
    ren = window.scene_renderer
    window.plotter.ren_win.Render()
    x0, y0, x1, y1 = window.panel_box("scene")
    pts = np.concatenate([window.pipeline.cameras().positions, window.pipeline.mesh()[::10]])
    for p in pts:
        ren.SetWorldPoint(*p, 1.0)
        ren.WorldToDisplay()
        x, y, _ = ren.GetDisplayPoint()
        assert x0 <= x <= x1 and y0 <= y <= y1, (p, x, y)
    assert window.legend.GetVisibility() and window.legend.GetLookupTable().GetNumberOfTableValues() == 48
    assert getattr(window.scene_renderer, "axes_widget", None) is not None  # orientation axes


def test_gaussian_controls(window, xin):
    n0 = window._glyph_index.size
    window.set_glyphs(count=50)
    assert window._glyph_index.size == 50 and window.glyphs.n_points == 50 * 12
    op = window.pipeline.gaussians().opacities
    op = op.detach().numpy() if hasattr(op, "detach") else op
    window.set_glyphs(count=n0, min_opacity=0.9)
    assert np.all(op[window._glyph_index] >= 0.9) and window._glyph_index.size == int((op >= 0.9).sum())
    pts = np.array(window.glyphs.points)
    window.set_glyphs(sigmas=3.0)
    assert np.ptp(np.array(window.glyphs.points), axis=0).max() > np.ptp(pts, axis=0).max()
    rgb = np.array(window.glyphs.point_data["rgb"])
    xin.settle(timeout=0.2)
    shot = window.read_pixels("scene").copy()
    assert xin.key("c", until=lambda: window.glyph_color == "opacity", timeout=5)  # a real key press
    xin.settle(timeout=0.2)
    assert not np.array_equal(np.array(window.glyphs.point_data["rgb"]), rgb)
    assert "opacity" in window._headers["Gaussians"].GetInput()
    assert np.abs(window.read_pixels("scene").astype(int) - shot).max() > 30  # recoloured on screen


def test_layout_readable_at_800x450(xvfb, tmp_path):
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    viewer = HoloViewer(_small_scene(), ViewerConfig(window_size=(800, 450), out_dir=str(tmp_path),
                                                     thumbnail_scale=0.1))
    try:
        viewer.open()
        _assert_layout_readable(viewer)
    finally:
        viewer.close()


def _assert_layout_readable(viewer) -> None:
    """Every slider title above its own slider, none overlapping; the quilt title above the thumbnail."""
    viewer.wait_for_thumbnail()  # the quilt panel's image (shown after the first frame)
    ren = viewer.slider_renderer
    boxes = []
    for spec in viewer._specs.values():
        assert spec.label.GetTextProperty().GetFontSize() >= 11
        bb = _text_box(spec.label, ren)
        knob_y = viewer.plotter.ren_win.GetSize()[1] - 1 - viewer.slider_point(spec.key)[1]
        assert bb[2] > knob_y, f"{spec.title}: title not above its own slider"
        boxes.append((spec.title, bb, knob_y))
    for (t1, b1, _), (t2, b2, k2) in zip(boxes, boxes[1:]):
        assert b2[3] < b1[2], f"titles {t1!r} and {t2!r} overlap"
        assert k2 < b1[2] - 2, f"slider of {t2!r} runs into the title {t1!r}"
    # the quilt title sits above the thumbnail image, not on it
    panel = viewer.thumb_panel
    bb = _text_box(panel.title, panel.renderer)
    assert panel.title.GetTextProperty().GetFontSize() >= 11
    img_top = _image_top_pixel(panel)
    assert bb[2] >= img_top - 1, (bb, img_top)


SCREENS = ((1280, 720), (1366, 768), (1920, 1080), (2560, 1440))


def test_entry_hints_and_errors_use_the_au_names():
    from holo_viewer.errors import InputError
    from holo_viewer.gui.keys import KeysMixin
    from holo_viewer.gui.widgets import _Slider

    specs = {"expr2": _Slider("expr2", "AU9 nose wrinkler", (0, 1.5), "%.2f", None, None, "face", aliases=("au9", "au9")),
             "pain": _Slider("pain", "pain (PSPI face)", (0, 1), "%.2f", None, None, "face")}
    entry = KeysMixin()
    entry._specs = specs
    assert [s.entry_name for s in specs.values()] == ["au9", "pain"]
    assert entry.find_slider("AU9") == "expr2"
    with pytest.raises(InputError) as err:
        entry.find_slider("expr9")
    assert "au9, pain" in str(err.value) and "expr2" not in str(err.value)


def test_splat_worker_renders_the_newest_pose_and_drops_stale_ones():
    """The camera-drag render thread: while a render runs, a newer request replaces the queued one (a stale
    pose never renders); results come back with their key; cancel() discards a running one's result."""
    import threading

    from holo_viewer.gui.splat_view import SplatWorker

    gate, ran = threading.Event(), []

    def job(name):
        def fn():
            ran.append(name)
            if name == "a":
                gate.wait(5)
            return np.full((2, 2, 3), ord(name), np.uint8)
        return fn

    w = SplatWorker()
    try:
        w.submit("a", job("a"))
        deadline = time.time() + 5
        while not ran and time.time() < deadline:
            time.sleep(0.005)
        w.submit("b", job("b"))
        w.submit("c", job("c"))  # replaces b, which never starts
        gate.set()
        got = []
        while (not got or got[-1] != "c") and time.time() < deadline:  # take() gives the newest
            r = w.take()
            if r is not None:
                got.append(r[0])
            time.sleep(0.005)
        assert ran == ["a", "c"] and w.dropped == 1 and got[-1] == "c"
        gate.clear()
        w.submit("a", job("a"))
        while ran.count("a") < 2 and time.time() < deadline:
            time.sleep(0.005)
        gate.set()
        w.cancel()  # waits for the running one, discards its result
        assert w.take() is None and w.idle
    finally:
        w.close()


def test_vertex_normals_by_bincount_equal_the_add_at_sums():
    """geometry.vertex_normals (the viewer's live mesh) sums face normals with np.bincount: equal to the
    np.add.at sums (float64) within 1e-12 on a perturbed mesh."""
    from holo_viewer.geometry import vertex_normals

    model = _small_scene().model
    rng = np.random.default_rng(2)
    v = np.asarray(model.v_template, dtype=np.float64) + rng.normal(scale=0.01, size=(model.n_vertices, 3))
    f = model.faces.numpy().astype(np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    ref = np.zeros_like(v)
    for k in range(3):
        np.add.at(ref, f[:, k], fn)
    norm = np.linalg.norm(ref, axis=1, keepdims=True)
    ref = np.divide(ref, norm, out=np.zeros_like(ref), where=norm > 0)  # unused vertices: zero
    np.testing.assert_allclose(vertex_normals(v, f), ref, atol=1e-12)
    v[f[0, 0]] += 0.05  # a moved vertex changes its normals: the comparison can fail
    assert np.abs(vertex_normals(v, f) - ref).max() > 1e-3


def test_viewer_angle_slider_stays_where_the_avatar_was_fitted(tmp_path):
    """The range comes from the avatar file's fit_angle_range_deg (every quilt view within the fit's
    cameras); a file without it: +-30 deg fit cameras assumed (+-10 at the 40 deg cone) and the note says so."""
    from types import SimpleNamespace as NS

    from holo_viewer.errors import AvatarError
    from holo_viewer.gui.sliders import viewer_angle_limits, viewer_angle_range

    with_range, without, bad = tmp_path / "fit.npz", tmp_path / "old.npz", tmp_path / "bad.npz"
    np.savez(with_range, fit_angle_range_deg=np.array([-25.0, 35.0]), binding=np.zeros(3))
    np.savez(without, binding=np.zeros(3))
    np.savez(bad, fit_angle_range_deg=np.array([5.0, -5.0]))
    cal = NS(view_cone=40.0)
    fitted = NS(avatar=NS(fit_file=with_range), model=NS(is_default_head=True), view=NS(view_cone=None),
                calibration=cal)
    lo, hi, note = viewer_angle_limits(fitted)
    assert (lo, hi) == (-5.0, 15.0) and "fit.npz" in note and "assumed" not in note
    old = NS(**{**vars(fitted), "avatar": NS(fit_file=without)})
    lo, hi, note = viewer_angle_limits(old)
    assert (lo, hi) == (-10.0, 10.0) and "no fit_angle_range_deg stored" in note and "old.npz" in note
    assert viewer_angle_range(NS(**{**vars(old), "view": NS(view_cone=60.0)})) == (-1.0, 1.0)
    with pytest.raises(AvatarError, match="bad.npz.*fit_angle_range_deg.*found \\[5.0, -5.0\\]"):
        viewer_angle_limits(NS(**{**vars(fitted), "avatar": NS(fit_file=bad)}))
    assert viewer_angle_range(NS(**{**vars(fitted), "avatar": None})) == (-30.0, 30.0)  # mesh only
    assert viewer_angle_range(NS(**{**vars(fitted), "avatar": NS(), "model": NS()})) == (-30.0, 30.0)  # not fitted


def test_set_avatar_swaps_the_avatar_and_refreshes_scene_and_panels(window, tmp_path):
    """The avatar chooser's hook: another avatar's Gaussians reach the ellipsoids, the preview and the
    thumbnail; its fit file sets the viewer-angle range; None leaves the mesh only."""
    swapped = _small_scene(seed=3).avatar
    fit = tmp_path / "fit.npz"
    np.savez(fit, fit_angle_range_deg=np.array([-20.0, 30.0]))
    swapped.fit_file = fit
    glyphs0 = np.array(window.glyphs.points)
    preview0 = window.preview_panel.image.copy()
    window.set_avatar(swapped)
    window.wait_for_thumbnail()
    assert window.pipeline.avatar is swapped
    assert np.abs(np.array(window.glyphs.points) - glyphs0).max() > 1e-3
    assert np.abs(window.preview_panel.image.astype(int) - preview0).max() > 30
    assert window._specs["angle"].rng == (0.0, 10.0) and window.pipeline.view.viewer_angle == 0.0
    window.set_avatar(None)
    assert not window.preview_panel.actor.GetVisibility() and window.mesh_actor.GetVisibility()
    assert "no Gaussian avatar" in window.preview_panel.message.GetInput()


def test_look_through_overlay_lines_up_with_the_sheared_camera(window):
    """Looking through the outermost (most sheared) quilt cameras, VTK draws the overlays where the quilt
    camera (the splat image) puts them: mesh vertices projected both ways agree within half a pixel."""
    from holo_viewer.gui.splat_view import look_through_camera

    ren = window.scene_renderer
    verts = window.pipeline.mesh()[::7]
    W, H = window._scene_pixels()
    x0, y0 = ren.GetOrigin()
    for view in (0, len(window.pipeline.cameras()) - 1):
        window.select_view(view)
        if window.look_through is None:
            window.toggle_look_through()
        cams = look_through_camera(window.pipeline.cameras(), view, W, H)
        assert abs(cams.cx[0] - W / 2) > 20  # off-axis: the principal point is far from the centre
        uv, _ = cams.project(verts)
        drawn = []
        for p in verts:
            ren.SetWorldPoint(*p, 1.0)
            ren.WorldToDisplay()
            x, y, _ = ren.GetDisplayPoint()
            drawn.append((x - x0, H - (y - y0)))  # pixels from the scene's top left, as the splat image
        assert np.abs(np.array(drawn) - uv[0]).max() < 0.5, view
    window.toggle_look_through()
    assert window.scene_renderer.GetActiveCamera().GetWindowCenter() == (0.0, 0.0)


def test_braces_resize_the_image_panels_and_the_scene_gives_way(splat_window, xdotool):
    """Real ``}`` / ``{`` presses: the image column grows / shrinks in steps within its limits, the scene
    takes the rest, and the splat image is rendered again at the scene's new size."""
    viewer = splat_window
    xin = XInput(xdotool, viewer)
    xin.move(*xin.centre("scene"))
    widths = lambda: {k: viewer.panel_box(k)[2] - viewer.panel_box(k)[0] for k in ("scene", "preview", "quilt")}
    w0 = widths()
    assert xin.key("braceright", until=lambda: widths()["preview"] > w0["preview"] + 20, timeout=5)
    w1 = widths()
    assert w1["scene"] < w0["scene"] - 20 and w1["quilt"] == w1["preview"]
    xin.settle(until=lambda: viewer._splat_full, timeout=5)
    assert viewer.splat_image.shape[1] == w1["scene"] + 1  # pixel for pixel at the new size
    for _ in range(12):
        xin.xdo("key", "braceright")
    xin.sync(timeout=30)  # every press handled (a fixed 0.5 s need not be, under load)
    assert viewer.panel_width == pytest.approx(0.55) and "widest" in viewer._message
    for _ in range(20):
        xin.xdo("key", "braceleft")
    xin.sync(timeout=30)
    assert viewer.panel_width == pytest.approx(0.15) and widths()["preview"] < w0["preview"]
    assert viewer.panel_box("preview")[2] == viewer.panel_box("quilt")[2]
    # s: the splat image off (the mesh and the ellipsoids over the gradient) and on again (the same picture)
    xin.settle(until=lambda: viewer._splat_full, timeout=5)
    xin.settle(timeout=0.2)
    def middle():  # the scene without its text corners (the status line's timings change)
        img = viewer.read_pixels("scene")[::-1].astype(int)
        return img[int(0.12 * len(img)):int(0.75 * len(img))]
    shot = middle()
    assert xin.key("s", until=lambda: not viewer.show_splats, timeout=5)
    xin.settle(timeout=0.2)
    assert not viewer.scene_renderer.GetTexturedBackground()
    assert viewer.mesh_actor.GetVisibility() and viewer.show_mesh  # not an empty scene
    assert np.abs(middle() - shot).mean() > 2
    assert xin.key("s", until=lambda: viewer.show_splats and viewer._splat_full, timeout=5)
    xin.settle(timeout=0.2)
    assert viewer.scene_renderer.GetTexturedBackground()
    assert not viewer.mesh_actor.GetVisibility()  # hidden again behind the splats, as before
    assert np.abs(middle() - shot).mean() < 0.5


@pytest.fixture()
def splat_window(xvfb, tmp_path):
    """A viewer with the splat view on (the default), 800x450, small scene."""
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    viewer = HoloViewer(_small_scene(), ViewerConfig(window_size=(800, 450), out_dir=str(tmp_path),
                                                     thumbnail_scale=0.1, auto_thumbnail=False))
    viewer.open()
    yield viewer
    viewer.close()


def _scene_readback(viewer) -> np.ndarray:
    """The 3D scene's pixels as on screen, (H, W, 3) with row 0 at the top."""
    viewer.run(timeout=0.3)
    return viewer.read_pixels("scene")[::-1]


def test_splat_view_looking_through_a_quilt_camera_shows_its_quilt_tile(splat_window, xdotool):
    """``v`` (real key) looks through the selected view; with the overlays off (``o``) the scene read back
    from the screen holds that view's quilt tile (Pipeline.quilt()) at full resolution."""
    from holo_viewer.display.quilt import split_quilt
    from holo_viewer.images import psnr

    viewer = splat_window
    xin = XInput(xdotool, viewer)
    assert viewer.show_splats and not viewer.mesh_actor.GetVisibility()  # the splats are the picture
    viewer.select_view(10)
    xin.move(*viewer.slider_point("view"))  # key presses go to the window under the pointer
    assert xin.key("v", until=lambda: viewer.look_through == 10, timeout=5)
    assert xin.key("o", until=lambda: not viewer.show_frusta, timeout=5)
    scene = _scene_readback(viewer)
    pipe = viewer.pipeline
    cams, cal = pipe.cameras(), pipe.calibration
    tile = split_quilt(pipe.quilt(), cal.cols, cal.rows, len(cams))[10]
    h, w = tile.shape[:2]
    oy, ox = (scene.shape[0] - h) // 2, (scene.shape[1] - w) // 2
    crop = scene[oy:oy + h, ox:ox + w] / 255.0
    assert psnr(tile / 255.0, crop) >= 40.0
    assert psnr(split_quilt(pipe.quilt(), cal.cols, cal.rows, len(cams))[30] / 255.0, crop) < 40.0  # can fail
    assert xin.key("Right", until=lambda: viewer.look_through == 11, timeout=5)  # follows the selection
    assert xin.key("v", until=lambda: viewer.look_through is None, timeout=5)


def test_splats_follow_a_face_slider_release_in_one_frame(splat_window, monkeypatch):
    """A face slider released with the splat view on: the next frame shows the new face's splats (the
    image of a fresh render at the scene camera), the stand-in mesh hidden and the scene's lights back, in
    one frame (no frame of the old splats in between). The stand-in's decimated triangles are drawn only
    during the drag; the release puts the whole mesh's back."""
    from holo_viewer.display.quilt import to_uint8
    from holo_viewer.pipeline import render_images

    from vtk.util.numpy_support import vtk_to_numpy

    def triangles():
        return vtk_to_numpy(viewer.mesh.GetPolys().GetConnectivityArray()).reshape(-1, 3)

    viewer = splat_window
    lights = viewer.scene_renderer.GetLights().GetNumberOfItems()
    # the random test mesh does not decimate (tests/test_gui_scene.py decimates a sphere): every other
    # triangle stands in for the stand-in here, to check where it is drawn
    monkeypatch.setattr("holo_viewer.gui.sliders.decimated_faces", lambda v, f, reduction: f[::2])
    viewer.standin_min_triangles = 0
    viewer._start_standin(wait=True)
    assert np.array_equal(triangles(), viewer.faces)  # the whole mesh until a face slider is dragged
    viewer._live_face("expr1", 0.7, time.perf_counter())  # a drag step: the mesh stands in, one headlight
    assert viewer.mesh_actor.GetVisibility() and viewer.scene_renderer.GetLights().GetNumberOfItems() == 1 < lights
    assert viewer.mesh_actor.GetProperty().GetBackfaceCulling()  # the stand-in skips back faces
    assert np.array_equal(triangles(), viewer.faces[::2])  # the stand-in's triangles, the mesh's own points
    # the mapper draws the viewer's mesh itself (no normals filter in between), smooth-shaded by its own
    # normals, which follow the live step
    from vtk.util.numpy_support import vtk_to_numpy

    from holo_viewer.geometry import vertex_normals

    assert viewer.mesh_actor.GetMapper().GetInputAlgorithm().IsA("vtkTrivialProducer")
    np.testing.assert_allclose(vtk_to_numpy(viewer.mesh.GetPointData().GetNormals()),
                               vertex_normals(np.asarray(viewer.mesh.points), viewer.faces), atol=1e-9)
    # the overlay lines cut at the head's box: kept while the head's pixel box stays, cut again when it
    # moves; what a drag step drew equals a fresh cut
    def cut_lines():
        out = []
        for k in ("frusta", "selected", "focal"):
            pts = viewer._cut_actors[k].GetMapper().GetInput().GetPoints()
            out.append(None if pts is None else vtk_to_numpy(pts.GetData()).copy())
        return out

    for value in (0.72, 1.4):
        viewer._live_face("expr1", value, time.perf_counter())
        drawn = cut_lines()
        viewer._cut_key = None
        viewer._cut_overlays()
        assert all((a is None and b is None) or np.array_equal(a, b) for a, b in zip(drawn, cut_lines()))
    before, frames0 = viewer.splat_image.copy(), viewer.frames_drawn
    _fire_slider(viewer.sliders["expr1"], 1.5)
    assert viewer.scene_renderer.GetLights().GetNumberOfItems() == lights  # the light kit is back
    assert not viewer.mesh_actor.GetProperty().GetBackfaceCulling()
    assert np.array_equal(triangles(), viewer.faces)  # the whole mesh is back
    assert viewer.frames_drawn == frames0 + 1 and viewer._splat_full and not viewer.mesh_actor.GetVisibility()
    fresh = to_uint8(render_images(viewer.pipeline.gaussians(), viewer.splat_cameras())[0])
    assert np.array_equal(viewer.splat_image, fresh) and np.abs(fresh.astype(int) - before).max() > 30


def test_partial_present_window_matches_the_framebuffer(splat_window, xdotool):
    """A frame that draws some panels copies only those to the X window (gui/present.py): after a live
    face step (scene + sliders), a scene-only frame and a preview-only frame, the X window itself (read
    with XGetImage) holds exactly the frame VTK drew, and each of those frames presented one rectangle.
    A window unmapped and mapped again (its pixels lost, an Expose event) is drawn whole again."""
    from holo_viewer.gui.present import x_window_pixels

    viewer = splat_window
    if viewer._presenter is None:
        pytest.skip("this GLX has no GLX_MESA_copy_sub_buffer: VTK presents every frame whole")
    rw = viewer.plotter.ren_win
    n0 = viewer._presenter.presented
    viewer._live_face("expr1", 1.2, time.perf_counter())
    viewer.scene_renderer.GetActiveCamera().Azimuth(8.0)
    viewer._render_now(("scene",))
    viewer.preview_panel.set_title("partial present")
    viewer._render_now(("preview",))
    assert viewer._presenter.presented == n0 + 3
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    W, H = rw.GetSize()

    def drawn() -> np.ndarray:  # the frame VTK drew (its display framebuffer), top row first
        arr = vtk.vtkUnsignedCharArray()
        rw.GetPixelData(0, 0, W - 1, H - 1, 1, arr, 0)
        return vtk_to_numpy(arr).reshape(H, W, 3)[::-1]

    shown = x_window_pixels(rw)
    assert shown is not None and shown.shape == (H, W, 3)
    assert np.array_equal(shown, drawn())
    presenter, viewer._presenter = viewer._presenter, None  # can fail: a frame drawn but not presented
    try:
        viewer._live_face("expr1", 0.1, time.perf_counter())
        assert not np.array_equal(x_window_pixels(rw), drawn())
    finally:
        viewer._presenter = presenter
    xin = XInput(xdotool, viewer)
    frames = viewer.frames_drawn
    xin.xdo("windowunmap", "--sync", xin.wid)
    xin.xdo("windowmap", "--sync", xin.wid)
    xin.settle(timeout=0.5)  # VTK asks for a frame on the Expose: every panel, so the whole window
    assert viewer.frames_drawn > frames and set(viewer.last_frame_parts) == {"scene", "sliders", "preview", "quilt"}
    assert np.array_equal(x_window_pixels(rw), drawn())
    # the loop's idle wait (HoloViewer.wait_for_input) ends on X input or a splat image, not only at its
    # timeout: no poll period between a drag step (or a rendered image) and its frame
    waiter, wake = viewer._input_wait, viewer._splat_worker.wake_fd
    assert waiter is not None
    for _ in range(50):  # drain what the map left (Expose, ConfigureNotify)
        viewer.step()
        if not waiter.wait(0.02, (wake,)):
            break
    else:
        raise AssertionError("the X connection never went quiet")
    cx, cy = xin.centre("scene")
    xin.move(cx + 7, cy + 5)
    assert waiter.wait(10.0, (wake,))  # the motion event woke it
    viewer.step()
    os.write(viewer._splat_worker._wake_w, b"1")  # what the worker writes with a finished image
    assert waiter.wait(10.0, (wake,))
    assert not waiter.wait(0.02, (wake,))  # the wake-up was read


def test_splat_view_follows_the_camera_reduced_while_dragging(splat_window, xdotool):
    """A real drag in the scene: while the button is down the splat image is the reduced one, after the
    release the full-resolution image of the new camera pose, which matches the float64 reference
    renderer at that pose (between the quilt cameras)."""
    from holo_viewer.images import psnr
    from holo_viewer.pipeline import render_images

    viewer = splat_window
    xin = XInput(xdotool, viewer)
    x0, y0, x1, y1 = viewer.panel_box("scene")
    H = viewer.plotter.ren_win.GetSize()[1]
    cx, cy = (x0 + x1) // 2, H - (y0 + y1) // 2
    xin.move(cx, cy)
    # the default framing: the face fills most of the scene; the overlay lines (frusta, selected frustum,
    # focal-plane outline) are drawn around it, none across it (cut at the head's screen box)
    with_overlays = _scene_readback(viewer).astype(int)
    hx0, hy0, hx1, hy1 = _head_screen_box(viewer)
    W, H = x1 - x0 + 1, y1 - y0 + 1
    assert hy1 - hy0 > 0.5 * H, (hy0, hy1, H)
    cut = [viewer._cut_actors[k].GetMapper().GetInput() for k in ("frusta", "selected", "focal")]
    assert all(a.GetVisibility() for a in viewer._cut_actors.values()) and sum(c.GetNumberOfCells() for c in cut) > 10
    assert not any(a.GetVisibility() for a in (viewer.frusta_actor, viewer.selected_actor, viewer.focal_actor))
    assert xin.key("o", until=lambda: not viewer.show_frusta, timeout=5)  # overlays off
    plain = _scene_readback(viewer).astype(int)
    changed = np.abs(with_overlays - plain).max(axis=2) > 40  # (H, W), row 0 at the top
    rows, cols = np.arange(H)[:, None], np.arange(W)[None, :]
    head = ((cols >= hx0 - x0 + 3) & (cols <= hx1 - x0 - 3) & (H - 1 - rows >= hy0 - y0 + 3)
            & (H - 1 - rows <= hy1 - y0 - 3))
    assert changed[head].mean() < 0.002, changed[head].mean()  # nothing drawn across the face
    assert changed[~head].sum() > 200  # the rig is drawn around it
    before = viewer.splat_image.copy()
    xin.xdo("mousedown", 1)
    try:
        for k in range(1, 4):
            xin.move(cx + 25 * k, cy)
            # the frame the move asks for, held for the splat image (a fixed 0.3 s settle could end first, under
            # load, and then saw the frame run() opens with: every panel)
            assert xin.next_frame()
            assert viewer.last_frame_parts == ("scene",)  # a camera-drag frame draws the scene panel only
        assert not viewer._splat_full and viewer.timings.splat_drag_ms is not None
    finally:
        xin.xdo("mouseup", 1)
    assert xin.settle(until=lambda: viewer._splat_full, timeout=10)
    assert viewer.last_frame_parts == ("scene",)  # the release's frame too: only the camera moved
    scene = _scene_readback(viewer)
    assert np.abs(scene.astype(int) - before).mean() > 1.0  # the camera moved: a new picture
    cams = viewer.splat_cameras()
    assert (cams.width, cams.height) == (scene.shape[1], scene.shape[0])
    ref = render_images(viewer.pipeline.gaussians(), cams, backend="reference")[0]  # float64
    band = np.zeros(scene.shape[:2], dtype=bool)  # the text and the axes stay in the corners
    band[int(0.12 * band.shape[0]):int(0.75 * band.shape[0])] = True
    assert psnr(ref, scene / 255.0, mask=band) >= 40.0
    assert psnr(ref, before / 255.0, mask=band) < 40.0  # the test can fail


def test_panel_shows_the_native_image_zoomed_and_what_a_placed_eye_sees(xvfb, xdotool, tmp_path):
    """``p`` (real key) cycles the upper panel: selected view -> native image (interleaved from the quilt
    thumbnail at first, then the full-resolution one from its worker: ``Pipeline.native()``; ``]`` zooms)
    -> the simulated eye's picture of that native image, which follows the eye sliders."""
    from holo_viewer.display.lenticular import Interleaver
    from holo_viewer.display.simulate import VirtualDisplay
    from holo_viewer.gui.previews import zoom_centre
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    viewer = HoloViewer(_small_scene(calibration=_small_panel()), ViewerConfig(
        window_size=(960, 540), out_dir=str(tmp_path), thumbnail_scale=0.1, splat_view=False))
    try:
        viewer.open()
        viewer.wait_for_thumbnail()
        xin = XInput(xdotool, viewer)
        xin.move(*xin.centre("scene"))
        cal = viewer.pipeline.calibration
        quilt = viewer.thumb_panel.image
        soft = Interleaver(cal, quilt.shape, cols=cal.cols, rows=cal.rows)(quilt)
        assert xin.key("p", until=lambda: viewer.panel_mode == "native", timeout=5)
        if viewer.native_source == "thumbnail":  # the full-resolution one not there yet
            assert np.array_equal(viewer.preview_panel.image, soft)
            assert "from the thumbnail" in viewer.preview_panel.title.GetInput()
        assert xin.settle(until=lambda: viewer.native_source == "full", timeout=60)
        native = viewer.pipeline.native()  # full resolution, rendered here in this process
        assert native.shape == (cal.screen_h, cal.screen_w, 3)
        assert np.abs(viewer.preview_panel.image.astype(int) - native).max() <= 1
        assert np.abs(soft.astype(int) - native).mean() > 2  # the thumbnail's is another picture: can fail
        assert "native" in viewer.preview_panel.title.GetInput()
        assert "thumbnail" not in viewer.preview_panel.title.GetInput()
        assert xin.key("bracketright", until=lambda: viewer.native_zoom == 2, timeout=5)
        assert np.abs(viewer.preview_panel.image.astype(int) - zoom_centre(native, 2)).max() <= 1
        assert viewer.preview_panel.image.shape[:2] == (cal.screen_h // 2, cal.screen_w // 2)
        xin.settle(timeout=0.2)
        zoomed = viewer.read_pixels("preview").copy()
        assert xin.key("bracketleft", until=lambda: viewer.native_zoom == 1, timeout=5)  # zoom out again
        xin.settle(timeout=0.2)
        assert np.abs(viewer.preview_panel.image.astype(int) - native).max() <= 1
        assert np.abs(viewer.read_pixels("preview").astype(int) - zoomed).mean() > 2
        assert xin.key("p", until=lambda: viewer.panel_mode == "eye", timeout=5)
        eye = VirtualDisplay(cal, n_views=len(viewer.pipeline.cameras()), downsample=4)
        seen0 = eye.see(native, viewer.eye_angle, viewer.eye_distance)
        np.testing.assert_allclose(viewer.preview_panel.image / 255.0, seen0, atol=2 / 255 + 1e-6)
        xin.key("Return")
        xin.type("eye 12")
        assert xin.key("Return", until=lambda: viewer.eye_angle == 12.0, timeout=5)
        seen = eye.see(native, 12.0, viewer.eye_distance)
        np.testing.assert_allclose(viewer.preview_panel.image / 255.0, seen, atol=2 / 255 + 1e-6)
        assert np.abs(seen - seen0).mean() > 1e-3  # another eye position, another picture
        assert "eye at +12.0 deg" in viewer.preview_panel.title.GetInput()
        for key, value in (("eye_angle", -20.0), ("eye_distance", 1.6)):  # the sliders, dragged
            xin.settle(timeout=0.2)
            shot, before = viewer.read_pixels("preview").copy(), (viewer.eye_angle, viewer.eye_distance)
            xin.drag(viewer.slider_point(key), viewer.slider_point(key, value), steps=2)
            now = (viewer.eye_angle, viewer.eye_distance)
            assert now[key == "eye_distance"] == pytest.approx(value, abs=0.1 * abs(value)), (key, now)
            assert now[key == "eye_angle"] == before[key == "eye_angle"]
            assert viewer._specs[key].value == pytest.approx(now[key == "eye_distance"])
            seen = eye.see(native, *now)
            np.testing.assert_allclose(viewer.preview_panel.image / 255.0, seen, atol=2 / 255 + 1e-6)
            assert np.abs(viewer.read_pixels("preview").astype(int) - shot).mean() > 1, key  # on screen
        assert xin.key("p", until=lambda: viewer.panel_mode == "view", timeout=5)
    finally:
        viewer.close()


def test_clicking_a_camera_selects_it(window, xin):
    ren = window.scene_renderer
    window.plotter.ren_win.Render()
    H = window.plotter.ren_win.GetSize()[1]

    def where(i: int) -> tuple[int, int]:
        ren.SetWorldPoint(*window.pipeline.cameras().positions[i], 1.0)
        ren.WorldToDisplay()
        x, y, _ = ren.GetDisplayPoint()
        return int(round(x)), int(round(H - 1 - y))

    target = 5 if window.selected_view != 5 else 6
    xin.move(*where(target))
    xin.xdo("click", 1)
    assert xin.settle(until=lambda: window.selected_view == target, timeout=5)
    assert window._specs["view"].value == target
    x, y = where(0)  # a drag that starts on a camera turns the scene; it selects nothing
    xin.drag((x, y), (x + 40, y + 10))
    xin.settle(timeout=0.5)
    assert window.selected_view == target


def test_default_window_fits_each_screen_size():
    from holo_viewer.gui.screen import window_size_for_screen

    for sw, sh in SCREENS:
        w, h = window_size_for_screen((sw, sh))
        assert 800 <= w <= sw and 450 <= h <= sh - 60, (sw, sh, w, h)  # room for a title / panel bar
    assert window_size_for_screen(None) == (1400, 800)


@pytest.mark.parametrize("screen", SCREENS, ids=[f"{w}x{h}" for w, h in SCREENS])
def test_window_sized_from_the_screen_lays_out_without_clipping(xvfb_server, xdotool_exe, screen, tmp_path,
                                                                 monkeypatch):
    """On an X screen of each size the default window fits on the screen (measured by the X server)
    and every slider, title, panel and the status line lie inside it, readable."""
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
    with xvfb_server(f"{screen[0]}x{screen[1]}x24") as display:
        monkeypatch.setenv("DISPLAY", display)
        viewer = HoloViewer(_small_scene(), ViewerConfig(out_dir=str(tmp_path), thumbnail_scale=0.1))
        try:
            viewer.open()
            viewer.run(timeout=0.3)
            geo = subprocess.run([xdotool_exe, "getwindowgeometry", str(viewer.window_id())], capture_output=True,
                                 text=True, check=True, timeout=10).stdout
            size = [int(v) for v in geo.split("Geometry:")[1].split()[0].split("x")]
            pos = [int(v) for v in geo.split("Position:")[1].split()[0].split(",")]
            assert size == list(viewer.plotter.ren_win.GetSize()), geo
            assert pos[0] >= 0 and pos[1] >= 0 and pos[0] + size[0] <= screen[0] and pos[1] + size[1] <= screen[1], geo
            W, H = size
            for which in ("scene", "preview", "quilt", "sliders"):
                x0, y0, x1, y1 = viewer.panel_box(which)
                assert 0 <= x0 < x1 < W and 0 <= y0 < y1 < H and (x1 - x0) > 150 and (y1 - y0) > 150, which
            for key in viewer._specs:
                x, y = viewer.slider_point(key)
                assert 0 <= x < W and 0 <= y < H, key
            status = _text_box(viewer.status, viewer.scene_renderer)
            assert status[0] >= viewer.panel_box("scene")[0] and status[2] >= 0, status
            _assert_layout_readable(viewer)
        finally:
            viewer.close()


def _text_box(actor, renderer) -> list[float]:
    """(x0, x1, y0, y1) display pixels of a 2D text actor (VTK gives the size relative to its anchor)."""
    x, y = actor.GetPositionCoordinate().GetComputedDisplayValue(renderer)
    size = [0.0, 0.0]
    actor.GetSize(renderer, size)
    w, h = size
    tp = actor.GetTextProperty()
    x0 = x - {0: 0.0, 1: w / 2, 2: w}[tp.GetJustification()]
    y0 = y - {0: 0.0, 1: h / 2, 2: h}[tp.GetVerticalJustification()]
    return [x0, x0 + w, y0, y0 + h]


def _image_top_pixel(panel) -> float:
    h, w = panel.shape
    ren = panel.renderer
    ren.SetWorldPoint(0.0, 0.5, 0.0, 1.0)
    ren.WorldToDisplay()
    return ren.GetDisplayPoint()[1]


def test_avatar_none_explains_the_black_panels(xvfb, tmp_path):
    from holo_viewer.pipeline.scene import load_scene
    from holo_viewer.gui.offscreen_viewer import offscreen_viewer

    with offscreen_viewer(load_scene("none"), window_size=(640, 360)) as viewer:
        assert "--avatar none" in viewer.preview_panel.message.GetInput()
        assert "--avatar none" in viewer.thumb_panel.message.GetInput()
        assert "glyphs" not in viewer.sliders
        viewer.press_key("c")  # no ellipsoids to recolour: said so, nothing claimed
        assert "no ellipsoids to colour" in viewer._message and viewer.glyph_color == "colour"
        job_error = None
        try:
            viewer.export_quilt()
        except Exception as exc:  # noqa: BLE001
            job_error = exc
        assert job_error is not None and "--avatar none" in str(job_error)


# ------------------------------------------------------------------ command line


def test_view_without_a_display_exits_1_pointing_to_xvfb_and_snapshot(monkeypatch, capsys):
    from holo_viewer.cli import main

    monkeypatch.delenv("DISPLAY", raising=False)
    assert main(["view", "--avatar", "none"]) == 1
    err = capsys.readouterr().err
    assert "xvfb-run" in err and "holo-viewer snapshot" in err
    monkeypatch.setenv("DISPLAY", ":4711")  # nothing listens there
    assert main(["view", "--avatar", "none"]) == 1
    assert "cannot open the X display" in capsys.readouterr().err


def test_a_refused_x_window_is_one_clear_line_and_the_viewer_tries_again():
    """VTK falls back to an EGL window when the X server refuses its connection; that is a DisplayError
    of one line (not pyvista's MismatchedInteractorError later), and the viewer tries again first."""
    from holo_viewer.errors import DisplayError
    from holo_viewer.gui.screen import open_window, require_x_window

    class vtkEGLRenderWindow:  # noqa: N801 - the class name VTK falls back to
        pass

    class vtkXOpenGLRenderWindow:  # noqa: N801
        pass

    require_x_window(vtkXOpenGLRenderWindow())
    with pytest.raises(DisplayError) as err:
        require_x_window(vtkEGLRenderWindow())
    msg = str(err.value)
    assert "\n" not in msg and "refused" in msg and "vtkEGLRenderWindow" in msg and "snapshot" in msg
    calls = []

    def flaky():
        calls.append(1)
        if len(calls) < 3:
            raise DisplayError("refused")
        return "window"
    assert open_window(flaky) == "window" and len(calls) == 3
    calls.clear()

    def refused():
        calls.append(1)
        raise DisplayError("refused")
    with pytest.raises(DisplayError):
        open_window(refused, tries=2)
    assert len(calls) == 2


def test_view_toolkit_option_and_deprecated_backend(monkeypatch, capsys):
    from holo_viewer.cli import main

    monkeypatch.setitem(sys.modules, "open3d", None)
    assert main(["view", "--toolkit", "open3d"]) == 1
    err = capsys.readouterr().err
    assert 'pip install -e ".[open3d]"' in err and "deprecated" not in err
    assert main(["view", "--backend", "open3d"]) == 1
    assert "--backend is deprecated, use --toolkit" in capsys.readouterr().err


def test_view_and_snapshot_share_the_ellipsoid_options_and_defaults():
    import argparse

    from holo_viewer.commands import snapshot, view
    from holo_viewer.gui.viewer import ViewerConfig

    cfg = ViewerConfig()
    for mod in (view, snapshot):
        ap = argparse.ArgumentParser()
        mod.add_arguments(ap)
        args = ap.parse_args([])
        assert view.glyph_config(args) == {"max_glyphs": cfg.max_glyphs, "glyph_sigmas": cfg.glyph_sigmas,
                                           "glyph_min_opacity": cfg.glyph_min_opacity,
                                           "glyph_color": cfg.glyph_color}


# ------------------------------------------------------------------ offscreen snapshot


def _snapshot_image() -> np.ndarray:
    from holo_viewer.gui.offscreen_viewer import offscreen_viewer

    with offscreen_viewer(_small_scene(), window_size=GOLDEN_SIZE, thumbnail_scale=0.1) as viewer:
        assert "OSOpenGL" in viewer.plotter.ren_win.GetClassName()
        return viewer.screenshot()


def test_offscreen_snapshot_matches_golden():
    from holo_viewer.fileio import load_image, save_image

    img = _snapshot_image()
    assert img.shape == (GOLDEN_SIZE[1], GOLDEN_SIZE[0], 3)
    assert img.std() > 10 and len(np.unique(img.reshape(-1, 3), axis=0)) > 100  # not blank
    if os.environ.get("HOLO_UPDATE_GOLDEN") == "1" or not GOLDEN.exists():
        if not os.environ.get("HOLO_UPDATE_GOLDEN"):
            pytest.fail(f"golden image {GOLDEN} missing; run with HOLO_UPDATE_GOLDEN=1 to create it")
        save_image(GOLDEN, img)
    ref = load_image(GOLDEN)
    diff = np.abs(img.astype(np.float32) / 255.0 - ref)
    assert diff.mean() < 0.01, f"mean abs difference {diff.mean():.4f} vs golden"
    assert (diff.max(axis=2) > 0.25).mean() < 0.01, "more than 1% of pixels differ strongly from the golden"


def test_snapshot_detects_a_changed_scene():
    """The golden comparison can fail: a different expression gives a measurably different image."""
    from holo_viewer.fileio import load_image
    from holo_viewer.gui.offscreen_viewer import offscreen_viewer

    if not GOLDEN.exists():
        pytest.skip("no golden image yet")
    pipe = _small_scene()
    pipe.set_face(expr=np.array([2.0, -2.0, 2.0]), jaw_pose=np.array([0.4, 0.0, 0.0]))
    with offscreen_viewer(pipe, window_size=GOLDEN_SIZE, thumbnail_scale=0.1) as viewer:
        img = viewer.screenshot()
    diff = np.abs(img.astype(np.float32) / 255.0 - load_image(GOLDEN))
    assert (diff.max(axis=2) > 0.25).mean() > 0.001


def test_snapshot_command_writes_png(tmp_path):
    from holo_viewer.cli import main
    from holo_viewer.fileio import load_image

    out = tmp_path / "snap.png"
    rc = main(["snapshot", "--avatar", "none", "--out", str(out), "--window-size", "480", "270"])
    assert rc == 0
    img = load_image(out)
    assert img.shape == (270, 480, 3) and img.std() > 0.02


def test_snapshot_face_figure_options(tmp_path, capsys):
    """--expr NAME=VALUE (AU names), --angle, --view and --close-up set what the viewer's entry and z set."""
    import argparse

    from holo_viewer.cli import main
    from holo_viewer.commands.snapshot import apply_settings
    from holo_viewer.errors import InputError
    from holo_viewer.gui.offscreen_viewer import offscreen_viewer
    from holo_viewer.pipeline.scene import load_scene

    def ns(**kw):
        return argparse.Namespace(**{"expr": [], "angle": None, "view": None, "close_up": False, **kw})

    with offscreen_viewer(load_scene("none"), window_size=(480, 270)) as viewer:
        far = viewer.screenshot()
        au9 = viewer.find_slider("au9")
        apply_settings(viewer, ns(expr=["au9=1", "jaw=0.2"], angle=12.5, view=5, close_up=True))
        assert viewer.pipeline.face.expr[int(au9[4:])] == pytest.approx(1.0)
        assert viewer.pipeline.face.jaw_pose[0] == pytest.approx(0.2)
        assert viewer.pipeline.view.viewer_angle == pytest.approx(12.5) and viewer.selected_view == 5
        viewer.plotter.ren_win.Render()
        assert np.abs(viewer.screenshot().astype(int) - far).mean() > 5  # the close-up frames the head
        for bad, words in ((["au99=1"], "no slider named 'au99'"), (["au9"], "NAME=VALUE"),
                           (["pain=2"], "pain (PSPI face): expected 0.00..1.00")):
            with pytest.raises(InputError, match=re.escape(words)):
                apply_settings(viewer, ns(expr=bad))
        with pytest.raises(InputError, match=re.escape("viewer angle (deg): expected -30.0..+30.0, found 45.0")):
            apply_settings(viewer, ns(angle=45.0))
    out = tmp_path / "face.png"
    assert main(["snapshot", "--avatar", "none", "--out", str(out), "--window-size", "480", "270",
                 "--expr", "au9=1", "--close-up"]) == 0 and out.exists()
    assert main(["snapshot", "--avatar", "none", "--out", str(out), "--expr", "au99=1"]) == 1
    assert "no slider named 'au99'" in capsys.readouterr().err


# ------------------------------------------------------------------ open3d


def test_open3d_backend_missing_is_a_clear_error(monkeypatch, capsys):
    from holo_viewer.cli import main
    from holo_viewer.errors import MissingDependencyError
    from holo_viewer.gui.open3d_viewer import require_open3d

    monkeypatch.setitem(sys.modules, "open3d", None)  # as if not installed
    with pytest.raises(MissingDependencyError, match=r"holo_viewer\[open3d\]"):
        require_open3d()
    rc = main(["view", "--toolkit", "open3d"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "open3d" in err and "pip install" in err


# ------------------------------------------------------------------ loading the scene (no window)


def test_load_scene_errors_name_the_problem(tmp_path):
    from holo_viewer.errors import InputError
    from holo_viewer.flame.io import save_flame_npz
    from holo_viewer.flame.synthetic import random_flame_arrays
    from holo_viewer.pipeline.scene import load_scene

    with pytest.raises(InputError, match="missing.ply: file not found"):
        load_scene(str(tmp_path / "missing.ply"))
    model_path = save_flame_npz(tmp_path / "flame.npz", random_flame_arrays(n_vertices=200, n_shape=4, n_expr=3))
    with pytest.raises(InputError, match="--avatar default"):
        load_scene("default", flame_model=model_path)


def test_load_scene_static_ply_and_mesh_only(tmp_path):
    from holo_viewer.avatar import save_ply
    from holo_viewer.flame.io import save_flame_npz
    from holo_viewer.flame.synthetic import random_flame_arrays
    from holo_viewer.pipeline.scene import StaticAvatar, load_scene

    model_path = save_flame_npz(tmp_path / "flame.npz", random_flame_arrays(n_vertices=200, n_shape=4, n_expr=3))
    scene = load_scene("none", flame_model=model_path)
    assert scene.pipeline.avatar is None and scene.pipeline.mesh().shape == (200, 3)
    g = _small_scene().gaussians().numpy()
    ply = save_ply(g.replace(extra={}), tmp_path / "static.ply")
    scene = load_scene(str(ply), flame_model=model_path)
    assert isinstance(scene.pipeline.avatar, StaticAvatar) and "static" in scene.description
    before = np.asarray(scene.pipeline.gaussians().means).copy()
    scene.pipeline.set_face(expr=[1.0, 0.5])
    np.testing.assert_array_equal(np.asarray(scene.pipeline.gaussians().means), before)


def test_flame_params_sequence_adds_a_frame_slider(tmp_path):
    from holo_viewer.flame.default_head import load_default_model
    from holo_viewer.pipeline.scene import load_scene
    from holo_viewer.gui.offscreen_viewer import offscreen_viewer

    T, n_expr = 4, load_default_model().n_expr
    expr = np.zeros((T, n_expr))
    expr[:, 4] = np.linspace(0.0, 1.0, T)  # brows lowering over the sequence
    np.savez(tmp_path / "seq.npz", expr=expr, jaw_pose=np.zeros((T, 3)), rotation=np.zeros((T, 3)),
             neck_pose=np.zeros((T, 3)), eyes_pose=np.zeros((T, 6)), translation=np.zeros((T, 3)),
             shape=np.zeros(5))
    scene = load_scene("none", flame_params=tmp_path / "seq.npz")
    assert len(scene.frames) == T
    with offscreen_viewer(scene, window_size=(480, 270)) as viewer:
        first = np.array(viewer.mesh.points)
        _fire_slider(viewer.sliders["frame"], T - 1)
        assert viewer.pipeline.face.expr[4] == pytest.approx(1.0)
        assert np.abs(np.array(viewer.mesh.points) - first).max() > 1e-4


def test_event_loop_shows_the_thumbnail_from_the_worker(xvfb, tmp_path):
    """run(): the viewer's own event loop; a slider release starts the worker, the loop shows its quilt."""
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    viewer = HoloViewer(_small_scene(), ViewerConfig(window_size=(640, 360), out_dir=str(tmp_path),
                                                     thumbnail_scale=0.1))
    try:
        viewer.open()
        before = viewer._thumb_key
        shot = viewer.read_pixels("quilt").copy()
        _fire_slider(viewer.sliders["expr1"], -1.0)
        assert viewer.run(until=lambda: viewer._thumb_key != before and viewer._thumb_pending_key is None,
                          timeout=30), "thumbnail not shown within 30 s"
        viewer.run(timeout=0.1)
        assert np.abs(viewer.read_pixels("quilt").astype(int) - shot).max() > 30  # on screen, not only in memory
    finally:
        viewer.close()


def test_view_command_opens_a_window_and_q_closes_it(xdotool, tmp_path):
    """The real command in its own process: the window appears on the X display, a real 'q' ends it (exit 0)."""
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen([sys.executable, "-m", "holo_viewer", "view", "--avatar", "none", "--window-size",
                             "640", "360", "--out-dir", str(tmp_path)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        found = subprocess.run([xdotool, "search", "--sync", "--onlyvisible", "--name", "h for help"],
                               capture_output=True, text=True, timeout=90)
        wid = found.stdout.split()[0]
        out = None
        for _ in range(20):  # the window may be mapped before the viewer listens to keys: press again
            subprocess.run([xdotool, "mousemove", "--window", wid, "300", "150"], timeout=10)
            subprocess.run([xdotool, "key", "q"], check=True, timeout=10)
            try:
                out, _ = proc.communicate(timeout=3)
                break
            except subprocess.TimeoutExpired:
                continue
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert "FLAME mesh only" in out and "press h" in out


def test_quit_while_exporting_finishes_the_export_first(xvfb, tmp_path):
    from holo_viewer.gui.viewer import HoloViewer, ViewerConfig

    viewer = HoloViewer(_small_scene(), ViewerConfig(window_size=(640, 360), out_dir=str(tmp_path),
                                                     thumbnail_scale=0.1))
    seen = {}

    def slow(job):  # still running when the window says it will quit after it
        end = time.time() + 30
        while "then quitting" not in viewer._message and time.time() < end:
            time.sleep(0.05)
        seen["status"] = viewer._message
        return viewer._out("late.txt")

    viewer._submit("exporting test", slow)
    viewer.quit()
    viewer.show()  # returns only once the export is written and the window closed
    assert viewer.exports and viewer.exports[-1].name == "late.txt"
    assert "then quitting" in seen["status"]
