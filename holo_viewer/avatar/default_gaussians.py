"""The default Gaussian avatar, generated deterministically from the default head.

No downloads: Gaussians are sampled on the triangles of
:func:`holo_viewer.flame.default_head.load_default_model` (with teeth) and bound to them
(:class:`~holo_viewer.avatar.rigged.RiggedAvatar`), so every FLAME parameter animates them.

Generation (``GENERATOR_VERSION`` below; bump it when any of this changes):

1. *Placement.* Faces get Gaussians in proportion to area x a per-region density weight
   (eyes, lips, brows denser; the neck sparser; none on the eye pockets, which
   lie inside the eyeballs), drawn with a seeded generator
   as uniform barycentric points; each Gaussian takes the region label of the nearest
   vertex of its face (teeth vertices are labelled ``teeth``).
2. *Shape.* Flat disks in the tangent plane (in-plane sigma = 1.15 x the local sample
   spacing, normal sigma = 0.2 x that) with a random in-plane rotation, so the surface is
   closed and opaque (opacity 0.99). Hair (the head's hair shell): half the hair Gaussians are
   strands (4 x longer along a down-and-back combing direction, lifted up to 2.5 mm off
   the shell); brows are short strands combed outward.
3. *Colour.* Region albedo (skin with low-frequency tone variation, cheek and nose
   redness; lips; brows; hair with per-strand variation; eyes with sclera, a radial iris
   (limbal ring, radial streaks) and a pupil by angle from the eye's optical axis; mouth
   interior; teeth), times baked soft lighting from the smooth rest normals (3DGS colours
   carry lighting; a key light from the upper front-left and ambient), stored as SH DC.
   SH degree 1 holds a little view-dependent sheen (brighter when seen along the normal:
   skin 0.03, lips 0.06, eyes 0.08); higher degrees are zero. SH stays in world space
   (as in GaussianAvatars), so the sheen does not turn with the head.

The local Gaussians are cached in ``$HOLO_VIEWER_CACHE`` or ``$XDG_CACHE_HOME/holo_viewer``
(default ``~/.cache/holo_viewer``) as ``default_avatar_<key>.npz``, keyed by a hash of the
generator version, this module's source, the parameters and the default head file; generation itself takes about
a second or two for 100k Gaussians, so the cache only saves start-up time.

Fitted Gaussians (shipped)
--------------------------
``assets/default_avatar.npz`` holds the generator's Gaussians after a fit against renders of the
head's own textured mesh (``scripts/fit_default_avatar.py``, :mod:`holo_viewer.assets_build.fit_avatar`,
docs/avatar_fit.md): same count and binding, refined offsets, scales, rotations, opacities and SH
(degree 1), stored as float16. It is keyed by the SHA-256 of the default head file and a digest of
the mesh colouring it was fitted to (:func:`appearance_digest`: texture version, mesh key and seed
of ``flame.head_textures`` for a textured head, else a hash of the region colours). :func:`default_avatar` with the
defaults (``n_gaussians=DEFAULT_N_GAUSSIANS``, ``seed=0``) loads it when both keys match the
current head; otherwise (asset missing, unreadable, or fitted to another head / colouring) it
warns once, saying why, and falls back to the generator. Any other ``n_gaussians`` or ``seed``
asks for the generator explicitly (no warning): the fit is for one Gaussian set.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import AvatarError, HoloViewerError, InputError
from ..fileio import file_sha256, read_npz, save_npz
from ..geometry import vertex_normals
from .binding import world_to_local_np
from .gaussians import SH_C0, Gaussians

__all__ = ["default_avatar", "generate_default_gaussians", "GENERATOR_VERSION", "REGION_DENSITY",
           "DEFAULT_N_GAUSSIANS", "FITTED_ASSET", "FITTED_FORMAT", "fitted_asset_path", "appearance_colors",
           "appearance_digest", "save_fitted_avatar", "load_fitted_avatar", "fitted_asset_status"]

GENERATOR_VERSION = 2  # 2: the ICT-based default head (hair shell, lashes, own teeth; issue 17)
#: the Gaussian count of the shipped, fitted avatar (and the default of :func:`default_avatar`)
DEFAULT_N_GAUSSIANS = 100_000
FITTED_ASSET = "default_avatar.npz"
FITTED_FORMAT = 1
SH_C1 = 0.4886025119029199

#: Relative Gaussian density per area by region (default 1.0).
REGION_DENSITY = {"skin": 1.0, "scalp": 0.1, "hair": 0.7, "lashes": 0.0, "tongue": 0.5, "gums": 0.3,
                  "brows": 2.5, "lips": 3.0, "eyeball_left": 0.5, "eyeball_right": 0.5, "iris": 4.0, "pupil": 4.0,
                  "ears": 0.8, "mouth_interior": 0.3, "eye_pocket": 0.0, "neck": 0.4, "nostrils": 1.0,
                  "teeth": 0.5}

_ALBEDO = {"skin": (0.80, 0.58, 0.47), "scalp": (0.70, 0.52, 0.43), "hair": (0.16, 0.10, 0.065),
           "lashes": (0.05, 0.04, 0.035), "tongue": (0.65, 0.30, 0.30), "gums": (0.70, 0.35, 0.36), "brows": (0.20, 0.13, 0.09),
           "lips": (0.70, 0.34, 0.34), "eyeball": (0.92, 0.90, 0.87), "ears": (0.80, 0.56, 0.46),
           "mouth_interior": (0.42, 0.12, 0.13), "eye_pocket": (0.25, 0.12, 0.12), "neck": (0.76, 0.55, 0.45),
           "nostrils": (0.38, 0.20, 0.18), "teeth": (0.93, 0.91, 0.84)}
_SHEEN = {"lips": 0.06, "eyeball": 0.08, "teeth": 0.05, "hair": 0.04}
_OPACITY = 0.99


def _cache_dir() -> Path:
    from ..cache import cache_dir

    return cache_dir()


def _smooth_noise(p: np.ndarray, rng: np.random.Generator, n_waves: int, wavelength: tuple[float, float]) -> np.ndarray:
    """Sum of random plane waves in 3D, roughly in [-1, 1]."""
    out = np.zeros(p.shape[0])
    for _ in range(n_waves):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        k = 2 * np.pi / rng.uniform(*wavelength)
        out += np.sin(k * (p @ d) + rng.uniform(0, 2 * np.pi))
    return out / np.sqrt(n_waves / 2)


def _tangent_frame(n: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangent t (closest to ``direction`` within the plane normal to n) and b = t x n."""
    t = direction - (direction * n).sum(1, keepdims=True) * n
    ln = np.linalg.norm(t, axis=1, keepdims=True)
    alt = np.cross(n, np.array([1.0, 0.0, 0.0]))
    t = np.where(ln > 1e-6, t / np.maximum(ln, 1e-12), alt / np.maximum(np.linalg.norm(alt, axis=1, keepdims=True),
                                                                          1e-12))
    return t, np.cross(t, n)


