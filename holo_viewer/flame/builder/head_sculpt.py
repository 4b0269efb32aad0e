"""Geometry of the embedded default head: a sculpted closed surface plus eyes and ears.

Pure numpy, no I/O, deterministic. FLAME's frame: metres, +y up, +z out of the
face (the face looks along +z), +x toward the subject's left.

Construction
------------
1. *Base surface.* A (theta, phi) grid of rays from a centre point inside the head
   (theta = 0 straight up, phi = 0 toward +z). Rows and columns are spaced
   non-uniformly (denser over the face). Each ray is cast against a signed-distance
   sculpture (smooth union of ellipsoids: cranium, brow ridge, cheekbones, maxilla,
   mandible, chin, nose, neck; eye sockets smoothly carved out) and its vertex is put
   on the outermost crossing, so the surface is a closed sphere-topology mesh with
   two poles (crown and the flat neck cap).
2. *Slits.* The mouth line and each palpebral fissure are grid rows cut open between
   two corner columns (the row's vertices are duplicated for the lower side). The
   mouth loop is closed by an inner mouth bag; each eye loop by a small pocket that
   lies inside the eyeball.
3. *Detail.* Lips are sculpted along the rays as functions of the vertical distance
   to the mouth line (so the two lip edges coincide at rest: lips closed); the eyelid
   rims are placed on a sphere 1.8 mm outside the eyeball and the lid skin is blended
   toward them and kept outside the eyeball.
4. *Separate parts.* Two eyeballs (UV spheres) and two ears (deformed UV spheres
   with a concha hollow and a rim) intersect the head, as FLAME's eyeballs do.

The result :class:`HeadMesh` also carries the bookkeeping the rig and the blend
shapes need (grid parameters, the lower-side flag of the slits, rim and bag ids).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["HeadMesh", "sculpt_head", "REGION_NAMES", "smoothstep", "HEAD_CENTRE",
           "EYE_CENTRES", "EYE_RADIUS", "LID_RADIUS", "HINGE", "NECK_JOINT_POS", "ROOT_JOINT_POS"]

#: Region labels stored as ``vertex_region`` (index into this tuple).
REGION_NAMES = ("skin", "scalp", "brows", "lips", "eyeball_left", "eyeball_right", "iris", "pupil",
                "ears", "mouth_interior", "eye_pocket", "neck", "nostrils")
_R = {name: i for i, name in enumerate(REGION_NAMES)}

HEAD_CENTRE = np.array([0.0, -0.012, 0.0])          # ray origin, metres
EYE_RADIUS = 0.0124
LID_RADIUS = EYE_RADIUS + 0.0018
#: Eyeball centres: index 0 = subject's left (+x, FLAME joint 3), 1 = right (joint 4).
EYE_CENTRES = np.array([[0.0315, 0.0, 0.0545], [-0.0315, 0.0, 0.0545]])
HINGE = np.array([0.0, -0.028, -0.008])            # jaw hinge (temporomandibular axis midpoint)
NECK_JOINT_POS = np.array([0.0, -0.062, -0.022])
ROOT_JOINT_POS = np.array([0.0, -0.135, -0.02])
_MOUTH_POINT = np.array([0.0, -0.068, 0.09])        # where the mouth line crosses the midline
_MOUTH_HALF_WIDTH = 0.0228
_NECK_BOTTOM_Y = -0.16


def smoothstep(x: np.ndarray, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    """Cubic smooth step from 0 (x <= lo) to 1 (x >= hi), elementwise."""
    t = np.clip((np.asarray(x, dtype=np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass(frozen=True)
class HeadMesh:
    """The sculpted default head before rigging.

    Attributes
    ----------
    vertices : numpy.ndarray
        (V, 3) float64 rest positions, metres.
    faces : numpy.ndarray
        (F, 3) int64 triangles, counter-clockwise seen from outside.
    region : numpy.ndarray
        (V,) int64 index into :data:`REGION_NAMES`.
    theta, phi : numpy.ndarray
        (V,) grid parameters of surface vertices in radians (NaN for eyes, ears, bag, pockets).
    lower : numpy.ndarray
        (V,) bool: the vertex is a duplicate on the lower side of *any* slit (the mouth or
        either palpebral fissure). Code about the mouth must use :attr:`lower_lip_side`.
    parts : dict
        Named vertex-index arrays: ``eyeball_0``/``eyeball_1``, ``pocket_0``/``pocket_1``,
        ``ear_0``/``ear_1``, ``bag``, ``mouth_upper``/``mouth_lower`` (slit edges, left to right,
        corners included), ``lid_upper_0``/``lid_lower_0`` and ``_1`` (eye rims, inner to outer),
        ``teeth_anchor_upper``/``teeth_anchor_lower``.
    bag_lower : numpy.ndarray
        (len(parts["bag"]),) float64 in [0, 1]: how much each bag vertex belongs to the lower jaw.
    eye_cols : tuple
        Per eye (row, c0, c1, side) of its slit on the grid, side = +1 for the +x eye.
    mouth_slit : tuple
        (row, c0, c1) of the mouth slit.
    grid : numpy.ndarray
        (n_rows, n_cols) vertex ids of the grid (upper side of slits).
    lid_pitch : numpy.ndarray
        (2, 2, n) rest pitch (radians) of the upper (0) and lower (1) rims of each eye.
    """

    vertices: np.ndarray
    faces: np.ndarray
    region: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    lower: np.ndarray
    parts: dict = field(default_factory=dict)
    bag_lower: np.ndarray = field(default_factory=lambda: np.zeros(0))
    eye_cols: tuple = ()
    mouth_slit: tuple = ()
    grid: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    lid_pitch: np.ndarray = field(default_factory=lambda: np.zeros((0,)))

    @property
    def lower_lip_side(self) -> np.ndarray:
        """(V,) bool: the lower-side duplicates of the *mouth* slit only (not the eye slits).

        The eye fissures are cut the same way as the mouth, so :attr:`lower` also flags
        the lower-lid rims; the jaw and the lip masks must not pick those up.
        """
        out = np.zeros(len(self.vertices), dtype=bool)
        out[self.parts["mouth_lower"][1:-1]] = True
        return out


# --------------------------------------------------------------------------- SDF sculpture
def _ellipsoid(p: np.ndarray, centre, radii, tilt_x: float = 0.0) -> np.ndarray:
    """Approximate signed distance to an ellipsoid (optionally rotated about x), metres."""
    q = p - np.asarray(centre)
    if tilt_x:
        c, s = np.cos(tilt_x), np.sin(tilt_x)
        y = c * q[..., 1] + s * q[..., 2]
        z = -s * q[..., 1] + c * q[..., 2]
        q = np.stack([q[..., 0], y, z], axis=-1)
    r = np.asarray(radii, dtype=np.float64)
    k = np.linalg.norm(q / r, axis=-1)
    return (k - 1.0) * r.min()


def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def _smax(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    return -_smin(-a, -b, k)


def _mirror(fn, p: np.ndarray) -> np.ndarray:
    """Evaluate a left-side primitive symmetrically (|x|)."""
    q = p.copy()
    q[..., 0] = np.abs(q[..., 0])
    return fn(q)


def head_sdf(p: np.ndarray) -> np.ndarray:
    """Signed distance (approximate; exact sign) of the head sculpture at points (..., 3)."""
    d = _ellipsoid(p, (0, 0.028, -0.018), (0.073, 0.083, 0.094))             # cranium
    d = _smin(d, _ellipsoid(p, (0, 0.006, 0.018), (0.066, 0.066, 0.062)), 0.02)  # upper face
    d = _smin(d, _ellipsoid(p, (0, 0.027, 0.055), (0.058, 0.02, 0.027)), 0.012)  # brow ridge
    d = _smin(d, _mirror(lambda q: _ellipsoid(q, (0.049, -0.009, 0.043), (0.022, 0.016, 0.028)), p), 0.015)
    d = _smin(d, _ellipsoid(p, (0, -0.052, 0.052), (0.036, 0.034, 0.038)), 0.018)  # maxilla / muzzle
    d = _smin(d, _ellipsoid(p, (0, -0.053, 0.008), (0.061, 0.043, 0.062)), 0.02)  # mandible
    d = _smin(d, _mirror(lambda q: _ellipsoid(q, (0.042, -0.042, 0.035), (0.022, 0.028, 0.03)), p), 0.015)
    d = _smin(d, _ellipsoid(p, (0, -0.093, 0.058), (0.026, 0.018, 0.021)), 0.016)   # chin
    # nose: bridge (tilted), tip, alae
    d = _smin(d, _ellipsoid(p, (0, -0.014, 0.088), (0.0095, 0.029, 0.013), tilt_x=-0.42), 0.008)
    d = _smin(d, _ellipsoid(p, (0, -0.036, 0.104), (0.0105, 0.009, 0.0105)), 0.008)
    d = _smin(d, _mirror(lambda q: _ellipsoid(q, (0.0125, -0.039, 0.092), (0.0085, 0.0072, 0.0095)), p), 0.006)
    # neck: elliptic vertical cylinder with a flat bottom
    q = p - np.array([0.0, 0.0, -0.022])
    dn = np.hypot(q[..., 0] / 0.053, q[..., 2] / 0.052) * 0.052 - 0.052
    dn = np.maximum(dn, np.maximum(p[..., 1] - 0.0, _NECK_BOTTOM_Y - p[..., 1]))
    d = _smin(d, dn, 0.012)
    d = np.maximum(d, _NECK_BOTTOM_Y - p[..., 1])
    # eye sockets
    sock = _mirror(lambda q: _ellipsoid(q, (0.032, 0.002, 0.066), (0.0195, 0.0145, 0.016)), p)
    d = _smax(d, -sock, 0.006)
    return d


def _cast(dirs: np.ndarray, sdf=head_sdf, t_max: float = 0.32, n_steps: int = 400) -> np.ndarray:
    """Distance along each unit ray from HEAD_CENTRE to the outermost surface crossing."""
    ts = np.linspace(t_max, 0.0, n_steps)
    inside_t = np.zeros(dirs.shape[0])
    found = np.zeros(dirs.shape[0], dtype=bool)
    for t in ts:  # march inward; first inside sample is just inside the outermost crossing
        d = sdf(HEAD_CENTRE + t * dirs)
        hit = (~found) & (d < 0)
        inside_t[hit] = t
        found |= hit
        if found.all():
            break
    if not found.all():
        raise RuntimeError("default head: a ray from the head centre missed the sculpture")
    lo, hi = inside_t, inside_t + (ts[0] - ts[1])
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        inside = sdf(HEAD_CENTRE + mid[:, None] * dirs) < 0
        lo = np.where(inside, mid, lo)
        hi = np.where(inside, hi, mid)
    return 0.5 * (lo + hi)


def _ray_dirs(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.sin(phi), np.cos(theta), st * np.cos(phi)], axis=-1)


def _angles_of(point: np.ndarray) -> tuple[float, float]:
    d = np.asarray(point, dtype=np.float64) - HEAD_CENTRE
    d = d / np.linalg.norm(d)
    return float(np.arccos(np.clip(d[1], -1, 1))), float(np.arctan2(d[0], d[2]))


def _warped(n: int, lo: float, hi: float, bumps, periodic: bool) -> np.ndarray:
    """n samples on [lo, hi] with density 1 + sum(a exp(-((x - c) / w)^2))."""
    x = np.linspace(lo, hi, 4001)
    dens = np.ones_like(x)
    for c, w, a in bumps:
        dens += a * np.exp(-((x - c) / w) ** 2)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(x))])
    cdf /= cdf[-1]
    u = (np.arange(n) + (0.0 if periodic else 1.0)) / (n if periodic else n + 1)
    return np.interp(u, cdf, x)


# --------------------------------------------------------------------------- small meshes
def uv_sphere(n_lat: int, n_lon: int, lat_deg: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Unit UV sphere with poles on +z / -z (so the +z pole is the cornea). CCW outward.

    ``lat_deg`` optionally gives the ring polar angles (degrees from +z) instead of
    ``n_lat`` uniform rings.
    """
    th = np.linspace(0, np.pi, n_lat + 2)[1:-1] if lat_deg is None else np.radians(np.asarray(lat_deg, float))
    n_lat = len(th)
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1.0]], v, [[0, 0, -1.0]]])
    f = []
    top, bot = 0, len(v) - 1
    idx = lambda i, j: 1 + i * n_lon + (j % n_lon)  # noqa: E731
    for j in range(n_lon):
        f.append([top, idx(0, j), idx(0, j + 1)])
        f.append([bot, idx(n_lat - 1, j + 1), idx(n_lat - 1, j)])
        for i in range(n_lat - 1):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j + 1), idx(i + 1, j)
            f += [[a, d, c], [a, c, b]]
    return v, np.asarray(f, dtype=np.int64)


