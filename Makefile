# The two commands of the README. Everything installs from PyPI into .venv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: demo test setup lint bench clean

$(BIN)/surveil: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(BIN)/surveil

setup: $(BIN)/surveil

demo: setup
	$(BIN)/surveil demo

test: setup
	$(BIN)/ruff check pipeline jobs tests bench
	$(BIN)/pytest

bench: setup
	$(BIN)/python bench/batch.py

clean:
	rm -rf $(VENV) warehouse/tables warehouse/*.duckdb
