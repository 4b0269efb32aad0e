"""The layering of docs/design.md section 2, checked on the imports (module level and lazy ones).

::

    entry      cli, __main__                      -> commands (lazily), base
    front      commands/, gui/, batch/, live/, apps/  -> pipeline, stage packages, base (apps: never gui/)
    build      assets_build/                      -> pipeline, stage packages, base (makes the shipped assets)
    pipeline   pipeline/, testing.py              -> stage packages, base
    stages     flame/ avatar/ render/ display/ reaction/ tracking/ behaviour/  -> base (+ the edges in STAGE_EDGES)
    base       errors validation fileio media geometry camera images (_uint8: its compiled pass) cache offscreen

No import runs back up the layers, and only ``pipeline/`` chains the stages: no other module
imports both a face stage (``reaction``, ``flame``, the avatar rigs) and the renderer, or both
the reaction model and the face (benchmarks and tests measure stages one by one and are exempt).
Build-time code (``assets_build/``) is imported by nothing below it but the lazy fallbacks in
``REBUILD_FALLBACKS``, which rebuild a missing or stale asset on first use.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "holo_viewer"

BASE = {"errors", "validation", "fileio", "media", "geometry", "camera", "images", "_uint8", "cache", "offscreen",
        "__init__"}
STAGE_PKGS = {"flame", "avatar", "render", "display", "reaction", "tracking", "behaviour"}
#: stage -> stages it may import: the rigged avatar is bound to FLAME triangles, the reaction model
#: speaks FLAME expressions (AU map), the renderer reads the Gaussians container, and the face tracker
#: fits the FLAME head to landmarks and reports the reaction model's face states
STAGE_EDGES = {"avatar": {"flame"}, "reaction": {"flame"}, "render": {"avatar"}, "flame": set(), "display": set(),
               "tracking": {"flame", "reaction"}, "behaviour": {"flame"}}
#: avatar modules that are plain data / I/O of Gaussians, not the avatar stage (the renderer's input type)
AVATAR_DATA = {"holo_viewer.avatar.gaussians", "holo_viewer.avatar.ply"}
AVATAR_DATA_NAMES = {"Gaussians", "SH_C0", "sh_degree_from_count", "load_ply", "save_ply"}
#: run-time module -> build modules it may import lazily: rebuild a missing head, paint textures a rebuilt head lacks
REBUILD_FALLBACKS = {"holo_viewer.flame.default_head": {"holo_viewer.assets_build.head"},
                     "holo_viewer.flame.head_textures": {"holo_viewer.assets_build.texture_painter"}}


def _modname(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path, mod: str | None = None) -> set[tuple[str, str]]:
    """(module, name) pairs of every holo_viewer import in ``path``, lazy ones included."""
    mod = mod or _modname(path)
    pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out: set[tuple[str, str]] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "holo_viewer" or target.startswith("holo_viewer."):
                for alias in node.names:
                    out.add((target, alias.name))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("holo_viewer"):
                    out.add((alias.name, ""))
    return out


def _area(module: str, name: str = "") -> str:
    """Top-level area of a holo_viewer module: 'flame', 'pipeline', 'cli', 'errors', ..."""
    parts = module.split(".")
    if parts[0] != "holo_viewer":
        return parts[0]
    if len(parts) == 1 and not name:  # holo_viewer/__init__.py itself
        return "__init__"
    if len(parts) == 1:  # ``from holo_viewer import X``: X is a subpackage or an __init__ name
        return name if (PKG / name).is_dir() or (PKG / f"{name}.py").exists() else "__init__"
    return parts[1]


#: the layers above the stages and their areas (testing.py builds small stage objects for tests)
UPPER_LAYERS = {"pipeline": {"pipeline", "testing"}, "build": {"assets_build"},
                "front": {"gui", "commands", "batch", "live", "apps"}, "entry": {"cli", "__main__"}}


def _layer(area: str) -> str:
    if area in BASE:
        return "base"
    if area in STAGE_PKGS:
        return "stages"
    for layer, areas in UPPER_LAYERS.items():
        if area in areas:
            return layer
    raise AssertionError(f"module area {area!r} is in no layer: add it to tests/test_architecture.py and "
                         "docs/design.md section 2")


ORDER = {"base": 0, "stages": 1, "pipeline": 2, "build": 3, "front": 4, "entry": 5}


def _sources() -> list[Path]:
    return sorted(PKG.rglob("*.py")) + sorted((ROOT / "apps").glob("*.py"))


def _is_face(module: str, name: str) -> bool:
    area = _area(module, name)
    if area in ("flame", "reaction"):
        return True
    if area == "avatar":
        return module not in AVATAR_DATA and not (module == "holo_viewer.avatar" and name in AVATAR_DATA_NAMES)
    return False


GRAPH = {_modname(p): _imports(p) for p in _sources()}


def test_every_module_is_in_a_layer():
    for mod in GRAPH:
        _layer("apps" if mod.startswith("apps") else _area(mod))


def _failures(check, modules) -> list[str]:
    """The AssertionError messages of ``check(mod)`` over ``modules`` (one test checks every module and lists
    each offender, instead of one collected test per module)."""
    out = []
    for mod in modules:
        try:
            check(mod)
        except AssertionError as exc:
            out.append(str(exc).splitlines()[0])
    return out


def test_no_import_runs_back_up_the_layers():
    assert len(GRAPH) > 100  # every module of the package and apps/ is checked
    assert _failures(_check_layers, sorted(GRAPH)) == []


def _check_layers(mod: str) -> None:
    src_area = "apps" if mod.startswith("apps") else _area(mod)
    src = _layer(src_area)
    for target, name in sorted(GRAPH[mod]):
        area = _area(target, name)
        if area == src_area:
            continue
        dst = _layer(area)
        if dst == "build" and src != "build":
            assert target in REBUILD_FALLBACKS.get(mod, set()), (
                f"{mod} imports build-time code {target}: run-time code imports assets_build/ only in the "
                "REBUILD_FALLBACKS")
            continue
        if src == "entry":
            assert area in BASE | {"commands", "cli"}, f"{mod} imports {target} (the CLI dispatches to commands/)"
            continue
        assert ORDER[dst] <= ORDER[src], f"{mod} ({src}) imports {target} ({dst}): an import back up the layers"
        if src == "stages" and dst == "stages":
            assert area in STAGE_EDGES[src_area], (
                f"{mod} imports {target}: stage package {src_area} may import only {sorted(STAGE_EDGES[src_area])} "
                "of the other stages; chain stages in holo_viewer/pipeline/")
        if src == "front" and dst == "front":
            assert not (src_area == "apps" and area == "gui"), f"{mod} imports {target}: apps/ are headless, no gui/"
            assert not (src_area == "gui" and area == "commands"), f"{mod} imports {target}: gui/ uses no commands/"
            assert not (src_area == "batch" and area in ("gui", "commands")), (
                f"{mod} imports {target}: batch/ is headless and below the commands")


def _chain_violations(mod: str, imports: set[tuple[str, str]]) -> list[str]:
    """Why ``mod`` (outside the pipeline and the stage packages) chains stages; empty if it does not."""
    face = sorted(t for t, n in imports if _is_face(t, n))
    render = sorted(t for t, n in imports if _area(t, n) == "render")
    reaction = sorted(t for t, n in imports if _area(t, n) == "reaction")
    face_not_reaction = sorted(t for t, n in imports if _is_face(t, n) and _area(t, n) != "reaction")
    out = []
    if face and render:
        out.append(f"{mod} imports a face stage {face} and the renderer {render}: ask holo_viewer.pipeline "
                   "(Pipeline, render_quilt) instead")
    if reaction and face_not_reaction:
        out.append(f"{mod} imports the reaction model {reaction} and the face {face_not_reaction}: use "
                   "holo_viewer.pipeline.reactions")
    return out


def test_only_the_pipeline_chains_the_stages():
    mods = sorted(m for m in GRAPH if not m.startswith(("holo_viewer.pipeline", "holo_viewer.assets_build")))
    assert _failures(_check_chains, mods) == []


def _check_chains(mod: str) -> None:
    src_area = "apps" if mod.startswith("apps") else _area(mod)
    if src_area in STAGE_PKGS:
        return  # stage packages are held to STAGE_EDGES above
    assert _chain_violations(mod, GRAPH[mod]) == []


def test_the_checker_sees_lazy_imports_and_catches_a_chain(tmp_path):
    """The rule above can fail: a command with lazy renderer + FLAME (or reaction + avatar) imports is caught."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from ..render.api import render_views\n    from ..flame.model import FlameModel\n")
    assert len(_chain_violations("holo_viewer.commands.bad", _imports(bad, "holo_viewer.commands.bad"))) == 1
    bad.write_text("import holo_viewer.reaction.api\nfrom holo_viewer.avatar import default_avatar\n")
    assert len(_chain_violations("apps.bad", _imports(bad, "apps.bad"))) == 1
    bad.write_text("from holo_viewer.avatar import Gaussians\nfrom holo_viewer.render import api\n")
    assert _chain_violations("apps.bad", _imports(bad, "apps.bad")) == []  # the renderer's input type is data


