# The two set-up commands of the README: `make demo` and `make test`.
# Both install what they need (scripts/setup.sh) and are safe to re-run.
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= out
PYTEST_ARGS ?=

.PHONY: demo test setup bench clean help

help:
	@echo "make demo   - set up .venv, then run the main job on the default avatar (writes $(OUT)/)"
	@echo "make test   - set up .venv, then run the test suite"
	@echo "make bench  - run the benchmarks under bench/ (writes bench/results/*.json)"

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) -m holo_viewer demo --out $(OUT)

test: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

bench: setup
	$(PY) bench/flame_speed.py --json bench/results/flame_speed.json

clean:
	rm -rf $(OUT) .pytest_cache build *.egg-info
