"""Offscreen VTK point-Gaussian backend against the float64 reference (skipped without offscreen GL)."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from holo_viewer.avatar.gaussians import Gaussians
from holo_viewer.camera import Cameras, intrinsics, look_at
from holo_viewer.render import reference, vtk_backend
from holo_viewer.render.config import RenderConfig

W, H = 48, 40


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def _skip_reason() -> str:
    ok, reason = vtk_backend.offscreen_available()
    return "" if ok else reason


needs_gl = pytest.mark.skipif(bool(_skip_reason()), reason=f"no VTK offscreen rendering: {_skip_reason()}")


def quilt(n_views: int = 3, shared: bool = True) -> Cameras:
    w2c, Ks = [], []
    for k in range(n_views):
        off = (k - (n_views - 1) / 2) * 0.1
        if shared:  # sheared quilt cameras: shifted eye, shifted principal point
            w2c.append(look_at([off, 0.0, 1.0], [off, 0.0, 0.0]))
            Ks.append(intrinsics(60.0, 60.0, W / 2 - 60.0 * off, H / 2))
        else:
            w2c.append(look_at([off, 0.04, 1.0], [0.0, 0.0, 0.0]))
            Ks.append(intrinsics(60.0, 62.0, W / 2 + 2.3, H / 2 - 1.6))
    return Cameras(np.stack(w2c), np.stack(Ks), W, H)


def dc_scene(n: int = 300, seed: int = 0) -> Gaussians:
    """Random anisotropic Gaussians, DC colour only, colours inside [0, 1]."""
    rng = np.random.default_rng(seed)
    sh = rng.uniform(-1.5, 1.5, (n, 1, 3))
    return Gaussians.from_arrays(rng.normal(0.0, 0.1, (n, 3)), rng.normal(size=(n, 4)),
                                 np.log(rng.uniform(0.005, 0.05, (n, 3))), rng.normal(1.0, 1.5, n), sh)


def test_import_is_lazy_and_env_untouched() -> None:
    """Importing the backend loads no VTK and sets no OpenGL window variable."""
    code = ("import os, sys; import holo_viewer.render.vtk_backend; "
            "print(any(m.startswith('vtkmodules') for m in sys.modules), "
            "'VTK_DEFAULT_OPENGL_WINDOW' in os.environ)")
    env = {k: v for k, v in os.environ.items() if k != "VTK_DEFAULT_OPENGL_WINDOW"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.split() == ["False", "False"]


@needs_gl
def test_single_gaussian_lands_on_the_reference_pixel() -> None:
    """An isotropic Gaussian seen by off-axis cameras: same peak pixel, same footprint (8-bit)."""
    g = Gaussians.from_arrays(np.array([[0.013, 0.031, 0.0]]), np.array([[1.0, 0, 0, 0]]),
                              np.log(np.full((1, 3), 0.02)), np.array([1.5]), np.full((1, 1, 3), 1.7))
    cams = quilt(3)
    ref = reference.render(g, cams).images
    out = vtk_backend.render(g, cams)
    assert out.images.shape == (3, H, W, 3) and out.images.dtype == np.float32
    uv, _ = cams.project(np.asarray(g.means))
    for v in range(3):
        peak = np.unravel_index(np.argmax(out.images[v, :, :, 0]), (H, W))
        assert peak == np.unravel_index(np.argmax(ref[v, :, :, 0]), (H, W))
        assert peak == (int(uv[v, 0, 1]), int(uv[v, 0, 0]))
        assert np.abs(out.images[v] - ref[v]).max() < 3.0 / 255.0


@needs_gl
def test_dc_scene_matches_reference() -> None:
    """Only 8-bit blending and the footprint cut-off differ on a DC-only scene."""
    g, cams = dc_scene(), quilt(3)
    config = RenderConfig(background=(0.2, 0.3, 0.4))
    ref = reference.render(g, cams, config).images
    out = vtk_backend.render(g, cams, config)
    for v in range(3):
        assert psnr(out.images[v], ref[v]) >= 40.0, f"view {v}"
    assert out.stats["shared_orientation"] == 1


@needs_gl
def test_unshared_orientation_resorts_per_view() -> None:
    g, cams = dc_scene(seed=2), quilt(3, shared=False)
    ref = reference.render(g, cams).images
    out = vtk_backend.render(g, cams)
    assert out.stats["shared_orientation"] == 0
    assert min(psnr(out.images[v], ref[v]) for v in range(3)) >= 40.0


@needs_gl
def test_back_to_front_order() -> None:
    """Two overlapping opaque splats: the nearer colour wins, whatever the input order."""
    means = np.array([[0.0, 0.0, 0.2], [0.0, 0.0, -0.2]])  # first is nearer (cameras at z = 1)
    for perm in ([0, 1], [1, 0]):
        sh = np.array([[[1.7, -1.7, -1.7]], [[-1.7, -1.7, 1.7]]])  # red near, blue far
        g = Gaussians.from_arrays(means[perm], np.tile([1.0, 0, 0, 0], (2, 1)), np.log(np.full((2, 3), 0.05)),
                                  np.full(2, 8.0), sh[perm])
        img = vtk_backend.render(g, quilt(1)).images[0]
        c = img[H // 2, W // 2]
        assert c[0] > 0.9 and c[2] < 0.1


@needs_gl
def test_sh_colour_is_evaluated_toward_the_quilt_centre() -> None:
    """With SH, VTK equals the reference's shared_sh mode (colour from the mean camera position)."""
    rng = np.random.default_rng(4)
    g = dc_scene(seed=4)
    sh = np.concatenate([np.asarray(g.sh), rng.normal(0.0, 0.1, (len(g), 15, 3))], axis=1)
    g = g.replace(sh=sh)
    cams = quilt(3)
    out = vtk_backend.render(g, cams)
    shared = reference.render(g, cams, RenderConfig(shared_sh=True)).images
    assert out.stats["sh_degree"] == 3
    assert min(psnr(out.images[v], shared[v]) for v in range(3)) >= 40.0


