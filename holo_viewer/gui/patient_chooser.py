"""The viewer's patient chooser: step the shown avatar through ``default`` and the shipped patients.

:func:`cycle_patient` loads the next (or previous) patient through the pipeline's avatar loader and
hands it to the viewer's avatar hook, ``HoloViewer.set_avatar(avatar, model)`` (which rebuilds the
mesh, splats, cameras, previews and thumbnail and keeps the face sliders). A patient that is not
fitted yet is shown as its textured mesh alone. Keys: ``P`` (shift-p) forward and ``O`` backward,
added to the viewer's key map by :func:`bind_patient_keys` (``holo-viewer view`` does; ``p`` itself
cycles the image panel).
"""

from __future__ import annotations

from typing import Any

__all__ = ["patient_cycle", "next_patient", "cycle_patient", "bind_patient_keys", "PATIENT_KEYS"]

#: key -> step through :func:`patient_cycle`
PATIENT_KEYS = {"P": 1, "O": -1}


def patient_cycle() -> tuple[str, ...]:
    """``default`` then the patients' names, sorted."""
    from ..avatar.patients import patient_names

    return ("default",) + patient_names()


def next_patient(current: str, step: int = 1, names: tuple[str, ...] | None = None) -> str:
    """The name ``step`` places after ``current`` in ``names`` (default :func:`patient_cycle`), wrapping;
    an unknown ``current`` (a PLY, ``none``) starts from ``default``."""
    names = patient_cycle() if names is None else tuple(names)
    if current not in names:
        return names[0] if step > 0 else names[-1]
    return names[(names.index(current) + int(step)) % len(names)]


def cycle_patient(viewer: Any, step: int = 1) -> str:
    """Show the next patient in ``viewer`` (through ``viewer.set_avatar``); returns its name and leaves
    a one-line description in ``viewer.patient_description``."""
    from ..pipeline.scene import load_avatar

    name = next_patient(getattr(viewer, "patient_name", "default"), step)
    model, avatar, desc, name = load_avatar(name)
    viewer.set_avatar(avatar if avatar is not False else None, model)
    viewer.patient_name = name
    viewer.patient_description = desc
    if hasattr(viewer, "_message"):
        viewer._message = desc
    return name


def bind_patient_keys(viewer: Any) -> None:
    """Add :data:`PATIENT_KEYS` to the viewer's key map (``KeysMixin._key_actions``), so they go through
    its own key handling: ignored while a value is typed, errors shown in the window."""
    own = viewer._key_actions

    def actions() -> dict:
        out = dict(own())
        out.update({key: (lambda s=step: cycle_patient(viewer, s)) for key, step in PATIENT_KEYS.items()})
        return out

    viewer._key_actions = actions
