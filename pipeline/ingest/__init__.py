"""Ingest: MCAP archive files -> raw Delta tables, rejects, ``mcap_index`` and the ledger.

A composition kernel above ``io``, ``decode`` and ``warehouse`` (it imports no sensor
family and no job); :mod:`~pipeline.ingest.driver` plans the units, runs them through an
executor, commits each manifest and sums up (``jobs/`` and the CLI only call it and print).

- :mod:`~pipeline.ingest.context`: :class:`IngestContext`, what an ingest process holds
  while it runs (buffer pool, helper threads, the views' DuckDB instance, the allocator
  setting), created by the job and passed to the workers;
- :mod:`~pipeline.ingest.worker`: one work unit per source file (:class:`IngestUnit`,
  small and picklable) -> staged Parquet files and a :class:`FileManifest` (commits
  nothing);
- :mod:`~pipeline.ingest.commit`: the driver's per-file commit (tables, then
  ``mcap_index``, the ledger row LAST);
- :mod:`~pipeline.ingest.summary`: the counts of a run (:class:`IngestSummary`).

Status of a file: ``ok``; ``partial`` (chunks lost, file cut off); ``quarantined`` (not
MCAP, or nothing readable: one rejects row says why). A windowed run neither skips by
the ledger nor writes it (nor ``mcap_index``).
"""

from pipeline.ingest.commit import commit_file
from pipeline.ingest.context import IngestContext
from pipeline.ingest.summary import IngestSummary
from pipeline.ingest.worker import FileManifest, IngestUnit, ingest_file

__all__ = [
    "FileManifest",
    "IngestContext",
    "IngestSummary",
    "IngestUnit",
    "commit_file",
    "ingest_file",
]