def test_pipeline_is_the_module_that_chains():
    """The pipeline itself does import every stage (the checks above are not vacuous)."""
    areas = {_area(t, n) for m, imp in GRAPH.items() if m.startswith("holo_viewer.pipeline") for t, n in imp}
    assert {"flame", "avatar", "render", "display", "reaction"} <= areas


def _is_package(area: str) -> bool:
    return area == "apps" or (PKG / area).is_dir()


def _design_layer_map() -> tuple[dict[str, str], set[tuple[str, str]]]:
    """docs/design.md section 2: the areas its layer map names (``name/`` for a package, ``name.py`` for a
    module of holo_viewer/) -> the layers they are listed under, and the stage edges ``a -> b`` of the
    paragraph after the map."""
    import re

    design = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    start = design.index("```", design.index("Package layout and layers")) + 3
    end = design.index("```", start)
    known = BASE | STAGE_PKGS | set().union(*UPPER_LAYERS.values())
    named: dict[str, set[str]] = {}
    layer = None
    for line in design[start:end].splitlines():
        head = line.split(maxsplit=1)
        if head and not line.startswith(" ") and head[0] in ORDER:
            layer = head[0]
        if layer is None:
            continue
        packages = set(re.findall(r"\b([a-z_0-9]+)/", line))
        modules = set(re.findall(r"\b([a-z_0-9]+)\.py\b", line))
        for area in known:
            if area in (packages if _is_package(area) else modules):
                named.setdefault(area, set()).add(layer)
    edges = set(re.findall(r"`([a-z_]+) -> ([a-z_]+)`", design[end:design.index("## 3.", end)]))
    return {a: ", ".join(sorted(ls)) for a, ls in named.items()}, edges


