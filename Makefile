# Two entry points on a fresh machine: `make demo` (the main job) and `make test` (the suite).
# Both create .venv with python3 -m venv and pip. torch is pinned (2.13.0, CPU build) in the
# `train` extra; the demo installs the server side only.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test test-fast lint wheel clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# The distribution was called `membrane` before `membrane-tissue`: an old editable install of it
# would register every command twice, so it goes first (a no-op when absent).
$(VENV)/.server-installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip uninstall -q -y membrane
	$(BIN)/pip install -q -e '.[server,plot]'
	touch $@

$(VENV)/.dev-installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip uninstall -q -y membrane
	$(BIN)/pip install -q -e '.[dev]'
	touch $@

demo: $(VENV)/.server-installed
	$(BIN)/python examples/demo.py

# lint-imports checks the import rules of docs/ARCHITECTURE.md ([tool.importlinter] in pyproject.toml).
test: $(VENV)/.dev-installed
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/lint-imports --no-cache
	$(BIN)/python -m pytest -q

# The fast lane (about a minute: 1,354 tests in 61-70 s wall on the 2-core machine, idle, on
# both cores with pytest-xdist; 105 s on one): the suite without the tests marked slow. Slow are
# every test over about 2 s, every test that starts a process (a server, the CLI, a fresh venv)
# and every browser test. `make test` runs them all, on one core.
test-fast: $(VENV)/.dev-installed
	$(BIN)/python -m pytest -q -m "not slow" -n 2

# The same static checks as `make test`, without the suite. Formatting is not enforced: the tree
# does not follow `ruff format`'s layout everywhere (README code blocks, docs, older modules), so a
# format check would fail on code that is fine; `ruff check` (lint rules, import order, line
# length) is what CI enforces.
lint: $(VENV)/.dev-installed
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/lint-imports --no-cache

# The wheel a simulator's Python installs (dist/membrane_tissue-VERSION-py3-none-any.whl): the
# distribution is not on the public index, where `membrane` is another project's name.
wheel: | $(BIN)/python
	$(BIN)/pip wheel . --no-deps -q -w dist

clean:
	rm -rf $(VENV) dist .pytest_cache .mypy_cache .ruff_cache
