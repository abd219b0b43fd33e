# The two commands of the README. Everything installs from PyPI into .venv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: demo test setup lint bench clean

NATIVE := pipeline/decode/_json_columns.c pipeline/decode/_pow5_128.h pipeline/io/_mcap_records.c \
          pipeline/maritime/_associate.c

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
	$(BIN)/python bench/batch.py --json bench-batch.json
	$(BIN)/python bench/region_day.py --json bench-region-day.json

clean:
	rm -rf $(VENV) warehouse/tables warehouse/*.duckdb
