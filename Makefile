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

# ours vs gymnax, navix, jaxmarl's JaxNav and rejax in one run; ARGS="--num-envs 1024,262144" etc.
bench: $(STAMP)
	$(BIN)/python -m benchmarks.compare $(ARGS)
	$(BIN)/python -m benchmarks.train_throughput

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
