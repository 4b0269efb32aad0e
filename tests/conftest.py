"""Shared test fixtures, and the repository root on ``sys.path`` for ``from bench.scenes import ...``.

The small random objects come from :mod:`holo_viewer.testing`; every fixture here is cheap.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # bench/ is a folder of scripts, not an installed package
    sys.path.insert(0, str(ROOT))


@pytest.fixture(scope="module")
def small_model():
    """A random 300-vertex FLAME-format model (8 shape, 6 expression components)."""
    from holo_viewer.testing import random_flame_model

    return random_flame_model(n_vertices=300, n_shape=8, n_expr=6, seed=1)


@pytest.fixture()
def small_avatar(small_model):
    """400 random Gaussians rigged to ``small_model``."""
    from holo_viewer.testing import random_rigged_avatar

    return random_rigged_avatar(small_model, n=400)
