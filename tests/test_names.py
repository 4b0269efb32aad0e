"""One name, one thing: no public class is defined twice in holo_viewer/, and a module basename repeats
only where it names the same role in different packages (listed here with the role)."""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "holo_viewer"

#: basename -> the role every module of that name plays in its own package
SAME_ROLE = {
    "api.py": "the package's public entry functions (render.api, reaction.api)",
    "model.py": "the package's model (flame.model: the head; reaction.model: the reaction generator)",
    "live.py": "the live frame: commands/ its subcommand, pipeline/ its native-frame renderer",
    "replay.py": "replay of a recorded live session: commands/ its subcommand, live/ the replay itself",
    "report.py": "a recorded session's debrief: commands/ its subcommand, live/ the report itself",
    "scene.py": "the scene shown: pipeline/ loads it from files, gui/ draws it",
    "viewer.py": "an interactive window: gui/ the hologram viewer, tracking/ the tracker's webcam viewer",
    "video.py": "video frames of the package: tracking/ reads webcam/video input, batch/ writes render-batch videos",
    "speech.py": "speech features from the microphone: reaction/ the model's prosody, behaviour/ its pause gate",
    "patients.py": "the ward (docs/patients.md): avatar/ its registry, assets_build/ its recipes, commands/ the listing",
}


@functools.lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"))


def public_classes(root: Path = PKG) -> dict[str, list[str]]:
    """Public class name -> the modules (paths relative to ``root``'s parent) that define it at top level."""
    out: dict[str, list[str]] = defaultdict(list)
    for path in sorted(root.rglob("*.py")):
        for node in _tree(path).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                out[node.name].append(str(path.relative_to(root.parent)))
    return out


def basenames(root: Path = PKG) -> dict[str, list[str]]:
    out: dict[str, list[str]] = defaultdict(list)
    for path in sorted(root.rglob("*.py")):
        if path.name != "__init__.py":
            out[path.name].append(str(path.relative_to(root.parent)))
    return out


def test_no_public_class_name_is_defined_twice():
    twice = {name: where for name, where in public_classes().items() if len(where) > 1}
    assert twice == {}, f"public classes defined more than once (name them by role): {twice}"


def test_module_basenames_repeat_only_for_one_role():
    repeated = {name: where for name, where in basenames().items() if len(where) > 1}
    unlisted = {name: where for name, where in repeated.items() if name not in SAME_ROLE}
    assert unlisted == {}, f"module basenames used twice for different things (rename, or list the role): {unlisted}"


def test_the_checks_can_fail(tmp_path):
    """A planted duplicate class and a planted basename are caught."""
    pkg = tmp_path / "holo_viewer"
    for sub in ("a", "b"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "jobs.py").write_text("class LiveRenderer:\n    pass\n\nclass _Private:\n    pass\n")
    assert public_classes(pkg) == {"LiveRenderer": ["holo_viewer/a/jobs.py", "holo_viewer/b/jobs.py"]}
    assert basenames(pkg) == {"jobs.py": ["holo_viewer/a/jobs.py", "holo_viewer/b/jobs.py"]}


#: helpers written once in the package (tests and bench import them): name -> (the module that defines
#: it, the call that gives an implementation away: a PSNR takes a log10, vertex normals a cross product)
ONE_OF_EACH = {"vertex_normals": ("holo_viewer/geometry.py", "cross"), "psnr": ("holo_viewer/images.py", "log10")}


def _calls(node: ast.AST) -> set[str]:
    return {c.func.attr if isinstance(c.func, ast.Attribute) else getattr(c.func, "id", "")
            for c in ast.walk(node) if isinstance(c, ast.Call)}


def implementations(word: str, tell: str, root: Path = PKG) -> list[str]:
    """Modules with a function (or method) named like ``word`` that computes it itself (calls ``tell``);
    functions built on the one (e.g. ``eyes.head_psnr`` calling ``psnr``) do not count."""
    out = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(_tree(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and word in node.name.lower() \
                    and tell in _calls(node):
                out.append(str(path.relative_to(root.parent)))
    return out


@pytest.mark.slow
def test_shared_helpers_are_defined_once(tmp_path):
    for word, (where, tell) in ONE_OF_EACH.items():
        assert implementations(word, tell) == [where], f"a second {word} implementation: use {where}'s"
    bad = tmp_path / "holo_viewer" / "x.py"  # the check can fail: a private copy is found
    bad.parent.mkdir()
    bad.write_text("import math\ndef _masked_psnr(a, b):\n    return 10 * math.log10(1 / ((a - b) ** 2))\n")
    assert implementations("psnr", "log10", bad.parent) == ["holo_viewer/x.py"]


def test_vertex_normals_and_psnr():
    import numpy as np

    from holo_viewer.errors import InputError
    from holo_viewer.geometry import vertex_normals
    from holo_viewer.images import psnr

    # an octahedron (+ one unused vertex): by symmetry each normal is the vertex direction
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [5, 5, 5]], np.float32)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    n = vertex_normals(v, f)
    assert n.dtype == np.float64
    np.testing.assert_allclose(n[:6], v[:6], atol=1e-15)
    assert not n[6].any()  # unused: zero
    a = np.zeros((4, 4, 3))
    b = a.copy()
    b[0, 0] = 0.1  # MSE 0.01 over the masked pixel -> 20 dB
    b[3, 3] = 1.0
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True
    assert psnr(a, b, mask=mask) == pytest.approx(20.0)
    assert psnr(a, b) == pytest.approx(10 * np.log10(48 / 3.03))  # (3 x 0.01 + 3 x 1) / 48
    assert psnr(a, a) == float("inf")
    with pytest.raises(InputError, match="mask"):
        psnr(a, b, mask=np.zeros((4, 4), bool))
    with pytest.raises(InputError, match="shape"):
        psnr(a, b[:2])


_SHADOW_CHECK = r"""
import importlib, pkgutil, types
import holo_viewer

# 1. no package exports a name that is both one of its submodules and something else (fresh interpreter:
#    the lazy attribute resolves first, as in `from holo_viewer.avatar import default_avatar`)
both = []
for info in pkgutil.iter_modules(holo_viewer.__path__):
    if not info.ispkg:
        continue
    pkg = importlib.import_module(f"holo_viewer.{info.name}")
    subs = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
    for name in set(getattr(pkg, "__all__", ())) & subs:
        obj = getattr(pkg, name, None)
        if obj is not None and not isinstance(obj, types.ModuleType):
            both.append(f"{pkg.__name__}.{name}")
# 2. docs/avatar.md's example after the module the pipeline imports was imported
importlib.import_module("holo_viewer.avatar.default_gaussians")
from holo_viewer.avatar import default_avatar
print(both, callable(default_avatar) and not isinstance(default_avatar, types.ModuleType))
"""


def test_no_package_name_is_both_a_submodule_and_a_function():
    """``holo_viewer.avatar.default_avatar`` was the function and its submodule: after ``Pipeline()``
    imported the submodule, ``from holo_viewer.avatar import default_avatar`` gave the module."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _SHADOW_CHECK], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["[]", "True"], out.stdout