def _ear(side: int) -> tuple[np.ndarray, np.ndarray]:
    """One ear: a flattened sphere with a hollow concha and a thick helix rim."""
    v, f = uv_sphere(9, 16)
    # local frame: z = outward (lateral) thickness, y = up, x = back-to-front
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    rad = np.hypot(x, y)
    outer = z > 0
    # concha: the lateral face is pushed in except near the rim
    dent = 0.75 * (1 - smoothstep(rad, 0.55, 0.95)) * outer
    z = z - dent * (z + 0.2)
    lx = x * 0.0165 * (1 - 0.15 * (y < 0) * np.abs(y))  # narrower lobe
    ly = y * 0.031
    lz = z * 0.0065
    local = np.stack([lx, ly, lz], -1)
    # orient: lateral axis mostly +-x, tilted back at the top, flaring outward 20 deg
    flare, back = np.radians(22.0), np.radians(14.0)
    out = np.array([side * np.cos(flare), 0.0, -np.sin(flare)])
    up = np.array([0.0, np.cos(back), -np.sin(back)])
    fwd = np.cross(out, up) * side
    fwd /= np.linalg.norm(fwd)
    up = np.cross(fwd, out) * side
    m = np.stack([fwd, up, out], axis=1)  # columns: local x, y, z axes in world
    centre = np.array([side * 0.0735, -0.012, -0.022])
    world = local @ m.T + centre
    if np.linalg.det(m) < 0:
        f = f[:, ::-1]
    return world, f


