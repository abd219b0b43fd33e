"""Typed columns from JSON-object payloads that lie in decompressed MCAP chunks.

The compiled parser ``_json_columns`` (``_json_columns.c``, built at install time; see
its header for what it accepts) reads every payload where it lies, for the fields of a
schema only, into numpy arrays, two threads on two halves of the rows with the GIL
released (the caller's thread and a helper of the pool it passes: an ingest keeps one,
:class:`pipeline.ingest.IngestContext`; without one, helpers live for the call only).
Rows it cannot decode exactly are *flagged*, never guessed: the caller sends
them to the Python fallback. When the extension could not be built (no C compiler),
:data:`AVAILABLE` is false and :func:`native_kinds` answers ``None``: callers use the
``polars.read_ndjson`` path.
"""

from __future__ import annotations

import contextlib
import itertools
import os
from collections.abc import Sequence
from concurrent.futures import Executor

import numpy as np
import polars as pl
import pyarrow as pa

from pipeline.threads import SECOND_PARSER_NICE, helper_pool

try:
    from pipeline.decode import _json_columns
except ImportError:  # built without a C compiler: the read_ndjson path is used
    _json_columns = None

AVAILABLE = _json_columns is not None
PARALLEL_ROWS = 20_000  # below this, one thread: the split costs more than it saves
HELPER_THREADS = 3  # the caller's thread parses one part, these the others

_KIND = {"f": (pl.Float64(), np.float64), "i": (pl.Int64(), np.int64),
         "s": (pl.String(), np.int64), "b": (pl.Boolean(), np.uint8)}  # fmt: skip


def native_kinds(schema: dict[str, pl.DataType]) -> str | None:
    """One kind letter per field (``f`` float64, ``i`` int64, ``s`` string, ``b`` bool),
    or ``None`` when the parser is not built or a field has another type."""
    if not AVAILABLE or not schema or len(schema) > 64:
        return None
    out = []
    for dtype in schema.values():
        letter = next((k for k, (t, _) in _KIND.items() if dtype == t), None)
        if letter is None:
            return None
        out.append(letter)
    return "".join(out)


def threads() -> int:
    """Parser threads: the worker's thread budget when an executor set one, else the
    cores this process may use (at most 4)."""
    budget = os.environ.get("SURVEIL_THREADS_PER_WORKER")
    if budget and budget.isdigit():
        return max(1, int(budget))
    return max(1, min(4, len(os.sched_getaffinity(0))))


def parser_pool() -> Executor:
    """A pool for :func:`parse_spans`' helper threads (niced ``SECOND_PARSER_NICE``: the
    chunk fetch thread comes first). The caller owns it and shuts it down."""
    return helper_pool(HELPER_THREADS, "json-columns", SECOND_PARSER_NICE)


def parse_spans(
    chunks: Sequence[bytes],
    chunk: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    schema: dict[str, pl.DataType],
    kinds: str,
    pool: Executor | None = None,
) -> tuple[pa.Table, np.ndarray]:
    """Parse the payloads ``chunks[chunk[r]][start[r]:end[r]]`` into ``schema``'s columns.

    Returns an Arrow table of one row per payload (values of flagged rows are meaningless;
    Arrow, not polars: the caller converts only the columns it validates) and the indexes
    of the flagged rows (int64, ascending). ``pool``: where the helper threads run
    (:func:`parser_pool`; ``None``: a pool for this call only)."""
    n = len(chunk)
    chunk, start, end = (np.ascontiguousarray(a, dtype=np.int64) for a in (chunk, start, end))
    outs = [np.empty(2 * n if k == "s" else n, dtype=_KIND[k][1]) for k in kinds]
    valid = np.empty((len(kinds), n), dtype=np.uint8)
    status = np.empty(n, dtype=np.uint8)
    keys = [name.encode() for name in schema]
    args = (list(chunks), chunk, start, end, keys, kinds, outs, valid, status)
    parts = threads() if n >= PARALLEL_ROWS else 1
    bounds = np.linspace(0, n, parts + 1).astype(np.int64).tolist()
    with contextlib.ExitStack() as own:
        if pool is None and parts > 1:
            pool = own.enter_context(parser_pool())
        # disjoint row ranges of the same output arrays, the last one in this thread; the
        # C loop holds no GIL
        jobs = [
            pool.submit(_json_columns.parse_objects, *args, a, b)  # type: ignore[union-attr]
            for a, b in itertools.pairwise(bounds[:-1])
        ]
        _json_columns.parse_objects(*args, bounds[-2], bounds[-1])
        for job in jobs:
            job.result()
    flagged = np.flatnonzero(status).astype(np.int64)
    columns = {
        name: _column(kind, out, valid[i].view(bool), list(chunks), chunk)
        for i, (name, kind, out) in enumerate(zip(schema, kinds, outs, strict=True))
    }
    return pa.table(columns), flagged


def _column(
    kind: str, values: np.ndarray, valid: np.ndarray, chunks: list[bytes], chunk: np.ndarray
) -> pa.Array:
    n = len(valid)
    all_valid = bool(valid.all())
    if kind == "s":
        spans = values.reshape(n, 2)
        if not all_valid:
            spans[~valid] = 0  # unset (or flagged) rows: an empty span
        offsets, data = _json_columns.gather_spans(chunks, chunk, values)
        buffers = [pa.py_buffer(offsets), pa.py_buffer(data)]
        return _with_validity(pa.string(), n, buffers, valid, all_valid)
    if kind == "b":
        return pa.array(values.view(bool), mask=None if all_valid else ~valid)
    dtype = pa.float64() if kind == "f" else pa.int64()
    return _with_validity(dtype, n, [pa.py_buffer(values)], valid, all_valid)


def _with_validity(
    dtype: pa.DataType, n: int, buffers: list, valid: np.ndarray, all_valid: bool
) -> pa.Array:
    if all_valid:
        return pa.Array.from_buffers(dtype, n, [None, *buffers], null_count=0)
    bitmap = pa.py_buffer(np.packbits(valid, bitorder="little"))
    return pa.Array.from_buffers(dtype, n, [bitmap, *buffers], null_count=int(n - valid.sum()))
