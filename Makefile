# SCET: `make demo` runs the main job on the default scene, `make test` runs the test suite,
# `make docs` builds the documentation site into docs/_build/html (warnings are errors).
# Both set everything up first: a virtual environment in .venv with the package and all its
# extras, and (as root, on Debian) libllvm19 for Mitsuba's LLVM backend and the AVR toolchain
# (gcc-avr, avr-libc, simavr) for the strobe firmware. `make firmware` builds its .hex;
# `make test-base` runs the estimator's tests in a second environment, .venv-base, with the
# base package alone.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.scet-installed
BASE_VENV  ?= .venv-base
BASE_PY    := $(BASE_VENV)/bin/python
BASE_STAMP := $(BASE_VENV)/.scet-installed
PYTEST_ARGS ?=
# Small matrices only: threaded BLAS on 2 cores oversubscribes (measured 40x slower joint fits).
export OPENBLAS_NUM_THREADS ?= 1

.PHONY: setup demo test test-base test-slow bench firmware docs clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[all]'
	bash tools/install-llvm.sh
	bash tools/install-avr.sh
	touch $(STAMP)

# The strobe firmware for the Arduino (hardware/firmware/build/strobe.hex) and its simulator
# harness; installs the AVR toolchain first when run as root on Debian.
firmware:
	bash tools/install-avr.sh
	$(MAKE) -C hardware/firmware sim

# The main job on the default scene: render, calibrate, track, compare (about 1-2 minutes).
demo: $(STAMP)
	$(VENV)/bin/scet validate --quick

# pytest exits 5 when it collected no test: that is a failure here, not a pass.
test: $(STAMP)
	@$(PY) -m pytest -m "not slow" $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "error: pytest collected no tests" >&2; exit 1; fi; exit $$rc

# The base package and its test tools only (the 'test' extra), isolated from .venv and from
# PYTHONPATH: the estimator runs on a Raspberry Pi without the renderer or Numba.
$(BASE_STAMP): pyproject.toml
	rm -rf $(BASE_VENV)
	$(PYTHON) -m venv $(BASE_VENV)
	$(BASE_PY) -m pip install -q --upgrade pip
	$(BASE_PY) -m pip install -q -e '.[test]'
	touch $(BASE_STAMP)

# tests/estimator on the base install. SCET_BASE_ONLY=1 stops it if a module of the render or
# fast extras can be imported there, and refuses imports of scet_render (tests/conftest.py).
test-base: $(BASE_STAMP)
	@env -u PYTHONPATH SCET_BASE_ONLY=1 $(BASE_PY) -m pytest tests/estimator -m "not slow" \
	$(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "error: pytest collected no tests" >&2; exit 1; fi; exit $$rc

# The documentation site: Sphinx (the 'docs' extra, part of 'all'), warnings as errors, the
# gallery's examples executed (a few small renders). SCET_DOCS_GALLERY=0 skips running them.
docs: $(STAMP)
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "documentation: docs/_build/html/index.html"

test-slow: $(STAMP)
	$(PY) -m pytest -m slow $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) benchmarks/bench_projection.py
	$(PY) benchmarks/bench_conic.py
	$(PY) benchmarks/bench_gaze.py
	$(PY) benchmarks/bench_glints.py
	$(PY) benchmarks/bench_render.py
	$(PY) benchmarks/bench_capture.py
	$(PY) benchmarks/bench_cluster.py

clean:
	rm -rf $(VENV) $(BASE_VENV) build *.egg-info .pytest_cache .hypothesis hardware/firmware/build \
	  docs/_build docs/auto_examples docs/sg_execution_times.rst