# --------------------------------------------------------------------------- the head
def sculpt_head(n_rows: int = 56, n_cols: int = 74) -> HeadMesh:
    """Build the default head geometry (deterministic; no randomness involved).

    Parameters
    ----------
    n_rows, n_cols : int
        Grid size of the sculpted surface (rows between the poles, columns around).

    Returns
    -------
    HeadMesh
    """
    theta_m, _ = _angles_of(_MOUTH_POINT)
    theta_e, _ = _angles_of(EYE_CENTRES[0] + np.array([0, 0, EYE_RADIUS]))
    thetas = _warped(n_rows, 0.0, np.pi, [(0.5 * (theta_e + theta_m) + 0.05, 0.55, 2.2),
                                         (theta_m, 0.2, 1.2), (theta_e, 0.15, 1.0)], periodic=False)
    phis = _warped(n_cols, -np.pi, np.pi, [(0.0, 0.85, 2.6), (0.0, 0.4, 1.0)], periodic=True)
    # snap feature rows exactly onto the grid
    r_m = int(np.argmin(np.abs(thetas - theta_m)))
    thetas[r_m] = theta_m
    r_e = int(np.argmin(np.abs(thetas - theta_e)))
    thetas[r_e] = theta_e
    tt, pp = np.meshgrid(thetas, phis, indexing="ij")
    dirs = _ray_dirs(tt.ravel(), pp.ravel())
    dist = _cast(dirs)
    grid_pts = HEAD_CENTRE + dist[:, None] * dirs
    top = HEAD_CENTRE + _cast(np.array([[0.0, 1.0, 0.0]]))[0] * np.array([0.0, 1.0, 0.0])
    bottom = HEAD_CENTRE + _cast(np.array([[0.0, -1.0, 0.0]]))[0] * np.array([0.0, -1.0, 0.0])

    verts = [grid_pts, top[None], bottom[None]]
    n_grid = n_rows * n_cols
    grid = np.arange(n_grid).reshape(n_rows, n_cols)
    top_id, bot_id = n_grid, n_grid + 1
    theta_v = [tt.ravel(), [0.0], [np.pi]]
    phi_v = [pp.ravel(), [0.0], [0.0]]
    n_v = n_grid + 2

    # face index table of the grid (lower-side vertex ids may be swapped below)
    quad_lo = grid.copy()  # vertex id used by quads *below* a row (row i as the top of quad band i)

    def col_of(phi: float) -> int:
        return int(np.argmin(np.abs(np.angle(np.exp(1j * (phis - phi))))))

    # mouth slit
    mouth_c0 = col_of(-np.arctan2(_MOUTH_HALF_WIDTH, _MOUTH_POINT[2] - 0.012))
    mouth_c1 = col_of(+np.arctan2(_MOUTH_HALF_WIDTH, _MOUTH_POINT[2] - 0.012))
    lower_ids: list[int] = []
    dup_pos = []

    def cut(row: int, c0: int, c1: int) -> np.ndarray:
        nonlocal n_v
        cols = np.arange(c0 + 1, c1)
        ids = n_v + np.arange(len(cols))
        n_v += len(cols)
        quad_lo[row, cols] = ids
        dup_pos.append(grid_pts[grid[row, cols]])
        theta_v.append(tt[row, cols])
        phi_v.append(pp[row, cols])
        lower_ids.extend(ids.tolist())
        return ids

    mouth_dups = cut(r_m, mouth_c0, mouth_c1)
    eye_slits = []
    for e, side in ((0, 1), (1, -1)):
        c = EYE_CENTRES[e]
        inner = c + LID_RADIUS * np.array([-side * np.sin(np.radians(62)), 0, np.cos(np.radians(62))])
        outer = c + LID_RADIUS * np.array([side * np.sin(np.radians(68)), 0, np.cos(np.radians(68))])
        ca, cb = sorted([col_of(_angles_of(inner)[1]), col_of(_angles_of(outer)[1])])
        eye_slits.append((r_e, ca, cb, side, cut(r_e, ca, cb)))

    # grid faces (CCW from outside: rows go down, columns go toward +x around the front)
    faces = []
    for i in range(n_rows - 1):
        for j in range(n_cols):
            j1 = (j + 1) % n_cols
            a, b = quad_lo[i, j], quad_lo[i, j1]
            c, d = grid[i + 1, j1], grid[i + 1, j]
            faces += [[a, d, c], [a, c, b]]
    for j in range(n_cols):
        j1 = (j + 1) % n_cols
        faces.append([top_id, grid[0, j], grid[0, j1]])
        faces.append([bot_id, grid[-1, j1], grid[-1, j]])
    faces = np.asarray(faces, dtype=np.int64)
    vertices = np.concatenate(verts + dup_pos, axis=0)
    theta_arr = np.concatenate([np.ravel(t) for t in theta_v])
    phi_arr = np.concatenate([np.ravel(p) for p in phi_v])
    lower = np.zeros(n_v, dtype=bool)
    lower[lower_ids] = True

    # orientation check: outward normals point away from the centre on average
    tri = vertices[faces]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.sum(nrm * (tri.mean(1) - HEAD_CENTRE)) < 0:
        faces = faces[:, ::-1].copy()

    region = np.zeros(n_v, dtype=np.int64)
    parts: dict[str, np.ndarray] = {}
    vertices = _sculpt_lips(vertices, grid, mouth_dups, r_m, mouth_c0, mouth_c1, lower, parts, region)
    lid_pitch = np.zeros((2, 2, 0))
    pitches = []
    for e, (row, ca, cb, side, dups) in enumerate(eye_slits):
        vertices, pu, pl = _sculpt_lids(vertices, faces, grid, dups, row, ca, cb, e, side, parts)
        pitches.append((pu, pl))
    lid_pitch = np.asarray(pitches)
    mesh_v, mesh_f = [vertices], [faces]

    # mouth bag and eye pockets
    bag_ids, bag_lower, bag_v, bag_f = _mouth_bag(vertices, faces, parts["mouth_upper"], parts["mouth_lower"], n_v)
    parts["bag"] = bag_ids
    mesh_v.append(bag_v)
    mesh_f.append(bag_f)
    n_v += len(bag_v)
    for e in range(2):
        pid, pv, pf = _eye_pocket(vertices, faces, parts[f"lid_upper_{e}"], parts[f"lid_lower_{e}"], e, n_v)
        parts[f"pocket_{e}"] = pid
        mesh_v.append(pv)
        mesh_f.append(pf)
        n_v += len(pv)
    # eyeballs
    sv, sf = uv_sphere(0, 18, lat_deg=[7, 14, 21, 27, 34, 45, 60, 80, 105, 135, 160])
    for e in range(2):
        parts[f"eyeball_{e}"] = n_v + np.arange(len(sv))
        mesh_v.append(EYE_CENTRES[e] + EYE_RADIUS * sv)
        mesh_f.append(sf + n_v)
        n_v += len(sv)
    for e, side in ((0, 1), (1, -1)):
        ev, ef = _ear(side)
        parts[f"ear_{e}"] = n_v + np.arange(len(ev))
        mesh_v.append(ev)
        mesh_f.append(ef + n_v)
        n_v += len(ev)

    vertices = np.concatenate(mesh_v, axis=0)
    faces = np.concatenate(mesh_f, axis=0)
    n_extra = n_v - len(theta_arr)
    theta_arr = np.concatenate([theta_arr, np.full(n_extra, np.nan)])
    phi_arr = np.concatenate([phi_arr, np.full(n_extra, np.nan)])
    lower = np.concatenate([lower, np.zeros(n_extra, dtype=bool)])
    region = np.concatenate([region, np.zeros(n_extra, dtype=np.int64)])
    _label_regions(vertices, region, parts, sv)
    parts["teeth_anchor_upper"], parts["teeth_anchor_lower"] = _teeth_anchors(grid, quad_lo, r_m, mouth_c0, mouth_c1)
    return HeadMesh(vertices=vertices, faces=faces, region=region, theta=theta_arr, phi=phi_arr,
                    lower=lower, parts=parts, bag_lower=bag_lower,
                    eye_cols=tuple((r, a, b, s) for r, a, b, s, _ in eye_slits),
                    mouth_slit=(r_m, mouth_c0, mouth_c1), grid=grid, lid_pitch=lid_pitch)