@needs_gl
def test_empty_scene_is_background_and_render_views() -> None:
    from holo_viewer.render.api import render_views

    g = dc_scene(n=4).replace(means=np.full((4, 3), 3.0))  # behind every camera
    out = render_views(g, quilt(2), backend="vtk", config=RenderConfig(background=(0.25, 0.5, 0.75)))
    assert out.backend == "vtk"
    assert np.abs(out.images - np.array([0.25, 0.5, 0.75], np.float32)).max() <= 0.5 / 255.0 + 1e-6


def test_missing_vtk_is_a_render_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from holo_viewer.errors import RenderError

    monkeypatch.setitem(sys.modules, "vtkmodules.vtkRenderingCore", None)  # makes the import fail
    with pytest.raises(RenderError, match="cannot import VTK"):
        vtk_backend.render(dc_scene(n=2), quilt(1))


def test_offscreen_policy_leaves_the_environment_alone(monkeypatch):
    """holo_viewer.offscreen: OSMesa is chosen without a display only while a window is created."""
    import os

    from holo_viewer.offscreen import WINDOW_ENV, offscreen_window_class

    monkeypatch.delenv(WINDOW_ENV, raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with offscreen_window_class() as chosen:
        assert chosen == os.environ[WINDOW_ENV] == "vtkOSOpenGLRenderWindow"
    assert WINDOW_ENV not in os.environ
    monkeypatch.setenv(WINDOW_ENV, "vtkEGLRenderWindow")  # the user's choice wins ...
    with offscreen_window_class() as chosen:
        assert chosen == "vtkEGLRenderWindow"
    with offscreen_window_class(force_osmesa=True) as chosen:  # ... unless OSMesa is forced
        assert chosen == "vtkOSOpenGLRenderWindow"
    assert os.environ[WINDOW_ENV] == "vtkEGLRenderWindow"
    monkeypatch.delenv(WINDOW_ENV)
    monkeypatch.setenv("DISPLAY", ":99")
    with offscreen_window_class() as chosen:
        assert chosen is None and WINDOW_ENV not in os.environ


def test_mesh_preview_sets_no_process_wide_vtk_variable():
    import subprocess
    import sys

    code = ("import os; os.environ.pop('DISPLAY', None); os.environ.pop('VTK_DEFAULT_OPENGL_WINDOW', None)\n"
            "import numpy as np\nfrom holo_viewer.flame.preview import render_mesh\n"
            "v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.]]); f = np.array([[0, 1, 2]])\n"
            "try:\n    render_mesh(v, f, views=('front',), size=(16, 16))\nexcept Exception as e:\n    print('ERR', e)\n"
            "print(os.environ.get('VTK_DEFAULT_OPENGL_WINDOW'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "None"
