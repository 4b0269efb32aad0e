"""The ward: the shipped patients (``assets/patients/<name>/``) and the one ``--avatar`` resolver.

Layout and formats: docs/patients.md. Each patient folder holds ``patient.json`` (who the patient is,
where every asset comes from, the files' sha256), ``head.npz`` (the default head's format), the painted
albedo textures (``albedo.json`` + PNGs) and, once fitted, ``avatar.npz`` (the fitted-avatar format of
``assets/default_avatar.npz``, keyed to ``head.npz`` by its sha256).

* :func:`list_patients` / :func:`patient_names` read only the JSON files (cheap: the CLI checks a
  name at parse time with them).
* :func:`load_patient` gives the head model (textures attached), and the fitted avatar when there is
  one (``None`` until ``avatar.npz`` exists).
* :func:`resolve_avatar` turns ``default|none|NAME|PLY|NPZ`` into an :class:`AvatarChoice` or an
  :class:`~holo_viewer.errors.InputError` listing the valid names.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import AvatarError, InputError
from ..fileio import file_sha256

__all__ = ["PATIENT_FORMAT", "PatientInfo", "Patient", "AvatarChoice", "patients_dir", "list_patients",
           "patient_names", "patient_info", "load_patient", "load_patient_model", "load_patient_avatar",
           "resolve_avatar", "avatar_spec_help", "SEXES", "FITZPATRICK", "file_sha256", "check_files",
           "patient_summary", "load_avatar_file", "head_for_avatar_file", "load_choice"]

PATIENT_FORMAT = 1
SEXES = ("female", "male")
FITZPATRICK = ("I", "II", "III", "IV", "V", "VI")
HEAD_FILE = "head.npz"
AVATAR_FILE = "avatar.npz"
INFO_FILE = "patient.json"
#: the names ``--avatar`` takes besides the patients and files
KEYWORDS = ("default", "none")


def patients_dir() -> Path:
    """``assets/patients/`` of the checkout."""
    return Path(__file__).resolve().parents[2] / "assets" / "patients"


@dataclass(frozen=True)
class PatientInfo:
    """A patient's ``patient.json`` (validated)."""

    name: str
    sex: str
    age: int
    fitzpatrick: str
    seed: int
    folder: Path
    description: str = ""
    files: dict = field(default_factory=dict, compare=False, hash=False)
    raw: dict = field(default_factory=dict, compare=False, hash=False, repr=False)

    @property
    def head_path(self) -> Path:
        return self.folder / HEAD_FILE

    @property
    def avatar_path(self) -> Path:
        return self.folder / AVATAR_FILE

    @property
    def fitted(self) -> bool:
        """Whether the patient has a fitted avatar file (not checked against the head here)."""
        return self.avatar_path.is_file()

    def size_bytes(self) -> int:
        """Bytes of every file in the patient's folder (head, textures, avatar, JSON)."""
        return sum(p.stat().st_size for p in self.folder.iterdir() if p.is_file())

    def age_band(self) -> str:
        return "young" if self.age < 40 else "middle" if self.age < 60 else "old"


def _fail(path: Path, what: str) -> AvatarError:
    return AvatarError(f"{path}: {what}")


def parse_patient_json(data: Any, path: Path) -> PatientInfo:
    """Validate a ``patient.json`` object; errors name the file and the field."""
    if not isinstance(data, dict):
        raise _fail(path, f"expected a JSON object, found {type(data).__name__}")
    if data.get("format") != PATIENT_FORMAT:
        raise _fail(path, f"field 'format': expected {PATIENT_FORMAT}, found {data.get('format')!r}")
    name = data.get("name")
    if not isinstance(name, str) or not name.isidentifier() or name != name.lower() or name in KEYWORDS:
        raise _fail(path, f"field 'name': expected a lower-case identifier other than {KEYWORDS}, found {name!r}")
    if name != path.parent.name:
        raise _fail(path, f"field 'name': expected the folder's name {path.parent.name!r}, found {name!r}")
    if data.get("sex") not in SEXES:
        raise _fail(path, f"field 'sex': expected one of {SEXES}, found {data.get('sex')!r}")
    age = data.get("age")
    if not isinstance(age, int) or isinstance(age, bool) or not 18 <= age <= 100:
        raise _fail(path, f"field 'age': expected an integer 18..100, found {age!r}")
    if data.get("fitzpatrick") not in FITZPATRICK:
        raise _fail(path, f"field 'fitzpatrick': expected one of {FITZPATRICK}, found {data.get('fitzpatrick')!r}")
    seed = data.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise _fail(path, f"field 'seed': expected an integer, found {seed!r}")
    files = data.get("files")
    if not isinstance(files, dict) or HEAD_FILE not in files:
        raise _fail(path, f"field 'files': expected an object naming {HEAD_FILE!r} and the textures with their sha256")
    for fname, digest in files.items():
        if not isinstance(fname, str) or "/" in fname or "\\" in fname or not isinstance(digest, str) \
                or len(digest) != 64:
            raise _fail(path, f"field 'files': expected file name -> 64-hex sha256, found {fname!r}: {digest!r}")
    if not isinstance(data.get("licence"), dict):
        raise _fail(path, "field 'licence': expected an object naming the source and licence of every asset")
    _check_pain_gains(data.get("pain_gains", {}), path)
    return PatientInfo(name=name, sex=data["sex"], age=age, fitzpatrick=data["fitzpatrick"], seed=seed,
                       folder=path.parent, description=str(data.get("description", "")), files=dict(files), raw=data)


