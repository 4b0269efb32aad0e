"""The default head's appearance (assets_build.texture_painter, flame.appearance, flame.head_textures) and its render.

Uses the committed head and textures (``assets/``); nothing here needs the ICT source.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from holo_viewer.errors import FlameError, InputError


@pytest.fixture(scope="module")
def model():
    from holo_viewer.flame.default_head import default_head_path
    from holo_viewer.flame.model import FlameModel

    return FlameModel.load(default_head_path(), n_shape=None, n_expr=None)


@pytest.fixture(scope="module")
def inputs(model):
    from holo_viewer.flame.head_textures import appearance_inputs

    inp = appearance_inputs(model)
    assert inp is not None, "the default head carries uv / faces_uv / regions / landmarks"
    return inp


def _args(inputs):
    return {k: inputs[k] for k in ("vertices", "faces", "uv", "faces_uv", "vertex_region", "region_names", "landmarks")}


@pytest.fixture(scope="module")
def small(inputs):
    """A small generation (128-texel tiles) of the default head: fast, every code path."""
    from holo_viewer.assets_build.texture_painter import generate_appearance

    return generate_appearance(**_args(inputs), seed=3, size=128, eye_size=64)


@pytest.fixture(scope="module")
def full(model):
    """The shipped appearance (full-size textures)."""
    from holo_viewer.flame.head_textures import head_appearance

    app = head_appearance(model)
    assert app is not None
    return app


# ----------------------------------------------------------------------------- rasteriser


def test_rasterize_uv_interpolates_exactly_at_texel_centres():
    """A jittered grid of triangles in UV; positions an affine function of UV: the position map at
    every covered texel centre equals the function there (float64, 1e-9), every texel inside the
    grid is covered, and where triangles overlap the higher index wins."""
    from holo_viewer.assets_build.texture_painter import rasterize_uv

    rng = np.random.default_rng(0)
    n = 9
    g = np.stack(np.meshgrid(np.linspace(0.1, 0.9, n), np.linspace(0.1, 0.9, n), indexing="xy"), -1).reshape(-1, 2)
    inner = (np.abs(g - 0.5) < 0.39).all(1)
    g[inner] += rng.uniform(-0.02, 0.02, (inner.sum(), 2))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.c_[a, b, d], np.c_[a, d, c]])
    uv = g + [2.0, 0.0]  # UDIM tile 2
    A = rng.normal(size=(2, 3))
    pos = (uv - [2.0, 0.0]) @ A + [0.3, -0.2, 0.1]
    size = 64
    tri, bary = rasterize_uv(uv[tris], size, (2.0, 0.0))
    cov = tri >= 0
    ii, jj = np.nonzero(cov)
    centre = np.c_[(jj + 0.5) / size, 1.0 - (ii + 0.5) / size]
    interp = np.einsum("nk,nkc->nc", bary[cov], pos[tris[tri[cov]]])
    assert np.abs(interp - (centre @ A + [0.3, -0.2, 0.1])).max() < 1e-9
    assert (bary[cov] >= -1e-9).all() and np.allclose(bary[cov].sum(1), 1.0)
    # texel centres strictly inside the grid's square are all covered
    jc, ic = np.meshgrid(np.arange(size), np.arange(size))
    cu, cv = (jc + 0.5) / size, 1.0 - (ic + 0.5) / size
    assert cov[(cu > 0.13) & (cu < 0.87) & (cv > 0.13) & (cv < 0.87)].all()
    assert not cov[(cu < 0.09) | (cu > 0.91)].any()
    # overlap: the same triangle twice -> the higher index owns the texels
    t2, _ = rasterize_uv(uv[np.r_[tris[:1], tris[:1]]], size, (2.0, 0.0))
    assert set(np.unique(t2[t2 >= 0])) == {1}


def test_texel_convention_and_albedo_at_agree(full, inputs):
    """For covered texels of every texture, the UV interpolated from the texel's triangle and
    barycentrics is the texel centre (1e-9), and albedo_at at that surface point returns the texel."""
    from holo_viewer.assets_build.texture_painter import rasterize_uv
    from holo_viewer.flame.appearance import MATERIAL_TEXTURE, MATERIALS, TEXTURE_TILE

    rng = np.random.default_rng(1)
    uv, fuv = inputs["uv"], inputs["faces_uv"]
    for tex in ("face", "hair", "eye_left"):
        sel = np.nonzero(np.isin(full.face_material, [MATERIALS.index(m) for m, t in MATERIAL_TEXTURE.items()
                                                      if t == tex]))[0]
        img = full.textures[tex]
        size = img.shape[0]
        tri, bary = rasterize_uv(uv[fuv[sel]], size, (TEXTURE_TILE[tex], 0.0))
        ii, jj = np.nonzero(tri >= 0)
        pick = rng.choice(len(ii), 300, replace=False)
        ii, jj = ii[pick], jj[pick]
        faces = sel[tri[ii, jj]]
        b = bary[ii, jj]
        got_uv = full.texture_uv(faces, b)
        want = np.c_[TEXTURE_TILE[tex] + (jj + 0.5) / size, 1.0 - (ii + 0.5) / size]
        assert np.abs(got_uv - want).max() < 1e-6  # float32 UVs in the asset
        # eyes: the outer shell owns shared texels; compare only where the picked face owns the texel
        col = full.albedo_at(faces, b)
        assert np.abs(col - img[ii, jj]).max() < 2e-3, tex


def test_position_map_reproduces_the_surface(full, inputs):
    """Rasterised positions at texel centres lie on the mesh: nearest vertex within the local edge length."""
    from holo_viewer.assets_build.texture_painter import rasterize_uv
    from holo_viewer.flame.appearance import MATERIALS

    v, f = inputs["vertices"], inputs["faces"]
    sel = full.material_faces("face")
    tri, bary = rasterize_uv(inputs["uv"][inputs["faces_uv"][sel]], 256)
    m = tri >= 0
    pos = np.einsum("nk,nkc->nc", bary[m], v[f[sel[tri[m]]]])
    corners = v[f[sel[tri[m]]]]
    edge = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(1)
    # every position is within its triangle's bounding sphere
    assert (np.linalg.norm(pos - corners.mean(1), axis=1) <= edge + 1e-12).all()
    assert MATERIALS.index("face") >= 0


# ----------------------------------------------------------------------------- generator


def test_deterministic_and_in_range(small, inputs):
    from holo_viewer.assets_build.texture_painter import generate_appearance

    again = generate_appearance(**_args(inputs), seed=3, size=128, eye_size=64)
    other = generate_appearance(**_args(inputs), seed=4, size=128, eye_size=64)
    for k, t in small.textures.items():
        assert t.dtype == np.float32 and np.isfinite(t).all() and t.min() >= 0 and t.max() <= 1, k
        assert np.array_equal(np.round(t * 255) / 255, t.astype(np.float64).astype(np.float32)), k  # 8-bit values
        assert np.array_equal(t, again.textures[k]), k
    assert np.array_equal(small.vertex_colors, again.vertex_colors)
    assert np.array_equal(small.face_material, again.face_material)
    assert not np.array_equal(small.textures["face"], other.textures["face"])
    assert small.vertex_colors.min() >= 0 and small.vertex_colors.max() <= 1


def test_materials_cover_the_parts(small, inputs):
    from holo_viewer.flame.appearance import MATERIALS

    names = list(inputs["region_names"])
    reg = inputs["vertex_region"]
    f = inputs["faces"]
    mat = small.face_material
    for region, material in (("hair", "hair"), ("teeth", "teeth"), ("lashes", "lashes")):
        faces = (reg[f] == names.index(region)).all(1)
        assert (mat[faces] == MATERIALS.index(material)).mean() > 0.95, region
    eye = np.isin(reg[f], [names.index(n) for n in ("eyeball_left", "eyeball_right", "iris", "pupil")]).all(1)
    assert np.isin(mat[eye], [MATERIALS.index("eye_left"), MATERIALS.index("eye_right")]).all()
    # the subject's left eye (+x) is eye_left
    cx = inputs["vertices"][f].mean(1)[:, 0]
    assert (cx[mat == MATERIALS.index("eye_left")] > 0).all() and (cx[mat == MATERIALS.index("eye_right")] < 0).all()
    assert (mat == MATERIALS.index("lips")).sum() > 100


def _near(v, p, r):
    return np.linalg.norm(v - p, axis=1) < r


def _lum(c):
    return c @ np.array([0.299, 0.587, 0.114])


def test_brows_darker_than_the_skin_around_them(full, inputs):
    v, lm = inputs["vertices"], inputs["landmarks"]
    col = full.vertex_colors
    names = list(inputs["region_names"])
    front = np.isin(inputs["vertex_region"], [names.index(n) for n in ("skin", "brows")])
    front = np.r_[front, np.zeros(len(v) - len(front), bool)]
    for k in (18, 19, 20, 23, 24, 25):
        dx = np.abs(v[:, 0] - lm[k, 0]) < 0.004
        dy = v[:, 1] - lm[k, 1]
        brow = front & dx & (np.abs(dy + 0.002) < 0.003)
        above = front & dx & (dy > 0.014) & (dy < 0.022)  # the forehead 14..22 mm above
        assert brow.sum() > 3 and above.sum() > 3, k
        assert _lum(col[brow]).mean() < 0.6 * _lum(col[above]).mean(), k


def test_lips_redder_than_skin(full, inputs):
    v, lm = inputs["vertices"], inputs["landmarks"]
    col = full.vertex_colors.astype(np.float64)
    red = lambda c: (c[:, 0] / np.maximum(c[:, 1], 1e-6)).mean()  # noqa: E731
    names = list(inputs["region_names"])
    outer = np.isin(inputs["vertex_region"], [names.index(n) for n in ("skin", "lips")])
    outer = np.nonzero(np.r_[outer, np.zeros(len(v) - len(outer), bool)])[0]

    def nearest(p, k=6):
        return col[outer[np.argsort(np.linalg.norm(v[outer] - p, axis=1))[:k]]]

    lips = np.r_[nearest(0.5 * (lm[51] + lm[62])), nearest(0.5 * (lm[57] + lm[66]))]
    cheek = np.r_[nearest(lm[[2, 31, 41]].mean(0), 20), nearest(lm[[14, 35, 46]].mean(0), 20)]
    chin = nearest(lm[8] + [0, 0.012, 0.0], 20)
    assert red(lips) > red(cheek) + 0.15 and red(lips) > red(chin) + 0.2


def test_pupil_iris_sclera_on_the_eye_axis(full, inputs):
    """Outer-shell eye vertices: dark at the optical axis, iris-coloured inside the limbus, white beyond."""
    from holo_viewer.assets_build.texture_painter import _components, eye_axis
    from holo_viewer.flame.appearance import MATERIALS, face_frame

    v, f = inputs["vertices"], inputs["faces"]
    o, R, mm = face_frame(inputs["landmarks"])
    for name in ("eye_left", "eye_right"):
        ef = f[full.face_material == MATERIALS.index(name)]
        ids = np.unique(ef)
        centre, axis, limbus = eye_axis((v[ids] - o) @ R * mm)
        # the visible shell: the connected piece farthest from the centre (ICT's iris mesh lies inside)
        comp = _components(ef)
        rad = np.linalg.norm((v[ef].mean(1) - o) @ R * mm - centre, axis=1)
        best = np.argmax([rad[comp == c].mean() for c in range(comp.max() + 1)])
        ids = np.unique(ef[comp == best])
        q = (v[ids] - o) @ R * mm
        assert axis[2] > 0.9 and 0.3 < limbus < 0.7  # forward; a 17..40 degree cornea
        d = q - centre
        r = np.linalg.norm(d, axis=1)
        outer = np.ones(len(q), bool)
        th = np.arccos(np.clip((d @ axis) / r, -1, 1)) / limbus
        lum = _lum(full.vertex_colors[ids].astype(np.float64))
        pupil, iris, sclera = outer & (th < 0.2), outer & (th > 0.55) & (th < 0.8), outer & (th > 1.4) & (th < 2.2)
        assert pupil.sum() >= 1 and iris.sum() > 5 and sclera.sum() > 20
        assert lum[pupil].max() < 0.08
        assert 0.08 < np.median(lum[iris]) < 0.5
        assert np.median(lum[sclera]) > 0.7


def test_generator_rejects_bad_input(inputs):
    from holo_viewer.assets_build.texture_painter import generate_appearance

    args = _args(inputs)
    with pytest.raises(InputError, match="landmarks"):
        generate_appearance(**{**args, "landmarks": args["landmarks"][:10]}, size=32, eye_size=16)
    with pytest.raises(InputError, match="faces_uv"):
        generate_appearance(**{**args, "faces_uv": args["faces_uv"][:5]}, size=32, eye_size=16)
    with pytest.raises(InputError, match="textures"):
        generate_appearance(**args, size=32, eye_size=16, textures={"face": np.zeros((32, 32, 3))})


# ----------------------------------------------------------------------------- files


def test_shipped_textures_match_the_head(inputs):
    """assets/default_head_albedo.json was painted for the committed head (else rebuild:
    scripts/build_head_textures.py)."""
    from holo_viewer.flame.head_textures import MANIFEST_NAME, assets_dir, load_textures, mesh_key

    key = mesh_key(inputs, 0)
    man = json.loads((assets_dir() / MANIFEST_NAME).read_text())
    assert man["mesh_key"] == key, "stale shipped textures: run scripts/build_head_textures.py"
    textures, alpha, seed = load_textures(assets_dir(), key)
    assert seed == 0 and set(alpha) == {"lashes"}
    total = sum((assets_dir() / p).stat().st_size for p in list(man["textures"].values()) + list(man["alpha"].values()))
    assert total < 4e6  # a few MB at most


def test_saved_textures_round_trip_and_corrupt_files_are_named(small, tmp_path):
    from holo_viewer.flame.head_textures import MANIFEST_NAME, load_textures, save_textures

    paths = save_textures(small, tmp_path, "k1")
    assert paths[-1].name == MANIFEST_NAME
    # round trip at the generation's sizes: patch the expected sizes through the manifest check
    import holo_viewer.flame.head_textures as ht

    sizes = (ht.TEXTURE_SIZE, ht.EYE_TEXTURE_SIZE)
    try:
        ht.TEXTURE_SIZE, ht.EYE_TEXTURE_SIZE = 128, 64
        textures, alpha, seed = load_textures(tmp_path, "k1")
    finally:
        ht.TEXTURE_SIZE, ht.EYE_TEXTURE_SIZE = sizes
    assert seed == 3
    for k, t in small.textures.items():
        assert np.array_equal(textures[k], t), k
    assert np.array_equal(alpha["lashes"], small.alpha["lashes"])
    # wrong size (the module's full sizes are expected)
    with pytest.raises(FlameError, match=r"default_head_albedo_face\.png.*expected 1024x1024 pixels, found 128x128"):
        load_textures(tmp_path, "k1")
    # another mesh
    with pytest.raises(FlameError, match="painted for mesh 'k1'"):
        load_textures(tmp_path, "k2")
    # a corrupt PNG
    face = tmp_path / "default_head_albedo_face.png"
    face.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(FlameError, match=r"head texture 'face'.*default_head_albedo_face\.png.*not a readable image"):
        load_textures(tmp_path, "k1")
    face.unlink()
    with pytest.raises(FlameError, match=r"default_head_albedo_face\.png: file not found"):
        load_textures(tmp_path, "k1")
    # a malformed manifest
    (tmp_path / MANIFEST_NAME).write_text("{not json")
    with pytest.raises(FlameError, match=r"default_head_albedo\.json: cannot read head texture manifest"):
        load_textures(tmp_path)
    (tmp_path / MANIFEST_NAME).unlink()
    with pytest.raises(FlameError, match="head texture manifest not found"):
        load_textures(tmp_path)


def test_stale_shipped_textures_are_repainted_and_cached(model, tmp_path, monkeypatch):
    """A manifest for another mesh in assets/ is skipped: the textures are painted and cached."""
    import holo_viewer.flame.head_textures as ht

    assets = tmp_path / "assets"
    assets.mkdir()
    for p in ht.assets_dir().glob("default_head_albedo*"):
        shutil.copy(p, assets / p.name)
    man = json.loads((assets / ht.MANIFEST_NAME).read_text())
    man["mesh_key"] = "0" * 16
    (assets / ht.MANIFEST_NAME).write_text(json.dumps(man))
    monkeypatch.setattr(ht, "assets_dir", lambda: assets)
    monkeypatch.setenv("HOLO_VIEWER_CACHE", str(tmp_path / "cache"))
    calls = []
    real = ht._appearance

    def small_gen(**kw):
        calls.append("textures" in kw and kw["textures"] is not None)
        if kw.get("textures") is None:
            kw.update(size=128, eye_size=64)
        return real(**kw)

    monkeypatch.setattr(ht, "_appearance", small_gen)
    app = ht.head_appearance(model)
    assert calls == [False] and app.textures["face"].shape == (128, 128, 3)
    assert list((tmp_path / "cache" / "head_textures").glob("*/default_head_albedo.json"))


def test_models_without_uvs_have_no_appearance(small_model):
    from holo_viewer.flame.head_textures import head_appearance

    assert head_appearance(small_model) is None


# ----------------------------------------------------------------------------- render


def test_textured_quad_renders_the_texture_the_right_way_up():
    """A camera-facing quad with a four-colour texture: each image quadrant shows its texel colour
    (no flip of u or v between the generator's convention and VTK), and a dark texel still shows
    a specular highlight on top (the albedo does not multiply the specular)."""
    from holo_viewer.flame.appearance import MATERIALS, HeadAppearance
    from holo_viewer.flame.preview import render_mesh

    v = np.array([[-0.1, -0.1, 0.0], [0.1, -0.1, 0.0], [0.1, 0.1, 0.0], [-0.1, 0.1, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], np.float32)
    tex = np.zeros((8, 8, 3), np.float32)
    tex[:4, :4] = (1, 0, 0)  # top-left: red
    tex[:4, 4:] = (0, 1, 0)  # top-right: green
    tex[4:, :4] = (0, 0, 1)  # bottom-left: blue
    tex[4:, 4:] = (1, 1, 1)  # bottom-right: white
    app = HeadAppearance(textures={"face": tex}, face_material=np.full(2, MATERIALS.index("face"), np.int16),
                         faces=f, uv=uv, faces_uv=f, vertex_colors=np.full((4, 3), 0.5, np.float32))
    app.specular = {"face": (0.0, 1.0)}
    img = render_mesh(v, f, views=("front",), size=(64, 64), appearance=app, background=(0, 0, 0))[0]
    q = {"tl": img[16, 16], "tr": img[16, 47], "bl": img[47, 16], "br": img[47, 47]}
    # the front camera looks along -z with +y up: +x (u) runs to the image's right, +y (v) up
    assert np.argmax(q["tl"]) == 0 and q["tl"][0] > 0.3 and q["tl"][1:].max() < 0.1  # red
    assert np.argmax(q["tr"]) == 1 and q["tr"][1] > 0.3 and q["tr"][[0, 2]].max() < 0.1  # green
    assert np.argmax(q["bl"]) == 2 and q["bl"][2] > 0.3 and q["bl"][:2].max() < 0.1  # blue
    assert q["br"].min() > 0.3  # white
    black = HeadAppearance(textures={"face": np.zeros((8, 8, 3), np.float32)}, face_material=app.face_material,
                           faces=f, uv=uv, faces_uv=f, vertex_colors=app.vertex_colors)
    black.specular = {"face": (1.0, 5.0)}
    img = render_mesh(v, f, views=("front",), size=(64, 64), appearance=black, background=(0, 0, 0))[0]
    assert img.max() > 0.3  # specular on a black texel


def test_textured_render_rejects_another_topology(full, inputs):
    from holo_viewer.flame.preview import render_mesh

    with pytest.raises(InputError, match="appearance"):
        render_mesh(inputs["vertices"], inputs["faces"][:100], size=(16, 16), appearance=full)
