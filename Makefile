# Each target does its own set-up (system libraries, virtualenv, package): `demo` only what
# the demo needs, `test` (and the targets that use the dev tools) everything the tests need.
VENV ?= .venv
DEMO_STAMP := $(VENV)/.treesim-demo-installed
TEST_STAMP := $(VENV)/.treesim-test-installed
DOCS_STAMP := $(VENV)/.treesim-docs-installed
SHARED_DATA ?= ../shared/data

.PHONY: demo test test-all bench lint docs setup clean

$(DEMO_STAMP): pyproject.toml scripts/setup.sh
	@VENV=$(VENV) bash scripts/setup.sh demo
	@touch $(DEMO_STAMP)

$(TEST_STAMP): pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh test
	@touch $(TEST_STAMP)

$(DOCS_STAMP): pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh docs
	@touch $(DOCS_STAMP)

setup: $(TEST_STAMP)

## Run the main job on the bundled sample tree with embedded defaults.
demo: $(DEMO_STAMP)
	$(VENV)/bin/treesim demo -o out/demo

## The test suite (what CI runs): every test, slow ones included; those that need the
## project's shared data skip with a reason where it is absent (a user's clone). On every
## core (pytest-xdist; PYTEST_WORKERS=0 runs in one process), a test file per worker at a
## time so that a file's cached scenes are made once, in the order tests/conftest.py gives
## (files with slow tests first, the many short files last, so that no worker idles at the
## end; xdist's own order puts the files with fewest tests, often the longest, last). The
## 25 slowest tests are listed at the end, to keep the suite inside its 20-minute budget.
PYTEST_WORKERS ?= auto
PYTEST := $(VENV)/bin/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile \
	--no-loadscope-reorder --durations=25
test: $(TEST_STAMP)
	$(PYTEST)

## Everything, and nothing may skip for want of data: the slow tests and the shared-data
## tests, which need $(SHARED_DATA) (present on the project's machines).
test-all: $(TEST_STAMP)
	@test -d $(SHARED_DATA)/trees || { echo "test-all needs $(SHARED_DATA)/trees (the project's shared data)"; exit 1; }
	$(PYTEST)

## Benchmarks: printed figures and side-by-side ratios, not pass/fail; every
## benchmarks/bench_*.py in turn.
bench: $(TEST_STAMP)
	@failed=""; for b in benchmarks/bench_*.py; do \
	  echo "== $$b"; $(VENV)/bin/python $$b || failed="$$failed $$b"; echo; \
	done; \
	if [ -n "$$failed" ]; then echo "bench: failed:$$failed"; exit 1; fi

## The manual (mkdocs.yml, docs/) built into site/, strictly: a broken link, a page
## missing from the navigation or an API reference that does not resolve fails it. Its
## Python examples run as tests in `make test` (tests/docs).
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check pipeline service tests benchmarks
	$(VENV)/bin/ruff format --check pipeline service tests benchmarks

clean:
	rm -rf out .pytest_cache site build/docs-src
