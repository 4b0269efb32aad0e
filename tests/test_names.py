"""One name, one thing: no public class is defined twice in holo_viewer/, and a module basename repeats
only where it names the same role in different packages (listed here with the role)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "holo_viewer"

#: basename -> the role every module of that name plays in its own package
SAME_ROLE = {
    "api.py": "the package's public entry functions (render.api, reaction.api)",
    "model.py": "the package's model (flame.model: the head; reaction.model: the reaction generator)",
    "live.py": "the live frame: commands/ its subcommand, pipeline/ its native-frame renderer",
    "replay.py": "replay of a recorded live session: commands/ its subcommand, live/ the replay itself",
    "scene.py": "the scene shown: pipeline/ loads it from files, gui/ draws it",
    "viewer.py": "an interactive window: gui/ the hologram viewer, tracking/ the tracker's webcam viewer",
    "video.py": "video frames of the package: tracking/ reads webcam/video input, batch/ writes render-batch videos",
    "speech.py": "speech features from the microphone: reaction/ the model's prosody, behaviour/ its pause gate",
}


def public_classes(root: Path = PKG) -> dict[str, list[str]]:
    """Public class name -> the modules (paths relative to ``root``'s parent) that define it at top level."""
    out: dict[str, list[str]] = defaultdict(list)
    for path in sorted(root.rglob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
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
