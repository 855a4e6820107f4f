# Quickstart: `make train` and `make test`. Both create .venv (Python >= 3.10) on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ARGS ?=

.PHONY: train test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[dev,notebook,bench]"
	touch $(STAMP)

train: $(STAMP)
	$(BIN)/python -m jaxnav.train $(ARGS)

test: $(STAMP)
	$(BIN)/python -m ruff check jaxnav tests benchmarks
	$(BIN)/python -m pytest -n 2 --dist loadgroup $(ARGS)

lint: $(STAMP)
	$(BIN)/python -m ruff check jaxnav tests benchmarks

bench: $(STAMP)
	$(BIN)/python -m benchmarks.env_throughput
	$(BIN)/python -m benchmarks.train_throughput

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