def test_design_layer_map_matches_the_tables_here():
    """docs/design.md's layer map lists every area of this file's tables under its layer, and only there
    (live/ and tracking/ included), and exactly the stage edges of STAGE_EDGES."""
    named, edges = _design_layer_map()
    areas = (BASE - {"__init__"}) | STAGE_PKGS | set().union(*UPPER_LAYERS.values())
    wrong = {a: (named.get(a, "nowhere"), _layer(a)) for a in sorted(areas) if named.get(a) != _layer(a)}
    assert not wrong, f"docs/design.md section 2 lists area: (under, should be) {wrong}"
    table = {(a, b) for a, bs in STAGE_EDGES.items() for b in bs}
    assert edges == table, f"docs/design.md section 2 lists stage edges {sorted(edges)}; STAGE_EDGES: {sorted(table)}"


def test_design_citations_point_to_docs_design_md():
    """The code and docs cite docs/design.md by section number or title; each cited section exists."""
    import re

    design = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    headings = [h.strip() for h in re.findall(r"^#{2,3} (.+)$", design, flags=re.M)]
    cited_numbers, cited_titles = set(), set()
    files = [p for p in _sources()] + sorted((ROOT / "docs").glob("*.md")) + sorted((ROOT / "tests").glob("*.py"))
    for path in files:
        text = path.read_text(encoding="utf-8")
        old = "DESIGN" + ".md"  # the shared file's name, cited before docs/design.md existed
        assert old not in text, f"{path}: cites {old}; use docs/design.md"
        cited_numbers |= set(re.findall(r"docs/design\.md,? section (\d)", text))
        cited_titles |= set(re.findall(r'docs/design\.md,? "([^"]+)"', text))
    for n in cited_numbers:
        assert any(h.startswith(f"{n}.") for h in headings), f"docs/design.md has no section {n}"
    for title in cited_titles:
        assert any(title.lower() in h.lower() for h in headings) or f"{title}:" in design, (
            f"docs/design.md has no section (or paragraph) {title!r}")
    assert cited_numbers and cited_titles  # the checks are not vacuous


def test_readme_stays_short():
    """The README is a front page (<= 120 lines); measured numbers live in docs/benchmarks.md."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 120, f"README.md has {len(lines)} lines; move detail to docs/ (numbers: docs/benchmarks.md)"