def _teeth_anchors(grid, quad_lo, r_m, c0, c1):
    """Lip rings one row above / below the mouth line, ordered by increasing x."""
    cols = np.arange(c0, c1 + 1)
    return grid[r_m - 1, cols].copy(), grid[r_m + 1, cols].copy()


def _sculpt_lips(v, grid, dups, r_m, c0, c1, lower, parts, region):
    """Lip volumes as ray-direction displacements keyed to the mouth line."""
    v = v.copy()
    upper_edge = grid[r_m, c0:c1 + 1]
    lower_edge = np.concatenate([[grid[r_m, c0]], dups, [grid[r_m, c1]]])
    parts["mouth_upper"], parts["mouth_lower"] = upper_edge.copy(), lower_edge.copy()
    x_c0, x_c1 = v[grid[r_m, c0], 0], v[grid[r_m, c1], 0]
    half = 0.5 * (x_c1 - x_c0)
    n_rows = grid.shape[0]
    rows = np.arange(max(r_m - 8, 0), min(r_m + 9, n_rows))
    cols = np.arange(c0 - 3, c1 + 4)
    for j in cols:
        ys = v[grid[r_m, j], 1]
        for i in rows:
            ids = [grid[i, j]]
            if i == r_m and c0 < j < c1:
                ids.append(dups[j - c0 - 1])
            for vid in ids:
                p = v[vid]
                dy = p[1] - ys
                t = p[0] / half
                width = np.clip(1 - t * t, 0, 1) ** 0.8
                is_low = lower[vid] or i > r_m
                if not is_low:
                    h = 0.0085 * (1 - 0.18 * np.exp(-(t / 0.16) ** 2))  # cupid's bow dip
                    f = 0.0029 * np.sin(np.pi * np.clip(dy / h, 0, 1)) ** 0.7
                    if 0 <= dy < h and width > 0.05:
                        region[vid] = _R["lips"]
                else:
                    h = 0.0095
                    f = 0.0033 * np.sin(np.pi * np.clip(-dy / h, 0, 1)) ** 0.7
                    if 0 <= -dy < h and width > 0.05:
                        region[vid] = _R["lips"]
                corner = -0.0016 * np.exp(-((abs(t) - 1) / 0.18) ** 2 - (dy / 0.006) ** 2)
                d = p - HEAD_CENTRE
                d /= np.linalg.norm(d)
                v[vid] = p + (f * width + corner) * d
    return v


