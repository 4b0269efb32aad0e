"""Offscreen shaded renders of a triangle mesh (VTK), and the default head's demo renders.

``render_mesh`` is generic (any (V, 3) mesh with per-vertex colours) so the GUI
snapshot can reuse it. VTK is imported lazily; its window comes from
:func:`holo_viewer.offscreen.new_offscreen_window` (OSMesa without a display, the
environment left as it was). Views are named cameras around the FLAME frame
(+y up, the face looking along +z): ``front`` (on the +z axis), ``three_quarter``
(40 degrees toward the subject's left, +x), ``side`` (on the +x axis), ``back``,
``top``, or ``(yaw_deg, pitch_deg)`` tuples.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import InputError, MissingDependencyError, RenderError
from ..validation import check_array

__all__ = ["render_mesh", "render_mesh_cameras", "box_downsample", "region_colors", "smooth_vertex_colors", "REGION_COLORS", "contact_sheet", "write_head_renders",
           "HEAD_POSES"]

_VIEWS = {"front": (0.0, 0.0), "three_quarter": (40.0, 5.0), "side": (90.0, 0.0), "back": (180.0, 0.0),
          "top": (0.0, 70.0), "left": (-90.0, 0.0), "right": (90.0, 0.0)}

#: Linear RGB in [0, 1] per region name of the default head.
REGION_COLORS = {
    "skin": (0.86, 0.66, 0.55), "scalp": (0.8, 0.62, 0.52), "brows": (0.3, 0.2, 0.14),
    "lips": (0.74, 0.4, 0.4), "eyeball_left": (0.95, 0.94, 0.92), "eyeball_right": (0.95, 0.94, 0.92),
    "iris": (0.3, 0.45, 0.6), "pupil": (0.04, 0.04, 0.05), "ears": (0.84, 0.62, 0.52),
    "mouth_interior": (0.45, 0.16, 0.17), "eye_pocket": (0.5, 0.25, 0.25), "neck": (0.84, 0.64, 0.53),
    "nostrils": (0.5, 0.3, 0.27), "teeth": (0.93, 0.92, 0.86), "hair": (0.22, 0.15, 0.1),
    "lashes": (0.06, 0.05, 0.05), "tongue": (0.72, 0.36, 0.36), "gums": (0.78, 0.42, 0.44),
}


def _import_vtk():
    try:
        import vtk  # noqa: F401
        from vtk.util import numpy_support
    except ImportError as exc:  # pragma: no cover - vtk is a core dependency
        raise MissingDependencyError("vtk", "offscreen mesh preview", "core") from exc
    return vtk, numpy_support


def region_colors(region: np.ndarray, region_names: Sequence[str], n_vertices: int | None = None) -> np.ndarray:
    """Per-vertex colours from region labels; vertices beyond the labels (e.g. teeth) are teeth-white.

    Parameters
    ----------
    region : numpy.ndarray
        (V0,) int labels into ``region_names``.
    region_names : sequence of str
        Names; unknown names get the skin colour.
    n_vertices : int, optional
        Total vertex count V >= V0 (FLAME teeth appended after the labelled vertices).

    Returns
    -------
    numpy.ndarray
        (V, 3) float32 colours in [0, 1].
    """
    region = np.asarray(region, dtype=np.int64)
    n = len(region) if n_vertices is None else int(n_vertices)
    table = np.array([REGION_COLORS.get(str(name), REGION_COLORS["skin"]) for name in region_names])
    out = np.tile(np.asarray(REGION_COLORS["teeth"]), (n, 1))
    out[: len(region)] = table[np.clip(region, 0, len(table) - 1)]
    return out.astype(np.float32)


def smooth_vertex_colors(colors: np.ndarray, faces: np.ndarray, iterations: int = 2) -> np.ndarray:
    """Average each vertex colour with its face neighbours (softens region boundaries).

    Parameters
    ----------
    colors : numpy.ndarray
        (V, 3) colours.
    faces : numpy.ndarray
        (F, 3) triangles.
    iterations : int
        Number of averaging passes.

    Returns
    -------
    numpy.ndarray
        (V, 3) float32 colours.
    """
    c = np.asarray(colors, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = len(c)
    for _ in range(int(iterations)):
        acc = c.copy()
        cnt = np.ones(n)
        for a, b in ((0, 1), (1, 2), (2, 0), (1, 0), (2, 1), (0, 2)):
            np.add.at(acc, f[:, a], c[f[:, b]])
            np.add.at(cnt, f[:, a], 1.0)
        c = acc / cnt[:, None]
    return c.astype(np.float32)


def _camera_dir(view: Any) -> tuple[np.ndarray, str]:
    if isinstance(view, str):
        if view not in _VIEWS:
            raise InputError(f"views: unknown view {view!r}; expected one of {sorted(_VIEWS)} or (yaw, pitch)")
        yaw, pitch = _VIEWS[view]
        name = view
    else:
        try:
            yaw, pitch = (float(a) for a in view)
        except (TypeError, ValueError) as exc:
            raise InputError(f"views: expected a view name or (yaw_deg, pitch_deg), found {view!r}") from exc
        name = f"yaw{yaw:g}_pitch{pitch:g}"
    y, p = np.radians(yaw), np.radians(pitch)
    return np.array([np.cos(p) * np.sin(y), np.sin(p), np.cos(p) * np.cos(y)]), name


def render_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    views: Sequence[Any] = ("front", "three_quarter", "side"),
    size: tuple[int, int] = (512, 512),
    colors: np.ndarray | None = None,
    background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    fov_deg: float = 20.0,
    target: np.ndarray | None = None,
    distance: float | None = None,
    appearance: Any = None,
) -> list[np.ndarray]:
    """Render a shaded triangle mesh offscreen from named views.

    Parameters
    ----------
    vertices : numpy.ndarray
        (V, 3) positions, metres, FLAME frame (+y up, face toward +z).
    faces : numpy.ndarray
        (F, 3) integer triangles.
    views : sequence
        View names (``front``, ``three_quarter``, ``side``, ``back``, ``top``, ``left``,
        ``right``) or (yaw_deg, pitch_deg) pairs; yaw turns toward +x.
    size : (int, int)
        Image (width, height) in pixels.
    colors : numpy.ndarray, optional
        (V, 3) per-vertex RGB in [0, 1]; default a uniform skin tone.
    background : (float, float, float)
        Background RGB.
    fov_deg : float
        Vertical field of view of the perspective camera.
    target, distance : optional
        Look-at point (default: bounding-box centre) and camera distance (default:
        framing the bounding sphere).
    appearance : HeadAppearance, optional
        Textures and materials of the mesh (:mod:`holo_viewer.flame.appearance`); when given,
        ``colors`` is ignored and each material is drawn textured (or vertex-coloured) with its
        own specular.

    Returns
    -------
    list of numpy.ndarray
        One (height, width, 3) float32 image in [0, 1] per view, row 0 at the top.
    """
    v = np.asarray(check_array(vertices, "vertices", ("V", 3)), dtype=np.float64)
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"faces: expected an integer array of shape (F, 3), found {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InputError(f"faces: indices must lie in [0, {len(v)}), found [{f.min()}, {f.max()}]")
    if colors is None:
        colors = np.tile(np.asarray(REGION_COLORS["skin"]), (len(v), 1))
    colors = np.asarray(check_array(colors, "colors", (len(v), 3)), dtype=np.float64)
    w, h = int(size[0]), int(size[1])
    if w < 8 or h < 8:
        raise InputError(f"size: expected at least 8x8 pixels, found {size}")
    cam_dirs = [_camera_dir(view)[0] for view in views]  # validate names before any GL work
    vtk, nps = _import_vtk()

    ren = mesh_renderer(vtk, nps, v, f, colors, background, appearance=appearance)
    from ..offscreen import new_offscreen_window

    win = new_offscreen_window(vtk.vtkRenderWindow, w, h, multisamples=None, what="render_mesh")
    win.AddRenderer(ren)
    lo, hi = v.min(0), v.max(0)
    centre = 0.5 * (lo + hi) if target is None else np.asarray(target, dtype=np.float64)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    dist = distance if distance is not None else 1.1 * radius / np.tan(np.radians(fov_deg) / 2)
    images = []
    try:
        for d in cam_dirs:
            cam = ren.GetActiveCamera()
            eye = centre + dist * d
            cam.SetPosition(*eye)
            cam.SetFocalPoint(*centre)
            up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.95 else np.array([0.0, 0.0, -1.0])
            cam.SetViewUp(*up)
            cam.SetViewAngle(fov_deg)
            cam.SetClippingRange(max(dist - 3 * radius, 1e-3), dist + 3 * radius)
            add_key_lights(vtk, ren, centre, dist, d, up)
            win.Render()
            images.append(_grab(vtk, nps, win, "rgb").astype(np.float32) / 255.0)
    except (RuntimeError, ValueError, TypeError, AttributeError) as exc:  # VTK/GL failures
        raise RenderError(f"render_mesh: offscreen VTK rendering failed ({exc})") from exc
    finally:
        win.Finalize()
    return images


def render_mesh_cameras(vertices: np.ndarray, faces: np.ndarray, cameras: Any, indices: Sequence[int] | None = None,
                        colors: np.ndarray | None = None,
                        background: tuple[float, float, float] = (0.0, 0.0, 0.0),
                        appearance: Any = None, supersample: int = 1, coverage: bool = False
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Render a vertex-coloured mesh through pinhole cameras with their exact OpenCV intrinsics (VTK).

    Lighting, material and normals are those of :func:`render_mesh`; the camera is the given
    camera: centre, orientation, vertical view angle ``2 atan(H / 2 fy)`` and the principal point
    (cx, cy) as VTK's window centre (an off-axis frustum, as the quilt cameras). The lights are
    directional and set from each camera's orientation only, so cameras sharing one orientation
    (every quilt camera) see the mesh under the same world-fixed lights.

    Parameters
    ----------
    vertices, faces : numpy.ndarray
        (V, 3) positions (metres) and (F, 3) triangles.
    cameras : holo_viewer.camera.Cameras
        ``world_to_cam`` (N, 4, 4), ``K`` (N, 3, 3), ``width``, ``height``, ``near``, ``far``.
    indices : sequence of int, optional
        Cameras to render (default all).
    colors : numpy.ndarray, optional
        (V, 3) per-vertex RGB in [0, 1]; default a uniform skin tone.
    background : (float, float, float)
        Background RGB.
    appearance : HeadAppearance, optional
        Draw the textured head instead of ``colors`` (as :func:`render_mesh`).
    supersample : int
        ``s`` > 1 renders each camera at ``s W x s H`` (the same frustum: view angle and window centre
        are unchanged, so sub-pixel ``(j, k)`` of pixel ``(x, y)`` samples the point
        ``(x + (j + 0.5) / s, y + (k + 0.5) / s)`` of the ``W x H`` image plane) and box-filters each
        ``s x s`` block (:func:`box_downsample`, float64, in the 8-bit buffer's sRGB code values): the
        pixel-area average of the picture, as a camera integrates a pixel, instead of one sample at
        the pixel centre (aliased silhouettes). The mask is then ``coverage >= 0.5`` (coverage: the
        fraction of a pixel's sub-samples with depth < 1). Default 1: one sample per pixel (unchanged).
        VTK picks the texture's mipmap level per sub-pixel, so the interior is sharper than at ``s = 1``
        (where the mipmap already averages the texture over the pixel), not only the silhouette.
    coverage : bool
        Return each pixel's coverage (float32 in [0, 1], the fraction of its sub-samples with depth < 1)
        instead of the bool mask.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        (n, H, W, 3) float32 images in [0, 1] and (n, H, W) bool masks (depth buffer < 1), or float32
        coverages (``coverage=True``).
    """
    v = np.asarray(check_array(vertices, "vertices", ("V", 3)), dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if colors is None:
        colors = np.tile(np.asarray(REGION_COLORS["skin"]), (len(v), 1))
    colors = np.asarray(check_array(colors, "colors", (len(v), 3)), dtype=np.float64)
    idx = list(range(len(cameras))) if indices is None else [int(i) for i in indices]
    for i in idx:
        if not 0 <= i < len(cameras):
            raise InputError(f"indices: expected camera indices in [0, {len(cameras)}), found {i}")
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or not 1 <= supersample <= 8:
        raise InputError(f"supersample: expected an integer in [1, 8], found {supersample!r}")
    ss = int(supersample)
    vtk, nps = _import_vtk()
    from ..offscreen import new_offscreen_window

    W, H = int(cameras.width), int(cameras.height)
    ren = mesh_renderer(vtk, nps, v, f, colors, background, appearance=appearance)
    win = new_offscreen_window(vtk.vtkRenderWindow, W * ss, H * ss, multisamples=None, what="render_mesh_cameras")
    win.AddRenderer(ren)
    images, masks = [], []
    try:
        for i in idx:
            R, t, K = cameras.world_to_cam[i, :3, :3], cameras.world_to_cam[i, :3, 3], cameras.K[i]
            C = -R.T @ t
            fwd, up = R[2], -R[1]  # OpenCV +z forward, +y down
            centre = C + fwd
            cam = ren.GetActiveCamera()
            cam.SetPosition(*C)
            cam.SetFocalPoint(*centre)
            cam.SetViewUp(*up)
            cam.SetViewAngle(float(np.degrees(2 * np.arctan(0.5 * H / K[1, 1]))))
            cam.SetWindowCenter(float(1 - 2 * K[0, 2] / W), float(2 * K[1, 2] / H - 1))  # optical axis at (cx, cy)
            cam.SetClippingRange(cameras.near, cameras.far)
            add_key_lights(vtk, ren, centre, 1.0, -fwd, up)
            win.Render()
            if ss == 1:
                images.append(_grab(vtk, nps, win, "rgb").astype(np.float32) / 255.0)
                cov = (_grab(vtk, nps, win, "z")[..., 0] < 1.0).astype(np.float64)
            else:
                images.append(box_downsample(_grab(vtk, nps, win, "rgb") / 255.0, ss).astype(np.float32))
                cov = box_downsample(_grab(vtk, nps, win, "z")[..., 0] < 1.0, ss)
            masks.append(cov.astype(np.float32) if coverage else cov >= 0.5)
    except (RuntimeError, ValueError, TypeError, AttributeError) as exc:  # VTK/GL failures
        raise RenderError(f"render_mesh_cameras: offscreen VTK rendering failed ({exc})") from exc
    finally:
        win.Finalize()
    if not images:
        return np.zeros((0, H, W, 3), np.float32), np.zeros((0, H, W), np.float32 if coverage else bool)
    return np.stack(images), np.stack(masks)


def box_downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """The float64 mean of each ``factor x factor`` block of ``image`` ((H f, W f) or (H f, W f, C)):
    the (H, W[, C]) pixel-area average of a picture sampled ``factor`` times finer on each axis."""
    a = np.asarray(image, dtype=np.float64)
    f = int(factor)
    if f < 1 or a.ndim not in (2, 3) or a.shape[0] % f or a.shape[1] % f:
        raise InputError(f"box_downsample: expected an (H*{f}, W*{f}[, C]) array, found shape {a.shape}")
    return a.reshape(a.shape[0] // f, f, a.shape[1] // f, f, *a.shape[2:]).mean(axis=(1, 3))


def _grab(vtk: Any, nps: Any, win: Any, kind: str) -> np.ndarray:
    """The rendered window's back buffer, row 0 at the top: ``rgb`` (H, W, 3) uint8 or ``z`` (H, W, 1) depth."""
    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(win)
    grab.SetInputBufferTypeToRGB() if kind == "rgb" else grab.SetInputBufferTypeToZBuffer()
    grab.ReadFrontBufferOff()
    grab.Update()
    w, h = win.GetSize()
    arr = nps.vtk_to_numpy(grab.GetOutput().GetPointData().GetScalars())
    return np.ascontiguousarray(arr.reshape(h, w, -1)[::-1])


def contact_sheet(rows: Sequence[Sequence[np.ndarray]], pad: int = 4,
                  background: float = 1.0) -> np.ndarray:
    """Tile images (all the same size) into one grid image; row r, column c = rows[r][c]."""
    if not rows or not rows[0]:
        raise InputError("contact_sheet: expected at least one image")
    h, w = rows[0][0].shape[:2]
    n_r, n_c = len(rows), max(len(r) for r in rows)
    sheet = np.full((n_r * h + (n_r + 1) * pad, n_c * w + (n_c + 1) * pad, 3), background, np.float32)
    for i, row in enumerate(rows):
        for j, img in enumerate(row):
            if img.shape[:2] != (h, w):
                raise InputError(f"contact_sheet: image [{i}][{j}] has shape {img.shape}, expected {(h, w, 3)}")
            y0, x0 = pad + i * (h + pad), pad + j * (w + pad)
            sheet[y0:y0 + h, x0:x0 + w] = img[..., :3]
    return sheet


#: The poses of :func:`write_head_renders`: name -> (expression name, intensity).
HEAD_POSES = (("neutral", 0.0), ("smile", 1.0), ("pain", 1.0), ("mouth_open", 1.0))


def write_head_renders(out_dir: str | os.PathLike, model: Any,
                       views: Sequence[str] = ("front", "three_quarter", "side"),
                       size: tuple[int, int] = (400, 480), verbose: bool = True,
                       textured: bool = True) -> list[Path]:
    """Pose a FLAME-format model (neutral, smile, pain, mouth open), render and write PNGs.

    Writes ``{pose}_{view}.png`` for every pose and view and ``contact_sheet.png``
    (rows = poses, columns = views), atomically.

    Parameters
    ----------
    out_dir : path
        Output folder (created).
    model : FlameModel
        The default head (or any model that :func:`~holo_viewer.flame.expressions.au_map_for` accepts).
    views : sequence of str
        View names for :func:`render_mesh`.
    size : (int, int)
        (width, height) of each view.
    verbose : bool
        Print each written file.
    textured : bool
        Draw the model's generated textures (:func:`holo_viewer.flame.head_textures.head_appearance`)
        when it carries texture coordinates (the default head); other models, or ``False``, get the
        smoothed region colours.

    Returns
    -------
    list of pathlib.Path
        The files written, contact sheet last.
    """
    import torch

    from ..fileio import save_image
    from .expressions import au_map_for, jaw_for_expression, named_expression

    out = Path(out_dir)
    au_map = au_map_for(model)
    faces = model.faces.cpu().numpy()
    meta = getattr(model, "metadata", {}) or {}
    n_v = int(model.n_vertices)
    appearance = None
    if textured:
        from .head_textures import head_appearance

        appearance = head_appearance(model, verbose=verbose)
    if appearance is not None:
        colors = None
    elif "vertex_region" in meta and "region_names" in meta:
        colors = region_colors(meta["vertex_region"], [str(s) for s in meta["region_names"]], n_v)
        colors = smooth_vertex_colors(colors, faces, 1)
    else:
        colors = None
    written: list[Path] = []
    sheet_rows = []
    for name, intensity in HEAD_POSES:
        expr = named_expression(name, intensity, au_map)
        jaw = jaw_for_expression(name, intensity)
        with torch.no_grad():
            outp = model(expr=torch.as_tensor(expr, dtype=model.dtype)[None],
                         jaw_pose=torch.as_tensor(jaw, dtype=model.dtype)[None])
        verts = outp.vertices[0].cpu().numpy().astype(np.float64)
        rest_lo, rest_hi = verts.min(0), verts.max(0)
        target = 0.5 * (rest_lo + rest_hi)
        imgs = render_mesh(verts, faces, views=views, size=size, colors=colors, target=target,
                           distance=0.95, appearance=appearance)
        sheet_rows.append(imgs)
        for view, img in zip(views, imgs):
            path = save_image(out / f"{name}_{view}.png", img)
            written.append(path)
            if verbose:
                print(f"wrote {path}")
    sheet = save_image(out / "contact_sheet.png", contact_sheet(sheet_rows))
    written.append(sheet)
    if verbose:
        print(f"wrote {sheet}  (rows: {', '.join(n for n, _ in HEAD_POSES)}; columns: {', '.join(views)})")
    return written


def mesh_renderer(vtk: Any, nps: Any, vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None,
                  background: tuple[float, float, float], appearance: Any = None) -> Any:
    """A vtkRenderer holding the shaded, vertex-coloured mesh (no lights; see :func:`add_key_lights`).

    ``vertices`` (V, 3) float64, ``faces`` (F, 3) integer, ``colors`` (V, 3) RGB in [0, 1]; the one
    material and normal set-up of every mesh render (the previews and the face-realism benchmark).
    With ``appearance`` (a :class:`~holo_viewer.flame.appearance.HeadAppearance` of this mesh's
    topology) the mesh is drawn textured instead: see :func:`textured_actors`.
    """
    if appearance is not None:
        ren = vtk.vtkRenderer()
        for actor in textured_actors(vtk, nps, vertices, faces, appearance):
            ren.AddActor(actor)
        ren.SetBackground(*background)
        ren.AutomaticLightCreationOff()
        return ren
    pts = vtk.vtkPoints()
    pts.SetData(nps.numpy_to_vtk(np.ascontiguousarray(vertices, dtype=np.float64), deep=True))
    polys = vtk.vtkCellArray()
    offsets = np.arange(0, 3 * len(faces) + 1, 3, dtype=np.int64)
    polys.SetData(nps.numpy_to_vtkIdTypeArray(offsets, deep=True),
                  nps.numpy_to_vtkIdTypeArray(np.ascontiguousarray(faces, dtype=np.int64).ravel(), deep=True))
    poly = vtk.vtkPolyData()
    poly.SetPoints(pts)
    poly.SetPolys(polys)
    rgb = nps.numpy_to_vtk(np.ascontiguousarray(np.clip(colors, 0, 1) * 255).astype(np.uint8), deep=True)
    rgb.SetName("rgb")
    poly.GetPointData().SetScalars(rgb)
    normals = vtk.vtkPolyDataNormals()
    normals.SetInputData(poly)
    normals.SetFeatureAngle(60.0)
    normals.SplittingOff()
    normals.ConsistencyOff()
    normals.AutoOrientNormalsOff()
    mapper = vtk.vtkPolyDataMapper()
    mapper.SetInputConnection(normals.GetOutputPort())
    mapper.SetColorModeToDirectScalars()
    actor = vtk.vtkActor()
    actor.SetMapper(mapper)
    prop = actor.GetProperty()
    prop.SetInterpolationToPhong()
    prop.SetAmbient(0.25)
    prop.SetDiffuse(0.8)
    prop.SetSpecular(0.12)
    prop.SetSpecularPower(20)

    ren = vtk.vtkRenderer()
    ren.AddActor(actor)
    ren.SetBackground(*background)
    ren.AutomaticLightCreationOff()
    return ren


def add_key_lights(vtk: Any, ren: Any, centre: np.ndarray, dist: float, d: np.ndarray, up: np.ndarray) -> None:
    """Replace ``ren``'s lights by the previews' key, fill and head lights.

    ``centre`` the look-at point, ``dist`` the camera distance, ``d`` (3,) the unit direction from
    ``centre`` toward the camera, ``up`` (3,) the camera's up vector.
    """
    ren.RemoveAllLights()
    right = np.cross(d, up)
    right /= np.linalg.norm(right)
    for offset, intensity in ((0.6 * up + 0.5 * right, 0.75), (-0.4 * right + 0.1 * up, 0.35), (np.zeros(3), 0.25)):
        light = vtk.vtkLight()
        light.SetLightTypeToSceneLight()
        light.SetPosition(*(centre + dist * (d + offset)))
        light.SetFocalPoint(*centre)
        light.SetIntensity(intensity)
        ren.AddLight(light)


def textured_actors(vtk: Any, nps: Any, vertices: np.ndarray, faces: np.ndarray, appearance: Any) -> list:
    """One vtkActor per material of ``appearance``: textured ones split at UV seams (a point per
    (vertex, uv) corner pair), the rest vertex-coloured; normals from the whole mesh (no shading
    seams), per-material specular (:data:`holo_viewer.flame.appearance.MATERIAL_SPECULAR`)."""
    from .appearance import MATERIAL_TEXTURE, MATERIALS, TEXTURE_TILE

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if f.shape != appearance.faces.shape or not np.array_equal(f, appearance.faces):
        raise InputError(f"appearance: made for {len(appearance.faces)} triangles of another topology; "
                         f"the mesh has {len(f)}")
    if len(v) != len(appearance.vertex_colors):
        raise InputError(f"appearance: made for {len(appearance.vertex_colors)} vertices, the mesh has {len(v)}")
    from ..geometry import vertex_normals

    normals = vertex_normals(v, f)
    textures = {}
    actors = []
    for mi, name in enumerate(MATERIALS):
        sel = np.nonzero(appearance.face_material == mi)[0]
        if len(sel) == 0:
            continue
        tex = MATERIAL_TEXTURE[name]
        if tex is None or tex not in appearance.textures:
            vi, tri = np.unique(f[sel].ravel(), return_inverse=True)
            pts, nrm, tri = v[vi], normals[vi], tri.reshape(-1, 3)
            rgb, tc = appearance.vertex_colors[vi], None
        else:
            pairs = np.stack([f[sel].ravel(), appearance.faces_uv[sel].ravel()], axis=1)
            uniq, tri = np.unique(pairs, axis=0, return_inverse=True)
            pts, nrm, tri = v[uniq[:, 0]], normals[uniq[:, 0]], tri.reshape(-1, 3)
            tc = appearance.uv[uniq[:, 1]].astype(np.float64) - [TEXTURE_TILE[tex], 0.0]
            rgb = None
        poly = vtk.vtkPolyData()
        vp = vtk.vtkPoints()
        vp.SetData(nps.numpy_to_vtk(np.ascontiguousarray(pts), deep=True))
        poly.SetPoints(vp)
        cells = vtk.vtkCellArray()
        cells.SetData(nps.numpy_to_vtkIdTypeArray(np.arange(0, 3 * len(tri) + 1, 3, dtype=np.int64), deep=True),
                      nps.numpy_to_vtkIdTypeArray(np.ascontiguousarray(tri, dtype=np.int64).ravel(), deep=True))
        poly.SetPolys(cells)
        poly.GetPointData().SetNormals(nps.numpy_to_vtk(np.ascontiguousarray(nrm), deep=True))
        mapper = vtk.vtkPolyDataMapper()
        mapper.SetInputData(poly)
        actor = vtk.vtkActor()
        actor.SetMapper(mapper)
        if tc is None:
            arr = nps.numpy_to_vtk(np.ascontiguousarray(np.round(np.clip(rgb, 0, 1) * 255)).astype(np.uint8), deep=True)
            arr.SetName("rgb")
            poly.GetPointData().SetScalars(arr)
            mapper.SetColorModeToDirectScalars()
        else:
            poly.GetPointData().SetTCoords(nps.numpy_to_vtk(np.ascontiguousarray(tc), deep=True))
            mapper.ScalarVisibilityOff()
            if tex not in textures:
                textures[tex] = _vtk_texture(vtk, nps, appearance.textures[tex], appearance.alpha.get(tex))
            actor.SetTexture(textures[tex])
            # VTK's legacy texturing multiplies the whole lit colour (specular included) by the
            # texel, which kills highlights on dark texels (the iris, the pupil): apply the albedo to
            # the ambient + diffuse terms only and add the specular on top
            actor.GetShaderProperty().AddFragmentShaderReplacement(
                "//VTK::TCoord::Impl", True,
                "vec4 tcolor = texture(actortexture, tcoordVCVSOutput);\n"
                "  gl_FragData[0] = vec4((ambientColor + diffuse) * tcolor.rgb + specular, opacity * tcolor.a);\n",
                False)
        prop = actor.GetProperty()
        prop.SetColor(1.0, 1.0, 1.0)
        prop.SetInterpolationToPhong()
        prop.SetAmbient(0.25)
        prop.SetDiffuse(0.8)
        spec, power = appearance.specular.get(name, (0.12, 20.0))
        prop.SetSpecular(spec)
        prop.SetSpecularPower(power)
        prop.SetSpecularColor(1.0, 1.0, 1.0)
        actors.append(actor)
    return actors


def _vtk_texture(vtk: Any, nps: Any, image: np.ndarray, alpha: np.ndarray | None = None) -> Any:
    """A linear-filtered, mipmapped, edge-clamped vtkTexture of an (H, W, 3) float image (row 0 at the
    top), RGBA when ``alpha`` (H, W) is given (the actor is then drawn blended)."""
    h, w = image.shape[:2]
    data = vtk.vtkImageData()
    data.SetDimensions(w, h, 1)
    img = image[..., :3] if alpha is None else np.concatenate([image[..., :3], alpha[..., None]], axis=-1)
    pix = np.ascontiguousarray(np.round(np.clip(img[::-1], 0, 1) * 255).astype(np.uint8).reshape(h * w, -1))
    arr = nps.numpy_to_vtk(pix, deep=True)
    arr.SetName("albedo")
    data.GetPointData().SetScalars(arr)
    t = vtk.vtkTexture()
    t.SetInputData(data)
    t.InterpolateOn()
    t.MipmapOn()
    t.RepeatOff()
    t.EdgeClampOn()
    t.SetColorModeToDirectScalars()
    return t