def _check_pain_gains(gains: Any, path: Path) -> None:
    """``patient.json``'s optional ``pain_gains``: AU name -> gain on the shared pain face's intensity of
    that AU (``flame.expressions.AUMap.pain_gains``), each in [1, ``PAIN_GAIN_MAX``]."""
    from ..flame.expressions import AU_NAMES, PAIN_GAIN_MAX

    if not isinstance(gains, dict):
        raise _fail(path, f"field 'pain_gains': expected an object AU name -> gain, found {type(gains).__name__}")
    for au, g in gains.items():
        ok = isinstance(g, (int, float)) and not isinstance(g, bool) and 1.0 <= float(g) <= PAIN_GAIN_MAX
        if au not in AU_NAMES or not ok:
            raise _fail(path, f"field 'pain_gains': expected an AU of {AU_NAMES[0]}..{AU_NAMES[-1]} -> a gain in "
                              f"[1, {PAIN_GAIN_MAX:g}], found {au!r}: {g!r}")


def _read_info(path: Path) -> PatientInfo:
    from ..fileio import read_json

    return parse_patient_json(read_json(path, AvatarError, "patient file"), path)


def list_patients(folder: str | Path | None = None) -> list[PatientInfo]:
    """Every patient under ``folder`` (default :func:`patients_dir`), sorted by name; a malformed
    ``patient.json`` raises (naming the file and field)."""
    root = patients_dir() if folder is None else Path(folder)
    if not root.is_dir():
        return []
    return [_read_info(p / INFO_FILE) for p in sorted(root.iterdir()) if (p / INFO_FILE).is_file()]


def patient_names(folder: str | Path | None = None) -> tuple[str, ...]:
    """The patients' names, sorted (``default`` is not among them)."""
    root = patients_dir() if folder is None else Path(folder)
    if not root.is_dir():
        return ()
    return tuple(p.name for p in sorted(root.iterdir()) if (p / INFO_FILE).is_file())


def patient_info(name: str, folder: str | Path | None = None) -> PatientInfo:
    """The :class:`PatientInfo` of ``name``; an unknown name is an InputError listing the valid ones."""
    root = patients_dir() if folder is None else Path(folder)
    if name not in patient_names(root):
        raise InputError(f"patient {name!r}: no such patient; expected one of {list(patient_names(root))}")
    return _read_info(root / name / INFO_FILE)


def check_files(info: PatientInfo) -> None:
    """Raise AvatarError when a file listed in ``patient.json`` is missing or has another sha256."""
    for fname, digest in info.files.items():
        p = info.folder / fname
        if not p.is_file():
            raise AvatarError(f"{info.folder / INFO_FILE}: lists {fname!r}, which is missing ({p})")
        got = file_sha256(p)
        if got != digest:
            raise AvatarError(f"{p}: sha256 {got[:16]}..., patient.json expects {digest[:16]}... "
                              "(rebuild with scripts/build_patients.py)")


@functools.lru_cache(maxsize=4)
def _model(head: str, mtime: float) -> Any:
    from ..flame.model import FlameModel

    model = FlameModel.load(head, n_shape=None, n_expr=None)
    # flame.head_textures.head_appearance reads the textures from here first
    model.metadata["appearance_dir"] = str(Path(head).parent)
    return model


