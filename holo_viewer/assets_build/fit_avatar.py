"""Fit a rigged Gaussian avatar to renders of its own textured mesh (issue 17; docs/avatar_fit.md).

The GaussianAvatars training recipe [Qian et al. CVPR'24] with the mesh renders as the dataset:

1. *Dataset.* The head is posed in many expressions (named ones, pain 0.25..1, random AU mixes
   from :mod:`holo_viewer.flame.expressions`, jaw and eye poses); each pose is rendered as the
   head's own mesh (textured when it has an appearance, else region colours:
   :class:`TargetSource`, :func:`holo_viewer.flame.preview.render_mesh_cameras`) through a subset of
   the quilt cameras plus a few orbit cameras, full resolution, black background, stored as uint8.
   Each pose renders in a forked child with a time limit (a hung offscreen render skips the pose).
2. *Parameters.* Per Gaussian, in its parent triangle's frame
   (docs/design.md "GaussianAvatars binding"): local offset ``mu``, local log-scale, local
   rotation, opacity logit and SH coefficients (degree 1: the mesh renders' lights are
   world-fixed, so view dependence is small). The binding (parent face) and the Gaussian count
   are fixed: no densification or pruning.
3. *Loss.* L1 over the whole image (``(1 - l) L1 + l (1 - SSIM)`` with ``l = config.ssim_weight``,
   0 by default: SSIM's convolutions cost as much as the render on this CPU) plus GaussianAvatars'
   regularisers ``w_pos mean(relu(|mu| - eps_pos))`` and ``w_scale mean(relu(exp(log_s) -
   eps_scale))`` (local units: the face scale).
4. *Optimiser.* Adam, per-parameter learning rates (:class:`AvatarFitConfig`), position learning rate
   decayed exponentially; one (pose, camera) image per step; the first ``1 - crop_fraction`` of
   the steps on the whole image at ``train_scale`` (box-downsampled target), the rest on
   full-resolution crops of the same pixel count centred on a random mesh pixel. Rendering with
   :mod:`holo_viewer.render.differentiable`.

Initial Gaussians come from the caller (the default avatar's generator) with their colours replaced by
the mesh colouring at each Gaussian's surface point (:func:`surface_colors`).

Build-time code (``scripts/fit_default_avatar.py`` writes ``assets/default_avatar.npz``): it wires the
face (flame, avatar) and the renderer together on top of :mod:`holo_viewer.pipeline`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import torch

from ..avatar.binding import bind_to_world, bind_to_world_np, face_frames
from ..avatar.gaussians import SH_C0, Gaussians
from ..camera import Cameras
from ..errors import InputError
from ..images import psnr
from ..render.config import RenderConfig
from ..render.differentiable import render_view
from ..pipeline.settings import FaceControls

__all__ = ["AvatarFitConfig", "AvatarFit", "TrainingPose", "TargetSource", "surface_points", "Dataset", "initial_with_surface_colors", "training_poses", "surface_colors",
           "orbit_cameras", "sheared_cameras", "camera_yaws", "camera_yaws_range", "training_cameras", "scaled_cameras", "build_dataset", "fit_gaussians", "fidelity",
           "transfer_avatar", "add_gaussians_on_faces", "prune_faintest", "slider_limit_deg", "quilt_fidelity",
           "detail_map", "rim_map"]

#: (mesh vertices, faces, cameras, indices) -> ((n, H, W, 3) float images in [0, 1], (n, H, W) bool masks)
TargetRenderer = Callable[[np.ndarray, np.ndarray, Cameras, Sequence[int]], "tuple[np.ndarray, np.ndarray]"]


@dataclass(frozen=True)
class AvatarFitConfig:
    """Fit settings (defaults: the shipped default avatar; see docs/avatar_fit.md)."""

    iterations: int = 3000
    views_per_step: int = 1
    train_scale: float = 0.5
    #: the last fraction of the iterations trains on full-resolution crops (train_scale x the tile)
    crop_fraction: float = 0.5
    #: a pose whose target render takes longer is skipped (None: render in-process, no limit)
    render_timeout_s: float | None = 60.0
    n_random_poses: int = 24
    quilt_views: tuple[int, ...] = (0, 4, 9, 14, 19, 24, 28, 33, 38, 43, 47)
    #: orbit cameras (yaw, pitch) in degrees about the framing centre, from quilt view 24
    orbit: tuple[tuple[float, float], ...] = ((-30.0, 0.0), (30.0, 0.0), (0.0, 12.0), (0.0, -12.0))
    #: "rotated": the orbit cameras turn to face the centre (their key lights turn with them, so the
    #: mesh is lit unlike in any quilt view; the first shipped fit); "sheared": they keep the quilt
    #: cameras' orientation with an off-axis principal point, as the quilt's own cameras (world-fixed lights)
    orbit_mode: str = "rotated"
    lr_means: float = 2e-3
    lr_means_final: float = 2e-4
    lr_log_scales: float = 5e-3
    lr_quats: float = 2e-3
    lr_opacity: float = 2e-2
    lr_sh_dc: float = 5e-3
    lr_sh_rest: float = 2.5e-4
    ssim_weight: float = 0.0
    w_pos: float = 1e-2
    eps_pos: float = 1.0
    w_scale: float = 1.0
    eps_scale: float = 0.6
    #: opacity regulariser ``w_opacity mean(o (1 - o))`` (o = sigmoid(logit)): pushes towards 0 or 1
    w_opacity: float = 0.0
    #: the share of the full-resolution crops centred on a mesh pixel drawn by the target's local detail
    #: (``detail_map``: |target - blur(target)|, where a smooth fit misses most, e.g. hair strands) instead
    #: of uniformly; 0: every crop uniform (the first fits)
    crop_detail: float = 0.0
    #: adaptive density control (3DGS, inside a budget; 0: off, the count and binding fixed): every
    #: ``densify_every`` steps from ``densify_from`` to ``densify_until`` (0: 3/4 of the iterations), the
    #: ``densify_split`` Gaussians of the highest mean world-space positional gradient (over the steps that
    #: saw them) are each split in two on their own triangle (centres drawn from the Gaussian, scales
    #: / ``split_factor``), those below ``prune_opacity`` are dropped, and the faintest beyond
    #: ``max_gaussians`` (0: no cap) too
    densify_every: int = 0
    densify_from: int = 0
    densify_until: int = 0
    densify_split: int = 0
    split_factor: float = 1.6
    #: "sample": children's centres drawn from the parent Gaussian, all scales / ``split_factor`` (3DGS);
    #: "axis": children at +-0.6 sigma along the parent's longest axis, that axis x 0.8 (the pair keeps the
    #: parent's variance), opacity ``1 - sqrt(1 - o)`` each (the pair keeps its alpha): the image barely
    #: changes at the split, for a fine-tune at a low position learning rate
    split_mode: str = "sample"
    prune_opacity: float = 0.0
    max_gaussians: int = 0
    #: the share of the steps drawn from each pose of the dataset (its order; normalised); empty: uniform.
    #: The patients' pain stage weights pain 1 up (its deformed skin is where a static colour misses most)
    pose_weights: tuple[float, ...] = ()
    #: the share of the steps drawn from each camera of the dataset (its order: ``quilt_views`` then
    #: ``orbit``; normalised); empty: uniform. The limit stage weights the outermost cameras up (the viewer
    #: slider's limits see the side hair at a grazing angle from those cameras only)
    camera_weights: tuple[float, ...] = ()
    #: silhouette terms (issue 35: helen's white hair against the black background puts 30-56 % of her
    #: squared error on the 4 px inside the mesh's outline; docs/avatar_fit.md "Silhouette stage"). The rim
    #: of a target is its pixels within ``rim_px`` of the mesh mask's outline, on either side
    #: (:func:`rim_map`). ``rim_weight``: those pixels' photometric loss weighted ``1 + rim_weight`` (the
    #: rest 1); ``crop_rim``: the share of the full-resolution crops centred on a rim pixel inside the mask
    #: (drawn before ``crop_detail``); ``w_alpha``: ``w_alpha`` x the mean |alpha - mask| over the image
    #: (alpha: the Gaussians' accumulated opacity, a second composite of the same projection with white
    #: colours; the mask the target's 1x depth mask), weighted as the photometric term. All 0: off (the
    #: random draws and the loss of the stages before are unchanged)
    rim_weight: float = 0.0
    rim_px: int = 4
    crop_rim: float = 0.0
    w_alpha: float = 0.0
    #: the photometric term per pixel: "l1" |image - target| (every stage so far), or "l2" (image - target)^2,
    #: the squared error that the fidelity's PSNR measures (it weighs the outline's large errors more than L1;
    #: tried for helen, docs/avatar_fit.md "Squared-error stage")
    photometric: str = "l1"
    seed: int = 0
    dtype: str = "float32"


@dataclass(frozen=True)
class TrainingPose:
    """One training expression: a name and its face controls."""

    name: str
    face: FaceControls


@dataclass
class AvatarFit:
    """The fitted local Gaussians (numpy float32), the loss per iteration and the timings (s)."""

    local: Gaussians
    losses: list[float]
    seconds: dict[str, float]
    n_images: int
    #: (N,) parent faces of ``local`` (the input binding unless densification changed the set)
    binding: np.ndarray | None = None
    #: adaptive density control per round: (step, split, pruned, count after)
    densify_log: list[tuple[int, int, int, int]] = dataclasses.field(default_factory=list)


# =============================================================================== poses and colours


def training_poses(au_map: Any, n_random: int = 24, seed: int = 0) -> list[TrainingPose]:
    """Named expressions, pain 0.25..1 and ``n_random`` random AU mixes with jaw and eye poses.

    Parameters
    ----------
    au_map : flame.expressions.AUMap
        Action-unit map of the head (``Pipeline.au_map``).
    n_random : int
        Random poses: 2-5 AUs at intensities U(0.5, AU max), jaw opening U(0, 0.25) rad with
        probability 0.5, eye gaze U(+-0.25) rad.
    """
    from ..flame.expressions import AU_MAX, AU_NAMES, expression_from_aus

    fixed: list[TrainingPose] = [TrainingPose("neutral", FaceControls())]
    for name, w in (("smile", 0.5), ("smile", 1.0), ("mouth_open", 0.5), ("mouth_open", 1.0), ("surprise", 1.0),
                    ("frown", 1.0)):
        fixed.append(TrainingPose(f"{name}_{w:g}", FaceControls(named=((name, w),))))
    for p in (0.25, 0.5, 0.75, 1.0):
        fixed.append(TrainingPose(f"pain_{p:g}", FaceControls(pain=p)))
    rng = np.random.default_rng(seed)
    usable = [a for a in AU_NAMES if a in getattr(au_map, "names", AU_NAMES)]
    for k in range(n_random):
        aus = {a: float(rng.uniform(0.5, AU_MAX[a])) for a in rng.choice(usable, size=int(rng.integers(2, 6)),
                                                                           replace=False)}
        expr = expression_from_aus(aus, au_map)
        jaw = np.array([rng.uniform(0.0, 0.25) if rng.uniform() < 0.5 else 0.0, 0.0, 0.0])
        eye = rng.uniform(-0.25, 0.25, size=2)
        eyes = np.array([eye[0], eye[1], 0.0, eye[0], eye[1], 0.0])
        fixed.append(TrainingPose(f"random_{k:02d}", FaceControls(expr=np.clip(expr, -2.5, 2.5), jaw_pose=jaw,
                                                                  eyes_pose=eyes)))
    return fixed


def _vertex_albedo(colors: np.ndarray, faces: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    colors = np.asarray(colors, np.float64)
    faces = np.asarray(faces)

    def albedo_at(face_idx: np.ndarray, bary: np.ndarray) -> np.ndarray:
        return np.einsum("nk,nkc->nc", bary, colors[faces[face_idx]])

    return albedo_at


@dataclass(frozen=True)
class TargetSource:
    """What the avatar is fitted to: a name (stored in the asset's key), the albedo at surface points
    ``albedo_at(face_idx (N,), bary (N, 3)) -> (N, 3)`` used to initialise the Gaussians' colours, and
    the target renderer."""

    name: str
    albedo_at: Callable[[np.ndarray, np.ndarray], np.ndarray]
    render: TargetRenderer

    @classmethod
    def for_model(cls, model: Any) -> "TargetSource":
        """The head's own mesh renders: textured when it has an appearance (``flame.head_textures``),
        else region colours (:meth:`region_colors`)."""
        from ..avatar.default_gaussians import _head_appearance, appearance_digest
        from ..flame.preview import render_mesh_cameras

        app = _head_appearance(model)
        if app is None:
            return cls.region_colors(model)
        colors = np.asarray(app.vertex_colors, np.float64)

        def render(vertices: np.ndarray, faces: np.ndarray, cameras: Cameras, indices: Sequence[int]
                   ) -> tuple[np.ndarray, np.ndarray]:
            return render_mesh_cameras(vertices, faces, cameras, indices, colors=colors, appearance=app)

        return cls(appearance_digest(model), app.albedo_at, render)

    @classmethod
    def region_colors(cls, model: Any) -> "TargetSource":
        """The head's region colours through :func:`holo_viewer.flame.preview.render_mesh_cameras` (VTK)."""
        from ..avatar.default_gaussians import appearance_colors, appearance_digest
        from ..flame.preview import render_mesh_cameras

        colors = appearance_colors(model)

        def render(vertices: np.ndarray, faces: np.ndarray, cameras: Cameras, indices: Sequence[int]
                   ) -> tuple[np.ndarray, np.ndarray]:
            return render_mesh_cameras(vertices, faces, cameras, indices, colors=colors)

        return cls(appearance_digest(model), _vertex_albedo(colors, model.faces.cpu().numpy()), render)


def surface_points(local: Gaussians, binding: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) barycentric coordinates in its parent triangle of each Gaussian's centre projected onto
    the triangle's plane (clamped into the triangle)."""
    g = local.numpy(np.float64)
    means, _, _ = bind_to_world_np(g.means, g.quats, g.log_scales, binding, vertices, faces)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)[binding]]  # (N, 3, 3)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    v0, v1, v2 = b - a, c - a, means - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 1e-30, d00 * d11 - d01 * d01, 1.0)
    w1 = (d11 * d20 - d01 * d21) / den
    w2 = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.column_stack([1 - w1 - w2, w1, w2]), 0.0, None)
    return bary / np.maximum(bary.sum(1, keepdims=True), 1e-12)


