"""The painter's limbus (assets_build.texture_painter.eye_axis): the cornea is the cap raised all the way
from the optical axis; a bump of the sclera far out is not cornea (it made four patients' irises cover
most of the visible eye: limbus 56-59 degrees instead of ~29)."""

from __future__ import annotations

import math

import numpy as np
import pytest


def _eyeball(bump_deg: float | None) -> np.ndarray:
    """Vertices of a 12 mm sphere looking along +z with a cornea cap (0.9 mm higher at the axis, to 28
    degrees) and, optionally, a 0.6 mm bump of the sclera around ``bump_deg`` from the axis."""
    th = np.radians(np.arange(0.0, 180.0, 1.5))
    ph = np.radians(np.arange(0.0, 360.0, 6.0))
    T, P = np.meshgrid(th, ph, indexing="ij")
    r = 12.0 + 0.9 * np.clip(1.0 - (T / np.radians(28.0)) ** 2, 0.0, None)
    if bump_deg is not None:
        r = r + 0.6 * np.exp(-(((T - np.radians(bump_deg)) / np.radians(2.0)) ** 2)) * (np.cos(P) > 0.8)
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    return (r[..., None] * d).reshape(-1, 3)


@pytest.mark.parametrize("bump", [None, 50.0, 56.0])
def test_the_limbus_is_the_raised_cap_not_a_bump_beyond_it(bump):
    from holo_viewer.assets_build.texture_painter import eye_axis

    centre, axis, limbus = eye_axis(_eyeball(bump))
    assert axis[2] > 0.99 and np.linalg.norm(centre) < 0.5
    assert math.radians(20) < limbus < math.radians(30), math.degrees(limbus)


def test_every_shipped_patients_iris_is_anatomical():
    """0.3 < limbus < 0.7 rad (a 17..40 degree cornea, tests/test_appearance.py's range for the default
    head) on both eyes of the patients whose eyeballs have such bumps."""
    from holo_viewer.assets_build.texture_painter import eye_axis
    from holo_viewer.avatar.patients import patient_info
    from holo_viewer.flame.appearance import MATERIALS, AppearanceMesh, _to_local, face_frame

    for name in ("kwame", "amara"):
        z = np.load(patient_info(name).head_path)
        m = AppearanceMesh.from_arrays(z["v_template"], z["f"], z["uv"], z["faces_uv"], z["vertex_region"],
                                       z["region_names"], z["v_template"][z["landmark_vertices"]])
        frame = face_frame(m.landmarks)
        for eye in ("eye_left", "eye_right"):
            sel = np.nonzero(m.material == MATERIALS.index(eye))[0]
            _, _, limbus = eye_axis(_to_local(m.vertices[np.unique(m.faces[sel])], frame))
            assert 0.3 < limbus < 0.7, (name, eye, math.degrees(limbus))
