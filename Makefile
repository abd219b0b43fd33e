# The two commands of the README. Everything installs from PyPI into .venv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: demo test setup lint bench clean

NATIVE := pipeline/decode/_json_columns.c pipeline/decode/_pow5_128.h pipeline/io/_mcap_records.c

# pip builds the two C extensions (optional: skipped without a C compiler)
$(BIN)/surveil: pyproject.toml $(NATIVE)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev,asterix]'
	touch $(BIN)/surveil

setup: $(BIN)/surveil

demo: setup
	$(BIN)/surveil demo

test: setup
	$(BIN)/ruff check pipeline jobs tests bench
	$(BIN)/lint-imports
	$(BIN)/pytest

bench: setup
	$(BIN)/python bench/pipeline.py
	$(BIN)/python bench/ingest.py

clean:
	rm -rf $(VENV) warehouse/tables warehouse/*.duckdb