def surface_colors(local: Gaussians, binding: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                   vertex_colors: np.ndarray) -> np.ndarray:
    """(N, 3) colour of each Gaussian's surface point (:func:`surface_points`): vertex colours
    interpolated barycentrically."""
    bary = surface_points(local, binding, vertices, faces)
    return _vertex_albedo(vertex_colors, faces)(np.asarray(binding), bary)


# =============================================================================== cameras


def orbit_cameras(cameras: Cameras, index: int, angles: Sequence[tuple[float, float]], centre: np.ndarray) -> Cameras:
    """Copies of camera ``index`` orbited about ``centre`` by (yaw, pitch) degrees (yaw about +y, then
    pitch about the camera's x axis), intrinsics kept."""
    from ..geometry import rodrigues_np

    w2c0 = np.asarray(cameras.world_to_cam[index], np.float64)
    c = np.asarray(centre, np.float64)
    out = []
    for yaw, pitch in angles:
        R = (rodrigues_np(np.array([0.0, math.radians(yaw), 0.0]))
             @ rodrigues_np(np.array([math.radians(pitch), 0.0, 0.0])))
        T = np.eye(4)  # world motion that maps the orbited camera's view back onto the original
        T[:3, :3] = R.T
        T[:3, 3] = c - R.T @ c
        out.append(w2c0 @ T)
    K = np.repeat(np.asarray(cameras.K[index])[None], len(out), 0)
    return Cameras(np.stack(out), K, cameras.width, cameras.height, near=cameras.near, far=cameras.far)