def _eye_dir(yaw, pitch):
    return np.stack([np.cos(pitch) * np.sin(yaw), np.sin(pitch), np.cos(pitch) * np.cos(yaw)], -1)


def _to_eye(p, c):
    q = p - c
    r = np.linalg.norm(q, axis=-1)
    yaw = np.arctan2(q[..., 0], q[..., 2])
    pitch = np.arcsin(np.clip(q[..., 1] / r, -1, 1))
    return r, yaw, pitch


def _sculpt_lids(v, faces, grid, dups, row, ca, cb, e, side, parts):
    """Open the palpebral fissure of eye ``e`` and shape the lids around the eyeball."""
    v = v.copy()
    c = EYE_CENTRES[e]
    n = cb - ca + 1
    t = np.linspace(0.0, 1.0, n)
    if side < 0:
        t = t[::-1]  # t = 0 at the inner corner
    r0, yaw0, _ = _to_eye(v[grid[row, ca:cb + 1]], c)
    yaw_in, yaw_out = -side * np.radians(60), side * np.radians(66)
    yaw = yaw_in + (yaw_out - yaw_in) * t
    tilt = np.radians(4.0) * t
    s = np.sin(np.pi * t)
    pitch_u = np.radians(38.0) * s ** 0.7 * (1 - 0.25 * t) + tilt
    pitch_l = -np.radians(24.0) * s ** 0.9 + tilt
    upper_ids = grid[row, ca:cb + 1]
    lower_ids = np.concatenate([[grid[row, ca]], dups, [grid[row, cb]]])
    k_up, k_lo = 5, 4
    for jj, j in enumerate(range(ca, cb + 1)):
        # blend rows above toward the lid surface, interpolating pitch/radius to the skin at k_up
        for sign, ids0, pitch0, kk in ((1, upper_ids, pitch_u, k_up), (-1, lower_ids, pitch_l, k_lo)):
            vid_end = grid[row - sign * kk, j]
            r_end, yaw_end, p_end = _to_eye(v[vid_end], c)
            for k in range(kk):
                vid = ids0[jj] if k == 0 else grid[row - sign * k, j]
                a = k / kk
                r_k = (1 - a) * LID_RADIUS + a * r_end
                p_k = (1 - a) * pitch0[jj] + a * p_end
                y_k = (1 - a) * yaw[jj] + a * yaw_end
                target = c + r_k * _eye_dir(y_k, p_k)
                v[vid] = target
    # keep all nearby skin outside the eyeball, then relax the lid skin
    near = np.where(np.linalg.norm(v - c, axis=1) < 0.024)[0]
    rim = set(upper_ids.tolist()) | set(lower_ids.tolist())
    free = np.array([i for i in near if i not in rim], dtype=np.int64)
    nbrs = _neighbours(faces, len(v))
    for _ in range(6):
        for i in free:
            v[i] = 0.5 * v[i] + 0.5 * v[nbrs[i]].mean(axis=0)
        q = v[free] - c
        r = np.linalg.norm(q, axis=1, keepdims=True)
        v[free] = np.where(r < LID_RADIUS, c + q / r * LID_RADIUS, v[free])
    parts[f"lid_upper_{e}"] = upper_ids.copy()
    parts[f"lid_lower_{e}"] = lower_ids.copy()
    return v, pitch_u, pitch_l