def load_patient_model(name: str, folder: str | Path | None = None) -> Any:
    """The patient's head as a FlameModel (cached per process; its textures are found beside it, and its
    ``patient.json``'s ``pain_gains`` in ``metadata["pain_gains"]``, which ``flame.expressions.au_map_for``
    attaches to its AU map)."""
    info = patient_info(name, folder)
    if not info.head_path.is_file():
        raise AvatarError(f"patient {name!r}: {info.head_path} is missing (run scripts/build_patients.py)")
    model = _model(str(info.head_path), info.head_path.stat().st_mtime)
    model.metadata["pain_gains"] = {k: float(v) for k, v in dict(info.raw.get("pain_gains") or {}).items()}
    return model


def load_patient_avatar(name: str, folder: str | Path | None = None) -> Any:
    """The patient's fitted RiggedAvatar; AvatarError when it is not fitted yet or fitted to another head."""
    info = patient_info(name, folder)
    if not info.fitted:
        raise AvatarError(f"patient {name!r} is not fitted yet: {info.avatar_path} does not exist "
                          "(its head and textures are there: the mesh views work; fitting writes the avatar)")
    return _rigged_from_file(info.avatar_path, load_patient_model(name, folder), info.head_path)


def _rigged_from_file(path: Path, model: Any, head_path: Path) -> Any:
    import numpy as np

    from .default_gaussians import front_to_back, load_fitted_avatar
    from .rigged import RiggedAvatar

    local, binding, keys = load_fitted_avatar(path)
    head = file_sha256(head_path)
    if keys["head_sha256"] != head:
        raise AvatarError(f"{path}: fitted to another head (sha256 {keys['head_sha256'][:12]}...), "
                          f"{head_path} is {head[:12]}...; refit it")
    if keys["n_faces"] != int(model.faces.shape[0]) or (binding.size and binding.max() >= model.faces.shape[0]):
        raise AvatarError(f"{path}: binding does not fit {head_path} ({int(model.faces.shape[0])} faces)")
    region = local.extra.get("region", np.zeros(len(local), np.int16))
    av = RiggedAvatar(model, local.replace(extra={}), binding=binding)
    order = front_to_back(av)
    av = RiggedAvatar(model, local.replace(extra={}).subset(order), binding=np.asarray(binding)[order])
    av.region = np.asarray(region).astype(np.int64)[order]
    names = tuple(str(s) for s in model.metadata["region_names"])
    av.region_names = names if "teeth" in names else names + ("teeth",)
    av.fit_file = Path(path)  # the viewer's angle range reads fit_angle_range_deg from it (gui/sliders.py)
    return av


@dataclass
class Patient:
    """A loaded patient: ``info``, the head ``model`` and the fitted ``avatar`` (None: not fitted yet)."""

    info: PatientInfo
    model: Any
    avatar: Any | None


def load_patient(name: str, folder: str | Path | None = None, avatar: bool = True) -> Patient:
    """Head (+ textures) and, when fitted and ``avatar``, the fitted Gaussian avatar of ``name``."""
    info = patient_info(name, folder)
    model = load_patient_model(name, folder)
    av = load_patient_avatar(name, folder) if (avatar and info.fitted) else None
    return Patient(info=info, model=model, avatar=av)


# ------------------------------------------------------------------------------ --avatar
@dataclass(frozen=True)
class AvatarChoice:
    """What ``--avatar`` named: ``kind`` is 'default', 'none', 'patient', 'ply' or 'npz'."""

    kind: str
    name: str
    path: Path | None = None

    def __str__(self) -> str:  # what argparse shows and the manifests store
        return str(self.path) if self.kind in ("ply", "npz") else self.name


def avatar_spec_help() -> str:
    names = "|".join(patient_names())
    return f"default|none|{names}|PLY|NPZ" if names else "default|none|PLY|NPZ"


