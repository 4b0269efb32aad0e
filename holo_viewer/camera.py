"""The camera type shared by every module (pure math, no I/O).

Conventions (docs/design.md section 3), stated once here and tested in ``tests/test_camera.py``:

* World frame = FLAME's: metres, +y up, +z out of the face toward the viewer.
* ``world_to_cam`` is a 4x4 rigid transform into OpenCV camera space:
  +x right, +y down, +z forward (the viewing direction).
* ``K`` = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels. Pixel (row i, col j)
  has its centre at (x, y) = (j + 0.5, i + 0.5); image row 0 is the top.
* Images are ``width`` x ``height`` (axis order of arrays: (H, W, 3)).
* An off-axis (sheared) projection is a shifted principal point ``cx``.

:class:`Cameras` is a batch of V cameras with one image size and clip range; a
single camera is a batch of one. All arrays are float64 numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .errors import InputError
from .validation import check_array, check_finite_scalar, check_json_number

__all__ = ["Cameras", "look_at", "intrinsics", "opencv_to_opengl", "MAX_IMAGE_SIDE", "MAX_IMAGE_PIXELS"]

#: Largest image side in pixels a camera may have (the common GPU texture limit).
MAX_IMAGE_SIDE = 16384
#: Largest image area per view (8192 x 8192 = 64 Mpx; one float32 RGB view is then 768 MiB).
MAX_IMAGE_PIXELS = 8192 * 8192


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """3x3 pinhole matrix ``K`` (pixels)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 1.0, 0.0)) -> np.ndarray:
    """OpenCV ``world_to_cam`` (4, 4) for a camera at ``eye`` looking at ``target``.

    ``up`` is the world direction that appears upward in the image (camera -y).
    """
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    z = target - eye
    nz = np.linalg.norm(z)
    if nz == 0:
        raise InputError("look_at: eye and target coincide")
    z = z / nz
    x = np.cross(z, up)  # camera +x (right) = down x forward = forward x up
    nx = np.linalg.norm(x)
    if nx < 1e-12:
        raise InputError("look_at: up is parallel to the viewing direction")
    x = x / nx
    y = np.cross(z, x)  # camera +y points down in the image
    R = np.stack([x, y, z], axis=0)
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = -R @ eye
    return M