def _neighbours(faces: np.ndarray, n: int) -> list[np.ndarray]:
    nb: list[set] = [set() for _ in range(n)]
    for a, b, c in faces:
        nb[a].update((b, c))
        nb[b].update((a, c))
        nb[c].update((a, b))
    return [np.array(sorted(s), dtype=np.int64) for s in nb]


def _loop_edge_dir(faces: np.ndarray, a: int, b: int) -> bool:
    """True if some face contains the directed edge a -> b."""
    for f in faces:
        for k in range(3):
            if f[k] == a and f[(k + 1) % 3] == b:
                return True
    return False


def _close_loop(loop_ids, rings, n_v, faces, cap_point):
    """Faces joining ``loop_ids`` through ``rings`` (list of (n,3) arrays) to a cap vertex."""
    n = len(loop_ids)
    ring_ids = [np.asarray(loop_ids)]
    new_v = []
    for rp in rings:
        ids = n_v + len(new_v) * 0 + np.arange(n) + sum(len(x) for x in new_v)
        new_v.append(rp)
        ring_ids.append(ids)
    cap_id = n_v + sum(len(x) for x in new_v)
    new_v.append(cap_point[None])
    f = []
    for a_ids, b_ids in zip(ring_ids[:-1], ring_ids[1:]):
        for k in range(n):
            k1 = (k + 1) % n
            f += [[a_ids[k], b_ids[k], b_ids[k1]], [a_ids[k], b_ids[k1], a_ids[k1]]]
    last = ring_ids[-1]
    for k in range(n):
        f.append([last[k], cap_id, last[(k + 1) % n]])
    f = np.asarray(f, dtype=np.int64)
    # the base mesh must use the loop edge in the opposite direction to our first face
    a, b = loop_ids[0], loop_ids[1]
    ours_ab = True  # our first quad uses edge b -> a? check explicitly
    ours_ab = _loop_edge_dir(f[:2], a, b)
    theirs_ab = _loop_edge_dir(faces, a, b)
    if ours_ab == theirs_ab:
        f = f[:, ::-1].copy()
    new_ids = np.arange(n_v, cap_id + 1)
    return new_ids, np.concatenate(new_v, axis=0), f


