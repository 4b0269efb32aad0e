"""Blend-shape avatar against the rigged avatar; back-face culling."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from holo_viewer.avatar import BlendshapeAvatar, Gaussians, RiggedAvatar, cull_backfacing
from holo_viewer.avatar.culling import face_visibility, visible_mask
from holo_viewer.camera import Cameras, intrinsics, look_at
from holo_viewer.errors import AvatarError, InputError
from holo_viewer.flame.model import FlameModel
from holo_viewer.flame.synthetic import random_flame_arrays


@pytest.fixture(scope="module")
def rigged() -> RiggedAvatar:
    arrays = random_flame_arrays(n_vertices=200, n_shape=4, n_expr=5, seed=1)
    v, f = arrays["v_template"], arrays["f"]
    e0, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    height = np.linalg.norm(np.cross(e0, e2), axis=1) / np.maximum(np.linalg.norm(e0, axis=1), 1e-30)
    arrays["f"] = f[height > 1e-3]  # no (near-)degenerate faces: their fallback frame is not equivariant
    model = FlameModel.from_arrays(arrays)
    rng = np.random.default_rng(0)
    n = 600
    g = Gaussians(rng.normal(scale=0.3, size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(-1, 0.2, size=(n, 3)),
                  rng.normal(size=n), rng.normal(size=(n, 4, 3)),
                  extra={"binding": rng.integers(0, model.faces.shape[0], n)})
    return RiggedAvatar(model, g, identity={"shape": rng.normal(size=4)})


@pytest.fixture(scope="module")
def blend(rigged) -> BlendshapeAvatar:
    return BlendshapeAvatar.from_rigged(rigged, include_jaw=True)


def _params(g: Gaussians) -> np.ndarray:
    q = g.quats.double().numpy()
    return np.concatenate([g.means.double().numpy(), q, g.log_scales.double().numpy()], axis=1)


def test_equals_rigged_at_zero(rigged, blend):
    r, b = rigged.pose(), blend.pose(np.zeros(5))
    np.testing.assert_allclose(b.means.numpy(), r.means.numpy(), atol=1e-6)
    np.testing.assert_allclose(b.quats.numpy(), r.quats.numpy(), atol=1e-6)
    np.testing.assert_allclose(b.log_scales.numpy(), r.log_scales.numpy(), atol=1e-5)
    assert torch.equal(b.opacity_logits, r.opacity_logits.float()) and torch.equal(b.sh, r.sh.float())


def test_first_order_agreement(rigged, blend):
    rng = np.random.default_rng(2)
    direction = rng.normal(size=5)
    jaw_dir = np.array([0.3, 0.05, 0.0])
    errs = []
    for eps in (1e-1, 1e-2):
        r = _params(rigged.pose(expr=eps * direction, jaw_pose=eps * jaw_dir))
        b = _params(blend.pose(eps * direction, jaw_pose=eps * jaw_dir))
        errs.append(np.abs(r - b)[:, :3].max())
    # second-order remainder: 10x smaller step -> ~100x smaller error (float32 floor 1e-7)
    assert errs[1] < errs[0] / 30 + 2e-7, errs


@pytest.fixture(scope="module")
def exact(rigged) -> BlendshapeAvatar:
    return BlendshapeAvatar.from_rigged(rigged, include_jaw=True, exact_jvp=True)


def test_face_chain_rule_equals_full_jvp(exact, blend):
    # the face-factorised B (B_k = A_i F_k) materialised per Gaussian equals the full per-Gaussian jvp
    assert blend.representation == "faces" and exact.representation == "gaussians"
    b0_exact, b_exact = exact.blend_shapes()
    b0, b = blend.blend_shapes()
    assert b.shape == (8, len(blend), 10)
    np.testing.assert_allclose(exact.base, blend.base, atol=1e-7)
    np.testing.assert_allclose(b0, b0_exact, atol=1e-7)
    np.testing.assert_allclose(b, b_exact, rtol=1e-5, atol=1e-7)


def _shuffled(rigged: RiggedAvatar, seed: int) -> RiggedAvatar:
    """The same avatar with its Gaussians in a random order (binding not sorted by face)."""
    order = np.random.default_rng(seed).permutation(rigged.n_gaussians)
    loc = rigged.local
    g = Gaussians(loc.means[order], loc.quats[order], loc.log_scales[order], loc.opacity_logits[order],
                  loc.sh[order])
    return RiggedAvatar(rigged.flame_model, g, binding=rigged.binding[order], identity=rigged.identity), order


@pytest.mark.parametrize("which", ["faces", "faces_unsorted", "faces_dropped", "gaussians"])
@pytest.mark.parametrize("threads", [1, 2])
def test_kernel_equals_dense_product(rigged, blend, exact, which, threads):
    import numba

    if which == "faces_unsorted":
        shuffled, order = _shuffled(rigged, 11)
        av = BlendshapeAvatar.from_rigged(shuffled, include_jaw=True)
        assert av._blend.perm.size == len(av)
        # the same Gaussians, in the shuffled order
        np.testing.assert_allclose(av.blend_shapes()[1], blend.blend_shapes()[1][:, order], rtol=1e-5, atol=1e-7)
    elif which == "faces_dropped":  # most (face, component) pairs dropped: faces without entries copy F_0
        av = BlendshapeAvatar.from_rigged(rigged, include_jaw=True, drop_tol=2e-2)
        assert 0 < av.nnz < blend.nnz / 2, (av.nnz, blend.nnz)
        static = av._blend.static_gaussians()
        assert 0 < static.sum() < len(av)  # both paths of the kernel (copy B_0, blend the face)
    else:
        av = blend if which == "faces" else exact
    coeffs = np.random.default_rng(3).normal(size=(3, 5)).astype(np.float32)
    coeffs[1, [0, 3]] = 0.0  # some components zero (skipped by the kernel)
    jaw = np.random.default_rng(4).normal(scale=0.1, size=(3, 3)).astype(np.float32)
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        av.backend = "auto"
        a = av.blend_tensors(coeffs, jaw)
    finally:
        numba.set_num_threads(before)
    av.backend = "torch"
    b = av.blend_tensors(coeffs, jaw)
    av.backend = "auto"
    # float64 reference: B_0 + sum_k psi_k B_k from the materialised blend shapes
    b0, bk = av.blend_shapes()
    c = np.concatenate([coeffs, jaw], axis=1).astype(np.float64)
    ref = b0[None] + np.einsum("tk,knp->tnp", c, bk)
    for x, y, sl in zip(a, b, (slice(0, 3), slice(3, 7), slice(7, 10))):
        assert x.dtype == torch.float32 and x.is_contiguous()
        torch.testing.assert_close(x, y, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(x.numpy(), ref[..., sl], rtol=1e-5, atol=1e-6)


def test_no_components_equals_rigged_rest(rigged):
    av = BlendshapeAvatar.from_rigged(rigged, n_expr=0)
    assert av.nnz == 0 and av.n_components == 0
    r, b = rigged.pose(), av.pose(np.zeros(0))
    np.testing.assert_allclose(b.means.numpy(), r.means.numpy(), atol=1e-6)
    np.testing.assert_allclose(b.quats.numpy(), r.quats.numpy(), atol=1e-6)
    np.testing.assert_allclose(b.log_scales.numpy(), r.log_scales.numpy(), atol=1e-5)


def test_rigid_head_pose_exact(rigged, blend):
    e = np.random.default_rng(5).normal(scale=0.01, size=5)
    rot, tr = np.array([0.2, -0.4, 0.1]), np.array([0.01, 0.02, -0.03])
    r = rigged.pose(expr=e, rotation=rot, translation=tr)
    b = blend.pose(e, rotation=rot, translation=tr)
    b0 = blend.pose(e)
    r0 = rigged.pose(expr=e)
    # the blend-shape error is the same before and after the rigid motion
    err_posed = (r.means - b.means).norm(dim=-1)
    err_rest = (r0.means - b0.means).norm(dim=-1)
    torch.testing.assert_close(err_posed, err_rest, atol=1e-5, rtol=0)


def _nan_at(a: np.ndarray, i: int) -> np.ndarray:
    return np.where(np.arange(a.size).reshape(a.shape) == i, np.nan, a)


@pytest.mark.parametrize("which", ["faces", "gaussians"])
def test_save_load_round_trip_and_errors(tmp_path, blend, exact, which):
    av = blend if which == "faces" else exact
    p = av.save(tmp_path / "bs.npz")
    b2 = BlendshapeAvatar.load(p)
    assert b2.representation == av.representation
    e = np.linspace(-1, 1, 5)
    assert torch.equal(b2.pose(e, jaw_pose=[0.1, 0, 0]).means, av.pose(e, jaw_pose=[0.1, 0, 0]).means)
    with np.load(p) as z:
        data = dict(z)
    values, floats, ptr = ("fvals", "f0", "fptr") if which == "faces" else ("vals", "base", "ptr")
    bad = dict(data)
    bad.pop(values)
    np.savez(tmp_path / "missing.npz", **bad)
    with pytest.raises(AvatarError, match=f"missing.npz: missing keys \\['{values}'\\]"):
        BlendshapeAvatar.load(tmp_path / "missing.npz")
    bad = dict(data, **{floats: _nan_at(data[floats], 7)})
    np.savez(tmp_path / "nan.npz", **bad)
    with pytest.raises(AvatarError, match=f"nan.npz: {floats}: holds NaN/inf"):
        BlendshapeAvatar.load(tmp_path / "nan.npz")
    bad = dict(data, **{ptr: data[ptr][:-1]})
    np.savez(tmp_path / "ptr.npz", **bad)
    with pytest.raises(AvatarError, match=f"ptr.npz: {'fptr' if which == 'faces' else 'ptr/comp/vals'}"):
        BlendshapeAvatar.load(tmp_path / "ptr.npz")
    if which == "faces":
        bad = dict(data, local=_nan_at(data["local"], 3))
        np.savez(tmp_path / "nanlocal.npz", **bad)
        with pytest.raises(AvatarError, match="nanlocal.npz: local: holds NaN/inf"):
            BlendshapeAvatar.load(tmp_path / "nanlocal.npz")
        bad = dict(data, perm=np.zeros(len(av), np.int64))
        np.savez(tmp_path / "perm.npz", **bad)
        with pytest.raises(AvatarError, match="perm.npz: perm: expected a permutation"):
            BlendshapeAvatar.load(tmp_path / "perm.npz")
        bad = dict(data, fcomp=np.full_like(data["fcomp"], 99))
        np.savez(tmp_path / "comp.npz", **bad)
        with pytest.raises(AvatarError, match="comp.npz: .*component indices outside"):
            BlendshapeAvatar.load(tmp_path / "comp.npz")
    bad = dict(data, format=np.array("holo_viewer.blendshape_avatar.v9"))
    np.savez(tmp_path / "fmt.npz", **bad)
    with pytest.raises(AvatarError, match="fmt.npz: format: expected"):
        BlendshapeAvatar.load(tmp_path / "fmt.npz")
    (tmp_path / "trunc.npz").write_bytes(p.read_bytes()[:300])
    with pytest.raises(AvatarError, match="trunc.npz: cannot read"):
        BlendshapeAvatar.load(tmp_path / "trunc.npz")


def test_bad_coefficients(blend):
    with pytest.raises(InputError, match="expr"):
        blend.pose(np.zeros(9))
    with pytest.raises(InputError, match="expr: expected finite"):
        blend.pose(np.array([np.nan, 0, 0, 0, 0]))
    with pytest.raises(InputError, match="jaw_pose"):
        blend.pose(np.zeros(5), jaw_pose=np.zeros(4))


# --------------------------------------------------------------------------- culling
def _cams(angles_deg, dist=0.6) -> Cameras:
    w2c = [look_at([dist * np.sin(np.deg2rad(a)), 0, dist * np.cos(np.deg2rad(a))], [0, 0, 0]) for a in angles_deg]
    return Cameras(np.stack(w2c), intrinsics(500, 500, 100, 100), 200, 200)


def test_visible_mask_margin():
    centres = np.zeros((3, 3))
    normals = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]])
    cam = np.array([[0, 0, 1.0]])
    assert visible_mask(centres, normals, cam, 0.0).tolist() == [True, False, False]
    # a normal at exactly 90 degrees is kept by any positive margin
    assert visible_mask(centres, normals, cam, 5.0).tolist() == [True, False, True]


def test_cull_sphere_keeps_front_half():
    # a closed sphere mesh: faces pointing away from all cameras are dropped
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    cams = _cams(np.linspace(-20, 20, 5))
    keep = face_visibility(sphere.vertices, sphere.faces, cams, margin_deg=0.0)
    z = sphere.triangles_center[:, 2]
    assert keep[z > 0.02].all() and not keep[z < -0.05].any()
    assert 0.4 < keep.mean() < 0.65


def test_cull_rigged_and_gaussians(rigged):
    cams = _cams([0, 10])
    out = rigged.flame_model()
    mask = cull_backfacing(rigged, cams, 10.0, vertices=out.vertices)
    assert mask.shape == (rigged.n_gaussians,) and 0 < mask.sum() < mask.size
    g = rigged.pose()
    normals = np.tile([0.0, 0.0, -1.0], (len(g), 1))
    assert not cull_backfacing(g, cams, 0.0, normals=normals).any()
    with pytest.raises(InputError, match="normals"):
        cull_backfacing(g, cams)
    with pytest.raises(InputError, match="vertices"):
        cull_backfacing(rigged, cams)
