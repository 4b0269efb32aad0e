"""The avatar option shared by ``demo``, ``view``, ``snapshot``, ``live`` and ``export-mesh``.

One spelling, ``--avatar default|none|NAME|PLY|NPZ`` (``args.avatar``, a string), checked when the
command line is parsed: an unknown name or a missing file exits with status 2 and the valid names,
before any model or avatar loads (:func:`holo_viewer.avatar.patients.resolve_avatar`; it reads only
the patients' ``patient.json`` files). Each command states which kinds it takes (``export-mesh``
writes a head, so no PLY; ``demo`` and ``live`` render Gaussians, so no ``none``).
"""

from __future__ import annotations

import argparse
from typing import Any, Callable, Sequence

__all__ = ["add_avatar_argument", "avatar_type", "ALL_KINDS"]

ALL_KINDS = ("default", "none", "patient", "ply", "npz")
_WHAT = {"default": "default", "none": "none", "patient": "a patient's name", "ply": "a .ply", "npz": "a fitted .npz"}


def avatar_type(kinds: Sequence[str] = ALL_KINDS, fitted: bool = False) -> Callable[[str], str]:
    """An argparse ``type`` accepting the ``kinds`` of :func:`~holo_viewer.avatar.patients.resolve_avatar`;
    ``fitted``: a patient must have its fitted avatar (the commands that render Gaussians)."""

    def parse(text: str) -> str:
        from ..avatar.patients import patient_names, resolve_avatar
        from ..errors import HoloViewerError

        try:
            choice = resolve_avatar(text)
        except HoloViewerError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if choice.kind not in kinds:
            takes = ", ".join(_WHAT[k] for k in kinds)
            names = ", ".join(patient_names()) or "none shipped"
            what = "" if choice.kind in ("default", "none") else f" ({_WHAT[choice.kind]})"
            raise argparse.ArgumentTypeError(f"{text!r}{what} is not taken here; expected {takes} "
                                             f"(patients: {names})")
        if fitted and choice.kind == "patient":
            from ..avatar.patients import patient_info

            info = patient_info(choice.name)
            if not info.fitted:
                raise argparse.ArgumentTypeError(f"patient {choice.name!r} is not fitted yet ({info.avatar_path} does "
                                                 "not exist); this command renders its Gaussians")
        return str(choice.path) if choice.kind in ("ply", "npz") else choice.name

    parse.__name__ = "avatar"  # argparse's "invalid avatar value" message
    return parse


def add_avatar_argument(parser: Any, *, kinds: Sequence[str] = ALL_KINDS, default: str = "default",
                        help: str = "", fitted: bool = False) -> None:
    """Add ``--avatar`` (``args.avatar``) taking ``kinds``, validated at parse time (``fitted``: see
    :func:`avatar_type`)."""
    parts = {"default": "default (the embedded head and its avatar)", "none": "none (the mesh only)",
             "patient": "NAME (a patient: holo-viewer patients)", "ply": "a 3DGS / GaussianAvatars PLY",
             "npz": "a fitted avatar .npz"}
    meta = "|".join({"default": "default", "none": "none", "patient": "NAME", "ply": "PLY", "npz": "NPZ"}[k]
                    for k in kinds)
    parser.add_argument("--avatar", type=avatar_type(kinds, fitted), default=default, metavar=meta,
                        help=(help + ": " if help else "") + ", ".join(parts[k] for k in kinds)
                        + f" (default {default})")
