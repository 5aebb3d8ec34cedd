# Every target sets up what it needs from nothing: a .venv filled from pyproject.toml.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: test demo lint bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# pytest's workers (pytest-xdist): two where the machine has two cores or more, none (one process, as before) on one.
# Two were measured (docs/reliability.md, "Suite time"); more were not: the tests were hardened for a loaded 2-core
# machine, and the slowest few (missions, Zenoh exchanges) set the end anyway. `make test WORKERS=0` runs serially.
# --durations: the slowest tests, so that a CI log shows how close each came to its timeout.
WORKERS ?= $(shell [ "$$(nproc 2>/dev/null || echo 1)" -ge 2 ] && echo 2 || echo 0)

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q -n $(WORKERS) --durations=15

demo: $(STAMP)
	$(BIN)/p3at demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports

bench: $(STAMP)
	for f in benchmarks/bench_*.py; do echo "== $$f"; $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
