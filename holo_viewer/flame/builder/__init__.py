"""Build-time code: generates the embedded default head (``assets/default_head.npz``).

Nothing here runs when the package is used: ``scripts/build_default_head.py`` calls
:func:`holo_viewer.flame.builder.head.build_default_head` and the tests check that a rebuild
reproduces the committed asset byte for byte. The one run-time use is a fallback: a checkout
without the asset rebuilds it on first load (``flame.default_head.default_head_path``).
"""
