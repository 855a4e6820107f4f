# Quickstart: `make train` and `make test`. Both create .venv (Python >= 3.11) on first use;
# each target installs only what it needs: train the package, test adds the dev extra and the
# benchmark peers (the suite checks the comparisons against them), bench the peers, notebooks
# Jupyter.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
ARGS ?=

.PHONY: train test test-slow lint bench notebooks clean

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null || { \
	  echo "jaxnav needs Python >= 3.11 (jax, flax and mujoco do); $(PYTHON) is $$($(PYTHON) -V 2>&1): use e.g. PYTHON=python3.11 make ..."; \
	  exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# one stamp per extra, remade when pyproject.toml changes
$(VENV)/.installed-core: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-%: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[$*]"
	touch $@

train: $(VENV)/.installed-core
	$(BIN)/python -m jaxnav.train $(ARGS)

# the fast tier; test-slow runs the end-to-end tests (tests/conftest.py: SLOW_MODULES and the
# tests marked slow), and CI runs both
test: $(VENV)/.installed-dev,bench
	$(BIN)/python -m ruff check jaxnav tests benchmarks
	$(BIN)/python -m pytest -n 2 --dist loadgroup -m "not slow" $(ARGS)

test-slow: $(VENV)/.installed-dev,bench
	$(BIN)/python -m pytest -n 2 --dist loadgroup -m slow $(ARGS)

lint: $(VENV)/.installed-dev
	$(BIN)/python -m ruff check jaxnav tests benchmarks

# ours vs gymnax, navix, jaxmarl's JaxNav and rejax in one run; ARGS="--num-envs 1024,262144" etc.
bench: $(VENV)/.installed-bench
	$(BIN)/python -m benchmarks.compare $(ARGS)
	$(BIN)/python -m benchmarks.train_throughput

# executes every notebook top to bottom (copies with their outputs in notebooks/executed/);
# `$(BIN)/jupyter lab notebooks` opens them instead
notebooks: $(VENV)/.installed-notebook
	$(BIN)/jupyter nbconvert --to notebook --execute --output-dir notebooks/executed notebooks/*.ipynb

clean:
	rm -rf $(VENV) runs notebooks/executed .pytest_cache .ruff_cache