@dataclass(frozen=True, eq=False)
class Cameras:
    """A batch of V pinhole cameras sharing image size and clip planes.

    Attributes
    ----------
    world_to_cam : numpy.ndarray
        (V, 4, 4) float64 rigid transforms, world -> OpenCV camera space.
    K : numpy.ndarray
        (V, 3, 3) float64 intrinsics in pixels.
    width, height : int
        Image size in pixels (arrays are (height, width, 3)); each side at most
        :data:`MAX_IMAGE_SIDE` and the area at most :data:`MAX_IMAGE_PIXELS`, checked here,
        before any renderer allocates an image.
    near, far : float
        Clip distances along camera +z in metres (0 < near < far).
    """

    world_to_cam: np.ndarray
    K: np.ndarray
    width: int
    height: int
    near: float = 0.01
    far: float = 100.0

    def __post_init__(self) -> None:
        w2c = np.asarray(self.world_to_cam, dtype=np.float64)
        K = np.asarray(self.K, dtype=np.float64)
        if w2c.ndim == 2:
            w2c = w2c[None]
        if K.ndim == 2:
            K = np.broadcast_to(K, (w2c.shape[0], 3, 3)).copy()
        sizes: dict[str, int] = {}
        check_array(w2c, "world_to_cam", ("V", 4, 4), sizes=sizes)
        check_array(K, "K", ("V", 3, 3), sizes=sizes)
        if sizes["V"] == 0:
            raise InputError("world_to_cam: expected at least one camera, found 0")
        R = w2c[:, :3, :3]
        err = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max()
        if err > 1e-6 or np.any(np.linalg.det(R) < 0):
            raise InputError(f"world_to_cam: expected a rotation block (orthonormal, det +1), "
                             f"found orthonormality error {err:.3g}")
        if np.abs(w2c[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
            raise InputError("world_to_cam: expected last row [0, 0, 0, 1]")
        if np.any(K[:, 0, 0] <= 0) or np.any(K[:, 1, 1] <= 0):
            raise InputError(f"K: expected fx, fy > 0, found fx={K[:, 0, 0].min()}, fy={K[:, 1, 1].min()}")
        try:
            width, height = int(self.width), int(self.height)
        except (TypeError, ValueError, OverflowError):
            width = height = 0
        if width <= 0 or height <= 0 or width != self.width or height != self.height:
            raise InputError(f"width, height: expected positive integers, found {self.width!r} x {self.height!r}")
        if max(width, height) > MAX_IMAGE_SIDE or width * height > MAX_IMAGE_PIXELS:
            raise InputError(f"width, height: expected at most {MAX_IMAGE_SIDE} pixels per side and "
                             f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpx per view (8192 x 8192), found {width} x {height}")
        near = check_finite_scalar(self.near, "near", low=0.0, low_open=True)
        far = check_finite_scalar(self.far, "far")
        if far <= near:
            raise InputError(f"far: expected > near ({near}), found {far}")
        w2c.setflags(write=False)
        K.setflags(write=False)
        object.__setattr__(self, "world_to_cam", w2c)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "height", height)
        object.__setattr__(self, "near", near)
        object.__setattr__(self, "far", far)

    # ------------------------------------------------------------------ basics
    def __len__(self) -> int:
        return int(self.world_to_cam.shape[0])

    def __getitem__(self, index: Any) -> "Cameras":
        idx = np.arange(len(self))[index]
        idx = np.atleast_1d(idx)
        return Cameras(self.world_to_cam[idx], self.K[idx], self.width, self.height, self.near, self.far)

    @property
    def R(self) -> np.ndarray:
        """(V, 3, 3) world -> camera rotations."""
        return self.world_to_cam[:, :3, :3]

    @property
    def t(self) -> np.ndarray:
        """(V, 3) world -> camera translations."""
        return self.world_to_cam[:, :3, 3]

    @property
    def positions(self) -> np.ndarray:
        """(V, 3) camera centres in world coordinates."""
        return -np.einsum("vji,vj->vi", self.R, self.t)

    @property
    def fx(self) -> np.ndarray:
        return self.K[:, 0, 0]

    @property
    def fy(self) -> np.ndarray:
        return self.K[:, 1, 1]

    @property
    def cx(self) -> np.ndarray:
        return self.K[:, 0, 2]

    @property
    def cy(self) -> np.ndarray:
        return self.K[:, 1, 2]

    @property
    def shared_orientation(self) -> bool:
        """True when every camera has the same rotation (view depth is identical across views)."""
        R = self.R
        return bool(np.abs(R - R[:1]).max() < 1e-12)

    def tan_half_fov(self) -> tuple[np.ndarray, np.ndarray]:
        """(V,) tangents of the half field of view in x and y (of a centred frustum of this size)."""
        return self.width / (2.0 * self.fx), self.height / (2.0 * self.fy)

    # ------------------------------------------------------------ projection
    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """Transform (N, 3) world points to (V, N, 3) camera coordinates."""
        pts = check_array(np.asarray(points, dtype=np.float64), "points", ("N", 3))
        return np.einsum("vij,nj->vni", self.R, pts) + self.t[:, None, :]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) world points.

        Returns
        -------
        uv : numpy.ndarray
            (V, N, 2) pixel coordinates (x right, y down; pixel centres at +0.5).
        depth : numpy.ndarray
            (V, N) camera-space z (positive in front of the camera).
        """
        pc = self.world_to_camera(points)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx[:, None] * pc[..., 0] / z + self.cx[:, None]
            v = self.fy[:, None] * pc[..., 1] / z + self.cy[:, None]
        return np.stack([u, v], axis=-1), z

    # ------------------------------------------------------------ conversion
    @classmethod
    def concatenate(cls, cams: Iterable["Cameras"]) -> "Cameras":
        cams = list(cams)
        if not cams:
            raise InputError("cameras: expected at least one camera batch, found none")
        c0 = cams[0]
        for c in cams[1:]:
            if (c.width, c.height, c.near, c.far) != (c0.width, c0.height, c0.near, c0.far):
                raise InputError("cameras: expected equal width, height, near, far in every batch, found "
                                 f"{(c0.width, c0.height, c0.near, c0.far)} and {(c.width, c.height, c.near, c.far)}")
        return cls(np.concatenate([c.world_to_cam for c in cams]), np.concatenate([c.K for c in cams]),
                   c0.width, c0.height, c0.near, c0.far)

    def to_dicts(self) -> list[dict]:
        """JSON-ready list of {"width","height","fx","fy","cx","cy","world_to_cam"} (row-major 4x4)."""
        out = []
        for i in range(len(self)):
            out.append({"width": self.width, "height": self.height,
                        "fx": float(self.fx[i]), "fy": float(self.fy[i]),
                        "cx": float(self.cx[i]), "cy": float(self.cy[i]),
                        "near": self.near, "far": self.far,
                        "world_to_cam": self.world_to_cam[i].tolist()})
        return out

    @classmethod
    def from_dicts(cls, items: Sequence[Mapping[str, Any]], *, source: str = "cameras") -> "Cameras":
        """Inverse of :meth:`to_dicts`. Every camera must have the same width and height.

        Raises
        ------
        InputError
            Naming the camera index and field that is missing or malformed.
        """
        if not isinstance(items, (list, tuple)) or not items:
            raise InputError(f"{source}: expected a non-empty list of camera objects, found {type(items).__name__}")
        w2c, Ks, sizes, clips = [], [], set(), set()
        for i, it in enumerate(items):
            where = f"{source}[{i}]"
            if not isinstance(it, Mapping):
                raise InputError(f"{where}: expected an object, found {type(it).__name__}")
            vals = {}
            for key in ("width", "height", "fx", "fy", "cx", "cy"):
                if key not in it:
                    raise InputError(f"{where}.{key}: missing")
                vals[key] = check_json_number(it[key], f"{where}.{key}", integer=key in ("width", "height"))
            if "world_to_cam" not in it:
                raise InputError(f"{where}.world_to_cam: missing")
            try:
                m = np.asarray(it["world_to_cam"])
            except (TypeError, ValueError):  # ragged nested lists
                m = np.asarray(None)
            if m.dtype.kind not in "iuf" or m.shape != (4, 4):
                raise InputError(f"{where}.world_to_cam: expected a 4x4 matrix of numbers (a list of 4 rows), "
                                 f"found {_describe_json(it['world_to_cam'])}")
            m = check_array(m.astype(np.float64), f"{where}.world_to_cam", (4, 4))
            w2c.append(m)
            Ks.append(intrinsics(vals["fx"], vals["fy"], vals["cx"], vals["cy"]))
            sizes.add((vals["width"], vals["height"]))
            near = check_json_number(it.get("near", 0.01), f"{where}.near", low=0.0, low_open=True)
            far = check_json_number(it.get("far", 100.0), f"{where}.far", low=0.0, low_open=True)
            clips.add((near, far))
        if len(sizes) != 1:
            raise InputError(f"{source}: expected one image size for all cameras, found {sorted(sizes)}")
        if len(clips) != 1:
            raise InputError(f"{source}: expected one near/far for all cameras, found {sorted(clips)}")
        (w, h), (near, far) = sizes.pop(), clips.pop()
        return cls(np.stack(w2c), np.stack(Ks), w, h, near, far)


def _describe_json(value: Any) -> str:
    """Short description of a JSON value for error messages."""
    if value is None:
        return "null"
    if isinstance(value, (list, tuple)):
        arr = None
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError):
            pass
        if arr is not None and arr.dtype != object:
            return f"an array of shape {arr.shape} and type {arr.dtype}"
        return f"a list of {len(value)} items (ragged or mixed types)"
    return f"{type(value).__name__} {value!r}"[:80]


def opencv_to_opengl(cams: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """OpenGL view and projection matrices (V, 4, 4), row-major, for VTK.

    The view matrix maps world to OpenGL eye space (+x right, +y up, -z forward);
    the projection maps eye space to clip space so that NDC x = -1 is the left edge of
    pixel column 0 and NDC y = +1 the top edge of row 0, with depth in [near, far].
    A shifted ``cx`` becomes the off-axis term ``P[0, 2]``.
    """
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    view = flip @ cams.world_to_cam
    W, H, n, f = cams.width, cams.height, cams.near, cams.far
    P = np.zeros((len(cams), 4, 4))
    P[:, 0, 0] = 2.0 * cams.fx / W
    P[:, 1, 1] = 2.0 * cams.fy / H
    P[:, 0, 2] = 1.0 - 2.0 * cams.cx / W
    P[:, 1, 2] = 2.0 * cams.cy / H - 1.0
    P[:, 2, 2] = -(f + n) / (f - n)
    P[:, 2, 3] = -2.0 * f * n / (f - n)
    P[:, 3, 2] = -1.0
    return view, P