def resolve_avatar(spec: str | Path | AvatarChoice | None, folder: str | Path | None = None) -> AvatarChoice:
    """``default`` (the embedded head and its avatar), ``none`` (mesh only), a patient's name, or an
    existing ``.ply`` (3DGS / GaussianAvatars) or ``.npz`` (a fitted avatar file). Cheap: reads no avatar.

    Raises
    ------
    InputError
        Anything else, naming what was given and listing the valid names.
    """
    if isinstance(spec, AvatarChoice):
        return spec
    s = "default" if spec is None else str(spec)
    low = s.lower()
    if low in KEYWORDS:
        return AvatarChoice(low, low)
    names = patient_names(folder)
    if low in names:
        root = patients_dir() if folder is None else Path(folder)
        return AvatarChoice("patient", low, root / low)
    p = Path(s)
    suffix = p.suffix.lower()
    valid = f"expected 'default', 'none', a patient ({', '.join(names) or 'none shipped'}) or a .ply / .npz file"
    if suffix in (".ply", ".npz"):
        if not p.is_file():
            raise InputError(f"--avatar {s}: file not found ({valid})")
        return AvatarChoice(suffix[1:], p.name, p)
    raise InputError(f"--avatar {s!r}: not a patient nor a file; {valid}")


def head_for_avatar_file(path: str | Path, folder: str | Path | None = None) -> tuple[Any, Path]:
    """(head model, head path) an avatar ``.npz`` was fitted to: the default head or a patient's head,
    found by the sha256 stored in the file."""
    from ..flame.default_head import default_head_path, load_default_model
    from .default_gaussians import load_fitted_avatar

    _, _, keys = load_fitted_avatar(path)
    want = keys["head_sha256"]
    if file_sha256(default_head_path()) == want:
        return load_default_model(add_teeth=True), default_head_path()
    for info in list_patients(folder):
        if info.head_path.is_file() and file_sha256(info.head_path) == want:
            return load_patient_model(info.name, folder), info.head_path
    raise AvatarError(f"{path}: fitted to a head with sha256 {want[:12]}..., which is neither the default head "
                      f"nor a patient's ({list(patient_names(folder))})")


def load_avatar_file(path: str | Path, folder: str | Path | None = None) -> Any:
    """The RiggedAvatar of a fitted avatar ``.npz`` on whichever shipped head it was fitted to."""
    model, head = head_for_avatar_file(path, folder)
    return _rigged_from_file(Path(path), model, head)


def patient_summary(info: PatientInfo) -> dict[str, Any]:
    """One row of ``holo-viewer patients``: name, sex, age, skin type, MB, fitted fidelity (None: unknown)."""
    psnr = None
    if info.fitted:
        try:
            from .default_gaussians import load_fitted_avatar

            psnr = load_fitted_avatar(info.avatar_path)[2]["info"].get("psnr_min_db")
        except AvatarError:
            psnr = None
    return {"name": info.name, "sex": info.sex, "age": info.age, "fitzpatrick": info.fitzpatrick,
            "size_mb": round(info.size_bytes() / 1e6, 2), "fitted": info.fitted, "psnr_min_db": psnr,
            "description": info.description}


def dumps_summary(rows: list[dict[str, Any]]) -> str:
    return json.dumps(rows, indent=1)


def load_choice(spec: str | AvatarChoice | None, need_gaussians: bool = False) -> tuple[Any, Any, str, str]:
    """(head model, rigged avatar or False, description, name) for ``default``, ``none``, a patient or a
    fitted ``.npz`` (PLY avatars are loaded by ``pipeline.load_scene``). ``need_gaussians``: a patient
    that is not fitted yet is an AvatarError instead of its mesh alone."""
    choice = resolve_avatar(spec)
    if choice.kind == "default":
        from .default_gaussians import default_avatar

        av = default_avatar()
        return av.flame_model, av, f"default head + default avatar ({len(av)} Gaussians)", "default"
    if choice.kind == "none":
        from ..flame.default_head import load_default_model

        return load_default_model(), False, "FLAME mesh only", "none"
    if choice.kind == "patient":
        info = patient_info(choice.name)
        who = f"patient {info.name} ({info.sex}, {info.age}, type {info.fitzpatrick})"
        if not info.fitted:
            if need_gaussians:
                load_patient_avatar(info.name)  # raises: not fitted yet
            return load_patient_model(info.name), False, f"{who}: not fitted yet, mesh only", info.name
        av = load_patient_avatar(info.name)
        return av.flame_model, av, f"{who}, {len(av)} Gaussians", info.name
    if choice.kind == "npz":
        av = load_avatar_file(choice.path)
        return av.flame_model, av, f"fitted avatar {choice.path.name} ({len(av)} Gaussians)", str(choice.path)
    raise InputError(f"--avatar {choice}: a PLY avatar is loaded by the scene loader, not here")
