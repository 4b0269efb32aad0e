"""GaussianAvatars binding and the rigged avatar, against direct float64 math."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holo_viewer.avatar import Gaussians, RiggedAvatar, load_gaussian_avatar
from holo_viewer.avatar.binding import (bind_to_world, bind_to_world_np, face_frames, face_frames_np,
                                        world_to_local_np)
from holo_viewer.avatar.gaussian_avatars import FlameParams, load_flame_params
from holo_viewer.errors import AvatarError, PlyError
from holo_viewer.flame.model import FlameModel
from holo_viewer.flame.synthetic import random_flame_arrays
from holo_viewer.geometry import quat_multiply_np, quat_to_rotmat_np, rotmat_to_quat_np


def _model(dtype=torch.float64, seed=0):
    return FlameModel.from_arrays(random_flame_arrays(n_vertices=300, n_shape=6, n_expr=5, seed=seed), dtype=dtype)


def _local(n: int, n_faces: int, seed: int = 1, degree: int = 1) -> Gaussians:
    rng = np.random.default_rng(seed)
    return Gaussians(rng.normal(scale=0.5, size=(n, 3)), rng.normal(size=(n, 4)),
                     rng.normal(-1, 0.3, size=(n, 3)), rng.normal(size=n),
                     rng.normal(size=(n, (degree + 1) ** 2, 3)),
                     extra={"binding_0": rng.integers(0, n_faces, n).astype(np.float32)})


def _direct(vertices, faces, binding, mu, q_local, log_s):
    """Per-Gaussian float64 formula written from docs/design.md, one Gaussian at a time."""
    means, rots, logs = [], [], []
    for b, m, q, ls in zip(binding, mu, q_local, log_s):
        v0, v1, v2 = vertices[faces[b]]
        a0 = (v1 - v0) / np.linalg.norm(v1 - v0)
        n = np.cross(a0, v2 - v0)
        a1 = n / np.linalg.norm(n)
        a2 = np.cross(a0, a1)
        R = np.stack([a0, a1, a2], axis=1)
        s = (np.linalg.norm(v1 - v0) + abs(a2 @ (v2 - v0))) / 2
        c = (v0 + v1 + v2) / 3
        means.append(s * R @ m + c)
        rots.append(R @ quat_to_rotmat_np(q))
        logs.append(ls + np.log(s))
    return np.array(means), np.array(rots), np.array(logs)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-6)])
def test_binding_matches_direct_float64(dtype, tol):
    rng = np.random.default_rng(3)
    verts = rng.normal(scale=0.1, size=(2, 60, 3))
    faces = np.array([rng.choice(60, 3, replace=False) for _ in range(90)])
    g = _local(200, 90)
    b = g.extra["binding_0"].astype(int)
    rot, scale, centre, deg = face_frames(torch.tensor(verts, dtype=dtype), torch.tensor(faces))
    assert not deg.any()
    q = torch.tensor(g.quats / np.linalg.norm(g.quats, axis=1, keepdims=True), dtype=dtype)
    m, qw, ls = bind_to_world(torch.tensor(g.means, dtype=dtype), q, torch.tensor(g.log_scales, dtype=dtype),
                              torch.tensor(b), rot, scale, centre)
    for i in range(2):
        dm, dr, dls = _direct(verts[i], faces, b, g.means, g.quats, g.log_scales)
        np.testing.assert_allclose(m[i].numpy(), dm, atol=tol * 10)
        np.testing.assert_allclose(quat_to_rotmat_np(qw[i].double().numpy()), dr, atol=tol * 10)
        np.testing.assert_allclose(ls[i].numpy(), dls, atol=tol * 10, rtol=tol)
        rm, rq, rls = bind_to_world_np(g.means, g.quats, g.log_scales, b, verts[i], faces)
        np.testing.assert_allclose(rm, dm, atol=1e-13)
        np.testing.assert_allclose(quat_to_rotmat_np(rq), dr, atol=1e-12)


def test_local_origin_sits_at_face_centre_with_face_frame():
    model = _model()
    nf = model.faces.shape[0]
    n = 40
    binding = np.arange(n) * 7 % nf
    g = Gaussians(np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros((n, 3)), np.zeros(n),
                  np.zeros((n, 1, 3)))
    av = RiggedAvatar(model, g, binding=binding)
    out = av.pose(expr=np.full(5, 0.7), jaw_pose=[0.2, 0, 0], rotation=[0.1, -0.3, 0.05])
    verts = model(expr=np.full(5, 0.7), jaw_pose=[0.2, 0, 0], rotation=[0.1, -0.3, 0.05]).vertices[0].numpy()
    faces = model.faces.numpy()
    rot, scale, centre, _ = face_frames_np(verts, faces)
    np.testing.assert_allclose(out.means.numpy(), centre[binding], atol=1e-12)
    np.testing.assert_allclose(quat_to_rotmat_np(out.quats.numpy()), rot[binding], atol=1e-12)
    np.testing.assert_allclose(np.exp(out.log_scales.numpy()), np.repeat(scale[binding, None], 3, 1), rtol=1e-12)
    # the frame: a0 along the first edge, a1 the normal
    v0, v1, v2 = (verts[faces[binding, k]] for k in range(3))
    e0 = (v1 - v0) / np.linalg.norm(v1 - v0, axis=1, keepdims=True)
    nrm = np.cross(v1 - v0, v2 - v0)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    np.testing.assert_allclose(rot[binding][:, :, 0], e0, atol=1e-12)
    np.testing.assert_allclose(rot[binding][:, :, 1], nrm, atol=1e-12)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-9), (torch.float32, 1e-6)])
def test_rigid_head_motion_moves_gaussians_rigidly(dtype, tol):
    model = _model(dtype)
    g = _local(300, model.faces.shape[0])
    av = RiggedAvatar(model, g)
    base = dict(expr=np.linspace(-1, 1, 5), jaw_pose=[0.15, 0, 0], neck_pose=[0.05, 0.1, 0])
    a = av.pose(**base)
    b = av.pose(**base, rotation=[0.4, -0.7, 0.2], translation=[0.03, -0.02, 0.1])
    # the degenerate-face fallback frame is not rotation-equivariant (and near-degenerate frames are
    # ill-conditioned): compare Gaussians on faces with a height of at least 0.1 mm
    v = model.v_template.double()
    f = model.faces
    e0, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    height = torch.linalg.cross(e0, e2).norm(dim=-1) / e0.norm(dim=-1).clamp_min(1e-30)
    ok = (height > 1e-4)[av.binding]
    assert int((~ok).sum()) > 0  # the random model has a few degenerate faces
    a, b = a.subset(ok), b.subset(ok)
    exact = "donot_use_mm_for_euclid_dist"
    da = torch.cdist(a.means.double(), a.means.double(), compute_mode=exact)
    db = torch.cdist(b.means.double(), b.means.double(), compute_mode=exact)
    assert float((da - db).abs().max()) < tol
    # orientation changes by one rotation for every Gaussian, scales unchanged
    ra = quat_to_rotmat_np(a.quats.double().numpy())
    rb = quat_to_rotmat_np(b.quats.double().numpy())
    rel = rb @ np.swapaxes(ra, 1, 2)
    assert np.abs(rel - rel[0]).max() < tol * 10
    assert float((a.log_scales - b.log_scales).abs().max()) < tol * 10


def test_world_to_local_inverts_binding():
    rng = np.random.default_rng(5)
    verts = rng.normal(scale=0.1, size=(40, 3))
    faces = np.array([rng.choice(40, 3, replace=False) for _ in range(50)])
    b = rng.integers(0, 50, 100)
    m, q, ls = rng.normal(size=(100, 3)), rng.normal(size=(100, 4)), rng.normal(size=(100, 3))
    wm, wq, wls = bind_to_world_np(m, q, ls, b, verts, faces)
    lm, lq, lls = world_to_local_np(wm, wq, wls, b, verts, faces)
    np.testing.assert_allclose(lm, m, atol=1e-10)
    np.testing.assert_allclose(quat_to_rotmat_np(lq), quat_to_rotmat_np(q), atol=1e-10)
    np.testing.assert_allclose(lls, ls, atol=1e-12)
    # the references frame only the bound faces (a 2000-Gaussian avatar on a 61k-face head: 12 s -> 0.4 s);
    # the result is exactly the frames of every face, indexed by the binding
    rot, scale, centre, _ = face_frames_np(verts, faces)
    q_face = rotmat_to_quat_np(rot[b])
    means = scale[b, None] * np.einsum("nij,nj->ni", rot[b], m) + centre[b]
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    assert np.array_equal(wm, means) and np.array_equal(wls, ls + np.log(scale[b])[:, None])
    assert np.array_equal(wq, quat_multiply_np(q_face, qn))


def test_degenerate_faces_give_no_nan_and_are_counted():
    verts = torch.tensor([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [0.5, 0.5, 0.5]]], dtype=torch.float32)
    faces = torch.tensor([[0, 1, 2], [0, 1, 3], [4, 4, 4], [0, 0, 2], [1, 2, 4]])
    rot, scale, centre, deg = face_frames(verts, faces)
    assert deg[0].tolist() == [False, True, True, True, False]
    assert torch.isfinite(rot).all() and torch.isfinite(scale).all() and (scale > 0).all()
    eye = torch.eye(3)
    assert torch.allclose(rot[0].transpose(-1, -2) @ rot[0], eye.expand(5, 3, 3), atol=1e-6)
    assert torch.allclose(torch.linalg.det(rot[0]), torch.ones(5), atol=1e-6)
    r_np, s_np, _, d_np = face_frames_np(verts[0].numpy(), faces.numpy())
    assert d_np.tolist() == deg[0].tolist()
    np.testing.assert_allclose(rot[0].numpy(), r_np, atol=1e-6)
    np.testing.assert_allclose(scale[0].numpy(), s_np, rtol=1e-6)


def test_rigged_degenerate_count_and_finite_output():
    arrays = random_flame_arrays(n_vertices=100, n_shape=2, n_expr=2, seed=2)
    arrays["f"] = arrays["f"].copy()
    arrays["f"][:3] = [[5, 5, 6], [7, 7, 7], [8, 9, 8]]
    model = FlameModel.from_arrays(arrays)
    av = RiggedAvatar(model, _local(50, model.faces.shape[0], seed=4), binding=np.arange(50) % 4)
    assert av.n_degenerate_faces >= 3
    out = av.pose(expr=[1.0, -1.0])
    assert all(torch.isfinite(t).all() for t in (out.means, out.quats, out.log_scales))


def test_batched_deform_matches_single_frames():
    model = _model(torch.float32)
    av = RiggedAvatar(model, _local(100, model.faces.shape[0]))
    expr = np.random.default_rng(0).normal(size=(3, 5))
    outs = av.pose(expr=expr, jaw_pose=np.array([[0.1, 0, 0]] * 3))
    assert isinstance(outs, list) and len(outs) == 3
    for i in range(3):
        one = av.pose(expr=expr[i], jaw_pose=[0.1, 0, 0])
        assert isinstance(one, Gaussians)
        torch.testing.assert_close(outs[i].means, one.means, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("backend", ["auto", "torch"])
def test_cache_exact_with_zero_tolerance_and_skips_unmoved(backend):
    model = _model(torch.float32)
    av = RiggedAvatar(model, _local(500, model.faces.shape[0]))
    av.backend = backend
    av.pose(cache=True)
    assert av.last_cache_fraction == 1.0
    frames = [dict(jaw_pose=[0.2, 0, 0]), dict(jaw_pose=[0.2, 0, 0]), dict(eyes_pose=[0, 0.3, 0, 0, 0.3, 0]),
              dict(expr=[0.5, 0, 0, 0, 0]), dict(expr=[0.5, 0, 0, 0, 0], eyes_pose=[0, 0.3, 0, 0, 0.2, 0])]
    fractions = []
    for full_fraction in (0.6, 1.0):
        av.cache_full_fraction = full_fraction
        for f in frames:
            cached = av.pose(cache=True, **f)
            fractions.append(av.last_cache_fraction)
            full = av.pose(**f)
            assert torch.equal(cached.means, full.means) and torch.equal(cached.quats, full.quats)
            assert torch.equal(cached.log_scales, full.log_scales)
    assert fractions[1] == 0.0 and 0 < fractions[0] < 1 and 0 < fractions[-1] < 1, fractions
    av.pose(cache=True, jaw_pose=[0.2, 0, 0])
    av.pose(cache=True, jaw_pose=[0.2, 0, 0])
    assert av.last_cache_fraction == 0.0


@pytest.mark.parametrize("backend", ["auto", "torch"])
def test_cache_tolerance_bounds_staleness(backend):
    model = _model(torch.float64)
    av = RiggedAvatar(model, _local(300, model.faces.shape[0]))
    av.backend = backend
    tol = 1e-3
    av.pose(cache=True, cache_tol=tol)
    for t in np.linspace(0, 0.01, 12):
        c = av.pose(cache=True, cache_tol=tol, jaw_pose=[t, 0, 0])
    full = av.pose(jaw_pose=[0.01, 0, 0])
    # stale Gaussians come from faces whose vertices moved < tol: error bounded by a few tol
    err = (c.means - full.means).norm(dim=-1).max()
    assert 0 < float(err) < 5 * tol


# --------------------------------------------------------------------------- GaussianAvatars files
def _write_avatar(tmp_path, model, n=80, T=4):
    g = _local(n, model.faces.shape[0], degree=3)
    g = g.replace(**{k: getattr(g, k).astype(np.float32) for k in ("means", "quats", "log_scales",
                                                                   "opacity_logits", "sh")})
    g.save_ply(tmp_path / "point_cloud.ply")
    rng = np.random.default_rng(0)
    params = FlameParams(shape=rng.normal(size=6).astype(np.float32), expr=rng.normal(size=(T, 5)).astype(np.float32),
                         rotation=np.zeros((T, 3), np.float32), neck_pose=np.zeros((T, 3), np.float32),
                         jaw_pose=np.tile([0.1, 0, 0], (T, 1)).astype(np.float32),
                         translation=np.zeros((T, 3), np.float32), eyes_pose=np.zeros((T, 6), np.float32),
                         static_offset=rng.normal(scale=1e-3, size=(1, model.n_vertices, 3)).astype(np.float32))
    params.save(tmp_path / "flame_param.npz")
    return g, params


def test_load_gaussian_avatar_round_trip(tmp_path):
    model = _model(torch.float32)
    g, params = _write_avatar(tmp_path, model)
    av, p = load_gaussian_avatar(tmp_path / "point_cloud.ply", flame_model=model)
    assert p is not None and p.n_frames == 4 and av.n_gaussians == 80
    frame = p.frame(2)
    out = av.pose(**frame)
    verts = model(shape=params.shape, static_offset=params.static_offset, **frame).vertices[0].double().numpy()
    rm, _, _ = bind_to_world_np(g.means, g.quats, g.log_scales, g.extra["binding_0"].astype(int), verts,
                                model.faces.numpy())
    np.testing.assert_allclose(out.means.numpy(), rm, atol=2e-6)
    av.save_ply(tmp_path / "again.ply")
    av2, _ = load_gaussian_avatar(tmp_path / "again.ply", flame_model=model)
    assert torch.equal(av2.binding, av.binding)


def test_load_gaussian_avatar_errors(tmp_path):
    model = _model(torch.float32)
    g, params = _write_avatar(tmp_path, model)
    with pytest.raises(AvatarError, match="point_cloud.ply: flame_model"):
        load_gaussian_avatar(tmp_path / "point_cloud.ply")
    bad = g.replace(extra={"binding_0": np.full(len(g), 1e6, np.float32)})
    bad.save_ply(tmp_path / "b" / "point_cloud.ply")
    with pytest.raises(AvatarError, match="binding: expected face indices in"):
        load_gaussian_avatar(tmp_path / "b" / "point_cloud.ply", flame_model=model)
    g.replace(extra={}).save_ply(tmp_path / "c.ply")
    with pytest.raises(AvatarError, match="binding_0"):
        load_gaussian_avatar(tmp_path / "c.ply", flame_model=model)
    # wrong vertex count in static_offset
    np.savez(tmp_path / "fp.npz", expr=params.expr, static_offset=np.zeros((1, 7, 3), np.float32))
    with pytest.raises(AvatarError, match="static_offset: wrong vertex count"):
        load_gaussian_avatar(tmp_path / "point_cloud.ply", tmp_path / "fp.npz", flame_model=model)
    np.savez(tmp_path / "fp2.npz", shape=params.shape)
    with pytest.raises(AvatarError, match="fp2.npz: missing key 'expr'"):
        load_flame_params(tmp_path / "fp2.npz")
    e = params.expr.copy()
    e[1, 2] = np.nan
    np.savez(tmp_path / "fp3.npz", expr=e)
    with pytest.raises(AvatarError, match=r"fp3.npz: expr: holds NaN/inf \(rows \[1\]"):
        load_flame_params(tmp_path / "fp3.npz")
    np.savez(tmp_path / "fp4.npz", expr=params.expr, jaw_pose=np.zeros((3, 3)))
    with pytest.raises(AvatarError, match="jaw_pose: expected shape \\(4, 3\\)"):
        load_flame_params(tmp_path / "fp4.npz")
    (tmp_path / "trunc.ply").write_bytes((tmp_path / "point_cloud.ply").read_bytes()[:-7])
    with pytest.raises(PlyError, match="trunc.ply: truncated"):
        load_gaussian_avatar(tmp_path / "trunc.ply", flame_model=model)
