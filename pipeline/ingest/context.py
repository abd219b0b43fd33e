"""What an ingest holds while it runs, in one object instead of module globals.

:class:`IngestContext` owns:

- ``chunk_buffers``: the pool zstd chunks are decompressed into
  (:class:`~pipeline.io.mcap_chunks.ChunkBuffers`): a buffer is handed out again once
  nothing refers to it, so the job's later files reuse the first file's pages (page
  faults of a second 1 M JSON ingest in a process ~38 k -> ~14 k);
- ``parse_pool``: the compiled JSON parser's helper threads (niced
  ``SECOND_PARSER_NICE``), and ``hasher``: the thread that computes each file's SHA-256
  while it decodes (niced ``HASHER_NICE``);
- ``strings``: the provenance string columns, one array per source file and topic
  (:class:`~pipeline.tables.ConstantStrings`);
- ``views``: the DuckDB instance that rebuilds the views file at the end (driver only;
  started by :meth:`~pipeline.warehouse.views.ViewsEngine.warm_up`);
- the allocator setting (:func:`keep_freed_memory`), applied on ``__enter__``.

The ingest job creates one (``with IngestContext() as ctx:``); the workers in its
process (serial executor) use it, and each process of a pool creates its own through
:meth:`IngestContext.for_workers`. ``__exit__`` stops the threads, closes DuckDB and
drops the buffers. Importing this module (or any other) changes nothing in the process:
``tests/ingest/test_context.py`` checks that no import starts a thread or calls
``mallopt``.
"""

from __future__ import annotations

import contextlib
import ctypes
import sys
from concurrent.futures import Executor
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Any

from pipeline.decode.json_columns import parser_pool
from pipeline.io.mcap_chunks import POOL_BUFFERS, ChunkBuffers
from pipeline.tables import ConstantStrings, table_specs
from pipeline.threads import HASHER_NICE, helper_pool
from pipeline.warehouse.views import ViewsEngine

# glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest on 64-bit
TRIM_THRESHOLD_BYTES = 128 << 20


def keep_freed_memory() -> bool:
    """Let glibc's malloc keep freed memory for reuse instead of handing it back to the
    kernel: blocks up to 32 MiB come from the heap (not a fresh ``mmap`` each), and up to
    128 MiB free at the heap's top stays mapped. A job allocates and frees arrays of
    ~1 MiB per column and group all the time; each fresh page costs a page fault here
    (~1 ms per MiB). A 1 M protobuf ingest: ~130 k -> ~46 k page faults, ~0.5 s less.
    The process keeps up to 128 MiB it no longer uses; peak resident set of a 1.2 M
    JSON ingest 396 -> 431 MB. False (nothing done) where the C library is not glibc.

    The setting stays for the rest of the process: glibc cannot read its thresholds back,
    and setting them again would not restore the dynamic mmap threshold it had."""
    if not sys.platform.startswith("linux"):
        return False
    try:  # the symbols the process already has (no ldconfig run, as find_library does)
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    return bool(
        mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
        and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )


class IngestContext:
    """The buffers, helper threads and DuckDB instance of an ingest (module docstring).

    ``keep_freed_memory``: apply :func:`keep_freed_memory` on ``__enter__`` (default).
    The members exist between ``__enter__`` and ``__exit__`` only.
    """

    def __init__(self, *, keep_freed_memory: bool = True):
        self.keep_freed_memory = keep_freed_memory
        self._entered = False
        self.chunk_buffers: ChunkBuffers | None = None
        self.parse_pool: Executor | None = None
        self.hasher: Executor | None = None
        self.strings: ConstantStrings | None = None
        self.views: ViewsEngine | None = None

    def __enter__(self) -> IngestContext:
        if self._entered:
            raise RuntimeError("an IngestContext is entered once")
        self._entered = True
        if self.keep_freed_memory:
            keep_freed_memory()
        # the table schemas (schemas/*.toml, ~20 ms of TOML), before the first file's
        # reads: its ledger lookup and decoders would wait for them otherwise
        table_specs()
        self.chunk_buffers = ChunkBuffers(limit=POOL_BUFFERS)
        self.parse_pool = parser_pool()  # threads start with the first parse
        self.hasher = helper_pool(1, "sha256", HASHER_NICE)
        self.strings = ConstantStrings()
        self.views = ViewsEngine()  # connects on warm_up() or first use
        return self

    def __exit__(self, *exc: object) -> None:
        for pool in (self.parse_pool, self.hasher):
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
        if self.views is not None:
            self.views.close()
        self.chunk_buffers = self.parse_pool = self.hasher = None
        self.strings = self.views = None

    def for_workers(self) -> WorkerContexts:
        """A picklable factory of the workers' context (for an executor's ``context``):
        in this process it hands out this context; unpickled in another process (a pool
        worker, a Ray task), it creates a new one with the same settings."""
        return WorkerContexts(self.keep_freed_memory, _local=self)


@dataclass(frozen=True)
class WorkerContexts:
    """Picklable: ``_local`` (the driver's context) stays behind when pickled."""

    keep_freed_memory: bool = True
    _local: IngestContext | None = None

    def __call__(self) -> AbstractContextManager[IngestContext]:
        if self._local is not None:  # the driver's process: its context, entered already
            return contextlib.nullcontext(self._local)
        return IngestContext(keep_freed_memory=self.keep_freed_memory)

    def __reduce__(self) -> tuple[Any, ...]:
        return (WorkerContexts, (self.keep_freed_memory,))