def _mouth_bag(v, faces, upper, lower, n_v):
    """Inner mouth: rings behind the lip loop, opening up/down into a closed sack."""
    loop = np.concatenate([upper, lower[1:-1][::-1]])
    p = v[loop]
    n_up = len(upper)
    is_low = np.zeros(len(loop), dtype=bool)
    is_low[n_up:] = True
    x = p[:, 0]
    half = np.abs(x).max()
    u = x / half
    rings = []
    lows = [is_low.astype(np.float64)]
    centre = np.array([0.0, p[:, 1].mean(), p[:, 2].min()])
    for depth, h, squeeze in ((0.004, 0.004, 0.9), (0.012, 0.011, 0.78), (0.024, 0.014, 0.66),
                              (0.036, 0.012, 0.5)):
        q = p.copy()
        q[:, 0] = x * squeeze
        sign = np.where(is_low, -1.0, 1.0)
        q[:, 1] = centre[1] + sign * h * np.sqrt(np.clip(1 - u * u, 0.0, 1.0)) * 1.0 + (p[:, 1] - centre[1]) * 0.3
        q[:, 2] = p[:, 2] - depth - 0.004 * (1 - u * u)
        rings.append(q)
    cap = np.array([0.0, centre[1], p[:, 2].max() - 0.05])
    ids, nv, nf = _close_loop(loop, rings, n_v, faces, cap)
    # lower-jaw membership of bag vertices: by side, smooth toward the corners
    low_ring = np.where(is_low, 1.0, 0.0)
    corner = np.abs(u) > 0.999
    low_ring[corner] = 0.5
    bag_lower = np.concatenate([np.tile(low_ring, len(rings)), [0.5]])
    return ids, bag_lower, nv, nf


