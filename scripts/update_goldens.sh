#!/usr/bin/env bash
# Regenerate the golden images of the image-regression tests (tests/golden/*.png) after an intended
# change of the look: the default avatar's quilt tiles, native crop and head sheet
# (tests/test_golden_images.py) and the GUI's offscreen snapshot (tests/test_gui.py).
# Look at the rewritten PNGs (git diff shows which changed) before committing them.
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PY:-.venv/bin/python}"
HOLO_UPDATE_GOLDEN=1 "$PY" -m pytest -q -p no:cacheprovider tests/test_golden_images.py \
  "tests/test_gui.py::test_offscreen_snapshot_matches_golden" "$@"
git status --short tests/golden
