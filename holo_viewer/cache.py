"""The one cache-directory helper, and the bounded in-process store the per-process caches share.

Files the package generates once and reuses (the default avatar's local Gaussians, a default
head rebuilt for a stripped checkout) go to :func:`cache_dir`:

1. ``$HOLO_VIEWER_CACHE`` when set (CI, read-only home directories, per-experiment caches);
2. else ``$XDG_CACHE_HOME/holo_viewer``;
3. else ``~/.cache/holo_viewer``.

Nothing is created here; writers create the folder (atomically written files, ``fileio``).
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir", "keep_recent", "ENV_VAR"]

#: environment variable that overrides the cache folder
ENV_VAR = "HOLO_VIEWER_CACHE"


def cache_dir() -> Path:
    """The folder for holo_viewer's generated files (see the module docstring for the order)."""
    root = os.environ.get(ENV_VAR)
    if root:
        return Path(root)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "holo_viewer"


def keep_recent(store: dict, key: object, value: object, n: int) -> object:
    """Put ``value`` in ``store`` as its most recently used entry and drop the oldest beyond ``n``; returns ``value``.

    The per-process caches (loaded models, interleave tables, table files, synthetic speakers) keep their last
    few entries this way, oldest first in the dict's order."""
    store.pop(key, None)
    store[key] = value
    while len(store) > n:
        store.pop(next(iter(store)))
    return value
