#!/usr/bin/env bash
# Set-up for `make demo` / `make test` on a fresh machine:
#   1. system packages (apt-get when root; otherwise say what to install),
#   2. the virtual environment .venv with `pip install -e ".[dev]"` and torch==2.13.0 pinned.
# Idempotent: a stamp file records a finished install of this pyproject.toml.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"
PYTHON="${PYTHON:-python3}"
APT_PKGS="libosmesa6 xvfb xdotool libusb-1.0-0 libgl1 libegl1 libxrender1 libportaudio2 espeak-ng"

have_lib() { ldconfig -p 2>/dev/null | grep -q "$1"; }
missing=""
have_lib libOSMesa.so || missing="$missing libosmesa6"
command -v Xvfb >/dev/null 2>&1 || missing="$missing xvfb"
command -v xdotool >/dev/null 2>&1 || missing="$missing xdotool"
have_lib libusb-1.0.so || missing="$missing libusb-1.0-0"
have_lib libGL.so.1 || missing="$missing libgl1"
have_lib libEGL.so.1 || missing="$missing libegl1"
have_lib libXrender.so.1 || missing="$missing libxrender1"
have_lib libportaudio.so.2 || missing="$missing libportaudio2"
command -v espeak-ng >/dev/null 2>&1 || missing="$missing espeak-ng"
if [ -n "$missing" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing system packages:$missing"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $APT_PKGS >/dev/null
  else
    echo "setup: WARNING: missing system packages:$missing" >&2
    echo "setup: install them with: sudo apt-get install$missing" >&2
    echo "setup: (offscreen rendering needs libosmesa6, GUI tests need xvfb and xdotool (real key presses / mouse drags), USB needs libusb-1.0-0;" >&2
    echo "        the live microphone needs libportaudio2;" >&2
    echo "        tests that need them are skipped with a message)" >&2
  fi
fi

stamp="$VENV/.holo_viewer_installed"
if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
# reinstall when the package metadata or a compiled kernel's source is newer than the last install
stale=""
for f in pyproject.toml setup.py holo_viewer/_cpu/*.h holo_viewer/*/_cpu/*.cpp; do
  [ -f "$f" ] && [ "$f" -nt "$stamp" ] && stale=1
done
if [ ! -f "$stamp" ] || [ -n "$stale" ]; then
  echo "setup: installing holo_viewer[dev] into $VENV (torch==2.13.0 CPU)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q "torch==2.13.0"
  "$VENV/bin/python" -m pip install -q -e ".[dev]"
  touch "$stamp"
fi
# numba kernels: compile and cache them once here when the clone has no cache yet, not in the first test run
# (scripts/warm_kernels.py: ~60 s of CPU in a fresh clone; it reports and skips a step that fails)
if ! ls holo_viewer/render/__pycache__/fast_kernels.*.nbi >/dev/null 2>&1; then
  echo "setup: compiling the numba kernels once (scripts/warm_kernels.py)"
  "$VENV/bin/python" scripts/warm_kernels.py || true
fi
# bytecode, as pip compiles an installed package: the package's .pyc and the tests' (pytest's assertion
# rewriting, cached beside them), once. Every make test worker collects all test files and the suite starts
# dozens of Python children; they read these instead of compiling again (also where PYTHONDONTWRITEBYTECODE is
# set: it stops writing, not reading). Whole-suite collection: 11.5 -> 6.4 s of CPU per worker.
if ! ls tests/__pycache__/conftest.*-pytest-*.pyc >/dev/null 2>&1; then
  echo "setup: compiling the package's and the tests' bytecode once"
  PYTHONDONTWRITEBYTECODE= "$VENV/bin/python" -m compileall -q holo_viewer bench >/dev/null || true
  PYTHONDONTWRITEBYTECODE= "$VENV/bin/python" -m pytest -q --collect-only -p no:cacheprovider -p no:xdist tests \
    >/dev/null 2>&1 || true
fi
