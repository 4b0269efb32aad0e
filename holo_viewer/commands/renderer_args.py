"""The renderer option shared by ``demo``, ``view``, ``snapshot``, ``render-ply`` and ``live``.

One spelling, ``--renderer NAME``, with its choices checked by argparse when the command line is
parsed (exit status 2 and the valid names, before any model or avatar loads). ``render-ply`` and
``live`` called it ``--backend``: that spelling still works there, with a deprecation note on stderr
(``view --backend`` is the deprecated spelling of ``--toolkit``, unchanged).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Sequence

__all__ = ["add_renderer_argument", "splat_renderers"]


def splat_renderers() -> tuple[str, ...]:
    """The renderers of :func:`holo_viewer.render.api.render_views` (and ``auto``)."""
    from ..render.api import BACKENDS

    return (*BACKENDS, "auto")


class _DeprecatedSpelling(argparse.Action):
    """Stores into ``--renderer``'s destination and says that the spelling is deprecated."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"holo-viewer: {option_string} is deprecated, use --renderer", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_renderer_argument(parser: Any, *, choices: Sequence[str] | None = None, default: str = "fast",
                          help: str = "splat renderer", old_spelling: str | None = None) -> None:
    """Add ``--renderer`` (``args.renderer``) with ``choices`` (default :func:`splat_renderers`) and,
    when ``old_spelling`` is given (e.g. ``"--backend"``), that spelling as a deprecated alias."""
    names = tuple(choices) if choices is not None else splat_renderers()
    parser.add_argument("--renderer", choices=names, default=default, metavar="NAME",
                        help=f"{help}: {', '.join(names)} (default {default})")
    if old_spelling is not None:
        parser.add_argument(old_spelling, choices=names, dest="renderer", action=_DeprecatedSpelling,
                            help=argparse.SUPPRESS)