def _eye_colours(p: np.ndarray, region: np.ndarray, names: list[str], v: np.ndarray, vregion: np.ndarray,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Colours (M, 3) of eye Gaussians (rows where ``region`` is an eye label) and their mask."""
    eye_ids = [names.index(k) for k in ("eyeball_left", "eyeball_right", "iris", "pupil") if k in names]
    mask = np.isin(region, eye_ids)
    col = np.zeros((int(mask.sum()), 3))
    if not mask.any():
        return col, mask
    pe = p[mask]
    out = np.zeros_like(pe)
    vmask = np.isin(vregion, eye_ids)
    front_ids = [names.index(k) for k in ("iris", "pupil") if k in names]
    for side in (1.0, -1.0):
        sel_v = vmask & (np.sign(v[:, 0]) == side)
        sel_g = np.sign(pe[:, 0]) == side
        if not sel_v.any() or not sel_g.any():
            continue
        centre = v[sel_v].mean(0)
        front = np.isin(vregion, front_ids) & sel_v
        axis = (v[front].mean(0) - centre) if front.any() else np.array([0.0, 0.0, 1.0])
        axis /= np.linalg.norm(axis)
        if front.any():
            ang_v = np.arccos(np.clip(((v[front] - centre) @ axis) / np.linalg.norm(v[front] - centre, axis=1), -1, 1))
            theta_i = float(np.clip(ang_v.max() * 1.05, 0.35, 0.75))
        else:
            theta_i = 0.5
        theta_p = 0.4 * theta_i
        d = pe[sel_g] - centre
        ang = np.arccos(np.clip((d @ axis) / np.maximum(np.linalg.norm(d, axis=1), 1e-12), -1, 1))
        # azimuth around the axis for radial iris streaks
        ref = np.cross(axis, [0.0, 1.0, 0.0])
        ref /= np.linalg.norm(ref)
        az = np.arctan2(d @ np.cross(axis, ref), d @ ref)
        r = ang / theta_i
        streak = 0.12 * np.sin(23 * az + 3 * rng.uniform()) + 0.06 * np.sin(57 * az)
        iris = np.array([0.28, 0.42, 0.55])[None] * (0.75 + 0.5 * r[:, None] + streak[:, None])
        iris = iris * (1.0 - 0.6 * np.clip((r[:, None] - 0.85) / 0.15, 0, 1))  # dark limbal ring
        sclera = np.array(_ALBEDO["eyeball"])[None] * (1.0 - 0.10 * np.clip((ang[:, None] - 1.2) / 0.6, 0, 1))
        c = np.where((r < 1.0)[:, None], iris, sclera)
        c = np.where((ang < theta_p)[:, None], np.array([0.02, 0.02, 0.025])[None], c)
        out[sel_g] = c
    col[:] = out
    return col, mask


def generate_default_gaussians(model: Any, n_gaussians: int = 100_000, sh_degree: int = 1, seed: int = 0
                               ) -> tuple[Gaussians, np.ndarray]:
    """Local Gaussians (numpy float32) and their binding (N,) on ``model``'s rest mesh.

    Parameters
    ----------
    model : FlameModel
        The default head (``metadata`` must hold ``vertex_region`` and ``region_names``).
    n_gaussians : int
        N.
    sh_degree : int
        1..3 (degree 0 has no sheen; allowed too).
    seed : int
        Random seed (the result is deterministic).
    """
    md = model.metadata
    if "vertex_region" not in md or "region_names" not in md:
        raise AvatarError("default avatar: the head model lacks 'vertex_region' / 'region_names' metadata")
    rng = np.random.default_rng(seed)
    v = model.v_template.detach().cpu().double().numpy()
    f = model.faces.cpu().numpy()
    names = [str(s) for s in md["region_names"]]
    if "teeth" not in names:  # FLAME-style teeth appended by add_teeth
        names.append("teeth")
    vregion = np.full(v.shape[0], len(names) - 1, np.int64)  # vertices beyond the labels: teeth
    vr = np.asarray(md["vertex_region"]).astype(np.int64)
    vregion[:vr.shape[0]] = vr

    # 1. placement
    e0, e1 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e0, e1), axis=1)
    face_region = np.array([np.bincount(vregion[tri], minlength=len(names)).argmax() for tri in f])
    dens = np.array([REGION_DENSITY.get(nm, 1.0) for nm in names])[face_region]
    w = area * dens
    counts = rng.multinomial(n_gaussians, w / w.sum())
    binding = np.repeat(np.arange(f.shape[0]), counts)
    n = binding.shape[0]
    uv = rng.uniform(size=(n, 2))
    flip = uv.sum(1) > 1
    uv[flip] = 1 - uv[flip]
    bary = np.column_stack([1 - uv.sum(1), uv])
    tri = v[f[binding]]  # (N, 3, 3)
    p = np.einsum("nk,nkc->nc", bary, tri)
    region = vregion[f[binding, np.argmax(bary, axis=1)]]
    vn = vertex_normals(v, f)
    nrm = np.einsum("nk,nkc->nc", bary, vn[f[binding]])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    face_n = np.cross(e0, e1)[binding]
    face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-12)

    # 2. shape: spacing from the density: d = sqrt(sum(w) / (N dens))
    spacing = np.sqrt(w.sum() / n_gaussians / dens[binding])
    sig = 1.15 * spacing
    scales = np.column_stack([sig, 0.2 * sig, sig])
    theta = rng.uniform(0, 2 * np.pi, n)
    t0, b0 = _tangent_frame(face_n, np.array([1.0, 0.0, 0.0]))
    t = np.cos(theta)[:, None] * t0 + np.sin(theta)[:, None] * b0
    rid = {nm: i for i, nm in enumerate(names)}
    hair = (region == rid.get("hair", rid.get("scalp", -1))) & (rng.uniform(size=n) < 0.5)
    if hair.any():
        comb = np.column_stack([np.zeros(n), -np.ones(n), -0.6 * np.ones(n)])
        comb[:, 0] = 0.25 * np.sign(p[:, 0])
        th, _ = _tangent_frame(face_n, comb / np.linalg.norm(comb, axis=1, keepdims=True))
        jitter = rng.normal(scale=0.25, size=(n, 1)) * np.cross(th, face_n)
        th = th + jitter
        th /= np.linalg.norm(th, axis=1, keepdims=True)
        t = np.where(hair[:, None], th, t)
        scales[hair] = np.column_stack([4.0 * sig[hair], 0.25 * sig[hair], 0.45 * sig[hair]])
        p = p + (hair * rng.uniform(0.0, 2.5e-3, n))[:, None] * face_n
    brows = region == rid.get("brows", -1)
    if brows.any():
        comb = np.column_stack([np.sign(p[:, 0]), 0.25 * np.ones(n), np.zeros(n)])
        tb, _ = _tangent_frame(face_n, comb / np.linalg.norm(comb, axis=1, keepdims=True))
        t = np.where(brows[:, None], tb, t)
        scales[brows] = np.column_stack([2.2 * sig[brows], 0.3 * sig[brows], 0.5 * sig[brows]])
        p = p + (brows * 4e-4)[:, None] * face_n
    t = t - (t * face_n).sum(1, keepdims=True) * face_n
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    rot_world = np.stack([t, face_n, np.cross(t, face_n)], axis=2)  # columns: tangent, normal, bitangent

    # 3. colour
    albedo = np.zeros((n, 3))
    for nm, i in rid.items():
        key = "eyeball" if nm in ("eyeball_left", "eyeball_right", "iris", "pupil") else nm
        albedo[region == i] = _ALBEDO.get(key, _ALBEDO["skin"])
    skin_like = np.isin(region, [rid[k] for k in ("skin", "ears", "neck", "nostrils") if k in rid])
    tone = 1.0 + 0.035 * _smooth_noise(p, rng, 8, (0.02, 0.06)) + 0.02 * rng.normal(size=n)
    red = 0.10 * sum(np.exp(-np.sum(((p - c) / np.array(r)) ** 2, axis=1)) for c, r in (
        ((0.045, -0.012, 0.075), (0.02, 0.015, 0.02)), ((-0.045, -0.012, 0.075), (0.02, 0.015, 0.02)),
        ((0.0, -0.005, 0.11), (0.012, 0.012, 0.02))))
    albedo[skin_like] *= tone[skin_like, None]
    albedo[skin_like] += red[skin_like, None] * np.array([0.6, -0.25, -0.25])
    lips = region == rid.get("lips", -1)
    albedo[lips] *= (1.0 + 0.05 * rng.normal(size=int(lips.sum())))[:, None]
    hairy = np.isin(region, [rid.get("hair", -1), rid.get("brows", -1)])
    albedo[hairy] *= np.clip(1.0 + 0.25 * rng.normal(size=int(hairy.sum())), 0.5, 1.6)[:, None]
    eye_col, eye_mask = _eye_colours(p, region, names, v, vregion, rng)
    albedo[eye_mask] = eye_col
    light = np.array([0.35, 0.55, 0.75])
    light /= np.linalg.norm(light)
    shade = 0.58 + 0.42 * np.clip(nrm @ light, 0.0, 1.0) + 0.08 * np.clip(nrm[:, 1], -1, 0)
    interior = np.isin(region, [rid.get(k, -1) for k in ("mouth_interior", "eye_pocket")])
    shade[interior] = 0.7
    shade[region == rid["teeth"]] = 0.95
    rgb = np.clip(albedo * shade[:, None], 0.0, 1.0)
    n_sh = (sh_degree + 1) ** 2
    sh = np.zeros((n, n_sh, 3))
    sh[:, 0] = (rgb - 0.5) / SH_C0
    if sh_degree >= 1:
        k = np.full(n, 0.03)
        for nm, val in _SHEEN.items():
            ids = [rid[x] for x in (("eyeball_left", "eyeball_right", "iris", "pupil") if nm == "eyeball" else (nm,))
                   if x in rid]
            k[np.isin(region, ids)] = val
        # colour += -k (dir . n) with dir from the camera to the Gaussian: SH_1 = (-y, z, -x) C1
        sh[:, 1] = (k * nrm[:, 1] / SH_C1)[:, None]
        sh[:, 2] = (-k * nrm[:, 2] / SH_C1)[:, None]
        sh[:, 3] = (k * nrm[:, 0] / SH_C1)[:, None]

    from ..geometry import rotmat_to_quat_np

    quats = rotmat_to_quat_np(rot_world)
    opacity = np.full(n, np.log(_OPACITY / (1 - _OPACITY)))
    mu, q_local, ls_local = world_to_local_np(p, quats, np.log(scales), binding, v, f)
    local = Gaussians(mu.astype(np.float32), q_local.astype(np.float32), ls_local.astype(np.float32),
                      opacity.astype(np.float32), sh.astype(np.float32),
                      extra={"region": region.astype(np.int16)})
    return local, binding


def _with_sh_degree(sh: np.ndarray, degree: int) -> np.ndarray:
    """(N, (degree+1)^2, 3): truncated, or padded with zeros."""
    k = (degree + 1) ** 2
    if sh.shape[1] >= k:
        return np.ascontiguousarray(sh[:, :k])
    return np.concatenate([sh, np.zeros((sh.shape[0], k - sh.shape[1], 3), sh.dtype)], axis=1)


@functools.lru_cache(maxsize=4)
def _cached_local(n_gaussians: int, sh_degree: int, seed: int, use_disk_cache: bool
                  ) -> tuple[Gaussians, np.ndarray, tuple[str, ...]]:
    from ..flame.default_head import default_head_path, load_default_model

    model = load_default_model(add_teeth=True)
    code = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]
    key_src = (f"v{GENERATOR_VERSION}|code{code}|n{n_gaussians}|sh{sh_degree}|seed{seed}"
               f"|head{file_sha256(default_head_path())}")
    key = hashlib.sha256(key_src.encode()).hexdigest()[:16]
    path = _cache_dir() / f"default_avatar_{key}.npz"
    names = tuple(str(s) for s in model.metadata["region_names"])
    names = names if "teeth" in names else names + ("teeth",)
    if use_disk_cache and path.exists():
        try:
            z = read_npz(path, AvatarError, "default avatar cache")
            local = Gaussians(z["means"], z["quats"], z["log_scales"], z["opacity_logits"], z["sh"],
                              extra={"region": z["region"]})
            return local, z["binding"].astype(np.int64), names
        except (HoloViewerError, KeyError):
            pass  # unreadable, truncated or stale cache: regenerate and overwrite
    local, binding = generate_default_gaussians(model, n_gaussians, sh_degree, seed)
    if use_disk_cache:
        try:
            save_npz(path, means=local.means, quats=local.quats, log_scales=local.log_scales,
                     opacity_logits=local.opacity_logits, sh=local.sh, region=local.extra["region"],
                     binding=binding, key=np.array(key_src))
        except Exception:  # noqa: BLE001 - a read-only cache dir must not break the avatar
            pass
    return local, binding, names


# ------------------------------------------------------------------------------ fitted asset
def fitted_asset_path() -> Path:
    """``assets/default_avatar.npz`` of the checkout."""
    return Path(__file__).resolve().parents[2] / "assets" / FITTED_ASSET


def _head_appearance(model: Any) -> Any:
    """The head's textured appearance (``flame.head_textures``) or None (no textures / no UVs)."""
    try:
        from ..flame.head_textures import head_appearance
    except ImportError:  # a head package without textures
        return None
    return head_appearance(model)


def appearance_colors(model: Any) -> np.ndarray:
    """(V, 3) per-vertex colours of the head's mesh renders: the textured appearance's vertex colours
    when the head has textures, else its region colours smoothed once (``flame.preview``)."""
    app = _head_appearance(model)
    if app is not None:
        return np.asarray(app.vertex_colors, np.float64)
    from ..flame.preview import region_colors, smooth_vertex_colors

    md = getattr(model, "metadata", {}) or {}
    if "vertex_region" not in md or "region_names" not in md:
        raise AvatarError("appearance: the head model lacks 'vertex_region' / 'region_names' metadata")
    c = region_colors(md["vertex_region"], [str(x) for x in md["region_names"]], int(model.n_vertices))
    return smooth_vertex_colors(c, model.faces.cpu().numpy(), 1)


def appearance_digest(model: Any) -> str:
    """A name for the colouring of the head's mesh renders (what the shipped avatar is fitted to):
    ``textures:v<version>:<mesh key>:<seed>`` for a textured head (``flame.head_textures``), else
    ``region-colours:<SHA-256 of the colours>``."""
    app = _head_appearance(model)
    if app is not None:
        from ..flame.head_textures import appearance_inputs, mesh_key

        return f"textures:v{app.version}:{mesh_key(appearance_inputs(model), app.seed)}:{app.seed}"
    c = np.ascontiguousarray(np.round(np.asarray(appearance_colors(model), np.float64), 6))
    return "region-colours:" + hashlib.sha256(c.tobytes()).hexdigest()[:16]


def save_fitted_avatar(path: str | Path, local: Gaussians, binding: np.ndarray, model: Any, colour_source: str,
                       head_path: str | Path | None = None, info: dict | None = None,
                       fit_angle_range_deg: tuple[float, float] | None = None) -> Path:
    """Write fitted local Gaussians (float16) + binding, keyed by the head file's digest and ``colour_source``;
    ``fit_angle_range_deg`` = [min, max] horizontal angle (deg) of the fit's cameras about the framing centre."""
    import json

    from ..flame.default_head import default_head_path

    g = local.numpy(np.float32)
    b = np.asarray(binding)
    if b.shape != (len(g),):
        raise InputError(f"binding: expected ({len(g)},), found {b.shape}")
    head = Path(head_path) if head_path is not None else default_head_path()
    arrays = {"means": g.means, "quats": g.quats, "log_scales": g.log_scales, "opacity_logits": g.opacity_logits,
              "sh": g.sh}
    for k, a in arrays.items():
        if not np.all(np.isfinite(a)):
            raise AvatarError(f"fitted avatar: {k} has non-finite values")
        if np.abs(a).max() > 6e4:
            raise AvatarError(f"fitted avatar: {k} exceeds the float16 range ({np.abs(a).max():.3g})")
    out = {k: a.astype(np.float16) for k, a in arrays.items()}
    out["binding"] = b.astype(np.int32)
    if "region" in local.extra:
        out["region"] = np.asarray(local.extra["region"]).astype(np.int16)
    out["format"] = np.array(FITTED_FORMAT)
    out["head_sha256"] = np.array(file_sha256(head))
    out["colour_source"] = np.array(str(colour_source))
    out["n_faces"] = np.array(int(model.faces.shape[0]))
    out["info"] = np.array(json.dumps(info or {}))
    if fit_angle_range_deg is not None:
        rng = np.asarray(fit_angle_range_deg, np.float64)
        if rng.shape != (2,) or not np.all(np.isfinite(rng)) or rng[0] > rng[1]:
            raise InputError(f"fit_angle_range_deg: expected [min, max] finite degrees, found {fit_angle_range_deg!r}")
        out["fit_angle_range_deg"] = rng
    from ..fileio import atomic_write

    target = Path(path)
    with atomic_write(target) as fh:
        np.savez_compressed(fh, **out)
    return target


def _unit_quats(q: np.ndarray) -> np.ndarray:
    """(N, 4) float32 unit quaternions that float32 re-normalisation (``RiggedAvatar``, PLY round trips)
    leaves unchanged: float16 storage is not unit length, and normalising a float32 vector again can
    move it by one ulp."""
    import torch

    n = np.linalg.norm(q, axis=1, keepdims=True)
    t = torch.from_numpy((q / np.where(n > 0, n, 1.0)).astype(np.float32))
    for _ in range(4):
        nxt = t / torch.linalg.norm(t, dim=-1, keepdim=True)
        if torch.equal(nxt, t):
            break
        t = nxt
    return t.numpy()


def load_fitted_avatar(path: str | Path) -> tuple[Gaussians, np.ndarray, dict[str, Any]]:
    """Local Gaussians (float32), binding (N,) int64 and the keys (``head_sha256``, ``colour_source``,
    ``format``, ``n_faces``, ``info``, ``fit_angle_range_deg``: [min, max] degrees or None for a file
    without it) of a fitted-avatar file.

    Raises
    ------
    AvatarError
        Unreadable file, missing fields, wrong shapes or non-finite values (naming the file and field).
    """
    import json

    z = read_npz(path, AvatarError, "fitted default avatar")
    need = ("means", "quats", "log_scales", "opacity_logits", "sh", "binding", "format", "head_sha256",
            "colour_source", "n_faces")
    missing = [k for k in need if k not in z]
    if missing:
        raise AvatarError(f"{path}: fitted default avatar: expected fields {list(need)}, missing {missing}")
    if int(z["format"]) != FITTED_FORMAT:
        raise AvatarError(f"{path}: fitted default avatar: expected format {FITTED_FORMAT}, found {int(z['format'])}")
    arrays = {k: np.asarray(z[k], np.float32) for k in ("means", "quats", "log_scales", "opacity_logits", "sh")}
    arrays["quats"] = _unit_quats(np.asarray(z["quats"], np.float64))
    for k, a in arrays.items():
        if not np.all(np.isfinite(a)):
            raise AvatarError(f"{path}: fitted default avatar: field {k!r} has non-finite values")
    extra = {"region": np.asarray(z["region"]).astype(np.int16)} if "region" in z else {}
    try:
        local = Gaussians(**arrays, extra=extra)
    except HoloViewerError as exc:
        raise AvatarError(f"{path}: fitted default avatar: {exc}") from exc
    binding = np.asarray(z["binding"]).astype(np.int64)
    if binding.shape != (len(local),):
        raise AvatarError(f"{path}: fitted default avatar: field 'binding': expected ({len(local)},), "
                          f"found {binding.shape}")
    keys = {"format": int(z["format"]), "head_sha256": str(z["head_sha256"]), "colour_source": str(z["colour_source"]),
            "n_faces": int(z["n_faces"]), "info": json.loads(str(z["info"])) if "info" in z else {},
            "fit_angle_range_deg": None}
    if "fit_angle_range_deg" in z:
        rng = np.asarray(z["fit_angle_range_deg"], np.float64)
        if rng.shape != (2,) or not np.all(np.isfinite(rng)) or rng[0] > rng[1]:
            raise AvatarError(f"{path}: fitted avatar: field 'fit_angle_range_deg': expected [min, max] finite "
                              f"degrees, found {rng.tolist()}")
        keys["fit_angle_range_deg"] = [float(rng[0]), float(rng[1])]
    return local, binding, keys


def _check_fitted(path: Path) -> tuple[tuple[Gaussians, np.ndarray, dict[str, Any]] | None, str]:
    """((local, binding, keys) or None, reason) for the fitted asset at ``path`` against the current head."""
    from ..flame.default_head import default_head_path, load_default_model

    if not path.exists():
        return None, f"{path} does not exist (run scripts/fit_default_avatar.py)"
    try:
        local, binding, keys = load_fitted_avatar(path)
    except AvatarError as exc:
        return None, str(exc)
    head = file_sha256(default_head_path())
    if keys["head_sha256"] != head:
        return None, (f"{path} was fitted to another default head (sha256 {keys['head_sha256'][:12]}..., the "
                      f"current head is {head[:12]}...); rerun scripts/fit_default_avatar.py")
    model = load_default_model(add_teeth=True)
    if keys["n_faces"] != int(model.faces.shape[0]) or (binding.size and binding.max() >= model.faces.shape[0]):
        return None, f"{path}: binding does not fit the current head ({int(model.faces.shape[0])} faces)"
    colours = appearance_digest(model)
    if keys["colour_source"] != colours:
        return None, (f"{path} was fitted to another mesh colouring ({keys['colour_source']}, the current one is "
                      f"{colours}); rerun scripts/fit_default_avatar.py")
    return (local, binding, keys), "ok"


def fitted_asset_status(path: str | Path | None = None) -> tuple[bool, str]:
    """(usable, reason): whether the fitted asset (default :func:`fitted_asset_path`) matches the current
    default head and its colouring; the reason says why not."""
    got, why = _check_fitted(Path(path) if path is not None else fitted_asset_path())
    return got is not None, why


_WARNED: set[str] = set()


@functools.lru_cache(maxsize=2)
def _fitted_local(path: str) -> tuple[Gaussians, np.ndarray] | None:
    """The fitted asset's local Gaussians and binding when usable, else None (warning once with the reason)."""
    import warnings

    got, why = _check_fitted(Path(path))
    if got is None:
        if why not in _WARNED:
            _WARNED.add(why)
            warnings.warn(f"default avatar: using the procedural generator, not the fitted Gaussians: {why}",
                          stacklevel=3)
        return None
    return got[0], got[1]


def default_avatar(n_gaussians: int = DEFAULT_N_GAUSSIANS, sh_degree: int = 1, seed: int = 0, *,
                   use_disk_cache: bool = True, fitted: bool = True) -> "RiggedAvatar":  # noqa: F821
    """The default rigged avatar: about ``n_gaussians`` Gaussians on the default head (with teeth).

    With the defaults (``n_gaussians == DEFAULT_N_GAUSSIANS``, ``seed == 0``, ``fitted``) these are the
    shipped fitted Gaussians (``assets/default_avatar.npz``) when it matches the current head and
    colouring, else the generator's (with one warning saying why). Other ``n_gaussians`` / ``seed``
    values, or ``fitted=False``, give the generator's Gaussians (see the module docstring).

    Parameters
    ----------
    n_gaussians : int
        N (>= 1000).
    sh_degree : int
        SH degree 0..3 (degree >= 1 carries a slight view-dependent sheen).
    seed : int
        Random seed of the generator (deterministic).
    use_disk_cache : bool
        Read/write the generated Gaussians in the user cache dir (see module docstring).
    fitted : bool
        Use the fitted asset when it applies (default True).

    Returns
    -------
    RiggedAvatar
        Bound to ``load_default_model(add_teeth=True)``; ``avatar.region`` (N,) holds the region
        label of each Gaussian and ``avatar.region_names`` the names.
    """
    from ..flame.default_head import load_default_model
    from .rigged import RiggedAvatar

    if not isinstance(n_gaussians, (int, np.integer)) or n_gaussians < 1000:
        raise InputError(f"n_gaussians: expected an integer >= 1000, found {n_gaussians!r}")
    if sh_degree not in (0, 1, 2, 3):
        raise InputError(f"sh_degree: expected 0..3, found {sh_degree!r}")
    got = None
    if fitted and int(n_gaussians) == DEFAULT_N_GAUSSIANS and int(seed) == 0:
        got = _fitted_local(str(fitted_asset_path()))
    if got is not None:
        local, binding = got[0], got[1]
        model = load_default_model(add_teeth=True)
        names = tuple(str(s) for s in model.metadata["region_names"])
        names = names if "teeth" in names else names + ("teeth",)
        local = local.replace(sh=_with_sh_degree(np.asarray(local.sh), int(sh_degree)))
    else:
        local, binding, names = _cached_local(int(n_gaussians), int(sh_degree), int(seed), bool(use_disk_cache))
        model = load_default_model(add_teeth=True)
    region = local.extra.get("region", np.zeros(len(local), np.int16))
    avatar = RiggedAvatar(model, local.replace(extra={}), binding=binding)
    # stored front to back: the renderers copy the splats in depth order every frame, and from an
    # input already nearly in that order the copies read memory in sequence (the tracked live
    # frame's depth-ordered copies: 13 -> 9 ms on 2 cores, the deformation 5.7 -> 6.7 ms, measured);
    # the pictures do not change
    order = front_to_back(avatar)
    avatar = RiggedAvatar(model, local.replace(extra={}).subset(order), binding=np.asarray(binding)[order])
    avatar.region = np.asarray(region).astype(np.int64)[order]
    avatar.region_names = names
    return avatar


def front_to_back(avatar: Any) -> np.ndarray:
    """Indices of ``avatar``'s Gaussians by decreasing z of their rest-pose centres (the face looks
    toward +z: nearest the viewer first), ties by index."""
    z = np.asarray(avatar.rest().numpy().means, dtype=np.float64)[:, 2]
    return np.argsort(-z, kind="stable")
