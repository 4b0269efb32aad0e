"""One renderer option (``--renderer``) on demo, view, snapshot, render-ply and live, checked when the
command line is parsed: a bad name exits with status 2 naming the valid ones, before anything loads."""

from __future__ import annotations

import pytest

from holo_viewer.cli import _build_parser, main

#: command -> the other arguments it needs to parse
COMMANDS = {"demo": [], "view": [], "snapshot": [], "live": [],
            "render-ply": ["scene.ply", "--cameras", "cams.json", "--out", "out"]}


@pytest.fixture
def nothing_loads(monkeypatch):
    """Fail the test if a command starts its work (a scene, an avatar or a PLY is loaded)."""
    def refuse(*args, **kwargs):
        raise AssertionError("the command ran: the renderer name was not checked at parse time")

    import holo_viewer.avatar.default_gaussians as dg
    import holo_viewer.pipeline.scene as scene

    monkeypatch.setattr(dg, "default_avatar", refuse)
    monkeypatch.setattr(scene, "load_scene", refuse)
    for name in ("demo", "view", "snapshot", "live", "render_ply"):
        mod = __import__(f"holo_viewer.commands.{name}", fromlist=["run"])
        monkeypatch.setattr(mod, "run", refuse)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_bad_renderer_is_refused_at_parse_time(command, nothing_loads, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, *COMMANDS[command], "--renderer", "nope"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--renderer" in err and "invalid choice: 'nope'" in err and "fast" in err


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_the_one_spelling_parses(command):
    name = "auto" if command == "live" else "reference"
    args = _build_parser(command).parse_args([command, *COMMANDS[command], "--renderer", name])
    assert args.renderer == name
    default = _build_parser(command).parse_args([command, *COMMANDS[command]]).renderer
    assert default == ("auto" if command == "live" else "fast")


@pytest.mark.parametrize("command", ["render-ply", "live"])
def test_the_old_spelling_is_a_deprecated_alias(command, capsys):
    args = _build_parser(command).parse_args([command, *COMMANDS[command], "--backend", "fast"])
    assert args.renderer == "fast" and not hasattr(args, "backend")
    assert "--backend is deprecated, use --renderer" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _build_parser(command).parse_args([command, *COMMANDS[command], "--backend", "nope"])


def test_view_backend_stays_the_toolkit_alias():
    args = _build_parser("view").parse_args(["view", "--backend", "open3d"])
    assert args.backend_deprecated == "open3d" and args.renderer == "fast"
