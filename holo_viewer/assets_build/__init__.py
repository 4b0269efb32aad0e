"""Build-time code: makes the assets the package ships; nothing here runs when the package is used.

* :mod:`.head` and :mod:`.ict` build the embedded default head (``assets/default_head.npz``) from the
  ICT Face Model (``scripts/build_default_head.py``); the tests check that a rebuild reproduces the
  committed asset byte for byte.
* :mod:`.texture_painter` paints the head's albedo textures (``scripts/build_head_textures.py``;
  ``assets/default_head_albedo_*.png``); the run-time side is :mod:`holo_viewer.flame.appearance`.
* :mod:`.fit_avatar` fits the default Gaussian avatar to renders of the textured head
  (``scripts/fit_default_avatar.py``; ``assets/default_avatar.npz``).

Layering (``tests/test_architecture.py``): this package sits above :mod:`holo_viewer.pipeline`; run-time
code imports it only in two lazy fallbacks that rebuild a missing or stale asset on first use
(``flame.default_head.default_head_path`` and ``flame.head_textures``).
"""