def sheared_cameras(cameras: Cameras, index: int, angles: Sequence[tuple[float, float]], centre: np.ndarray
                    ) -> Cameras:
    """Copies of camera ``index`` moved on the sphere about ``centre`` by (yaw, pitch) degrees (as
    :func:`orbit_cameras`) but keeping its orientation: the principal point is shifted so ``centre``
    stays at the pixel it had (an off-axis frustum, like the quilt's own cameras). Lights set from the
    camera orientation (``flame.preview.render_mesh_cameras``) are then the same as in the quilt views."""
    from ..geometry import rodrigues_np

    w2c0 = np.asarray(cameras.world_to_cam[index], np.float64)
    K0 = np.asarray(cameras.K[index], np.float64)
    R0, t0 = w2c0[:3, :3], w2c0[:3, 3]
    C0 = -R0.T @ t0
    c = np.asarray(centre, np.float64)
    p0 = K0 @ (R0 @ c + t0)
    px0 = p0[:2] / p0[2]
    w2cs, Ks = [], []
    for yaw, pitch in angles:
        R = (rodrigues_np(np.array([0.0, math.radians(yaw), 0.0]))
             @ rodrigues_np(np.array([math.radians(pitch), 0.0, 0.0])))
        C = c + R @ (C0 - c)
        t = -R0 @ C
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R0, t
        pc = R0 @ c + t
        K = K0.copy()
        K[0, 2] = px0[0] - K0[0, 0] * pc[0] / pc[2]
        K[1, 2] = px0[1] - K0[1, 1] * pc[1] / pc[2]
        w2cs.append(w2c)
        Ks.append(K)
    return Cameras(np.stack(w2cs), np.stack(Ks), cameras.width, cameras.height, near=cameras.near, far=cameras.far)


def camera_yaws(cameras: Cameras, centre: np.ndarray) -> np.ndarray:
    """(N,) horizontal angle (degrees, + toward world +x) of each camera centre seen from ``centre``
    (bench/face_realism.py's ``camera_angles``)."""
    R, t = np.asarray(cameras.world_to_cam)[:, :3, :3], np.asarray(cameras.world_to_cam)[:, :3, 3]
    rel = -np.einsum("vji,vj->vi", R, t) - np.asarray(centre, np.float64)[None]
    return np.degrees(np.arctan2(rel[:, 0], rel[:, 2]))


