# d1-fleet: every target creates .venv and installs what it needs, so each works first on a clean clone.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/fleet demo --inventory inventory.toml

lint: $(STAMP)
	$(BIN)/ruff check fleet edge_agent viewer tests bench
	$(BIN)/ruff format --check fleet edge_agent viewer tests bench
	$(BIN)/mypy fleet/wire fleet/d1

test: $(STAMP) lint
	sh scripts/ensure-chromium
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/python -m bench

clean:
	rm -rf $(VENV) build *.egg-info artifacts
