"""Offscreen VTK/OSMesa backend: ``vtkPointGaussianMapper`` with anisotropic splats.

A second, independent implementation of the 3DGS forward pass, done by OpenGL
through VTK (>= 9.4), that needs no display: the render window is an offscreen
OSMesa window (``VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow``) when no
``DISPLAY`` is in use. It is the slow baseline the fast CPU rasterizer is measured
against (docs/design.md, "What this machine can do").

How the 3DGS pass maps onto VTK (and where it differs from the float64 reference)
---------------------------------------------------------------------------------
* Projection: each camera's OpenCV ``world_to_cam`` / ``K`` become an explicit
  OpenGL view (camera position, focal point, view-up) and projection matrix
  (:func:`holo_viewer.camera.opencv_to_opengl`, off-axis ``cx`` included), so
  splat centres land on the same pixels as in the reference.
* Covariance: the mapper's anisotropic vertex shader projects ``R S S^T R^T`` with
  the EWA Jacobian in NDC units; the 0.3 px^2 low-pass filter is passed in NDC
  units, ``dilation * (2/W)^2`` and ``dilation * (2/H)^2`` (passing pixels makes
  splats ~100x too large and the pass ~120x slower). The shader does not clamp the
  Jacobian for off-screen centres (the reference clamps at 1.3 tan(fov/2)) and
  drops centres beyond 1.3 NDC.
* Falloff: a splat shader of ours computes ``alpha = min(alpha_cap, o exp(-d^2/2))``
  with ``d`` the Mahalanobis distance in sigmas and discards ``alpha <
  alpha_threshold``; the footprint is an ellipse of ``radius_sigmas`` sigmas
  (``SetBoundScale``), where the reference uses a square box of
  ``ceil(radius_sigmas sqrt(lambda_max))`` pixels. Same Gaussian, slightly
  different cut-off of the faint skirt.
* Order and blending: VTK does not sort splats. We sort them back to front by view
  depth and feed the order as the ``Verts`` cell array; the actor is forced
  translucent and the renderer uses plain "over" blending (no OIT). Back-to-front
  blending cannot stop early, so the reference's ``t_min`` early termination is not
  applied. All cameras of a quilt share one orientation, so one sort serves every
  view; otherwise the cells are re-sorted per view.
* Colour: VTK has no spherical harmonics. Each splat gets one RGB colour, SH
  evaluated once toward the mean camera position (the quilt's centre camera),
  i.e. the reference with ``shared_sh=True``. Views away from the centre lose
  view-dependent colour.
* Precision: blending happens in the 8-bit RGBA framebuffer, so every blend
  step rounds to 1/255 and a splat colour above 1 (SH overshoot, allowed by
  3DGS) is clipped to 1 before blending. On the 100k shell scene (~45 blends per
  pixel) this leaves ~43.5 dB against the reference on DC-only colour and ~40 dB
  against the shared-SH reference; the per-view SH loss brings the outer quilt views
  down to ~30 dB against the exact per-view reference (README, renderer section).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..camera import Cameras, opencv_to_opengl
from ..errors import RenderError
from .config import RenderConfig, RenderResult

__all__ = ["render", "is_available", "offscreen_available", "splat_colors", "BACKEND_NAME"]

BACKEND_NAME = "vtk"

def _import_vtk() -> dict[str, Any]:
    """Import the VTK classes this backend needs (lazily: ``import holo_viewer`` never loads VTK)."""
    try:
        import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL factory overrides)
        from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy
        from vtkmodules.vtkCommonCore import vtkFloatArray, vtkPoints
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
        from vtkmodules.vtkCommonMath import vtkMatrix4x4
        from vtkmodules.vtkRenderingCore import vtkActor, vtkPointGaussianMapper, vtkRenderer, vtkRenderWindow
    except ImportError as exc:
        raise RenderError(f"vtk backend: cannot import VTK ({exc}); install vtk >= 9.4 "
                          "(pip install 'vtk>=9.4')") from exc
    if not hasattr(vtkPointGaussianMapper, "SetLowpassMatrix"):
        raise RenderError("vtk backend: expected vtkPointGaussianMapper with anisotropic splats "
                          "(VTK >= 9.4), found an older VTK without SetLowpassMatrix")
    return dict(numpy_to_vtk=numpy_to_vtk, numpy_to_vtkIdTypeArray=numpy_to_vtkIdTypeArray,
                vtk_to_numpy=vtk_to_numpy, vtkFloatArray=vtkFloatArray, vtkPoints=vtkPoints,
                vtkCellArray=vtkCellArray, vtkPolyData=vtkPolyData, vtkMatrix4x4=vtkMatrix4x4,
                vtkActor=vtkActor, vtkPointGaussianMapper=vtkPointGaussianMapper, vtkRenderer=vtkRenderer,
                vtkRenderWindow=vtkRenderWindow)


def _new_offscreen_window(vtk: dict[str, Any], width: int, height: int) -> Any:
    """An offscreen render window of ``width`` x ``height`` (:func:`holo_viewer.offscreen.new_offscreen_window`)."""
    from ..offscreen import new_offscreen_window

    return new_offscreen_window(vtk["vtkRenderWindow"], width, height, what="vtk backend")


_AVAILABLE: tuple[bool, str] | None = None


def offscreen_available() -> tuple[bool, str]:
    """Whether this process can render offscreen with VTK, and why not (cached).

    Returns
    -------
    ok : bool
    reason : str
        Empty when ``ok``; otherwise the RenderError message (used by tests to skip).
    """
    global _AVAILABLE
    if _AVAILABLE is None:
        try:
            vtk = _import_vtk()
            rw = _new_offscreen_window(vtk, 8, 8)
            rw.Finalize()
            _AVAILABLE = (True, "")
        except RenderError as exc:
            _AVAILABLE = (False, str(exc))
    return _AVAILABLE


def is_available() -> bool:
    """True when VTK imports and an offscreen OpenGL context can be created (cached)."""
    return offscreen_available()[0]


def splat_colors(gaussians: Any, cameras: Cameras, config: RenderConfig) -> tuple[np.ndarray, int]:
    """One RGB colour per Gaussian: SH evaluated toward the mean camera position.

    Parameters
    ----------
    gaussians : holo_viewer.avatar.Gaussians
        N Gaussians (numpy float64).
    cameras : Cameras
        The V cameras; their mean position stands in for the quilt's centre camera.
    config : RenderConfig
        ``sh_degree`` caps the degree used.

    Returns
    -------
    rgb : numpy.ndarray
        (N, 3) float64, ``max(SH(dir) + 0.5, 0)``, not clipped above.
    degree : int
        The SH degree evaluated.
    """
    degree = gaussians.sh_degree if config.sh_degree is None else min(gaussians.sh_degree, config.sh_degree)
    sh = np.asarray(gaussians.sh, dtype=np.float64)
    if degree == 0:
        from ..avatar.gaussians import SH_C0

        return np.maximum(sh[:, 0] * SH_C0 + 0.5, 0.0), 0
    from .sh import eval_sh

    centre = cameras.positions.mean(axis=0)
    dirs = np.asarray(gaussians.means, dtype=np.float64) - centre
    norm = np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs = dirs / np.where(norm > 0, norm, 1.0)
    return np.maximum(eval_sh(degree, sh[:, : (degree + 1) ** 2], dirs) + 0.5, 0.0), degree


#: fragment code of our splat: the 3DGS alpha (cap, threshold) from the Mahalanobis offset
_SPLAT_SHADER = """//VTK::Color::Impl
  float power = -0.5 * dot(offsetVCVSOutput.xy, offsetVCVSOutput.xy);
  float splatAlpha = min({cap:.9g}, opacity * exp(power));
  if (splatAlpha < {thr:.9g}) {{ discard; }}
  opacity = splatAlpha;
