"""Ingest ledger: one row per archived source file (path, size, hash, counts, status).

Re-ingesting a file whose size and SHA-256 match a ledger row with status ``ok`` or
``duplicate`` is a no-op. A ``partial`` file (something lost: a cut-off file, a decoder
not installed) and a ``quarantined`` one are retried: the README promises that a re-run
reads them again. ``duplicate``: the file's content (SHA-256) is already in the warehouse
under another path (its ``error`` names it): recorded, its rows not ingested twice.
Ledger rows are replaced with ``replace_source_file`` and written LAST
for a file, after its data rows, so a crash in between makes the next run redo the file.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.dataset as pds

from pipeline.tables import conform, default_site
from pipeline.warehouse.delta import read_table, replace_source_file

LEDGER = "ingest_ledger"
STATUSES = ("ok", "partial", "quarantined", "duplicate")
SKIP_STATUSES = ("ok", "duplicate")


def file_fingerprint(path: Path) -> tuple[int, str]:
    """``(size_bytes, sha256 hex)`` of the file's content (``hashlib.file_digest`` reads
    into one reused buffer: no fresh 1 MiB block, and its page faults, per read)."""
    with open(path, "rb") as f:
        h = hashlib.file_digest(f, "sha256")
        return f.tell(), h.hexdigest()


def ledger_entry(
    source_file: str,
    *,
    size_bytes: int,
    sha256: str,
    status: str,
    error: str | None,
    message_count: int,
    rows: dict[str, int],
    rejects_count: int,
    start_time_ns: int | None,
    end_time_ns: int | None,
    ingested_at_ns: int | None = None,
    not_stored: dict[str, int] | None = None,
    site: str | None = None,
) -> pa.Table:
    """One conformed ledger row. ``rows`` (rows written per table) and ``not_stored``
    (valid messages not kept, per type: ``nmea_GSV``, ``ais_type_4``, ...) are stored as
    JSON; ``ingested_at_ns`` defaults to the wall clock (ns since the Unix epoch)."""
    if status not in STATUSES:
        raise ValueError(f"ledger status must be one of {STATUSES}, got {status!r}")
    row = {
        "source_file": source_file,
        "size_bytes": size_bytes,
        "sha256": sha256,
        "status": status,
        "error": error,
        "message_count": message_count,
        "rows_json": json.dumps(rows, sort_keys=True),
        "rejects_count": rejects_count,
        "start_time_ns": start_time_ns,
        "end_time_ns": end_time_ns,
        "ingested_at_ns": time.time_ns() if ingested_at_ns is None else ingested_at_ns,
        "not_stored_json": json.dumps(not_stored or {}, sort_keys=True),
    }
    return conform(LEDGER, pa.Table.from_pylist([row]), site=site or default_site())


def write_entry(warehouse: Path, entry: pa.Table) -> None:
    """Replace the ledger row of the entry's source file (one commit)."""
    files = set(entry["source_file"].to_pylist())
    if len(files) != 1:
        raise ValueError(f"a ledger entry is one source file, got {sorted(files)}")
    replace_source_file(warehouse, LEDGER, entry, source_file=files.pop())


def lookup(warehouse: Path, source_file: str) -> dict | None:
    """The ledger row of ``source_file`` as a dict, or ``None``."""
    rows = read_table(
        warehouse, LEDGER, predicate=pds.field("source_file") == source_file
    ).to_pylist()
    return rows[-1] if rows else None


def same_content(warehouse: Path, sha256: str, source_file: str) -> str | None:
    """Another file the ledger holds with this SHA-256 and its rows ingested (status ok
    or partial), or ``None``."""
    rows = read_table(warehouse, LEDGER, predicate=pds.field("sha256") == sha256).to_pylist()
    ingested = ("ok", "partial")
    others = sorted(
        r["source_file"]
        for r in rows
        if r["source_file"] != source_file and r["status"] in ingested
    )
    return others[0] if others else None


def is_unchanged(warehouse: Path, path: str | Path, size: int, sha256: str) -> bool:
    """True when the ledger already holds ``path`` with this size and hash and status
    ok/duplicate: ingesting it again would change nothing."""
    row = lookup(warehouse, str(path))
    return (
        row is not None
        and row["status"] in SKIP_STATUSES
        and row["size_bytes"] == size
        and row["sha256"] == sha256
    )


def files_overlapping(warehouse: Path, start_ns: int, end_ns: int, site: str | None = None
                      ) -> list[str]:
    """Archived files (from the ingest ledger; of ``site`` when given) whose time span
    overlaps the window."""
    ledger = read_table(warehouse, "ingest_ledger", site=site)
    if ledger.num_rows == 0:
        return []
    overlaps = pc.and_(
        pc.less(ledger["start_time_ns"], end_ns), pc.greater_equal(ledger["end_time_ns"], start_ns)
    )
    # quarantined: nothing readable; duplicate: its content is ingested under another name
    ingested = pc.is_in(ledger["status"], value_set=pa.array(["ok", "partial"]))
    mask = pc.and_(overlaps, ingested)
    return sorted(set(ledger.filter(mask)["source_file"].to_pylist()))
