"""The driver's side of an ingest: commit one file's manifest to the warehouse.

Per file, in this order: every raw table (``RAW_TABLES``) with
:func:`~pipeline.warehouse.staged.commit_staged`, ONE Delta commit per table that removes
the file's old data files and adds the staged ones (also when the file has no rows for a
table, so a changed file leaves no stale rows; a table with nothing to add or remove is
not touched), then the file's ``mcap_index`` rows, and the ledger row LAST. A crash in
between leaves a ledger without the new hash, so the next run redoes the file.

A windowed run replaces the file's rows inside the window only
(:func:`~pipeline.warehouse.staged.commit_source_window`, one commit per table: the
staged files added, the file's data files inside the window removed, any data file also
holding other rows rewritten without the window's rows of the file; no row of the staged
files passes through the driver) and writes neither ``mcap_index`` nor the ledger: those
describe whole-file ingests.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.decode.registry import RAW_TABLES
from pipeline.ingest.worker import FileManifest
from pipeline.tables import conform, default_site, empty
from pipeline.warehouse import pending
from pipeline.warehouse.crashpoints import crash_point
from pipeline.warehouse.delta import replace_source_file
from pipeline.warehouse.ledger import ledger_entry, write_entry
from pipeline.warehouse.staged import commit_source_window, commit_staged


def commit_file(
    warehouse: Path, m: FileManifest, *, start_ns: int | None = None, end_ns: int | None = None
) -> None:
    """Replace the file's rows in every raw table (one commit per table that changes),
    then (whole-file runs) its ``mcap_index`` rows and its ledger row. Readers see the
    file's tables as before until all are made (``pipeline.warehouse.pending``)."""
    names = list(dict.fromkeys((*RAW_TABLES, *m.staged)))
    marker = pending.begin(warehouse, [*names, "mcap_index", "ingest_ledger"], job="ingest",
                           source_file=m.source_file)
    _commit_tables(warehouse, m, names, start_ns, end_ns)
    pending.finish(warehouse, marker,
                   supersedes=lambda doc: doc.get("source_file") == m.source_file)


def _commit_tables(warehouse: Path, m: FileManifest, names: list[str],
                   start_ns: int | None, end_ns: int | None) -> None:
    for name in names:
        staged = m.staged.get(name, [])
        if start_ns is None:
            commit_staged(warehouse, name, staged, source_file=m.source_file)
        else:
            commit_source_window(warehouse, name, staged, source_file=m.source_file,
                                 start_ns=start_ns, end_ns=end_ns)
        crash_point(f"ingest.{name}")
    if start_ns is None:
        index = m.index_rows if m.index_rows is not None else empty("mcap_index")
        index = conform("mcap_index", index, site=m.site or default_site())
        replace_source_file(warehouse, "mcap_index", index, source_file=m.source_file)
        crash_point("ingest.mcap_index")
        entry = ledger_entry(
            m.source_file,
            size_bytes=m.size_bytes,
            sha256=m.sha256,
            status=m.status,
            error=m.error,
            message_count=m.message_count,
            rows={n: m.rows.get(n, 0) for n in RAW_TABLES if n != "rejects"},
            rejects_count=m.rows.get("rejects", 0),
            start_time_ns=m.start_time_ns,
            end_time_ns=m.end_time_ns,
            not_stored=m.not_stored,
            site=m.site or None,
        )
        write_entry(warehouse, entry)
        crash_point("ingest.ingest_ledger")