"""


def _float_array(vtk: dict[str, Any], values: np.ndarray, name: str) -> Any:
    arr = vtk["numpy_to_vtk"](np.ascontiguousarray(values, dtype=np.float32), deep=1)
    arr.SetName(name)
    return arr


def _verts(vtk: dict[str, Any], order: np.ndarray) -> Any:
    """A vtkCellArray of one vertex cell per index in ``order`` (drawn in that order)."""
    cells = vtk["vtkCellArray"]()
    offsets = np.arange(order.size + 1, dtype=np.int64)
    cells.SetData(vtk["numpy_to_vtkIdTypeArray"](offsets, deep=1),
                  vtk["numpy_to_vtkIdTypeArray"](np.ascontiguousarray(order, dtype=np.int64), deep=1))
    return cells


def _set_camera(vtk: dict[str, Any], camera: Any, cams: Cameras, i: int, proj: np.ndarray) -> None:
    """Point a vtkCamera exactly like OpenCV camera ``i`` (explicit projection matrix)."""
    R = cams.R[i]
    pos = cams.positions[i]
    camera.SetPosition(*pos)
    camera.SetFocalPoint(*(pos + R[2]))  # camera +z is the viewing direction
    camera.SetViewUp(*(-R[1]))  # camera +y points down in the image
    m = vtk["vtkMatrix4x4"]()
    m.DeepCopy(proj.ravel().tolist())
    camera.SetExplicitProjectionTransformMatrix(m)
    camera.UseExplicitProjectionTransformMatrixOn()


def render(gaussians: Any, cameras: Cameras, config: RenderConfig | None = None) -> RenderResult:
    """Render V views with VTK's anisotropic point-Gaussian mapper, offscreen.

    Parameters
    ----------
    gaussians : holo_viewer.avatar.Gaussians
        N Gaussians (numpy or torch; copied to float64 numpy). Validated by the caller
        (:func:`holo_viewer.render.api.render_views`).
    cameras : Cameras
        V cameras of one size W x H.
    config : RenderConfig, optional
        Honoured: ``background``, ``alpha_threshold``, ``alpha_cap``, ``radius_sigmas``
        (ellipse bound), ``dilation``, ``near``, ``sh_degree``; SH is always shared across
        views (``shared_sh`` is implied). Not applicable: ``t_min``, ``tile_size``,
        ``cull_margin``, ``num_threads``, ``kernel``, ``max_chunk_bytes``.

    Returns
    -------
    RenderResult
        ``images`` (V, H, W, 3) float32 in [0, 1], row 0 at the top; timings "preprocess",
        "sort", "setup", "render" (draw and read back), "total".

    Raises
    ------
    RenderError
        VTK is missing/too old or no offscreen OpenGL context can be created.
    """
    t_start = time.perf_counter()
    config = config or RenderConfig()
    vtk = _import_vtk()
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    g = gaussians.numpy(np.float64)
    near = cameras.near if config.near is None else float(config.near)
    means = np.asarray(g.means)
    rgb, degree = splat_colors(g, cameras, config)
    opac = np.asarray(g.opacities)
    # a splat whose opacity is below the threshold can never pass the alpha test
    keep = opac >= config.alpha_threshold
    depth = np.einsum("vj,nj->vn", cameras.R[:, 2], means) + cameras.t[:, 2:3]  # (V, N) view depth
    keep &= (depth > near).any(axis=0)
    idx = np.flatnonzero(keep)
    quats = np.asarray(g.quats)[idx]
    quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    timings["preprocess"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    shared = cameras.shared_orientation
    # back to front: farthest first. With one shared orientation the order is the same in every view.
    orders = [np.argsort(-depth[0, idx], kind="stable")] if shared else None
    timings["sort"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    W, H = cameras.width, cameras.height
    poly = vtk["vtkPolyData"]()
    pts = vtk["vtkPoints"]()
    pts.SetData(_float_array(vtk, means[idx], "points"))
    poly.SetPoints(pts)
    pdata = poly.GetPointData()
    pdata.AddArray(_float_array(vtk, np.exp(np.asarray(g.log_scales)[idx]), "scale"))
    pdata.AddArray(_float_array(vtk, quats, "rotation"))
    pdata.AddArray(_float_array(vtk, opac[idx], "opacity"))
    colors = _float_array(vtk, np.clip(rgb[idx], 0.0, 1.0), "rgb")
    pdata.AddArray(colors)
    pdata.SetScalars(colors)
    poly.SetVerts(_verts(vtk, orders[0] if shared else np.arange(idx.size)))

    mapper = vtk["vtkPointGaussianMapper"]()
    mapper.SetInputData(poly)
    mapper.EmissiveOff()
    mapper.AnisotropicOn()
    mapper.SetScaleArray("scale")
    mapper.SetRotationArray("rotation")
    mapper.SetOpacityArray("opacity")
    mapper.SetScaleFactor(1.0)
    mapper.SetBoundScale(float(config.radius_sigmas))
    mapper.SetLowpassMatrix(config.dilation * (2.0 / W) ** 2, 0.0, config.dilation * (2.0 / H) ** 2)
    mapper.SetSplatShaderCode(_SPLAT_SHADER.format(cap=config.alpha_cap, thr=config.alpha_threshold))
    mapper.SetColorModeToDirectScalars()
    mapper.ScalarVisibilityOn()

    actor = vtk["vtkActor"]()
    actor.SetMapper(mapper)
    actor.ForceTranslucentOn()
    actor.GetProperty().LightingOff()
    renderer = vtk["vtkRenderer"]()
    renderer.AddActor(actor)
    renderer.SetBackground(*config.background)
    renderer.SetUseOIT(False)

    window = _new_offscreen_window(vtk, W, H)
    window.AddRenderer(renderer)
    timings["setup"] = time.perf_counter() - t0

    cams_view = cameras
    if config.near is not None and config.near != cameras.near:
        cams_view = Cameras(cameras.world_to_cam, cameras.K, W, H, near, max(cameras.far, near * 2))
    _, proj = opencv_to_opengl(cams_view)
    images = np.empty((len(cameras), H, W, 3), dtype=np.float32)
    buf = vtk["vtkFloatArray"]()
    t0 = time.perf_counter()
    t_sort = 0.0
    try:
        camera = renderer.GetActiveCamera()
        for i in range(len(cameras)):
            if not shared:
                ts = time.perf_counter()
                poly.SetVerts(_verts(vtk, np.argsort(-depth[i, idx], kind="stable")))
                t_sort += time.perf_counter() - ts
            _set_camera(vtk, camera, cameras, i, proj[i])
            window.Render()
            window.GetRGBAPixelData(0, 0, W - 1, H - 1, 1, buf)
            rgba = vtk["vtk_to_numpy"](buf).reshape(H, W, 4)
            images[i] = rgba[::-1, :, :3]  # OpenGL rows start at the bottom
    finally:
        window.Finalize()
    timings["sort"] += t_sort
    timings["render"] = time.perf_counter() - t0 - t_sort
    np.clip(images, 0.0, 1.0, out=images)
    timings["total"] = time.perf_counter() - t_start
    stats = {"n_input": len(g), "n_visible": int(idx.size), "sh_degree": degree, "shared_orientation": int(shared)}
    return RenderResult(images=images, timings=timings, stats=stats, backend=BACKEND_NAME)