def _eye_pocket(v, faces, upper, lower, e, n_v):
    """A cone from the fissure rim into the eyeball (hidden by it) closing the eye hole."""
    loop = np.concatenate([upper, lower[1:-1][::-1]])
    c = EYE_CENTRES[e]
    q = v[loop] - c
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rings = [c + 0.85 * EYE_RADIUS * q]
    ids, nv, nf = _close_loop(loop, rings, n_v, faces, c - np.array([0, 0, 0.3 * EYE_RADIUS]))
    return ids, nv, nf


def _label_regions(v, region, parts, sphere_v):
    """Assign skin sub-regions (scalp, brows, neck, nostrils) and the separate parts."""
    skin = region == _R["skin"]
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    # scalp: above a hairline that is high on the forehead and drops behind the ears
    hairline = np.where(z > 0.0, 0.062 - 0.25 * np.clip(np.abs(x) - 0.035, 0, None) - 0.0 * z,
                        0.03 + 0.45 * z)
    hairline = np.where((z < 0.0) & (np.abs(x) > 0.05), 0.01 + 0.6 * np.maximum(z, -0.08), hairline)
    scalp = skin & (y > np.maximum(hairline, -0.06)) & ~((z > 0.0) & (y < 0.045))
    region[scalp] = _R["scalp"]
    for side in (1, -1):
        bx = side * x
        brow_y = 0.0205 + 0.004 * np.exp(-((bx - 0.032) / 0.012) ** 2) - 0.02 * np.clip(bx - 0.05, 0, None)
        brow = skin & (bx > 0.011) & (bx < 0.056) & (np.abs(y - brow_y) < 0.0052) & (z > 0.035)
        region[brow] = _R["brows"]
    neck = skin & (y < -0.105) & ~((z > 0.045) & (y > -0.115))
    region[neck] = _R["neck"]
    nostril = skin & (np.abs(np.abs(x) - 0.0085) < 0.004) & (np.abs(y + 0.045) < 0.003) & (z > 0.085)
    region[nostril] = _R["nostrils"]
    region[parts["bag"]] = _R["mouth_interior"]
    for e in range(2):
        region[parts[f"pocket_{e}"]] = _R["eye_pocket"]
        ids = parts[f"eyeball_{e}"]
        region[ids] = _R["eyeball_left" if e == 0 else "eyeball_right"]
        cosang = sphere_v[:, 2]
        region[ids[cosang > np.cos(np.radians(25))]] = _R["iris"]
        region[ids[cosang > np.cos(np.radians(10))]] = _R["pupil"]
        region[parts[f"ear_{e}"]] = _R["ears"]
