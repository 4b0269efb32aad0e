"""Back-face culling over a view cone: drop Gaussians whose surface faces away from every camera.

A Gaussian bound to a face (or given its own normal) at centre ``c`` with unit normal ``n`` is
*kept* when at least one camera at position ``p`` sees the front of its surface within a margin::

    n . (p - c) / |p - c|  >  -sin(margin)

i.e. the angle between the normal and the direction to the camera is below 90 deg + margin.
A positive margin keeps surfaces seen at grazing angles (and Gaussians whose thickness or
offset from the face, e.g. hair, makes them visible slightly beyond the silhouette).

This is only safe where the surface in front is opaque: culled Gaussians are behind it.
Transparent or sparse scenes (e.g. a 3DGS scan with semi-transparent floaters) lose content
that was visible through the gaps; measure the image error (``bench/deform_tradeoff.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..camera import Cameras
from ..errors import InputError
from ..validation import check_array, check_finite_scalar

__all__ = ["visible_mask", "face_visibility", "cull_backfacing"]


def visible_mask(centres: np.ndarray, normals: np.ndarray, cam_positions: np.ndarray, margin_deg: float) -> np.ndarray:
    """(M,) bool: True where some camera sees the front side of (centre, normal) within the margin.

    Parameters
    ----------
    centres, normals : numpy.ndarray
        (M, 3) points (metres) and unit normals.
    cam_positions : numpy.ndarray
        (V, 3) camera centres, metres.
    margin_deg : float
        Extra angle beyond 90 degrees, in degrees (-90 < margin < 90).
    """
    thr = -np.sin(np.deg2rad(margin_deg))
    cams = np.asarray(cam_positions, np.float64)
    centres = np.asarray(centres, np.float64)
    normals = np.asarray(normals, np.float64)
    keep = np.zeros(centres.shape[0], bool)
    for start in range(0, centres.shape[0], 20_000):  # bounded memory: (V, chunk, 3)
        c, n = centres[start:start + 20_000], normals[start:start + 20_000]
        d = cams[:, None, :] - c[None]
        dist = np.sqrt(np.einsum("vmc,vmc->vm", d, d))
        keep[start:start + c.shape[0]] = (np.einsum("vmc,mc->vm", d, n) > thr * dist).any(axis=0)
    return keep


def face_visibility(vertices: Any, faces: Any, cameras: Cameras, margin_deg: float = 10.0) -> np.ndarray:
    """(F,) bool faces that some camera of ``cameras`` sees from the front (within ``margin_deg``).

    Parameters
    ----------
    vertices : array-like
        (V, 3) posed mesh vertices (numpy or torch), metres.
    faces : array-like
        (F, 3) int vertex indices; normals follow the right-hand rule (counter-clockwise = front).
    """
    v = vertices.detach().cpu().numpy() if hasattr(vertices, "detach") else np.asarray(vertices)
    v = np.asarray(v, np.float64)
    if v.ndim == 3 and v.shape[0] == 1:
        v = v[0]
    check_array(v, "vertices", ("V", 3))
    f = faces.cpu().numpy() if hasattr(faces, "cpu") else np.asarray(faces)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(ln > 0, n / np.maximum(ln, 1e-30), 0.0)  # zero-area faces: kept (n = 0 passes)
    c = v[f].mean(axis=1)
    return visible_mask(c, n, cameras.positions, margin_deg)


def cull_backfacing(source: Any, cameras: Cameras, margin_deg: float = 10.0, *, vertices: Any = None,
                    normals: Any = None) -> np.ndarray:
    """Mask of Gaussians to keep (True) for a set of cameras (e.g. the 48 of the view cone).

    Parameters
    ----------
    source : RiggedAvatar or Gaussians
        A rigged avatar (then ``vertices`` gives the posed mesh and each Gaussian inherits the
        visibility of its face), or world Gaussians with per-Gaussian ``normals``.
    cameras : Cameras
        The views that will be rendered.
    margin_deg : float
        Angle beyond 90 degrees still counted as visible (default 10).
    vertices : array-like, optional
        (V, 3) or (1, V, 3) posed vertices (or a FlameOutput) for a RiggedAvatar.
    normals : array-like, optional
        (N, 3) unit normals for Gaussians.

    Returns
    -------
    numpy.ndarray
        (N,) bool; ``gaussians.subset(mask)`` keeps the visible ones.
    """
    from .gaussians import Gaussians

    if not isinstance(cameras, Cameras):
        raise InputError(f"cameras: expected Cameras, found {type(cameras).__name__}")
    margin = check_finite_scalar(margin_deg, "margin_deg", low=-89.0, high=89.0)
    if isinstance(source, Gaussians):
        if normals is None:
            raise InputError("normals: expected (N, 3) per-Gaussian normals when culling Gaussians")
        nrm = normals.detach().cpu().numpy() if hasattr(normals, "detach") else np.asarray(normals)
        check_array(nrm, "normals", (len(source), 3))
        nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
        means = source.numpy().means.astype(np.float64)
        return visible_mask(means, nrm, cameras.positions, margin)
    if hasattr(source, "binding") and hasattr(source, "faces"):
        if vertices is None:
            raise InputError("vertices: expected the posed (V, 3) mesh vertices when culling a RiggedAvatar")
        verts = getattr(vertices, "vertices", vertices)
        keep_face = face_visibility(verts, source.faces, cameras, margin)
        return keep_face[source.binding.cpu().numpy()]
    raise InputError(f"source: expected a RiggedAvatar or Gaussians, found {type(source).__name__}")
