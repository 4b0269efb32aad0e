"""FLAME head model: LBS in torch, chumpy-free file I/O, the embedded default head, expressions.

Exports (torch is imported only when one of them is first used)::

    FlameModel, FlameOutput          holo_viewer.flame.model
    load_flame_arrays, save_flame_npz holo_viewer.flame.io
    rodrigues                         holo_viewer.geometry (all rotations live there)

``default_head`` and ``expressions`` are submodules; import them directly
(``from holo_viewer.flame import expressions``).
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["FlameModel", "FlameOutput", "load_flame_arrays", "save_flame_npz", "validate_flame_arrays",
           "rodrigues", "load_default_model"]

_EXPORTS = {
    "FlameModel": "model",
    "FlameOutput": "model",
    "load_flame_arrays": "io",
    "save_flame_npz": "io",
    "validate_flame_arrays": "io",
    "rodrigues": "..geometry",
    "load_default_model": "default_head",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'holo_viewer.flame' has no attribute {name!r}")
    target = "holo_viewer.geometry" if module == "..geometry" else f"{__name__}.{module}"
    value = getattr(importlib.import_module(target), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
