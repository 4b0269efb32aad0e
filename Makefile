# The two set-up commands of the README: `make demo` and `make test`.
# Both install what they need (scripts/setup.sh) and are safe to re-run.
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= out
PYTEST_ARGS ?=
# the suite runs on JOBS pytest-xdist workers, whole files per worker (module fixtures are built once),
# the costliest files first (tests/conftest.py orders them; the default reorder by test count is off).
# make test: 2 workers on 2 cores (a third, to run while another waits, was slower in a quiet fresh
# clone: 5 min 32 s against 5 min 17 s; docs/development.md, "Measured"). make test-fast: FAST_JOBS=2.
JOBS ?= 2
FAST_JOBS ?= 2
XDIST_OPTS := --dist loadfile --no-loadscope-reorder
XDIST := -n $(JOBS) $(XDIST_OPTS)

.PHONY: demo test test-fast setup bench bench-quick clean help

help:
	@echo "make demo   - set up .venv, then run the main job on the default avatar (writes $(OUT)/)"
	@echo "make test   - set up .venv, then run the whole test suite (as CI does; JOBS=2 workers)"
	@echo "make test-fast - the suite without the tests marked slow (every module, about a minute; FAST_JOBS=2 workers)"
	@echo "make bench  - run the benchmarks under bench/ (writes bench/results/*.json); bench-quick: < 3 min"

setup:
	@bash scripts/setup.sh

demo: setup
	$(PY) -m holo_viewer demo --out $(OUT)

# pytest's exit code 5 (no tests collected) fails make test with a message: a run that ran nothing has not passed
test: setup
	$(PY) -m pytest -q $(XDIST) $(PYTEST_ARGS) || { rc=$$?; [ $$rc -ne 5 ] || echo "make test: pytest collected no tests (exit 5)" >&2; exit $$rc; }

# exit code 5 (nothing collected: PYTEST_ARGS picked only slow tests) is not a failure here; CI runs make test
test-fast: setup
	$(PY) -m pytest -q -n $(FAST_JOBS) $(XDIST_OPTS) -m "not slow" $(PYTEST_ARGS) || { rc=$$?; [ $$rc -eq 5 ] && echo "test-fast: no fast tests selected"; [ $$rc -eq 5 ]; }

bench: setup
	mkdir -p bench/results
	$(PY) bench/flame_speed.py --threads 1 --json bench/results/flame_speed.json
	$(PY) bench/deform_tradeoff.py --json bench/results/deform_tradeoff.json
	$(PY) bench/render_tradeoff.py --json bench/results/render_tradeoff.json --plot bench/results/render_tradeoff.png
	$(PY) bench/lenticular_speed.py --json bench/results/lenticular_speed.json
	$(PY) bench/reaction_latency.py --json bench/results/reaction_latency.json
	$(PY) bench/react_metrics_speed.py --json bench/results/react_metrics_speed.json
	$(PY) bench/listener_behaviour.py --out bench/results/listener_behaviour.json
	$(PY) bench/live_latency.py --json bench/results/live_latency.json
	$(PY) bench/live_frame.py --json bench/results/live_frame.json
	$(PY) bench/cpu_scaling.py --json bench/results/cpu_scaling.json

bench-quick: setup
	mkdir -p bench/results
	$(PY) bench/render_tradeoff.py --quick --json bench/results/render_tradeoff_quick.json

clean:
	rm -rf $(OUT) .pytest_cache build *.egg-info
