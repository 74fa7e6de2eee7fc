# d1-fleet: every target creates .venv and installs what it needs, so each works first on a clean clone.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
FUZZ_SECONDS ?= 60
FUZZ_TIMEOUT ?= 10
DURATION ?= 30m
UNITREE_SDK := unitree-sdk2py-dimos==1.0.3

.PHONY: demo test test-fast lint bench fuzz soak docs clean

# Some machines (this project's CI among them) set PYTHONDONTWRITEBYTECODE: then no process
# keeps its compiled modules, each of the suite's ~700 processes compiles ours again (a fleet's
# start in a test: 0.8-1.0 s against 0.45-0.6 s) and each pytest worker rewrites the asserts of
# every test module (collection: 6.8 s against 1.9 s). Every target here writes __pycache__.
unexport PYTHONDONTWRITEBYTECODE

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# Unitree's Python SDK with its G1 clients is the far side of the G1 tests, installed
# --no-deps: it declares opencv-python, which none of its code the tests use imports, and it
# runs on our cyclonedds 11. The stamp depends on this Makefile too, so an older venv gets it.
$(STAMP): pyproject.toml Makefile | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	$(BIN)/python -m pip install --quiet --no-deps $(UNITREE_SDK)
	touch $(STAMP)

# atheris (fuzz) and matplotlib (soak plot) are optional extras: never needed by `make test`.
$(VENV)/.installed-fuzz: pyproject.toml | $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,fuzz]'
	touch $@

$(VENV)/.installed-soak: pyproject.toml | $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,soak]'
	touch $@

# mkdocs (the documentation site) is an optional extra too.
$(VENV)/.installed-docs: pyproject.toml | $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,docs]'
	touch $@

demo: $(STAMP)
	$(BIN)/fleet demo --inventory inventory.toml

lint: $(STAMP)
	$(BIN)/ruff check fleet edge_agent viewer tests testkit bench fuzz
	$(BIN)/ruff format --check fleet edge_agent viewer tests testkit bench fuzz
	$(BIN)/mypy fleet/wire fleet/d1

# Everything: lint, then unit, e2e, browser and netlab tests on three workers (the browser
# tests share one, the netlab tests another, --dist loadgroup), about 8 minutes on 2 cores; the
# tests that measure time run at a higher priority than the rest (testkit/priority.py). Every
# test's time is kept in artifacts/test-results.xml (JUnit XML).
# Three workers on two cores: most tests wait for a simulated arm to move, and since the
# harness forks its processes with the fleet imported (testkit/forkserver.py) the host is no
# longer saturated: 446 s against 624 s on two workers (docs/design/testing.md).
TEST_WORKERS ?= 3
test: $(STAMP) lint
	sh scripts/ensure-chromium
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadgroup --durations=40 \
		--junitxml=artifacts/test-results.xml

# The pure tests only (tests/unit: no process, no network), in under a minute: while working.
test-fast: $(STAMP)
	$(BIN)/python -m pytest -n 2 -q tests/unit

bench: $(STAMP)
	$(BIN)/python -m bench

# Coverage-guided fuzzing of every hostile-input decoder: FUZZ_SECONDS per target (docs/design/testing.md, "Fuzzing").
fuzz: $(VENV)/.installed-fuzz
	$(BIN)/python -m fuzz.run --seconds $(FUZZ_SECONDS) --timeout $(FUZZ_TIMEOUT)

# The demo fleet under link flaps, restarts, reconnects and stops for DURATION (90s, 5m, 30m...).
soak: $(VENV)/.installed-soak
	$(BIN)/python -m bench.soak --duration $(DURATION)

# docs/ as a website in site/ (ignored): the results pages are refreshed from the newest
# bench and soak outputs first (scripts/docs_results.py), then every link is checked (--strict).
docs: $(VENV)/.installed-docs
	$(BIN)/python scripts/docs_results.py
	$(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) build *.egg-info artifacts site
	find fleet edge_agent viewer testkit tests bench fuzz scripts -name __pycache__ -prune -exec rm -rf {} +
