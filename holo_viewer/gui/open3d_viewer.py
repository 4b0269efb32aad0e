"""Optional Open3D inspection window (``holo-viewer view --toolkit open3d``).

Shows the same inspection scene as the PyVista viewer with Open3D's legacy
``Visualizer``: the FLAME mesh, the Gaussian centres (a subsample, coloured by their DC
colour) and the 48 camera frusta coloured by view index with the focal plane. Keys: ``,``
/ ``.`` pain down / up, ``M`` toggle the mesh, ``G`` toggle the Gaussians. Open3D is
imported lazily; without it a :class:`~holo_viewer.errors.MissingDependencyError` says
how to install the ``[open3d]`` extra.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import MissingDependencyError
from .scene import focal_plane_corners, frusta_arrays, subsample_indices, view_colors

__all__ = ["require_open3d", "build_open3d_geometries", "run_open3d_viewer"]


def require_open3d() -> Any:
    """Import open3d or raise MissingDependencyError naming the extra to install."""
    try:
        import open3d  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError("open3d", "the Open3D viewer (--toolkit open3d)", extra="open3d") from exc
    return open3d


def build_open3d_geometries(pipeline: Any, max_glyphs: int = 20000) -> dict[str, Any]:
    """Open3D geometries of the pipeline's current state: ``mesh``, ``gaussians``, ``frusta``, ``focal``."""
    o3d = require_open3d()
    verts = pipeline.mesh()
    faces = pipeline.model.faces.detach().cpu().numpy()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(faces))
    mesh.compute_vertex_normals()
    mesh.paint_uniform_color([0.91, 0.77, 0.66])
    out = {"mesh": mesh}
    if pipeline.avatar is not None:
        g = pipeline.gaussians().numpy()
        idx = subsample_indices(len(g), max_glyphs)
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(g.means[idx], dtype=np.float64)))
        pc.colors = o3d.utility.Vector3dVector(np.clip(g.colors_dc()[idx], 0.0, 1.0).astype(np.float64))
        out["gaussians"] = pc
    cams = pipeline.cameras()
    centre, _ = pipeline.get("framing")
    pts, lines, vid = frusta_arrays(cams, centre)
    ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(pts), o3d.utility.Vector2iVector(lines))
    ls.colors = o3d.utility.Vector3dVector(view_colors(len(cams))[vid])
    out["frusta"] = ls
    c = focal_plane_corners(cams, centre)
    fp = o3d.geometry.LineSet(o3d.utility.Vector3dVector(c),
                              o3d.utility.Vector2iVector(np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [1, 3]])))
    fp.paint_uniform_color([0.37, 0.66, 1.0])
    out["focal"] = fp
    return out


def run_open3d_viewer(pipeline: Any, max_glyphs: int = 20000) -> None:
    """Open the Open3D window (blocks until closed)."""
    o3d = require_open3d()
    geoms = build_open3d_geometries(pipeline, max_glyphs)
    vis = o3d.visualization.VisualizerWithKeyCallback()
    vis.create_window(window_name="holo-viewer (Open3D)", width=1280, height=800)
    for g in geoms.values():
        vis.add_geometry(g)
    shown = {"mesh": True, "gaussians": True}

    def refresh(v: Any) -> bool:
        new = build_open3d_geometries(pipeline, max_glyphs)
        geoms["mesh"].vertices = new["mesh"].vertices
        geoms["mesh"].vertex_normals = new["mesh"].vertex_normals
        v.update_geometry(geoms["mesh"])
        if "gaussians" in geoms:
            geoms["gaussians"].points = new["gaussians"].points
            geoms["gaussians"].colors = new["gaussians"].colors
            v.update_geometry(geoms["gaussians"])
        return True

    def pain(delta: float) -> Any:
        def cb(v: Any) -> bool:
            p = float(np.clip(pipeline.face.pain + delta, 0.0, 1.0))
            pipeline.set_face(pain=p)
            print(f"pain {p:.2f}")
            return refresh(v)
        return cb

    def toggle(key: str) -> Any:
        def cb(v: Any) -> bool:
            if key not in geoms:
                return False
            shown[key] = not shown[key]
            (v.add_geometry if shown[key] else v.remove_geometry)(geoms[key], reset_bounding_box=False)
            return True
        return cb

    vis.register_key_callback(ord(","), pain(-0.1))
    vis.register_key_callback(ord("."), pain(0.1))
    vis.register_key_callback(ord("M"), toggle("mesh"))
    vis.register_key_callback(ord("G"), toggle("gaussians"))
    vis.run()
    vis.destroy_window()
