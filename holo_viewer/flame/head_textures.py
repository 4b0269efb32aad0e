"""The default head's textures on disk: ship, load, cache (the I/O side of :mod:`.appearance`).

:func:`head_appearance` gives the :class:`~.appearance.HeadAppearance` of a FLAME-format model that
carries texture coordinates (``uv`` / ``faces_uv`` and region labels in its metadata, as the default
head does) and ``None`` for models without them (user FLAME models keep the region-colour preview).
The textures are painted by the build-time painter
:func:`holo_viewer.assets_build.texture_painter.generate_appearance` (about 20 s on one core) once:

* at build time, ``scripts/build_head_textures.py`` (or :func:`build_head_textures`, which
  ``scripts/build_default_head.py`` may call) writes ``assets/default_head_albedo_{name}.png`` for
  ``face``, ``head``, ``hair``, ``eye_left``, ``eye_right``, ``lashes`` (+ ``lashes_alpha``) and
  ``assets/default_head_albedo.json`` (the appearance version, seed, texture sizes and a hash of the
  mesh they were painted for);
* at run time the shipped PNGs are used when the manifest's mesh hash matches the model; otherwise
  (a rebuilt or different head) the textures are painted and cached under
  :func:`holo_viewer.cache.cache_dir` ``/head_textures/{hash}/``: the one run-time use of the
  painter, imported lazily (:func:`_appearance`). Loaded textures only go through
  :func:`~.appearance.assemble_appearance` (materials and vertex colours).

A missing, unreadable or wrongly sized texture file is a :class:`~holo_viewer.errors.FlameError`
naming the file, what was expected and what was found.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ExportError, FlameError, HoloViewerError, InputError
from .appearance import (APPEARANCE_VERSION, EYE_TEXTURE_SIZE, LASH_TEXTURE_SIZE, TEXTURE_SIZE, HeadAppearance,
                         assemble_appearance)

__all__ = ["head_appearance", "appearance_inputs", "build_head_textures", "save_textures", "load_textures",
           "mesh_key", "TEXTURE_NAMES", "MANIFEST_NAME", "assets_dir"]

PREFIX = "default_head_albedo"
MANIFEST_NAME = f"{PREFIX}.json"
#: a patient's textures (assets/patients/<name>/, docs/patients.md): ``albedo_{name}.png`` + ``albedo.json``
PATIENT_PREFIX = "albedo"
PATIENT_MANIFEST = f"{PATIENT_PREFIX}.json"
TEXTURE_NAMES = ("face", "head", "hair", "eye_left", "eye_right", "lashes")
ALPHA_NAMES = ("lashes",)


def assets_dir() -> Path:
    """The checkout's ``assets/`` folder."""
    return Path(__file__).resolve().parents[2] / "assets"


def appearance_inputs(model: Any) -> dict[str, np.ndarray] | None:
    """The rest mesh, UVs, regions and 68 landmark points of ``model`` for the generator, or None
    when the model has no texture coordinates (or no landmarks) to paint on."""
    import torch

    meta = getattr(model, "metadata", {}) or {}
    if not all(k in meta for k in ("uv", "faces_uv", "vertex_region", "region_names")):
        return None
    faces = model.faces.cpu().numpy().astype(np.int64)
    rest = model.v_template.detach().cpu().numpy().astype(np.float64)
    if len(rest) != int(model.n_vertices):  # vertices appended at run time (FLAME-style teeth)
        with torch.no_grad():
            rest = model().vertices[0].cpu().numpy().astype(np.float64)
    uv = np.asarray(meta["uv"], dtype=np.float64)
    fuv = np.asarray(meta["faces_uv"], dtype=np.int64)
    if fuv.ndim != 2 or fuv.shape[1] != 3 or len(fuv) > len(faces) or uv.ndim != 2 or uv.shape[1] != 2:
        raise FlameError(f"model metadata: faces_uv {fuv.shape} / uv {uv.shape} do not fit {len(faces)} triangles")
    if len(fuv) < len(faces):  # triangles appended after the UV layout (FLAME-style teeth): tile 3, teeth
        uv = np.vstack([uv, [[3.5, 0.5]]])
        fuv = np.vstack([fuv, np.full((len(faces) - len(fuv), 3), len(uv) - 1)])
    lm = _landmarks(meta, rest, faces)
    if lm is None:
        return None
    return {"vertices": rest, "faces": faces, "uv": uv, "faces_uv": fuv,
            "vertex_region": np.asarray(meta["vertex_region"], dtype=np.int64),
            "region_names": np.asarray([str(s) for s in meta["region_names"]]), "landmarks": lm}


