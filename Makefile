# The two commands of the README. Everything installs from PyPI into .venv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: demo test setup lint bench clean fuzz fuzz-asan bench-hostile

NATIVE := pipeline/decode/_json_columns.c pipeline/decode/_pow5_128.h pipeline/io/_mcap_records.c \
          pipeline/maritime/_associate.c pipeline/filters/_particle.c

# pip builds the four C extensions (optional: skipped without a C compiler); the cluster
# extra (Ray, the object-store clients) so that `make test` runs the S3 and Ray tests
$(BIN)/surveil: pyproject.toml $(NATIVE)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev,asterix,cluster]'
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

bench-hostile: setup
	$(BIN)/python bench/hostile.py

# Fuzzing (docs/hostile_input.md): atheris over the MCAP reader, the ingest decoders (the
# compiled JSON parser among them), the NMEA/AIS and ASTERIX/pcap importers, FUZZ_SECONDS
# per target (coverage-guided), then every corpus replayed with the C extensions built
# with AddressSanitizer + UBSan (build/asan): fuzz/run.py says why in two phases.
FUZZ_SECONDS ?= 300
ASAN_CFLAGS := -shared -fPIC -O1 -g -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined
EXT = $$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_config_var("EXT_SUFFIX"))')
PYINC = $$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["include"])')

fuzz-asan: setup
	mkdir -p build/asan/pipeline/decode build/asan/pipeline/io
	gcc $(ASAN_CFLAGS) -I$(PYINC) pipeline/decode/_json_columns.c -o build/asan/pipeline/decode/_json_columns$(EXT)
	gcc $(ASAN_CFLAGS) -I$(PYINC) pipeline/io/_mcap_records.c -o build/asan/pipeline/io/_mcap_records$(EXT)

fuzz: fuzz-asan
	$(BIN)/pip install --quiet -e '.[dev,asterix,fuzz]'
	$(BIN)/python fuzz/run.py all --seconds $(FUZZ_SECONDS)
	LD_PRELOAD="$$(gcc -print-file-name=libasan.so) $$(gcc -print-file-name=libubsan.so)" \
	ASAN_OPTIONS=detect_leaks=0:allocator_may_return_null=1:handle_segv=1 \
	UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	$(BIN)/python fuzz/run.py all --replay --asan

clean:
	rm -rf $(VENV) warehouse/tables warehouse/*.duckdb build/asan fuzz/corpus
