"""Subcommands of the ``holo-viewer`` CLI; each module has ``add_arguments`` and ``run``."""