def _landmarks(meta: dict, rest: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    for key in ("landmarks68", "landmark_vertices"):
        if key in meta:
            idx = np.asarray(meta[key]).reshape(-1).astype(np.int64)
            if idx.shape == (68,) and idx.min() >= 0 and idx.max() < len(rest):
                return rest[idx]
    if "holo_viewer_default_head" in meta:
        path = assets_dir() / "default_head_landmarks.npz"
        if path.exists():
            from ..fileio import read_npz

            emb = read_npz(path, FlameError, "landmark embedding")
            tri = np.asarray(emb.get("triangles", []), dtype=np.int64)
            bary = np.asarray(emb.get("bary", []), dtype=np.float64)
            if tri.shape == (68,) and bary.shape == (68, 3) and tri.min() >= 0 and tri.max() < len(faces):
                return np.einsum("nk,nkc->nc", bary, rest[faces[tri]])
    return None


def mesh_key(inputs: dict[str, np.ndarray], seed: int = 0) -> str:
    """A short hash of everything the textures depend on (mesh, UVs, labels, landmarks, seed,
    generator version and texture sizes)."""
    h = hashlib.sha256()
    h.update(f"v{APPEARANCE_VERSION} s{int(seed)} {TEXTURE_SIZE} {EYE_TEXTURE_SIZE} {LASH_TEXTURE_SIZE}".encode())
    for k in ("vertices", "faces", "uv", "faces_uv", "vertex_region", "landmarks"):
        a = np.asarray(inputs[k])
        a = np.round(a.astype(np.float64), 6) if a.dtype.kind == "f" else a.astype(np.int64)
        h.update(k.encode())
        h.update(np.ascontiguousarray(a).tobytes())
    h.update("|".join(str(s) for s in inputs["region_names"]).encode())
    return h.hexdigest()[:16]


def save_textures(app: HeadAppearance, folder: str | Path, key: str, prefix: str = PREFIX) -> list[Path]:
    """Write the textures as PNGs plus the manifest, atomically; returns the paths (manifest last).
    ``prefix``: file names ``{prefix}_{name}.png`` and ``{prefix}.json`` (a patient's: ``albedo``)."""
    from ..fileio import atomic_write, ensure_dir, save_image

    out = ensure_dir(folder, "texture folder")
    paths = [save_image(Path(out) / f"{prefix}_{n}.png", app.textures[n]) for n in TEXTURE_NAMES]
    for n in ALPHA_NAMES:
        if n in app.alpha:
            paths.append(save_image(Path(out) / f"{prefix}_{n}_alpha.png", app.alpha[n]))
    manifest = {"appearance_version": APPEARANCE_VERSION, "seed": int(app.seed), "mesh_key": key,
                "textures": {n: f"{prefix}_{n}.png" for n in TEXTURE_NAMES},
                "alpha": {n: f"{prefix}_{n}_alpha.png" for n in ALPHA_NAMES if n in app.alpha},
                "sizes": {"skin_hair": TEXTURE_SIZE, "eyes": EYE_TEXTURE_SIZE, "lashes": LASH_TEXTURE_SIZE}}
    target = Path(out) / f"{prefix}.json"
    with atomic_write(target, "w") as fh:
        json.dump(manifest, fh, indent=1)
        fh.write("\n")
    paths.append(target)
    return paths


def load_textures(folder: str | Path, key: str | None = None, manifest: str = MANIFEST_NAME) -> tuple[dict, dict, int]:
    """Read the textures written by :func:`save_textures`.

    Parameters
    ----------
    folder : path
        Folder holding ``default_head_albedo.json`` (or ``manifest``) and the PNGs.
    key : str, optional
        Expected :func:`mesh_key`; a different one raises (textures painted for another mesh).

    Returns
    -------
    (textures, alpha, seed)

    Raises
    ------
    FlameError
        Missing or malformed manifest, a missing/unreadable PNG, a texture of the wrong size, or a
        manifest for another mesh or generator version; the message names the file.
    """
    from ..fileio import load_image, read_json

    folder = Path(folder)
    mpath = folder / manifest
    man = read_json(mpath, FlameError, "head texture manifest")
    if not isinstance(man, dict) or not isinstance(man.get("textures"), dict):
        raise FlameError(f"{mpath}: expected a JSON object with 'textures', found {type(man).__name__}")
    if man.get("appearance_version") != APPEARANCE_VERSION:
        raise FlameError(f"{mpath}: textures of appearance version {man.get('appearance_version')!r}, this code "
                         f"paints version {APPEARANCE_VERSION}; rebuild them (scripts/build_head_textures.py)")
    if key is not None and man.get("mesh_key") != key:
        raise FlameError(f"{mpath}: textures painted for mesh {man.get('mesh_key')!r}, the model is {key!r}; "
                         "rebuild them (scripts/build_head_textures.py)")
    sizes = {"face": TEXTURE_SIZE, "head": TEXTURE_SIZE, "hair": TEXTURE_SIZE, "eye_left": EYE_TEXTURE_SIZE,
             "eye_right": EYE_TEXTURE_SIZE, "lashes": LASH_TEXTURE_SIZE}

    def read(name: str, fname: Any) -> np.ndarray:
        if not isinstance(fname, str) or "/" in fname or "\\" in fname:
            raise FlameError(f"{mpath}: texture {name!r}: expected a file name, found {fname!r}")
        path = folder / fname
        try:
            img = load_image(path)
        except ExportError as exc:
            raise FlameError(f"head texture {name!r}: {exc}") from None
        side = sizes[name]
        if img.shape != (side, side, 3):
            raise FlameError(f"{path}: head texture {name!r}: expected {side}x{side} pixels, found "
                             f"{img.shape[1]}x{img.shape[0]}")
        return img

    textures = {}
    for name in TEXTURE_NAMES:
        if name not in man["textures"]:
            raise FlameError(f"{mpath}: no texture {name!r}; expected {list(TEXTURE_NAMES)}")
        textures[name] = read(name, man["textures"][name])
    alpha = {n: read(n, f)[..., 0] for n, f in (man.get("alpha") or {}).items() if n in sizes}
    return textures, alpha, int(man.get("seed", 0))


def _appearance(**kw: Any) -> HeadAppearance:
    """Assemble the appearance from ``textures`` when given; else paint them (build-time code, imported
    lazily: a checkout whose shipped textures do not match its head paints once and caches)."""
    if kw.get("textures") is not None:
        return assemble_appearance(**kw)
    from ..assets_build.texture_painter import generate_appearance

    return generate_appearance(**kw)


def head_appearance(model: Any, seed: int = 0, verbose: bool = False) -> HeadAppearance | None:
    """The appearance of ``model`` (shipped textures, else cached, else painted and cached), or
    None when the model carries no texture coordinates (see the module docstring)."""
    inputs = appearance_inputs(model)
    if inputs is None:
        return None
    key = mesh_key(inputs, seed)
    from ..cache import cache_dir

    args = {k: inputs[k] for k in ("vertices", "faces", "uv", "faces_uv", "vertex_region", "region_names", "landmarks")}
    own = (getattr(model, "metadata", {}) or {}).get("appearance_dir")
    if own is not None:  # a patient's head (avatar.patients): its own textures, never repainted with the default look
        from ..fileio import read_json

        man = read_json(Path(own) / PATIENT_MANIFEST, FlameError, "head texture manifest")
        s = int(man.get("seed", 0)) if isinstance(man, dict) else 0  # painted with the patient's seed
        textures, alpha, s = load_textures(own, mesh_key(inputs, s), PATIENT_MANIFEST)
        return _appearance(**args, seed=s, textures=textures, alpha=alpha)
    for folder in (assets_dir(), cache_dir() / "head_textures" / key):
        if not (folder / MANIFEST_NAME).exists():
            continue
        try:
            textures, alpha, s = load_textures(folder, key)
        except FlameError as exc:
            if folder == assets_dir():  # stale shipped textures (the head was rebuilt): paint anew
                if verbose:
                    print(f"head textures: {exc}")
                continue
            raise
        if s == seed:
            return _appearance(**args, seed=seed, textures=textures, alpha=alpha)
    if verbose:
        print("head textures: painting (one-off, ~20 s) ...")
    app = _appearance(**args, seed=seed)
    try:
        save_textures(app, cache_dir() / "head_textures" / key, key)
    except (HoloViewerError, OSError) as exc:  # a read-only cache only costs the repaint next time
        if verbose:
            print(f"head textures: not cached ({exc})")
    return app


def build_head_textures(model: Any, out: str | Path | None = None, seed: int = 0, prefix: str = PREFIX,
                        look: Any = None) -> list[Path]:
    """Paint ``model``'s textures and write them (default: ``assets/``) for shipping; ``look``: a
    patient's :class:`~holo_viewer.assets_build.texture_painter.Look` (default: the default head's)."""
    inputs = appearance_inputs(model)
    if inputs is None:
        raise InputError("build_head_textures: the model has no uv / faces_uv / vertex_region / region_names "
                         "metadata or no 68 landmarks; nothing to paint")
    key = mesh_key(inputs, seed)
    extra = {} if look is None else {"look": look}
    app = _appearance(**{k: inputs[k] for k in ("vertices", "faces", "uv", "faces_uv", "vertex_region",
                                                         "region_names", "landmarks")}, seed=seed, **extra)
    return save_textures(app, assets_dir() if out is None else out, key, prefix)
