"""Build a :class:`~holo_viewer.pipeline.Pipeline` from files (the inputs of ``view``, ``snapshot``
and ``apps/stream_sequence.py``); headless, below the GUI.

``--avatar``: ``default`` (the embedded default head and its Gaussian avatar), ``none``
(mesh only), a patient's name (docs/patients.md: its head and fitted avatar, or its head alone
until it is fitted), a fitted avatar ``.npz`` (on the head it was fitted to), or a PLY: a
GaussianAvatars ``point_cloud.ply`` (local Gaussians + ``binding_0``, rigged to the FLAME model) or a plain 3DGS PLY (world Gaussians, shown as they are: they do
not follow the sliders). ``--flame-model``: a FLAME ``.pkl`` / ``.npz`` (default: the embedded
head). ``--flame-params``: a ``flame_param.npz`` sequence (frame 0 is shown first).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from .avatars import StaticAvatar
from .core import Pipeline
from .settings import FaceControls, flame_sequence_frames

__all__ = ["Scene", "load_scene", "StaticAvatar", "load_avatar", "is_patient", "patient_files"]


def load_avatar(spec: str, need_gaussians: bool = False) -> tuple[Any, Any, str, str]:
    """(model, avatar or False, description, name) of ``default``, ``none``, a patient or a fitted .npz
    (:func:`holo_viewer.avatar.patients.load_choice`), for the callers above the pipeline."""
    from ..avatar.patients import load_choice

    return load_choice(spec, need_gaussians=need_gaussians)


def is_patient(name: str) -> bool:
    """Whether ``name`` is a shipped patient's name."""
    from ..avatar.patients import patient_names

    return str(name) in patient_names()


def patient_files(name: str) -> tuple[bool, list[Path]]:
    """(fitted, every file of the patient's folder): what a job on the patient reads."""
    from ..avatar.patients import patient_info

    info = patient_info(name)
    return info.fitted, sorted(p for p in info.folder.iterdir() if p.is_file())


@dataclass
class Scene:
    """What ``holo-viewer view`` / ``snapshot`` show: a pipeline and, optionally, a FLAME sequence."""

    pipeline: Pipeline
    frames: list[dict[str, np.ndarray]] | None
    description: str


def load_scene(avatar: str | os.PathLike | None = "default", flame_model: str | os.PathLike | None = None,
               flame_params: str | os.PathLike | None = None, calibration: str | os.PathLike | None = None,
               backend: str = "fast", face: FaceControls | None = None) -> Scene:
    """Load the model, avatar, parameters and calibration; return a ready pipeline.

    Raises
    ------
    InputError, FlameError, AvatarError, PlyError, CalibrationError
        Naming the file and what is wrong with it.
    """
    from ..display.calibration import DisplayCalibration

    cal = DisplayCalibration.load(calibration)
    spec = "default" if avatar is None else str(avatar)
    from ..avatar.patients import load_choice, patient_names

    if spec.lower() in patient_names() or spec.lower().endswith(".npz"):  # a patient, a fitted avatar file
        if flame_model is not None:
            raise InputError(f"--avatar {spec}: bound to its own head; --flame-model goes with --avatar none or a PLY")
        model, av, desc, _ = load_choice(spec)
        return _scene(model, av, cal, backend, face, flame_params, None, desc)
    is_ply = spec.lower() not in ("default", "none")
    rigged_ply = False
    if is_ply:
        ply = Path(spec)
        if not ply.exists():
            raise InputError(f"--avatar {ply}: file not found (expected 'default', 'none' or a PLY path)")
        from ..avatar.ply import read_ply_header

        read_ply_header(ply)  # a clear PlyError for a file that is not a PLY
        rigged_ply = _ply_has_binding(ply)
    model = None
    if flame_model is not None:
        from ..flame.model import FlameModel

        path = Path(flame_model)
        if not path.exists():
            raise InputError(f"--flame-model {path}: file not found")
        # GaussianAvatars binds its Gaussians to FLAME with teeth; the mesh alone does not need them
        model = FlameModel.load(path, add_teeth=rigged_ply)

    params = None
    if spec.lower() == "default":
        if model is not None:
            raise InputError("--avatar default: the default avatar is bound to the embedded default head; with "
                             "--flame-model pass --avatar none (mesh only) or your GaussianAvatars PLY")
        from ..avatar.default_gaussians import default_avatar

        av = default_avatar()
        model = av.flame_model
        desc = f"default head + default avatar ({len(av)} Gaussians)"
    elif spec.lower() == "none":
        if model is None:
            from ..flame.default_head import load_default_model

            model = load_default_model()
        av = False
        desc = "FLAME mesh only"
    else:
        ply = Path(spec)
        if rigged_ply:
            from ..avatar import load_gaussian_avatar

            av, params = load_gaussian_avatar(ply, flame_params, flame_model=model)
            model = av.flame_model
            desc = f"GaussianAvatars avatar {ply.name} ({len(av)} Gaussians)"
        else:
            from ..avatar import load_ply

            av = StaticAvatar(load_ply(ply))
            if model is None:
                from ..flame.default_head import load_default_model

                model = load_default_model()
            desc = f"static 3DGS {ply.name} ({len(av)} Gaussians; not rigged: sliders move the mesh only)"

    return _scene(model, av, cal, backend, face, flame_params, params, desc)


def _scene(model: Any, av: Any, cal: Any, backend: str, face: FaceControls | None, flame_params: Any, params: Any,
           desc: str) -> Scene:
    frames = None
    if flame_params is not None:
        if params is None:
            from ..avatar import load_flame_params

            params = load_flame_params(flame_params)
        frames = flame_sequence_frames(params, source=str(flame_params))
    pipe = Pipeline(model=model, avatar=av, calibration=cal, backend=backend, face=face)
    if frames:
        pipe.set_face(_first_frame(pipe.face, frames[0]))
    return Scene(pipeline=pipe, frames=frames, description=desc)


def _ply_has_binding(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    return b"binding_0" in (head[:end] if end >= 0 else head)


def _first_frame(face: FaceControls, frame: dict[str, np.ndarray]) -> FaceControls:
    changes = {k: (np.asarray(v) if k == "dynamic_offset" else np.asarray(v).reshape(-1)) for k, v in frame.items()}
    return face.replace(**changes)
