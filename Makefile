# Each target does its own set-up (system libraries, virtualenv, package).
VENV ?= .venv
STAMP := $(VENV)/.treesim-installed

.PHONY: demo test test-all bench lint setup clean

$(STAMP): pyproject.toml scripts/setup.sh
	VENV=$(VENV) bash scripts/setup.sh
	@touch $(STAMP)

setup: $(STAMP)

## Run the main job on the bundled sample tree with embedded defaults.
demo: $(STAMP)
	$(VENV)/bin/treesim demo -o out/demo

## The test suite (what CI runs).
test: $(STAMP)
	$(VENV)/bin/python -m pytest -q

## Benchmarks: printed figures and side-by-side ratios, not pass/fail.
bench: $(STAMP)
	$(VENV)/bin/python benchmarks/bench_scan.py

lint: $(STAMP)
	$(VENV)/bin/ruff check pipeline service tests benchmarks
	$(VENV)/bin/ruff format --check pipeline service tests benchmarks

clean:
	rm -rf out .pytest_cache