def training_cameras(pipe: Any, config: AvatarFitConfig) -> tuple[Cameras, np.ndarray]:
    """The training cameras (quilt subset + orbit, full resolution) and their horizontal angles (deg)."""
    cams = pipe.cameras()
    (framing,), _ = pipe.compute("framing")
    centre = np.asarray(framing[0])
    quilt_idx = [int(i) for i in config.quilt_views]
    if config.orbit_mode not in ("rotated", "sheared"):
        raise InputError(f"orbit_mode: expected 'rotated' or 'sheared', found {config.orbit_mode!r}")
    make = orbit_cameras if config.orbit_mode == "rotated" else sheared_cameras
    orbit = make(cams, len(cams) // 2, config.orbit, centre) if config.orbit else None
    full = Cameras(np.concatenate([cams.world_to_cam[quilt_idx]] + ([orbit.world_to_cam] if orbit else [])),
                   np.concatenate([cams.K[quilt_idx]] + ([orbit.K] if orbit else [])), cams.width, cams.height,
                   near=cams.near, far=cams.far)
    return full, camera_yaws(full, centre)


def camera_yaws_range(pipe: Any, config: AvatarFitConfig) -> tuple[float, float]:
    """[min, max] horizontal angle (deg) of :func:`training_cameras` (``fit_angle_range_deg``), no renders."""
    _, yaws = training_cameras(pipe, config)
    return float(np.min(yaws)), float(np.max(yaws))


def scaled_cameras(cameras: Cameras, scale: float) -> Cameras:
    """The same cameras at ``scale`` x the resolution (an integer downsampling factor 1/scale): focal
    lengths and principal points scaled (pixel edges line up with 1/scale x 1/scale blocks)."""
    f = round(1.0 / scale) if scale > 0 else 0
    if f < 1 or abs(f * scale - 1.0) > 1e-9 or cameras.width % f or cameras.height % f:
        raise InputError(f"train_scale: expected 1/k for an integer k dividing the tile {cameras.width}x"
                         f"{cameras.height}, found {scale}")
    w, h = cameras.width // f, cameras.height // f
    K = np.asarray(cameras.K, np.float64).copy()
    K[:, :2, :] *= scale
    return Cameras(np.asarray(cameras.world_to_cam), K, int(round(w)), int(round(h)), near=cameras.near,
                   far=cameras.far)


def _downsample(images: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return images
    n, H, W = images.shape[:3]
    return images.reshape(n, H // factor, factor, W // factor, factor, *images.shape[3:]).mean(axis=(2, 4))


# =============================================================================== dataset


@dataclass
class Dataset:
    """Training images (uint8, full resolution) with their pose's face frames and cameras."""

    images: np.ndarray  # (P, C, H, W, 3) uint8
    masks: np.ndarray  # (P, C, H, W) bool: the mesh covers the pixel
    frames: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]  # per pose: rot (1,F,3,3), scale, centre
    cameras: Cameras  # C cameras at full resolution
    names: list[str]
    vertices: list[np.ndarray]
    skipped: list[str] = dataclasses.field(default_factory=list)  # poses whose target render hung
    #: [min, max] horizontal angle (deg) of the cameras about the framing centre (``fit_angle_range_deg``)
    angle_range_deg: tuple[float, float] = (float("nan"), float("nan"))


def _render_isolated(target_renderer: TargetRenderer, verts: np.ndarray, faces: np.ndarray, cameras: Cameras,
                     timeout_s: float | None, indices: Sequence[int] | None = None
                     ) -> tuple[np.ndarray, np.ndarray] | None:
    """(uint8 images, bool masks) of every camera, rendered in a forked child process that is killed
    after ``timeout_s`` (None: in this process). Returns None on timeout or failure of the child.

    Why: the offscreen Mesa rasterizer (llvmpipe) was seen to spin forever on one textured pose of the
    ICT head (a jaw + expression combination, front view); one pose must not hang the fit."""
    idx = list(range(len(cameras))) if indices is None else [int(i) for i in indices]

    def run() -> tuple[np.ndarray, np.ndarray]:
        im, mk = target_renderer(verts, faces, cameras, idx)
        return np.clip(np.asarray(im, np.float64) * 255 + 0.5, 0, 255).astype(np.uint8), np.asarray(mk, bool)

    if timeout_s is None:
        return run()
    import multiprocessing as mp
    import queue as _queue

    ctx = mp.get_context("fork")
    q = ctx.Queue()

    def child() -> None:
        try:
            q.put(run())
        except Exception as exc:  # noqa: BLE001 - reported to the parent as a failed pose
            q.put(exc)

    proc = ctx.Process(target=child, daemon=True)
    proc.start()
    try:
        out = q.get(timeout=timeout_s)
    except _queue.Empty:
        out = None
    if proc.is_alive():
        proc.kill()
    proc.join()
    return out if isinstance(out, tuple) else None


def build_dataset(pipe: Any, poses: Sequence[TrainingPose], target_renderer: TargetRenderer,
                  config: AvatarFitConfig, progress: bool = True) -> Dataset:
    """Render every pose through the training cameras (quilt subset + orbit), full resolution.

    ``pipe`` is a mesh pipeline (``Pipeline(model, avatar=False)``) of the head the avatar is bound to.
    """
    from tqdm import tqdm

    full, yaws = training_cameras(pipe, config)
    scaled_cameras(full, config.train_scale)  # checks the factor
    faces = pipe.model.faces.cpu().numpy()
    imgs, masks, frames, verts_all, names, skipped = [], [], [], [], [], []
    dtype = getattr(torch, config.dtype)
    for pose in tqdm(poses, desc="mesh renders", disable=not progress):
        pipe.set_face(pose.face)
        verts = np.asarray(pipe.mesh(), np.float64)
        got = _render_isolated(target_renderer, verts, faces, full, config.render_timeout_s)
        if got is None:
            skipped.append(pose.name)
            if progress:
                print(f"  {pose.name}: the target render did not finish in {config.render_timeout_s:g} s; pose skipped",
                      flush=True)
            continue
        imgs.append(got[0])
        masks.append(got[1])
        names.append(pose.name)
        rot, scale, centre, _ = face_frames(torch.as_tensor(verts, dtype=torch.float64)[None],
                                            pipe.model.faces.cpu())
        frames.append((rot.to(dtype), scale.to(dtype), centre.to(dtype)))
        verts_all.append(verts)
    if not imgs:
        raise InputError(f"build_dataset: no pose could be rendered (skipped {skipped})")
    return Dataset(np.stack(imgs), np.stack(masks), frames, full, names, verts_all, skipped,
                   (float(np.min(yaws)), float(np.max(yaws))))


# =============================================================================== loss


def _ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of two (H, W, 3) images (11x11 Gaussian window, sigma 1.5, as 3DGS)."""
    x = a.permute(2, 0, 1)[None]
    y = b.permute(2, 0, 1)[None]
    k1d = torch.exp(-((torch.arange(11, dtype=a.dtype) - 5.0) ** 2) / (2 * 1.5 ** 2))
    k1d = k1d / k1d.sum()
    win = (k1d[:, None] * k1d[None, :]).expand(3, 1, 11, 11).contiguous()

    def f(z: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.conv2d(z, win, padding=5, groups=3)

    mx, my = f(x), f(y)
    sxx, syy, sxy = f(x * x) - mx * mx, f(y * y) - my * my, f(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return s.mean()


# =============================================================================== fit


def detail_map(image: np.ndarray, sigma: float = 1.5, floor: float = 0.1) -> np.ndarray:
    """(H, W) float64 sampling weight of a (H, W, 3) uint8 target: the mean over channels of |image -
    Gaussian blur (``sigma`` px)|, plus ``floor`` times its mean so smooth skin is still drawn."""
    from scipy import ndimage

    x = np.asarray(image, np.float64) / 255.0
    hp = np.abs(x - ndimage.gaussian_filter(x, (sigma, sigma, 0))).mean(axis=2)
    return hp + floor * max(float(hp.mean()), 1e-6)


def rim_map(mask: np.ndarray, width_px: float = 4.0) -> np.ndarray:
    """(H, W) bool: the pixels of a (H, W) bool mesh mask within ``width_px`` (Euclidean, pixel centres) of
    its outline on either side: mask pixels whose distance to the nearest background pixel is <= ``width_px``
    and background pixels as near to the mask (an empty or full mask has no rim; the image border is not an
    outline)."""
    from scipy import ndimage

    m = np.asarray(mask, bool)
    if not m.any() or m.all():
        return np.zeros(m.shape, bool)
    inside = ndimage.distance_transform_edt(m) <= float(width_px)
    outside = ndimage.distance_transform_edt(~m) <= float(width_px)
    return (m & inside) | (~m & outside)


def _render_rgba(means: torch.Tensor, quats: torch.Tensor, log_scales: torch.Tensor, opacity_logits: torch.Tensor,
                 sh: torch.Tensor, world_to_cam: np.ndarray, K: np.ndarray, width: int, height: int, near: float,
                 config: RenderConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """(H, W, 3) image and (H, W) alpha of one view: ``render.differentiable.render_view``'s projection
    composited twice, with the SH colours and with white (alpha = the white composite on a black
    background: 1 - the transmittance left), both differentiable."""
    from ..render.differentiable import covariance, project, rasterize, sh_rgb

    degree = int(round(math.sqrt(sh.shape[1]))) - 1
    if config.sh_degree is not None:
        degree = min(degree, int(config.sh_degree))
    w2c = np.asarray(world_to_cam, np.float64)
    cam_pos = torch.tensor(-w2c[:3, :3].T @ w2c[:3, 3], dtype=means.dtype)
    uv, conic, depth, radius, valid = project(means, covariance(quats, log_scales), w2c, K, width, height, near,
                                              config.dilation, config.radius_sigmas)
    op = torch.sigmoid(opacity_logits)
    img = rasterize(uv, conic, op, sh_rgb(means, sh, degree, cam_pos), depth, radius, valid, width, height, config)
    black = dataclasses.replace(config, background=(0.0, 0.0, 0.0))
    white = torch.ones((means.shape[0], 3), dtype=means.dtype)
    alpha = rasterize(uv, conic, op, white, depth, radius, valid, width, height, black)[..., 0]
    return img, alpha


def fit_gaussians(local: Gaussians, binding: np.ndarray, data: Dataset,
                  config: AvatarFitConfig = AvatarFitConfig(), progress: bool = True,
                  render_config: RenderConfig | None = None) -> AvatarFit:
    """Optimise the local Gaussians against ``data`` (see the module docstring).

    Parameters
    ----------
    local : Gaussians
        Initial local Gaussians (numpy), colours already set (e.g. :func:`surface_colors`).
    binding : numpy.ndarray
        (N,) parent faces (fixed).
    data : Dataset
        From :func:`build_dataset`.
    """
    from tqdm import tqdm

    t0 = time.perf_counter()
    dtype = getattr(torch, config.dtype)
    rng = np.random.default_rng(config.seed)
    g = local.numpy(np.float64)
    q0 = g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True)
    params = {
        "means": torch.tensor(g.means, dtype=dtype, requires_grad=True),
        "quats": torch.tensor(q0, dtype=dtype, requires_grad=True),
        "log_scales": torch.tensor(g.log_scales, dtype=dtype, requires_grad=True),
        "opacity": torch.tensor(g.opacity_logits, dtype=dtype, requires_grad=True),
        "sh_dc": torch.tensor(g.sh[:, :1], dtype=dtype, requires_grad=True),
        "sh_rest": torch.tensor(g.sh[:, 1:], dtype=dtype, requires_grad=True),
    }
    lrs = {"means": config.lr_means, "quats": config.lr_quats, "log_scales": config.lr_log_scales,
           "opacity": config.lr_opacity, "sh_dc": config.lr_sh_dc, "sh_rest": config.lr_sh_rest}
    opt = torch.optim.Adam([{"params": [p], "lr": lrs[k], "name": k} for k, p in params.items()], eps=1e-15)
    b = torch.as_tensor(np.asarray(binding, np.int64))
    full = data.cameras
    factor = int(round(1.0 / config.train_scale))
    small = scaled_cameras(full, config.train_scale)
    crop_w, crop_h = small.width, small.height
    crop_from = int(round(config.iterations * (1.0 - config.crop_fraction)))
    rc = render_config or RenderConfig()
    n_pose, n_cam = data.images.shape[:2]
    losses: list[float] = []
    detail_cdf: dict[tuple[int, int], np.ndarray] = {}
    rims: dict[tuple[int, int], np.ndarray] = {}
    silhouette = config.rim_weight > 0 or config.crop_rim > 0 or config.w_alpha > 0

    def rim_of(p: int, c: int) -> np.ndarray:
        if (p, c) not in rims:
            rims[(p, c)] = rim_map(data.masks[p, c], config.rim_px)
        return rims[(p, c)]
    src = np.arange(len(local))  # each current Gaussian's index in ``local`` (for ``extra``)
    densify_until = config.densify_until or int(config.iterations * 0.75)
    dens = config.densify_every > 0 and (config.densify_split > 0 or config.prune_opacity > 0
                                         or config.max_gaussians > 0)
    acc = np.zeros(len(local))
    cnt = np.zeros(len(local))
    dlog: list[tuple[int, int, int, int]] = []
    decay = (config.lr_means_final / config.lr_means) ** (1.0 / max(config.iterations - 1, 1))
    bar = tqdm(range(config.iterations), desc="fit", disable=not progress, mininterval=5.0)
    if config.pose_weights and len(config.pose_weights) != n_pose:
        raise ValueError(f"AvatarFitConfig.pose_weights: expected {n_pose} weights (one per pose of the dataset: "
                         f"{', '.join(data.names)}), found {len(config.pose_weights)}")
    if config.photometric not in ("l1", "l2"):
        raise ValueError(f"AvatarFitConfig.photometric: expected 'l1' or 'l2', found {config.photometric!r}")
    pose_p = np.asarray(config.pose_weights, np.float64) if config.pose_weights else None
    if pose_p is not None:
        if not np.all(np.isfinite(pose_p)) or np.any(pose_p < 0) or pose_p.sum() <= 0:
            raise ValueError(f"AvatarFitConfig.pose_weights: expected non-negative weights with a positive sum, "
                             f"found {config.pose_weights}")
        pose_p = pose_p / pose_p.sum()
    if config.camera_weights and len(config.camera_weights) != n_cam:
        raise ValueError(f"AvatarFitConfig.camera_weights: expected {n_cam} weights (one per camera of the dataset), "
                         f"found {len(config.camera_weights)}")
    cam_p = np.asarray(config.camera_weights, np.float64) if config.camera_weights else None
    if cam_p is not None:
        if not np.all(np.isfinite(cam_p)) or np.any(cam_p < 0) or np.count_nonzero(cam_p) < config.views_per_step:
            raise ValueError(f"AvatarFitConfig.camera_weights: expected non-negative weights, at least "
                             f"views_per_step ({config.views_per_step}) of them positive, found {config.camera_weights}")
        cam_p = cam_p / cam_p.sum()
    for it in bar:
        p = int(rng.integers(n_pose)) if pose_p is None else int(rng.choice(n_pose, p=pose_p))
        rot, scale, centre = data.frames[p]
        q = params["quats"] / torch.linalg.norm(params["quats"], dim=-1, keepdim=True)
        means, quats, log_scales = bind_to_world(params["means"], q, params["log_scales"], b, rot, scale, centre)
        if dens:
            means.retain_grad()
        sh = torch.cat([params["sh_dc"], params["sh_rest"]], dim=1)
        loss = torch.zeros((), dtype=dtype)
        for c in rng.choice(n_cam, size=min(config.views_per_step, n_cam), replace=False, p=cam_p):
            if it < crop_from:  # the whole image at train_scale (box-downsampled target)
                w2c, K, W, H = small.world_to_cam[c], small.K[c], small.width, small.height
                target = torch.from_numpy(_downsample(data.images[p, c][None].astype(np.float32), factor)[0])
                if silhouette:
                    rim_t = _downsample(rim_of(p, int(c))[None].astype(np.float32), factor)[0]
                    mask_t = _downsample(data.masks[p, c][None].astype(np.float32), factor)[0]
            else:  # a full-resolution crop of the same pixel count, centred on a random mesh pixel
                ys, xs = np.nonzero(data.masks[p, c])
                if config.crop_rim > 0 and len(ys) and rng.random() < config.crop_rim:  # on the outline
                    ry, rx = np.nonzero(rim_of(p, int(c)) & data.masks[p, c])
                    ys, xs = (ry, rx) if len(ry) else (ys, xs)
                    k = int(rng.integers(len(ys)))
                elif config.crop_detail > 0 and len(ys) and rng.random() < config.crop_detail:
                    key = (p, int(c))
                    if key not in detail_cdf:
                        w = detail_map(data.images[p, c])[ys, xs]
                        detail_cdf[key] = np.cumsum(w) / w.sum()
                    k = int(min(np.searchsorted(detail_cdf[key], rng.random()), len(ys) - 1))
                else:
                    k = int(rng.integers(len(ys))) if len(ys) else 0
                cy0 = int(ys[k]) if len(ys) else full.height // 2
                cx0 = int(xs[k]) if len(xs) else full.width // 2
                y0 = int(np.clip(cy0 - crop_h // 2, 0, full.height - crop_h))
                x0 = int(np.clip(cx0 - crop_w // 2, 0, full.width - crop_w))
                K = np.asarray(full.K[c], np.float64).copy()
                K[0, 2] -= x0
                K[1, 2] -= y0
                w2c, W, H = full.world_to_cam[c], crop_w, crop_h
                target = torch.from_numpy(data.images[p, c, y0:y0 + H, x0:x0 + W].astype(np.float32))
                if silhouette:
                    rim_t = rim_of(p, int(c))[y0:y0 + H, x0:x0 + W].astype(np.float32)
                    mask_t = data.masks[p, c, y0:y0 + H, x0:x0 + W].astype(np.float32)
            if config.w_alpha > 0:
                img, alpha = _render_rgba(means[0], quats[0], log_scales[0], params["opacity"], sh, w2c, K, W, H,
                                          full.near, rc)
            else:
                img = render_view(means[0], quats[0], log_scales[0], params["opacity"], sh, w2c, K, W, H, full.near,
                                  rc)
            target = target.to(dtype) / 255.0
            err = (img - target).abs() if config.photometric == "l1" else (img - target) ** 2
            if silhouette:
                wpix = 1.0 + config.rim_weight * torch.from_numpy(rim_t).to(dtype)
                l1 = (err.mean(dim=2) * wpix).mean()
            else:
                l1 = err.mean()
            if config.ssim_weight > 0:
                l1 = (1 - config.ssim_weight) * l1 + config.ssim_weight * (1 - _ssim(img, target))
            if config.w_alpha > 0:
                l1 = l1 + config.w_alpha * ((alpha - torch.from_numpy(mask_t).to(dtype)).abs() * wpix).mean()
            loss = loss + l1 / config.views_per_step
        reg = (config.w_pos * torch.relu(torch.linalg.norm(params["means"], dim=-1) - config.eps_pos).mean()
               + config.w_scale * torch.relu(torch.exp(params["log_scales"]) - config.eps_scale).mean())
        if config.w_opacity > 0:
            o = torch.sigmoid(params["opacity"])
            reg = reg + config.w_opacity * (o * (1 - o)).mean()
        total = loss + reg
        opt.zero_grad(set_to_none=True)
        total.backward()
        if dens and means.grad is not None:
            gn = torch.linalg.norm(means.grad[0], dim=-1).numpy()
            acc += gn
            cnt += gn > 0
        opt.step()
        if (dens and config.densify_from <= it < densify_until and it > 0
                and (it - config.densify_from) % config.densify_every == config.densify_every - 1):
            params, opt, keep_src, n_split, n_pruned = _densify(params, opt, acc, cnt, config, rng)
            src = src[keep_src]
            b = b[torch.as_tensor(keep_src)]
            acc = np.zeros(len(src))
            cnt = np.zeros(len(src))
            dlog.append((it, n_split, n_pruned, len(src)))
        for grp in opt.param_groups:
            if grp["name"] == "means":
                grp["lr"] *= decay
        losses.append(float(loss.detach()))
        if progress and it % 50 == 0:
            bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
    with torch.no_grad():
        sh = torch.cat([params["sh_dc"], params["sh_rest"]], dim=1)
        q = params["quats"] / torch.linalg.norm(params["quats"], dim=-1, keepdim=True)
        extra = {k: (np.asarray(v)[src] if np.ndim(v) and len(v) == len(local) else v)
                 for k, v in local.extra.items()}
        out = Gaussians(params["means"].numpy().astype(np.float32), q.numpy().astype(np.float32),
                        params["log_scales"].numpy().astype(np.float32),
                        params["opacity"].numpy().astype(np.float32), sh.numpy().astype(np.float32),
                        extra=extra)
    return AvatarFit(out, losses, {"fit": time.perf_counter() - t0}, int(n_pose * n_cam),
                     b.numpy().copy(), dlog)


def _densify(params: dict[str, torch.Tensor], opt: torch.optim.Optimizer, acc: np.ndarray, cnt: np.ndarray,
             config: AvatarFitConfig, rng: np.random.Generator
             ) -> tuple[dict[str, torch.Tensor], torch.optim.Optimizer, np.ndarray, int, int]:
    """One round of adaptive density control (:class:`AvatarFitConfig` ``densify_*``): split the
    ``densify_split`` Gaussians of the highest mean positional gradient ``acc / cnt`` in two (local centres
    drawn from the Gaussian, in its triangle's frame; scales / ``split_factor``; the rest copied), drop
    those below ``prune_opacity`` and the faintest beyond ``max_gaussians``. Returns the new parameters
    and optimiser (Adam moments carried over, zero for the children) and, per new Gaussian, the index
    of the Gaussian it came from, the number split and the number dropped."""
    from ..geometry import quat_to_rotmat_np

    n = len(acc)
    avg = np.where(cnt > 0, acc / np.maximum(cnt, 1), 0.0)
    k = int(min(config.densify_split, int((avg > 0).sum())))
    split = np.zeros(n, bool)
    if k > 0:
        split[np.argpartition(-avg, k - 1)[:k]] = True
    with torch.no_grad():
        op = torch.sigmoid(params["opacity"]).numpy().reshape(n, -1)[:, 0]
        keep = ~split
        if config.prune_opacity > 0:
            keep &= op >= config.prune_opacity
        si = np.nonzero(split)[0]
        n_new = 2 * len(si)
        if config.max_gaussians > 0 and keep.sum() + n_new > config.max_gaussians:  # the faintest kept go
            ki = np.nonzero(keep)[0]
            drop = int(keep.sum() + n_new - config.max_gaussians)
            keep[ki[np.argsort(op[ki], kind="stable")[:min(drop, len(ki))]]] = False
        ki = np.nonzero(keep)[0]
        mu = params["means"].numpy().astype(np.float64)
        q = params["quats"].numpy().astype(np.float64)
        ls = params["log_scales"].numpy().astype(np.float64)
        R = quat_to_rotmat_np(q[si] / np.linalg.norm(q[si], axis=1, keepdims=True))  # (k, 3, 3)
        children = []
        child_ls = np.concatenate([ls[si], ls[si]]) - math.log(config.split_factor)
        child_op = None
        if config.split_mode == "axis":
            j = np.argmax(ls[si], axis=1)
            axis = R[np.arange(len(si)), :, j] * np.exp(ls[si, j])[:, None]  # (k, 3): sigma along the axis
            children = [mu[si] + 0.6 * axis, mu[si] - 0.6 * axis]
            child_ls = np.concatenate([ls[si], ls[si]])
            child_ls[np.arange(2 * len(si)), np.concatenate([j, j])] += math.log(0.8)
            o = np.clip(np.concatenate([op[si], op[si]]), 1e-6, 1 - 1e-6)
            oc = np.clip(1 - np.sqrt(1 - o), 1e-6, 1 - 1e-6)
            child_op = np.log(oc / (1 - oc))
        elif config.split_mode == "sample":
            for _ in range(2):
                z = rng.standard_normal((len(si), 3)) * np.exp(ls[si])
                children.append(mu[si] + np.einsum("nij,nj->ni", R, z))
        else:
            raise InputError(f"split_mode: expected 'sample' or 'axis', found {config.split_mode!r}")
        new: dict[str, torch.Tensor] = {}
        idx = np.concatenate([ki, si, si])
        for name, p in params.items():
            t = p.detach()[torch.as_tensor(idx)].clone()
            if name == "means" and len(si):
                t[len(ki):] = torch.as_tensor(np.concatenate(children), dtype=t.dtype)
            if name == "log_scales" and len(si):
                t[len(ki):] = torch.as_tensor(child_ls, dtype=t.dtype)
            if name == "opacity" and len(si) and child_op is not None:
                t[len(ki):] = torch.as_tensor(child_op, dtype=t.dtype).reshape(t[len(ki):].shape)
            new[name] = t.requires_grad_(True)
        groups = [{"params": [new[g["name"]]], "lr": g["lr"], "name": g["name"]} for g in opt.param_groups]
        opt2 = torch.optim.Adam(groups, eps=1e-15)
        for g_old, g_new in zip(opt.param_groups, opt2.param_groups):
            st = opt.state.get(g_old["params"][0], {})
            if not st:
                continue
            moved = {}
            for key, v in st.items():
                if torch.is_tensor(v) and v.dim() > 0 and v.shape[0] == n:
                    v2 = v[torch.as_tensor(idx)].clone()
                    v2[len(ki):] = 0
                    moved[key] = v2
                else:
                    moved[key] = v.clone() if torch.is_tensor(v) else v
            opt2.state[g_new["params"][0]] = moved
    return new, opt2, idx, len(si), int(n - len(ki) - len(si))


def initial_with_surface_colors(local: Gaussians, binding: np.ndarray, model: Any,
                                albedo_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
                                sh_degree: int = 1) -> Gaussians:
    """``local`` with SH DC set to ``albedo_at`` the Gaussian's surface point (:func:`surface_points` on
    the rest mesh), higher SH zero."""
    v = model.v_template.detach().cpu().double().numpy()
    bary = surface_points(local, binding, v, model.faces.cpu().numpy())
    col = np.clip(np.asarray(albedo_at(np.asarray(binding), bary), np.float64), 0.0, 1.0)
    k = (sh_degree + 1) ** 2
    sh = np.zeros((len(local), k, 3), np.float32)
    sh[:, 0] = (col - 0.5) / SH_C0
    return local.replace(sh=sh)


# =============================================================================== measurement


def fidelity(avatar: Any, faces: dict[str, FaceControls], views: Sequence[int], target_renderer: TargetRenderer,
             images: dict[str, np.ndarray] | None = None, timeout_s: float | None = 300.0,
             view: Any = None) -> dict[str, dict[int, float]]:
    """PSNR of the avatar's quilt views (``Pipeline.views()``, full resolution) against the target render
    of the same posed mesh and camera, over the mesh mask (the target's 8-bit VTK buffer, as in
    bench/face_realism.py; NaN when it does not finish in ``timeout_s``, rendered in a child process);
    ``images`` (optional) receives, per
    expression, the (len(views), H, 2W, 3) side-by-side pairs (Gaussians | mesh); ``view`` (a
    ``pipeline.ViewSettings``, optional) e.g. moves the cone (``viewer_angle``)."""
    from ..pipeline.core import Pipeline

    pipe = Pipeline(avatar=avatar, view=view)
    cams = pipe.cameras()
    f = pipe.model.faces.cpu().numpy()
    out: dict[str, dict[int, float]] = {}
    for name, face in faces.items():
        pipe.set_face(face)
        views_g = pipe.views()
        got = _render_isolated(target_renderer, np.asarray(pipe.mesh(), np.float64), f, cams, timeout_s, views)
        if got is None:  # the target render hung or failed: no number
            out[name] = {int(i): float("nan") for i in views}
            continue
        mimg, mmask = got[0].astype(np.float32) / 255.0, got[1]
        out[name] = {int(i): psnr(views_g[i], mimg[k], mask=mmask[k]) for k, i in enumerate(views)}
        if images is not None:
            images[name] = np.stack([np.concatenate([views_g[i], mimg[k]], axis=1) for k, i in enumerate(views)])
    return out


def average_gaussians(fits: Sequence[Gaussians]) -> Gaussians:
    """The parameter average of fits of one set of Gaussians (the same count and binding, e.g. a file and a
    short fine-tune of it: a "model soup"), in float64: centres, log-scales, opacity logits and SH averaged
    alike; the quaternions normalised, sign-aligned to the first fit's, averaged and normalised again.
    Returned as float32 (``extra`` of the first)."""
    if not fits:
        raise ValueError("average_gaussians: expected at least one set of Gaussians, found none")
    gs = [f.numpy(np.float64) for f in fits]
    if any(len(g) != len(gs[0]) or g.sh.shape != gs[0].sh.shape for g in gs):
        raise ValueError(f"average_gaussians: expected fits of one set, found counts {[len(g) for g in gs]} and SH "
                         f"shapes {[g.sh.shape for g in gs]}")
    qs = [g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True) for g in gs]
    qs = [q * np.sign((q * qs[0]).sum(axis=1, keepdims=True) + 1e-30) for q in qs]
    q = sum(qs) / len(qs)
    q /= np.linalg.norm(q, axis=1, keepdims=True)

    def mean(field: str) -> np.ndarray:
        return (sum(getattr(g, field) for g in gs) / len(gs)).astype(np.float32)
    return fits[0].replace(means=mean("means"), quats=q.astype(np.float32), log_scales=mean("log_scales"),
                           opacity_logits=mean("opacity_logits"), sh=mean("sh"))


def replace_config(config: AvatarFitConfig, **changes: Any) -> AvatarFitConfig:
    """A copy of ``config`` with some fields replaced."""
    return dataclasses.replace(config, **changes)


# =============================================================================== transfer to another identity


def folder_appearance(model: Any, folder: Any) -> Any:
    """``model``'s head painted with the textures in ``folder`` (its ``albedo.json`` and PNGs, e.g. a
    patient's earlier textures kept beside the avatar fitted to them); ``.albedo_at`` and
    ``.face_material`` as the head's own appearance."""
    from pathlib import Path

    from ..errors import FlameError
    from ..fileio import read_json
    from ..flame import head_textures as ht

    folder = Path(folder)
    inputs = ht.appearance_inputs(model)
    args = {k: inputs[k] for k in ("vertices", "faces", "uv", "faces_uv", "vertex_region", "region_names", "landmarks")}
    man = read_json(folder / ht.PATIENT_MANIFEST, FlameError, "head texture manifest")
    seed = int(man.get("seed", 0)) if isinstance(man, dict) else 0
    tex, alpha, s = ht.load_textures(folder, ht.mesh_key(inputs, seed), ht.PATIENT_MANIFEST)
    return ht._appearance(**args, seed=s, textures=tex, alpha=alpha)


def transfer_avatar(local: Gaussians, binding: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                    src_albedo_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
                    dst_albedo_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
                    mode: str = "shade", eps: float = 0.03, max_gain: float = 4.0, clip: bool = True) -> Gaussians:
    """A fitted avatar's Gaussians for another head of the same topology (issue 35).

    The binding is kept: each Gaussian stays on its triangle with its local offset, rotation and
    scale (all in the triangle's frame, so they follow the new identity's geometry). Colours are
    re-initialised at each Gaussian's surface point (:func:`surface_points` on ``vertices``, the
    source rest mesh; barycentric, so the same point on the new head): ``mode="albedo"`` sets SH DC to
    the new albedo (higher SH zero); ``mode="shade"`` (default) keeps the fitted shading, scaling
    every SH coefficient per channel by ``(dst + eps) / (src + eps)`` (clamped to ``max_gain``), so
    the baked lighting of the source fit carries over to the new skin and hair; ``clip=False`` keeps
    fitted colours outside [0, 1] (a recolour on the same head: unchanged texels keep every value)."""
    if mode not in ("shade", "albedo"):
        raise InputError(f"transfer mode: expected 'shade' or 'albedo', found {mode!r}")
    b = np.asarray(binding)
    bary = surface_points(local, b, vertices, faces)
    a_dst = np.clip(np.asarray(dst_albedo_at(b, bary), np.float64), 0.0, 1.0)
    sh = np.asarray(local.sh, np.float64).copy()
    if mode == "albedo":
        sh[:] = 0.0
        sh[:, 0] = (a_dst - 0.5) / SH_C0
    else:
        a_src = np.clip(np.asarray(src_albedo_at(b, bary), np.float64), 0.0, 1.0)
        gain = np.clip((a_dst + eps) / (a_src + eps), 0.0, max_gain)
        c = sh[:, 0] * SH_C0 + 0.5
        c = np.clip(c, 0.0, 1.0) if clip else c
        sh[:, 1:] *= gain[:, None, :]
        sh[:, 0] = ((np.clip(c * gain, 0.0, 1.0) if clip else c * gain) - 0.5) / SH_C0
    return local.replace(sh=sh.astype(np.float32))


def add_gaussians_on_faces(local: Gaussians, binding: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                           face_ids: np.ndarray, n: int, albedo_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
                           seed: int = 0, size: float = 4e-4, opacity: float = 0.5,
                           region: int | None = None) -> tuple[Gaussians, np.ndarray]:
    """``local`` plus ``n`` new Gaussians on ``face_ids`` (area-weighted, uniform in each triangle, on
    its surface): flat discs ``size`` metres wide (a tenth as thick) lying in the triangle, of the
    albedo at their point and ``opacity``; e.g. for the lashes, which the generator leaves bare.
    ``region`` labels them in ``extra["region"]`` when ``local`` has one. Deterministic in ``seed``."""
    from ..avatar.binding import world_to_local_np
    from ..geometry import rotmat_to_quat_np

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    ids = np.asarray(face_ids, np.int64)
    if n < 1 or ids.size == 0:
        raise InputError(f"add_gaussians_on_faces: expected n >= 1 and some faces, found n={n}, {ids.size} faces")
    rng = np.random.default_rng(seed)
    tri = v[f[ids]]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise InputError("add_gaussians_on_faces: the faces have no area")
    nb = ids[rng.choice(len(ids), size=int(n), p=area / area.sum())]
    uv = rng.uniform(size=(int(n), 2))
    uv[uv.sum(1) > 1] = 1 - uv[uv.sum(1) > 1]
    bary = np.column_stack([1 - uv.sum(1), uv])
    t = v[f[nb]]
    p = np.einsum("nk,nkc->nc", bary, t)
    e0 = t[:, 1] - t[:, 0]
    nrm = np.cross(e0, t[:, 2] - t[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    a0 = e0 / np.maximum(np.linalg.norm(e0, axis=1, keepdims=True), 1e-30)
    rot = np.stack([a0, nrm, np.cross(a0, nrm)], axis=2)
    ls = np.log(np.tile([size, 0.1 * size, size], (int(n), 1)))
    mu, q, lsl = world_to_local_np(p, rotmat_to_quat_np(rot), ls, nb, v, f)
    col = np.clip(np.asarray(albedo_at(nb, bary), np.float64), 0.0, 1.0)
    sh = np.zeros((int(n),) + local.sh.shape[1:], np.float32)
    sh[:, 0] = (col - 0.5) / SH_C0
    o = np.full(int(n), math.log(opacity / (1 - opacity)), np.float32)
    extra = dict(local.extra)
    if "region" in extra:
        extra["region"] = np.concatenate([np.asarray(extra["region"]),
                                          np.full(int(n), -1 if region is None else region, np.int16)])
    g = local.numpy(np.float32)
    new = Gaussians(np.concatenate([g.means, mu.astype(np.float32)]), np.concatenate([g.quats, q.astype(np.float32)]),
                    np.concatenate([g.log_scales, lsl.astype(np.float32)]), np.concatenate([g.opacity_logits, o]),
                    np.concatenate([g.sh, sh]), extra=extra)
    return new, np.concatenate([np.asarray(binding, np.int64), nb])


def prune_faintest(local: Gaussians, binding: np.ndarray, n_keep: int, protect: np.ndarray | None = None
                   ) -> tuple[Gaussians, np.ndarray]:
    """The ``n_keep`` Gaussians left after dropping the least opaque ones (``protect``: (N,) bool never
    dropped), in their original order: keeps the count (and the file size) when others are added."""
    o = np.asarray(local.opacity_logits, np.float64).reshape(len(local), -1)[:, 0].copy()
    if protect is not None:
        o[np.asarray(protect, bool)] = np.inf
    drop = len(local) - int(n_keep)
    if drop <= 0:
        return local, np.asarray(binding)
    keep = np.sort(np.argsort(o, kind="stable")[drop:])
    return local.subset(keep), np.asarray(binding)[keep]


def slider_limit_deg(angle_range_deg: Sequence[float] | None, cone_deg: float, default: float = 10.0) -> float:
    """The viewer-angle slider's limit (deg) for an avatar fitted over ``angle_range_deg`` (its outermost
    quilt view stays inside the fitted range: ``min(-lo, hi) - cone / 2``, within [1, 30]); ``default``
    for an avatar without the field."""
    if angle_range_deg is None:
        return float(default)
    lo, hi = float(angle_range_deg[0]), float(angle_range_deg[1])
    return float(np.clip(min(-lo, hi) - cone_deg / 2, 1.0, 30.0))


def quilt_fidelity(avatar: Any, target_renderer: TargetRenderer, face: FaceControls,
                   angle_range_deg: Sequence[float] | None = None,
                   images: dict[str, np.ndarray] | None = None, timeout_s: float | None = 300.0) -> dict[str, Any]:
    """PSNR (:func:`fidelity`) of every quilt view with the cone centred and of the outermost views with
    the cone at the viewer slider's limits (:func:`slider_limit_deg`): per-view list, worst (and which
    view), median, the two limit views and their minimum over all (``min_db``). ``images`` receives
    ``"views"`` (48 Gaussians | mesh pairs), ``"slider_lo"`` and ``"slider_hi"``. A target render that
    does not finish in ``timeout_s`` (wall clock; a loaded machine) raises ``TimeoutError``: a minimum
    over the views that did finish would not be the worst view."""
    from ..pipeline.core import Pipeline
    from ..pipeline.settings import ViewSettings

    pipe = Pipeline(avatar=avatar)
    cone = float(pipe.view.view_cone or pipe.calibration.view_cone)
    lim = slider_limit_deg(angle_range_deg, cone)
    n = len(pipe.cameras())
    per: dict[str, dict[str, np.ndarray]] = {"views": {}, "slider_lo": {}, "slider_hi": {}}
    want = images is not None
    centre = fidelity(avatar, {"f": face}, list(range(n)), target_renderer, per["views"] if want else None,
                      timeout_s=timeout_s)["f"]
    lo = fidelity(avatar, {"f": face}, [0], target_renderer, per["slider_lo"] if want else None, timeout_s=timeout_s,
                  view=ViewSettings(viewer_angle=-lim))["f"][0]
    hi = fidelity(avatar, {"f": face}, [n - 1], target_renderer, per["slider_hi"] if want else None,
                  timeout_s=timeout_s, view=ViewSettings(viewer_angle=lim))["f"][n - 1]
    if not np.isfinite([*centre.values(), lo, hi]).all():
        raise TimeoutError(f"quilt_fidelity: the textured mesh's target render did not finish in {timeout_s} s "
                           f"(wall clock) for {sum(not np.isfinite(v) for v in [*centre.values(), lo, hi])} views; "
                           "expected every view measured (run it on a less loaded machine or with a longer timeout_s)")
    if want:
        for k, d in per.items():
            images[k] = d["f"]
    vals = np.array([centre[i] for i in range(n)], np.float64)
    worst = int(np.nanargmin(vals))
    return {"per_view_db": [float(x) for x in vals], "worst_db": float(vals[worst]), "worst_view": worst,
            "median_db": float(np.nanmedian(vals)), "slider_limit_deg": lim, "slider_min_db": float(lo),
            "slider_max_db": float(hi), "min_db": float(min(np.nanmin(vals), lo, hi))}
