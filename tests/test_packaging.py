"""environment.yml's pip section mirrors pyproject.toml's dependencies (+ the dev extra)."""

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _pyproject():
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        tomllib = pytest.importorskip("tomli")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _env_pip_requirements():
    lines = (ROOT / "environment.yml").read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "- pip:")
    reqs = []
    for line in lines[start + 1:]:
        m = re.match(r"^\s+- (\S+)\s*$", line)
        if not m:
            break
        reqs.append(m.group(1))
    return reqs


def test_environment_mirrors_pyproject():
    proj = _pyproject()["project"]
    wanted = list(proj["dependencies"]) + list(proj["optional-dependencies"]["dev"])
    assert sorted(_env_pip_requirements()) == sorted(wanted)


def test_torch_is_pinned_everywhere():
    proj = _pyproject()["project"]
    assert "torch==2.13.0" in proj["dependencies"]
    assert "torch==2.13.0" in _env_pip_requirements()
    assert '"torch==2.13.0"' in (ROOT / "scripts" / "setup.sh").read_text()


def test_console_script_and_extras():
    proj = _pyproject()["project"]
    assert proj["scripts"]["holo-viewer"] == "holo_viewer.cli:main"
    assert {"dev", "gui", "open3d", "bench"} <= set(proj["optional-dependencies"])
